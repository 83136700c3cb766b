// Registry entry of OpenPBR Surface's dielectric base under fuzz (kernels/models/openpbr.h, docs/models.md
// "Standard lobes for export"): the lobe a fitted cloth is exported as to MaterialX. Packing takes the specular
// lobe's albedo E_spec(mu) at the material's roughness and ior from a table over (mu, specular_roughness, ior)
// built once per process.
#include <algorithm>
#include <cmath>

#include "server/models/registry.h"
#include "server/models/standard/microfacet_albedo.h"

namespace loomlight::models {
namespace {
namespace op_layout {
typedef double real;
#include "common/shim.h"
#include "common/ggx.h"
#include "models/openpbr.h"
}  // namespace op_layout
using op_layout::real;  // what the layout's macros (R, LL_HORIZON_EPS) name

constexpr int kRoughnessNodes = 33;  // specular_roughness uniform on [0, 1]
// specular_ior at x = sqrt((eta - 1) / 2) uniform on [0, 1] (eta 1 to 3): near eta = 1 the albedo grows like
// sqrt(eta - 1) (Fresnel's grazing rise narrows to cosines below sqrt(eta^2 - 1)), linear in x.
constexpr int kIorNodes = 17;
constexpr int kQuadratureNodes = 48;

double IorCoordinate(double eta) { return std::sqrt((eta - 1) / 2); }

// The directional albedo of f_spec at cosine mu: the kernel's own Fresnel and G2 / (4 N.L N.V) (double build).
// GGX's D(h) cos(theta_h) has tan^2(theta_h) = alpha^2 u / (1 - u) for u uniform.
double SpecularAlbedo(double alpha, double eta, double mu) {
  const double alpha2 = alpha * alpha;
  return standard::MicrofacetAlbedo(
      mu, [&](double u) { return std::sqrt(alpha2 * u / (1 - u + alpha2 * u)); },
      [&](double mu_l, double o_dot_h) {
        return op_layout::ll_fresnel_dielectric(eta, o_dot_h) * op_layout::ll_ggx_visibility(alpha2, mu_l, mu);
      },
      kQuadratureNodes);
}

struct AlbedoTable {
  std::vector<double> roughness, ior;  // the rows' specular_roughness and specular_ior
  std::vector<double> mu;              // the kernel's nodes (OP_ALBEDO_NODES)
  std::vector<double> values;          // [(ior_row * kRoughnessNodes + row) * OP_ALBEDO_NODES + k]
};

const AlbedoTable& SpecularAlbedoTable() {
  static const AlbedoTable table = [] {
    AlbedoTable t;
    for (int i = 0; i < kRoughnessNodes; ++i) t.roughness.push_back(double(i) / (kRoughnessNodes - 1));
    for (int j = 0; j < kIorNodes; ++j) t.ior.push_back(1 + 2 * std::pow(double(j) / (kIorNodes - 1), 2));
    t.mu = standard::SqrtSpacedCosines(OP_ALBEDO_NODES, LL_HORIZON_EPS);
    t.values = standard::ParallelTable(kIorNodes * kRoughnessNodes, OP_ALBEDO_NODES, [&](int row, int k) {
      const double alpha = op_layout::ll_ggx_alpha(t.roughness[row % kRoughnessNodes]);
      return SpecularAlbedo(alpha, t.ior[row / kRoughnessNodes], t.mu[k]);
    });
    return t;
  }();
  return table;
}

// E_spec at the kernel's nodes for (roughness, eta): bilinear in (roughness, sqrt((eta - 1) / 2)).
std::vector<double> SpecularAlbedoSlice(double roughness, double eta) {
  const AlbedoTable& t = SpecularAlbedoTable();
  const size_t slab = size_t(kRoughnessNodes) * OP_ALBEDO_NODES;
  const double x = std::clamp(IorCoordinate(eta) * (kIorNodes - 1), 0.0, double(kIorNodes - 1));
  const int j = std::min(int(x), kIorNodes - 2);
  std::vector<double> rows[2];
  for (int side = 0; side < 2; ++side) {
    const std::vector<double> one(t.values.begin() + (j + side) * slab, t.values.begin() + (j + side + 1) * slab);
    rows[side] = standard::InterpolateRow(one, t.roughness, OP_ALBEDO_NODES, roughness);
  }
  for (int k = 0; k < OP_ALBEDO_NODES; ++k) rows[0][k] += (x - j) * (rows[1][k] - rows[0][k]);
  return rows[0];
}

std::vector<ParamSpec> Schema() {
  return {
      {"base_color", ParamType::kRgb, "1", 0.0, 1.0, {0.8, 0.8, 0.8},
       "base_color (linear RGB): the diffuse albedo under the dielectric specular (base_weight 1, metalness 0)", 3,
       3},
      {"specular_roughness", ParamType::kReal, "1", 0.0, 1.0, {0.3},
       "specular_roughness: the GGX alpha is its square", 1, 1},
      {"specular_ior", ParamType::kReal, "1", 1.0, 3.0, {1.5},
       "specular_ior: the dielectric's index of refraction (exact Fresnel)", 1, 1},
      {"fuzz_weight", ParamType::kReal, "1", 0.0, 1.0, {0.0}, "fuzz_weight: the fuzz layer's coverage", 1, 1},
      {"fuzz_color", ParamType::kRgb, "1", 0.0, 1.0, {1.0, 1.0, 1.0}, "fuzz_color (linear RGB)", 3, 3},
      {"fuzz_roughness", ParamType::kReal, "1", 0.0, 1.0, {0.5},
       "fuzz_roughness: Zeltner et al.'s LTC sheen roughness (read as at least 0.01, the fits' range)", 1, 1},
  };
}

std::vector<PresetSpec> Presets() {
  return {
      {"openpbr_velvet",
       "Velvet as OpenPBR writes it: a deep red rough base with full white-ish fuzz (fuzz_weight 1, "
       "fuzz_roughness 0.5)",
       {{"base_color", {0.35, 0.02, 0.05}}, {"specular_roughness", {0.8}}, {"fuzz_weight", {1.0}},
        {"fuzz_color", {0.9, 0.85, 0.85}}, {"fuzz_roughness", {0.5}}}},
      {"openpbr_cotton",
       "Matte cotton: an off-white rough base with a light, rough fuzz (fuzz_weight 0.5, fuzz_roughness 0.8)",
       {{"base_color", {0.75, 0.72, 0.66}}, {"specular_roughness", {0.9}}, {"fuzz_weight", {0.5}},
        {"fuzz_color", {1.0, 1.0, 1.0}}, {"fuzz_roughness", {0.8}}}},
  };
}

class OpenPbrModel : public Model {
 public:
  std::string name() const override { return "openpbr"; }
  std::string description() const override {
    return "OpenPBR Surface 1.1 (as MaterialX's open_pbr_surface) reduced to a dielectric base (GGX, exact "
           "Fresnel, albedo-scaled diffuse) under Zeltner et al.'s LTC fuzz; the lobe MaterialX exports carry";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override { return {"models/openpbr.cl", "openpbr_eval"}; }
  std::string Validate(const ParamValues&) const override { return ""; }  // the schema's ranges suffice

  PackedMaterial PackLayout(const ParamValues& v) const override {
    PackedMaterial m;
    m.data.assign(OP_PACKED_SIZE, 0.0);
    const std::vector<double>& base = v.at("base_color");
    const std::vector<double>& fuzz = v.at("fuzz_color");
    const double roughness = v.at("specular_roughness")[0], eta = v.at("specular_ior")[0];
    const double fuzz_weight = v.at("fuzz_weight")[0];
    for (int c = 0; c < 3; ++c) m.data[c] = base[c] / M_PI;
    m.data[3] = std::pow(op_layout::ll_ggx_alpha(roughness), 2);
    m.data[4] = eta;
    for (int c = 0; c < 3; ++c) m.data[5 + c] = fuzz_weight * fuzz[c];
    m.data[8] = fuzz_weight;
    m.data[9] = std::clamp(v.at("fuzz_roughness")[0], OP_FUZZ_ROUGHNESS_MIN, 1.0);
    op_layout::op_fuzz_albedo_fit(m.data[9], m.data.data() + 10);
    const std::vector<double> slice = SpecularAlbedoSlice(roughness, eta);
    std::copy(slice.begin(), slice.end(), m.data.begin() + OP_ALBEDO_AT);
    return m;
  }

  bool isotropic() const override { return true; }  // the fuzz's frame turns with V: no fixed azimuth

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace
}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(openpbr, OpenPbrModel)
