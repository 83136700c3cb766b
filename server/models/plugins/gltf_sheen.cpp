// Registry entry of the glTF 2.0 metallic-roughness material (metallic 0) with KHR_materials_sheen
// (kernels/models/gltf_sheen.h, docs/models.md "Standard lobes for export"): the lobe a fitted cloth is exported
// as to glTF. Packing takes the Charlie lobe's albedo E(mu) at the material's sheen alpha from a table over
// (mu, sheen_roughness) built once per process.
#include <algorithm>
#include <cmath>

#include "server/models/registry.h"
#include "server/models/standard/microfacet_albedo.h"

namespace loomlight::models {
namespace {
namespace gs_layout {
typedef double real;
#include "common/shim.h"
#include "common/ggx.h"
#include "models/gltf_sheen.h"
}  // namespace gs_layout
using gs_layout::real;  // what the layout's macros (R, LL_HORIZON_EPS) name

constexpr int kRoughnessNodes = 33;  // sheen_roughness uniform on [sqrt(GS_SHEEN_ALPHA_MIN), 1]
constexpr int kQuadratureNodes = 96;

double SheenAlpha(double sheen_roughness) { return std::max(sheen_roughness * sheen_roughness, GS_SHEEN_ALPHA_MIN); }

// The directional albedo of the Charlie lobe (sheen_color 1) with the README's visibility, at cosine mu: the
// kernel's own D and V (double build). D cos(theta_h) has the cumulative distribution sin(theta_h)^(2 + 1/alpha).
// Clamped to 1 as MaterialX clamps the sheen albedo: near grazing the fitted visibility lets E exceed 1
// (docs/models.md), and the albedo scaling 1 - E must stay a fraction.
double CharlieAlbedo(double alpha, double mu) {
  double fit[6];
  gs_layout::gs_visibility_fit(alpha, fit);
  const double e = standard::MicrofacetAlbedo(
      mu, [&](double u) { return std::pow(u, 1 / (2 + 1 / alpha)); },
      [&](double mu_l, double) { return gs_layout::gs_charlie_visibility(fit, mu_l, mu); }, kQuadratureNodes);
  return std::min(e, 1.0);
}

struct AlbedoTable {
  std::vector<double> roughness;  // sheen_roughness of each row
  std::vector<double> mu;         // the kernel's nodes (GS_ALBEDO_NODES)
  std::vector<double> values;     // [row * GS_ALBEDO_NODES + k]
};

const AlbedoTable& CharlieAlbedoTable() {
  static const AlbedoTable table = [] {
    AlbedoTable t;
    const double r0 = std::sqrt(GS_SHEEN_ALPHA_MIN);
    for (int i = 0; i < kRoughnessNodes; ++i) t.roughness.push_back(r0 + (1 - r0) * i / (kRoughnessNodes - 1));
    t.mu = standard::SqrtSpacedCosines(GS_ALBEDO_NODES, LL_HORIZON_EPS);
    t.values = standard::ParallelTable(kRoughnessNodes, GS_ALBEDO_NODES, [&](int i, int k) {
      return CharlieAlbedo(SheenAlpha(t.roughness[i]), t.mu[k]);
    });
    return t;
  }();
  return table;
}

std::vector<ParamSpec> Schema() {
  return {
      {"base_color", ParamType::kRgb, "1", 0.0, 1.0, {0.5, 0.5, 0.5},
       "baseColorFactor (linear RGB): the diffuse albedo under the dielectric specular", 3, 3},
      {"roughness", ParamType::kReal, "1", 0.0, 1.0, {0.8},
       "roughnessFactor: the GGX specular's alpha is its square (metallic 0, ior 1.5)", 1, 1},
      {"sheen_color", ParamType::kRgb, "1", 0.0, 1.0, {0.0, 0.0, 0.0},
       "KHR_materials_sheen sheenColorFactor (linear RGB): 0 disables the sheen", 3, 3},
      {"sheen_roughness", ParamType::kReal, "1", 0.0, 1.0, {0.0},
       "KHR_materials_sheen sheenRoughnessFactor: the Charlie alpha is its square (at least 0.005)", 1, 1},
  };
}

std::vector<PresetSpec> Presets() {
  return {
      {"gltf_velvet",
       "KHR_materials_sheen's velvet example: white sheen (0.9) over a dark red base, rough (roughness 0.9) with a "
       "soft sheen (sheen_roughness 0.5)",
       {{"base_color", {0.3, 0.02, 0.04}}, {"roughness", {0.9}}, {"sheen_color", {0.9, 0.9, 0.9}},
        {"sheen_roughness", {0.5}}}},
      {"gltf_cushion",
       "The README's cushion: a rough blue base (roughness 1) with a narrow bright sheen at grazing "
       "(sheen_roughness 0.3)",
       {{"base_color", {0.05, 0.1, 0.35}}, {"roughness", {1.0}}, {"sheen_color", {0.6, 0.7, 1.0}},
        {"sheen_roughness", {0.3}}}},
  };
}

class GltfSheenModel : public Model {
 public:
  std::string name() const override { return "gltf_sheen"; }
  std::string description() const override {
    return "glTF 2.0 metallic-roughness (metallic 0, ior 1.5) with KHR_materials_sheen: Charlie sheen with the "
           "Conty-Kulla visibility over the Appendix B base, albedo-scaled; the lobe glTF exports carry";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override { return {"models/gltf_sheen.cl", "gltf_sheen_eval"}; }
  std::string Validate(const ParamValues&) const override { return ""; }  // the schema's ranges suffice

  PackedMaterial PackLayout(const ParamValues& v) const override {
    PackedMaterial m;
    m.data.assign(GS_PACKED_SIZE, 0.0);
    const std::vector<double>& base = v.at("base_color");
    const std::vector<double>& sheen = v.at("sheen_color");
    const double alpha_b = gs_layout::ll_ggx_alpha(v.at("roughness")[0]);
    const double sheen_roughness = v.at("sheen_roughness")[0];
    for (int c = 0; c < 3; ++c) m.data[c] = base[c] / M_PI;
    m.data[3] = alpha_b * alpha_b;
    for (int c = 0; c < 3; ++c) m.data[4 + c] = sheen[c];
    m.data[7] = std::max({sheen[0], sheen[1], sheen[2]});
    const double alpha_s = SheenAlpha(sheen_roughness);
    m.data[8] = 1 / alpha_s;
    gs_layout::gs_visibility_fit(alpha_s, m.data.data() + 9);
    const AlbedoTable& table = CharlieAlbedoTable();
    const std::vector<double> slice = standard::InterpolateRow(table.values, table.roughness, GS_ALBEDO_NODES,
                                                               sheen_roughness);
    std::copy(slice.begin(), slice.end(), m.data.begin() + GS_ALBEDO_AT);
    return m;
  }

  bool isotropic() const override { return true; }  // f depends on the two cosines and the angle between wi, wo
  // Every term is symmetric in (wi, wo), and the albedo scaling takes the larger of E(N.L) and E(N.V).
  bool reciprocal() const override { return true; }
  // Not energy conserving: the fitted Charlie visibility lets the sheen alone reflect more than 1 near grazing
  // (docs/models.md "Standard lobes for export").
  bool energy_conserving() const override { return false; }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace
}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(gltf_sheen, GltfSheenModel)
