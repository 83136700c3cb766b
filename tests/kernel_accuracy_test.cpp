// The OpenCL kernels against the double reference (the same source compiled as C++): 100,000 random
// direction pairs per preset plus the hard cases, in float32 and float64, and the native float baseline.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <iterator>
#include <random>

#include "server/models/registry.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using models::Model;

const Model& Microcylinder() { return *models::Registry::Global().FindModel("microcylinder"); }

using accuracy::Pairs;
using accuracy::RandomPairs;

std::vector<double> Reference(const models::PackedMaterial& m, const Pairs& p) {
  std::vector<double> f(p.wi.size());
  Microcylinder().ReferenceEval(m, p.wi.data(), p.wo.data(), nullptr, p.wi.size() / 3, f.data());
  return f;
}

void ExpectFiniteNonNegative(const std::vector<double>& f, const std::string& what) {
  for (size_t i = 0; i < f.size(); ++i)
    ASSERT_TRUE(std::isfinite(f[i]) && f[i] >= 0) << what << " query " << i / 3 << " f " << f[i];
}

class PresetAccuracy : public ::testing::TestWithParam<std::string> {};

// float32 carries 6e-8 relative rounding per operation and the model chains ~100 of them per tangent
// sample, so 1e-4 at the 99th percentile leaves room for the worst conditioned (narrow-lobe) samples
// while still catching any formula that cancels; f <= 1e-4 is below what any display or table resolves.
constexpr double kFloor = 1e-4;
constexpr double kP99Fp32 = 1e-4;
// The max is dominated by narrow Gaussian lobes evaluated far in their tails (exp of a large argument
// amplifies the argument's float rounding): bounded, not tiny.
constexpr double kMaxFp32 = 1e-3;
// The fp64 kernel runs the same double arithmetic (PoCL may contract to FMA): agreement to 1e-9.
constexpr double kMaxFp64 = 1e-9;

TEST_P(PresetAccuracy, KernelsMatchDoubleReference) {
  const models::PresetSpec* preset = nullptr;
  const Model* model = models::Registry::Global().FindPreset(GetParam(), &preset);
  ASSERT_NE(model, nullptr);
  const models::PackedMaterial m = model->Pack(model->PresetValues(*preset));
  const Pairs p = RandomPairs(100000, 1234);
  const std::vector<double> ref = Reference(m, p);
  ExpectFiniteNonNegative(ref, "reference");

  const std::vector<double> f32 = testing::RunKernel(*model, m, false, p.wi, p.wo);
  ExpectFiniteNonNegative(f32, "fp32 kernel");
  const accuracy::Accuracy e32 = accuracy::Compare(f32, ref, kFloor);
  std::printf("%-34s fp32   %s\n", GetParam().c_str(), e32.ToString().c_str());
  EXPECT_GT(e32.count, 100000u);  // most of the 300,000 values are above the floor
  EXPECT_LE(e32.p99, kP99Fp32);
  EXPECT_LE(e32.max, kMaxFp32);

  const std::vector<double> f64 = testing::RunKernel(*model, m, true, p.wi, p.wo);
  const accuracy::Accuracy e64 = accuracy::Compare(f64, ref, 0.0);
  std::printf("%-34s fp64   %s\n", GetParam().c_str(), e64.ToString().c_str());
  EXPECT_LE(e64.max, kMaxFp64);

  std::vector<float> native(ref.size());
  model->NativeEval(m, p.wi.data(), p.wo.data(), nullptr, p.wi.size() / 3, native.data());
  const accuracy::Accuracy en =
      accuracy::Compare(std::vector<double>(native.begin(), native.end()), ref, kFloor);
  std::printf("%-34s native %s\n", GetParam().c_str(), en.ToString().c_str());
  EXPECT_LE(en.p99, kP99Fp32);
}

INSTANTIATE_TEST_SUITE_P(Presets, PresetAccuracy,
                         ::testing::Values("linen_plain", "silk_crepe_de_chine", "polyester_satin_charmeuse_front",
                                           "polyester_satin_charmeuse_back", "silk_shot", "velvet"));

void Push(Pairs& p, double ix, double iy, double iz, double ox, double oy, double oz) {
  const double li = std::sqrt(ix * ix + iy * iy + iz * iz), lo = std::sqrt(ox * ox + oy * oy + oz * oz);
  p.wi.insert(p.wi.end(), {float(ix / li), float(iy / li), float(iz / li)});
  p.wo.insert(p.wo.end(), {float(ox / lo), float(oy / lo), float(oz / lo)});
}

// SPEC.md section 2 hard cases, for every preset and with gamma_s = 0.5 degrees.
Pairs HardCases(const models::PackedMaterial& m) {
  Pairs p;
  std::mt19937 rng(99);
  for (int k = 0; k < 500; ++k) {
    float a[3], b[3];
    accuracy::RandomHemisphere(rng, a);
    accuracy::RandomHemisphere(rng, b);
    Push(p, a[0], a[1], a[2], a[0], a[1], a[2]);       // wi = wo
    Push(p, -a[0], -a[1], a[2], a[0], a[1], a[2]);     // mirror pair
    Push(p, a[0], a[1], 1e-6, b[0], b[1], b[2]);       // grazing light, n.wi = 1e-6
    Push(p, b[0], b[1], b[2], a[0], a[1], 1e-6);       // grazing view
    Push(p, a[0], a[1], 1e-6, -a[0], -a[1], 1e-6);     // theta_d -> 90 degrees
    Push(p, a[0], a[1], 1e-3, -a[0], -a[1], 1e-3);
  }
  for (int j = 0; j < 2; ++j)
    for (int k = 0; k < m.uniform; ++k) {  // directions along every sampled tangent
      const size_t at = 1 + j * (7 + 2 * m.uniform) + 7 + 2 * k;
      double t[3] = {j == 0 ? m.data[at] : 0, j == 1 ? m.data[at] : 0, m.data[at + 1]};
      if (t[2] < 0) for (double& x : t) x = -x;
      if (t[2] == 0) t[2] = 1e-6;
      Push(p, t[0], t[1], t[2], -t[0], -t[1], t[2]);
      Push(p, t[0], t[1], t[2], t[0], t[1], t[2]);
      Push(p, t[0], t[1], t[2], 0, 0, 1);
      Push(p, 0, 0, 1, t[0], t[1], t[2]);
    }
  return p;
}

TEST(HardCases, Fp32KernelFiniteAndCloseToReference) {
  const Model* model = &Microcylinder();
    for (const models::PresetSpec& preset : model->presets())
      for (double gamma_s : {-1.0, 0.5}) {
        models::ParamValues v = model->PresetValues(preset);
        if (gamma_s > 0) v["thread1.gamma_s"] = v["thread2.gamma_s"] = {gamma_s};
        const models::PackedMaterial m = model->Pack(v);
        const Pairs p = HardCases(m);
        const std::vector<double> ref = Reference(m, p);
        ExpectFiniteNonNegative(ref, preset.name + " reference");
        const std::vector<double> f32 = testing::RunKernel(*model, m, false, p.wi, p.wo);
        ExpectFiniteNonNegative(f32, preset.name + " fp32");
        const accuracy::Accuracy e = accuracy::Compare(f32, ref, kFloor);
        std::printf("%-34s gamma_s %-4g hard cases fp32 %s\n", preset.name.c_str(), gamma_s, e.ToString().c_str());
        // Hard cases sit on lobe peaks and at grazing angles, where float inputs themselves carry the error.
        EXPECT_LE(e.p99, 1e-3) << preset.name;
      }
}

TEST(TangentSamples, EveryCountGivesFiniteResultsAndConverges) {
  const models::PresetSpec* preset = nullptr;
  const Model* model = models::Registry::Global().FindPreset("polyester_satin_charmeuse_front", &preset);
  const Pairs p = RandomPairs(20000, 5);
  models::ParamValues v = model->PresetValues(*preset);
  v["tangent_samples"] = {256};
  const std::vector<double> ref = Reference(model->Pack(v), p);
  double previous_error = 1e30;
  for (int T : {1, 4, 16, 64, 256}) {
    v["tangent_samples"] = {double(T)};
    const std::vector<double> f = testing::RunKernel(*model, model->Pack(v), false, p.wi, p.wo);
    ExpectFiniteNonNegative(f, "T=" + std::to_string(T));
    double num = 0, den = 0;  // relative L1 error against T = 256
    for (size_t i = 0; i < f.size(); ++i) {
      num += std::fabs(f[i] - ref[i]);
      den += ref[i];
    }
    std::printf("tangent samples %3d: relative L1 error %.3e against 256\n", T, num / den);
    if (T < 256) {
      EXPECT_LT(num / den, previous_error) << "T=" << T;
    }
    previous_error = num / den;
  }
  EXPECT_LT(previous_error, 1e-5);
}

TEST(MaterialIndex, MixedMaterialsInOneLaunchEqualSeparateLaunches) {
  const auto& model = *models::Registry::Global().FindModel("microcylinder");
  std::vector<models::PackedMaterial> mats;
  for (const auto& preset : model.presets()) mats.push_back(model.Pack(model.PresetValues(preset)));
  const Pairs p = RandomPairs(6 * 1000, 77);
  std::vector<const models::PackedMaterial*> all;
  for (const auto& m : mats) all.push_back(&m);
  std::vector<int> index;
  for (size_t q = 0; q < p.wi.size() / 3; ++q) index.push_back(static_cast<int>(q % mats.size()));
  const runtime::LaunchArgs args{.model = &model, .fp64 = false, .uniform = mats[0].uniform, .materials = &all,
                                 .material_index = &index, .wi = p.wi.data(), .wo = p.wo.data(),
                                 .n = p.wi.size() / 3};
  const std::vector<double> mixed = testing::RunLaunch(args);
  for (size_t j = 0; j < mats.size(); ++j) {
    const std::vector<double> alone = testing::RunKernel(model, mats[j], false, p.wi, p.wo);
    for (size_t q = j; q < p.wi.size() / 3; q += mats.size())
      for (int c = 0; c < 3; ++c) ASSERT_EQ(mixed[3 * q + c], alone[3 * q + c]) << "material " << j << " query " << q;
  }
}

// The woven-cotton BRDF kernel (two analytic ellipse-window areas per query) against its double reference.
// Its float error is set by the area's conditioning, ~eps |c| / (minor semi-axis) relative (about 2e-5 for
// the paper's thin warp ellipse, kernels/common/ellipse_window.h), diluted by the diffuse part.
TEST(Woven, KernelsMatchDoubleReferenceAndStayFiniteOnHardCases) {
  const models::PresetSpec* preset = nullptr;
  const Model* model = models::Registry::Global().FindPreset("cotton_twill", &preset);
  ASSERT_NE(model, nullptr);
  const models::PackedMaterial m = model->Pack(model->PresetValues(*preset));
  Pairs p = RandomPairs(100000, 4321);
  std::mt19937 rng(5);
  for (int k = 0; k < 2000; ++k) {
    float a[3];
    accuracy::RandomHemisphere(rng, a);
    Push(p, 0, 0, 1, 0, 0, 1);                          // h = n
    Push(p, a[0], a[1], a[2], a[0], a[1], a[2]);       // wi = wo
    Push(p, -a[0], -a[1], a[2], a[0], a[1], a[2]);     // mirror pair
    Push(p, a[0], a[1], 1e-6, -a[0], -a[1], 1e-6);     // both grazing
    Push(p, a[0], a[1], 1e-6, a[0], a[1], a[2]);       // grazing light
  }
  std::vector<double> ref(p.wi.size());
  model->ReferenceEval(m, p.wi.data(), p.wo.data(), nullptr, p.size(), ref.data());
  ExpectFiniteNonNegative(ref, "woven reference");
  const std::vector<double> f32 = testing::RunKernel(*model, m, false, p.wi, p.wo);
  ExpectFiniteNonNegative(f32, "woven fp32");
  const accuracy::Accuracy e32 = accuracy::Compare(f32, ref, kFloor);
  std::printf("cotton_twill fp32 %s\n", e32.ToString().c_str());
  EXPECT_LE(e32.p99, 1e-5);
  EXPECT_LE(e32.max, 1e-3);
  const std::vector<double> f64 = testing::RunKernel(*model, m, true, p.wi, p.wo);
  const accuracy::Accuracy e64 = accuracy::Compare(f64, ref, 0.0);
  std::printf("cotton_twill fp64 %s\n", e64.ToString().c_str());
  EXPECT_LE(e64.max, kMaxFp64);
}

// Texture positions for BTF queries: random in [-3, 3) (the pattern tiles), plus the hard ones: exact cell
// boundaries of a 2-, 4- and 5-thread repeat, tiny negatives (u - floor(u) rounds to 1) and far repeats.
std::vector<float> TexturePositions(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> U(-3, 3);
  const float hard[] = {0.0f, 0.5f, 0.25f, 0.75f, 0.2f, 0.4f, 0.6f, 0.8f, 1.0f, -1e-9f, -1e-30f, 0.99999994f, 1000.25f, -1023.9f};
  std::vector<float> uv(2 * n);
  for (size_t i = 0; i < uv.size(); ++i) uv[i] = (i % 7 == 0) ? hard[(i / 7) % std::size(hard)] : U(rng);
  return uv;
}

std::vector<models::PackedMaterial> WovenPresets(const Model** model) {
  *model = models::Registry::Global().FindModel("woven");
  std::vector<models::PackedMaterial> packed;
  for (const auto& preset : (*model)->presets()) packed.push_back((*model)->Pack((*model)->PresetValues(preset)));
  return packed;
}

// The woven BTF kernels against the double reference for every woven preset. The BTF is an indicator of
// the highlight ellipse, so a float rounding of a sample lying within ~1e-7 of an ellipse edge flips it: such
// values differ by ks Fr G/(n.wi n.wo), while every other value agrees to float rounding. The test bounds the
// share of flips (ellipse perimeter x ~1e-7 relative position error: ~1e-5 expected) and the error of the rest.
TEST(Woven, BtfKernelsMatchDoubleReference) {
  const Model* model = nullptr;
  const auto packed = WovenPresets(&model);
  ASSERT_EQ(packed.size(), 4u);  // cotton_twill, cotton_plain, cotton_satin, cotton_gingham
  Pairs p = RandomPairs(50000, 99);
  const Pairs near = accuracy::NearSpecularPairs(50000, 98);
  p.wi.insert(p.wi.end(), near.wi.begin(), near.wi.end());
  p.wo.insert(p.wo.end(), near.wo.begin(), near.wo.end());
  const std::vector<float> uv = TexturePositions(p.size(), 17);
  for (size_t k = 0; k < packed.size(); ++k) {
    const std::string name = model->presets()[k].name;
    std::vector<double> ref(p.wi.size());
    model->ReferenceEval(packed[k], p.wi.data(), p.wo.data(), uv.data(), p.size(), ref.data());
    ExpectFiniteNonNegative(ref, name + " reference");
    for (bool fp64 : {false, true}) {
      const std::vector<double> f = testing::RunKernel(*model, packed[k], fp64, p.wi, p.wo, uv);
      ExpectFiniteNonNegative(f, name);
      size_t flips = 0;
      std::vector<double> rest_got, rest_ref;
      for (size_t i = 0; i < f.size(); ++i) {
        if (std::fabs(f[i] - ref[i]) > 1e-4 * ref[i]) {
          ++flips;
        } else {
          rest_got.push_back(f[i]);
          rest_ref.push_back(ref[i]);
        }
      }
      const accuracy::Accuracy e = accuracy::Compare(rest_got, rest_ref, kFloor);
      std::printf("%s BTF %s: %zu of %zu values flipped at highlight edges; others %s\n", name.c_str(),
                  fp64 ? "fp64" : "fp32", flips, f.size(), e.ToString().c_str());
      EXPECT_LE(flips, fp64 ? 0u : f.size() / 2000) << name;
      EXPECT_LE(e.max, fp64 ? kMaxFp64 : 1e-5) << name;
      // Reciprocity, exact in the kernels too: h and wi.h come from the commutative wi + wo.
      const std::vector<double> swapped = testing::RunKernel(*model, packed[k], fp64, p.wo, p.wi, uv);
      for (size_t i = 0; i < f.size(); ++i) ASSERT_EQ(f[i], swapped[i]) << name << " value " << i;
    }
  }
}

// Materials of different sizes (2x2, 4x4 and 5x5 cell tables) in one BTF launch, interleaved query by query,
// give exactly what each gives alone: each work-item finds its own material's offset.
TEST(Woven, MixedPatternsInOneBtfLaunchEqualSeparateLaunches) {
  const Model* model = nullptr;
  const auto packed = WovenPresets(&model);
  const Pairs p = RandomPairs(3 * 2000, 7);
  const std::vector<float> uv = TexturePositions(p.size(), 8);
  std::vector<const models::PackedMaterial*> all;
  for (const auto& m : packed) all.push_back(&m);
  std::vector<int> index;
  for (size_t q = 0; q < p.size(); ++q) index.push_back(static_cast<int>((q / 5) % packed.size()));  // runs of 5
  const runtime::LaunchArgs args{.model = model, .fp64 = false, .uniform = 0, .materials = &all,
                                 .material_index = &index, .wi = p.wi.data(), .wo = p.wo.data(), .uv = uv.data(),
                                 .n = p.size()};
  const std::vector<double> mixed = testing::RunLaunch(args);
  for (size_t j = 0; j < packed.size(); ++j) {
    const std::vector<double> alone = testing::RunKernel(*model, packed[j], false, p.wi, p.wo, uv);
    for (size_t q = 0; q < p.size(); ++q) {
      if (index[q] != int(j)) continue;
      for (int c = 0; c < 3; ++c) ASSERT_EQ(mixed[3 * q + c], alone[3 * q + c]) << "material " << j << " query " << q;
    }
  }
}

}  // namespace
}  // namespace loomlight
