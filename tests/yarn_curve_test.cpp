// Yarns along client centre curves (server/yarn/curve_layout.h): a straight curve gives the straight yarn's
// fibers, a bent one keeps every fiber's place relative to it, the frames are rotation minimizing (planar curves,
// a helix's known twist), B-splines are sampled on the clamped uniform cubic B-spline (evaluated here
// independently, by the Cox-de Boor recursion), and bad curves and limits are refused naming the yarn.
#include "server/yarn/curve_layout.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "server/yarn/knit.h"
#include "server/yarn/yarn_job.h"

namespace loomlight::yarn {
namespace {

constexpr double kPi = 3.14159265358979323846;

double Distance(Vec3 a, Vec3 b) { return Norm(a - b); }
Vec3 Unit(Vec3 v) { return (1 / Norm(v)) * v; }
double Angle(Vec3 a, Vec3 b) { return std::atan2(Norm(Cross(a, b)), Dot(a, b)); }

bool StartsWith(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

// The arc length at each vertex of a polyline, summed here.
std::vector<double> VertexArcs(const std::vector<Vec3>& v) {
  std::vector<double> arcs(v.size(), 0.0);
  for (size_t i = 1; i < v.size(); ++i) arcs[i] = arcs[i - 1] + Distance(v[i - 1], v[i]);
  return arcs;
}

// One yarn through GenerateCurveLayout.
std::string GenerateOne(const CurveYarn& yarn, YarnGeometry* fibers, PolylineYarnCurve* centre,
                        const DetailOptions& options = {}) {
  LayoutGeometry layout;
  std::vector<PolylineYarnCurve> centres;
  const std::string e = GenerateCurveLayout({yarn}, options, YarnLimits{}, &layout, &centres);
  if (!e.empty()) return e;
  *fibers = layout.yarns.at(0);
  *centre = centres.at(0);
  return "";
}

// A circular arc of radius r turning by `turn` radians, from the origin along +z, bending towards +x (in the xz
// plane), as a polyline of `segments` equal chords.
std::vector<Vec3> ArcPolyline(double r, double turn, int segments) {
  std::vector<Vec3> v;
  for (int i = 0; i <= segments; ++i) {
    const double phi = turn * i / segments;
    v.push_back({r * (1 - std::cos(phi)), 0, r * std::sin(phi)});
  }
  return v;
}

// A gentle S in 3-D: B-spline control points along +z, swaying in x and y.
std::vector<Vec3> SwayingControlPoints() {
  std::vector<Vec3> p;
  for (int k = 0; k < 8; ++k) p.push_back({0.1 * std::sin(0.9 * k), 0.06 * std::cos(0.6 * k), 0.25 * k});
  return p;
}

// The clamped uniform cubic B-spline at parameter u in [0, n - 3], by the Cox-de Boor recursion on the knot
// vector 0,0,0,0,1,..,n-4,n-3,n-3,n-3,n-3 (the last span closed at its end).
Vec3 BSplineAt(const std::vector<Vec3>& points, double u) {
  const int n = int(points.size());
  std::vector<double> knots(size_t(n + 4));
  for (int k = 0; k < n + 4; ++k) knots[size_t(k)] = std::clamp(k - 3, 0, n - 3);
  // Degree-0 basis: 1 on the span holding u (the last non-empty span for u at the end).
  std::vector<double> basis(size_t(n + 3), 0.0);
  for (int i = 0; i < n + 3; ++i)
    if (knots[size_t(i)] < knots[size_t(i + 1)] &&
        ((knots[size_t(i)] <= u && u < knots[size_t(i + 1)]) || (u == n - 3 && knots[size_t(i + 1)] == n - 3)))
      basis[size_t(i)] = 1;
  for (int d = 1; d <= 3; ++d) {
    for (int i = 0; i + d < n + 3; ++i) {
      double b = 0;
      const double left = knots[size_t(i + d)] - knots[size_t(i)];
      const double right = knots[size_t(i + d + 1)] - knots[size_t(i + 1)];
      if (left > 0) b += (u - knots[size_t(i)]) / left * basis[size_t(i)];
      if (right > 0) b += (knots[size_t(i + d + 1)] - u) / right * basis[size_t(i + 1)];
      basis[size_t(i)] = b;
    }
  }
  Vec3 out;
  for (int i = 0; i < n; ++i) out = out + basis[size_t(i)] * points[size_t(i)];
  return out;
}

// ---- Straight ----

TEST(YarnCurveTest, StraightPolylineHasTheStraightYarnsFrames) {
  PolylineYarnCurve centre;
  ASSERT_EQ(MakeCentreCurve({{0, 0, 0}, {0, 0, 1.25}}, CurveKind::kPolyline, &centre), "");
  const StraightYarnCurve straight(1.25);
  EXPECT_EQ(centre.Length(), 1.25);
  double worst = 0;
  for (int i = 0; i <= 1000; ++i) {
    const double a = 1.25 * i / 1000;
    const CurveFrame f = centre.At(a), g = straight.At(a);
    worst = std::max({worst, Distance(f.position, g.position), Distance(f.tangent, g.tangent),
                      Distance(f.normal, g.normal)});
  }
  EXPECT_LE(worst, 1e-15);
}

TEST(YarnCurveTest, StraightPolylineGivesTheStraightYarnsFibers) {
  YarnParams p;  // cotton1
  p.seed = 12345;
  p.length = 1.25;
  YarnGeometry straight;
  ASSERT_EQ(GenerateStraightYarn(p, {}, {}, &straight), "");
  YarnGeometry laid;
  PolylineYarnCurve centre;
  ASSERT_EQ(GenerateOne({{{0, 0, 0}, {0, 0, 1.25}}, CurveKind::kPolyline, p}, &laid, &centre), "");
  ASSERT_EQ(laid.fibers.size(), straight.fibers.size());
  EXPECT_EQ(laid.control_points, straight.control_points);
  EXPECT_EQ(laid.plies, straight.plies);
  double worst = 0;
  int64_t exact = 0, points = 0;
  for (size_t c = 0; c < laid.fibers.size(); ++c) {
    const FiberCurve &a = laid.fibers[c], &b = straight.fibers[c];
    ASSERT_EQ(a.type, b.type);
    ASSERT_EQ(a.ply, b.ply);
    ASSERT_EQ(a.fiber, b.fiber);
    ASSERT_EQ(a.width, b.width);
    ASSERT_EQ(a.points.size(), b.points.size());
    for (size_t i = 0; i < a.points.size(); ++i) {
      worst = std::max(worst, Distance(a.points[i], b.points[i]));
      exact += a.points[i] == b.points[i];
      ++points;
    }
  }
  std::printf("straight polyline vs straight yarn: %lld of %lld control points identical, largest difference %.3g\n",
              static_cast<long long>(exact), static_cast<long long>(points), worst);
  EXPECT_LE(worst, 1e-12 * p.length);
}

// ---- Bent ----

// The largest turn at a vertex of a polyline and the largest rate at which its vertex tangents (bisectors) turn
// per unit length over a segment.
void Turning(const std::vector<Vec3>& v, double* max_turn, double* max_rate) {
  *max_turn = 0;
  *max_rate = 0;
  std::vector<Vec3> tangents(v.size());
  for (size_t i = 0; i < v.size(); ++i) {
    const Vec3 before = i > 0 ? Unit(v[i] - v[i - 1]) : Vec3{};
    const Vec3 after = i + 1 < v.size() ? Unit(v[i + 1] - v[i]) : Vec3{};
    tangents[i] = Unit(before + after);
    if (i > 0 && i + 1 < v.size()) *max_turn = std::max(*max_turn, Angle(before, after));
  }
  for (size_t i = 0; i + 1 < v.size(); ++i)
    *max_rate = std::max(*max_rate, Angle(tangents[i], tangents[i + 1]) / Distance(v[i], v[i + 1]));
}

// Bends the straight yarn of the curve's length along the curve and checks every control point of every fiber:
// (1) rebuilt from the straight yarn's point q as At(q.z).position + q.x N + q.y B, it is the bent yarn's point
// (the straight yarn's frame is x, y, z at arc z, so that is the same fiber in the same place relative to the
// curve), to rounding; (2) its coordinates in the frame ClosestFrame finds ((p - c).N, (p - c).B, arc) are the
// straight point's x, y, z, within what the polyline's chords allow: a point at distance rho from the centre lies
// in the cross-section plane of the interpolated tangent, which is within half a vertex turn (theta / 2) of the
// segment's direction, so the closest point on the segment is off along it by at most rho sin(theta / 2), and
// the transverse coordinates then by that times (sin(theta / 2) + rho w + that w), w the frame's turning rate.
// The bounds below take theta itself (twice that) for the closest point landing on a neighbouring segment.
void ExpectFibersKeepTheirPlace(const std::vector<Vec3>& points, CurveKind kind, const char* name) {
  SCOPED_TRACE(name);
  PolylineYarnCurve centre;
  ASSERT_EQ(MakeCentreCurve(points, kind, &centre), "");
  YarnParams p;  // cotton1
  p.seed = 99;
  p.length = centre.Length();
  YarnGeometry straight, bent;
  ASSERT_EQ(GenerateStraightYarn(p, {}, {}, &straight), "");
  PolylineYarnCurve laid_centre;
  ASSERT_EQ(GenerateOne({points, kind, p}, &bent, &laid_centre), "");
  EXPECT_EQ(laid_centre.CentrePolyline(), centre.CentrePolyline());
  ASSERT_EQ(bent.fibers.size(), straight.fibers.size());
  double theta = 0, rate = 0;
  Turning(centre.CentrePolyline(), &theta, &rate);
  rate *= 1.5;  // the normalised linear interpolation turns unevenly over a segment, by at most this much faster
  double rebuilt = 0, worst_arc = 0, worst_across = 0, worst_arc_share = 0, worst_across_share = 0, farthest = 0;
  for (size_t c = 0; c < bent.fibers.size(); ++c) {
    const FiberCurve &a = bent.fibers[c], &b = straight.fibers[c];
    ASSERT_EQ(a.type, b.type);
    ASSERT_EQ(a.points.size(), b.points.size());
    for (size_t i = 0; i < a.points.size(); ++i) {
      const Vec3 q = b.points[i];
      const CurveFrame f = centre.At(q.z);
      const Vec3 binormal = Cross(f.tangent, f.normal);
      rebuilt = std::max(rebuilt, Distance(a.points[i], f.position + q.x * f.normal + q.y * binormal));

      double arc = 0;
      const CurveFrame g = centre.ClosestFrame(a.points[i], &arc);
      const Vec3 w = a.points[i] - g.position;
      const double rho = std::hypot(q.x, q.y);
      farthest = std::max(farthest, rho);
      const double arc_bound = rho * std::sin(theta) + 1e-12;
      const double across_bound = arc_bound * (std::sin(theta) + rho * rate + arc_bound * rate) + 1e-12;
      const double arc_error = std::abs(arc - q.z);
      const double across_error =
          std::max(std::abs(Dot(w, g.normal) - q.x), std::abs(Dot(w, Cross(g.tangent, g.normal)) - q.y));
      ASSERT_LE(arc_error, arc_bound) << "fiber curve " << c << " point " << i;
      ASSERT_LE(across_error, across_bound) << "fiber curve " << c << " point " << i;
      worst_arc = std::max(worst_arc, arc_error);
      worst_across = std::max(worst_across, across_error);
      worst_arc_share = std::max(worst_arc_share, arc_error / arc_bound);
      worst_across_share = std::max(worst_across_share, across_error / across_bound);
    }
  }
  std::printf("%s: length %.4f, largest vertex turn %.3f deg, fibers reach %.4f from the centre; rebuilt from the "
              "straight yarn within %.2g; closest-frame arc within %.2g (%.0f%% of its bound), across within %.2g "
              "(%.0f%%)\n",
              name, centre.Length(), theta * 180 / kPi, farthest, rebuilt, worst_arc, 100 * worst_arc_share,
              worst_across, 100 * worst_across_share);
  EXPECT_LE(rebuilt, 1e-12);
}

TEST(YarnCurveTest, BentCurvesKeepEachFibersPlaceRelativeToThem) {
  ExpectFibersKeepTheirPlace(ArcPolyline(1.5, kPi / 3, 32), CurveKind::kPolyline, "60-degree arc, 32 chords");
  ExpectFibersKeepTheirPlace(SwayingControlPoints(), CurveKind::kBSpline, "swaying B-spline");
}

// ---- Frames ----

// Normals at the polyline's vertices (At at each vertex's arc).
std::vector<Vec3> VertexNormals(const PolylineYarnCurve& centre) {
  const std::vector<double> arcs = VertexArcs(centre.CentrePolyline());
  std::vector<Vec3> out;
  for (double a : arcs) out.push_back(centre.At(a).normal);
  return out;
}

TEST(YarnCurveTest, FramesAlongPlanarCurvesStayInOrAcrossThePlane) {
  // In the xz plane from the origin along +z: the first normal is +x (x before y on the tie), in the plane.
  // (A lead-in along +z first: the arc's own first chord leans towards +x, and y would be the least aligned axis.)
  std::vector<Vec3> xz = ArcPolyline(0.5, 2.5, 100);
  xz.insert(xz.begin(), Vec3{0, 0, -0.1});
  PolylineYarnCurve in_plane;
  ASSERT_EQ(MakeCentreCurve(xz, CurveKind::kPolyline, &in_plane), "");
  EXPECT_EQ(in_plane.At(0).normal, (Vec3{1, 0, 0}));
  double off_plane = 0;
  for (int i = 0; i <= 1000; ++i)
    off_plane = std::max(off_plane, std::abs(in_plane.At(in_plane.Length() * i / 1000).normal.y));
  EXPECT_LE(off_plane, 1e-15);

  // The arc turned into the yz plane: its first chord has no x, so the first normal is +x, across the plane.
  std::vector<Vec3> yz = ArcPolyline(0.5, 2.5, 100);
  for (Vec3& v : yz) v = {0, v.x, v.z};
  PolylineYarnCurve across;
  ASSERT_EQ(MakeCentreCurve(yz, CurveKind::kPolyline, &across), "");
  double drift = 0;
  for (int i = 0; i <= 1000; ++i)
    drift = std::max(drift, Distance(across.At(across.Length() * i / 1000).normal, {1, 0, 0}));
  EXPECT_LE(drift, 1e-15);

  // A B-spline S in a tilted plane (normal m): the normal's component along m stays as it started.
  const Vec3 m = Unit({1, 2, 3});
  const Vec3 e1 = Unit(Cross(m, {0, 0, 1}));
  const Vec3 e2 = Cross(m, e1);
  std::vector<Vec3> control;
  for (int k = 0; k < 12; ++k)
    control.push_back(Vec3{0.3, -0.2, 0.7} + (0.2 * k) * e1 + (0.3 * std::sin(0.8 * k)) * e2);
  PolylineYarnCurve tilted;
  ASSERT_EQ(MakeCentreCurve(control, CurveKind::kBSpline, &tilted), "");
  const std::vector<Vec3> normals = VertexNormals(tilted);
  double spread = 0, total_turn = 0;
  for (const Vec3& n : normals) spread = std::max(spread, std::abs(Dot(n, m) - Dot(normals[0], m)));
  for (size_t i = 1; i < normals.size(); ++i) total_turn += Angle(normals[i - 1], normals[i]);
  std::printf("tilted planar B-spline: %zu vertices, the normal turns %.3f rad in all, its m component spread %.2g\n",
              normals.size(), total_turn, spread);
  EXPECT_GT(std::abs(Dot(normals[0], m)), 0.1);  // not trivially 0
  EXPECT_GT(total_turn, 1.0);                    // the curve does bend the frame
  EXPECT_LE(spread, 1e-12);
}

// A helix of radius a and pitch 2 pi h: x = a cos t, y = a sin t, z = h t. Its Frenet frame turns about the tangent
// at the torsion tau = h / c^2 (c = sqrt(a^2 + h^2)) per unit length; a rotation-minimizing frame does not, so
// relative to the Frenet frame it turns by -tau per unit length (with N_rmf = cos phi N + sin phi B, dN_rmf/ds has
// no B component iff phi' = -tau). After one turn (arc 2 pi c) the Frenet frame is back where it started (a
// screw motion's translation), so the RMF has turned about the tangent by -2 pi h / c: the holonomy, 2 pi minus
// the solid angle the tangent sweeps (2 pi (1 - h / c)).
TEST(YarnCurveTest, HelixFrameTurnsByTheRotationMinimizingTwist) {
  const double a = 1, h = 0.3, c = std::hypot(a, h);
  const int per_turn = 256;
  std::vector<Vec3> v;
  for (int i = 0; i <= 3 * per_turn / 2; ++i) {
    const double t = 2 * kPi * i / per_turn;
    v.push_back({a * std::cos(t), a * std::sin(t), h * t});
  }
  PolylineYarnCurve helix;
  ASSERT_EQ(MakeCentreCurve(v, CurveKind::kPolyline, &helix), "");
  const std::vector<double> arcs = VertexArcs(v);
  // Interior vertices one turn apart: the screw motion maps one's neighbourhood to the other's, so their vertex
  // tangents (bisectors) agree and the normals differ by a turn about that tangent only.
  const int first = per_turn / 4, second = first + per_turn;
  const CurveFrame f0 = helix.At(arcs[size_t(first)]), f1 = helix.At(arcs[size_t(second)]);
  EXPECT_LE(Distance(f0.tangent, f1.tangent), 1e-12);
  const double turned = std::atan2(Dot(Cross(f0.normal, f1.normal), f0.tangent), Dot(f0.normal, f1.normal));
  const double expected = -2 * kPi * h / c;  // in (-pi, pi] for these a, h
  // The double reflection method's global error is fourth order in the chord (Wang et al. 2008); measured: 3.7e-7
  // rad off at 64 chords a turn, 2.3e-8 at 128, 1.4e-9 at 256 (each halving 16 times closer). Allowed 1e-7.
  std::printf("helix, %d chords a turn: the frame turns by %.9f rad over a turn, expected %.9f (Frenet: 0)\n", per_turn,
              turned, expected);
  EXPECT_NEAR(turned, expected, 1e-7);

  // And along the way: the normal's rate of turn has no component about the tangent (dN/ds . B = 0), where the
  // Frenet frame's is the torsion. Differences over a chord, B taken at its middle: the difference quotient is
  // itself second order in the chord (measured 6.1e-4 at 64 chords a turn, 1.5e-4 at 128, 3.8e-5 at 256).
  const double tau = h / (c * c);
  double worst = 0;
  for (int i = 1; i + 2 < int(v.size()); ++i) {
    const CurveFrame g0 = helix.At(arcs[size_t(i)]), g1 = helix.At(arcs[size_t(i + 1)]);
    const Vec3 b = Unit(Cross(g0.tangent, g0.normal) + Cross(g1.tangent, g1.normal));
    worst = std::max(worst, std::abs(Dot(g1.normal - g0.normal, b)) / (arcs[size_t(i + 1)] - arcs[size_t(i)]));
  }
  std::printf("helix: largest twist rate dN/ds . B %.3g, the torsion %.4f\n", worst, tau);
  EXPECT_LE(worst, 1e-3 * tau);
}

// ---- B-spline sampling ----

TEST(YarnCurveTest, BSplineSamplesLieOnTheClampedUniformCubicBSpline) {
  const std::vector<Vec3> control = SwayingControlPoints();
  PolylineYarnCurve centre;
  ASSERT_EQ(MakeCentreCurve(control, CurveKind::kBSpline, &centre), "");
  const std::vector<Vec3> v = centre.CentrePolyline();
  const int spans = int(control.size()) - 3;
  // A gentle curve: no span turns by 15 degrees within a chord, so 8 chords a span.
  ASSERT_EQ(v.size(), size_t(spans * kBSplineSegmentsPerSpan + 1));
  EXPECT_EQ(v.front(), control.front());
  EXPECT_EQ(v.back(), control.back());
  double worst = 0;
  for (size_t j = 0; j < v.size(); ++j)
    worst = std::max(worst, Distance(v[j], BSplineAt(control, double(j) / kBSplineSegmentsPerSpan)));
  EXPECT_LE(worst, 1e-12);
}

TEST(YarnCurveTest, BSplineSamplingRefinesSharpSpansAndRefusesCusps) {
  // A hairpin: control points out along +z and back beside themselves, 0.2 apart.
  const std::vector<Vec3> hairpin = {{0, 0, 0},   {0, 0, 1}, {0, 0, 2}, {0.1, 0, 2.3},
                                     {0.2, 0, 2}, {0.2, 0, 1}, {0.2, 0, 0}};
  PolylineYarnCurve centre;
  ASSERT_EQ(MakeCentreCurve(hairpin, CurveKind::kBSpline, &centre), "");
  const std::vector<Vec3> v = centre.CentrePolyline();
  EXPECT_GT(v.size(), size_t((hairpin.size() - 3) * kBSplineSegmentsPerSpan + 1));  // refined where it turns
  EXPECT_LE(v.size(), size_t((hairpin.size() - 3) * kMaxBSplineSegmentsPerSpan + 1));
  double turn = 0, worst_turn = 0;
  for (size_t i = 1; i + 1 < v.size(); ++i) {
    const double t = Angle(v[i] - v[i - 1], v[i + 1] - v[i]);
    turn += t;
    worst_turn = std::max(worst_turn, t);
  }
  std::printf("hairpin B-spline: %zu vertices, turning %.1f degrees in all, at most %.1f at a vertex\n", v.size(),
              turn * 180 / kPi, worst_turn * 180 / kPi);
  EXPECT_NEAR(turn, kPi, 0.05);  // out and back
  EXPECT_LT(worst_turn, 30 * kPi / 180);

  // Points doubling back on a line: the curve stops and reverses (a cusp), which no sampling makes a polyline of.
  const std::string e = MakeCentreCurve({{0, 0, 0}, {0, 0, 1}, {0, 0, -1}, {0, 0, 2}}, CurveKind::kBSpline, &centre);
  EXPECT_TRUE(StartsWith(e, "points: ")) << e;
  EXPECT_NE(e.find("cusp"), std::string::npos) << e;
}

// ---- Closest points ----

// Loops that do not advance along their chord (here Crane's plain-knit course shape, as knit.cpp's, and a
// spiral) are searched through PolylineYarnCurve's box tree: its answer is the nearest point
// of the whole polyline, found here by testing every segment.
TEST(YarnCurveTest, ClosestArcOnLoopingCurvesIsTheNearestPointOfAllSegments) {
  std::vector<Vec3> course;
  for (int i = 0; i <= 6 * 32; ++i) {
    const double t = 2 * kPi * i / 32;
    course.push_back({0.05 * (t + 1.5 * std::sin(2 * t)), 0.05 * 4 * std::cos(t), 0.05 * std::cos(2 * t)});
  }
  std::vector<Vec3> spiral;  // 8 turns 0.1 apart, rising slowly
  for (int i = 0; i <= 8 * 40; ++i) {
    const double t = 2 * kPi * i / 40, r = 0.1 + 0.1 * t / (2 * kPi);
    spiral.push_back({r * std::cos(t), r * std::sin(t), 0.001 * i});
  }
  for (const auto& [name, v] : {std::pair{"knit course", course}, std::pair{"spiral", spiral}}) {
    SCOPED_TRACE(name);
    PolylineYarnCurve curve;
    ASSERT_EQ(MakeCentreCurve(v, CurveKind::kPolyline, &curve), "");
    const std::vector<double> arcs = VertexArcs(v);
    double worst = 0;
    uint64_t state = 12345;
    const auto uniform = [&state] {  // xorshift64*, any fixed sequence will do
      state ^= state >> 12, state ^= state << 25, state ^= state >> 27;
      return double((state * 0x2545F4914F6CDD1Dull) >> 11) * 0x1p-53;
    };
    for (int q = 0; q < 2000; ++q) {
      // Near the curve (within 0.2 of a point on it) and anywhere in a box around it.
      const size_t i = size_t(uniform() * double(v.size() - 1));
      const Vec3 near = v[i] + Vec3{0.4 * uniform() - 0.2, 0.4 * uniform() - 0.2, 0.4 * uniform() - 0.2};
      const Vec3 far = {4 * uniform() - 2, 4 * uniform() - 2, 4 * uniform() - 2};
      for (const Vec3& p : {near, far}) {
        double nearest = INFINITY, nearest_arc = 0;
        for (size_t k = 0; k + 1 < v.size(); ++k) {
          const Vec3 d = v[k + 1] - v[k];
          const double u = std::clamp(Dot(p - v[k], d) / Dot(d, d), 0.0, 1.0);
          const double dist = Distance(p, v[k] + u * d);
          if (dist < nearest) nearest = dist, nearest_arc = arcs[k] + u * (arcs[k + 1] - arcs[k]);
        }
        const double arc = curve.ClosestArc(p);
        worst = std::max(worst, Distance(p, curve.At(arc).position) - nearest);
        // The same point unless two are equally near.
        if (std::abs(arc - nearest_arc) > 1e-9) {
          EXPECT_NEAR(Distance(p, curve.At(arc).position), nearest, 1e-12);
        }
      }
    }
    EXPECT_LE(worst, 1e-12);
  }
}

// ---- Refusals and limits ----

TEST(YarnCurveTest, BadCurvesAreRefusedNamingTheYarnAndPoint) {
  const CurveYarn good{{{0, 0, 0}, {0, 0, 0.5}}, CurveKind::kPolyline, YarnParams{}};
  struct Case {
    std::vector<Vec3> points;
    CurveKind kind;
    std::string prefix;
    std::string mentions;
  };
  const double nan = std::nan("");
  const std::vector<Case> cases = {
      {{{0, 0, 0}, {0, 0, 0.2}, {0, nan, 0.4}}, CurveKind::kPolyline, "yarns[1].points: point 2 ", "not finite"},
      {{{0, 0, 0}, {0, 0, INFINITY}}, CurveKind::kPolyline, "yarns[1].points: point 1 ", "not finite"},
      {{{0, 0, 0}, {0, 0, 2e6}}, CurveKind::kPolyline, "yarns[1].points: point 1 ", "farther than 1e+06"},
      {{{0, 0, 0}, {0, 0, 0.2}, {0, 0, 0.2}, {0, 0, 0.4}}, CurveKind::kPolyline,
       "yarns[1].points: point 2 repeats point 1", ""},
      {{{0, 0, 0}, {0, 0, 0.2}, {0, 0, 0.2}, {0, 0, 0.4}}, CurveKind::kBSpline,
       "yarns[1].points: point 2 repeats point 1", ""},
      {{{0, 0, 0}}, CurveKind::kPolyline, "yarns[1].points: has 1 points", "at least 2"},
      {{{0, 0, 0}, {0, 0, 0.2}, {0, 0, 0.4}}, CurveKind::kBSpline, "yarns[1].points: has 3 points", "at least 4"},
      // A 63-degree corner at point 1 (the turn's cosine is 1 / sqrt(5) < 1/2).
      {{{0, 0, 0}, {0, 0, 0.3}, {0.2, 0, 0.4}}, CurveKind::kPolyline,
       "yarns[1].points: the polyline turns 60 degrees or more at point 1", "use a B-spline or more points"},
      {{{0, 0, 0}, {0, 0, 1e-7}}, CurveKind::kPolyline, "yarns[1].points: the curve is 1e-07 long", ""},
      {{{0, 0, 0}, {0, 0, 2000}}, CurveKind::kPolyline, "yarns[1].points: the curve is 2000 long", ""},
  };
  for (const Case& c : cases) {
    LayoutGeometry fibers;
    std::vector<PolylineYarnCurve> centres;
    const std::string e =
        GenerateCurveLayout({good, {c.points, c.kind, YarnParams{}}}, {}, {}, &fibers, &centres);
    EXPECT_TRUE(StartsWith(e, c.prefix)) << e;
    EXPECT_NE(e.find(c.mentions), std::string::npos) << e;
    EXPECT_TRUE(fibers.yarns.empty());
    EXPECT_TRUE(centres.empty());
  }
  // The sharp corner is accepted as a B-spline's control points (with a fourth).
  PolylineYarnCurve centre;
  EXPECT_EQ(MakeCentreCurve({{0, 0, 0}, {0, 0, 0.3}, {0.2, 0, 0.4}, {0.4, 0, 0.45}}, CurveKind::kBSpline, &centre), "");

  // A bad yarn parameter names the yarn too.
  CurveYarn bad = good;
  bad.params.alpha = -1;
  LayoutGeometry fibers;
  std::vector<PolylineYarnCurve> centres;
  const std::string e = GenerateCurveLayout({good, good, bad}, {}, {}, &fibers, &centres);
  EXPECT_TRUE(StartsWith(e, "yarns[2].alpha: ")) << e;
}

TEST(YarnCurveTest, TooManyYarnsPointsOrVerticesAreRefused) {
  LayoutGeometry fibers;
  std::vector<PolylineYarnCurve> centres;
  const CurveYarn good{{{0, 0, 0}, {0, 0, 0.5}}, CurveKind::kPolyline, YarnParams{}};
  std::string e = GenerateCurveLayout({}, {}, {}, &fibers, &centres);
  EXPECT_TRUE(StartsWith(e, "yarns: the layout has no yarns")) << e;
  e = GenerateCurveLayout(std::vector<CurveYarn>(kMaxCurveYarns + 1, good), {}, {}, &fibers, &centres);
  EXPECT_TRUE(StartsWith(e, "yarns: has 4097 yarns, more than 4096")) << e;

  // A straight line of many points.
  const auto line = [](int64_t n) {
    std::vector<Vec3> v(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) v[size_t(i)] = {0, 0, 1e-4 * double(i)};
    return v;
  };
  e = GenerateCurveLayout({{line(int64_t(kMaxCurveVertices) + 1), CurveKind::kPolyline, YarnParams{}}}, {}, {}, &fibers,
                          &centres);
  EXPECT_TRUE(StartsWith(e, "yarns[0].points: the yarns up to this one have more than 1000000 points in all")) << e;
  e = GenerateCurveLayout({good, {line(600'000), CurveKind::kPolyline, YarnParams{}},
                           {line(600'000), CurveKind::kPolyline, YarnParams{}}},
                          {}, {}, &fibers, &centres);
  EXPECT_TRUE(StartsWith(e, "yarns[2].points: the yarns up to this one have more than 1000000 points")) << e;
  PolylineYarnCurve centre;
  e = MakeCentreCurve(line(int64_t(kMaxCurveVertices) + 1), CurveKind::kPolyline, &centre);
  EXPECT_TRUE(StartsWith(e, "points: has 1000001 points, more than 1000000")) << e;
  // B-splines: 8 vertices a span at least, counted before any is sampled.
  const std::vector<CurveYarn> splines = {good, {line(300'000), CurveKind::kBSpline, YarnParams{}}};
  EXPECT_GT(CurveLayoutVerticesAtMost(splines), kMaxCurveLayoutVertices);
  e = GenerateCurveLayout(splines, {}, {}, &fibers, &centres);
  EXPECT_TRUE(StartsWith(e, "yarns[1].points: the centre curves up to this yarn need at least 2399979 vertices")) << e;
  // One B-spline over kMaxCurveVertices once sampled, refused as it is sampled (8 x 149,997 spans > 1,000,000).
  e = GenerateCurveLayout({{line(150'000), CurveKind::kBSpline, YarnParams{}}}, {}, {}, &fibers, &centres);
  EXPECT_TRUE(StartsWith(e, "yarns[0].points: the B-spline samples to more than 1000000 vertices")) << e;
  EXPECT_EQ(CurveLayoutVerticesAtMost({good, good}), 4);
  EXPECT_EQ(CurveLayoutVerticesAtMost({{line(10), CurveKind::kBSpline, YarnParams{}}}),
            7 * kMaxBSplineSegmentsPerSpan + 1);
}

TEST(YarnCurveTest, LimitsAreCheckedBeforeGeneratingAndCancellationPassesThrough) {
  YarnParams p;  // cotton1: 3 x 75 fibers a yarn
  const CurveYarn first{{{0, 0, 0}, {0, 0, 0.5}}, CurveKind::kPolyline, p};
  CurveYarn second{{{0.2, 0, 0}, {0.2, 0, 0.5}}, CurveKind::kPolyline, p};
  second.params.seed = 2;
  int polls = 0;
  DetailOptions counting;
  counting.core = false;  // every fiber its own curves, so a yarn returns more curves than plies x fibers_per_ply
  counting.stop = [&polls] {
    ++polls;
    return false;
  };
  LayoutGeometry full;
  std::vector<PolylineYarnCurve> centres;
  ASSERT_EQ(GenerateCurveLayout({first, second}, counting, {}, &full, &centres), "");
  ASSERT_GT(polls, 0);  // the stop callback is polled while fibers are generated
  ASSERT_EQ(full.yarns.size(), 2u);
  ASSERT_GT(full.fibers - 1, 2 * 3 * 75);  // so a max_fibers of full.fibers - 1 passes the check before generating
  ASSERT_EQ(centres.size(), 2u);
  EXPECT_EQ(full.control_points, full.yarns[0].control_points + full.yarns[1].control_points);
  // Each yarn with its own seed: the second yarn's fibers are not the first's moved over to its curve.
  const FiberCurve &a = full.yarns[0].fibers.back(), &b = full.yarns[1].fibers.back();
  EXPECT_FALSE(a.points.size() == b.points.size() &&
               Distance(a.points.back() + Vec3{0.2, 0, 0}, b.points.back()) < 1e-9);

  struct Case {
    YarnLimits limits;
    std::string prefix;
    bool before_generating;
  };
  const std::vector<Case> cases = {
      {{2 * 3 * 75 - 1, 4'000'000}, "max_fibers: the layout's 2 yarns have 450 fibers", true},
      {{100'000, 10}, "max_control_points: the layout needs at least", true},
      {{100'000, full.control_points - 1}, "max_control_points: the layout needs more than", false},
      {{full.fibers - 1, 4'000'000}, "max_fibers: the layout needs more than", false},
      {{-1, 4'000'000}, "max_fibers: is -1", true},
  };
  for (const Case& c : cases) {
    polls = 0;
    LayoutGeometry fibers;
    const std::string e = GenerateCurveLayout({first, second}, counting, c.limits, &fibers, &centres);
    EXPECT_TRUE(StartsWith(e, c.prefix)) << e;
    if (c.before_generating) {
      EXPECT_EQ(polls, 0) << e;
    } else {
      EXPECT_NE(e.find("(at yarns[1])"), std::string::npos) << e;  // the last one generated
    }
    EXPECT_TRUE(fibers.yarns.empty());
    EXPECT_TRUE(centres.empty());
  }

  DetailOptions stopping;
  stopping.stop = [] { return true; };
  LayoutGeometry fibers;
  EXPECT_EQ(GenerateCurveLayout({first, second}, stopping, {}, &fibers, &centres), "cancelled");
  EXPECT_TRUE(fibers.yarns.empty());
}

// ---- Jobs ----

TEST(YarnCurveTest, CurveJobLaysEachCurveOutAsAYarn) {
  YarnJob job;
  job.kind = YarnLayoutKind::kCurves;
  YarnParams thin;
  ASSERT_EQ(YarnPreset("silk1", &thin), "");
  thin.seed = 77;
  job.curves = {{ArcPolyline(1.5, kPi / 3, 32), CurveKind::kPolyline, YarnParams{}},
                {SwayingControlPoints(), CurveKind::kBSpline, thin}};
  std::vector<YarnGeometry> yarns;
  std::vector<LaidYarn> laid;
  ASSERT_EQ(GenerateYarnJob(&job, &yarns, &laid), "");
  ASSERT_EQ(yarns.size(), 2u);
  ASSERT_EQ(laid.size(), 2u);
  for (size_t k = 0; k < 2; ++k) {
    PolylineYarnCurve centre;
    ASSERT_EQ(MakeCentreCurve(job.curves[k].points, job.curves[k].kind, &centre), "");
    EXPECT_FALSE(laid[k].warp);
    EXPECT_EQ(laid[k].thread, int(k));
    EXPECT_EQ(laid[k].length, centre.Length());
    EXPECT_EQ(laid[k].centre->CentrePolyline(), centre.CentrePolyline());
    // Each yarn with its own params, seed as given: silk1's 3 plies of 33 fibers for the second.
    YarnGeometry alone;
    ASSERT_EQ(GenerateYarn(job.curves[k].params, centre, job.detail, job.limits, &alone), "");
    EXPECT_EQ(yarns[k], alone);
  }

  // A bad curve names its yarn.
  job.curves[1].points[2] = job.curves[1].points[1];
  const std::string e = GenerateYarnJob(&job, &yarns, &laid);
  EXPECT_TRUE(StartsWith(e, "yarns[1].points: point 2 repeats point 1")) << e;
  EXPECT_TRUE(yarns.empty());
  EXPECT_TRUE(laid.empty());
}

TEST(YarnCurveTest, KnitJobLaysEachCourseOutAsAYarnOfItsOwnSeed) {
  YarnJob job;
  job.kind = YarnLayoutKind::kKnit;
  ASSERT_EQ(YarnPreset("cotton2", &job.params), "");  // radius 0.033, not KnitParams' default 0.0378
  job.params.seed = 5;
  job.knit.wales = 2;
  job.knit.courses = 3;
  std::vector<YarnGeometry> yarns;
  std::vector<LaidYarn> laid;
  ASSERT_EQ(GenerateYarnJob(&job, &yarns, &laid), "");
  KnitParams knit = job.knit;
  knit.yarn_radius = job.params.yarn_radius;  // the job's yarn sets the loops' size
  KnitLayout layout;
  ASSERT_EQ(BuildKnit(knit, &layout), "");
  ASSERT_EQ(laid.size(), layout.courses.size());
  ASSERT_EQ(yarns.size(), layout.courses.size());
  for (size_t c = 0; c < laid.size(); ++c) {
    EXPECT_FALSE(laid[c].warp);
    EXPECT_EQ(laid[c].thread, int(c));
    EXPECT_EQ(laid[c].centre->CentrePolyline(), layout.courses[c]);
    EXPECT_EQ(laid[c].length, laid[c].centre->Length());
    EXPECT_EQ(yarns[c].plies.size(), 3u);  // cotton2
  }
  // Course c's seed: LayoutYarnSeed(seed, c), as a woven layout's yarns.
  YarnParams course1 = job.params;
  course1.seed = LayoutYarnSeed(job.params.seed, 1);
  YarnGeometry alone;
  ASSERT_EQ(GenerateYarn(course1, *laid[1].centre, job.detail, job.limits, &alone), "");
  EXPECT_EQ(yarns[1], alone);

  // Same job, same fibers; another stitch count or yarn, another job.
  YarnJob other = job;
  EXPECT_TRUE(SameFibers(job, other));
  other.knit.wales = 3;
  EXPECT_FALSE(SameFibers(job, other));
  other = job;
  other.params.seed = 6;
  EXPECT_FALSE(SameFibers(job, other));

  // A footprint under a fiber's width (Eq. 4's lambda 1) generates exactly the full-detail fibers, so it is the
  // same job (the cache serves a close-up LOD render the FULL one's scene); a footprint that thins them is not.
  other = job;
  other.detail.footprint = 0.5 * job.params.fiber_width;
  std::vector<YarnGeometry> close_up;
  std::vector<LaidYarn> close_up_laid;
  ASSERT_EQ(GenerateYarnJob(&other, &close_up, &close_up_laid), "");
  EXPECT_EQ(close_up, yarns);
  EXPECT_TRUE(SameFibers(job, other));
  other.detail.footprint = 4 * job.params.fiber_width;
  EXPECT_FALSE(SameFibers(job, other));
}

}  // namespace
}  // namespace loomlight::yarn
