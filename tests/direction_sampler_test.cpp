// Importance sampling (server/models/direction_sampler.h), for every preset of every registered model and a
// curtain, as pbrt-v4's and Mitsuba 3's BSDF tests do: a chi-square test of the sampled directions against the
// density the sampler reports, the density integrating to one, and f |cos| / pdf carrying the material's
// albedo (the sampled mean against a quadrature of f |cos| over the sphere).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>

#include "server/models/cdf.h"
#include "server/models/direction_sampler.h"
#include "server/models/material_plan.h"
#include "server/models/registry.h"

namespace loomlight {
namespace {

// CdfGuide (server/models/cdf.h) must find exactly SearchCdf's cell and remainder: empty cells, a heavy spike,
// trailing zeros, float sums, targets on bucket edges and at the very top, and any bucket count.
template <class T>
void ExpectGuideMatchesSearch(const std::vector<T>& cdf, int buckets, std::mt19937_64& rng) {
  const int n = int(cdf.size()) - 1;
  const models::CdfGuide guide(cdf.data(), n, buckets);
  const double total = double(cdf[n]);
  std::vector<double> targets;
  std::uniform_real_distribution<double> u01(0, 1);
  for (int k = 0; k < 4000; ++k) targets.push_back(u01(rng) * total);
  for (int g = 0; g <= buckets; ++g) {
    const double edge = double(g) * total / buckets;
    targets.insert(targets.end(), {edge, std::nextafter(edge, 0.0), std::nextafter(edge, 2 * total + 1)});
  }
  for (const T& c : cdf) targets.insert(targets.end(), {double(c), std::nextafter(double(c), 0.0)});
  targets.insert(targets.end(), {0.0, total, std::nextafter(total, 0.0), 2 * total});
  for (double t : targets) {
    double want_r = -1, got_r = -2;
    const int want = models::SearchCdf(cdf.data(), n, t, &want_r);
    const int got = guide.Search(cdf.data(), n, t, &got_r);
    ASSERT_EQ(got, want) << "target " << t << " of " << total << ", " << buckets << " buckets";
    ASSERT_EQ(got_r, want_r) << "target " << t;
  }
}

TEST(CdfGuide, FindsWhatBinarySearchFinds) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u01(0, 1);
  for (int n : {1, 2, 7, 64, 1000}) {
    std::vector<double> cdf(size_t(n) + 1, 0.0);
    std::vector<float> cdf_f(size_t(n) + 1, 0.0f);
    for (int i = 0; i < n; ++i) {
      double w = u01(rng) < 0.3 ? 0.0 : u01(rng);  // empty cells
      if (i == n / 3) w = 1e4;                      // a spike: most targets in one cell
      if (i >= n - n / 5) w = 0;                    // trailing zeros
      cdf[size_t(i) + 1] = cdf[size_t(i)] + w;
      cdf_f[size_t(i) + 1] = cdf_f[size_t(i)] + float(w);
    }
    for (int buckets : {1, 3, std::max(1, n / 4), n, 4 * n}) {
      ExpectGuideMatchesSearch(cdf, buckets, rng);
      ExpectGuideMatchesSearch(cdf_f, buckets, rng);
    }
  }
  // No weight at all: the guide is empty and searches as SearchCdf does.
  ExpectGuideMatchesSearch(std::vector<double>(9, 0.0), 8, rng);
}


using models::DirectionSampler;
using Dir = DirectionSampler::Dir;
constexpr double kPi = std::numbers::pi;

struct Case {
  const models::Model* model;
  const models::PresetSpec* preset;
  const models::PresetSpec* layer;  // a curtain's thin layer, or null
};

std::vector<Case> Cases() {
  std::vector<Case> cases;
  const models::Registry& registry = models::Registry::Global();
  for (const auto& model : registry.models())
    for (const models::PresetSpec& preset : model->presets()) cases.push_back({model.get(), &preset, nullptr});
  const models::PresetSpec *top = nullptr, *layer = nullptr;
  const models::Model* woven = registry.FindPreset("cotton_twill", &top);
  registry.FindPreset("cotton_curtain", &layer);
  if (woven && layer) cases.push_back({woven, top, layer});
  return cases;
}

void PrintTo(const Case& c, std::ostream* os) {
  *os << c.model->name() << "/" << c.preset->name << (c.layer ? " with a curtain layer" : "");
}

std::string CaseName(const ::testing::TestParamInfo<Case>& info) {
  std::string name = info.param.model->name() + "_" + info.param.preset->name + (info.param.layer ? "_curtain" : "");
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name;
}

std::shared_ptr<models::PreparedMaterial> Prepare(const models::Model& model, const models::PresetSpec& preset) {
  auto m = std::make_shared<models::PreparedMaterial>();
  m->model = &model;
  m->values = model.PresetValues(preset);
  m->packed = model.Pack(m->values);
  return m;
}

Dir FromZPhi(double z, double phi) {
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  return {r * std::cos(phi), r * std::sin(phi), z};
}

class Sampling : public ::testing::TestWithParam<Case> {
 protected:
  void SetUp() override {
    const Case& c = GetParam();
    material_ = Prepare(*c.model, *c.preset);
    if (c.layer) {
      const models::PresetSpec* p = nullptr;
      const models::Model* layer = models::Registry::Global().FindPreset(c.layer->name, &p);
      material_->transmission = Prepare(*layer, *p);
    }
    sampler_ = std::make_unique<DirectionSampler>(*material_);
  }
  // The directions wo is tested at: near the normal, oblique, grazing; fibers also from the other side.
  std::vector<Dir> Outgoing() const {
    std::vector<Dir> wo = {FromZPhi(0.95, 0.3), FromZPhi(0.5, 2.0), FromZPhi(0.12, 4.0)};
    if (sampler_->sphere()) wo.push_back(FromZPhi(-0.6, 1.0));
    return wo;
  }
  // f (RGB mean) at n pairs, from the material's native build, as the sampler's table was.
  std::vector<double> F(const std::vector<Dir>& wi, const Dir& wo) const {
    std::vector<float> i, o, uv;
    for (const Dir& w : wi) {
      i.insert(i.end(), {float(w[0]), float(w[1]), float(w[2])});
      o.insert(o.end(), {float(wo[0]), float(wo[1]), float(wo[2])});
    }
    std::vector<double> rgb(3 * wi.size());
    models::EvaluateNative(models::EvaluationPlan(*material_, i.data(), o.data(), nullptr, wi.size()), rgb.data());
    std::vector<double> f(wi.size());
    for (size_t q = 0; q < wi.size(); ++q) f[q] = (rgb[3 * q] + rgb[3 * q + 1] + rgb[3 * q + 2]) / 3;
    return f;
  }
  std::shared_ptr<models::PreparedMaterial> material_;
  std::unique_ptr<DirectionSampler> sampler_;
};

// Histogram bins uniform in (cos theta, phi) over the sphere: equal solid angle.
constexpr int kBinsZ = 16, kBinsPhi = 32;

int BinOf(const Dir& w) {
  const int z = std::clamp(int((w[2] + 1) / 2 * kBinsZ), 0, kBinsZ - 1);
  double phi = std::atan2(w[1], w[0]);
  if (phi < 0) phi += 2 * kPi;
  return z * kBinsPhi + std::clamp(int(phi / (2 * kPi) * kBinsPhi), 0, kBinsPhi - 1);
}

// At each wo, with the cosine floor the Sample RPC draws with and the smaller one the renderer weighs by MIS.
TEST_P(Sampling, HistogramMatchesDensity) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  constexpr int kSamples = 200000, kSub = 64;  // fine: table cells do not align with the bins
  std::vector<std::pair<Dir, double>> cases;
  for (const Dir& wo : Outgoing())
    for (const double fraction : {DirectionSampler::kCosineFraction, DirectionSampler::kMisCosineFraction})
      cases.push_back({wo, fraction});
  for (const auto& [wo, fraction] : cases) {
    SCOPED_TRACE("cosine fraction " + std::to_string(fraction));
    const DirectionSampler::Conditional density = sampler_->At(wo, fraction);
    // Expected counts: the density integrated over each bin on a kSub x kSub midpoint grid.
    std::vector<double> expected(kBinsZ * kBinsPhi, 0.0);
    const double dz = 2.0 / kBinsZ / kSub, dphi = 2 * kPi / kBinsPhi / kSub;
    double total = 0;
    for (int b = 0; b < kBinsZ * kBinsPhi; ++b)
      for (int j = 0; j < kSub; ++j)
        for (int i = 0; i < kSub; ++i) {
          const double z = -1 + ((b / kBinsPhi) * kSub + j + 0.5) * dz;
          const double phi = ((b % kBinsPhi) * kSub + i + 0.5) * dphi;
          const double p = density.Pdf(FromZPhi(z, phi)) * dz * dphi;
          expected[b] += p;
          total += p;
        }
    EXPECT_NEAR(total, 1.0, 2e-3) << "the density's integral, wo.z " << wo[2];
    std::vector<double> observed(expected.size(), 0.0);
    for (int s = 0; s < kSamples; ++s) {
      const DirectionSampler::Sample sample = density.Draw(u(rng), u(rng), u(rng));
      ASSERT_GT(sample.pdf, 0);
      ASSERT_NEAR(sample.pdf, density.Pdf(sample.wi), 1e-9 * sample.pdf) << "Draw and Pdf disagree";
      ASSERT_NEAR(std::sqrt(sample.wi[0] * sample.wi[0] + sample.wi[1] * sample.wi[1] + sample.wi[2] * sample.wi[2]), 1, 1e-9);
      observed[BinOf(sample.wi)] += 1;
    }
    // Pearson's chi-square, bins with fewer than 5 expected merged (pbrt-v4's chi2test).
    double chi2 = 0, pooled_expected = 0, pooled_observed = 0;
    int dof = -1;
    for (size_t b = 0; b < expected.size(); ++b) {
      const double e = expected[b] * kSamples;
      if (e < 5) {
        pooled_expected += e;
        pooled_observed += observed[b];
        continue;
      }
      chi2 += (observed[b] - e) * (observed[b] - e) / e;
      ++dof;
    }
    if (pooled_expected >= 5) {
      chi2 += (pooled_observed - pooled_expected) * (pooled_observed - pooled_expected) / pooled_expected;
      ++dof;
    } else {
      EXPECT_LT(pooled_observed, 30) << "samples where the density is ~0";
    }
    // The chi-square quantile at 1 - 1e-4 (Wilson-Hilferty), so ~200 such tests rarely fail by chance.
    const double z = 3.719, k = std::max(dof, 1);
    const double limit = k * std::pow(1 - 2 / (9 * k) + z * std::sqrt(2 / (9 * k)), 3);
    EXPECT_LT(chi2, limit) << "wo.z " << wo[2] << ", " << dof << " degrees of freedom";
  }
}

TEST_P(Sampling, WeightsCarryTheAlbedo) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  for (const Dir& wo : Outgoing()) {
    // Quadrature: f |cos| on a fine midpoint grid (equal-area cells) over the sampler's domain: the sphere, or
    // wo's hemisphere (a reflection model's f below it is never used).
    constexpr int kZ = 256, kPhi = 512;
    const double z_min = sampler_->sphere() ? -1 : 0, span = sampler_->sphere() ? 4 * kPi : 2 * kPi;
    std::vector<Dir> grid;
    for (int j = 0; j < kZ; ++j)
      for (int i = 0; i < kPhi; ++i)
        grid.push_back(FromZPhi(z_min + (j + 0.5) * (1 - z_min) / kZ, (i + 0.5) * 2 * kPi / kPhi));
    const std::vector<double> fg = F(grid, wo);
    double albedo = 0;
    for (size_t q = 0; q < grid.size(); ++q) albedo += fg[q] * sampler_->Cosine(grid[q]);
    albedo *= span / grid.size();

    constexpr int kSamples = 40000;
    std::vector<Dir> wi;
    std::vector<double> pdf;
    for (int s = 0; s < kSamples; ++s) {
      const DirectionSampler::Sample sample = sampler_->Draw(wo, u(rng), u(rng), u(rng));
      wi.push_back(sample.wi);
      pdf.push_back(sample.pdf);
    }
    const std::vector<double> f = F(wi, wo);
    double sum = 0, sum2 = 0;
    for (int s = 0; s < kSamples; ++s) {
      const double w = f[s] * sampler_->Cosine(wi[s]) / pdf[s];
      ASSERT_TRUE(std::isfinite(w) && w >= 0);
      sum += w;
      sum2 += w * w;
    }
    const double mean = sum / kSamples, sd = std::sqrt(std::max(0.0, sum2 / kSamples - mean * mean) / kSamples);
    // 5 standard errors, plus the quadrature's own error on peaked lobes (1% of the albedo).
    EXPECT_NEAR(mean, albedo, 5 * sd + 0.01 * albedo + 1e-6) << "wo.z " << wo[2];
    // The table follows the lobes: one sample's weight deviates from the mean by at most ~2x the mean (0.04-2.0
    // over the presets; fibers' narrow R cones are the hardest).
    const double relative_deviation = sd * std::sqrt(double(kSamples)) / std::max(mean, 1e-12);
    EXPECT_LT(relative_deviation, 2.5) << "wo.z " << wo[2];
    std::printf("wo.z %+.2f: albedo %.4f, sampled %.4f, one sample's relative deviation %.2f\n", wo[2], albedo, mean,
                relative_deviation);
  }
}

INSTANTIATE_TEST_SUITE_P(Registry, Sampling, ::testing::ValuesIn(Cases()), CaseName);

}  // namespace
}  // namespace loomlight
