// Registry entry of the thin semi-transparent layer (Frisvad et al., SPEC.md section 4): schema, presets,
// packing into kernels/models/thin_layer.h's layout. Single scattering only (issue 4 item 6, the all-orders
// mode, is not wired in); wi and wo on opposite sides of the layer give its diffuse transmission.
#include <cmath>

#include "server/models/host_models.h"
#include "server/models/registry.h"

namespace loomlight::models {
namespace {

constexpr int kMaterialSize = 4;  // TL_MATERIAL_SIZE

std::vector<ParamSpec> Schema() {
  return {
      {"tau", ParamType::kReal, "1", 0.0, 100.0, {0.5},
       "optical thickness of the layer (single scattering: with albedo 1 about 10% below all scattering orders "
       "in reflection at 0.05, 35% at 0.2)", 1, 1},
      {"albedo", ParamType::kRgb, "1", 0.0, 1.0, {0.8, 0.8, 0.8}, "single-scattering albedo Lambda (linear RGB)",
       3, 3},
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
    return "Frisvad et al. thin semi-transparent layer: Chandrasekhar's single scattering in a plane-parallel "
           "slab, front-lit reflection and back-lit diffuse transmission (wi, wo on opposite sides)";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override { return {"models/thin_layer.cl", "thin_layer_eval", ""}; }

  std::string Validate(const ParamValues&) const override { return ""; }  // the schema's ranges suffice

  PackedMaterial Pack(const ParamValues& v) const override {
    PackedMaterial m;
    m.data.reserve(kMaterialSize);
    m.data.push_back(v.at("tau")[0]);
    for (double a : v.at("albedo")) m.data.push_back(a / (4.0 * M_PI));
    return m;
  }

  void ReferenceEval(const PackedMaterial& m, const float* wi, const float* wo, const float*, size_t n,
                     double* f) const override {
    reference::ThinLayerEval(m.data.data(), wi, wo, n, f);
  }
  void NativeEval(const PackedMaterial& m, const float* wi, const float* wo, const float*, size_t n,
                  float* f) const override {
    const std::vector<float> data(m.data.begin(), m.data.end());
    native::ThinLayerEval(data.data(), wi, wo, n, f);
  }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace

std::unique_ptr<Model> MakeThinLayerModel() { return std::make_unique<ThinLayerModel>(); }

}  // namespace loomlight::models
