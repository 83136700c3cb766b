#include "server/models/registry.h"

#include <cstdio>
#include <cstdlib>

#include "server/models/accuracy.h"
#include "server/models/host_kernels.h"

namespace loomlight::models {

const ParamSpec* FindParam(const std::vector<ParamSpec>& schema, const std::string& name) {
  for (const ParamSpec& p : schema)
    if (p.name == name) return &p;
  return nullptr;
}

ParamValues DefaultValues(const std::vector<ParamSpec>& schema) {
  ParamValues values;
  for (const ParamSpec& p : schema)
    if (p.type != ParamType::kText) values[p.name] = p.defaults;
  return values;
}

const ParamSpec* Model::FindParam(const std::string& name) const { return models::FindParam(params(), name); }

ParamValues Model::DefaultValues() const { return models::DefaultValues(params()); }

ParamValues Model::PresetValues(const PresetSpec& preset) const {
  ParamValues values = DefaultValues();
  for (const auto& [name, v] : preset.values) values[name] = v;
  return values;
}

namespace {
// A kernel entry the model names, which its .cl must define (the host builds list every entry by name).
const host::HostKernel& HostKernelOf(const Model& model, const std::string& name) {
  const host::HostKernel* kernel = host::FindKernel(name);
  if (!kernel) {
    std::fprintf(stderr, "model '%s' names kernel '%s', which no kernels/models/*.cl defines\n", model.name().c_str(),
                 name.c_str());
    std::abort();
  }
  return *kernel;
}
}  // namespace

PackedMaterial Model::Pack(const ParamValues& values) const {
  PackedMaterial m = PackLayout(values);
  m.data32.assign(m.data.begin(), m.data.end());
  return m;
}

const host::HostKernel& Model::EvalKernel(const float** uv) const {
  if (!spatially_varying()) *uv = nullptr;
  return HostKernelOf(*this, *uv ? spec().uv_function : spec().function);
}

void Model::ReferenceEval(const PackedMaterial& m, const float* wi, const float* wo, const float* uv, size_t n,
                          double* f) const {
  const host::HostKernel& kernel = EvalKernel(&uv);
  host::RunReference(kernel, m.values64(), m.uniform, wi, wo, uv, n, f);
}

void Model::NativeEval(const PackedMaterial& m, const float* wi, const float* wo, const float* uv, size_t n,
                       float* f) const {
  const host::HostKernel& kernel = EvalKernel(&uv);
  host::RunNative(kernel, m.values32(), m.uniform, wi, wo, uv, n, f);
}

void Model::ReferenceAmbient(const PackedMaterial& m, const float* wo, size_t n, double* a) const {
  host::RunReference(HostKernelOf(*this, spec().ambient_function), m.values64(), m.uniform, wo, wo, nullptr, n, a);
}

void Model::NativeAmbient(const PackedMaterial& m, const float* wo, size_t n, float* a) const {
  host::RunNative(HostKernelOf(*this, spec().ambient_function), m.values32(), m.uniform, wo, wo, nullptr, n, a);
}

void Model::DirectTransmittance(const PackedMaterial& m, const float* wo, size_t n, double* t) const {
  const std::string& name = spec().transmittance_function;
  if (name.empty()) {
    std::fill(t, t + n, 0.0);
    return;
  }
  std::vector<double> rgb(3 * n);
  host::RunReference(HostKernelOf(*this, name), m.values64(), m.uniform, wo, wo, nullptr, n, rgb.data());
  for (size_t q = 0; q < n; ++q) t[q] = rgb[3 * q];
}

std::vector<double> Model::KnobErrors(const ParamValues& values) const {
  return accuracy::MeasureKnobErrors(*this, values);
}

Registry& Registry::Global() {
  static Registry* registry = [] {
    auto* r = new Registry;
    AddBuiltinModels(r);
    return r;
  }();
  return *registry;
}

void Registry::Add(std::unique_ptr<Model> model) { models_.push_back(std::move(model)); }

const Model* Registry::FindModel(const std::string& name) const {
  for (const auto& m : models_)
    if (m->name() == name) return m.get();
  return nullptr;
}

const Model* Registry::FindPreset(const std::string& name, const PresetSpec** preset) const {
  for (const auto& m : models_)
    for (const PresetSpec& p : m->presets())
      if (p.name == name) {
        if (preset) *preset = &p;
        return m.get();
      }
  return nullptr;
}

}  // namespace loomlight::models
