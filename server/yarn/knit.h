// Weft-knitted patches as yarn centre curves (proto KnitYarnLayout): one yarn per course along +x whose loops
// interlock with the course below, for stockinette jersey and 1 x 1 rib, the loop shape from a published
// parametric knit-loop model (Crane's, cited with its formula in knit.cpp). The fibers then follow these centres
// through curve_layout.h.
//
// Readings (ours; Crane gives the plain-knit curve, not these choices):
// - The loop: a course is Crane's centreline gamma(t) = (t + a sin 2t, h cos t, d cos 2t), one loop per 2 pi of
//   t, with his shape a = 3/2 and his proportions h : d : row offset : loop period = 4 : 1 : 4.5 : 2 pi, scaled
//   by s yarn radii per unit of his: s = 1.34 for jersey, 1.40 for the rib (below). So the default wale spacing
//   is 2 pi s yarn radii (8.42 jersey, 8.80 rib), the default course spacing 4.5 s (6.03, 6.30), the loop
//   height h = 4 s and the depth d = s (1.34, 1.40). A client's spacings stretch x by wale_spacing / (2 pi) per
//   unit of t and y by course_spacing / 4.5 (h = 4/4.5 course_spacing); the depth d stays s yarn radii.
// - Frame: wales along +y, courses along +x, the technical face toward +z. Crane's +z side shows the heads and
//   sinker loops, i.e. the technical back, so z is negated: the legs lie at z = +d, heads and sinkers at -d. Wale
//   w's head is at x = (w + 1/2) wale_spacing, the sinker loops at x = w wale_spacing; course j's legs are
//   centred on y = (j + 1/2) course_spacing. A course runs from x = 0 to wales * wale_spacing, from the bottom of
//   a sinker loop to the bottom of one (half a sinker loop at each end), so patches side by side join into
//   continuous yarns (for jersey C-infinity: the tangent is +x at both ends). Since 2 h > course_spacing, course
//   j + 1's sinker loops reach down between course j's legs: the loops interlock with the course below only.
// - Rib: wales 0, 2, 4, ... are knit, 1, 3, ... purl, a purl loop the knit loop mirrored through the fabric
//   plane (z -> -z), so its loop is pulled through from the back. Between a knit and a purl wale the yarn must
//   pass through the fabric: z = -sigma d cos 2t with sigma +1 on knit wales and -1 on purl wales, going from
//   one to the other by a quintic smootherstep (C2) over |t - 2 pi k| < kRibTransition around the bottom of the
//   sinker loop at the wale boundary, where the sinker passes between the legs of the course below (one in
//   front of it, the other behind). sigma(t + 2 pi) = -sigma(t), so a purl wale is exactly the mirrored knit
//   wale, transitions included (and every loop is as long).
// - Contact: s is the smallest scale (to 0.01) at which, at kMinPointsPerLoop points per loop, the centre
//   polylines of different courses, and the parts of one course more than pi yarn radii apart along it, stay at
//   least 2 yarn radii apart, so round yarns of that radius do not interpenetrate. Crane's own pairing (tube
//   radius 4/5 of his unit, s = 1.25) overlaps: his smooth curves come within 1.53 units, 1.92 tube radii.
//   Measured (knit_test): jersey at s = 1.34 and 32 points, 2.003 yarn radii between courses and 2.074 within a
//   course (the smooth curves: 2.056 and 2.069); rib at 1.40, 2.010 and 2.167 (smooth: 2.054 and 2.162); finer
//   polylines come closer to the smooth curves (2.043 and 2.046 between courses at 64 points). The rib needs the
//   larger s because its sinker crosses the fabric between two legs of the course below. Stretching x and y by
//   factors >= 1 with z fixed moves no two points closer, so spacings at or above the defaults keep the
//   clearance; smaller spacings are refused (the loops would interpenetrate). The smallest radius of curvature
//   is 2.56 yarn radii in jersey and 1.16 in the rib's transition (smooth curves): a tube of the yarn's radius
//   does not fold on itself.
// - Polyline: each loop is sampled at points_per_loop equal steps of t (vertex i of a course at t = 2 pi i /
//   points_per_loop), so a course has wales * points_per_loop + 1 vertices. At 32 points per loop the polyline
//   turns at most 21 degrees at a vertex in jersey and 36 in the rib (its transition) at the default spacings,
//   and 46.3 degrees at the worst stretch (3 x the default wale spacing, 1 x the course spacing), inside
//   PolylineYarnCurve's 60.
// - Periodicity: course j + 1 is course j translated by (0, course_spacing, 0) and each course repeats with
//   period_x = wale_spacing (jersey) or 2 wale_spacing (rib) along x, vertex for vertex (vertex i + points per
//   period is vertex i + (period_x, 0, 0)): one repeat, period_x by period_y = course_spacing, is a BTF tile.
// - Geometry (defaults): a loop takes 16.5 yarn diameters of yarn in jersey (17.5 in the rib), within the 14 to
//   20 of real jerseys and close to the jamming loop length of round incompressible yarns in plain knit (l/d =
//   16.67 in Chamberlain's 1926 model, 16.75 in Hepworth and Leaf's): the defaults are a tight, jammed jersey, as
//   the smallest contact-free scale should be. Munden's constants: kc = l / course spacing = 5.48, kw = l / wale
//   spacing = 3.93.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "server/yarn/curve.h"

namespace loomlight::yarn {

enum class KnitStitch { kJersey, kRib1x1 };

struct KnitParams {
  KnitStitch stitch = KnitStitch::kJersey;
  int wales = 8;               // stitches across, along x, in 1..kMaxKnitStitches
  int courses = 8;             // rows of stitches, along y, in 1..kMaxKnitStitches
  double yarn_radius = 0.0378; // the round yarn the loops are shaped for (cotton1's by default)
  double wale_spacing = 0;     // 0 = DefaultWaleSpacing(stitch, yarn_radius); else in [1, kMaxSpacingStretch] x it
  double course_spacing = 0;   // 0 = DefaultCourseSpacing(stitch, yarn_radius); likewise
  int points_per_loop = 32;    // polyline vertices per stitch loop, in kMinPointsPerLoop..kMaxPointsPerLoop

  bool operator==(const KnitParams&) const = default;
};

inline constexpr int kMaxKnitStitches = 512;            // per direction
inline constexpr int64_t kMaxKnitVertices = 1'000'000;  // all courses together
inline constexpr int kMinPointsPerLoop = 32;            // the defaults' clearance is set at 32 (above)
inline constexpr int kMaxPointsPerLoop = 256;
inline constexpr double kMaxSpacingStretch = 3;         // most spacing, in defaults (keeps turning < 47 degrees)
inline constexpr double kRibTransition = 0.5;           // half-width in t of the rib's knit-purl passage (radians)

// The tightest spacings free of contact (above): 2 pi s and 4.5 s yarn radii, s = 1.34 (jersey) or 1.40 (rib).
double DefaultWaleSpacing(KnitStitch stitch, double yarn_radius);
double DefaultCourseSpacing(KnitStitch stitch, double yarn_radius);

// Returns "" or "field: reason" (wales, courses, yarn_radius, wale_spacing, course_spacing, points_per_loop).
std::string ValidateKnitParams(const KnitParams& p);

struct KnitLayout {
  std::vector<std::vector<Vec3>> courses;  // each course yarn's centre polyline, in order along +x; course 0 lowest
  double wale_spacing = 0;                 // as used (defaults resolved)
  double course_spacing = 0;
  double loop_height = 0;  // h: a course's heads at +h and sinkers at -h about its legs' centre line
  double loop_depth = 0;   // d: legs at z = +d (knit) or -d (purl), heads and sinkers at the opposite
  // One repeat of the stitch pattern (jersey: one wale x one course; rib: two wales x one course): the patch is
  // periodic with it, for a BTF tile.
  double period_x = 0;
  double period_y = 0;
  Vec3 lower;  // every centre widened by yarn_radius
  Vec3 upper;
  int64_t vertices = 0;
  double course_length = 0;  // of each course's polyline (all are equal)
};

// Builds the courses' centre polylines. Returns "" and fills *out, or "field: reason", leaving *out empty. Besides
// ValidateKnitParams: "points_per_loop: ..." for more than kMaxKnitVertices vertices, "wales: ..." for a course
// longer than a yarn may be (kMaxLength), both checked before anything is allocated.
std::string BuildKnit(const KnitParams& p, KnitLayout* out);

}  // namespace loomlight::yarn
