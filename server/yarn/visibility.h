// How much light reaches a point inside a yarn, the cheap way (Wu and Yuksel Sec. 4.1-4.2): the yarn's own
// fibers by its cross-section density (YarnCrossSection's self-shadow slices and occlusion textures), other
// yarns as thick opaque tubes along their centre curves (Sec. 4.1's shadow-map geometry, here traced: eight-sided
// prisms of the tube's cross-section area, a triangle mesh in Embree). The reference it approximates is rays traced through the fibers themselves
// (FiberScene::Occluded); a renderer chooses between the two per request.
//
// Readings (ours):
// - A point is placed in its yarn's cross-section by the nearest point of the yarn's centre curve (its arc
//   length a), its offset in that frame's (N_yarn, B_yarn), turned back by the ply phase 2 pi a / alpha_yarn
//   (yarn.cpp's ply frame), the light's direction likewise by its projection onto (N_yarn, B_yarn).
// - Sec. 4.2's occlusion is within the yarn only; other yarns' occlusion ("existing techniques") is their
//   tubes' precomputed openness (OtherYarnsOpenness: the share of the sphere they leave open, traced once per
//   node of a table along each yarn), so both methods see the neighbouring yarns without a ray per sample.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "server/yarn/cross_section.h"
#include "server/yarn/curve.h"

namespace loomlight::yarn {

class TubeMesh;

// Light toward a fiber from a light: rays through the fibers, or the self-shadow slices (Sec. 4.1).
enum class ShadowMethod { kTraced, kSlices };
// Ambient light toward a fiber: rays through the fibers, the occlusion texture or the distance-based
// occlusion (Sec. 4.2).
enum class OcclusionMethod { kTraced, kTexture, kDistance };
const char* ToString(ShadowMethod m);
const char* ToString(OcclusionMethod m);

// A point in its yarn's untwisted cross-section frame (YarnCrossSection's).
struct CrossSectionPoint {
  int yarn = -1;  // -1: not in a yarn (an index out of range); the approximations then see nothing
  double x = 0, y = 0;
  double cos_phase = 1, sin_phase = 0;  // the ply twist turned back: phase 2 pi arc / alpha_yarn
  Vec3 normal, binormal;                // the yarn's N_yarn and B_yarn there
  double arc = 0;                       // along the yarn's centre curve
  double n = 0, b = 0;                  // the offset from the centre along N_yarn and B_yarn (before the turn)
};

class YarnVisibility {
 public:
  // One per yarn, in the fiber scene's yarn order: the centre curves the fibers were generated along, all
  // with `params`. tube_radius: the other yarns' thick tubes. `stop` is polled while the tubes are built.
  static std::string Make(const YarnParams& params, std::vector<std::shared_ptr<const YarnCurve>> centres,
                          double tube_radius, const CrossSectionOptions& options, std::function<bool()> stop,
                          YarnVisibility* out);

  // The point p of yarn `yarn` in that yarn's cross-section (once per shading point: it finds the nearest
  // point of the centre curve).
  CrossSectionPoint Locate(int yarn, Vec3 p) const;
  // Transmittance from a fiber of radius own_radius at x (on its axis) toward the light in direction w,
  // within its yarn: the slices.
  double SelfShadow(const CrossSectionPoint& x, Vec3 w, double own_radius) const;
  // Whether another yarn's tube blocks the ray from p (in yarn `yarn`) along w within max_distance.
  bool OtherYarnsBlock(int yarn, Vec3 p, Vec3 w, double max_distance) const;
  // Mean visibility at x within its yarn: the occlusion texture or its radial mean (kTraced: 1).
  double Occlusion(const CrossSectionPoint& x, OcclusionMethod method) const;
  // The share of directions, uniform on the sphere, in which no other yarn's tube blocks a ray from x: the
  // expectation of !OtherYarnsBlock over the sphere, interpolated in a table per yarn over arc length, angle
  // about the centre and distance from it. A node is traced on first use (kOpennessDirections stratified
  // directions; the same value whichever thread gets there first, so images do not depend on timing). 1 with
  // one yarn or outside a yarn.
  double OtherYarnsOpenness(const CrossSectionPoint& x) const;
  // Bytes of the openness table (allocated by Make, at most kMaxOpennessBytes).
  size_t openness_bytes() const;

  static constexpr int kOpennessDirections = 64;
  static constexpr size_t kMaxOpennessBytes = size_t{4} << 20;

  const YarnCrossSection& cross_section() const { return *cross_section_; }
  int yarns() const { return static_cast<int>(centres_.size()); }

 private:
  std::shared_ptr<const YarnCrossSection> cross_section_;
  std::vector<std::shared_ptr<const YarnCurve>> centres_;
  std::shared_ptr<const TubeMesh> tubes_;  // null with one yarn (nothing else to block)
  struct OpennessTable;
  std::shared_ptr<const OpennessTable> openness_;  // null without tubes
  double alpha_yarn_ = 1;
};

// The cross-section of a yarn, shared between calls: built once per distinct density (the parameters it
// depends on), the last few kept.
std::string SharedCrossSection(const YarnParams& params, const CrossSectionOptions& options,
                               std::shared_ptr<const YarnCrossSection>* out);

}  // namespace loomlight::yarn
