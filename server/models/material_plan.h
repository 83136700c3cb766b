// The material plan: how a material the service was sent (a model and its parameters, possibly with a
// thin layer behind it: a curtain) is evaluated by the kernels. Defined once here and used by every RPC:
// which queries go to which kernel, on which directions, and how the kernels' results combine into f.
//
// A curtain (docs/models.md "Curtains"): pairs on one side of the cloth go to the reflection model (a pair below
// the cloth is mirrored to the front: the cloth is two-sided), pairs on opposite sides to the layer; reflection is
// scaled by sqrt((1 - T(wi)) (1 - T(wo))), T the layer's direct transmittance, because light the layer lets
// straight through cannot be reflected (symmetric, so the curtain stays reciprocal).
#pragma once

#include <atomic>
#include <cstddef>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"
#include "server/models/direction_sampler.h"
#include "server/models/material.h"
#include "server/models/registry.h"

namespace loomlight::models {

class TabulatedBrdf;  // server/models/tabulated_brdf.h

// A material resolved and packed, ready for the kernels; immutable and shared (the material cache keeps it).
struct PreparedMaterial {
  const Model* model = nullptr;
  ParamValues values;
  PackedMaterial packed;
  std::shared_ptr<const PreparedMaterial> transmission;  // a curtain's layer (Material.transmission), or null
  // What Evaluate reports as the approximation when no error target is asked (DescribeOwnSettings), written once
  // by the material cache: its two snprintf on every call were ~1% of a small Evaluate's server CPU.
  std::string own_settings;

  // The model's estimated error at each accuracy-knob setting for this material (Model::KnobErrors), measured
  // on first use and kept.
  const std::vector<double>& KnobErrors() const {
    std::call_once(knob_errors_once_, [this] { knob_errors_ = model->KnobErrors(values); });
    return knob_errors_;
  }

  // The material's importance-sampling table, built on first use (0.1-0.3 s: a worker's job, not a gRPC or
  // host-worker thread's) and kept.
  const DirectionSampler& Sampler() const {
    std::call_once(sampler_once_, [this] {
      sampler_ = std::make_unique<DirectionSampler>(*this);
      sampler_built_.store(true, std::memory_order_release);
    });
    return *sampler_;
  }
  // Whether Sampler() returns at once.
  bool SamplerBuilt() const { return sampler_built_.load(std::memory_order_acquire); }

  // Its BRDF tabulated (TabulatedBrdf::Build with the default budget: seconds on every core for a narrow lobe; a
  // worker's job), built on first use and kept; null when the material cannot be tabulated (TableRefusal says
  // why: a layer, a model without a declared lobe width, a grid over the budget).
  const TabulatedBrdf* Table() const;
  const std::string& TableRefusal() const;
  bool TableBuilt() const { return table_built_.load(std::memory_order_acquire); }
  // "" when Table() may give a table (its grid fits the budget: cheap, no table is built), else why not.
  std::string Untabulable() const;

 private:
  mutable std::once_flag knob_errors_once_;
  mutable std::vector<double> knob_errors_;
  mutable std::once_flag sampler_once_;
  mutable std::unique_ptr<const DirectionSampler> sampler_;
  mutable std::atomic<bool> sampler_built_{false};
  mutable std::once_flag table_once_;
  mutable std::shared_ptr<const TabulatedBrdf> table_;
  mutable std::string table_refusal_;
  mutable std::atomic<bool> table_built_{false};
};

// Resolves a material and its curtain layer, checking the composition (a layer only behind a reflection
// model, layers do not nest), naming fields under "material". Returns "" or the INVALID_ARGUMENT message.
std::string ResolveComposition(const v1::Material& material, const Registry& registry, ResolvedMaterial* top,
                               ResolvedMaterial* layer);

// A curtain's reflection scale for one pair, from the layer's direct transmittance toward wi and wo.
double CurtainReflectionScale(double transmittance_wi, double transmittance_wo);

// The kernel work for n queries of one prepared material: one part per kernel (the material alone, or a
// curtain's reflection and its layer), and how their results combine. The request's arrays must outlive it.
class EvaluationPlan {
 public:
  // `axis` (xyz per query, unit; nullptr: none) is each query's fiber axis, for a fiber model without a layer
  // (the caller checks): the model re-expresses each pair about the material's own axis (Model::AlignToAxis).
  // `quantity` kAmbient (models with has_ambient(), without a layer; the caller checks) evaluates the ambient
  // factor toward each wo (wi is not read and may be wo).
  EvaluationPlan(const PreparedMaterial& material, const float* wi, const float* wo, const float* uv, size_t n,
                 const float* axis = nullptr, Quantity quantity = Quantity::kScattering);

  Quantity quantity() const { return quantity_; }

  size_t parts() const { return parts_.size(); }
  const Model& model(size_t k) const { return *parts_[k].material->model; }
  const PackedMaterial& packed(size_t k) const { return parts_[k].material->packed; }
  // Part k's queries and their directions (uv nullptr when the request has none or the part's model does not
  // vary over the surface).
  size_t size(size_t k) const { return parts_[k].whole ? n_ : parts_[k].index.size(); }
  const float* wi(size_t k) const { return parts_[k].wi.empty() ? wi_ : parts_[k].wi.data(); }
  const float* wo(size_t k) const { return parts_[k].wo.empty() ? wo_ : parts_[k].wo.data(); }
  const float* uv(size_t k) const;
  // Where part k's results go, for a kernel writing them straight into the request's f (3 per request query):
  // part query i is request query slots(k)[i] (nullptr: i), scaled by scale(k)[request query] (nullptr: 1).
  const size_t* slots(size_t k) const { return parts_[k].whole ? nullptr : parts_[k].index.data(); }
  const double* scale(size_t k) const { return parts_[k].scaled ? scale_.data() : nullptr; }
  // Per query, the direct transmittance toward wo, for materials that transmit (empty otherwise).
  const std::vector<double>& transmittance() const { return transmittance_; }

 private:
  struct Part {
    const PreparedMaterial* material = nullptr;
    bool whole = false;               // every query, in order
    std::vector<size_t> index;        // the part's queries in the request, when not whole
    std::vector<float> wi, wo, uv;    // their directions; wi and wo empty: the request's own
    bool scaled = false;              // a curtain's reflection: times scale_[query]
  };
  const float *wi_, *wo_, *uv_;
  size_t n_;
  Quantity quantity_;
  std::vector<Part> parts_;
  std::vector<double> transmittance_;
  std::vector<double> scale_;  // curtains: the reflection scale per query
};

// f (3 per request query) of a plan's queries from each part's native host build (float, -O3: the same kernel
// source), combined as the kernels' results are. For host-side work that needs f at once (the fidelity
// pilot, importance-sampling tables).
void EvaluateNative(const EvaluationPlan& plan, double* f);

}  // namespace loomlight::models
