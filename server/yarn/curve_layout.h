// Yarns along client centre curves (proto CurveYarnLayout; Wu and Yuksel Sec. 2, whose input is yarn-level
// control points): a polyline or a uniform cubic B-spline per yarn, sampled into a PolylineYarnCurve whose
// normals are carried along by parallel transport (a rotation-minimizing frame), so the cross-section does not
// twist on its own and a yarn's fibers keep their place relative to its curve when the curve moves or bends
// (temporal coherence: same seed, same fibers). Knits (knit.h) lay their courses out through the same code.
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

// One yarn of a curve layout: its control points and its own yarn parameters (seed included).
struct CurveYarn {
  std::vector<Vec3> points;
  CurveKind kind = CurveKind::kPolyline;
  YarnParams params;

  bool operator==(const CurveYarn&) const = default;
};

inline constexpr int kMaxCurveYarns = 4096;
inline constexpr int64_t kMaxCurveLayoutPoints = 1'000'000;  // control points of all yarns together

// The centre of one yarn as a PolylineYarnCurve with parallel-transported normals. A polyline keeps its vertices
// (a straight two-point polyline along +z from the origin gives exactly StraightYarnCurve's frames); a B-spline is
// sampled finely enough for the polyline rules of PolylineYarnCurve::Make. Returns "" or "points: reason" (fewer
// than 2 points, or 4 for a B-spline; a non-finite or repeated point; a turn of 60 degrees or more at a polyline
// vertex; too many points).
std::string MakeCentreCurve(const std::vector<Vec3>& points, CurveKind kind, PolylineYarnCurve* out);

// Builds every yarn's centre and generates its fibers (GenerateYarn with the yarn's own params), the layout's
// `limits` bounding all yarns together as GenerateLayout's do. Returns "" and fills *fibers (one YarnGeometry per
// yarn) and *centres, or "yarns[k].field: reason" for the first bad yarn ("max_fibers: ...",
// "max_control_points: ...", "cancelled" as GenerateLayout), leaving both empty.
std::string GenerateCurveLayout(const std::vector<CurveYarn>& yarns, const DetailOptions& options,
                                const YarnLimits& limits, LayoutGeometry* fibers,
                                std::vector<PolylineYarnCurve>* centres);

}  // namespace loomlight::yarn
