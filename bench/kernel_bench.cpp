// Sections 1 and 2: every registered model's kernels, OpenCL fp32 / fp64 and the native float baseline on the
// same random direction pairs, timed best-of-N, with their errors against the double reference; and each
// accuracy knob's speed against its error. Models come from the registry and are measured by what they
// declare (presets, spatially_varying, transmission, fiber_axis_param, accuracy_knob, KnobErrors, the schema),
// so a new model appears here without code of its own.
#include <cmath>
#include <cstdio>
#include <functional>
#include <optional>
#include <random>
#include <set>

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
using models::ParamSpec;

std::string Plain(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", v);
  return text;
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

// One workload through every implementation, against the same reference.
struct Result {
  Measurement fp32, native;
  std::optional<Measurement> fp64;  // when the device has cl_khr_fp64
};

// `ref` is the double reference of a prefix of the workload's pairs: at the workload's own parameters (the
// implementations' rounding) or at a more exact knob setting (the setting's error too). The implementations
// take turns (BestOfEach), so a busy spell of the machine does not favour one of them.
Result Measure(runtime::ClRuntime& rt, const Workload& w, const std::vector<double>& ref, int timed_runs) {
  std::vector<double> fp32, fp64;
  std::vector<float> native;
  std::vector<std::function<void()>> runs = {[&] { RunOpenCl(rt, false, w, &fp32); }, [&] { RunNative(w, &native); }};
  if (rt.has_fp64()) runs.push_back([&] { RunOpenCl(rt, true, w, &fp64); });
  const std::vector<double> seconds = BestOfEach(timed_runs, runs);
  Result r;
  r.fp32 = Summarise(seconds[0], fp32, w.pairs, ref);
  r.native = Summarise(seconds[1], native, w.pairs, ref);
  if (rt.has_fp64()) r.fp64 = Summarise(seconds[2], fp64, w.pairs, ref);
  return r;
}

const std::vector<std::string> kSpeedHeader = {"OpenCL fp32 (q/s)", "OpenCL fp64 (q/s)", "native fp32 (q/s)",
                                               "OpenCL fp32 / native", "OpenCL fp64 / fp32"};

std::vector<std::string> SpeedColumns(const Result& r) {
  const double fp32 = r.fp32.queries_per_second, native = r.native.queries_per_second;
  return {Rate(fp32), r.fp64 ? Rate(r.fp64->queries_per_second) : "n/a", Rate(native), Fixed(fp32 / native, 2),
          r.fp64 ? Fixed(r.fp64->queries_per_second / fp32, 2) : "n/a"};
}

template <class T>
std::vector<T> Concat(std::vector<T> a, const std::vector<T>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

// Integer parameters with this few values select between formulas (a switch, e.g. between a simple and a
// physically based lobe): section 1 times each value.
constexpr double kMaxSwitchValues = 4;

std::vector<const ParamSpec*> Switches(const Model& model) {
  std::vector<const ParamSpec*> switches;
  const std::string knob = model.accuracy_knob().param;  // swept in section 2
  for (const ParamSpec& p : model.params())
    if (p.type == models::ParamType::kInt && p.name != knob && p.max - p.min + 1 <= kMaxSwitchValues)
      switches.push_back(&p);
  return switches;
}

// One way of querying a model: a label, parameter overrides on each preset, and whether queries carry uv.
struct Variant {
  std::string label;
  models::ParamValues overrides;
  bool uv = false;
};

// f(wi, wo), or for a model that varies over the surface its BRDF and its BTF (queries with uv); with
// `switches`, each of them at every value of every switch parameter.
std::vector<Variant> VariantsOf(const Model& model, bool switches) {
  std::vector<Variant> variants = {{"", {}, false}};
  if (model.spatially_varying()) variants = {{"BRDF", {}, false}, {"BTF (uv)", {}, true}};
  for (const ParamSpec* s : switches ? Switches(model) : std::vector<const ParamSpec*>{}) {
    std::vector<Variant> each_value;
    for (const Variant& v : variants)
      for (double value = s->min; value <= s->max; ++value) {
        Variant with = v;
        with.label += (with.label.empty() ? "" : ", ") + s->name + " " + Plain(value);
        with.overrides[s->name] = {value};
        each_value.push_back(std::move(with));
      }
    variants = std::move(each_value);
  }
  for (Variant& v : variants)
    if (v.label.empty()) v.label = "f(wi, wo)";
  return variants;
}

// Uniform pairs over the whole sphere: wo flipped below the surface for every other pair (transmission), and
// every 50th pair exactly straight through (wo = -wi, so |n.wo| = |n.wi|: the 0/0 of a printed formula).
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

// Models whose f reaches below the surface or is about a fiber's axis are queried over the whole sphere.
bool WholeSphere(const Model& model) { return model.transmission() || !model.fiber_axis_param().empty(); }

// The direction pairs (and texture positions) every model of a section is measured on.
struct PairSets {
  Pairs hemisphere, sphere;
  std::vector<float> uv;  // a (u, v) per pair, uniform over 4 x 4 pattern repeats (the pattern tiles)

  PairSets(size_t n, unsigned seed) : hemisphere(RandomPairs(n, seed)), sphere(SpherePairs(n, seed + 1)), uv(2 * n) {
    std::mt19937 rng(seed + 2);
    std::uniform_real_distribution<float> U(0.0f, 4.0f);
    for (float& x : uv) x = U(rng);
  }
  const Pairs& For(const Model& model) const { return WholeSphere(model) ? sphere : hemisphere; }
  Workload Of(const Model& model, const PackedMaterial& m, const Variant& v) const {
    return {model, m, For(model), v.uv ? uv.data() : nullptr};
  }
};

// The printed formulas of SPEC.md section 4, before their stable rewrite (tests/naive_formulas.h), exist for
// one model and one of its settings (single scattering): the one comparison here that names its model.
constexpr char kPrintedFormulasModel[] = "thin_layer";

// The printed formulas in float on the same pairs, when they are this material's: the 0/0 count, and the
// error of the other values.
std::optional<std::pair<std::string, Accuracy>> PrintedFormulaRow(const Model& model, const PackedMaterial& m,
                                                                  const std::vector<double>& ref, const Pairs& p) {
  if (model.name() != kPrintedFormulasModel || m.uniform != 0) return std::nullopt;
  std::vector<double> f = naive::ThinLayerFloat(m, p.Head(ref.size() / 3));
  size_t nonfinite = 0;
  for (size_t i = 0; i < f.size(); ++i)
    if (!std::isfinite(f[i])) {
      ++nonfinite;
      f[i] = ref[i];  // counted apart; the statistics cover the rest
    }
  return std::pair("naive float (" + Count(nonfinite) + " NaN/Inf)", Compare(f, ref, kErrorFloor, &p));
}

// What a model's tables measure, from its declarations: pairs, knob setting, switches.
std::string AboutModel(const Model& model) {
  std::string text = model.description() + ".\n\nPairs over the ";
  if (!WholeSphere(model))
    text += "upper hemisphere";
  else if (model.transmission())
    text += "whole sphere (it transmits)";
  else
    text += "whole sphere (f about the fiber axis, parameter `" + model.fiber_axis_param() + "`, as each preset sets it)";
  if (model.spatially_varying()) text += "; its BTF with a texture position per pair";
  text += ".";
  const models::AccuracyKnob knob = model.accuracy_knob();
  if (!knob.param.empty()) {
    std::set<double> own;
    for (const models::PresetSpec& preset : model.presets()) own.insert(model.PresetValues(preset).at(knob.param).at(0));
    std::string values;
    for (double v : own) values += (values.empty() ? "" : ", ") + Plain(v);
    text += " Accuracy knob `" + knob.param + "` at the presets' own setting (" + values + "; section 2 sweeps it).";
  }
  for (const ParamSpec* s : Switches(model)) text += " Switch `" + s->name + "`: " + s->description + ".";
  return text;
}

// Every preset of the model in every variant through OpenCL fp32 / fp64 and the native baseline: a speed
// table, the geometric mean of fp32 / native and an error table.
std::string ModelKernelTables(runtime::ClRuntime& rt, const Sizes& sizes, const Model& model, const PairSets& pairs) {
  Table speed(Concat<std::string>({"preset", "variant"}, kSpeedHeader), 2);
  Table error({"preset", "variant", "implementation", "rel. err median", "rel. err p99", "rel. err max",
               "values > 1e-4", "cos-weighted log RMSE"},
              3);
  double log_ratio_sum = 0;
  int ratios = 0;
  for (const models::PresetSpec& preset : model.presets()) {
    for (const Variant& variant : VariantsOf(model, true)) {
      models::ParamValues values = model.PresetValues(preset);
      for (const auto& [name, v] : variant.overrides) values[name] = v;
      const PackedMaterial m = model.Pack(values);
      Progress("kernels: %s %s %s\n", model.name().c_str(), preset.name.c_str(), variant.label.c_str());
      const Workload w = pairs.Of(model, m, variant);
      const std::vector<double> ref = Reference(w, sizes.kernel_error_queries, sizes.reference_threads);
      const Result r = Measure(rt, w, ref, sizes.timed_runs);
      speed.Add(Concat({preset.name, variant.label}, SpeedColumns(r)));
      log_ratio_sum += std::log(r.fp32.queries_per_second / r.native.queries_per_second);
      ++ratios;
      const auto add_error = [&](const std::string& implementation, const Accuracy& a) {
        error.Add({preset.name, variant.label, implementation, Sci(a.median), Sci(a.p99), Sci(a.max), Count(a.count),
                   Sci(a.log_rmse)});
      };
      add_error("OpenCL fp32", r.fp32.accuracy);
      if (r.fp64) add_error("OpenCL fp64", r.fp64->accuracy);
      add_error("native fp32", r.native.accuracy);
      if (const auto printed = PrintedFormulaRow(model, m, ref, w.pairs)) add_error(printed->first, printed->second);
    }
  }
  return "### `" + model.name() + "`\n\n" + AboutModel(model) + "\n\n" +
         TableBlock("queries/s, higher is better; fp32 / native above 1 means the OpenCL kernel beats the native "
                    "C++ build of the same source.",
                    speed) +
         "**OpenCL fp32 / native, geometric mean over the presets and variants: " +
         Fixed(std::exp(log_ratio_sum / ratios), 2) + "**\n\n" +
         TableBlock("relative error |f - f_ref| / f_ref over the RGB values with f_ref > 1e-4 (median, p99, max), "
                    "and sqrt(mean((log(1 + f cos_o) - log(1 + f_ref cos_o))^2)) over all values, the error a "
                    "tone-mapped image sees; float rounding alone is ~1e-7.",
                    error);
}

// Every preset of the model at every setting of its accuracy knob, BRDF (and BTF), against the double reference
// at the exact setting, with the model's own estimate (Model::KnobErrors) beside the measured error.
std::string KnobSweepTable(runtime::ClRuntime& rt, const Sizes& sizes, const Model& model, const PairSets& pairs) {
  const models::AccuracyKnob knob = model.accuracy_knob();
  Table table(Concat(Concat<std::string>({"preset", "variant", knob.param}, kSpeedHeader),
                     {"declared error", "rel. L1 err", "log RMSE", "rel. err p99"}),
              3);
  for (const models::PresetSpec& preset : model.presets()) {
    const models::ParamValues own = model.PresetValues(preset);
    const std::vector<double> declared = model.KnobErrors(own);
    for (const Variant& variant : VariantsOf(model, false)) {
      models::ParamValues values = own;
      values[knob.param] = {knob.settings.back()};
      Progress("knob sweep: %s %s %s reference\n", model.name().c_str(), preset.name.c_str(), variant.label.c_str());
      const PackedMaterial exact = model.Pack(values);
      const std::vector<double> ref =
          Reference(pairs.Of(model, exact, variant), sizes.sweep_error_queries, sizes.reference_threads);
      for (size_t s = 0; s < knob.settings.size(); ++s) {
        const double setting = knob.settings[s];
        Progress("knob sweep: %s %s %s %s=%g\n", model.name().c_str(), preset.name.c_str(), variant.label.c_str(),
                 knob.param.c_str(), setting);
        values[knob.param] = {setting};
        const PackedMaterial m = model.Pack(values);
        const Result r = Measure(rt, pairs.Of(model, m, variant), ref, sizes.timed_runs);
        const bool last = s + 1 == knob.settings.size();
        table.Add(Concat(Concat({preset.name, variant.label, Plain(setting) + (last ? " (exact: rounding only)" : "")},
                                SpeedColumns(r)),
                         {s < declared.size() ? Sci(declared[s]) : "n/a", Sci(r.fp32.accuracy.rel_l1),
                          Sci(r.fp32.accuracy.log_rmse), Sci(r.fp32.accuracy.p99)}));
      }
    }
  }
  return "### `" + model.name() + "`: `" + knob.param + "`\n\nDeclared error: " + knob.error_estimate + ".\n\n" +
         TableBlock("cost grows with the setting; the measured errors (OpenCL fp32) are the setting's approximation "
                    "plus float rounding (the exact row is the rounding alone); the declared error is the model's own "
                    "estimate, which Evaluate's error_target chooses by; pick the cheapest setting whose error the "
                    "use tolerates.",
                    table);
}

std::string HowMeasured(const Sizes& sizes, size_t pairs, size_t error_pairs) {
  return "Best of " + std::to_string(sizes.timed_runs) + " timed runs over " + Count(pairs) +
         " pairs after a warm-up, the implementations taking turns. OpenCL: a whole `ClRuntime::Run` launch on PoCL "
         "(host copies, padding and read-back included). Native: `NativeEval`, the same model source built with -O3 "
         "-march=native, on all hardware threads. Errors: against the double reference `ReferenceEval` on the first " +
         Count(error_pairs) + " pairs (split over " + std::to_string(sizes.reference_threads) + " threads).";
}

}  // namespace

std::string KernelSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  const PairSets pairs(sizes.kernel_queries, 2024);
  std::string body;
  for (const auto& model : models::Registry::Global().models()) {
    if (model->presets().empty())
      body += "### `" + model->name() + "`\n\nNo presets: nothing to measure without a client's material.\n\n";
    else
      body += ModelKernelTables(rt, sizes, *model, pairs);
  }
  const std::string method =
      "Every model of the registry, every preset, on the same " + Count(sizes.kernel_queries) +
      " uniformly random direction pairs (float): over the upper hemisphere, or over the whole sphere for models "
      "that transmit or scatter about a fiber axis (wo below the surface for every other pair; every 50th pair "
      "straight through, wo = -wi, where |n.wo| = |n.wi|). Variants: the BRDF; the BTF of spatially varying "
      "models, with a texture position per pair uniform over 4 x 4 pattern repeats; each value of an integer "
      "parameter with at most " + Plain(kMaxSwitchValues) + " values (a switch between formulas). " +
      HowMeasured(sizes, sizes.kernel_queries, sizes.kernel_error_queries) +
      " Rows `naive float` evaluate the formulas as printed in SPEC.md section 4 (1 - exp, and (exp(-tau/mu) - "
      "exp(-tau/mu0)) / (mu - mu0)) in float on the same pairs: the NaN/Inf count is the 0/0 at mu = mu0, the "
      "statistics cover the other values.";
  return Section("1. Kernel throughput and accuracy per model and preset", method, body);
}

std::string KnobSweepSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  const PairSets pairs(sizes.sweep_queries, 7);
  std::string body, without;
  for (const auto& model : models::Registry::Global().models()) {
    const models::AccuracyKnob knob = model->accuracy_knob();
    if (knob.param.empty() || knob.settings.size() < 2 || model->presets().empty())
      without += (without.empty() ? "" : ", ") + model->name();
    else
      body += KnobSweepTable(rt, sizes, *model, pairs);
  }
  if (!without.empty()) body += "No knob to sweep (or no preset): " + without + ".\n\n";
  const std::string method =
      "Each model's declared accuracy knob (`accuracy_knob`: a parameter's settings from cheapest to exact) at "
      "every setting, on every preset, the pairs as in section 1. " +
      HowMeasured(sizes, sizes.sweep_queries, sizes.sweep_error_queries) +
      " The reference is at the exact setting: relative L1 = sum|f - f_ref| / sum f_ref, the log RMSE of section "
      "1, p99 relative error over values > 1e-4. Declared error: `Model::KnobErrors` for the preset.";
  return Section("2. Accuracy knobs: speed against error", method, body);
}

}  // namespace loomlight::bench
