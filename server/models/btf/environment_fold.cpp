#include "server/models/btf/environment_fold.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

#include "server/runtime/parallel_for.h"

namespace loomlight::models::btf {
namespace {
// The kernels' own neighbour search (kernels/models/btf.h) on the float32 tables, so the fold weighs light
// directions exactly as f does.
namespace bt_float {
typedef float real;
#include "common/shim.h"
#include "models/btf.h"
}  // namespace bt_float

// The packed layout's header (kernels/models/btf.h), with the blocks' offsets as the kernels compute them.
struct Header {
  int kept, directions;
  size_t weights;
  explicit Header(const float* mat)
      : kept(int(mat[0])), directions(int(mat[4])), weights(size_t(bt_float::bt_weights_offset(mat))) {}
};

double Dot(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

}  // namespace

uint64_t EnvironmentFold::TableBytes(const PackedTables& tables, int components, size_t frames) {
  const Header h(tables.data32().data());
  const int c = std::clamp(components, 0, h.kept);
  return uint64_t(frames) * uint64_t(h.directions) * 3 * uint64_t(1 + c) * sizeof(float);
}

std::shared_ptr<const EnvironmentFold> EnvironmentFold::Make(std::shared_ptr<const PackedTables> tables,
                                                             int components,
                                                             const std::vector<EnvironmentDirection>& environment,
                                                             const std::vector<FoldFrame>& frames,
                                                             const FoldVisibility& visible, int threads,
                                                             const std::function<bool()>& cancelled) {
  auto fold = std::make_shared<EnvironmentFold>();
  const float* mat = tables->data32().data();
  const Header h(mat);
  const int c = std::clamp(components, 0, h.kept), n = h.directions, stride = 1 + c;
  const size_t count = frames.size();
  fold->kept_ = h.kept;
  fold->components_ = c;
  fold->views_ = n;
  fold->frames_ = count;

  // g_i per frame (rows 3 f + channel): the environment weighed by each light direction's interpolation weight
  // and the cosine, summed over the directions above the frame's horizon that it sees.
  Eigen::MatrixXd g = Eigen::MatrixXd::Zero(Eigen::Index(3 * count), n);
  const bool done = runtime::ParallelFor(count, threads, cancelled, [&](size_t f) {
    const FoldFrame& frame = frames[f];
    for (const EnvironmentDirection& e : environment) {
      const double* d = e.direction;
      const double z = Dot(d, frame.n);
      // f is 0 at and below the horizon (the kernel's test on the unit wi).
      if (!(z > 1e-7) || !(e.solid_angle > 0)) continue;
      if (e.radiance[0] <= 0 && e.radiance[1] <= 0 && e.radiance[2] <= 0) continue;
      if (visible && !visible(f, d)) continue;
      float slot[4], weight[4];  // slots as whole numbers, as the kernel holds them
      bt_float::bt_neighbours(mat, float(Dot(d, frame.x)), float(Dot(d, frame.y)), float(z), slot, weight);
      const double scale = e.solid_angle * z;  // dw cos(theta_i)
      for (int m = 0; m < 4; ++m) {
        if (weight[m] == 0) continue;
        for (int ch = 0; ch < 3; ++ch) g(Eigen::Index(3 * f + ch), Eigen::Index(slot[m])) += double(weight[m]) * scale * e.radiance[ch];
      }
    }
  });
  if (!done) return nullptr;

  // Per view slot j, every frame at once: G_j = sum_i g_i, gamma_kj = sum_i g_i p_ikj (one matrix product of
  // (3 frames x N) by the view's (N x c) coefficients: one pass over them for all frames).
  fold->coefficients_.assign(count * size_t(n) * 3 * size_t(stride), 0.0f);
  const Eigen::VectorXd sums = g.rowwise().sum();
  using RowMajor = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const bool folded = runtime::ParallelFor(size_t(n), threads, cancelled, [&](size_t j) {
    Eigen::MatrixXd gamma;
    if (c > 0) {
      const Eigen::Map<const RowMajor, 0, Eigen::OuterStride<>> p(mat + h.weights + j * size_t(n) * h.kept, n, c,
                                                                 Eigen::OuterStride<>(h.kept));
      gamma = g * p.cast<double>();
    }
    for (size_t row = 0; row < 3 * count; ++row) {
      const size_t f = row / 3, ch = row % 3;
      float* out = fold->coefficients_.data() + ((f * n + j) * 3 + ch) * stride;
      out[0] = float(sums(Eigen::Index(row)));
      for (int k = 0; k < c; ++k) out[1 + k] = float(gamma(Eigen::Index(row), k));
    }
  });
  if (!folded) return nullptr;
  fold->tables_ = std::move(tables);
  return fold;
}

void EnvironmentFold::Radiance(const int frame[4], const double weight[4], const double wo_in[3], bool textured,
                               double u, double v, double out[3]) const {
  out[0] = out[1] = out[2] = 0;
  const double length = std::sqrt(Dot(wo_in, wo_in));
  if (!(length > 0) || !tables_) return;
  const double wo[3] = {wo_in[0] / length, wo_in[1] / length, wo_in[2] / length};
  if (!(wo[2] > 1e-7)) return;  // a reflection model (SPEC.md section 1)
  const float* mat = tables_->data32().data();
  const int c = components_, stride = 1 + c, block_stride = 1 + kept_;
  float view[4], view_w[4];  // slots as whole numbers, as the kernel holds them
  bt_float::bt_neighbours(mat, float(wo[0]), float(wo[1]), float(wo[2]), view, view_w);

  // The kernel's texel footprint: bilinear over the wrapped tile, or the tile-mean block.
  int texel[4], block_offset, view_stride;
  float texel_w[4];
  const int texels =
      bt_float::bt_footprint(mat, textured, float(u), float(v), texel, texel_w, &block_offset, &view_stride);
  const float* block = mat + block_offset;
  double acc[3] = {0, 0, 0};
  double coefficient[1 + BT_MAX_COMPONENTS], sum[1 + BT_MAX_COMPONENTS];
  for (int m = 0; m < 4; ++m) {
    if (view_w[m] == 0) continue;
    const float* slot = block + size_t(view[m]) * size_t(view_stride);
    for (int ch = 0; ch < 3; ++ch) {
      // G and gamma of this view blended over the frames (they are linear in g, so this is g blended).
      std::fill(coefficient, coefficient + stride, 0.0);
      for (int f = 0; f < 4; ++f) {
        if (frame[f] < 0 || weight[f] == 0) continue;
        const float* cf = coefficients_.data() + ((size_t(frame[f]) * views_ + size_t(view[m])) * 3 + ch) * stride;
        for (int k = 0; k < stride; ++k) coefficient[k] += weight[f] * cf[k];
      }
      // The texels' filter over (mean, components), then one dot product with (G, gamma), as the kernel does.
      std::fill(sum, sum + stride, 0.0);
      for (int t = 0; t < texels; ++t) {
        const float* e = slot + size_t(texel[t]) * 3 * block_stride + ch * block_stride;
        for (int k = 0; k < stride; ++k) sum[k] += double(texel_w[t]) * e[k];
      }
      double value = 0;
      for (int k = 0; k < stride; ++k) value += coefficient[k] * sum[k];
      acc[ch] += view_w[m] * value;
    }
  }
  // The kernel clamps each f at 0 before it is integrated; this folded sum integrates the unclamped series (the
  // fold is linear), so where a truncated PCA undershoots below 0 it is darker than sampled lighting would be.
  // Only the total is clamped: radiance is never negative.
  for (int ch = 0; ch < 3; ++ch) out[ch] = std::isfinite(acc[ch]) && acc[ch] > 0 ? acc[ch] : 0.0;
}

}  // namespace loomlight::models::btf
