// Woven yarn layouts: the centre curves of the warp and weft yarns of a patch of cloth woven to any weave
// pattern the woven model accepts (a matrix, or a WIF draft through ParseWif), going over and under each
// other with crimp, and the fibers of every yarn generated along them (yarn.h). The single straight yarn of
// Wu and Yuksel's Fig. 7 is StraightYarnCurve / GenerateStraightYarn.
//
// Readings (ours; the papers give no woven geometry):
// - Frame (SPEC.md section 1): cloth normal +z; weft yarns (thread 1, texture u) run along +x, warp yarns
//   (thread 2, texture v) along +y. Warp yarn i (i = 0 .. repeats_u * warps - 1) lies at x = (i + 0.5)
//   spacing and takes pattern warp i mod warps; weft yarn j lies at y = (j + 0.5) spacing and takes pattern
//   pick j mod picks. So crossings sit at the centres of spacing x spacing cells, pattern cell (w, p) at
//   ((w + 0.5) s, (p + 0.5) s), and the patch is [0, repeats_u warps s] x [0, repeats_v picks s].
// - Extent: every yarn runs from patch edge to patch edge, and its height there follows the pattern
//   periodically (the edge lies halfway between the last crossing and the first one of the next repeat),
//   so patches placed side by side join into continuous, C1 yarns.
// - Crimp: at a crossing the yarn on top has its centre at z = +h and the other at z = -h, with
//   h = crimp * yarn_radius, crimp in [0, 1]. Full crimp puts the two centres 2 yarn_radius apart: two round
//   yarns of that radius just touch there, the smallest separation at which they do not interpenetrate.
//   crimp = 0 gives flat, straight yarns all at z = 0 (for comparison; they intersect at every crossing).
// - Between two consecutive crossings the height goes from one crossing's to the next with a half cosine,
//   z = z0 + (z1 - z0) (1 - cos(pi u)) / 2, u in [0, 1]: level at every crossing (C1), flat along a float.
// - Contact between crossings: the half cosine's curvature radius at a crossing it leaves is
//   s^2 / (pi^2 h), and two perpendicular round yarns touching at a crossing stay clear of each other nearby
//   only if that is at least their centre separation 2 h, i.e. s >= pi sqrt(2) h (about 4.44 yarn radii at
//   full crimp; measured: the warp and weft centres of a plain weave at full crimp come within 1.39 yarn
//   radii of each other at s = 2.2 yarn radii, 1.87 at 3.46, 2.00 from 4.44 on). Round, incompressible yarns
//   of any shape cannot do much better: a yarn passing from over one crossing yarn to under the next fits
//   between them only if s >= 2 sqrt(3) yarn_radius. Real yarns flatten against each other instead; this
//   model keeps them round. So the default spacing (4.5 yarn radii of cotton1) is the tightest whose full-crimp
//   layout is free of contact between yarns, an open weave; tighter spacings (down to 2 yarn_radius, where
//   neighbouring parallel yarns touch) are accepted and overlap near the crossings. (That is for the smooth
//   curve; the polyline's chords cut inside each crest, by 0.25% of the separation at 16 points per crossing,
//   0.02% at 64.)
// - Polyline: each crossing interval (one spacing) is sampled with points_per_crossing segments, an even
//   number so that every crossing and both patch edges are vertices. With spacing >= 2 yarn_radius and
//   crimp <= 1 the slope is at most pi/2 (57.5 degrees) and the polyline turns at most 34 degrees at a vertex
//   at 8 points per crossing, inside PolylineYarnCurve's 60-degree rule.
// - Yarn frame: the normal (N_yarn, where ply 0 starts) is the component of +z perpendicular to the vertex
//   tangent (the tangent PolylineYarnCurve uses: the bisector of the two segments), so ply 0 starts on top.
// - Seeds: yarn k of a layout has seed_offset (0 << 32 | i) for warp yarn i and (1 << 32 | j) for weft yarn j
//   (so a yarn keeps its offset when the patch grows), and GenerateLayout generates it with seed
//   SplitMix64(SplitMix64(yarn.seed) ^ seed_offset). SplitMix64 is a bijection, so distinct offsets always get
//   distinct seeds.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"
#include "server/yarn/curve.h"
#include "server/yarn/yarn.h"

namespace loomlight::yarn {

// ---- Layout ----

struct LayoutParams {
  // Centre-to-centre distance of neighbouring parallel yarns (warp and weft alike), in [2 yarn_radius,
  // kMaxLength]. Default 4.5 cotton1 yarn radii: the tightest at which full crimp leaves no contact (above).
  double spacing = 0.1701;
  // The round yarn the heights are set for, in [kMinLength, kMaxLength]; cotton1's by default. Normally the
  // YarnParams::yarn_radius the layout is generated with.
  double yarn_radius = 0.0378;
  // Height excursion of the centres, as a fraction of yarn_radius, in [0, 1] (1: touching at crossings).
  double crimp = 1.0;
  // Pattern repeats across the patch along x (u: how many times the warps repeat) and along y (v: picks),
  // each in [1, kMaxLayoutRepeats].
  int repeats_u = 1;
  int repeats_v = 1;
  // Polyline segments per crossing interval, even, in [kMinPointsPerCrossing, kMaxPointsPerCrossing].
  int points_per_crossing = 16;

  bool operator==(const LayoutParams&) const = default;
};

inline constexpr int kMaxLayoutRepeats = 256;
// Yarns per direction in one patch (warp yarns: repeats_u * warps; weft yarns: repeats_v * picks).
inline constexpr int kMaxLayoutYarns = 2048;
// Vertices of all the centre polylines of a patch together (about 130 bytes each once built, the curve's copy
// included).
inline constexpr int64_t kMaxLayoutVertices = 1'000'000;
inline constexpr int kMinPointsPerCrossing = 8;  // keeps the turning at a vertex under 34 degrees (above)
inline constexpr int kMaxPointsPerCrossing = 256;
// Largest patch side. A crimped yarn is at most 1.47 times as long as the patch side it spans (a half cosine
// of slope up to pi/2 at every crossing), so every yarn stays within GenerateYarn's kMaxLength.
inline constexpr double kMaxLayoutExtent = kMaxLength / 2;

// Returns "" or "field: reason" for the first problem. Rules: yarn_radius finite in [kMinLength, kMaxLength];
// spacing finite in [2 yarn_radius, kMaxLength]; crimp in [0, 1]; repeats_u, repeats_v in
// 1..kMaxLayoutRepeats; points_per_crossing even in kMinPointsPerCrossing..kMaxPointsPerCrossing.
std::string ValidateLayoutParams(const LayoutParams& p);

// One yarn of a layout.
struct LayoutYarn {
  bool warp = false;  // along +y (warp) or +x (weft)
  int index = 0;      // warp yarn i (at x = (i + 0.5) spacing) or weft yarn j (at y = (j + 0.5) spacing)
  int thread = 0;     // its thread in the pattern repeat: index mod warps (warp) or index mod picks (weft)
  uint64_t seed_offset = 0;  // (warp ? 0 : 1) << 32 | index; see the header's readings
  std::vector<Vec3> vertices;  // the centre polyline, in order along +y (warp) or +x (weft)
  std::vector<Vec3> normals;   // per vertex, the curve's N_yarn there
  PolylineYarnCurve curve;     // built from vertices and normals
};

struct WovenLayout {
  std::vector<LayoutYarn> yarns;  // warp yarns by index, then weft yarns by index
  int warp_yarns = 0;
  int weft_yarns = 0;
  double size_u = 0;   // patch extent along x: repeats_u * warps * spacing
  double size_v = 0;   // along y: repeats_v * picks * spacing
  double height = 0;   // h: crossing centre heights are +h (on top) and -h
  // Box holding every yarn's centre and its round cross-section (flyaways may stick out of it):
  // (0, 0, -(h + yarn_radius)) to (size_u, size_v, h + yarn_radius).
  Vec3 lower;
  Vec3 upper;
  int64_t vertices = 0;  // all polylines together
};

// Builds the centre curves of every warp and weft yarn of the patch. Returns "" and fills *out, or
// "field: reason" ("pattern: ..." for an unusable pattern, else a LayoutParams field; the patch limits
// report "repeats_u: ..." / "repeats_v: ..." for too many yarns or too wide a patch, "points_per_crossing:
// ..." for too many vertices), leaving *out empty.
std::string BuildLayout(const models::weave::WeavePattern& pattern, const LayoutParams& params, WovenLayout* out);

// ---- Fibers ----

// The seed GenerateLayout uses for a yarn: SplitMix64(SplitMix64(seed) ^ seed_offset).
uint64_t LayoutYarnSeed(uint64_t seed, uint64_t seed_offset);

struct LayoutGeometry {
  std::vector<YarnGeometry> yarns;  // one per layout yarn, in the layout's order
  int64_t fibers = 0;               // fiber curves, all yarns together
  int64_t control_points = 0;       // likewise
};

// The generation loop every layout shares (woven, client curves, knits): yarn k of `count` along curve(k) with
// params(k), one after another, each within what the yarns before it left of `limits` (its plies x fibers_per_ply at
// least, which the caller has checked for the whole layout), so a refused request costs at most one yarn's work
// past the budget. Returns "" and fills *out; "max_fibers: the layout needs more than N fiber curves (at NAME)" or
// "max_control_points: ..." with NAME = name(k); "cancelled"; or yarn k's own GenerateYarn error with *failed = k,
// for the caller to place. *out is left empty on error.
std::string GenerateYarnsInTurn(size_t count, const std::function<YarnParams(size_t)>& params,
                                const std::function<const YarnCurve&(size_t)>& curve,
                                const std::function<std::string(size_t)>& name, const DetailOptions& options,
                                const YarnLimits& limits, LayoutGeometry* out, size_t* failed);

// Generates every yarn of the layout along its curve (GenerateYarn), yarn k with `yarn` but seed
// LayoutYarnSeed(yarn.seed, layout.yarns[k].seed_offset). `limits` bound the whole layout as GenerateYarn's
// bound one yarn: max_fibers both the yarns' fibers together (yarns x plies x fibers_per_ply, checked first)
// and the fiber curves returned, all yarns together ("max_fibers: ..."); max_control_points the control
// points returned, all yarns together ("max_control_points: ...", with a lower bound from the curve lengths
// checked before any fiber is generated). A yarn that takes the curve total over its limit is the last one
// generated, so a refused request costs at most one yarn's work past the budget. Yarns are generated one
// after another, each on options.threads threads, so the result does not depend on the thread count.
// Returns "" and fills *out, or "field: reason" (as GenerateYarn, or "cancelled"), leaving *out empty.
std::string GenerateLayout(const YarnParams& yarn, const WovenLayout& layout, const DetailOptions& options,
                           const YarnLimits& limits, LayoutGeometry* out);

}  // namespace loomlight::yarn
