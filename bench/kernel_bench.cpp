// Sections 1 and 2: the OpenCL kernels (fp32, fp64) and the native float baseline on the same random
// direction pairs, timed best-of-N, with their errors against the double reference.
#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>
#include <random>

#include "bench/bench.h"
#include "bench/kernel_runs.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/models/registry.h"
#include "tests/naive_formulas.h"

namespace loomlight::bench {
namespace {

using models::Model;
using models::PackedMaterial;

const Model& Microcylinder() { return *models::Registry::Global().FindModel("microcylinder"); }

// A preset's material; tangent_samples > 0 overrides the preset's count.
PackedMaterial PresetMaterial(const models::PresetSpec& preset, int tangent_samples = 0) {
  models::ParamValues v = Microcylinder().PresetValues(preset);
  if (tangent_samples > 0) v["tangent_samples"] = {static_cast<double>(tangent_samples)};
  return Microcylinder().Pack(v);
}

const models::PresetSpec& FindPreset(const std::string& name) {
  const models::PresetSpec* preset = nullptr;
  models::Registry::Global().FindPreset(name, &preset);
  return *preset;
}

struct Measurement {
  double queries_per_second = 0;
  Accuracy accuracy;
};

// Throughput from the best time, error of the values against ref (which covers a prefix of the pairs).
template <class Out>
Measurement Summarise(double seconds, const std::vector<Out>& f, const Pairs& p, const std::vector<double>& ref) {
  return {static_cast<double>(p.size()) / seconds, Compare(f, ref, kErrorFloor, &p)};
}

std::vector<std::string> AccuracyRow(const std::string& preset, const std::string& impl, const Accuracy& a) {
  return {preset, impl, Sci(a.median), Sci(a.p99), Sci(a.max), Count(a.count), Sci(a.log_rmse)};
}

// One preset through every implementation, on the same pairs and against the same reference.
struct PresetResult {
  Measurement fp32, native;
  std::optional<Measurement> fp64;  // when the device has cl_khr_fp64
};

// The implementations take turns (BestOfEach), so a busy spell of the machine does not favour one of them.
PresetResult MeasurePreset(runtime::ClRuntime& rt, const Workload& w, const Sizes& sizes) {
  const std::vector<double> ref = Reference(w, sizes.kernel_error_queries, sizes.reference_threads);
  const Pairs& pairs = w.pairs;
  std::vector<double> fp32, fp64;
  std::vector<float> native;
  std::vector<std::function<void()>> runs = {[&] { RunOpenCl(rt, false, w, &fp32); }, [&] { RunNative(w, &native); }};
  if (rt.has_fp64()) runs.push_back([&] { RunOpenCl(rt, true, w, &fp64); });
  const std::vector<double> seconds = BestOfEach(sizes.timed_runs, runs);
  PresetResult r;
  r.fp32 = Summarise(seconds[0], fp32, pairs, ref);
  r.native = Summarise(seconds[1], native, pairs, ref);
  if (rt.has_fp64()) r.fp64 = Summarise(seconds[2], fp64, pairs, ref);
  return r;
}

std::vector<std::string> SpeedRow(const std::string& preset, const PresetResult& r) {
  const double fp32 = r.fp32.queries_per_second, native = r.native.queries_per_second;
  return {preset, Rate(fp32), r.fp64 ? Rate(r.fp64->queries_per_second) : "n/a", Rate(native), Fixed(fp32 / native, 2),
          r.fp64 ? Fixed(r.fp64->queries_per_second / fp32, 2) : "n/a"};
}

}  // namespace

std::string KernelSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  const Pairs pairs = RandomPairs(sizes.kernel_queries, 2024);
  Table speed({"preset", "OpenCL fp32 (q/s)", "OpenCL fp64 (q/s)", "native fp32 (q/s)", "OpenCL fp32 / native",
               "OpenCL fp64 / fp32"});
  Table error({"preset", "implementation", "rel. err median", "rel. err p99", "rel. err max", "values > 1e-4",
               "cos-weighted log RMSE"},
              2);
  double log_ratio_sum = 0;
  const auto& presets = Microcylinder().presets();
  for (const models::PresetSpec& preset : presets) {
    Progress("kernels: %s\n", preset.name.c_str());
    const PackedMaterial m = PresetMaterial(preset);
    const PresetResult r = MeasurePreset(rt, {Microcylinder(), m, pairs}, sizes);
    speed.Add(SpeedRow(preset.name, r));
    log_ratio_sum += std::log(r.fp32.queries_per_second / r.native.queries_per_second);
    error.Add(AccuracyRow(preset.name, "OpenCL fp32", r.fp32.accuracy));
    if (r.fp64) error.Add(AccuracyRow(preset.name, "OpenCL fp64", r.fp64->accuracy));
    error.Add(AccuracyRow(preset.name, "native fp32", r.native.accuracy));
  }
  const double mean_ratio = std::exp(log_ratio_sum / static_cast<double>(presets.size()));

  const std::string method =
      "The same " + Count(sizes.kernel_queries) + " uniform-hemisphere direction pairs (float) for every preset "
      "and implementation, default T = " + std::to_string(PresetMaterial(presets[0]).uniform) +
      " tangent samples per thread; best of " + std::to_string(sizes.timed_runs) +
      " timed runs after a warm-up, the implementations taking turns. OpenCL: a whole `ClRuntime::Run` launch "
      "on PoCL (host copies, padding and read-back included). Native: `NativeEval`, the same model source built "
      "with -O3 -march=native, on all hardware threads. Errors: the values of those runs against the double "
      "reference `ReferenceEval` on the first " + Count(sizes.kernel_error_queries) + " pairs (the reference split over " +
      std::to_string(sizes.reference_threads) + " threads).";
  const std::string body =
      TableBlock("queries/s, higher is better; fp32 / native above 1 means the OpenCL kernel beats the native "
                 "C++ build of the same source.",
                 speed) +
      "**OpenCL fp32 / native, geometric mean over the presets: " + Fixed(mean_ratio, 2) + "**\n\n" +
      TableBlock("relative error |f - f_ref| / f_ref over the RGB values with f_ref > 1e-4 (median, p99, max), and "
                 "sqrt(mean((log(1 + f cos_o) - log(1 + f_ref cos_o))^2)) over all values, the error a tone-mapped "
                 "image sees; float rounding alone is ~1e-7.",
                 error);
  return Section("1. Kernel throughput and accuracy per preset", method, body);
}

namespace {

// One way of querying a model: a label, parameter overrides on each preset, and whether queries carry uv.
struct Variant {
  std::string label;
  models::ParamValues overrides;
  bool uv = false;
};

// Extra error rows for a preset and variant (e.g. a naive formula), given the material and the reference.
using ExtraRows = std::function<void(const PackedMaterial& m, const std::vector<double>& ref, const Pairs& pairs,
                                     std::vector<std::pair<std::string, Accuracy>>* rows)>;

// Every preset of the model in every variant through OpenCL fp32 / fp64 and the native baseline: a speed
// table and an error table (first columns preset, variant).
std::string VariantTables(runtime::ClRuntime& rt, const Sizes& sizes, const Model& model,
                          const std::vector<Variant>& variants, const Pairs& pairs, const std::vector<float>& uv,
                          const ExtraRows& extra = {}) {
  Table speed({"preset", "variant", "OpenCL fp32 (q/s)", "OpenCL fp64 (q/s)", "native fp32 (q/s)",
               "OpenCL fp32 / native", "OpenCL fp64 / fp32"},
              2);
  Table error({"preset", "variant", "implementation", "rel. err median", "rel. err p99", "rel. err max",
               "values > 1e-4", "cos-weighted log RMSE"},
              3);
  auto add_error = [&](const std::string& preset, const std::string& variant, const std::string& impl,
                       const Accuracy& a) {
    std::vector<std::string> e = AccuracyRow(preset, impl, a);
    e.insert(e.begin() + 1, variant);
    error.Add(e);
  };
  for (const models::PresetSpec& preset : model.presets()) {
    for (const Variant& variant : variants) {
      models::ParamValues values = model.PresetValues(preset);
      for (const auto& [name, v] : variant.overrides) values[name] = v;
      const PackedMaterial m = model.Pack(values);
      Progress("%s: %s %s\n", model.name().c_str(), preset.name.c_str(), variant.label.c_str());
      const Workload w{model, m, pairs, variant.uv ? uv.data() : nullptr};
      const PresetResult r = MeasurePreset(rt, w, sizes);
      std::vector<std::string> row = SpeedRow(preset.name, r);
      row.insert(row.begin() + 1, variant.label);
      speed.Add(row);
      add_error(preset.name, variant.label, "OpenCL fp32", r.fp32.accuracy);
      if (r.fp64) add_error(preset.name, variant.label, "OpenCL fp64", r.fp64->accuracy);
      add_error(preset.name, variant.label, "native fp32", r.native.accuracy);
      if (extra) {
        std::vector<std::pair<std::string, Accuracy>> rows;
        extra(m, Reference(w, sizes.kernel_error_queries, sizes.reference_threads), pairs, &rows);
        for (const auto& [impl, a] : rows) add_error(preset.name, variant.label, impl, a);
      }
    }
  }
  return TableBlock("queries/s, higher is better, as in section 1.", speed) +
         TableBlock("errors against the double reference, as in section 1 (f > 1e-4).", error);
}

// Uniform pairs over the whole sphere: wo flipped below the surface for every other pair (transmission), and
// every 50th pair exactly straight through (wo = -wi, so |n.wo| = |n.wi|: the 0/0 of the printed formula).
Pairs SpherePairs(size_t n, unsigned seed) {
  Pairs p = RandomPairs(n, seed);
  for (size_t q = 0; q < p.size(); ++q) {
    if (q % 50 == 0)
      for (int c = 0; c < 3; ++c) p.wo[3 * q + c] = -p.wi[3 * q + c];
    else if (q % 2 == 1)
      p.wo[3 * q + 2] = -p.wo[3 * q + 2];
  }
  return p;
}

}  // namespace

std::string WovenSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  const Model& woven = *models::Registry::Global().FindModel("woven");
  const Pairs pairs = RandomPairs(sizes.kernel_queries, 2025);
  // Texture positions uniform over 4 x 4 repeats (the pattern tiles; the lookup cost does not depend on them).
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> U(0.0f, 4.0f);
  std::vector<float> uv(2 * pairs.size());
  for (float& x : uv) x = U(rng);
  const std::string method =
      "Woven cotton presets, the same " + Count(sizes.kernel_queries) + " uniform-hemisphere pairs for every "
      "implementation; the BTF rows add a texture position per pair, uniform over 4 x 4 pattern repeats. Timing and "
      "errors as in section 1 (best of " + std::to_string(sizes.timed_runs) + ", whole launches, errors on the first " +
      Count(sizes.kernel_error_queries) + " pairs against the double reference).";
  const std::string how =
      "*How to read:* the BRDF costs two analytic ellipse-window areas per query, the BTF one cell-table lookup (a "
      "per-lane gather in the OpenCL kernel) and two ellipse tests. The BTF is an indicator of the highlight "
      "ellipse, so a float sample within ~1e-7 of an edge can flip: the max column shows such flips when they "
      "occur.\n\n";
  return Section("4. Woven cotton: BRDF and BTF throughput and accuracy", method,
                 how + VariantTables(rt, sizes, woven, {{"BRDF", {}, false}, {"BTF (uv)", {}, true}}, pairs, uv));
}

std::string TransmissionSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  const models::Registry& registry = models::Registry::Global();
  const Pairs pairs = SpherePairs(sizes.kernel_queries, 2026);
  const ExtraRows naive_rows = [](const PackedMaterial& m, const std::vector<double>& ref, const Pairs& p,
                                  std::vector<std::pair<std::string, Accuracy>>* rows) {
    if (m.uniform != 0) return;  // the printed formulas are single scattering's: no match for all orders
    const std::vector<double> f = naive::ThinLayerFloat(m, p.Head(ref.size() / 3));
    size_t nonfinite = 0;
    for (double v : f) nonfinite += !std::isfinite(v);
    std::vector<double> finite = f;
    for (size_t i = 0; i < finite.size(); ++i)
      if (!std::isfinite(finite[i])) finite[i] = ref[i];  // counted apart; the statistics cover the rest
    rows->push_back({"naive float (" + Count(nonfinite) + " NaN/Inf)", Compare(finite, ref, kErrorFloor, &p)});
  };
  const std::string thin = VariantTables(
      rt, sizes, *registry.FindModel("thin_layer"),
      {{"single scattering", {{"scattering", {0}}}, false}, {"all orders", {{"scattering", {1}}}, false}}, pairs, {},
      naive_rows);
  const std::string fiber = VariantTables(
      rt, sizes, *registry.FindModel("fiber"),
      {{"simple (Eq. 5)", {{"mode", {0}}}, false}, {"R + TT (Eq. 6)", {{"mode", {1}}}, false}}, pairs, {});
  const std::string method =
      "Thin layer and fiber presets, each in both modes, on the same " + Count(sizes.kernel_queries) +
      " pairs over the whole sphere (wo below the surface for every other pair; every 50th pair straight through, "
      "wo = -wi, where |n.wo| = |n.wi|). Timing and errors as in section 1. The thin layer's `naive float` rows "
      "evaluate the formulas as printed (1 - exp, and (exp(-tau/mu) - exp(-tau/mu0)) / (mu - mu0)) in float on "
      "the same pairs: the NaN/Inf count is the 0/0 at mu = mu0, the statistics cover the other values.";
  return Section("6. Thin layer and fiber: throughput and accuracy, stable against naive formulas", method,
                 "### Thin layer (single scattering closed form; all orders from adding-doubling tables)\n\n" + thin +
                     "### Fiber (simple model; physically based R + TT)\n\n" + fiber);
}

std::string TangentSweepSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  constexpr int kReferenceSamples = 256;
  const std::vector<int> counts = {4, 8, 16, 32, 64, 128, kReferenceSamples};
  const std::vector<std::string> presets = {"polyester_satin_charmeuse_front", "velvet"};
  const Pairs pairs = RandomPairs(sizes.sweep_queries, 7);
  Table table({"preset", "T", "queries/s", "rel. L1 err", "log RMSE", "rel. err p99"}, 2);
  for (const std::string& name : presets) {
    const models::PresetSpec& preset = FindPreset(name);
    Progress("tangent sweep: %s reference\n", name.c_str());
    const PackedMaterial reference_material = PresetMaterial(preset, kReferenceSamples);
    const std::vector<double> ref =
        Reference({Microcylinder(), reference_material, pairs}, sizes.sweep_error_queries, sizes.reference_threads);
    for (int T : counts) {
      Progress("tangent sweep: %s T=%d\n", name.c_str(), T);
      const PackedMaterial m = PresetMaterial(preset, T);
      std::vector<double> f;
      const double seconds = BestOf(sizes.timed_runs, [&] { RunOpenCl(rt, false, {Microcylinder(), m, pairs}, &f); });
      const Measurement r = Summarise(seconds, f, pairs, ref);
      const std::string label = std::to_string(T) + (T == kReferenceSamples ? " (rounding only)" : "");
      table.Add({name, label, Rate(r.queries_per_second), Sci(r.accuracy.rel_l1), Sci(r.accuracy.log_rmse),
                 Sci(r.accuracy.p99)});
    }
  }
  const std::string method =
      "OpenCL fp32 with the material parameter `tangent_samples` = T. Throughput: best of " +
      std::to_string(sizes.timed_runs) + " runs over " + Count(sizes.sweep_queries) +
      " pairs. Errors: the first " + Count(sizes.sweep_error_queries) +
      " pairs against the double reference at T = 256 (split over " + std::to_string(sizes.reference_threads) +
      " threads): relative L1 = sum|f - f_ref| / sum f_ref, the log RMSE of section 1, p99 relative error over "
      "values > 1e-4.";
  const std::string how =
      "cost grows linearly with T; the errors are the tangent-curve quadrature error plus float rounding (the "
      "T = 256 row is the rounding alone); pick the smallest T whose error the use tolerates.";
  return Section("2. Tangent samples per thread: speed against accuracy", method, TableBlock(how, table));
}

}  // namespace loomlight::bench
