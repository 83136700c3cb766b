// Weft-knitted patches as yarn centre curves (proto KnitYarnLayout): one yarn per course along +x whose loops
// interlock with the course below, for stockinette jersey and 1 x 1 rib, the loop shape from a published
// parametric knit-loop model (cited in knit.cpp). The fibers then follow these centres through curve_layout.h.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "server/yarn/curve.h"

namespace loomlight::yarn {

enum class KnitStitch { kJersey, kRib1x1 };

struct KnitParams {
  KnitStitch stitch = KnitStitch::kJersey;
  int wales = 8;               // stitches across, along x
  int courses = 8;             // rows of stitches, along y
  double yarn_radius = 0.0378; // the round yarn the loops are shaped for (cotton1's by default)
  double wale_spacing = 0;     // 0 = DefaultWaleSpacing(yarn_radius)
  double course_spacing = 0;   // 0 = DefaultCourseSpacing(yarn_radius)
  int points_per_loop = 32;    // polyline vertices per stitch loop

  bool operator==(const KnitParams&) const = default;
};

inline constexpr int kMaxKnitStitches = 512;            // per direction
inline constexpr int64_t kMaxKnitVertices = 1'000'000;  // all courses together
double DefaultWaleSpacing(double yarn_radius);
double DefaultCourseSpacing(double yarn_radius);

// Returns "" or "field: reason" (wales, courses, yarn_radius, wale_spacing, course_spacing, points_per_loop).
std::string ValidateKnitParams(const KnitParams& p);

struct KnitLayout {
  std::vector<std::vector<Vec3>> courses;  // each course yarn's centre polyline, in order along +x; course 0 lowest
  double wale_spacing = 0;                 // as used (defaults resolved)
  double course_spacing = 0;
  // One repeat of the stitch pattern (jersey: one wale x one course; rib: two wales x one course): the patch is
  // periodic with it, for a BTF tile.
  double period_x = 0;
  double period_y = 0;
  Vec3 lower;  // every centre widened by yarn_radius
  Vec3 upper;
  int64_t vertices = 0;
};

// Builds the courses' centre polylines. Returns "" and fills *out, or "field: reason", leaving *out empty.
std::string BuildKnit(const KnitParams& p, KnitLayout* out);

}  // namespace loomlight::yarn
