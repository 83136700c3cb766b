// Environment lighting of a BTF asset folded per view slot (Sattler, Sarlette and Klein 2003, Sec. 5.3, Eq. 10;
// SPEC.md section 7). f(wi, wo, uv) interpolates the light directions around wi with weights h_i(wi) (summing to
// 1) and the view slots around wo (Eq. 5), so for an environment L(w) seen from a frame R (x = u, y = v, z = n):
//   L_o(wo, uv) = integral of f(wi, wo, uv) L(R wi) cos(theta_i) V(wi) dwi
//               = sum over views j of w_j(wo) [G_j mean_j(uv) + sum_k gamma_kj B_kj(uv)],
//   g_i = integral of L(R wi) h_i(wi) cos(theta_i) V(wi) dwi (RGB), G_j = sum_i g_i, gamma_kj = sum_i g_i p_ikj.
// The stored images are f itself (the cosine is not in them: CreateBtf synthesises them from the models' f,
// SPEC.md section 1), hence the cosine in g_i. This is exact for the interpolated BTF; the errors are the
// discretisation of the integral over the map's directions and, in a renderer, the interpolation of G and gamma
// between the frames they are computed at (the paper's vertices, Eq. 12).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::models::btf {

// One direction of a discretised environment: a unit world-space direction, the solid angle it stands for and
// the radiance over it (RGB).
struct EnvironmentDirection {
  double direction[3] = {0, 0, 1};
  double solid_angle = 0;
  double radiance[3] = {0, 0, 0};
};

// A shading frame in world space, orthonormal: x = texture u (thread 1), y = v, n = the side lit and seen.
struct FoldFrame {
  double x[3] = {1, 0, 0}, y[3] = {0, 1, 0}, n[3] = {0, 0, 1};
};

// Whether the environment is seen from frame `frame` toward the world direction (e.g. a shadow ray through the
// scene: the paper's visibility maps, Sec. 5.2). Empty: always.
using FoldVisibility = std::function<bool(size_t frame, const double direction[3])>;

// The folded coefficients of one asset (with c of its components) for one environment at a set of frames:
// per frame, view slot and channel, G_j then gamma_kj (k < c), float32. Immutable once made.
class EnvironmentFold {
 public:
  // Bytes of the coefficient tables for `frames` frames (what Make allocates, besides its temporaries of
  // 3 x frames x N doubles).
  static uint64_t TableBytes(const PackedTables& tables, int components, size_t frames);

  // Folds `environment` at every frame (directions below a frame's horizon, or not visible from it, add
  // nothing). Runs on `threads` threads; `cancelled` (may be empty) is polled between frames (then nullptr).
  // `tables` is an asset's packed layout (kernels/models/btf.h); components is clamped to its K.
  static std::shared_ptr<const EnvironmentFold> Make(std::shared_ptr<const PackedTables> tables, int components,
                                                     const std::vector<EnvironmentDirection>& environment,
                                                     const std::vector<FoldFrame>& frames,
                                                     const FoldVisibility& visible, int threads,
                                                     const std::function<bool()>& cancelled);

  // Radiance toward wo (the hit's shading frame, any length) at texture coordinates (u, v) (textured: the BTF,
  // else the tile's mean, the BRDF) from the coefficients of up to 4 frames blended with `weight` (frame -1 or
  // weight 0: unused): the kernel's view blend and bilinear texel filter. Never negative, never NaN.
  void Radiance(const int frame[4], const double weight[4], const double wo[3], bool textured, double u, double v,
                double out[3]) const;

  size_t frames() const { return frames_; }
  int components() const { return components_; }
  uint64_t bytes() const { return uint64_t(coefficients_.size()) * sizeof(float); }

 private:
  std::shared_ptr<const PackedTables> tables_;
  int components_ = 0, kept_ = 0, views_ = 0;
  size_t frames_ = 0;
  std::vector<float> coefficients_;  // [frame][view][channel][1 + c]: G_j, then gamma_kj
};

}  // namespace loomlight::models::btf
