#include "server/render/btf_capture.h"

#include <algorithm>
#include <thread>

#include "server/render/sample_points.h"
#include "server/yarn/fiber_scene.h"

namespace loomlight::render {

BtfCapture::BtfCapture(std::shared_ptr<const yarn::FiberScene> fibers, const Scene::Tiling& tile,
                       const models::btf::DirectionGrid& grid, int width, int height, int samples, uint64_t seed)
    : tile_(tile), grid_(grid), width_(width), height_(height), samples_(std::max(samples, 1)) {
  RenderSetup& s = setup_;
  s.scene = MakeScene(SceneKind::kWovenPatch);
  s.scene.fibers = fibers;
  s.scene.tiling = tile;
  s.fiber_shadows = yarn::ShadowMethod::kTraced;
  s.fiber_occlusion = yarn::OcclusionMethod::kTraced;
  s.ambient = 0;
  s.environment = nullptr;
  s.seed = seed;
  s.lights.clear();
  for (size_t l = 0; l < grid.size(); ++l) {
    double w[3];
    grid.Direction(l, w);
    s.lights.push_back({Light::Type::kDirectional, {w[0], w[1], w[2]}, {}, {1, 1, 1}, {}, {}, 0, 0});
    inverse_cosine_.push_back(1 / w[2]);  // grid directions keep theta <= 89 degrees: w[2] >= 0.017
  }
  ray_start_z_ = double(fibers->upper().z) + 1e-3 * std::max(tile.period_x, tile.period_y);
}

size_t BtfCapture::MaxQueriesPerView() const {
  return size_t(width_) * height_ * size_t(samples_) * grid_.size();
}

void BtfCapture::TraceView(size_t view, size_t begin, size_t end, int threads, const std::function<bool()>& stop,
                           QueryBucket* bucket) const {
  bucket->Clear();
  if (end <= begin) return;
  const size_t count = end - begin;
  const size_t n = std::clamp<size_t>(size_t(std::max(threads, 1)), 1, count);
  const auto split = [&](size_t t) { return begin + count * t / n; };
  std::vector<QueryBucket> parts(n - 1);
  std::vector<std::thread> workers;
  for (size_t t = 1; t < n; ++t)
    workers.emplace_back([&, t] { TraceTexels(view, split(t), split(t + 1), stop, &parts[t - 1]); });
  TraceTexels(view, split(0), split(1), stop, bucket);
  for (std::thread& w : workers) w.join();
  for (const QueryBucket& part : parts) bucket->Append(part);
}

void BtfCapture::TraceTexels(size_t view, size_t begin, size_t end, const std::function<bool()>& stop,
                             QueryBucket* bucket) const {
  double w[3];
  grid_.Direction(view, w);
  const Vec3 wo{w[0], w[1], w[2]};
  const double to_start = ray_start_z_ / wo.z;  // from the plane z = 0 up to the start height, along wo
  const size_t texels = size_t(width_) * height_;
  const ObjectShading shading{0, -1};
  const std::vector<Evaluator> evaluators{{nullptr, false, false, true}};
  std::vector<QueryBucket> one(1);
  ShadingPoint point;
  for (size_t t = begin; t < end; ++t) {
    if (stop && stop()) return;
    const double iu = double(t % size_t(width_)), iv = double(t / size_t(width_));
    for (int s = 0; s < samples_; ++s) {
      // The texel's samples: Owen-scrambled Sobol points over its cell (a (0, k, 2)-net for 2^k samples).
      const SamplePoints points(setup_.seed ^ (uint64_t(view) << 40), t, uint32_t(s));
      const std::array<double, 2> u = points.Get2D(0);
      const Vec3 on_plane{tile_.x0 + (iu + u[0]) / width_ * tile_.period_x,
                          tile_.y0 + (iv + u[1]) / height_ * tile_.period_y, 0};
      TraceRay(setup_, on_plane + to_start * wo, -1.0 * wo, 0, points, &point);
      if (point.object < 0) continue;
      one[0].Clear();
      AppendQueries(point, shading, evaluators, 0, &one);
      // One query per light sample on a fiber, in order (AppendQueries keeps every one: a fiber scatters from the
      // whole sphere), and every sample from a grid light (the setup has no environment).
      if (one[0].size() != point.lights.size()) continue;
      // Each query's weight over samples x cos theta_i (the light of its index), tagged with its image value.
      for (size_t q = 0; q < point.lights.size(); ++q) {
        const int light = point.lights[q].light;
        const float scale = float(inverse_cosine_[size_t(light)] / samples_);
        for (int c = 0; c < 3; ++c) one[0].weight[3 * q + c] *= scale;
        one[0].tag[q] = uint32_t(size_t(light) * texels + t);
      }
      bucket->Append(one[0]);
    }
  }
}

void BtfCapture::Accumulate(const QueryBucket& bucket, const float* f, float* view_images) {
  for (size_t q = 0; q < bucket.size(); ++q) {
    float* out = view_images + 3 * size_t(bucket.tag[q]);
    for (int c = 0; c < 3; ++c) out[c] += f[3 * q + c] * bucket.weight[3 * q + c];
  }
}

}  // namespace loomlight::render
