// A material's BRDF tabulated once from its analytic model: the cheapest rung of the render's fidelity ladder
// (issue 46 item 5), taken where its measured error against the analytic model is within a request's error target.
//
// The grid (kernels/models/tabulated_brdf.h) is 4D, in the cloth's own frame (threads along x and y, so the
// anisotropy is kept). Two axes place the half vector h = (wi + wo) / |wi + wo|: (eta_x, eta_y) = (atan2(h.x, h.z),
// atan2(h.y, h.z)). The microcylinder's specular peak lies exactly where h is perpendicular to a tangent, whatever
// else the pair is, and for a thread along x with tangent elevation a that is the grid line eta_x = -a (along y,
// eta_y = -a): the narrowest lobe is resolved by these two axes alone, at TabulationBudget::nodes_per_lobe nodes per
// its width (Model::NarrowestLobe, declared by the model from the material's parameters). Rusinkiewicz's (theta_h,
// phi_h) would cut those lobes obliquely, and MERL's sqrt(theta_h) suits a peak at the normal, which cloth's are not.
// The other two place wi about h (psi in the plane of h and the normal, chi across it), each relative to the range
// where wi and wo are both above the surface, so the grid's edges are the horizon; f (n.wi) grows like sqrt(n.w)
// from the horizon, so these axes are warped to be linear in it (a uniform (theta_d, phi_d) grid cut the horizon
// across its cells: twice the error at the same bytes, most of it at grazing pairs). A grid that would pass
// TabulationBudget::max_bytes is refused, and the renderer keeps the analytic model.
//
// Values stored: X = f(wi, wo) (n.wi), which has no pole at a grazing wi; the lookup divides by n.wi again. Nodes on
// the horizon hold the limit from above (the model's own value there is 0).
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "server/models/material_plan.h"
#include "server/models/registry.h"

namespace loomlight::models {

struct TabulationBudget {
  size_t max_bytes = size_t{64} << 20;  // the table (float RGB per node); a grid needing more is refused
  double nodes_per_lobe = 1.5;          // h grid steps per standard deviation of the narrowest lobe
  int difference_nodes = 32;            // nodes along each of the psi and chi axes
  size_t error_pairs = 20000;           // cosine-weighted pairs the error is measured on
  uint64_t error_seed = 0x7ab;          // and their seed (the tests measure on others)
};

// The grid's size: nodes along eta_x, eta_y, psi and chi (kernels/models/tabulated_brdf.h).
struct TabulationGrid {
  int eta_x = 0, eta_y = 0, psi = 0, chi = 0;
  size_t nodes() const { return size_t(eta_x) * eta_y * psi * chi; }
  size_t bytes() const;  // the packed table, header included
};

class TabulatedBrdf {
 public:
  // Tabulates `material`'s BRDF (its model's float host build on every core: 1-30 s for the microcylinder presets
  // on two cores) and measures its error. Returns "" and sets *out, or why not: the model declares no lobe width
  // (Model::NarrowestLobe), transmits light or scatters about a fiber axis, the material has a curtain layer, the
  // budget is malformed, the grid would need more than budget.max_bytes ("tabulated BRDF needs N bytes (...), over
  // the budget of M bytes"), or stop() returned true (asked between chunks of 32,768 nodes; "stopped").
  static std::string Build(const PreparedMaterial& material, const TabulationBudget& budget,
                           const std::function<bool()>& stop, std::shared_ptr<const TabulatedBrdf>* out);
  // The grid Build would use for `material` under `budget`, or why none fits ("" on success).
  static std::string PlanGrid(const PreparedMaterial& material, const TabulationBudget& budget,
                              TabulationGrid* grid);

  // f(wi, wo), RGB, from the table (double arithmetic on the host: the same source as the kernel). wi and wo
  // are unit vectors in the cloth frame; 0 where either is at or below the surface.
  std::array<double, 3> Evaluate(const double wi[3], const double wo[3]) const;
  // n queries (xyz per query, float as the API holds them) into f (RGB per query).
  void Evaluate(const float* wi, const float* wo, size_t n, double* f) const;

  // Relative L1 against the analytic model, sum |f_table - f| / sum |f| over budget.error_pairs pairs drawn
  // cosine-weighted in wi and in wo (as a renderer's paths see them), the largest of the three channels: what
  // the fidelity chooser compares with a request's error target. per_channel_error() holds each channel's.
  double measured_error() const { return std::max({error_[0], error_[1], error_[2]}); }
  const std::array<double, 3>& per_channel_error() const { return error_; }

  const TabulationGrid& grid() const { return grid_; }
  size_t bytes() const { return grid_.bytes(); }
  // The analytic material it was built from.
  const Model& source_model() const { return *source_model_; }

  // The device path: the table as a material of KernelModel(), for a ClRuntime launch (LaunchArgs.model =
  // &KernelModel(), materials = {&packed()}; fp32 and fp64 both read it, but an fp64 launch converts the table to
  // double once and keeps it, twice bytes(): the render's rung launches fp32). The runtime must have built
  // KernelRegistry()'s programs (ClRuntime::BuildPrograms(TabulatedBrdf::KernelRegistry(), ...)).
  const PackedMaterial& packed() const { return packed_; }
  // The kernel's model: not among the registry's user-facing models (it has no parameters a client could set;
  // its materials come from Build). Its ReferenceEval and NativeEval are not available (no host kernel is
  // generated for it): use Evaluate.
  static const Model& KernelModel();
  // A registry holding only KernelModel(), for ClRuntime::BuildPrograms and Warm.
  static const Registry& KernelRegistry();

 private:
  TabulatedBrdf() = default;
  TabulationGrid grid_;
  PackedMaterial packed_;
  std::array<double, 3> error_{};
  const Model* source_model_ = nullptr;
};

}  // namespace loomlight::models
