// Tabulated BRDFs (server/models/tabulated_brdf.h) against the analytic model they are built from.
#include "server/models/tabulated_brdf.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>

#include "server/models/material_plan.h"
#include "server/models/registry.h"
#include "tests/testing.h"

namespace loomlight::models {
namespace {

std::unique_ptr<PreparedMaterial> Prepare(const std::string& preset_name) {
  const PresetSpec* preset = nullptr;
  const Model* model = Registry::Global().FindPreset(preset_name, &preset);
  EXPECT_NE(model, nullptr) << preset_name;
  auto m = std::make_unique<PreparedMaterial>();
  m->model = model;
  m->values = model->PresetValues(*preset);
  m->packed = model->Pack(m->values);
  return m;
}

// A coarse budget: a table in a second or two (the tests check the mechanism, not the default's accuracy).
TabulationBudget CoarseBudget() {
  TabulationBudget b;
  b.nodes_per_lobe = 1.5;
  b.difference_nodes = 12;
  b.error_pairs = 20000;
  return b;
}

std::shared_ptr<const TabulatedBrdf> BuildOrFail(const PreparedMaterial& m, const TabulationBudget& b) {
  std::shared_ptr<const TabulatedBrdf> t;
  const std::string error = TabulatedBrdf::Build(m, b, nullptr, &t);
  EXPECT_EQ(error, "");
  return t;
}

// n pairs drawn cosine-weighted in wi and in wo (as the table's own error measurement draws them), from a
// generator of the test's own.
void CosinePairs(size_t n, unsigned seed, std::vector<float>* wi, std::vector<float>* wo) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  wi->resize(3 * n);
  wo->resize(3 * n);
  for (std::vector<float>* w : {wi, wo})
    for (size_t q = 0; q < n; ++q) {
      const double r2 = u(rng), phi = 2 * M_PI * u(rng);
      (*w)[3 * q] = static_cast<float>(std::sqrt(r2) * std::cos(phi));
      (*w)[3 * q + 1] = static_cast<float>(std::sqrt(r2) * std::sin(phi));
      (*w)[3 * q + 2] = static_cast<float>(std::sqrt(1 - r2));
    }
}

TEST(TabulatedBrdf, MatchesTheAnalyticModelWithinItsMeasuredErrorOnFreshPairs) {
  for (const char* preset : {"silk_shot", "velvet"}) {
    SCOPED_TRACE(preset);
    auto m = Prepare(preset);
    auto t = BuildOrFail(*m, CoarseBudget());
    ASSERT_NE(t, nullptr);
    // A coarse table errs measurably, so the comparison below is not of two zeros.
    EXPECT_GT(t->measured_error(), 1e-3);
    const size_t n = 50000;
    std::vector<float> wi, wo;
    CosinePairs(n, 4242, &wi, &wo);
    std::vector<double> ref(3 * n), tab(3 * n);
    m->model->ReferenceEval(m->packed, wi.data(), wo.data(), nullptr, n, ref.data());
    t->Evaluate(wi.data(), wo.data(), n, tab.data());
    for (int c = 0; c < 3; ++c) {
      double diff = 0, sum = 0;
      for (size_t q = 0; q < n; ++q) {
        diff += std::fabs(tab[3 * q + c] - ref[3 * q + c]);
        sum += std::fabs(ref[3 * q + c]);
      }
      // Both are estimates of the same expectation from 20,000 and 50,000 pairs: 25% covers their sampling
      // spread (the narrow lobe is met by few pairs), not a different error.
      EXPECT_LE(diff / sum, 1.25 * t->per_channel_error()[c]) << "channel " << c;
      EXPECT_GE(diff / sum, 0.75 * t->per_channel_error()[c]) << "channel " << c;
    }
  }
}

TEST(TabulatedBrdf, FiniteAndNonNegativeAtGrazingAnglesAndTheGridsEdges) {
  auto m = Prepare("velvet");  // vertical tangents: its lobes reach the horizon
  auto t = BuildOrFail(*m, CoarseBudget());
  ASSERT_NE(t, nullptr);
  std::vector<std::array<double, 6>> pairs;
  for (double z : {1e-6, 1e-4, 1e-3, 0.05, 0.5, 1.0}) {
    const double s = std::sqrt(1 - z * z);
    for (double phi : {0.0, 0.3, M_PI / 2, 2.0, M_PI, 4.0, 3 * M_PI / 2}) {
      const double x = s * std::cos(phi), y = s * std::sin(phi);
      pairs.push_back({x, y, z, x, y, z});       // wi = wo
      pairs.push_back({x, y, z, -x, -y, z});     // wo the mirror of wi: h is the normal
      pairs.push_back({x, y, z, 0, 0, 1});       // one grazing, one at the normal
      pairs.push_back({x, y, z, -y, x, 1e-6});   // both grazing, crossed: h near the horizon (eta = +-90 degrees)
      pairs.push_back({x, y, z, x, y, 1e-6});
    }
  }
  for (const auto& p : pairs) {
    double wi[3] = {p[0], p[1], p[2]}, wo[3] = {p[3], p[4], p[5]};
    for (double* w : {wi, wo}) {
      const double norm = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
      for (int c = 0; c < 3; ++c) w[c] /= norm;
    }
    const std::array<double, 3> f = t->Evaluate(wi, wo);
    for (double v : f) {
      EXPECT_TRUE(std::isfinite(v)) << wi[0] << " " << wi[1] << " " << wi[2] << " / " << wo[0] << " " << wo[1] << " " << wo[2];
      EXPECT_GE(v, 0);
    }
  }
  // At or below the horizon, and wi = -wo (one of them below): 0, as the analytic model.
  const double horizontal[3] = {1, 0, 0}, up[3] = {0, 0, 1}, down[3] = {0, 0, -1};
  const double below[3] = {0.6, 0, -0.8}, opposite[3] = {-0.6, 0, 0.8};
  for (const auto& [a, b] : {std::pair{horizontal, up}, std::pair{up, horizontal}, std::pair{up, down},
                             std::pair{below, opposite}, std::pair{opposite, below}})
    for (double v : t->Evaluate(a, b)) EXPECT_EQ(v, 0);
}

// silk_shot's threads (x: tangents in the x-z plane; y: flat) make f symmetric under y -> -y of both directions. The
// grid is symmetric about eta_y = 0 and chi = 0, which the mirror swaps, so the table keeps the model's symmetry.
// (The microcylinder is not reciprocal: no model that declares a lobe width is, so the table does not fold by it.)
TEST(TabulatedBrdf, KeepsTheModelsMirrorSymmetry) {
  auto m = Prepare("silk_shot");
  auto t = BuildOrFail(*m, CoarseBudget());
  ASSERT_NE(t, nullptr);
  const size_t n = 2000;
  std::vector<float> wi, wo;
  CosinePairs(n, 9, &wi, &wo);
  std::vector<float> mi = wi, mo = wo;
  for (size_t q = 0; q < n; ++q) mi[3 * q + 1] = -wi[3 * q + 1], mo[3 * q + 1] = -wo[3 * q + 1];
  std::vector<double> ref(3 * n), ref_mirrored(3 * n), tab(3 * n), tab_mirrored(3 * n);
  m->model->ReferenceEval(m->packed, wi.data(), wo.data(), nullptr, n, ref.data());
  m->model->ReferenceEval(m->packed, mi.data(), mo.data(), nullptr, n, ref_mirrored.data());
  t->Evaluate(wi.data(), wo.data(), n, tab.data());
  t->Evaluate(mi.data(), mo.data(), n, tab_mirrored.data());
  for (size_t i = 0; i < 3 * n; ++i) {
    ASSERT_NEAR(ref_mirrored[i], ref[i], 1e-9 * ref[i] + 1e-12) << "the model's own symmetry, query " << i / 3;
    // The table's nodes come from the model's float build: mirrored nodes agree to float rounding.
    EXPECT_NEAR(tab_mirrored[i], tab[i], 1e-4 * tab[i] + 1e-9) << "query " << i / 3;
  }
}

TEST(TabulatedBrdf, ABudgetTooSmallRefusesAndTheDefaultBoundsTheBytes) {
  auto m = Prepare("silk_shot");
  TabulationBudget small = CoarseBudget();
  small.max_bytes = 1 << 20;
  std::shared_ptr<const TabulatedBrdf> t;
  const std::string error = TabulatedBrdf::Build(*m, small, nullptr, &t);
  EXPECT_NE(error.find("over the budget of 1048576 bytes"), std::string::npos) << error;
  EXPECT_EQ(t, nullptr);
  // Every preset's grid under the default budget fits it, or the preset is refused.
  const TabulationBudget budget;
  for (const PresetSpec& preset : Registry::Global().FindModel("microcylinder")->presets()) {
    auto p = Prepare(preset.name);
    TabulationGrid grid;
    const std::string plan = TabulatedBrdf::PlanGrid(*p, budget, &grid);
    if (plan.empty())
      EXPECT_LE(grid.bytes(), budget.max_bytes) << preset.name;
    else
      EXPECT_NE(plan.find("over the budget"), std::string::npos) << plan;
  }
}

TEST(TabulatedBrdf, ModelsWithoutALobeWidthOrWithTransmissionAreRefused) {
  std::shared_ptr<const TabulatedBrdf> t;
  EXPECT_NE(TabulatedBrdf::Build(*Prepare("cotton_twill"), CoarseBudget(), nullptr, &t).find("declares no lobe width"),
            std::string::npos);
  const Model* thin = Registry::Global().FindModel("thin_layer");
  ASSERT_NE(thin, nullptr);
  PreparedMaterial layer;
  layer.model = thin;
  layer.values = thin->DefaultValues();
  layer.packed = thin->Pack(layer.values);
  EXPECT_NE(TabulatedBrdf::Build(layer, CoarseBudget(), nullptr, &t).find("not a reflection model"), std::string::npos);
  EXPECT_EQ(t, nullptr);
}

TEST(TabulatedBrdf, StopStopsTheBuild) {
  auto m = Prepare("silk_shot");
  std::shared_ptr<const TabulatedBrdf> t;
  EXPECT_EQ(TabulatedBrdf::Build(*m, CoarseBudget(), [] { return true; }, &t), "stopped");
  EXPECT_EQ(t, nullptr);
  // Asked between chunks of nodes: a stop on the third question ends the build there, with chunks left.
  TabulationGrid grid;
  ASSERT_EQ(TabulatedBrdf::PlanGrid(*m, CoarseBudget(), &grid), "");
  ASSERT_GT(grid.nodes(), size_t{4} << 15);  // more than three chunks of 2^15 nodes
  int asked = 0;
  EXPECT_EQ(TabulatedBrdf::Build(*m, CoarseBudget(), [&] { return ++asked == 3; }, &t), "stopped");
  EXPECT_EQ(asked, 3);
  EXPECT_EQ(t, nullptr);
}

// The device kernel reads the same table as the host's Evaluate: the same values to float rounding (fp32) or
// nearly exactly (fp64).
TEST(TabulatedBrdf, DeviceKernelMatchesTheHostEvaluation) {
  auto m = Prepare("silk_shot");
  auto t = BuildOrFail(*m, CoarseBudget());
  ASSERT_NE(t, nullptr);
  runtime::ClRuntime& rt = testing::SharedRuntime();
  std::string error;
  ASSERT_TRUE(rt.BuildPrograms(TabulatedBrdf::KernelRegistry(), &error)) << error;
  // The kernel model's own smallest table warms it as every model's default material does.
  ASSERT_TRUE(rt.Warm(TabulatedBrdf::KernelRegistry(), &error)) << error;
  const size_t n = 5000;
  std::vector<float> wi, wo;
  CosinePairs(n, 77, &wi, &wo);
  // Some pairs at the horizon, below it and straight back, as a launch may carry.
  wi[0] = 1, wi[1] = 0, wi[2] = 0;
  wo[3] = 0.6f, wo[4] = 0, wo[5] = -0.8f;
  for (int c = 0; c < 3; ++c) wo[6 + c] = wi[6 + c];
  std::vector<double> host(3 * n);
  t->Evaluate(wi.data(), wo.data(), n, host.data());
  double scale = 0;
  for (double v : host) scale = std::max(scale, v);
  for (bool fp64 : {false, true}) {
    if (fp64 && !rt.has_fp64()) continue;
    const std::vector<double> device = testing::RunKernel(TabulatedBrdf::KernelModel(), t->packed(), fp64, wi, wo);
    ASSERT_EQ(device.size(), host.size());
    for (size_t i = 0; i < host.size(); ++i)
      ASSERT_NEAR(device[i], host[i], (fp64 ? 1e-9 : 1e-4) * std::max(host[i], 1e-3 * scale))
          << (fp64 ? "fp64" : "fp32") << " query " << i / 3;
  }
}

}  // namespace
}  // namespace loomlight::models
