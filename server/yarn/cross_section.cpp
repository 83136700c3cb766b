#include "server/yarn/cross_section.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace loomlight::yarn {
namespace {

constexpr double kTwoPi = 2 * std::numbers::pi;

}  // namespace

std::string ValidateCrossSectionOptions(const CrossSectionOptions& o) {
  if (o.resolution < 16 || o.resolution > 512)
    return "resolution: " + std::to_string(o.resolution) + " must be in 16..512";
  if (o.slices < 1 || o.slices > 256) return "slices: " + std::to_string(o.slices) + " must be in 1..256";
  return "";
}

std::string YarnCrossSection::Make(const YarnParams& p, const CrossSectionOptions& o, YarnCrossSection* out) {
  if (std::string e = ValidateYarnParams(p); !e.empty()) return e;
  if (std::string e = ValidateCrossSectionOptions(o); !e.empty()) return e;
  YarnCrossSection x;
  x.params_ = p;
  x.options_ = o;
  // Every ply's ellipse lies within R_ply / 2 + its long semi-axis of the centre; 2% more keeps its edge
  // off the last texel.
  x.extent_ = 1.02 * (0.5 * p.yarn_radius + std::max(p.ellipse_n, p.ellipse_b));
  x.cell_ = 2 * x.extent_ / o.resolution;
  // D(R) over the unit disk (midpoint rule in R; D is smooth there), so a ply's density integrates to its fibers.
  constexpr int kSteps = 4096;
  double disk = 0;
  for (int i = 0; i < kSteps; ++i) {
    const double r = (i + 0.5) / kSteps;
    disk += FiberDensity(r, p.eps, p.beta) * r;
  }
  disk *= kTwoPi / kSteps;
  x.ply_norm_ = p.fiber_width * p.fibers_per_ply / (p.ellipse_n * p.ellipse_b * disk);

  const int n = o.resolution;
  // The extinction per texel centre, for Shadow's own-fiber correction (bilinear: D's exp and pow per ply
  // cost more than the rest of a lookup).
  x.extinction_.resize(size_t(n) * n);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      x.extinction_[size_t(j) * n + i] =
          float(x.Extinction(-x.extent_ + (i + 0.5) * x.cell_, -x.extent_ + (j + 0.5) * x.cell_));
  const double slice_angle = kTwoPi / (p.plies * o.slices);
  x.depth_.assign(size_t(o.slices) * n * n, 0.0f);
  for (int k = 0; k < o.slices; ++k) {
    const double gamma = k * slice_angle, c = std::cos(gamma), s = std::sin(gamma);
    for (int j = 0; j < n; ++j) {
      const double t = -x.extent_ + (j + 0.5) * x.cell_;
      // Slice (s, t) is the frame's R(gamma) (s, t): the light comes from +s.
      const auto at = [&](double u) { return x.Extinction(c * u - s * t, s * u + c * t); };
      // Slices innermost: a lookup's two slices share cache lines.
      const auto texel = [&](int i) -> float& { return x.depth_[(size_t(j) * n + i) * o.slices + k]; };
      double u_last = -x.extent_ + (n - 0.5) * x.cell_;
      double depth = 0.5 * x.cell_ * at(u_last + 0.25 * x.cell_);  // the last half texel, to the edge
      texel(n - 1) = float(depth);
      for (int i = n - 2; i >= 0; --i) {
        const double u = -x.extent_ + (i + 0.5) * x.cell_;
        depth += 0.5 * x.cell_ * (at(u + 0.25 * x.cell_) + at(u + 0.75 * x.cell_));
        texel(i) = float(depth);
      }
    }
  }

  // Occlusion: the mean transmittance over the K * slices slice directions.
  const int directions = p.plies * o.slices;
  x.occlusion_.assign(size_t(n) * n, 0.0f);
  std::vector<double> cosines(directions), sines(directions);
  for (int m = 0; m < directions; ++m) cosines[m] = std::cos(m * slice_angle), sines[m] = std::sin(m * slice_angle);
  for (int j = 0; j < n; ++j) {
    const double py = -x.extent_ + (j + 0.5) * x.cell_;
    for (int i = 0; i < n; ++i) {
      const double px = -x.extent_ + (i + 0.5) * x.cell_;
      double sum = 0;
      for (int m = 0; m < directions; ++m) {
        const double c = cosines[m], s = sines[m];
        sum += std::exp(-x.Texel(x.depth_, o.slices, m % o.slices, c * px + s * py, -s * px + c * py));
      }
      x.occlusion_[size_t(j) * n + i] = float(sum / directions);
    }
  }

  // Radial mean, bins one texel wide.
  const int bins = n / 2;
  std::vector<double> sum(bins, 0.0), count(bins, 0.0);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double px = -x.extent_ + (i + 0.5) * x.cell_, py = -x.extent_ + (j + 0.5) * x.cell_;
      const int b = int(std::hypot(px, py) / x.extent_ * bins);
      if (b >= bins) continue;
      sum[b] += x.occlusion_[size_t(j) * n + i];
      count[b] += 1;
    }
  }
  x.radial_.assign(bins, 1.0f);
  for (int b = 0; b < bins; ++b) x.radial_[b] = float(count[b] > 0 ? sum[b] / count[b] : b > 0 ? x.radial_[b - 1] : 0.0);
  *out = std::move(x);
  return "";
}

double YarnCrossSection::Extinction(double x, double y) const {
  const YarnParams& p = params_;
  double total = 0;
  for (int j = 0; j < p.plies; ++j) {
    const double a = kTwoPi * j / p.plies, c = std::cos(a), s = std::sin(a);
    const double dx = x - 0.5 * p.yarn_radius * c, dy = y - 0.5 * p.yarn_radius * s;
    const double u = (dx * c + dy * s) / p.ellipse_n, v = (-dx * s + dy * c) / p.ellipse_b;
    const double r2 = u * u + v * v;
    if (r2 < 1) total += FiberDensity(std::sqrt(r2), p.eps, p.beta);
  }
  return ply_norm_ * total;
}

double YarnCrossSection::Texel(const std::vector<float>& t, int stride, int slice, double s, double u) const {
  const int n = options_.resolution;
  const double fi = std::clamp((s + extent_) / cell_ - 0.5, 0.0, n - 1.0);
  const double fj = std::clamp((u + extent_) / cell_ - 0.5, 0.0, n - 1.0);
  const int i = std::min(int(fi), n - 2), j = std::min(int(fj), n - 2);
  const double a = fi - i, b = fj - j;
  const float* p = &t[(size_t(j) * n + i) * stride + slice];
  const size_t right = stride, down = size_t(n) * stride;
  return (1 - b) * ((1 - a) * p[0] + a * p[right]) + b * ((1 - a) * p[down] + a * p[down + right]);
}

double YarnCrossSection::Depth(double x, double y, double light_angle) const {
  if (!std::isfinite(light_angle)) return 0;
  return DepthToward(x, y, std::cos(light_angle), std::sin(light_angle));
}

double YarnCrossSection::DepthToward(double x, double y, double dx, double dy) const {
  if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(dx) || !std::isfinite(dy)) return 0;
  // A direction's components (|d| <= 1 in use): a plain root cannot overflow, and glibc's hypot costs 4 times more.
  const double length = std::sqrt(dx * dx + dy * dy);
  // A light along the yarn: any 2D direction (the parallel-fiber depth does not depend on the elevation).
  const double c = length > 1e-12 ? dx / length : 1.0, s = length > 1e-12 ? dy / length : 0.0;
  const double ps = c * x + s * y, pt = -s * x + c * y;  // R(-light angle) (x, y): the slice's coordinates
  // The slice index: the light angle modulo the plies' symmetry, in units of the slice spacing.
  const double slice_angle = kTwoPi / (params_.plies * options_.slices);
  double f = std::fmod(std::atan2(s, c) / slice_angle, double(options_.slices));
  if (f < 0) f += options_.slices;
  const int k0 = std::min(int(f), options_.slices - 1), k1 = (k0 + 1) % options_.slices;
  const double w = f - k0;
  return (1 - w) * Texel(depth_, options_.slices, k0, ps, pt) + w * Texel(depth_, options_.slices, k1, ps, pt);
}

double YarnCrossSection::Shadow(double x, double y, double light_angle, double own_radius) const {
  if (!std::isfinite(light_angle)) return 1;
  return ShadowToward(x, y, std::cos(light_angle), std::sin(light_angle), own_radius);
}

double YarnCrossSection::ShadowToward(double x, double y, double dx, double dy, double own_radius) const {
  if (!std::isfinite(x) || !std::isfinite(y)) return 1;
  const double own = std::isfinite(own_radius) ? std::max(0.0, own_radius) * Texel(extinction_, 1, 0, x, y) : 0.0;
  return std::exp(-std::max(0.0, DepthToward(x, y, dx, dy) - own));
}

double YarnCrossSection::DepthExact(double x, double y, double light_angle, int steps) const {
  const double c = std::cos(light_angle), s = std::sin(light_angle);
  // From the point to where the ray leaves the disk of radius extent * sqrt(2) (the texture's corners).
  const double b = x * c + y * s, q = x * x + y * y - 2 * extent_ * extent_;
  const double length = std::max(0.0, -b + std::sqrt(std::max(0.0, b * b - q)));
  const double h = length / steps;
  double depth = 0;
  for (int i = 0; i < steps; ++i) depth += Extinction(x + (i + 0.5) * h * c, y + (i + 0.5) * h * s);
  return depth * h;
}

double YarnCrossSection::Occlusion(double x, double y) const {
  if (!std::isfinite(x) || !std::isfinite(y)) return 1;
  return Texel(occlusion_, 1, 0, x, y);
}

double YarnCrossSection::DistanceOcclusion(double r) const {
  if (!std::isfinite(r)) return 1;
  const int bins = int(radial_.size());
  const double f = std::clamp(std::fabs(r) / extent_ * bins - 0.5, 0.0, bins - 1.0);
  const int b = std::min(int(f), bins - 2);
  const double w = f - b;
  return (1 - w) * radial_[b] + w * radial_[b + 1];
}

}  // namespace loomlight::yarn
