#include "server/yarn/layout.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "server/models/quote.h"
#include "server/models/rng.h"

namespace loomlight::yarn {
namespace {

constexpr double kPi = 3.14159265358979323846;

using models::Number;

Vec3 Normalized(Vec3 v) { return (1 / Norm(v)) * v; }

// Centre height at sample m (of `intervals` = crossings * per) of a yarn whose crossing k has height
// heights[k mod crossings]. Crossing k sits at sample k * per + per / 2; between crossings a half cosine.
double Height(const std::vector<double>& heights, int per, int64_t m) {
  const int64_t n = int64_t(heights.size());
  const int64_t q = m - per / 2;  // samples past crossing 0
  const int64_t k = q >= 0 ? q / per : -((-q + per - 1) / per);  // floor(q / per)
  const int64_t r = q - k * per;                                  // in [0, per)
  const double z0 = heights[size_t(((k % n) + n) % n)];
  const double z1 = heights[size_t((((k + 1) % n) + n) % n)];
  if (r == 0 || z0 == z1) return z0;  // exact at crossings and along floats
  const double u = double(r) / per;
  return z0 + (z1 - z0) * 0.5 * (1 - std::cos(kPi * u));
}

// Builds one yarn: `along` is its arc direction's coordinate axis (0: x for a weft, 1: y for a warp),
// `across` its fixed coordinate, heights one per crossing.
std::string BuildYarn(const std::vector<double>& heights, int per, double spacing, bool warp, double across,
                      LayoutYarn* yarn) {
  const int64_t intervals = int64_t(heights.size()) * per;
  yarn->vertices.resize(size_t(intervals + 1));
  for (int64_t m = 0; m <= intervals; ++m) {
    const double t = double(m) * spacing / per;
    const double z = Height(heights, per, m);
    yarn->vertices[size_t(m)] = warp ? Vec3{across, t, z} : Vec3{t, across, z};
  }
  // Normals: +z made perpendicular to the tangent PolylineYarnCurve computes (the bisector of the segments).
  // The yarn never climbs steeper than 57.5 degrees (readings), so that component is at least 0.5 long.
  const std::vector<Vec3>& v = yarn->vertices;
  yarn->normals.resize(v.size());
  const Vec3 up{0, 0, 1};
  for (size_t i = 0; i < v.size(); ++i) {
    const Vec3 before = i > 0 ? Normalized(v[i] - v[i - 1]) : Vec3{};
    const Vec3 after = i + 1 < v.size() ? Normalized(v[i + 1] - v[i]) : Vec3{};
    const Vec3 tangent = Normalized(before + after);
    yarn->normals[i] = Normalized(up - Dot(up, tangent) * tangent);
  }
  std::string e = PolylineYarnCurve::Make(yarn->vertices, yarn->normals, &yarn->curve);
  if (!e.empty())  // ruled out by ValidateLayoutParams; kept so a broken invariant is reported, not hidden
    return "internal: " + std::string(warp ? "warp" : "weft") + " yarn " + std::to_string(yarn->index) + ": " + e;
  return "";
}

}  // namespace

std::string ValidateLayoutParams(const LayoutParams& p) {
  if (!(p.yarn_radius >= kMinLength && p.yarn_radius <= kMaxLength))
    return "yarn_radius: is " + Number(p.yarn_radius) + ", must be a finite number in [" + Number(kMinLength) + ", " +
           Number(kMaxLength) + "]";
  // Closer than a diameter, neighbouring parallel yarns would overlap, and the crimp could turn the
  // polyline by 60 degrees or more.
  if (!(p.spacing >= 2 * p.yarn_radius && p.spacing <= kMaxLength))
    return "spacing: is " + Number(p.spacing) + ", must be a finite number in [2 yarn_radius = " +
           Number(2 * p.yarn_radius) + ", " + Number(kMaxLength) + "]";
  if (!(p.crimp >= 0 && p.crimp <= 1)) return "crimp: is " + Number(p.crimp) + ", must be a finite number in [0, 1]";
  if (p.repeats_u < 1 || p.repeats_u > kMaxLayoutRepeats)
    return "repeats_u: is " + std::to_string(p.repeats_u) + ", must be in 1.." + std::to_string(kMaxLayoutRepeats);
  if (p.repeats_v < 1 || p.repeats_v > kMaxLayoutRepeats)
    return "repeats_v: is " + std::to_string(p.repeats_v) + ", must be in 1.." + std::to_string(kMaxLayoutRepeats);
  if (p.points_per_crossing < kMinPointsPerCrossing || p.points_per_crossing > kMaxPointsPerCrossing ||
      p.points_per_crossing % 2 != 0)
    return "points_per_crossing: is " + std::to_string(p.points_per_crossing) + ", must be even and in " +
           std::to_string(kMinPointsPerCrossing) + ".." + std::to_string(kMaxPointsPerCrossing);
  return "";
}

std::string BuildLayout(const models::weave::WeavePattern& pattern, const LayoutParams& params, WovenLayout* out) {
  *out = WovenLayout();
  if (std::string e = models::weave::ValidatePattern(pattern); !e.empty()) return "pattern: " + e;
  if (std::string e = ValidateLayoutParams(params); !e.empty()) return e;

  // Work and size bounds, before anything is allocated.
  const int64_t warp_yarns = int64_t(params.repeats_u) * pattern.warps;
  const int64_t weft_yarns = int64_t(params.repeats_v) * pattern.picks;
  if (warp_yarns > kMaxLayoutYarns)
    return "repeats_u: " + std::to_string(params.repeats_u) + " repeats of " + std::to_string(pattern.warps) +
           " warps make " + std::to_string(warp_yarns) + " warp yarns, more than " + std::to_string(kMaxLayoutYarns);
  if (weft_yarns > kMaxLayoutYarns)
    return "repeats_v: " + std::to_string(params.repeats_v) + " repeats of " + std::to_string(pattern.picks) +
           " picks make " + std::to_string(weft_yarns) + " weft yarns, more than " + std::to_string(kMaxLayoutYarns);
  const double size_u = double(warp_yarns) * params.spacing;
  const double size_v = double(weft_yarns) * params.spacing;
  if (size_u > kMaxLayoutExtent)
    return "repeats_u: the patch would be " + Number(size_u) + " wide along x, more than " + Number(kMaxLayoutExtent);
  if (size_v > kMaxLayoutExtent)
    return "repeats_v: the patch would be " + Number(size_v) + " long along y, more than " + Number(kMaxLayoutExtent);
  const int per = params.points_per_crossing;
  // Each warp yarn crosses every weft yarn once and vice versa.
  const int64_t vertices = warp_yarns * (weft_yarns * per + 1) + weft_yarns * (warp_yarns * per + 1);
  if (vertices > kMaxLayoutVertices)
    return "points_per_crossing: the patch's yarns need " + std::to_string(vertices) + " vertices at " +
           std::to_string(per) + " per crossing, more than " + std::to_string(kMaxLayoutVertices) +
           " (use fewer points per crossing or fewer repeats)";

  const double h = params.crimp * params.yarn_radius;
  WovenLayout layout;
  layout.warp_yarns = int(warp_yarns);
  layout.weft_yarns = int(weft_yarns);
  layout.size_u = size_u;
  layout.size_v = size_v;
  layout.height = h;
  layout.lower = {0, 0, -(h + params.yarn_radius)};
  layout.upper = {size_u, size_v, h + params.yarn_radius};
  layout.vertices = vertices;
  layout.yarns.resize(size_t(warp_yarns + weft_yarns));
  std::vector<double> heights;
  for (int64_t k = 0; k < warp_yarns + weft_yarns; ++k) {
    LayoutYarn& yarn = layout.yarns[size_t(k)];
    yarn.warp = k < warp_yarns;
    yarn.index = int(yarn.warp ? k : k - warp_yarns);
    yarn.thread = yarn.index % (yarn.warp ? pattern.warps : pattern.picks);
    yarn.seed_offset = (uint64_t(yarn.warp ? 0 : 1) << 32) | uint64_t(yarn.index);
    // Crossing heights along the yarn: a warp crosses weft yarns 0.., a weft crosses warp yarns 0..;
    // the warp is on top where the cell is 1.
    const int64_t crossings = yarn.warp ? weft_yarns : warp_yarns;
    heights.resize(size_t(crossings));
    for (int64_t c = 0; c < crossings; ++c) {
      const bool warp_on_top = yarn.warp ? pattern.at(yarn.thread, int(c % pattern.picks)) != 0
                                         : pattern.at(int(c % pattern.warps), yarn.thread) != 0;
      heights[size_t(c)] = warp_on_top == yarn.warp ? h : -h;
    }
    const double across = (yarn.index + 0.5) * params.spacing;
    if (std::string e = BuildYarn(heights, per, params.spacing, yarn.warp, across, &yarn); !e.empty()) return e;
  }
  *out = std::move(layout);
  return "";
}

uint64_t LayoutYarnSeed(uint64_t seed, uint64_t seed_offset) { return models::Mix64(models::Mix64(seed) ^ seed_offset); }

std::string GenerateLayout(const YarnParams& yarn, const WovenLayout& layout, const DetailOptions& options,
                           const YarnLimits& limits, LayoutGeometry* out) {
  *out = LayoutGeometry();
  std::string e;
  if (!(e = ValidateYarnParams(yarn)).empty()) return e;
  if (!(e = ValidateDetailOptions(options)).empty()) return e;
  if (limits.max_fibers < 0) return "max_fibers: is " + std::to_string(limits.max_fibers) + ", must be >= 0";
  if (limits.max_control_points < 0)
    return "max_control_points: is " + std::to_string(limits.max_control_points) + ", must be >= 0";

  // Whole-layout bounds from the parameters and curve lengths alone, as GenerateYarn does for one yarn.
  const int64_t yarns = int64_t(layout.yarns.size());
  const int64_t fibers_per_yarn = int64_t(yarn.plies) * yarn.fibers_per_ply;
  const int64_t fibers = yarns * fibers_per_yarn;
  if (fibers > limits.max_fibers)
    return "max_fibers: the layout has " + std::to_string(yarns) + " yarns x " + std::to_string(yarn.plies) + " x " +
           std::to_string(yarn.fibers_per_ply) + " = " + std::to_string(fibers) + " fibers, more than the limit " +
           std::to_string(limits.max_fibers);
  double min_points = 0;
  for (const LayoutYarn& y : layout.yarns) {
    const double length = y.curve.Length();
    if (!(length >= kMinLength && length <= kMaxLength)) continue;  // GenerateYarn reports it below
    min_points += MinControlPoints(yarn, options, length);
  }
  if (min_points > double(limits.max_control_points))
    return "max_control_points: the layout needs at least " + Number(min_points) + " control points (" +
           std::to_string(yarns) + " yarns), more than the limit " + std::to_string(limits.max_control_points);

  const auto name = [&](size_t k) {
    const LayoutYarn& y = layout.yarns[k];
    return std::string(y.warp ? "warp" : "weft") + " yarn " + std::to_string(y.index);
  };
  size_t failed = 0;
  e = GenerateYarnsInTurn(
      layout.yarns.size(),
      [&](size_t k) {
        YarnParams p = yarn;
        p.seed = LayoutYarnSeed(yarn.seed, layout.yarns[k].seed_offset);
        return p;
      },
      [&](size_t k) -> const YarnCurve& { return layout.yarns[k].curve; }, name, options, limits, out, &failed);
  if (!e.empty() && e != "cancelled" && e.rfind("max_", 0) != 0) return e + " (" + name(failed) + ")";
  return e;
}

std::string GenerateYarnsInTurn(size_t count, const std::function<YarnParams(size_t)>& params,
                                const std::function<const YarnCurve&(size_t)>& curve,
                                const std::function<std::string(size_t)>& name, const DetailOptions& options,
                                const YarnLimits& limits, LayoutGeometry* out, size_t* failed) {
  *out = LayoutGeometry();
  LayoutGeometry result;
  result.yarns.resize(count);
  for (size_t k = 0; k < count; ++k) {
    const YarnParams p = params(k);
    // GenerateYarn refuses a yarn whose plies x fibers_per_ply exceed its max_fibers; the caller's whole-layout
    // check covers that, so it gets at least that much and the total is checked after it.
    const int64_t fibers_per_yarn = int64_t(p.plies) * p.fibers_per_ply;
    const YarnLimits left{std::max(limits.max_fibers - result.fibers, fibers_per_yarn),
                          limits.max_control_points - result.control_points};
    YarnGeometry& g = result.yarns[k];
    const std::string e = GenerateYarn(p, curve(k), options, left, &g);
    if (e.rfind("max_fibers:", 0) == 0 || (e.empty() && result.fibers + int64_t(g.fibers.size()) > limits.max_fibers))
      return "max_fibers: the layout needs more than " + std::to_string(limits.max_fibers) + " fiber curves (at " +
             name(k) + ")";
    if (e.rfind("max_control_points:", 0) == 0)
      return "max_control_points: the layout needs more than " + std::to_string(limits.max_control_points) +
             " control points (at " + name(k) + ")";
    if (!e.empty()) {
      *failed = k;
      return e;
    }
    result.fibers += int64_t(g.fibers.size());
    result.control_points += g.control_points;
  }
  *out = std::move(result);
  return "";
}

}  // namespace loomlight::yarn
