#include "server/yarn/knit.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "server/models/quote.h"
#include "server/yarn/yarn.h"

namespace loomlight::yarn {
namespace {

// The loop shape: Keenan Crane, "A Simple Parametric Model of Plain-Knit Yarns" (technical note, Carnegie Mellon
// University, 2023; github.com/keenancrane/plain-knit-yarn, YarnCurve.pdf, Eq. 1 and Fig. 2, and its
// plain-knit.c), a course's centreline
//   gamma(t) = (t + a sin(2t), h cos(t), d cos(2t)),
// one loop per 2 pi of t: a sinusoid of height h whose x overshoots and backtracks (a) to round the loops, bent out
// of the plane at twice the frequency (d) so that each row loops around the next. His example: a = 3/2, h = 4,
// d = 1, rows offset by h + 1/2 in y, a tube of radius 4/5. We keep his shape and proportions and set the scale
// (knit.h's readings).
constexpr double kRoundness = 1.5;          // a
constexpr double kCraneLoopHeight = 4;      // h
constexpr double kCraneCourseSpacing = 4.5; // h + 1/2
constexpr double kCraneDepth = 1;           // d
constexpr double kTwoPi = 2 * std::numbers::pi;

// Yarn radii per unit of Crane's curve (knit.h: the smallest scale free of contact at kMinPointsPerLoop).
double Scale(KnitStitch stitch) { return stitch == KnitStitch::kRib1x1 ? 1.40 : 1.34; }

using models::Number;

// "" or "name: ..." for a spacing that is neither 0 (the default) nor in [1, kMaxSpacingStretch] x the default.
std::string CheckSpacing(const char* name, double spacing, double default_spacing) {
  if (spacing == 0) return "";
  const double most = kMaxSpacingStretch * default_spacing;
  if (!(spacing >= default_spacing && spacing <= most))
    return std::string(name) + ": is " + Number(spacing) + ", must be 0 (the default) or a finite number in [" +
           Number(default_spacing) + ", " + Number(most) + "] (closer loops would interpenetrate)";
  return "";
}

struct LoopShape {
  double x_per_t = 0;         // wale_spacing / (2 pi)
  double course_spacing = 0;  // y of course 0's leg centre line is course_spacing / 2
  double height = 0;          // h
  double depth = 0;           // d
  bool rib = false;
};

// Quintic smootherstep of u clamped to [0, 1]: C2, 0 at 0 and 1 at 1.
double SmootherStep(double u) {
  u = std::clamp(u, 0.0, 1.0);
  return u * u * u * (u * (6 * u - 15) + 10);
}

// sigma(t): +1 on a knit wale, -1 on a purl wale. Jersey: +1. Rib: wale w = floor(t / 2 pi) is knit when even;
// around the boundary t = 2 pi k, sigma goes from wale k - 1's sign to wale k's over |t - 2 pi k| < kRibTransition.
double WaleSign(const LoopShape& s, double t) {
  if (!s.rib) return 1;
  const double k = std::floor(t / kTwoPi + 0.5);  // the nearest wale boundary
  const double into = t - kTwoPi * k;             // in [-pi, pi)
  const double sign_after = std::fmod(k, 2.0) == 0 ? 1.0 : -1.0;  // wale k (k >= 0 here)
  return -sign_after + 2 * sign_after * SmootherStep((into + kRibTransition) / (2 * kRibTransition));
}

// Course 0's centre at parameter t >= 0, Crane's curve with t shifted by pi (so that t = 0 is the bottom of a
// sinker loop at x = 0 and wale w's head is at t = 2 pi w + pi) and z negated (face toward +z).
Vec3 CoursePoint(const LoopShape& s, double t) {
  return {s.x_per_t * (t + kRoundness * std::sin(2 * t)), 0.5 * s.course_spacing - s.height * std::cos(t),
          -WaleSign(s, t) * s.depth * std::cos(2 * t)};
}

}  // namespace

double DefaultWaleSpacing(KnitStitch stitch, double yarn_radius) { return kTwoPi * Scale(stitch) * yarn_radius; }

double DefaultCourseSpacing(KnitStitch stitch, double yarn_radius) {
  return kCraneCourseSpacing * Scale(stitch) * yarn_radius;
}

std::string ValidateKnitParams(const KnitParams& p) {
  if (p.stitch != KnitStitch::kJersey && p.stitch != KnitStitch::kRib1x1) return "stitch: unknown stitch";
  if (p.wales < 1 || p.wales > kMaxKnitStitches)
    return "wales: is " + std::to_string(p.wales) + ", must be in 1.." + std::to_string(kMaxKnitStitches);
  if (p.courses < 1 || p.courses > kMaxKnitStitches)
    return "courses: is " + std::to_string(p.courses) + ", must be in 1.." + std::to_string(kMaxKnitStitches);
  if (!(p.yarn_radius >= kMinLength && p.yarn_radius <= kMaxLength))
    return "yarn_radius: is " + Number(p.yarn_radius) + ", must be a finite number in [" + Number(kMinLength) + ", " +
           Number(kMaxLength) + "]";
  if (std::string e = CheckSpacing("wale_spacing", p.wale_spacing, DefaultWaleSpacing(p.stitch, p.yarn_radius));
      !e.empty())
    return e;
  if (std::string e =
          CheckSpacing("course_spacing", p.course_spacing, DefaultCourseSpacing(p.stitch, p.yarn_radius));
      !e.empty())
    return e;
  if (p.points_per_loop < kMinPointsPerLoop || p.points_per_loop > kMaxPointsPerLoop)
    return "points_per_loop: is " + std::to_string(p.points_per_loop) + ", must be in " +
           std::to_string(kMinPointsPerLoop) + ".." + std::to_string(kMaxPointsPerLoop);
  return "";
}

std::string BuildKnit(const KnitParams& p, KnitLayout* out) {
  *out = KnitLayout();
  if (std::string e = ValidateKnitParams(p); !e.empty()) return e;
  const bool rib = p.stitch == KnitStitch::kRib1x1;
  const double wale_spacing = p.wale_spacing != 0 ? p.wale_spacing : DefaultWaleSpacing(p.stitch, p.yarn_radius);
  const double course_spacing =
      p.course_spacing != 0 ? p.course_spacing : DefaultCourseSpacing(p.stitch, p.yarn_radius);
  const LoopShape shape{wale_spacing / kTwoPi, course_spacing,
                        course_spacing * (kCraneLoopHeight / kCraneCourseSpacing),
                        Scale(p.stitch) * kCraneDepth * p.yarn_radius, rib};

  // Work and size bounds, before the patch is allocated.
  const int64_t per_course = int64_t(p.wales) * p.points_per_loop + 1;
  const int64_t vertices = per_course * p.courses;
  if (vertices > kMaxKnitVertices)
    return "points_per_loop: " + std::to_string(p.wales) + " x " + std::to_string(p.courses) + " stitches at " +
           std::to_string(p.points_per_loop) + " points per loop make " + std::to_string(vertices) +
           " vertices, more than " + std::to_string(kMaxKnitVertices);
  // One repeat along x (the rest of a course is it translated), and its length: knit and purl loops are mirror
  // images, so every loop is as long and a course is wales loops long.
  const int period_wales = rib ? 2 : 1;
  const int period_points = period_wales * p.points_per_loop;
  const double period_x = period_wales * wale_spacing;
  std::vector<Vec3> period(size_t(period_points) + 1);
  for (int i = 0; i <= period_points; ++i) period[size_t(i)] = CoursePoint(shape, kTwoPi * i / p.points_per_loop);
  double period_length = 0;
  for (int i = 0; i < period_points; ++i) period_length += Norm(period[size_t(i) + 1] - period[size_t(i)]);
  const double course_length = period_length / period_wales * p.wales;
  if (!(course_length <= kMaxLength))
    return "wales: each course would be " + Number(course_length) + " long, more than a yarn may be (" +
           Number(kMaxLength) + ")";

  out->courses.resize(size_t(p.courses));
  out->courses[0].resize(size_t(per_course));
  for (int64_t v = 0; v < per_course; ++v)
    out->courses[0][size_t(v)] = period[size_t(v % period_points)] + Vec3{double(v / period_points) * period_x, 0, 0};
  for (int j = 1; j < p.courses; ++j) {
    const Vec3 up{0, j * course_spacing, 0};
    out->courses[size_t(j)].reserve(size_t(per_course));
    for (const Vec3& v : out->courses[0]) out->courses[size_t(j)].push_back(v + up);
  }

  // The other courses lie between the first and the last.
  Vec3 lo = out->courses[0][0], hi = lo;
  for (const size_t j : {size_t(0), out->courses.size() - 1})
    for (const Vec3& v : out->courses[j]) {
      lo = {std::min(lo.x, v.x), std::min(lo.y, v.y), std::min(lo.z, v.z)};
      hi = {std::max(hi.x, v.x), std::max(hi.y, v.y), std::max(hi.z, v.z)};
    }
  const Vec3 widen{p.yarn_radius, p.yarn_radius, p.yarn_radius};
  out->lower = lo - widen;
  out->upper = hi + widen;
  out->wale_spacing = wale_spacing;
  out->course_spacing = course_spacing;
  out->loop_height = shape.height;
  out->loop_depth = shape.depth;
  out->period_x = period_x;
  out->period_y = course_spacing;
  out->vertices = vertices;
  out->course_length = course_length;
  return "";
}

}  // namespace loomlight::yarn
