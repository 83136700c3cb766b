#include "server/yarn/curve_layout.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>

#include <unsupported/Eigen/Splines>

#include "server/models/quote.h"

namespace loomlight::yarn {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kMaxCoordinate = 1e6;  // PolylineYarnCurve::Make's bound
constexpr double kCos60 = 0.5;          // PolylineYarnCurve::Make refuses turns whose cosine is at most this
const double kCosRefine = std::cos(kBSplineRefineDegrees * kPi / 180);

using models::Number;

Vec3 Normalized(Vec3 v) { return (1 / Norm(v)) * v; }

// The direction from a to b, computed as PolylineYarnCurve::Make computes a segment's (so turning tests here and
// there agree bit for bit).
Vec3 Direction(Vec3 a, Vec3 b) {
  const Vec3 d = b - a;
  return (1 / Norm(d)) * d;
}

std::string CheckPoints(const std::vector<Vec3>& points, CurveKind kind) {
  const bool bspline = kind == CurveKind::kBSpline;
  const size_t fewest = bspline ? 4 : 2;
  if (points.size() < fewest)
    return "points: has " + std::to_string(points.size()) + " points, a " + (bspline ? "B-spline" : "polyline") +
           " needs at least " + std::to_string(fewest);
  if (points.size() > kMaxCurveVertices)
    return "points: has " + std::to_string(points.size()) + " points, more than " + std::to_string(kMaxCurveVertices);
  for (size_t i = 0; i < points.size(); ++i) {
    const Vec3& p = points[i];
    if (!(std::abs(p.x) <= kMaxCoordinate && std::abs(p.y) <= kMaxCoordinate && std::abs(p.z) <= kMaxCoordinate))
      return "points: point " + std::to_string(i) + " is not finite or is farther than " + Number(kMaxCoordinate) +
             " from the origin";
    // Norm, not ==: points a few subnormals apart would give a segment of length 0 too.
    if (i > 0 && !(Norm(p - points[i - 1]) > 0))
      return "points: point " + std::to_string(i) + " repeats point " + std::to_string(i - 1);
  }
  return "";
}

// Samples the clamped uniform cubic B-spline through `points` by the header's rule.
std::string SampleBSpline(const std::vector<Vec3>& points, std::vector<Vec3>* out) {
  using Spline3 = Eigen::Spline<double, 3, 3>;
  const Eigen::Index n = Eigen::Index(points.size());
  const Eigen::Index spans = n - 3;
  Spline3::KnotVectorType knots(n + 4);
  for (Eigen::Index k = 0; k < n + 4; ++k) knots(k) = double(std::clamp<Eigen::Index>(k - 3, 0, spans));
  Spline3::ControlPointVectorType control(3, n);
  for (Eigen::Index k = 0; k < n; ++k) control.col(k) << points[k].x, points[k].y, points[k].z;
  const Spline3 spline(knots, control);

  out->assign(1, points.front());  // clamped: the curve starts at the first point and ends at the last
  std::vector<Vec3> samples;
  for (Eigen::Index s = 0; s < spans; ++s) {
    for (int segments = kBSplineSegmentsPerSpan;; segments *= 2) {
      samples.clear();
      for (int j = 1; j <= segments; ++j) {
        if (s + 1 == spans && j == segments) {
          samples.push_back(points.back());
        } else {
          const Spline3::PointType p = spline(double(s) + double(j) / segments);
          samples.push_back({p(0), p(1), p(2)});
        }
      }
      // The sharpest turn from chord to chord, starting from the polyline's last chord (across the knot).
      double worst = 1;
      bool degenerate = false;
      Vec3 from = out->back();
      bool has_direction = out->size() >= 2;
      Vec3 direction = has_direction ? Direction((*out)[out->size() - 2], from) : Vec3{};
      for (const Vec3& q : samples) {
        if (!(Norm(q - from) > 0)) {
          degenerate = true;
          break;
        }
        const Vec3 next = Direction(from, q);
        if (has_direction) worst = std::min(worst, Dot(direction, next));
        direction = next;
        has_direction = true;
        from = q;
      }
      if (!degenerate && worst >= kCosRefine) break;
      if (segments < kMaxBSplineSegmentsPerSpan) continue;
      if (degenerate || worst <= kCos60)
        return "points: the B-spline turns 60 degrees or more within 1/" + std::to_string(kMaxBSplineSegmentsPerSpan) +
               " of the span of points " + std::to_string(s) + ".." + std::to_string(s + 3) +
               " (a cusp: the points double back); move them apart";
      break;
    }
    if (out->size() + samples.size() > kMaxCurveVertices)
      return "points: the B-spline samples to more than " + std::to_string(kMaxCurveVertices) +
             " vertices (at point " + std::to_string(s + 3) + ")";
    out->insert(out->end(), samples.begin(), samples.end());
  }
  return "";
}

// The first normal: the world axis least aligned with t (x, then y, then z on ties), made perpendicular to it.
Vec3 InitialNormal(Vec3 t) {
  const double x = std::abs(t.x), y = std::abs(t.y), z = std::abs(t.z);
  const Vec3 axis = x <= y && x <= z ? Vec3{1, 0, 0} : y <= z ? Vec3{0, 1, 0} : Vec3{0, 0, 1};
  return Normalized(axis - Dot(axis, t) * t);
}

// Normal r at vertex x0 (tangent t0) carried to x1 (tangent t1) by the double reflection method (Wang, Juettler,
// Zheng and Liu 2008). The tangents lie within 30 degrees of the segment (PolylineYarnCurve's turning
// rule), so the second reflection's vector t1 - t0' is at least sqrt(3) long and the reflection is well defined.
Vec3 DoubleReflection(Vec3 r, Vec3 x0, Vec3 t0, Vec3 x1, Vec3 t1) {
  const Vec3 v1 = x1 - x0;
  const double c1 = Dot(v1, v1);
  const Vec3 r_l = r - (2 / c1 * Dot(v1, r)) * v1;
  const Vec3 t_l = t0 - (2 / c1 * Dot(v1, t0)) * v1;
  const Vec3 v2 = t1 - t_l;
  const double c2 = Dot(v2, v2);
  const Vec3 r1 = r_l - (2 / c2 * Dot(v2, r_l)) * v2;
  return Normalized(r1 - Dot(r1, t1) * t1);  // reflections keep it perpendicular; this removes rounding only
}

std::string BuildCentre(const std::vector<Vec3>& points, CurveKind kind, PolylineYarnCurve* out, size_t* vertices) {
  *vertices = 0;
  if (std::string e = CheckPoints(points, kind); !e.empty()) return e;
  std::vector<Vec3> v;
  if (kind == CurveKind::kBSpline) {
    if (std::string e = SampleBSpline(points, &v); !e.empty()) return e;
  } else {
    for (size_t i = 1; i + 1 < points.size(); ++i)
      if (Dot(Direction(points[i - 1], points[i]), Direction(points[i], points[i + 1])) <= kCos60)
        return "points: the polyline turns 60 degrees or more at point " + std::to_string(i) +
               "; use a B-spline or more points";
    v = points;
  }
  std::vector<Vec3> normals(v.size());
  Vec3 tangent = PolylineYarnCurve::VertexTangent(v, 0);
  normals[0] = InitialNormal(tangent);
  for (size_t i = 0; i + 1 < v.size(); ++i) {
    const Vec3 next = PolylineYarnCurve::VertexTangent(v, i + 1);
    normals[i + 1] = DoubleReflection(normals[i], v[i], tangent, v[i + 1], next);
    tangent = next;
  }
  const size_t n = v.size();
  if (std::string e = PolylineYarnCurve::Make(std::move(v), std::move(normals), out); !e.empty())
    return "internal: the centre polyline was refused: " + e;  // ruled out above; reported, not hidden
  *vertices = n;
  return "";
}

// The centre vertices of a yarn whose B-spline spans get `per_span` chords each (a polyline: its points).
int64_t CentreVertices(const CurveYarn& y, int per_span) {
  const int64_t n = int64_t(y.points.size());
  if (y.kind == CurveKind::kPolyline) return n;
  return n >= 4 ? int64_t(per_span) * (n - 3) + 1 : 0;
}

}  // namespace

std::string MakeCentreCurve(const std::vector<Vec3>& points, CurveKind kind, PolylineYarnCurve* out) {
  size_t vertices = 0;
  return BuildCentre(points, kind, out, &vertices);
}

int64_t CurveLayoutVerticesAtMost(const std::vector<CurveYarn>& yarns) {
  int64_t total = 0;
  for (const CurveYarn& y : yarns) {
    total += CentreVertices(y, kMaxBSplineSegmentsPerSpan);
    if (total > kMaxCurveLayoutVertices) return kMaxCurveLayoutVertices + 1;
  }
  return total;
}

std::string GenerateCurveLayout(const std::vector<CurveYarn>& yarns, const DetailOptions& options,
                                const YarnLimits& limits, LayoutGeometry* fibers,
                                std::vector<PolylineYarnCurve>* centres) {
  *fibers = LayoutGeometry();
  centres->clear();
  std::string e;
  if (!(e = ValidateDetailOptions(options)).empty()) return e;
  if (limits.max_fibers < 0) return "max_fibers: is " + std::to_string(limits.max_fibers) + ", must be >= 0";
  if (limits.max_control_points < 0)
    return "max_control_points: is " + std::to_string(limits.max_control_points) + ", must be >= 0";
  if (yarns.empty()) return "yarns: the layout has no yarns";
  if (yarns.size() > size_t(kMaxCurveYarns))
    return "yarns: has " + std::to_string(yarns.size()) + " yarns, more than " + std::to_string(kMaxCurveYarns);

  // Sizes and work bounds from the points and parameters alone, before anything is built.
  int64_t points = 0;
  int64_t fewest_vertices = 0;
  int64_t all_fibers = 0;
  for (size_t k = 0; k < yarns.size(); ++k) {
    const CurveYarn& y = yarns[k];
    const std::string at = "yarns[" + std::to_string(k) + "]";
    points += int64_t(y.points.size());
    // The layout-wide sizes name the yarn that takes them over, so a client knows where to cut.
    if (points > kMaxCurveLayoutPoints)
      return at + ".points: the yarns up to this one have more than " + std::to_string(kMaxCurveLayoutPoints) +
             " points in all";
    fewest_vertices += CentreVertices(y, kBSplineSegmentsPerSpan);
    if (fewest_vertices > kMaxCurveLayoutVertices)
      return at + ".points: the centre curves up to this yarn need at least " + std::to_string(fewest_vertices) +
             " vertices (" + std::to_string(kBSplineSegmentsPerSpan) + " per B-spline span), more than " +
             std::to_string(kMaxCurveLayoutVertices) + " in all; use fewer B-spline points";
    if (!(e = ValidateYarnParams(y.params)).empty()) return at + "." + e;
    all_fibers += int64_t(y.params.plies) * y.params.fibers_per_ply;
  }
  if (all_fibers > limits.max_fibers)
    return "max_fibers: the layout's " + std::to_string(yarns.size()) + " yarns have " + std::to_string(all_fibers) +
           " fibers (plies x fibers_per_ply), more than the limit " + std::to_string(limits.max_fibers);

  // The centres (their cost bounded by the vertex limits), then the control points their lengths need.
  std::vector<PolylineYarnCurve> built(yarns.size());
  int64_t vertices = 0;
  double min_points = 0;
  for (size_t k = 0; k < yarns.size(); ++k) {
    const std::string at = "yarns[" + std::to_string(k) + "]";
    size_t n = 0;
    if (!(e = BuildCentre(yarns[k].points, yarns[k].kind, &built[k], &n)).empty()) return at + "." + e;
    vertices += int64_t(n);
    if (vertices > kMaxCurveLayoutVertices)
      return at + ".points: the centre curves up to this yarn sample to more than " +
             std::to_string(kMaxCurveLayoutVertices) + " vertices in all; use fewer B-spline points";
    const double length = built[k].Length();
    if (!(length >= kMinLength && length <= kMaxLength))
      return at + ".points: the curve is " + Number(length) + " long, must be in [" + Number(kMinLength) + ", " +
             Number(kMaxLength) + "]";
    min_points += MinControlPoints(yarns[k].params, options, length);
  }
  if (min_points > double(limits.max_control_points))
    return "max_control_points: the layout needs at least " + Number(min_points) + " control points (" +
           std::to_string(yarns.size()) + " yarns), more than the limit " + std::to_string(limits.max_control_points);

  const auto name = [](size_t k) { return "yarns[" + std::to_string(k) + "]"; };
  size_t failed = 0;
  e = GenerateYarnsInTurn(
      yarns.size(), [&](size_t k) { return yarns[k].params; },
      [&](size_t k) -> const YarnCurve& { return built[k]; }, name, options, limits, fibers, &failed);
  if (!e.empty()) return e == "cancelled" || e.rfind("max_", 0) == 0 ? e : name(failed) + "." + e;
  *centres = std::move(built);
  return "";
}

}  // namespace loomlight::yarn
