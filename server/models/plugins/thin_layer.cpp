// Registry entry of the thin semi-transparent layer (Frisvad et al., SPEC.md section 4): schema, presets,
// packing into kernels/models/thin_layer.h's layout; wi and wo on opposite sides of the layer give its diffuse
// transmission. `scattering` is the launch-uniform value: 0 the closed-form single scattering, 1 all orders
// (issue 4 item 6), for which Pack tabulates the adding-doubling solution (server/models/slab) per channel.
// `scattering` is the model's accuracy knob; KnobErrors gives single scattering's error from the same solve.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <future>
#include <utility>

#include "server/models/registry.h"
#include "server/models/slab/adding_doubling.h"

namespace loomlight::models {
namespace {
// The layout constants (TL_*) of the shared source; evaluation goes through server/models/host_kernels.h.
namespace tl_layout {
typedef double real;
#include "common/shim.h"
#include "models/thin_layer.h"
}  // namespace tl_layout

// The single-scattering error estimate covers directions at least this far from the layer's plane.
constexpr double kErrorMinCosine = 0.1;

// Table cosines: uniform in sqrt(mu), TL_TABLE_NODES of them (kernels/models/thin_layer.h).
std::vector<double> TableCosines() {
  std::vector<double> mu(TL_TABLE_NODES);
  for (int k = 0; k < TL_TABLE_NODES; ++k) mu[k] = std::pow(double(k) / (TL_TABLE_NODES - 1), 2);
  return mu;
}

// Writes the multiply scattered f of every channel into the material's tables and returns the largest
// relative error of single scattering against all orders over the table's nodes with mu, mu0 >= 0.1 (up to
// 84 degrees from the normal). Closer to the horizon light crossing the layer is nearly all multiply
// scattered, so including those nodes makes the error ~100% for any tau >= 0.05 and useless for choosing.
// Channels of equal albedo share one solve; distinct ones are solved in parallel (a few ms each).
double TabulateAllOrders(double tau, const std::vector<double>& albedo, std::vector<double>* data) {
  static const std::vector<double> mu = TableCosines();
  constexpr int n = TL_TABLE_NODES;
  std::array<int, 3> solved_by;  // the first channel of the same albedo
  std::array<std::future<slab::SlabFunctions>, 3> solves;
  for (int c = 0; c < 3; ++c) {
    solved_by[c] = int(std::find(albedo.begin(), albedo.begin() + c, albedo[c]) - albedo.begin());
    if (solved_by[c] == c) solves[c] = std::async(std::launch::async, slab::SolveSlab, tau, albedo[c], mu,
                                                  slab::AddingDoublingOptions{});
  }
  double worst = 0;
  for (int c = 0; c < 3; ++c) {
    double* reflection = data->data() + TL_MATERIAL_SIZE + 2 * c * TL_TABLE_SIZE;
    double* transmission = reflection + TL_TABLE_SIZE;
    if (solved_by[c] < c) {
      const double* from = data->data() + TL_MATERIAL_SIZE + 2 * solved_by[c] * TL_TABLE_SIZE;
      std::copy(from, from + 2 * TL_TABLE_SIZE, reflection);
      continue;
    }
    const slab::SlabFunctions s = solves[c].get();
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) {
        // Symmetrised (the solver's two halves agree to rounding), so the kernel's lookup is reciprocal.
        const size_t ij = s.index(i, j), ji = s.index(j, i);
        reflection[i * n + j] = 0.5 * (s.reflection_multiple[ij] + s.reflection_multiple[ji]);
        transmission[i * n + j] = 0.5 * (s.transmission_multiple[ij] + s.transmission_multiple[ji]);
        if (mu[i] < kErrorMinCosine || mu[j] < kErrorMinCosine) continue;
        for (const auto& [all, multiple] : {std::pair(s.reflection[ij], s.reflection_multiple[ij]),
                                            std::pair(s.transmission[ij], s.transmission_multiple[ij])})
          if (all > 0) worst = std::max(worst, std::fabs(multiple) / all);
      }
    // At mu = mu0 = 0 the multiply scattered reflection diverges like log(1 / mu): the corner takes its
    // diagonal neighbour's value (the solver's corner value misses the divergent second order entirely).
    reflection[0] = reflection[n + 1];
  }
  return worst;
}

std::vector<ParamSpec> Schema() {
  return {
      {"tau", ParamType::kReal, "1", 0.0, 100.0, {0.5},
       "optical thickness of the layer (single scattering: with albedo 1 about 10% below all scattering orders "
       "in reflection at 0.05, 35% at 0.2)", 1, 1},
      {"albedo", ParamType::kRgb, "1", 0.0, 1.0, {0.8, 0.8, 0.8}, "single-scattering albedo Lambda (linear RGB)",
       3, 3},
      {"scattering", ParamType::kInt, "1", 0, 1, {TL_SCATTERING_SINGLE},
       "0: single scattering (closed form); 1: all scattering orders (adding-doubling tables, within 0.5% of "
       "the exact plane-parallel f)", 1, 1},
  };
}

// tau sets how much light passes unscattered, exp(-tau) at normal incidence; albedo the fibres' colour.
std::vector<PresetSpec> Presets() {
  return {
      {"sheer_voile",
       "Sheer white polyester voile: an open weave, 86% of normal light passes unscattered (tau 0.15), "
       "near-white fibres (albedo 0.95)",
       {{"tau", {0.15}}, {"albedo", {0.95, 0.95, 0.93}}}},
      {"cotton_curtain",
       "Medium-weight undyed cotton curtain: about 45% direct transmission at normal incidence (tau 0.8), "
       "warm off-white (albedo 0.85, 0.80, 0.70)",
       {{"tau", {0.8}}, {"albedo", {0.85, 0.80, 0.70}}}},
      {"linen_blind",
       "Dense natural linen roller blind: 8% direct transmission (tau 2.5), so its glow is mostly scattered "
       "light; flax's beige absorbs blue (albedo 0.75, 0.68, 0.55)",
       {{"tau", {2.5}}, {"albedo", {0.75, 0.68, 0.55}}}},
  };
}

class ThinLayerModel : public Model {
 public:
  std::string name() const override { return "thin_layer"; }
  std::string description() const override {
    return "Frisvad et al. thin semi-transparent layer: a plane-parallel slab, single scattering (Chandrasekhar's "
           "closed form) or all orders (adding-doubling tables); front-lit reflection and back-lit diffuse "
           "transmission (wi, wo on opposite sides)";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override {
    return {"models/thin_layer.cl", "thin_layer_eval", "", "thin_layer_transmittance"};
  }

  std::string Validate(const ParamValues&) const override { return ""; }  // the schema's ranges suffice

  PackedMaterial PackLayout(const ParamValues& v) const override {
    PackedMaterial m;
    m.uniform = static_cast<int>(v.at("scattering")[0]);
    m.data.assign(TL_PACKED_SIZE, 0.0);
    m.data[0] = v.at("tau")[0];
    const std::vector<double>& albedo = v.at("albedo");
    for (int c = 0; c < 3; ++c) m.data[1 + c] = albedo[c] / (4.0 * M_PI);
    TabulateAllOrders(m.data[0], albedo, &m.data);
    return m;
  }

  bool isotropic() const override { return true; }  // f depends on |n.wi|, |n.wo| and the side only
  // Both modes are symmetric in mu and mu0 and evaluated symmetrically (the all-orders tables are symmetrised
  // and read at (larger, smaller)): bit-exact. Single scattering with albedo <= 1 is part of the exact slab's
  // response, whose reflected plus transmitted fraction is at most 1 - exp(-tau / mu0); all orders stay within
  // the tables' accuracy (0.5% of f) of it.
  bool reciprocal() const override { return true; }
  bool energy_conserving() const override { return true; }
  AccuracyKnob accuracy_knob() const override {
    return {"scattering", {TL_SCATTERING_SINGLE, TL_SCATTERING_ALL},
            "single scattering: its largest relative error against all orders over the adding-doubling table's "
            "nodes with both cosines >= 0.1; all orders: 0 (the tables are within 0.5% of the exact slab)"};
  }
  std::vector<double> KnobErrors(const ParamValues& v) const override {
    std::vector<double> scratch(TL_PACKED_SIZE, 0.0);
    return {TabulateAllOrders(v.at("tau")[0], v.at("albedo"), &scratch), 0.0};
  }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace

}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(thin_layer, ThinLayerModel)
