// The contract every registered model passes without test code of its own (issue 11, item 2), the way
// pbrt-v4's generic TestBSDF and Mitsuba 3's per-plugin tests work: GoogleTest parameterized over every
// (model, preset) pair found in models::Registry::Global() at run time, so a new plugin with presets is
// tested the moment it registers. Nothing here knows a model's or a parameter's name: the schema (types,
// ranges, counts), the kernels, the double reference and the model's declared capabilities (isotropic(),
// reciprocal(), energy_conserving(), spatially_varying(), transmission()) are all it uses.
//
// Per model (suite ModelSchema): every parameter's defaults and every preset's values within range and count,
// integers integral; presets resolve, validate and pack to finite data; names unique (RegistryContract: across
// the registry). Per model and preset (suite ModelContract):
//   KernelsAreFiniteAndMatchReference  the double reference and the fp32 and fp64 OpenCL kernels (and the BTF
//                   kernels with texture positions) on random and hard directions: never NaN, Inf or negative,
//                   and the kernels within tolerance of the reference.
// And per preset of the models that declare the property (one suite each, instantiated only with those):
//   ReciprocalModel, EnergyConservingModel, IsotropicModel, SpatiallyVaryingModel (the BTF's mean over one
//   pattern repeat is the BRDF).
//
// Tolerances are the loosest of the per-model tests' (kernel_accuracy_test, woven_model_test, thin_layer_test,
// fiber_test), so every model passes here and keeps its own, tighter bounds there; each is justified where it is
// defined. Everything is seeded: the same build gives the same numbers.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "server/models/host_kernels.h"
#include "server/models/registry.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using accuracy::Pairs;
using models::Model;
using models::PackedMaterial;
using models::ParamSpec;
using Type = models::ParamType;
using models::PresetSpec;
using Vec = std::array<double, 3>;

constexpr double kPi = 3.14159265358979323846;

// ---- Tolerances ----

// Relative errors are measured over values above 1e-4 1/sr (kernel_accuracy_test's floor: below what any
// display or table resolves).
constexpr double kFloor = 1e-4;
// fp32 on random pairs: kernel_accuracy_test's microcylinder bounds, the loosest of the per-model tests (float
// carries 6e-8 relative rounding per operation over ~100 chained operations per tangent sample: p99 1e-4; the
// max is set by narrow Gaussian lobes far in their tails, where exp amplifies its argument's rounding). The
// woven BRDF (p99 1e-5), the thin layer (1e-5) and the fiber (5e-5) meet tighter bounds in their own tests.
constexpr double kFp32P99 = 1e-4;
constexpr double kFp32Max = 1e-3;
// fp32 on the hard directions: kernel_accuracy_test's hard-case bound (lobe peaks and grazing angles, where the
// float inputs themselves carry the error) for the 99th percentile; the max as on random pairs.
constexpr double kFp32HardP99 = 1e-3;
constexpr double kFp32HardMax = kFp32Max;
// The fp64 kernels run the same double arithmetic as the reference (PoCL may contract to FMA): 1e-9, as every
// per-model test asserts. Over values above 1e-30 (thin_layer_test: a layer passing 1e-30 of the light is
// opaque to any renderer; below it exp lands in denormals, where relative precision is gone in any library).
constexpr double kFp64Max = 1e-9;
constexpr double kFp64Floor = 1e-30;
// A BTF is an indicator of highlight regions: a float rounding of a position or a half vector within ~1e-7 of a
// region's edge flips the value (kernel_accuracy_test's woven BTF: the share of flips is ~ edge length x 1e-7,
// ~1e-5 expected, bounded by 1/2000 of the values); the other values meet the fp32 bounds above.
constexpr double kFlipRelative = 1e-4;
constexpr double kMaxFlipShare = 1.0 / 2000;
// Directions within a float rounding of the horizon (SPEC.md section 1, docs/models.md "The microcylinder model":
// n.w <= 1e-7 lies in the surface, LL_HORIZON_EPS in kernels/common/shim.h) may land on either side after
// renormalisation in float or double: there the kernel and the reference may disagree between 0 and the lit value.
// They are still checked for finiteness and sign, and excluded from the comparisons.
constexpr double kHorizonBandLow = 0.5e-7, kHorizonBandHigh = 2e-7;
// Reciprocity of the double reference: a symmetric formula evaluated in another order differs by a few double
// roundings amplified by lobe sharpness: 1e-12 relative (woven_model_test and thin_layer_test find it exact).
constexpr double kReciprocityReference = 1e-12;
// Isotropy: rotating both directions about the normal changes their float rounding (1e-7 relative), which f
// amplifies by at most its log-derivative (thin_layer_test: tau/mu < 25 wherever f > 1e-12): 1e-5 relative over
// values above 1e-12.
constexpr double kIsotropy = 1e-5;
constexpr double kIsotropyFloor = 1e-12;
// Stratified estimates (energy, BTF mean) are judged against their own standard error, estimated from
// collapsed strata (neighbouring strata paired: an upper bound on the true variance): 4 standard errors. For
// the BTF, an indicator of highlight regions, that estimate has as many degrees of freedom as there are strata
// cut by the regions' edges, too few for a region that cuts only a few dozen (a highlight clipped to a sliver
// of its window: 26 lit samples of a million for one of cotton_twill's pairs), so its tolerance also admits 16
// strata's worth of the largest jump (largest minus smallest sample): 4 standard deviations of a region cutting
// up to 64 strata (each at most jump / 2). The albedo's integrand f |cos theta_o| is continuous (it vanishes at
// the horizon, where reflection meets transmission), so it needs no such term. The albedo may exceed 1 by a
// tabulated mode's documented accuracy too (the thin layer's all-orders tables: within 0.5% of the exact f,
// docs/models.md "The thin layer: all scattering orders"; measured 1.0006 for albedo 1 at grazing light); the BTF
// mean may differ by 1e-9 relative (double rounding).
constexpr double kSigmas = 4;
constexpr double kFewStrata = 16;
constexpr double kEnergySlack = 5e-3;

// ---- The registry's (model, preset) pairs ----

struct Case {
  const Model* model;
  const PresetSpec* preset;
};

// Every (model, preset) pair, or those of the models declaring `property`.
std::vector<Case> RegisteredCases(bool (Model::*property)() const = nullptr) {
  std::vector<Case> cases;
  for (const auto& model : models::Registry::Global().models())
    if (!property || (model.get()->*property)())
      for (const PresetSpec& preset : model->presets()) cases.push_back({model.get(), &preset});
  return cases;
}

// How GoogleTest prints a case (e.g. in failure messages), instead of its bytes.
void PrintTo(const Case& c, std::ostream* os) { *os << c.model->name() << "/" << c.preset->name; }

std::string CaseName(const ::testing::TestParamInfo<Case>& info) {
  std::string name = info.param.model->name() + "_" + info.param.preset->name;
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name;
}

// ---- Directions ----

Vec Normalize(Vec v) {
  const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / l, v[1] / l, v[2] / l};
}
Vec Neg(const Vec& v) { return {-v[0], -v[1], -v[2]}; }
Vec Mirror(const Vec& v) { return {-v[0], -v[1], v[2]}; }  // the mirror direction about the normal
Vec Below(const Vec& v) { return {v[0], v[1], -v[2]}; }
// The unit direction with n.w = z (exactly, before rounding to float) at azimuth phi.
Vec WithCosine(double z, double phi) {
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  return {r * std::cos(phi), r * std::sin(phi), z};
}
Vec RandomUpper(std::mt19937& rng) {
  std::uniform_real_distribution<double> U(0, 1);
  return WithCosine(U(rng), 2 * kPi * U(rng));
}

void Push(Pairs& p, const Vec& wi, const Vec& wo) {
  const Vec a = Normalize(wi), b = Normalize(wo);
  for (int k = 0; k < 3; ++k) {
    p.wi.push_back(static_cast<float>(a[k]));
    p.wo.push_back(static_cast<float>(b[k]));
  }
}

void Append(Pairs& to, const Pairs& from) {
  to.wi.insert(to.wi.end(), from.wi.begin(), from.wi.end());
  to.wo.insert(to.wo.end(), from.wo.begin(), from.wo.end());
}

// Random pairs: half on the upper hemisphere (where reflection models live), half over the whole sphere.
Pairs RandomDirections(size_t n, unsigned seed) {
  Pairs p = accuracy::RandomPairs(n, seed);
  std::mt19937 rng(seed + 1);
  for (size_t q = n / 2; q < n; ++q) {
    if (rng() & 1) p.wi[3 * q + 2] = -p.wi[3 * q + 2];
    if (rng() & 1) p.wo[3 * q + 2] = -p.wo[3 * q + 2];
  }
  return p;
}

// SPEC.md's hard cases that every model shares: normal incidence; grazing n.w = 1e-6, 1e-7 (the horizon
// threshold) and exactly 0; wi = wo, wi = mirror(wo), wi = -wo (straight through, for models that transmit);
// directions along the thread axes x and y and their negatives (in the surface, and lifted 1e-6 above and
// below it) against each other, the normal and random directions; pairs below the surface; and lobe peaks.
Pairs HardDirections() {
  Pairs p;
  std::mt19937 rng(2024);
  std::uniform_real_distribution<double> U(0, 2 * kPi);
  const Vec n = {0, 0, 1};
  Push(p, n, n);
  Push(p, n, Neg(n));
  Push(p, Neg(n), Neg(n));
  for (int k = 0; k < 48; ++k) {
    const Vec a = RandomUpper(rng), b = RandomUpper(rng);
    for (const Vec& w : {a, Below(a)}) {
      Push(p, n, w);  // normal incidence, and normal view
      Push(p, w, n);
      Push(p, w, w);          // wi = wo
      Push(p, Mirror(w), w);  // wi = mirror(wo)
      Push(p, Neg(w), w);     // wi = -wo
    }
    Push(p, Below(a), b);  // below the surface: light, view, both
    Push(p, a, Below(b));
    Push(p, Below(a), Below(b));
    Push(p, Below(a), Mirror(Below(a)));
    for (double z : {1e-6, 1e-7, 0.0, -1e-7, -1e-6}) {
      const double phi = U(rng);
      const Vec g = WithCosine(z, phi);
      Push(p, g, b);  // grazing light, grazing view
      Push(p, b, g);
      Push(p, g, g);
      Push(p, g, Mirror(g));  // both grazing, theta_d -> 90 degrees
      Push(p, g, Neg(g));
      Push(p, g, WithCosine(z, U(rng)));
      Push(p, g, n);
      Push(p, n, g);
    }
  }
  const Vec axes[] = {{1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, -1, 0}};
  for (const Vec& axis : axes)
    for (double lift : {0.0, 1e-6, -1e-6}) {
      const Vec t = Normalize({axis[0], axis[1], lift});
      for (const Vec& other : axes) Push(p, t, other);
      Push(p, t, Mirror(t));
      Push(p, t, n);
      Push(p, n, t);
      for (double lift2 : {1e-6, -1e-6}) Push(p, t, Normalize({-axis[0], -axis[1], lift2}));
      for (int k = 0; k < 8; ++k) {
        const Vec b = RandomUpper(rng);
        Push(p, t, b);
        Push(p, b, t);
        Push(p, t, Below(b));
      }
    }
  Append(p, accuracy::NearSpecularPairs(600, 77));
  return p;
}

// Texture positions (pattern repeats): random in [-3, 3), and every 7th one hard: cell boundaries of repeats of
// up to 8 cells, tiny negatives (u - floor(u) rounds to 1), the last float below 1, far repeats.
std::vector<float> TexturePositions(size_t n, unsigned seed) {
  std::vector<float> hard = {-1e-9f, -1e-30f, 0.99999994f, 1000.25f, -1023.9f};
  for (int cells = 1; cells <= 8; ++cells)
    for (int k = 0; k <= cells; ++k) hard.push_back(float(k) / float(cells));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> U(-3, 3);
  std::vector<float> uv(2 * n);
  for (size_t i = 0; i < uv.size(); ++i) uv[i] = (i % 7 == 0) ? hard[(i / 7) % hard.size()] : U(rng);
  return uv;
}

bool InHorizonBand(const Pairs& p, size_t q) {
  for (const float* w : {&p.wi[3 * q], &p.wo[3 * q]}) {
    const double z = std::fabs(w[2]);
    if (z > kHorizonBandLow && z <= kHorizonBandHigh) return true;
  }
  return false;
}

// ---- Evaluation ----

// The double reference on both cores (models are stateless; ReferenceEval is const).
std::vector<double> Reference(const Model& model, const PackedMaterial& m, const Pairs& p,
                              const std::vector<float>& uv = {}) {
  const size_t n = p.size();
  std::vector<double> f(3 * n);
  const size_t half = n / 2;
  auto run = [&](size_t from, size_t to) {
    model.ReferenceEval(m, p.wi.data() + 3 * from, p.wo.data() + 3 * from, uv.empty() ? nullptr : uv.data() + 2 * from,
                        to - from, f.data() + 3 * from);
  };
  std::thread other(run, half, n);
  run(0, half);
  other.join();
  return f;
}

std::vector<double> Kernel(const Model& model, const PackedMaterial& m, bool fp64, const Pairs& p,
                           const std::vector<float>& uv = {}) {
  return testing::RunKernel(model, m, fp64, p.wi, p.wo, uv);
}

// Relative errors of got against ref over the values outside the horizon band.
accuracy::Accuracy Errors(const std::vector<double>& got, const std::vector<double>& ref, const Pairs& p,
                          double floor) {
  std::vector<double> g, r;
  for (size_t i = 0; i < ref.size(); ++i) {
    if (InHorizonBand(p, i / 3)) continue;
    g.push_back(got[i]);
    r.push_back(ref[i]);
  }
  return accuracy::Compare(g, r, floor);
}

void ExpectFiniteNonNegative(const std::vector<double>& f, const Pairs& p, const std::string& what) {
  for (size_t i = 0; i < f.size(); ++i) {
    const size_t q = i / 3;
    ASSERT_TRUE(std::isfinite(f[i]) && f[i] >= 0)
        << what << ": query " << q << " channel " << i % 3 << " f " << f[i] << " wi (" << p.wi[3 * q] << ", "
        << p.wi[3 * q + 1] << ", " << p.wi[3 * q + 2] << ") wo (" << p.wo[3 * q] << ", " << p.wo[3 * q + 1] << ", "
        << p.wo[3 * q + 2] << ")";
  }
}

// ---- The fixture: one packed material and its direction sets per case ----

class ModelContract : public ::testing::TestWithParam<Case> {
 protected:
  const Model& model() const { return *GetParam().model; }
  const PresetSpec& preset() const { return *GetParam().preset; }
  std::string label() const { return model().name() + "/" + preset().name; }
  PackedMaterial Packed() const { return model().Pack(model().PresetValues(preset())); }

  // 20,000 random pairs and the hard directions, built once per process.
  static const Pairs& Random() {
    static const Pairs p = RandomDirections(20000, 1234);
    return p;
  }
  static const Pairs& Hard() {
    static const Pairs p = HardDirections();
    return p;
  }
  // For BTF queries: random pairs, near-specular pairs (where highlights are lit) and the hard directions.
  static const Pairs& BtfDirections() {
    static const Pairs p = [] {
      Pairs all = RandomDirections(10000, 4321);
      Append(all, accuracy::NearSpecularPairs(10000, 98));
      Append(all, Hard());
      return all;
    }();
    return p;
  }
  static const std::vector<float>& Uv() {
    static const std::vector<float> uv = TexturePositions(BtfDirections().size(), 17);
    return uv;
  }
};

// ---- 1. Schema ----

// One value list against its parameter's spec: "" or the reason.
std::string CheckValues(const ParamSpec& spec, const std::vector<double>& values) {
  if (values.size() < spec.min_count || values.size() > spec.max_count)
    return std::to_string(values.size()) + " values, schema allows " + std::to_string(spec.min_count) + ".." +
           std::to_string(spec.max_count);
  for (double v : values) {
    if (!std::isfinite(v) || v < spec.min || v > spec.max)
      return "value " + std::to_string(v) + " outside [" + std::to_string(spec.min) + ", " + std::to_string(spec.max) + "]";
    if (spec.type == Type::kInt && v != std::round(v)) return "integer parameter with value " + std::to_string(v);
  }
  return "";
}

// A preset: known, non-text parameters with values the schema accepts; resolved, every parameter present,
// valid, and packed to finite data.
void CheckPreset(const Model& model, const PresetSpec& preset) {
  SCOPED_TRACE(model.name() + "/" + preset.name);
  EXPECT_FALSE(preset.description.empty());
  for (const auto& [name, values] : preset.values) {
    const ParamSpec* spec = model.FindParam(name);
    ASSERT_NE(spec, nullptr) << "preset sets unknown parameter " << name;
    ASSERT_NE(spec->type, Type::kText) << name;
    EXPECT_EQ(CheckValues(*spec, values), "") << name;
  }
  const models::ParamValues resolved = model.PresetValues(preset);
  size_t value_params = 0;
  for (const ParamSpec& spec : model.params()) {
    if (spec.type == Type::kText) {
      EXPECT_EQ(resolved.count(spec.name), 0u) << spec.name;
      continue;
    }
    ++value_params;
    ASSERT_EQ(resolved.count(spec.name), 1u) << spec.name << " unresolved";
    EXPECT_EQ(CheckValues(spec, resolved.at(spec.name)), "") << spec.name;
  }
  EXPECT_EQ(resolved.size(), value_params) << "resolved values for parameters outside the schema";
  ASSERT_EQ(model.Validate(resolved), "");
  const PackedMaterial m = model.Pack(resolved);
  ASSERT_GT(m.size(), 0u);
  for (size_t i = 0; i < m.size(); ++i) {
    ASSERT_TRUE(std::isfinite(m.values64()[i])) << "packed value " << i;
    ASSERT_EQ(float(m.values64()[i]), m.values32()[i]) << "packed value " << i;
  }
}

// The schema is the model's, so this suite runs once per model (over all its presets): fewer test processes.
class ModelSchema : public ::testing::TestWithParam<const Model*> {};

TEST_P(ModelSchema, ParametersAndPresetsValid) {
  const Model& model = *GetParam();
  std::set<std::string> names;
  for (const ParamSpec& spec : model.params()) {
    SCOPED_TRACE(model.name() + " parameter " + spec.name);
    EXPECT_FALSE(spec.name.empty());
    EXPECT_TRUE(names.insert(spec.name).second) << "duplicate parameter name";
    EXPECT_EQ(model.FindParam(spec.name), &spec);
    EXPECT_LE(spec.min_count, spec.max_count);
    if (spec.type == Type::kText) {
      EXPECT_TRUE(spec.defaults.empty()) << "text parameters carry text, not values";
      continue;
    }
    EXPECT_LE(spec.min, spec.max);
    // Counts are fixed by the type except for lists (registry.h).
    if (spec.type == Type::kRgb) {
      EXPECT_TRUE(spec.min_count == 3 && spec.max_count == 3);
    }
    if (spec.type == Type::kReal || spec.type == Type::kInt) {
      EXPECT_TRUE(spec.min_count == 1 && spec.max_count == 1);
    }
    EXPECT_EQ(CheckValues(spec, spec.defaults), "") << "defaults";
  }
  EXPECT_EQ(model.Validate(model.DefaultValues()), "") << "the defaults";
  for (const PresetSpec& preset : model.presets()) CheckPreset(model, preset);
}

// Registry-wide: unique model and preset names, and no model without a preset (it would escape the harness).
TEST(RegistryContract, NamesUniqueAndEveryModelHasPresets) {
  std::set<std::string> model_names, preset_names;
  ASSERT_FALSE(models::Registry::Global().models().empty());
  for (const auto& model : models::Registry::Global().models()) {
    EXPECT_TRUE(model_names.insert(model->name()).second) << "duplicate model " << model->name();
    EXPECT_FALSE(model->description().empty()) << model->name();
    EXPECT_FALSE(model->presets().empty()) << model->name() << " has no preset, so no contract test";
    std::printf("%-14s %zu presets; declares: reciprocal %d, energy_conserving %d, isotropic %d, "
                "spatially_varying %d, transmission %d\n", model->name().c_str(), model->presets().size(),
                model->reciprocal(), model->energy_conserving(), model->isotropic(), model->spatially_varying(),
                model->transmission());
    for (const PresetSpec& preset : model->presets()) {
      EXPECT_TRUE(preset_names.insert(preset.name).second) << "preset " << preset.name << " of " << model->name()
                                                           << " is not unique across the registry";
      EXPECT_EQ(models::Registry::Global().FindPreset(preset.name, nullptr), model.get()) << preset.name;
    }
  }
}

// The generated host-kernel table (cmake/ModelList.cmake): every kernel a model names is built for the host,
// from that model's own .cl; no two entries share a name (OpenCL would accept it in separate programs, the
// host table by name would not); a model lets light through exactly when it names a transmittance kernel.
TEST(RegistryContract, EveryNamedKernelHasHostBuilds) {
  std::set<std::string> names;
  for (const models::host::HostKernel& k : models::host::AllKernels()) {
    EXPECT_TRUE(names.insert(k.name).second) << "duplicate kernel entry " << k.name;
    EXPECT_NE(k.reference, nullptr) << k.name;
    EXPECT_NE(k.native, nullptr) << k.name;
    EXPECT_NE(models::Registry::Global().FindModel(k.model), nullptr) << k.name << " of unregistered " << k.model;
  }
  for (const auto& model : models::Registry::Global().models()) {
    const models::KernelSpec spec = model->kernel();
    EXPECT_EQ(spec.source, "models/" + model->name() + ".cl") << model->name();
    for (const std::string& name : {spec.function, spec.uv_function, spec.transmittance_function}) {
      if (name.empty()) continue;
      const models::host::HostKernel* k = models::host::FindKernel(name);
      ASSERT_NE(k, nullptr) << model->name() << " names " << name;
      EXPECT_EQ(k->model, model->name()) << name;
    }
  }
}

// ---- 2 and 3. Kernels against the double reference; finite and non-negative everywhere ----

// The fp32 (and, where the device has it, fp64) kernel against the double reference on random and hard
// directions, every value of each finite and non-negative; the BTF kernels likewise with texture positions.
TEST_P(ModelContract, KernelsAreFiniteAndMatchReference) {
  const PackedMaterial m = Packed();
  const bool fp64 = testing::SharedRuntime().has_fp64();
  if (!fp64) std::printf("%-40s the device has no fp64: fp64 kernels not checked\n", label().c_str());
  for (bool hard : {false, true}) {
    const Pairs& p = hard ? Hard() : Random();
    const std::string set = label() + (hard ? " hard" : " random");
    const std::vector<double> ref = Reference(model(), m, p);
    ExpectFiniteNonNegative(ref, p, set + " reference");
    const std::vector<double> f32 = Kernel(model(), m, false, p);
    ExpectFiniteNonNegative(f32, p, set + " fp32 kernel");
    const accuracy::Accuracy e32 = Errors(f32, ref, p, kFloor);
    std::printf("%-40s fp32 %-6s %s\n", label().c_str(), hard ? "hard" : "random", e32.ToString().c_str());
    EXPECT_GT(e32.count, hard ? 100u : 1000u) << set << ": too few values above the floor to judge";
    EXPECT_LE(e32.p99, hard ? kFp32HardP99 : kFp32P99) << set << " fp32";
    EXPECT_LE(e32.max, hard ? kFp32HardMax : kFp32Max) << set << " fp32";
    if (fp64) {
      const std::vector<double> f64 = Kernel(model(), m, true, p);
      ExpectFiniteNonNegative(f64, p, set + " fp64 kernel");
      const accuracy::Accuracy e64 = Errors(f64, ref, p, kFp64Floor);
      std::printf("%-40s fp64 %-6s %s\n", label().c_str(), hard ? "hard" : "random", e64.ToString().c_str());
      EXPECT_LE(e64.max, kFp64Max) << set << " fp64";
    }
    if (model().transmission()) {
      std::vector<double> t(p.size());
      model().DirectTransmittance(m, p.wo.data(), p.size(), t.data());
      for (size_t q = 0; q < t.size(); ++q)
        ASSERT_TRUE(t[q] >= 0 && t[q] <= 1) << set << " direct transmittance " << t[q] << " query " << q;
    }
  }
  if (!model().spatially_varying()) return;
  const Pairs& p = BtfDirections();
  const std::vector<double> ref = Reference(model(), m, p, Uv());
  ExpectFiniteNonNegative(ref, p, label() + " BTF reference");
  for (bool use_fp64 : {false, true}) {
    if (use_fp64 && !fp64) continue;
    const std::vector<double> f = Kernel(model(), m, use_fp64, p, Uv());
    ExpectFiniteNonNegative(f, p, label() + (use_fp64 ? " BTF fp64 kernel" : " BTF fp32 kernel"));
    size_t flips = 0;
    std::vector<double> got, want;
    for (size_t i = 0; i < f.size(); ++i) {
      if (InHorizonBand(p, i / 3)) continue;
      if (std::fabs(f[i] - ref[i]) > kFlipRelative * ref[i] && ref[i] > kFloor) {
        ++flips;
      } else {
        got.push_back(f[i]);
        want.push_back(ref[i]);
      }
    }
    const accuracy::Accuracy e = accuracy::Compare(got, want, use_fp64 ? kFp64Floor : kFloor);
    std::printf("%-40s BTF %s: %zu of %zu values flipped; others %s\n", label().c_str(), use_fp64 ? "fp64" : "fp32",
                flips, f.size(), e.ToString().c_str());
    EXPECT_LE(flips, use_fp64 ? 0u : size_t(kMaxFlipShare * f.size())) << "BTF";
    if (use_fp64) {
      EXPECT_LE(e.max, kFp64Max) << "BTF fp64";
    } else {
      EXPECT_LE(e.p99, kFp32P99) << "BTF fp32";
      EXPECT_LE(e.max, kFp32Max) << "BTF fp32";
    }
  }
}

// ---- 4. Declared properties ----

// f(wi, wo) against f(wo, wi): the largest relative difference over values above `floor` (horizon band excluded).
double Asymmetry(const std::vector<double>& f, const std::vector<double>& g, const Pairs& p, double floor) {
  double worst = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    if (InHorizonBand(p, i / 3)) continue;
    const double larger = std::max(f[i], g[i]);
    if (larger > floor) worst = std::max(worst, std::fabs(f[i] - g[i]) / larger);
  }
  return worst;
}

Pairs Swapped(const Pairs& p) { return Pairs{p.wo, p.wi}; }

// The property suites below are instantiated only with the models that declare the property.
class ReciprocalModel : public ModelContract {};
class EnergyConservingModel : public ModelContract {};
class IsotropicModel : public ModelContract {};
class SpatiallyVaryingModel : public ModelContract {};

TEST_P(ReciprocalModel, SwappingDirectionsKeepsF) {
  const PackedMaterial m = Packed();
  for (bool hard : {false, true}) {
    const Pairs& p = hard ? Hard() : Random();
    const double reference = Asymmetry(Reference(model(), m, p), Reference(model(), m, Swapped(p)), p, 0.0);
    // The fp32 kernel: each direction agrees with the reciprocal reference to the fp32 bounds, so the two
    // directions agree to twice them.
    const double fp32 = Asymmetry(Kernel(model(), m, false, p), Kernel(model(), m, false, Swapped(p)), p, kFloor);
    std::printf("%-40s reciprocity %-6s: reference %.3g, fp32 kernel %.3g\n", label().c_str(), hard ? "hard" : "random",
                reference, fp32);
    EXPECT_LE(reference, kReciprocityReference) << (hard ? "hard" : "random");
    EXPECT_LE(fp32, 2 * (hard ? kFp32HardMax : kFp32Max)) << (hard ? "hard" : "random");
  }
  if (model().spatially_varying()) {
    const Pairs& p = BtfDirections();
    const double btf = Asymmetry(Reference(model(), m, p, Uv()), Reference(model(), m, Swapped(p), Uv()), p, 0.0);
    std::printf("%-40s reciprocity BTF reference %.3g\n", label().c_str(), btf);
    EXPECT_LE(btf, kReciprocityReference) << "BTF";
  }
}

// A stratified estimate: the sum of one sample per stratum, with its standard error from collapsed strata
// (strata 2k and 2k + 1 paired: sum over pairs of (x_2k - x_2k+1)^2 bounds the estimate's variance from above).
struct Estimate {
  std::array<double, 3> value{0, 0, 0}, sigma{0, 0, 0};
  std::array<double, 3> spread{0, 0, 0};  // largest minus smallest sample
  // For a discontinuous integrand (see kFewStrata).
  double tolerance(int c) const { return kSigmas * sigma[c] + kFewStrata * spread[c]; }
};
// x: 3 values per stratum, strata in pairs (an even count).
Estimate Stratified(const std::vector<double>& x) {
  Estimate e;
  std::array<double, 3> var{0, 0, 0}, lo{0, 0, 0}, hi{0, 0, 0};
  for (int c = 0; c < 3 && !x.empty(); ++c) lo[c] = hi[c] = x[c];
  for (size_t i = 0; i < x.size(); ++i) {
    lo[i % 3] = std::min(lo[i % 3], x[i]);
    hi[i % 3] = std::max(hi[i % 3], x[i]);
  }
  for (size_t s = 0; s + 1 < x.size() / 3; s += 2)
    for (int c = 0; c < 3; ++c) {
      e.value[c] += x[3 * s + c] + x[3 * s + 3 + c];
      const double d = x[3 * s + c] - x[3 * s + 3 + c];
      var[c] += d * d;
    }
  for (int c = 0; c < 3; ++c) {
    e.sigma[c] = std::sqrt(var[c]);
    e.spread[c] = hi[c] - lo[c];
  }
  return e;
}

// Directional albedo: the integral of f(wi, wo) |n.wo| over the sphere of wo, by the double reference at one
// jittered sample per cell of a 256 x 512 grid in (theta_o, phi_o) (dw = sin theta d theta d phi; cells of
// 0.7 degrees, finer than any lobe the presets have).
Estimate Albedo(const Model& model, const PackedMaterial& m, const Vec& wi, std::mt19937& rng) {
  constexpr int kTheta = 256, kPhi = 512;
  std::uniform_real_distribution<double> U(0, 1);
  Pairs p;
  std::vector<double> weight;
  for (int a = 0; a < kTheta; ++a)
    for (int b = 0; b < kPhi; ++b) {
      const double th = kPi * (a + U(rng)) / kTheta, ph = 2 * kPi * (b + U(rng)) / kPhi;
      Push(p, wi, WithCosine(std::cos(th), ph));
      weight.push_back(std::sin(th) * std::fabs(std::cos(th)) * (kPi / kTheta) * (2 * kPi / kPhi));
    }
  std::vector<double> f = Reference(model, m, p);
  for (size_t q = 0; q < weight.size(); ++q)
    for (int c = 0; c < 3; ++c) f[3 * q + c] *= weight[q];
  return Stratified(f);
}

TEST_P(EnergyConservingModel, DirectionalAlbedoAtMostOne) {
  const PackedMaterial m = Packed();
  std::mt19937 rng(8);
  double worst = 0;
  // Light from the normal to 0.01 degrees above the surface, at three azimuths; from below for models that
  // transmit.
  std::vector<double> thetas = {0, 30, 60, 80, 89, 89.99};
  if (model().transmission()) thetas.insert(thetas.end(), {120, 179});
  for (double theta : thetas)
    for (double phi : {0.0, 55.0, 200.0}) {
      const Vec wi = WithCosine(std::cos(theta * kPi / 180), phi * kPi / 180);
      const Estimate e = Albedo(model(), m, wi, rng);
      for (int c = 0; c < 3; ++c) {
        EXPECT_LE(e.value[c], 1 + kSigmas * e.sigma[c] + kEnergySlack)
            << label() << " light theta " << theta << " phi " << phi << " channel " << c << " (+- " << e.sigma[c] << ")";
        EXPECT_GE(e.value[c], 0.0);
        worst = std::max(worst, e.value[c]);
      }
    }
  std::printf("%-40s largest directional albedo %.4f\n", label().c_str(), worst);
}

TEST_P(IsotropicModel, RotationAboutNormalKeepsF) {
  const PackedMaterial m = Packed();
  Pairs p = Random();
  Append(p, Hard());
  // Both directions rotated about the normal by one random angle per pair.
  Pairs rotated = p;
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> U(0, 2 * kPi);
  for (size_t q = 0; q < p.size(); ++q) {
    const double a = U(rng), c = std::cos(a), s = std::sin(a);
    for (std::vector<float>* w : {&rotated.wi, &rotated.wo}) {
      const double x = (*w)[3 * q], y = (*w)[3 * q + 1];
      (*w)[3 * q] = static_cast<float>(c * x - s * y);
      (*w)[3 * q + 1] = static_cast<float>(s * x + c * y);
    }
  }
  const double change = Asymmetry(Reference(model(), m, p), Reference(model(), m, rotated), p, kIsotropyFloor);
  std::printf("%-40s isotropy: largest relative change under rotation %.3g\n", label().c_str(), change);
  EXPECT_LE(change, kIsotropy);
}

// ---- 5. BTF mean = BRDF ----

// The mean of the BTF over one pattern repeat (uv in [0, 1)^2, the API's unit) by one jittered sample per cell
// of a 1024 x 1024 grid, against the BRDF (the same reference without uv), for random pairs and pairs at
// highlight peaks. The BTF is discontinuous along highlight and cell edges, so the stratified mean's error is
// ~ (edge length in cells)^(1/2) cells x the jump; its standard error comes from collapsed strata.
TEST_P(SpatiallyVaryingModel, BtfMeanIsBrdf) {
  const PackedMaterial m = Packed();
  constexpr int kN = 1024;
  Pairs dirs = accuracy::RandomPairs(4, 55);  // mostly the diffuse part
  Append(dirs, accuracy::NearSpecularPairs(8, 56));          // highlights lit, partly clipped by their windows
  const std::vector<double> brdf = Reference(model(), m, dirs);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> U(0, 1);
  double worst = 0, widest = 0;  // the largest error relative to the tolerance, the largest tolerance / BRDF
  for (size_t q = 0; q < dirs.size(); ++q) {
    Pairs p;
    std::vector<float> uv;
    for (int j = 0; j < kN; ++j)
      for (int i = 0; i < kN; ++i) {
        p.wi.insert(p.wi.end(), &dirs.wi[3 * q], &dirs.wi[3 * q] + 3);
        p.wo.insert(p.wo.end(), &dirs.wo[3 * q], &dirs.wo[3 * q] + 3);
        uv.push_back((i + U(rng)) / kN);
        uv.push_back((j + U(rng)) / kN);
      }
    std::vector<double> btf = Reference(model(), m, p, uv);
    for (double& x : btf) x /= double(kN) * kN;
    const Estimate e = Stratified(btf);
    for (int c = 0; c < 3; ++c) {
      const double want = brdf[3 * q + c], err = std::fabs(e.value[c] - want);
      EXPECT_LE(err, e.tolerance(c) + 1e-9 * want)
          << label() << " pair " << q << " channel " << c << ": BTF mean " << e.value[c] << " +- " << e.sigma[c]
          << ", BRDF " << want;
      worst = std::max(worst, err / (e.tolerance(c) + 1e-9 * want));
      if (want > 0) widest = std::max(widest, e.tolerance(c) / want);
    }
  }
  std::printf("%-40s BTF mean vs BRDF over %zu pairs: largest error %.2f of its tolerance; tolerances up to %.2g "
              "of the BRDF\n", label().c_str(), dirs.size(), worst, widest);
}

std::vector<const Model*> RegisteredModels() {
  std::vector<const Model*> models;
  for (const auto& model : models::Registry::Global().models()) models.push_back(model.get());
  return models;
}
std::string ModelName(const ::testing::TestParamInfo<const Model*>& info) {
  std::string name = info.param->name();
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name;
}

INSTANTIATE_TEST_SUITE_P(Registry, ModelSchema, ::testing::ValuesIn(RegisteredModels()), ModelName);
INSTANTIATE_TEST_SUITE_P(Registry, ModelContract, ::testing::ValuesIn(RegisteredCases()), CaseName);
INSTANTIATE_TEST_SUITE_P(Registry, ReciprocalModel, ::testing::ValuesIn(RegisteredCases(&Model::reciprocal)),
                         CaseName);
INSTANTIATE_TEST_SUITE_P(Registry, EnergyConservingModel,
                         ::testing::ValuesIn(RegisteredCases(&Model::energy_conserving)), CaseName);
INSTANTIATE_TEST_SUITE_P(Registry, IsotropicModel, ::testing::ValuesIn(RegisteredCases(&Model::isotropic)), CaseName);
INSTANTIATE_TEST_SUITE_P(Registry, SpatiallyVaryingModel,
                         ::testing::ValuesIn(RegisteredCases(&Model::spatially_varying)), CaseName);
// A property no registered model declares leaves its suite empty.
GTEST_ALLOW_UNINSTANTIATED_PARAMETERIZED_TEST(ReciprocalModel);
GTEST_ALLOW_UNINSTANTIATED_PARAMETERIZED_TEST(EnergyConservingModel);
GTEST_ALLOW_UNINSTANTIATED_PARAMETERIZED_TEST(IsotropicModel);
GTEST_ALLOW_UNINSTANTIATED_PARAMETERIZED_TEST(SpatiallyVaryingModel);

}  // namespace
}  // namespace loomlight
