// The renderer's estimator (server/render/shading.h): sampling the material as well as the environment, weighed
// by multiple importance sampling, changes the noise and never the expected image. For every registered
// model (its first preset) and a curtain, the sphere under the built-in sky is shaded on the host with MIS and
// with environment sampling alone (the estimator before MIS, with no material density involved): their means
// agree within their noise, and MIS has less of it where the material is glossy.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "server/models/material_plan.h"
#include "server/models/registry.h"
#include "server/render/shading.h"

namespace loomlight {
namespace {

struct Case {
  std::string preset;
  std::string layer;  // a curtain's layer preset, or ""
};

std::vector<Case> Cases() {
  std::vector<Case> cases;
  for (const auto& model : models::Registry::Global().models())
    if (model->fiber_axis_param().empty()) cases.push_back({model->presets().front().name, ""});
  cases.push_back({"polyester_satin_charmeuse_front", ""});
  cases.push_back({"cotton_twill", "cotton_curtain"});
  return cases;
}

std::string CaseName(const ::testing::TestParamInfo<Case>& info) {
  std::string name = info.param.preset + (info.param.layer.empty() ? "" : "_with_" + info.param.layer);
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name;
}

std::shared_ptr<models::PreparedMaterial> Prepare(const std::string& preset_name) {
  const models::PresetSpec* preset = nullptr;
  const models::Model* model = models::Registry::Global().FindPreset(preset_name, &preset);
  EXPECT_NE(model, nullptr) << preset_name;
  auto m = std::make_shared<models::PreparedMaterial>();
  m->model = model;
  m->values = model->PresetValues(*preset);
  m->packed = model->Pack(m->values);
  return m;
}

// Each pixel sample's radiance (R + G + B), by tag = pixel x samples per pixel + sample.
std::vector<double> Shade(const render::RenderSetup& setup, const render::Evaluator& evaluator) {
  const std::vector<render::Evaluator> evaluators = {evaluator};
  const render::ObjectShading shading{0, -1};
  std::vector<render::QueryBucket> buckets(1);
  const uint32_t samples = uint32_t(setup.width) * setup.height * setup.samples_per_pixel;
  std::vector<double> radiance(samples, 0.0);
  render::ShadingPoint point;
  for (uint64_t pixel = 0; pixel < uint64_t(setup.width) * setup.height; ++pixel)
    for (uint32_t s = 0; s < setup.samples_per_pixel; ++s) {
      const uint32_t tag = uint32_t(pixel) * setup.samples_per_pixel + s;
      render::TracePixelSample(setup, pixel, s, &point);
      const render::Rgb direct = point.object < 0 ? point.background : render::AppendQueries(point, shading, evaluators, tag, &buckets);
      radiance[tag] += direct.x + direct.y + direct.z;
    }
  std::vector<double> f;
  render::EvaluateOnHost(evaluator, buckets[0], &f);
  for (size_t q = 0; q < buckets[0].size(); ++q)
    for (int c = 0; c < 3; ++c) radiance[buckets[0].tag[q]] += double(buckets[0].weight[3 * q + c]) * f[3 * q + c];
  for (double r : radiance) EXPECT_TRUE(std::isfinite(r));
  return radiance;
}

// The mean within-pixel variance of the samples: the image's noise (its structure left out).
double PixelNoise(const std::vector<double>& radiance, uint32_t spp) {
  double total = 0;
  const size_t pixels = radiance.size() / spp;
  for (size_t p = 0; p < pixels; ++p) {
    double sum = 0, sum2 = 0;
    for (uint32_t s = 0; s < spp; ++s) {
      sum += radiance[p * spp + s];
      sum2 += radiance[p * spp + s] * radiance[p * spp + s];
    }
    total += (sum2 - sum * sum / spp) / (spp - 1);
  }
  return total / pixels;
}

class MisEstimator : public ::testing::TestWithParam<Case> {};

TEST_P(MisEstimator, SameMeanAsEnvironmentSamplingAlone) {
  const std::shared_ptr<models::PreparedMaterial> material = Prepare(GetParam().preset);
  if (!GetParam().layer.empty()) material->transmission = Prepare(GetParam().layer);
  const bool transmits = material->transmission || material->model->transmission();

  render::RenderSetup setup;
  setup.scene = render::MakeScene(render::SceneKind::kSphere);
  setup.width = setup.height = 48;
  setup.samples_per_pixel = 16;
  setup.seed = 3;
  setup.camera = render::PinholeCamera(setup.scene.default_camera, setup.width, setup.height);
  setup.texture_scale = setup.scene.default_texture_scale;
  auto sky = std::make_shared<render::Environment>(render::Environment::Builtin());
  sky->SetTransform(1, 130);  // the sun in front, so the cloth's highlight faces the camera
  setup.environment = sky;
  setup.object_transmits = {transmits};
  const render::Evaluator evaluator{material.get(), material->model->spatially_varying(), transmits};

  const std::vector<double> light_only = Shade(setup, evaluator);
  setup.object_samplers = {&material->Sampler()};
  const std::vector<double> mis = Shade(setup, evaluator);
  // Both see the same camera rays (same seed): their per-sample differences are lighting noise alone.
  double sum = 0, sum2 = 0, mean_light = 0;
  const size_t n = mis.size();
  for (size_t i = 0; i < n; ++i) {
    const double d = mis[i] - light_only[i];
    sum += d;
    sum2 += d * d;
    mean_light += light_only[i] / n;
  }
  const double difference = sum / n, standard_error = std::sqrt(std::max(0.0, sum2 / n - difference * difference) / n);
  ASSERT_GT(mean_light, 0);
  EXPECT_NEAR(difference, 0.0, 4.5 * standard_error + 1e-4 * mean_light)
      << "mean radiance " << mean_light << ", MIS minus environment sampling " << difference << " +- " << standard_error;
  // Material sampling may add a little noise to a diffuse-looking cloth, never much.
  const double noise_light = PixelNoise(light_only, setup.samples_per_pixel), noise_mis = PixelNoise(mis, setup.samples_per_pixel);
  EXPECT_LT(noise_mis, 1.25 * noise_light);
  std::printf("mean %.5f, MIS - environment sampling %.2e +- %.2e; pixel variance %.3e with MIS, %.3e without\n",
              mean_light, difference, standard_error, noise_mis, noise_light);
}

INSTANTIATE_TEST_SUITE_P(Registry, MisEstimator, ::testing::ValuesIn(Cases()), CaseName);

}  // namespace
}  // namespace loomlight
