// Yarns along client centre curves (proto CurveYarnLayout; Wu and Yuksel Sec. 2, whose input is yarn-level
// control points): a polyline or a uniform cubic B-spline per yarn, sampled into a PolylineYarnCurve whose
// normals are carried along by parallel transport (a rotation-minimizing frame), so the cross-section does not
// twist on its own and a yarn's fibers keep their place relative to its curve when the curve moves or bends
// (temporal coherence: same seed, same fibers). Knits (knit.h) lay their courses out through the same code.
//
// Readings (ours):
// - B-spline: "uniform cubic with clamped ends" is the open uniform knot vector, n points, knots 0,0,0,0, 1, 2,
//   ..., n-4, n-3,n-3,n-3,n-3 (n - 3 spans), so the curve starts at the first point and ends at the last
//   (Piegl and Tiller, The NURBS Book, 2.2; evaluated with Eigen's Splines module).
// - Sampling rule: each span becomes kBSplineSegmentsPerSpan chords of equal parameter step, doubled (up to
//   kMaxBSplineSegmentsPerSpan) while a chord turns by more than kBSplineRefineDegrees from the one before it
//   (the previous span's last chord included); a span whose chords still turn by 60 degrees or more at 64 chords
//   (a cusp, where the control points double back) is refused. So a span costs at most 8 + 16 + 32 + 64
//   evaluations, and the polyline always passes PolylineYarnCurve::Make's 60-degree rule. Each of the 8 chords of
//   a span that turns by theta radians sits within about L theta / 512 of the curve (L the span's length; exactly
//   so for a circular arc): 0.2% of L at 60 degrees.
// - Frames: the polyline's vertex tangents are PolylineYarnCurve's (the bisector of the two segments); the first
//   normal is the world axis least aligned with the first tangent (x, then y, then z on ties) made
//   perpendicular to it, so a two-point polyline from the origin along +z has StraightYarnCurve's frame; each
//   next normal is the last one carried over by the double reflection method (Wang, Juettler, Zheng and Liu,
//   "Computation of rotation minimizing frames", ACM TOG 27(1), article 2, 2008): reflect the frame in the plane
//   bisecting the segment, then in the plane that takes the reflected tangent to the next one. Along a planar
//   curve both reflection planes contain the plane's normal, so the normal's component along it stays exactly
//   as it started.
// - Arc length is the sampled polyline's. Wu and Yuksel keep a yarn's length coordinate fixed through an
//   animation (their Sec. 5): the fibers here are the same relative to the curve when its length is the same,
//   and stretch with it otherwise (the twist grid is laid over the whole length).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "server/yarn/curve.h"
#include "server/yarn/layout.h"
#include "server/yarn/yarn.h"

namespace loomlight::yarn {

enum class CurveKind { kPolyline, kBSpline };

// One yarn of a curve layout: its control points and its own yarn parameters. The library uses params.seed as
// it is (the API layer mixes a default seed with the curve's index); params.length is not used (the curve's).
struct CurveYarn {
  std::vector<Vec3> points;
  CurveKind kind = CurveKind::kPolyline;
  YarnParams params;

  bool operator==(const CurveYarn&) const = default;
};

inline constexpr int kMaxCurveYarns = 4096;
inline constexpr int64_t kMaxCurveLayoutPoints = 1'000'000;  // control points of all yarns together
// Centre polyline vertices of all yarns together once sampled (up to 120 bytes each built, a looping curve's
// search boxes included; a polyline has one per point, a B-spline at least kBSplineSegmentsPerSpan per span).
// One yarn: kMaxCurveVertices (curve.h).
inline constexpr int64_t kMaxCurveLayoutVertices = 2'000'000;
inline constexpr int kBSplineSegmentsPerSpan = 8;
inline constexpr int kMaxBSplineSegmentsPerSpan = 64;
inline constexpr double kBSplineRefineDegrees = 15;

// The centre of one yarn as a PolylineYarnCurve with parallel-transported normals. A polyline keeps its vertices
// (a straight two-point polyline along +z from the origin gives StraightYarnCurve's frames); a B-spline is
// sampled by the rule above. Returns "" or "points: reason" naming the point (fewer than 2 points, or 4 for a
// B-spline; a non-finite point or one farther than 1e6 from the origin; a point repeating the one before; a turn
// of 60 degrees or more at a polyline vertex; a B-spline cusp; more than kMaxCurveVertices points or vertices).
std::string MakeCentreCurve(const std::vector<Vec3>& points, CurveKind kind, PolylineYarnCurve* out);

// The most centre vertices MakeCentreCurve can make of these yarns (kMaxBSplineSegmentsPerSpan per B-spline
// span), at most kMaxCurveLayoutVertices + 1: for a request's memory estimate.
int64_t CurveLayoutVerticesAtMost(const std::vector<CurveYarn>& yarns);

// Builds every yarn's centre and generates its fibers (GenerateYarn with the yarn's own params), the layout's
// `limits` bounding all yarns together as GenerateLayout's do: max_fibers (the yarns' plies x fibers_per_ply
// summed) and a lower bound on the control points from the curve lengths are checked before any fiber is
// generated, and a yarn that takes a total over its limit is the last one generated. Returns "" and fills
// *fibers (one YarnGeometry per yarn) and *centres, or the first problem, leaving both empty: "yarns: ..." (none,
// more than kMaxCurveYarns), "yarns[k].field: reason" for a bad yarn (its points or a YarnParams field; the yarn
// that takes the layout past kMaxCurveLayoutPoints or kMaxCurveLayoutVertices: "yarns[k].points: ..."),
// "max_fibers: ..." or "max_control_points: ..." for the limits, "cancelled" as GenerateLayout.
std::string GenerateCurveLayout(const std::vector<CurveYarn>& yarns, const DetailOptions& options,
                                const YarnLimits& limits, LayoutGeometry* fibers,
                                std::vector<PolylineYarnCurve>* centres);

}  // namespace loomlight::yarn
