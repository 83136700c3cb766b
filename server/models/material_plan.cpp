#include "server/models/material_plan.h"

#include "server/models/tabulated_brdf.h"

#include <algorithm>
#include <cmath>

namespace loomlight::models {

std::string ResolveComposition(const v1::Material& material, const Registry& registry, ResolvedMaterial* top,
                               ResolvedMaterial* layer) {
  if (std::string error = ResolveMaterial(material, registry, top, "material"); !error.empty()) return error;
  if (!material.has_transmission()) return "";
  const std::string layer_field = "material.transmission";
  if (top->model->transmission())
    return layer_field + ": model '" + top->model->name() + "' already transmits; add a layer to a reflection model";
  if (material.transmission().has_transmission()) return layer_field + ".transmission: layers do not nest";
  if (std::string error = ResolveMaterial(material.transmission(), registry, layer, layer_field); !error.empty())
    return error;
  if (!layer->model->transmission())
    return layer_field + ": model '" + layer->model->name() + "' has no transmission (use a thin_layer material)";
  return "";
}

double CurtainReflectionScale(double transmittance_wi, double transmittance_wo) {
  return std::sqrt((1 - transmittance_wi) * (1 - transmittance_wo));
}

EvaluationPlan::EvaluationPlan(const PreparedMaterial& material, const float* wi, const float* wo, const float* uv,
                               size_t n, const float* axis, Quantity quantity)
    : wi_(quantity == Quantity::kAmbient ? wo : wi), wo_(wo), uv_(quantity == Quantity::kAmbient ? nullptr : uv), n_(n),
      quantity_(quantity) {
  wi = wi_;
  uv = uv_;
  if (material.model->transmission() && quantity == Quantity::kScattering) {
    transmittance_.resize(n);
    material.model->DirectTransmittance(material.packed, wo, n, transmittance_.data());
  }
  const PreparedMaterial* layer = material.transmission.get();
  if (!layer) {
    parts_.push_back({&material, true, {}, {}, {}, {}, false});
    if (axis) {
      Part& part = parts_.back();
      part.wi.assign(wi, wi + 3 * n);
      part.wo.assign(wo, wo + 3 * n);
      material.model->AlignToAxis(material.values, axis, n, part.wi.data(), part.wo.data());
    }
    return;
  }
  parts_.resize(2);
  Part& reflect = parts_[0];
  Part& transmit = parts_[1];
  reflect.material = &material;
  reflect.scaled = true;
  transmit.material = layer;
  const bool reflect_uv = uv && material.model->spatially_varying();
  const bool transmit_uv = uv && layer->model->spatially_varying();
  for (size_t q = 0; q < n; ++q) {
    const bool front_i = wi[3 * q + 2] >= 0, front_o = wo[3 * q + 2] >= 0;
    Part& part = front_i == front_o ? reflect : transmit;
    const float flip = &part == &reflect && !front_i ? -1.0f : 1.0f;  // the back mirrored to the front
    part.index.push_back(q);
    part.wi.insert(part.wi.end(), {wi[3 * q], wi[3 * q + 1], flip * wi[3 * q + 2]});
    part.wo.insert(part.wo.end(), {wo[3 * q], wo[3 * q + 1], flip * wo[3 * q + 2]});
    if (&part == &reflect ? reflect_uv : transmit_uv) part.uv.insert(part.uv.end(), {uv[2 * q], uv[2 * q + 1]});
  }
  std::vector<double> ti(n);
  transmittance_.resize(n);
  layer->model->DirectTransmittance(layer->packed, wi, n, ti.data());
  layer->model->DirectTransmittance(layer->packed, wo, n, transmittance_.data());
  scale_.resize(n);
  for (size_t q = 0; q < n; ++q) scale_[q] = CurtainReflectionScale(ti[q], transmittance_[q]);
}

const float* EvaluationPlan::uv(size_t k) const {
  const Part& part = parts_[k];
  if (!uv_ || !part.material->model->spatially_varying()) return nullptr;
  return part.whole ? uv_ : part.uv.data();
}

void EvaluateNative(const EvaluationPlan& plan, double* f) {
  size_t total = 0;
  for (size_t k = 0; k < plan.parts(); ++k) total += plan.size(k);
  std::fill(f, f + 3 * total, 0.0);
  std::vector<float> part;
  for (size_t k = 0; k < plan.parts(); ++k) {
    part.assign(3 * plan.size(k), 0.0f);
    if (plan.quantity() == Quantity::kAmbient)
      plan.model(k).NativeAmbient(plan.packed(k), plan.wo(k), plan.size(k), part.data());
    else
      plan.model(k).NativeEval(plan.packed(k), plan.wi(k), plan.wo(k), plan.uv(k), plan.size(k), part.data());
    const size_t* slots = plan.slots(k);
    const double* scale = plan.scale(k);
    for (size_t i = 0; i < plan.size(k); ++i) {
      const size_t q = slots ? slots[i] : i;
      for (int c = 0; c < 3; ++c) f[3 * q + c] = (scale ? scale[q] : 1.0) * part[3 * i + c];
    }
  }
}

const TabulatedBrdf* PreparedMaterial::Table() const {
  std::call_once(table_once_, [this] {
    if (transmission) table_refusal_ = "a curtain's layer is not tabulated";
    else table_refusal_ = TabulatedBrdf::Build(*this, TabulationBudget{}, {}, &table_);
    table_built_.store(true, std::memory_order_release);
  });
  return table_.get();
}

const std::string& PreparedMaterial::TableRefusal() const {
  Table();
  return table_refusal_;
}

std::string PreparedMaterial::Untabulable() const {
  if (transmission) return "a curtain's layer is not tabulated";
  TabulationGrid grid;
  return TabulatedBrdf::PlanGrid(*this, TabulationBudget{}, &grid);
}

}  // namespace loomlight::models
