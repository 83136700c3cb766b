#include "server/models/tabulated_brdf.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdio>
#include <vector>

#include "server/models/rng.h"

namespace loomlight::models {
namespace {
// The kernel's source on the host: double arithmetic over the float table.
namespace tb_host {
typedef double real;
#include "common/shim.h"
#include "models/tabulated_brdf.h"
}  // namespace tb_host

constexpr double kPi = 3.14159265358979323846;
// Nodes on the horizon (the grid's edges) take the pair lifted to this height (n.w): the model's value there is
// 0, the table's the limit from above.
constexpr double kLiftedCos = 1e-5;
// Nodes per NativeEval call: the stop callback is asked between them.
constexpr size_t kChunkNodes = size_t{1} << 15;

class TabulatedKernelModel : public Model {
 public:
  std::string name() const override { return "tabulated_brdf"; }
  std::string description() const override {
    return "A material's BRDF tabulated from its analytic model (server/models/tabulated_brdf.h)";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override { return {"models/tabulated_brdf.cl", "tabulated_brdf_eval"}; }
  std::string Validate(const ParamValues&) const override { return ""; }

 protected:
  // The smallest table (2 nodes on every axis, all 0): what ClRuntime::Warm launches.
  PackedMaterial PackLayout(const ParamValues&) const override {
    PackedMaterial m;
    m.data.assign(TB_HEADER_SIZE + 3 * 16, 0.0);
    for (int axis = 0; axis < 4; ++axis) m.data[axis] = 2;
    return m;
  }

 private:
  std::vector<ParamSpec> schema_;
  std::vector<PresetSpec> presets_;
};

const Registry& KernelRegistryInstance() {
  static const Registry* registry = [] {
    auto* r = new Registry;
    r->Add(std::make_unique<TabulatedKernelModel>());
    return r;
  }();
  return *registry;
}

// wi (or wo) lifted to n.w = kLiftedCos when at or below it, keeping its azimuth.
void LiftAboveHorizon(double* w) {
  if (w[2] >= kLiftedCos) return;
  const double xy = std::hypot(w[0], w[1]);
  const double scale = xy > 0 ? std::sqrt(1 - kLiftedCos * kLiftedCos) / xy : 0;
  w[0] = xy > 0 ? w[0] * scale : std::sqrt(1 - kLiftedCos * kLiftedCos);
  w[1] *= scale;
  w[2] = kLiftedCos;
}

// The inverse of tb_warp: t in [-1, 1] to s = sign(t) (1 - (1 - |t|)^2).
double Unwarp(double t) {
  const double a = 1 - (1 - std::fabs(t)) * (1 - std::fabs(t));
  return t < 0 ? -a : a;
}

// The pair at node (i, j, k, l) (kernels/models/tabulated_brdf.h's axes), lifted above the horizon.
void NodePair(const TabulationGrid& g, int i, int j, int k, int l, double wi[3], double wo[3]) {
  // eta_x, eta_y at +-90 degrees are the horizon itself, where h = (tan, tan, 1) has no direction: nudged in.
  const double edge = kPi / 2 - 1e-6;
  const double eta_x = std::clamp(-kPi / 2 + i * kPi / (g.eta_x - 1), -edge, edge);
  const double eta_y = std::clamp(-kPi / 2 + j * kPi / (g.eta_y - 1), -edge, edge);
  double h[3] = {std::sin(eta_x) * std::cos(eta_y), std::cos(eta_x) * std::sin(eta_y), std::cos(eta_x) * std::cos(eta_y)};
  const double norm = std::sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
  for (double& c : h) c /= norm;
  const double rho = std::hypot(h[0], h[1]);
  const double ex = rho > 1e-12 ? h[0] / rho : 1, ey = rho > 1e-12 ? h[1] / rho : 0;
  const double E[3] = {h[2] * ex, h[2] * ey, -rho}, P[3] = {-ey, ex, 0};
  const double psi = Unwarp(-1 + 2.0 * k / (g.psi - 1)) * std::atan2(h[2], rho);
  const double chi = Unwarp(-1 + 2.0 * l / (g.chi - 1)) * (kPi / 2);
  const double d_par = std::cos(chi) * std::sin(psi), d_perp = std::sin(chi), d_h = std::cos(chi) * std::cos(psi);
  for (int c = 0; c < 3; ++c) {
    wi[c] = d_par * E[c] + d_perp * P[c] + d_h * h[c];
    wo[c] = -d_par * E[c] - d_perp * P[c] + d_h * h[c];
  }
  LiftAboveHorizon(wi);
  LiftAboveHorizon(wo);
}

// A cosine-weighted direction on the upper hemisphere from two uniform numbers.
void CosineDirection(double u1, double u2, float w[3]) {
  const double r = std::sqrt(u1), phi = 2 * kPi * u2;
  w[0] = static_cast<float>(r * std::cos(phi));
  w[1] = static_cast<float>(r * std::sin(phi));
  w[2] = static_cast<float>(std::sqrt(1 - u1));
}

// Linear interpolation between point samples blurs: over a cell its mean exceeds the function's by h^2/12 of the
// second derivative. Each node minus 1/12 of its second difference along each axis (in grid steps; axis by
// axis, in place; the ends unchanged) removes that to second order: half the L1 error of a lobe sampled at 1.5
// nodes per width, for no extra evaluation of the model.
void SharpenForLinearInterpolation(const TabulationGrid& g, float* nodes) {
  const size_t extent[4] = {size_t(g.eta_x), size_t(g.eta_y), size_t(g.psi), size_t(g.chi)};
  size_t stride[4];
  stride[3] = 3;
  for (int a = 2; a >= 0; --a) stride[a] = stride[a + 1] * extent[a + 1];
  const size_t values = 3 * g.nodes();
  std::vector<float> line;
  for (int axis = 0; axis < 4; ++axis) {
    const size_t n = extent[axis], step = stride[axis];
    if (n < 3) continue;
    line.resize(n);
    // Every line along `axis`: its first value runs over the values whose index along `axis` is 0.
    for (size_t first = 0; first < values; ++first) {
      if ((first / step) % n != 0) continue;
      for (size_t i = 0; i < n; ++i) line[i] = nodes[first + i * step];
      for (size_t i = 1; i + 1 < n; ++i)
        nodes[first + i * step] = line[i] - (line[i - 1] + line[i + 1] - 2 * line[i]) / 12;
    }
  }
}

}  // namespace

size_t TabulationGrid::bytes() const { return (TB_HEADER_SIZE + 3 * nodes()) * sizeof(float); }

std::string TabulatedBrdf::PlanGrid(const PreparedMaterial& material, const TabulationBudget& budget,
                                    TabulationGrid* grid) {
  const Model& model = *material.model;
  if (material.transmission) return "a material with a transmission layer is not tabulated";
  if (model.transmission() || !model.fiber_axis_param().empty())
    return "model '" + model.name() + "' is not a reflection model about the surface normal";
  const double lobe = model.NarrowestLobe(material.values);
  if (!(lobe > 0)) return "model '" + model.name() + "' declares no lobe width";
  if (!(budget.nodes_per_lobe > 0) || budget.difference_nodes < 2 || budget.error_pairs == 0)
    return "tabulation budget: nodes_per_lobe must be positive, difference_nodes at least 2 and error_pairs at "
           "least 1";
  // Node counts in double first: a tiny lobe must not overflow an int before the byte bound refuses it.
  const double eta_nodes = std::ceil(kPi / (lobe / budget.nodes_per_lobe)) + 1;
  const double d_nodes = static_cast<double>(budget.difference_nodes);
  const double nodes = eta_nodes * eta_nodes * d_nodes * d_nodes;
  const double bytes = (TB_HEADER_SIZE + 3 * nodes) * sizeof(float);
  if (bytes > static_cast<double>(budget.max_bytes) || 3 * nodes > INT_MAX) {
    char text[200];
    std::snprintf(text, sizeof text,
                  "tabulated BRDF needs %.0f bytes (%.0f x %.0f x %.0f x %.0f nodes for a %.3g degree lobe), over the "
                  "budget of %zu bytes",
                  bytes, eta_nodes, eta_nodes, d_nodes, d_nodes, lobe * 180 / kPi, budget.max_bytes);
    return text;
  }
  grid->eta_x = grid->eta_y = static_cast<int>(eta_nodes);
  grid->psi = grid->chi = static_cast<int>(d_nodes);
  return "";
}

std::string TabulatedBrdf::Build(const PreparedMaterial& material, const TabulationBudget& budget,
                                 const std::function<bool()>& stop, std::shared_ptr<const TabulatedBrdf>* out) {
  TabulationGrid grid;
  if (std::string error = PlanGrid(material, budget, &grid); !error.empty()) return error;
  const Model& model = *material.model;
  std::vector<float> table(TB_HEADER_SIZE + 3 * grid.nodes(), 0.0f);
  table[0] = static_cast<float>(grid.eta_x);
  table[1] = static_cast<float>(grid.eta_y);
  table[2] = static_cast<float>(grid.psi);
  table[3] = static_cast<float>(grid.chi);

  // Nodes in chunks through the model's float host build (every core), X = f (n.wi) of the lifted pair.
  std::vector<float> wi(3 * kChunkNodes), wo(3 * kChunkNodes), f(3 * kChunkNodes);
  std::vector<double> cos_i(kChunkNodes);
  const size_t per_eta_y = size_t(grid.psi) * grid.chi, per_eta_x = per_eta_y * grid.eta_y;
  for (size_t first = 0; first < grid.nodes(); first += kChunkNodes) {
    if (stop && stop()) return "stopped";
    const size_t count = std::min(kChunkNodes, grid.nodes() - first);
    for (size_t q = 0; q < count; ++q) {
      const size_t node = first + q;
      const int i = static_cast<int>(node / per_eta_x), j = static_cast<int>(node / per_eta_y % grid.eta_y);
      const int k = static_cast<int>(node / grid.chi % grid.psi), l = static_cast<int>(node % grid.chi);
      double a[3], b[3];
      NodePair(grid, i, j, k, l, a, b);
      for (int c = 0; c < 3; ++c) {
        wi[3 * q + c] = static_cast<float>(a[c]);
        wo[3 * q + c] = static_cast<float>(b[c]);
      }
      cos_i[q] = a[2];
    }
    model.NativeEval(material.packed, wi.data(), wo.data(), nullptr, count, f.data());
    for (size_t q = 0; q < count; ++q)
      for (int c = 0; c < 3; ++c) {
        const double x = static_cast<double>(f[3 * q + c]) * cos_i[q];
        table[TB_HEADER_SIZE + 3 * (first + q) + c] = std::isfinite(x) && x > 0 ? static_cast<float>(x) : 0.0f;
      }
  }

  SharpenForLinearInterpolation(grid, table.data() + TB_HEADER_SIZE);

  std::shared_ptr<TabulatedBrdf> t(new TabulatedBrdf);
  t->grid_ = grid;
  t->source_model_ = &model;
  t->packed_.tables = std::make_shared<PackedTables>(std::move(table));

  // The error on cosine-weighted pairs against the double reference.
  const size_t n = budget.error_pairs;
  std::vector<float> ei(3 * n), eo(3 * n);
  for (size_t q = 0; q < n; ++q) {
    const CounterRng rng(budget.error_seed, q);
    CosineDirection(rng.Uniform(0), rng.Uniform(1), &ei[3 * q]);
    CosineDirection(rng.Uniform(2), rng.Uniform(3), &eo[3 * q]);
  }
  std::vector<double> reference(3 * n), tabulated(3 * n);
  model.ReferenceEval(material.packed, ei.data(), eo.data(), nullptr, n, reference.data());
  t->Evaluate(ei.data(), eo.data(), n, tabulated.data());
  for (int c = 0; c < 3; ++c) {
    double diff = 0, sum = 0;
    for (size_t q = 0; q < n; ++q) {
      diff += std::fabs(tabulated[3 * q + c] - reference[3 * q + c]);
      sum += std::fabs(reference[3 * q + c]);
    }
    t->error_[c] = sum > 0 ? diff / sum : (diff > 0 ? 1.0 : 0.0);
  }
  *out = std::move(t);
  return "";
}

std::array<double, 3> TabulatedBrdf::Evaluate(const double wi[3], const double wo[3]) const {
  std::array<double, 3> f;
  tb_host::tb_eval(packed_.values32(), 0, wi[0], wi[1], wi[2], wo[0], wo[1], wo[2], f.data());
  return f;
}

void TabulatedBrdf::Evaluate(const float* wi, const float* wo, size_t n, double* f) const {
  for (size_t q = 0; q < n; ++q) {
    const double a[3] = {wi[3 * q], wi[3 * q + 1], wi[3 * q + 2]}, b[3] = {wo[3 * q], wo[3 * q + 1], wo[3 * q + 2]};
    const std::array<double, 3> v = Evaluate(a, b);
    std::copy(v.begin(), v.end(), f + 3 * q);
  }
}

const Model& TabulatedBrdf::KernelModel() { return *KernelRegistryInstance().models()[0]; }
const Registry& TabulatedBrdf::KernelRegistry() { return KernelRegistryInstance(); }

}  // namespace loomlight::models
