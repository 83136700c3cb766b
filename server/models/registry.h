// Model registry: every model registers its name, parameter schema, presets, kernel and packing in one
// place (as Mitsuba registers plugins). The API, the batcher, the client and the tests discover models here.
#pragma once

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"

namespace loomlight::models {
namespace host {
struct HostKernel;
}

// kText parameters carry text (Param.text, up to max_count bytes) that the model turns into other
// parameters' values (Model::ApplyText); they have no values of their own.
enum class ParamType { kReal, kInt, kRgb, kRealList, kText };

struct ParamSpec {
  std::string name;
  ParamType type;
  std::string unit;
  double min;
  double max;
  std::vector<double> defaults;
  std::string description;
  size_t min_count;  // values accepted; fixed by the type except for lists
  size_t max_count;
};

// A fully resolved parameter set: every schema parameter has values.
using ParamValues = std::map<std::string, std::vector<double>>;

// A schema's parameter by name, or nullptr; its non-text parameters at their defaults (models' and scenes').
const ParamSpec* FindParam(const std::vector<ParamSpec>& schema, const std::string& name);
ParamValues DefaultValues(const std::vector<ParamSpec>& schema);

struct PresetSpec {
  std::string name;
  std::string description;
  ParamValues values;  // overrides of the defaults; the registry completes them
};

// A data-driven material's kernel layout (a BTF asset: tens of MB), shared by every material naming it instead
// of copied into each: float as stored, double made from it on first use (fp64 kernels, the reference).
class PackedTables {
 public:
  explicit PackedTables(std::vector<float> values) : data32_(std::move(values)) {}
  const std::vector<float>& data32() const { return data32_; }
  const std::vector<double>& data() const {
    std::call_once(data_once_, [this] { data_.assign(data32_.begin(), data32_.end()); });
    return data_;
  }
  size_t size() const { return data32_.size(); }

 private:
  std::vector<float> data32_;
  mutable std::once_flag data_once_;
  mutable std::vector<double> data_;
};

// Device layout of one material, packed once per precision: `data` in double (fp64 kernels, the reference),
// `data32` the same rounded once to float (fp32 kernels, the native baseline). Its size may depend on the
// parameters (a woven material carries its pattern); a launch concatenates materials.
struct PackedMaterial {
  std::vector<double> data;
  std::vector<float> data32;
  int uniform = 0;  // launch-uniform integer (e.g. tangent samples); only equal ones share a launch
  std::shared_ptr<const PackedTables> tables;  // when set, the layout is the tables' (data, data32 empty)

  // The layout in either precision, wherever it is held.
  size_t size() const { return tables ? tables->size() : data.size(); }
  const double* values64() const { return tables ? tables->data().data() : data.data(); }
  const float* values32() const { return tables ? tables->data32().data() : data32.data(); }
};

// A model's kernels: the entry file under kernels/ and its kernel functions, all with the signature of
// kernels/common/eval_kernel.h. `function` evaluates f(wi, wo); a spatially varying model also names
// `uv_function`, f(wi, wo, uv) (its BTF), used when a request carries texture coordinates; a model that lets
// light through names `transmittance_function`, the direct (unscattered) transmittance toward each wo in
// every channel (wi ignored); a fiber model may name `ambient_function`, the ambient factor of Wu and Yuksel's
// Eq. 7 toward each wo (the integral of f(wi, wo) cos(theta_i) over the sphere of wi; wi ignored).
struct KernelSpec {
  std::string source;
  std::string function;
  std::string uv_function = "";             // "" when the model does not vary over the surface
  std::string transmittance_function = "";  // "" when the model lets no light through
  std::string ambient_function = "";        // "" when the model serves no ambient factor
};

// What a launch computes per query: f(wi, wo) (or the BTF with texture coordinates), or the ambient factor
// toward wo (KernelSpec::ambient_function).
enum class Quantity : uint8_t { kScattering, kAmbient };

// A model's accuracy knob, declared as data: a parameter whose settings trade speed for accuracy, cheapest
// first and exact last, and how the error of a cheaper setting is estimated. Evaluate's error_target picks
// the cheapest setting whose estimated error (Model::KnobErrors) is within it; Render's fidelity chooser
// searches the settings with its pilot; ListModels serves it.
struct AccuracyKnob {
  std::string param;              // "" = the model has none
  std::vector<double> settings;   // ascending cost; the last is full fidelity
  std::string error_estimate;     // how a setting's error is measured, for people
  // A setting that keeps the lobes' shape (NaN: none does): importance-sampling tables, which need the shape and
  // not its last percent, are built at it when it is cheaper than the material's own.
  double shape_setting = std::nan("");
};

class Model {
 public:
  virtual ~Model() = default;
  virtual std::string name() const = 0;
  virtual std::string description() const = 0;
  virtual const std::vector<ParamSpec>& params() const = 0;
  virtual const std::vector<PresetSpec>& presets() const = 0;
  virtual KernelSpec kernel() const = 0;
  // Cross-parameter checks beyond the schema's per-value ranges; returns "" or "field: reason".
  virtual std::string Validate(const ParamValues& values) const = 0;
  // The material in its kernel layout, in both precisions (PackLayout's doubles, and data32 from them).
  PackedMaterial Pack(const ParamValues& values) const;
  // Sets the parameters a kText parameter stands for (e.g. a WIF draft -> the weave pattern). Returns ""
  // or the reason, e.g. "line 12: ...". Models without text parameters keep this default.
  virtual std::string ApplyText(const std::string& name, const std::string& text, ParamValues* values) const {
    return "parameter '" + name + "' takes no text";
  }
  // The most heap ApplyText holds at once for a text of `text_bytes` bytes, the text's copy included: what a
  // server charges to its memory budget while a client's text parses. Models whose parse holds more override it.
  virtual size_t TextParseBytes(const std::string& name, size_t text_bytes) const { return text_bytes; }
  // Double-precision host reference: f for n queries (RGB), the kernel's own source built for the host
  // (server/models/host_kernels.h). uv (pairs) selects the spatially varying kernel; nullptr: f(wi, wo).
  void ReferenceEval(const PackedMaterial& m, const float* wi, const float* wo, const float* uv, size_t n,
                     double* f) const;
  // Float native baseline (same source, -O3 -march=native, all cores).
  void NativeEval(const PackedMaterial& m, const float* wi, const float* wo, const float* uv, size_t n,
                  float* f) const;

  // The ambient factor (KernelSpec::ambient_function) toward each of n directions wo, RGB: the double
  // reference and the float native build. Only for models with has_ambient().
  void ReferenceAmbient(const PackedMaterial& m, const float* wo, size_t n, double* a) const;
  void NativeAmbient(const PackedMaterial& m, const float* wo, size_t n, float* a) const;
  bool has_ambient() const { return !spec().ambient_function.empty(); }

  bool spatially_varying() const { return !spec().uv_function.empty(); }
  // Models that let light through the cloth (non-zero f with wi and wo on opposite sides) also report the
  // direct (unscattered) transmittance toward each wo, in [0, 1].
  bool transmission() const { return !spec().transmittance_function.empty(); }
  // The direct transmittance toward each of n directions wo into t (the reference build); 0 for models
  // without transmission.
  void DirectTransmittance(const PackedMaterial& m, const float* wo, size_t n, double* t) const;
  // True when f depends only on the angles between wi, wo and the normal (not on the azimuth of the
  // pair): Tabulate's MERL grid then needs one half-vector azimuth sample instead of an average.
  virtual bool isotropic() const { return false; }
  // Physical properties a model declares when they hold for every parameter set its schema accepts (not only
  // its presets); ListModels serves them and tests/model_contract_test.cpp checks them on every preset.
  // Reciprocal: f(wi, wo) = f(wo, wi) for every pair (Helmholtz reciprocity; a tabulation may then fold by it).
  virtual bool reciprocal() const { return false; }
  // Energy conserving: for every wi the directional albedo, the integral of f(wi, wo) |n.wo| over the sphere
  // of wo (SPEC.md section 1's f), is at most 1: the material scatters no more light than reaches it.
  virtual bool energy_conserving() const { return false; }
  // A fiber model (f about a fiber's axis, not about the surface normal) names the parameter holding the
  // axis; "" for surface models. Served by ListModels, so clients choose views without knowing model names.
  virtual std::string fiber_axis_param() const { return ""; }
  // Fiber models: rewrites n query pairs in place so that f about each query's own fiber axis (axis, xyz per
  // query, unit) is the material's f of the rewritten pair: an exact change of frame, so the kernels take a
  // per-query axis without a per-query kernel input. Only called for models with a fiber_axis_param.
  virtual void AlignToAxis(const ParamValues& values, const float* axis, size_t n, float* wi, float* wo) const {}
  virtual AccuracyKnob accuracy_knob() const { return {}; }
  // The angular width (radians, one standard deviation) of the narrowest lobe of f for the material `values`
  // describe: how fine a grid must be to tabulate it (server/models/tabulated_brdf.h). 0: the model declares none,
  // and its materials are not tabulated.
  virtual double NarrowestLobe(const ParamValues& values) const { return 0; }
  // The estimated relative error of f at each accuracy-knob setting (cheapest first; the exact one's is 0) for
  // the material `values` describe. The default measures it (accuracy::MeasureKnobErrors: the reference at
  // each setting against the exact one); a model with a cheaper or sharper estimate overrides it.
  virtual std::vector<double> KnobErrors(const ParamValues& values) const;
  // Models whose material is woven to a weave pattern (cells or a WIF draft among its parameters) give it,
  // e.g. for laying out yarns (server/yarn/layout.h). Returns "" and fills *out, or why not.
  virtual std::string WeavePatternOf(const ParamValues& values, weave::WeavePattern* out) const {
    return "model '" + name() + "' has no weave pattern";
  }
  // Threads across one repeat of the material's pattern, the larger of its two directions (the fidelity
  // chooser compares a thread's width with a pixel's footprint); 1 for materials without a pattern.
  virtual double ThreadsPerRepeat(const ParamValues& values) const { return 1; }
  // Models whose packed material is a BTF asset's layout (kernels/models/btf.h) let a renderer fold an
  // environment map into it once (server/models/btf/environment_fold.h) instead of sampling the map per hit.
  virtual bool folds_environment() const { return false; }
  // Where to put each of n queries of one material in a launch so that the kernel reads the model's tables
  // with more locality than in the request's order: fills position[q] (a permutation of 0..n-1) and returns
  // true, or returns false (position untouched) when the request's order is as good. ClRuntime::Run lays out
  // a launch's lanes so; every result still goes to its own query. uv is null for queries without one.
  virtual bool LocalityOrder(const float* wo, const float* uv, size_t n, size_t* position) const { return false; }

  const ParamSpec* FindParam(const std::string& name) const;
  // Defaults completed with the preset's values.
  ParamValues PresetValues(const PresetSpec& preset) const;
  ParamValues DefaultValues() const;

 private:
  // The host build of the entry that evaluates f: the BTF when *uv is given and the model varies over the
  // surface, else the BRDF (then *uv becomes nullptr).
  const host::HostKernel& EvalKernel(const float** uv) const;
  // kernel(), asked once: the capabilities it implies are read on every request.
  const KernelSpec& spec() const {
    std::call_once(spec_once_, [this] { spec_ = kernel(); });
    return spec_;
  }
  mutable std::once_flag spec_once_;
  mutable KernelSpec spec_;

 protected:
  // The plugin's packing: the material's values in its kernel's layout (double), and its launch-uniform value.
  virtual PackedMaterial PackLayout(const ParamValues& values) const = 0;
};

class Registry {
 public:
  static Registry& Global();
  void Add(std::unique_ptr<Model> model);
  const Model* FindModel(const std::string& name) const;
  // The model of a preset, or nullptr; *preset receives the preset.
  const Model* FindPreset(const std::string& name, const PresetSpec** preset) const;
  const std::vector<std::unique_ptr<Model>>& models() const { return models_; }

 private:
  std::vector<std::unique_ptr<Model>> models_;
};

// The models of LOOMLIGHT_MODELS (CMakeLists.txt), in its order: generated by cmake/ModelList.cmake, which
// calls each plugin's factory (an explicit list: static registrars in a static library would be dropped by
// the linker). Registry::Global() starts with them.
void AddBuiltinModels(Registry* registry);

}  // namespace loomlight::models

// Ends a plugin's source (server/models/plugins/NAME.cpp, outside any namespace): the factory the generated
// model list calls for NAME.
#define LOOMLIGHT_REGISTER_MODEL(NAME, CLASS)                                         \
  namespace loomlight::models {                                                       \
  std::unique_ptr<Model> MakeModel_##NAME() { return std::make_unique<CLASS>(); }    \
  }
