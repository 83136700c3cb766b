// The fiber BTF source (server/render/btf_capture.h): rays through a periodic fiber patch meet the same fibers
// one period apart, the capture does not depend on its thread count, and the captured BTF's tile mean is
// reciprocal (a physical property of single scattering over a periodic surface; it fails if the images are not
// radiance per unit irradiance on the reference plane, e.g. without the 1 / cos theta_i).
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <numbers>
#include <random>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"
#include "server/api/yarn_rpc.h"
#include "server/models/registry.h"
#include "server/render/btf_capture.h"
#include "server/render/scene.h"
#include "server/yarn/fiber_scene.h"

namespace loomlight {
namespace {

using render::Vec3;

struct Patch {
  std::shared_ptr<const yarn::FiberScene> fibers;
  render::Scene::Tiling tile;
};

// cotton1 woven as cotton_twill, 3 x 3 repeats around the central tile (as CreateBtf lays it out).
const Patch& TwillPatch() {
  static const Patch patch = [] {
    Patch p;
    api::YarnJob job;
    job.limits.max_fibers = 100'000;
    job.limits.max_control_points = 2'000'000;
    job.detail.threads = 2;
    v1::WovenYarnLayout woven;
    woven.mutable_weave()->set_preset("cotton_twill");
    woven.set_repeats_u(3);
    woven.set_repeats_v(3);
    EXPECT_EQ(api::YarnJobOf(models::Registry::Global(), v1::Yarn(), &woven, 0, &job), "");
    const grpc::Status s = api::BuildFiberScene(
        &job, [] { return grpc::Status::OK; }, [](size_t) { return true; }, &p.fibers, nullptr, nullptr);
    EXPECT_TRUE(s.ok()) << s.error_message();
    const double s_u = job.pattern.warps * job.layout.spacing, s_v = job.pattern.picks * job.layout.spacing;
    p.tile = {s_u, s_v, s_u, s_v};
    return p;
  }();
  return patch;
}

// The fiber model (preset cotton), shading each query about its own axis.
const models::PreparedMaterial& Cotton() {
  static const std::unique_ptr<models::PreparedMaterial> material = [] {
    const models::PresetSpec* preset = nullptr;
    const models::Model* model = models::Registry::Global().FindPreset("cotton", &preset);
    auto m = std::make_unique<models::PreparedMaterial>();
    m->model = model;
    m->values = model->PresetValues(*preset);
    m->packed = model->Pack(m->values);
    return m;
  }();
  return *material;
}

Vec3 FromAngles(double theta_deg, double phi_deg) {
  const double t = theta_deg * std::numbers::pi / 180, p = phi_deg * std::numbers::pi / 180;
  return {std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t)};
}

TEST(PeriodicFibers, RaysOnePeriodApartMeetTheSameFibers) {
  const Patch& patch = TwillPatch();
  ASSERT_TRUE(patch.fibers);
  render::Scene scene = render::MakeScene(render::SceneKind::kWovenPatch);
  scene.fibers = patch.fibers;
  scene.tiling = patch.tile;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(0, 1);
  int rays = 0, hits = 0, same = 0, grazing = 0, grazing_hits = 0;
  for (int i = 0; i < 400; ++i) {
    // Downward rays from above the patch, a third of them at 80-85 degrees (they cross several tiles).
    const bool graze = i % 3 == 0;
    const Vec3 d = -1.0 * FromAngles(graze ? 80 + 5 * unit(rng) : 70 * unit(rng), 360 * unit(rng));
    const Vec3 o{patch.tile.x0 + unit(rng) * patch.tile.period_x, patch.tile.y0 + unit(rng) * patch.tile.period_y,
                 double(patch.fibers->upper().z) + 0.01};
    render::Hit first;
    const bool hit = scene.Intersect(o, d, 0, INFINITY, &first);
    ++rays;
    hits += hit;
    grazing += graze;
    grazing_hits += graze && hit;
    const int k = 1 + i % 5, m = -2 + i % 4;  // far outside the patch's own 3 x 3 repeats
    const Vec3 shifted = o + Vec3{k * patch.tile.period_x, m * patch.tile.period_y, 0};
    render::Hit second;
    const bool hit2 = scene.Intersect(shifted, d, 0, INFINITY, &second);
    if (hit == hit2 && (!hit || std::fabs(first.distance - second.distance) < 1e-4 * (1 + first.distance))) ++same;
    // Occlusion agrees with intersection, shifted or not.
    EXPECT_EQ(scene.Occluded(shifted, d, INFINITY), hit2) << i;
  }
  // Float rounding of the shifted origin may flip a ray grazing a fiber's silhouette; nothing else may differ.
  EXPECT_GE(same, rays - 4) << same << " of " << rays;
  // The cloth is dense: almost every ray meets it; grazing ones too (without the tiling they would leave the patch).
  EXPECT_GE(hits, rays * 9 / 10) << hits;
  EXPECT_GE(grazing_hits, grazing * 9 / 10) << grazing_hits << " of " << grazing;
}

// A small grid: normal, 30 and 60 degrees.
models::btf::DirectionGrid SmallGrid() {
  models::btf::DirectionGrid grid;
  grid.rings = {{0, 1}, {30, 6}, {60, 6}};
  EXPECT_EQ(grid.Validate(), "");
  return grid;
}

TEST(BtfCapture, DoesNotDependOnItsThreads) {
  const Patch& patch = TwillPatch();
  const render::BtfCapture capture(patch.fibers, patch.tile, SmallGrid(), 8, 8, 2, 5);
  render::QueryBucket one, two;
  capture.TraceView(7, 0, 64, 1, nullptr, &one);
  capture.TraceView(7, 0, 64, 3, nullptr, &two);
  ASSERT_GT(one.size(), 64u);
  EXPECT_LE(one.size(), capture.MaxQueriesPerView());
  EXPECT_EQ(one.wi, two.wi);
  EXPECT_EQ(one.weight, two.weight);
  EXPECT_EQ(one.tag, two.tag);
  // Pieces of a view are the view's queries, in texel order.
  render::QueryBucket first, second;
  capture.TraceView(7, 0, 20, 2, nullptr, &first);
  capture.TraceView(7, 20, 64, 2, nullptr, &second);
  first.Append(second);
  EXPECT_EQ(first.tag, one.tag);
  EXPECT_EQ(first.axis, one.axis);
}

TEST(BtfCapture, TileMeanIsReciprocal) {
  const Patch& patch = TwillPatch();
  const models::btf::DirectionGrid grid = SmallGrid();
  const size_t n = grid.size();
  constexpr int kTexels = 16, kSamples = 64;
  const render::BtfCapture capture(patch.fibers, patch.tile, grid, kTexels, kTexels, kSamples, 11);
  const render::Evaluator evaluator{&Cotton(), false, false, true};
  const size_t texels = kTexels * kTexels;
  // mean[v][l]: the tile's mean f, view v, light l.
  std::vector<std::vector<double>> mean(n, std::vector<double>(n, 0.0));
  for (size_t v = 0; v < n; ++v) {
    render::QueryBucket bucket;
    capture.TraceView(v, 0, texels, 2, nullptr, &bucket);
    std::vector<double> f;
    render::EvaluateOnHost(evaluator, bucket, &f);
    const std::vector<float> f32(f.begin(), f.end());
    std::vector<float> images(3 * n * texels, 0.0f);
    render::BtfCapture::Accumulate(bucket, f32.data(), images.data());
    for (size_t l = 0; l < n; ++l) {
      double sum = 0;
      for (size_t t = 0; t < texels; ++t) sum += images[3 * (l * texels + t)];  // red
      mean[v][l] = sum / texels;
      EXPECT_TRUE(std::isfinite(mean[v][l]));
      EXPECT_GE(mean[v][l], 0.0);
    }
  }
  // Pairs at different polar angles, a the higher: without the 1 / cos theta_i (or with it twice) every
  // f(view a, light b) / f(view b, light a) would be off by cos(theta_b) / cos(theta_a), 0.87 to 0.5.
  std::vector<double> differences;
  double log_ratio_sum = 0;
  for (size_t a = 0; a < n; ++a)
    for (size_t b = a + 1; b < n; ++b) {
      double wa[3], wb[3];
      grid.Direction(a, wa);
      grid.Direction(b, wb);
      if (wa[2] - wb[2] < 0.1) continue;
      const double m = 0.5 * (mean[a][b] + mean[b][a]);
      ASSERT_GT(mean[a][b], 0.0) << a << "," << b;
      ASSERT_GT(mean[b][a], 0.0) << a << "," << b;
      differences.push_back(std::fabs(mean[a][b] - mean[b][a]) / m);
      log_ratio_sum += std::log(mean[a][b] / mean[b][a]);
    }
  ASSERT_EQ(differences.size(), 48u);
  std::sort(differences.begin(), differences.end());
  const double median = differences[differences.size() / 2], worst = differences.back();
  const double mean_log_ratio = log_ratio_sum / double(differences.size());
  std::printf("tile-mean reciprocity over %zu pairs: relative difference median %.3f, max %.3f; mean log ratio %.4f\n",
              differences.size(), median, worst, mean_log_ratio);
  // Measured (16 x 16 texels, 64 rays each): median 0.058, max 0.28 (glints: noise, both signs), mean log ratio
  // 0.01-0.02 (the far-field fiber's rays start on its axis, the camera's on its surface: not exactly symmetric).
  EXPECT_LT(std::fabs(mean_log_ratio), 0.05);
  EXPECT_LT(median, 0.1);
  EXPECT_LT(worst, 0.4);
}

}  // namespace
}  // namespace loomlight
