// Knit layouts (server/yarn/knit.h): the courses' loops interlock without any yarn passing through another, the
// patch repeats with its period, the rib's purl wales are the knit wales mirrored, the polylines are usable
// curves, and bad parameters are refused by name. Every expectation here comes from the yarn radius, the spacings
// and the definitions of a knit, measured with this file's own geometry (segment distances, Gauss linking
// numbers), never from the layout code's own formulas.
#include "server/yarn/knit.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <vector>

#include "server/yarn/curve_layout.h"

namespace loomlight::yarn {
namespace {

using Polyline = std::vector<Vec3>;

// Distance between segments p0p1 and q0q1 (Ericson, Real-Time Collision Detection, 5.1.9).
double SegmentDistance(Vec3 p0, Vec3 p1, Vec3 q0, Vec3 q1) {
  const Vec3 d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const double a = Dot(d1, d1), e = Dot(d2, d2), f = Dot(d2, r), c = Dot(d1, r), b = Dot(d1, d2);
  const double denom = a * e - b * b;
  double s = denom > 1e-12 * a * e ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
  double t = (b * s + f) / e;
  if (t < 0) {
    t = 0;
    s = std::clamp(-c / a, 0.0, 1.0);
  } else if (t > 1) {
    t = 1;
    s = std::clamp((b - c) / a, 0.0, 1.0);
  }
  return Norm((p0 + s * d1) - (q0 + t * d2));
}

double MinDistance(const Polyline& a, const Polyline& b) {
  double best = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i + 1 < a.size(); ++i)
    for (size_t k = 0; k + 1 < b.size(); ++k) best = std::min(best, SegmentDistance(a[i], a[i + 1], b[k], b[k + 1]));
  return best;
}

// The closest approach of two parts of one course that lie more than pi r apart along it. A tube of radius r
// around a curve whose curvature radius is at least r overlaps itself exactly when two such parts come within
// 2 r (nearer along the curve, a bend of radius r brings points 2 r sin(s / 2r) < 2 r apart without overlap).
double MinSelfDistance(const Polyline& c, double r) {
  std::vector<double> arc(c.size(), 0.0);
  for (size_t i = 1; i < c.size(); ++i) arc[i] = arc[i - 1] + Norm(c[i] - c[i - 1]);
  double best = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i + 1 < c.size(); ++i)
    for (size_t k = i + 1; k + 1 < c.size(); ++k)
      if (arc[k] - arc[i + 1] > std::numbers::pi * r)
        best = std::min(best, SegmentDistance(c[i], c[i + 1], c[k], c[k + 1]));
  return best;
}

// Turning angle (degrees) at each interior vertex, the largest.
double MaxTurningDegrees(const Polyline& c) {
  double most = 0;
  for (size_t i = 1; i + 1 < c.size(); ++i) {
    const Vec3 u = c[i] - c[i - 1], v = c[i + 1] - c[i];
    most = std::max(most, std::acos(std::clamp(Dot(u, v) / (Norm(u) * Norm(v)), -1.0, 1.0)));
  }
  return most * 180 / std::numbers::pi;
}

// Smallest radius of curvature, from the turning at each vertex over the mean of its two segments.
double MinCurvatureRadius(const Polyline& c) {
  double least = std::numeric_limits<double>::infinity();
  for (size_t i = 1; i + 1 < c.size(); ++i) {
    const Vec3 u = c[i] - c[i - 1], v = c[i + 1] - c[i];
    const double angle = std::acos(std::clamp(Dot(u, v) / (Norm(u) * Norm(v)), -1.0, 1.0));
    if (angle > 0) least = std::min(least, 0.5 * (Norm(u) + Norm(v)) / angle);
  }
  return least;
}

double Length(const Polyline& c) {
  double length = 0;
  for (size_t i = 1; i < c.size(); ++i) length += Norm(c[i] - c[i - 1]);
  return length;
}

// Gauss linking number of two closed polygons (each given open, its last vertex joined to its first), summed
// exactly segment pair by segment pair as the solid angle each pair subtends (Klenin and Langowski, "Computation
// of writhe in modeling of supercoiled DNA", Biopolymers 54, 2000): an integer up to rounding for disjoint curves.
double LinkingNumber(const Polyline& a, const Polyline& b) {
  auto unit = [](Vec3 v) {
    const double n = Norm(v);
    return n > 0 ? (1 / n) * v : Vec3{};
  };
  auto asin_dot = [](Vec3 u, Vec3 v) { return std::asin(std::clamp(Dot(u, v), -1.0, 1.0)); };
  double total = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const Vec3 a0 = a[i], a1 = a[(i + 1) % a.size()];
    for (size_t k = 0; k < b.size(); ++k) {
      const Vec3 b0 = b[k], b1 = b[(k + 1) % b.size()];
      const Vec3 r13 = b0 - a0, r14 = b1 - a0, r23 = b0 - a1, r24 = b1 - a1;
      const Vec3 n1 = unit(Cross(r13, r14)), n2 = unit(Cross(r14, r24)), n3 = unit(Cross(r24, r23)),
                 n4 = unit(Cross(r23, r13));
      const double omega = asin_dot(n1, n2) + asin_dot(n2, n3) + asin_dot(n3, n4) + asin_dot(n4, n1);
      total += Dot(Cross(b1 - b0, a1 - a0), r13) > 0 ? omega : -omega;
    }
  }
  return total / (4 * std::numbers::pi);
}

// The part of `course` from vertex `first` to `last`, closed by going straight along y to `far_y` from both ends
// and across there: the closing path then stays in a slab of y that the other loop of a linking test never
// reaches, so the linking number counts only how the two open arcs wind around each other.
Polyline ClosedAlongY(const Polyline& course, size_t first, size_t last, double far_y) {
  Polyline loop(course.begin() + long(first), course.begin() + long(last) + 1);
  const Vec3 end = loop.back(), start = loop.front();
  loop.push_back({end.x, far_y, end.z});
  loop.push_back({start.x, far_y, start.z});
  return loop;
}

KnitParams Params(KnitStitch stitch, int wales, int courses, int points_per_loop = 32) {
  KnitParams p;
  p.stitch = stitch;
  p.wales = wales;
  p.courses = courses;
  p.points_per_loop = points_per_loop;
  return p;
}

KnitLayout Build(const KnitParams& p) {
  KnitLayout layout;
  const std::string e = BuildKnit(p, &layout);
  EXPECT_EQ(e, "");
  return layout;
}

const char* Name(KnitStitch s) { return s == KnitStitch::kJersey ? "jersey" : "rib"; }

constexpr double kContactTolerance = 1e-3;  // of 2 yarn radii

// Two round yarns of radius r interpenetrate where their centres come closer than 2 r: between different
// courses, and between parts of one course more than pi r apart along it. Checked at the defaults for several
// polyline resolutions and at the corners of the accepted spacings (stretched by 1 and kMaxSpacingStretch).
TEST(KnitTest, NoYarnPassesThroughAnother) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    for (int points : {32, 33, 48, 64, 101}) {
      for (double stretch_x : {1.0, kMaxSpacingStretch}) {
        for (double stretch_y : {1.0, kMaxSpacingStretch}) {
          if (points != 32 && (stretch_x != 1 || stretch_y != 1)) continue;
          KnitParams p = Params(stitch, 4, 3, points);
          p.wale_spacing = stretch_x * DefaultWaleSpacing(stitch, p.yarn_radius);
          p.course_spacing = stretch_y * DefaultCourseSpacing(stitch, p.yarn_radius);
          const KnitLayout k = Build(p);
          ASSERT_EQ(k.courses.size(), 3u);
          const double r = p.yarn_radius;
          double between = std::numeric_limits<double>::infinity(), within = between;
          for (size_t j = 0; j < k.courses.size(); ++j) {
            within = std::min(within, MinSelfDistance(k.courses[j], r));
            for (size_t i = j + 1; i < k.courses.size(); ++i)
              between = std::min(between, MinDistance(k.courses[j], k.courses[i]));
          }
          std::printf("%s, %d points per loop, spacings x (%g, %g): closest centres %.4f r between courses, "
                      "%.4f r within one; smallest curvature radius %.3f r\n",
                      Name(stitch), points, stretch_x, stretch_y, between / r, within / r,
                      MinCurvatureRadius(k.courses[1]) / r);
          EXPECT_GE(between, 2 * r * (1 - kContactTolerance)) << Name(stitch) << " " << points;
          EXPECT_GE(within, 2 * r * (1 - kContactTolerance)) << Name(stitch) << " " << points;
          // No bend so sharp that the tube folds on itself.
          EXPECT_GE(MinCurvatureRadius(k.courses[1]), r) << Name(stitch) << " " << points;
        }
      }
    }
  }
}

// Separated is not interlocked: the loops must also be linked. Course j's loop of wale w (from the bottom of one
// sinker loop to the next, its head in the middle) is closed by running down (-y) from both feet and across far
// below; course j + 1's sinker loop at a wale boundary (from one head to the next) by running up (+y) from both
// ends and across far above. Each closing path lies in y beyond the other loop's reach, so the Gauss linking
// number of the two closed curves is the winding of the two arcs themselves: +-1 where course j + 1's yarn passes
// through course j's loop (its legs in front of course j's head, its sinker behind course j's legs, as in a
// knit), 0 where the two merely lie near each other. In jersey every wale is the same, so the pairs (wale w, boundary w) all link alike; in the
// rib a purl wale is a knit wale mirrored, and a mirror reverses linking, so their signs alternate. Lifting
// course j + 1 in front of course j (z + 4 d) unlinks every pair: the test can fail.
TEST(KnitTest, LoopsOfNeighbouringCoursesInterlock) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    const int n = 32;
    const KnitParams p = Params(stitch, 6, 2, n);
    const KnitLayout k = Build(p);
    const double below = k.lower.y - 10 * k.course_spacing, above = k.upper.y + 10 * k.course_spacing;
    Polyline lifted = k.courses[1];
    for (Vec3& v : lifted) v.z += 4 * k.loop_depth;
    double first_sign = 0;
    for (int w = 1; w + 1 < p.wales; ++w) {
      const Polyline loop = ClosedAlongY(k.courses[0], size_t(w * n), size_t((w + 1) * n), below);
      // Course 1's sinker loops at the boundaries w (left of the loop), w + 1 (right) and w + 2 (beyond).
      auto sinker = [&](const Polyline& course, int boundary) {
        return ClosedAlongY(course, size_t(boundary * n - n / 2), size_t(boundary * n + n / 2), above);
      };
      const double left = LinkingNumber(loop, sinker(k.courses[1], w));
      const double right = LinkingNumber(loop, sinker(k.courses[1], w + 1));
      std::printf("%s wale %d: linking numbers with course 1's sinker loops at its left %.6f, right %.6f\n",
                  Name(stitch), w, left, right);
      EXPECT_NEAR(std::abs(left), 1, 1e-6) << Name(stitch) << " wale " << w;
      EXPECT_NEAR(std::abs(right), 1, 1e-6) << Name(stitch) << " wale " << w;
      if ((w + 2) * n + n / 2 < int(k.courses[1].size())) {
        EXPECT_NEAR(LinkingNumber(loop, sinker(k.courses[1], w + 2)), 0, 1e-6) << Name(stitch) << " wale " << w;
      }
      EXPECT_NEAR(LinkingNumber(loop, sinker(lifted, w)), 0, 1e-6) << Name(stitch) << " wale " << w;
      EXPECT_NEAR(LinkingNumber(loop, sinker(lifted, w + 1)), 0, 1e-6) << Name(stitch) << " wale " << w;
      if (w == 1) {
        first_sign = left;
        continue;
      }
      const bool mirrored = stitch == KnitStitch::kRib1x1 && (w - 1) % 2 == 1;
      EXPECT_NEAR(left, mirrored ? -first_sign : first_sign, 1e-6) << Name(stitch) << " wale " << w;
    }
  }
}

// The face toward +z: a knit loop's legs (a quarter loop from its head) in front, its head behind; in the rib the
// purl wales the other way round.
TEST(KnitTest, TechnicalFaceTowardPlusZ) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    const int n = 32;
    const KnitLayout k = Build(Params(stitch, 4, 1, n));
    for (int w = 0; w < 4; ++w) {
      const bool purl = stitch == KnitStitch::kRib1x1 && w % 2 == 1;
      const Polyline& c = k.courses[0];
      const Vec3 head = c[size_t(w * n + n / 2)], leg = c[size_t(w * n + n / 4)];
      EXPECT_GT(head.y, leg.y);
      EXPECT_NEAR(head.x, (w + 0.5) * k.wale_spacing, 1e-12);
      EXPECT_LT(purl ? -head.z : head.z, 0) << Name(stitch) << " wale " << w;
      EXPECT_GT(purl ? -leg.z : leg.z, 0) << Name(stitch) << " wale " << w;
    }
  }
}

// Course j + 1 is course j moved up by course_spacing; along x each course repeats with period_x vertex for
// vertex; one repeat is a wale in jersey, two in the rib.
TEST(KnitTest, PatchIsPeriodic) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    const int n = 40;
    const KnitLayout k = Build(Params(stitch, 6, 4, n));
    const double wales_per_period = stitch == KnitStitch::kJersey ? 1 : 2;
    EXPECT_DOUBLE_EQ(k.period_x, wales_per_period * k.wale_spacing);
    EXPECT_DOUBLE_EQ(k.period_y, k.course_spacing);
    const double tol = 1e-12 * (k.upper.x + k.upper.y);
    for (size_t j = 0; j < k.courses.size(); ++j) {
      const Polyline& c = k.courses[j];
      ASSERT_EQ(c.size(), size_t(6 * n + 1));
      EXPECT_NEAR(c.front().x, 0, tol);
      EXPECT_NEAR(c.back().x, 6 * k.wale_spacing, tol);
      const size_t period = size_t(wales_per_period * n);
      for (size_t v = 0; v + period < c.size(); ++v) {
        EXPECT_NEAR(c[v + period].x, c[v].x + k.period_x, tol);
        EXPECT_NEAR(c[v + period].y, c[v].y, tol);
        EXPECT_NEAR(c[v + period].z, c[v].z, tol);
      }
      if (j == 0) continue;
      for (size_t v = 0; v < c.size(); ++v) {
        EXPECT_NEAR(c[v].x, k.courses[j - 1][v].x, tol);
        EXPECT_NEAR(c[v].y, k.courses[j - 1][v].y + k.course_spacing, tol);
        EXPECT_NEAR(c[v].z, k.courses[j - 1][v].z, tol);
      }
    }
  }
}

// 1 x 1 rib: each purl wale is the knit wale before it mirrored through the fabric plane (z -> -z) and moved
// one wale along x.
TEST(KnitTest, RibPurlWalesAreMirroredKnitWales) {
  const int n = 32;
  const KnitLayout k = Build(Params(KnitStitch::kRib1x1, 4, 1, n));
  const Polyline& c = k.courses[0];
  const double tol = 1e-12 * k.upper.x;
  for (size_t v = 0; v <= size_t(n); ++v) {
    for (size_t knit : {size_t(0), size_t(2 * n)}) {
      const Vec3 a = c[knit + v], b = c[knit + v + size_t(n)];
      EXPECT_NEAR(b.x, a.x + k.wale_spacing, tol);
      EXPECT_NEAR(b.y, a.y, tol);
      EXPECT_NEAR(b.z, -a.z, tol);
    }
  }
  // And it is not jersey: the purl wale's head is in front.
  EXPECT_GT(c[size_t(n + n / 2)].z, 0);
}

TEST(KnitTest, PolylinesTurnLessThan60DegreesAndAreFinite) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    for (double stretch_x : {1.0, 2.0, kMaxSpacingStretch}) {
      for (double stretch_y : {1.0, 2.0, kMaxSpacingStretch}) {
        for (int points : {kMinPointsPerLoop, kMaxPointsPerLoop}) {
          KnitParams p = Params(stitch, 3, 2, points);
          p.wale_spacing = stretch_x * DefaultWaleSpacing(stitch, p.yarn_radius);
          p.course_spacing = stretch_y * DefaultCourseSpacing(stitch, p.yarn_radius);
          const KnitLayout k = Build(p);
          for (const Polyline& c : k.courses) {
            for (const Vec3& v : c) ASSERT_TRUE(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z));
            for (size_t i = 1; i < c.size(); ++i) ASSERT_GT(Norm(c[i] - c[i - 1]), 0);
            const double turning = MaxTurningDegrees(c);
            if (points == kMinPointsPerLoop && &c == &k.courses[0])
              std::printf("%s spacings x (%g, %g), %d points per loop: turns at most %.1f degrees\n", Name(stitch),
                          stretch_x, stretch_y, points, turning);
            EXPECT_LT(turning, 60) << Name(stitch) << " " << stretch_x << " " << stretch_y << " " << points;
          }
        }
      }
    }
  }
}

// The courses go to the fibers through curve_layout.h as polylines: PolylineYarnCurve's rules must accept them.
TEST(KnitTest, CoursesAreValidCentreCurves) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    for (double stretch_x : {1.0, kMaxSpacingStretch}) {
      KnitParams p = Params(stitch, 4, 2);
      p.wale_spacing = stretch_x * DefaultWaleSpacing(stitch, p.yarn_radius);
      const KnitLayout k = Build(p);
      for (const Polyline& c : k.courses) {
        PolylineYarnCurve curve;
        EXPECT_EQ(MakeCentreCurve(c, CurveKind::kPolyline, &curve), "") << Name(stitch) << " " << stretch_x;
        EXPECT_NEAR(curve.Length(), Length(c), 1e-9 * Length(c));
      }
    }
  }
}

TEST(KnitTest, BoundsHoldEveryVertex) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    const KnitParams p = Params(stitch, 5, 3);
    const KnitLayout k = Build(p);
    int64_t vertices = 0;
    for (const Polyline& c : k.courses) {
      vertices += int64_t(c.size());
      for (const Vec3& v : c) {
        for (double coordinate_gap : {v.x - k.lower.x, v.y - k.lower.y, v.z - k.lower.z, k.upper.x - v.x,
                                      k.upper.y - v.y, k.upper.z - v.z})
          EXPECT_GE(coordinate_gap, p.yarn_radius * (1 - 1e-12));
      }
      EXPECT_NEAR(Length(c), k.course_length, 1e-9 * k.course_length);
    }
    EXPECT_EQ(vertices, k.vertices);
    // The loops reach across the courses' centre lines: more than half a course spacing each way (so they can
    // interlock), within a yarn's width of the model's depth in z.
    EXPECT_GT(k.loop_height, 0.5 * k.course_spacing);
    EXPECT_NEAR(k.upper.z, k.loop_depth + p.yarn_radius, 1e-12);
  }
}

TEST(KnitTest, FortyByFortyStitchesBuildWithinTheVertexBound) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    for (int points : {32, kMaxPointsPerLoop}) {
      const KnitLayout k = Build(Params(stitch, 40, 40, points));
      ASSERT_EQ(k.courses.size(), 40u);
      EXPECT_EQ(k.vertices, int64_t(40) * (40 * points + 1));
      EXPECT_LE(k.vertices, kMaxKnitVertices);
      EXPECT_NEAR(k.courses[39].back().x, 40 * k.wale_spacing, 1e-9);
    }
  }
}

// What a loop of this knit amounts to, against published plain-knit figures: the yarn in one stitch (the loop
// length l) in yarn diameters D is typically 14 to 20 for jersey, and round incompressible yarns jam at l/D about
// 16.7 (Chamberlain's and Hepworth and Leaf's models); Munden's dimensionless constants kc = l / course spacing,
// kw = l / wale spacing. Prints the numbers (they go in the report) and checks l/D against the typical range.
TEST(KnitTest, LoopLengthIsThatOfARealKnit) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    const KnitParams p = Params(stitch, 8, 1, 256);
    const KnitLayout k = Build(p);
    const double loop = Length(k.courses[0]) / p.wales;
    const double diameters = loop / (2 * p.yarn_radius);
    std::printf("%s defaults: wale spacing %.4f r, course spacing %.4f r, loop height %.4f r, depth %.4f r; loop "
                "length %.4f r = %.3f yarn diameters; kc = l / course spacing %.3f, kw = l / wale spacing %.3f, "
                "kc / kw %.3f\n",
                Name(stitch), k.wale_spacing / p.yarn_radius, k.course_spacing / p.yarn_radius,
                k.loop_height / p.yarn_radius, k.loop_depth / p.yarn_radius, loop / p.yarn_radius, diameters,
                loop / k.course_spacing, loop / k.wale_spacing, k.wale_spacing / k.course_spacing);
    EXPECT_GE(diameters, 14);
    EXPECT_LE(diameters, 20);
  }
}

TEST(KnitTest, DefaultsScaleWithTheYarnRadius) {
  for (KnitStitch stitch : {KnitStitch::kJersey, KnitStitch::kRib1x1}) {
    KnitParams p = Params(stitch, 2, 2);
    const KnitLayout a = Build(p);
    p.yarn_radius *= 3;
    const KnitLayout b = Build(p);
    EXPECT_NEAR(b.wale_spacing, 3 * a.wale_spacing, 1e-12);
    EXPECT_NEAR(b.course_spacing, 3 * a.course_spacing, 1e-12);
    for (size_t v = 0; v < a.courses[1].size(); ++v) {
      EXPECT_NEAR(b.courses[1][v].x, 3 * a.courses[1][v].x, 1e-9);
      EXPECT_NEAR(b.courses[1][v].z, 3 * a.courses[1][v].z, 1e-9);
    }
    EXPECT_EQ(a.wale_spacing, DefaultWaleSpacing(stitch, 0.0378));
    EXPECT_EQ(a.course_spacing, DefaultCourseSpacing(stitch, 0.0378));
  }
}

std::string BuildError(const KnitParams& p) {
  KnitLayout k;
  k.vertices = 7;
  const std::string e = BuildKnit(p, &k);
  if (!e.empty()) {
    EXPECT_TRUE(k.courses.empty()) << e;
    EXPECT_EQ(k.vertices, 0) << e;
  }
  if (!ValidateKnitParams(p).empty()) {
    EXPECT_NE(e, "");
  }
  return e;
}

void ExpectField(const KnitParams& p, const std::string& field) {
  const std::string e = BuildError(p);
  EXPECT_EQ(e.substr(0, field.size() + 2), field + ": ") << e;
}

TEST(KnitTest, BadParametersNameTheirField) {
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  const KnitParams good = Params(KnitStitch::kRib1x1, 3, 3);
  EXPECT_EQ(BuildError(good), "");
  auto with = [&](auto change) {
    KnitParams p = good;
    change(p);
    return p;
  };
  for (int wales : {0, -1, kMaxKnitStitches + 1}) ExpectField(with([&](KnitParams& p) { p.wales = wales; }), "wales");
  for (int courses : {0, kMaxKnitStitches + 1})
    ExpectField(with([&](KnitParams& p) { p.courses = courses; }), "courses");
  for (double r : {0.0, -0.01, nan, inf, 1e-9, 2e3})
    ExpectField(with([&](KnitParams& p) { p.yarn_radius = r; }), "yarn_radius");
  const double wale = DefaultWaleSpacing(good.stitch, good.yarn_radius);
  const double course = DefaultCourseSpacing(good.stitch, good.yarn_radius);
  for (double s : {-1.0, nan, inf, 0.99 * wale, kMaxSpacingStretch * wale * 1.01})
    ExpectField(with([&](KnitParams& p) { p.wale_spacing = s; }), "wale_spacing");
  for (double s : {-1.0, nan, inf, 0.99 * course, kMaxSpacingStretch * course * 1.01})
    ExpectField(with([&](KnitParams& p) { p.course_spacing = s; }), "course_spacing");
  // The jersey's tighter default is too tight for the rib.
  ExpectField(with([&](KnitParams& p) { p.wale_spacing = DefaultWaleSpacing(KnitStitch::kJersey, p.yarn_radius); }),
              "wale_spacing");
  EXPECT_EQ(BuildError(with([&](KnitParams& p) { p.wale_spacing = wale; })), "");
  EXPECT_EQ(BuildError(with([&](KnitParams& p) { p.course_spacing = kMaxSpacingStretch * course; })), "");
  for (int points : {0, kMinPointsPerLoop - 1, kMaxPointsPerLoop + 1})
    ExpectField(with([&](KnitParams& p) { p.points_per_loop = points; }), "points_per_loop");
  ExpectField(with([](KnitParams& p) { p.stitch = KnitStitch(7); }), "stitch");
  // Too many vertices, refused before allocating: 512 x 512 stitches at 32 points are 8.4 million.
  ExpectField(with([](KnitParams& p) { p.wales = p.courses = kMaxKnitStitches; }), "points_per_loop");
  // A course longer than a yarn may be: 512 loops of a 1-radius yarn are about 17,000 long.
  ExpectField(with([](KnitParams& p) {
                p.wales = kMaxKnitStitches;
                p.courses = 1;
                p.yarn_radius = 1;
              }),
              "wales");
}

}  // namespace
}  // namespace loomlight::yarn
