// Registry entry of the microcylinder cloth model (Sadeghi et al. 2012, SPEC.md section 2): schema,
// presets of the paper's Tables 2 and 3, validation and packing into the kernel's material layout.
#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::models {
namespace {
// The tangent curve (mc_curve_offset) of the shared source, in double.
namespace mc_source {
typedef double real;
#include "common/shim.h"
#include "models/microcylinder.h"
}  // namespace mc_source

constexpr int kDefaultTangentSamples = 32;
constexpr int kMaxTangentSamples = 256;  // MC_MAX_TANGENT_SAMPLES
constexpr size_t kMaxControlPoints = 64;
constexpr double kDegree = M_PI / 180.0;

// cos and sin of an angle in degrees, exact at multiples of 90 so vertical tangents are exactly vertical.
void CosSinDegrees(double deg, double* c, double* s) {
  const double quarter = deg / 90.0;
  if (quarter == std::round(quarter)) {
    const int k = ((static_cast<int>(quarter) % 4) + 4) % 4;
    const double cs[4] = {1, 0, -1, 0}, sn[4] = {0, 1, 0, -1};
    *c = cs[k];
    *s = sn[k];
    return;
  }
  *c = std::cos(deg * kDegree);
  *s = std::sin(deg * kDegree);
}

std::vector<ParamSpec> ThreadParams(const std::string& t, const std::string& axis) {
  const std::string p = t + ".";
  return {
      {p + "coverage", ParamType::kReal, "1", 0.0, 1.0, {0.5}, "area fraction a of the " + t + " (along " + axis + ")", 1, 1},
      {p + "albedo", ParamType::kRgb, "1", 0.0, 1.0, {0.3, 0.3, 0.3}, "volume scattering albedo A (linear RGB)", 3, 3},
      {p + "kd", ParamType::kReal, "1", 0.0, 1.0, {0.3}, "isotropic part of volume scattering", 1, 1},
      {p + "gamma_s", ParamType::kReal, "deg", 0.1, 90.0, {12.0}, "surface reflection Gaussian width", 1, 1},
      {p + "gamma_v", ParamType::kReal, "deg", 0.1, 90.0, {24.0}, "volume scattering Gaussian width", 1, 1},
      {p + "tangent_offsets", ParamType::kRealList, "deg", -90.0, 90.0, {0.0, 0.0},
       "tangent elevation at the control points of the tangent curve", 2, kMaxControlPoints},
      {p + "tangent_lengths", ParamType::kRealList, "1", 0.0, 1000.0, {1.0},
       "segment lengths between control points (one fewer than offsets; 0 is a jump)", 1, kMaxControlPoints - 1},
  };
}

std::vector<ParamSpec> Schema() {
  std::vector<ParamSpec> s = {
      {"eta", ParamType::kReal, "1", 1.0, 3.0, {1.46}, "refractive index of the fibres", 1, 1},
      {"tangent_samples", ParamType::kInt, "1", 1, kMaxTangentSamples, {kDefaultTangentSamples},
       "tangent curve samples T per thread (accuracy against speed)", 1, 1},
  };
  for (auto& p : ThreadParams("thread1", "x, texture u")) s.push_back(p);
  for (auto& p : ThreadParams("thread2", "y, texture v")) s.push_back(p);
  return s;
}

// Table 2 parameters of one thread and its Table 3 curve.
ParamValues Thread(const std::string& t, double a, std::vector<double> rgb, double factor, double kd,
                   double gamma_s, double gamma_v, std::vector<double> offsets, std::vector<double> lengths) {
  for (double& c : rgb) c *= factor;
  return {{t + ".coverage", {a}},         {t + ".albedo", rgb},
          {t + ".kd", {kd}},              {t + ".gamma_s", {gamma_s}},
          {t + ".gamma_v", {gamma_v}},    {t + ".tangent_offsets", offsets},
          {t + ".tangent_lengths", lengths}};
}

PresetSpec Preset(std::string name, std::string description, double eta, ParamValues t1, ParamValues t2) {
  ParamValues v = {{"eta", {eta}}};
  v.merge(t1);
  v.merge(t2);
  return {std::move(name), std::move(description), std::move(v)};
}

std::vector<PresetSpec> Presets() {
  return {
      Preset("linen_plain", "Linen plain weave, one thread type in both directions (Tables 2, 3a)", 1.46,
             Thread("thread1", 0.33, {0.2, 0.8, 1}, 0.3, 0.3, 12, 24, {25, 25}, {1}),
             Thread("thread2", 0.33, {0.2, 0.8, 1}, 0.3, 0.3, 12, 24, {25, 25}, {1})),
      Preset("silk_crepe_de_chine", "Silk crepe de chine: flat threads along x, twisted along y (Tables 2, 3b)",
             1.345, Thread("thread1", 0.75, {1, 0.95, 0.05}, 0.12, 0.2, 5, 10, {-35, -35, 35, 35}, {1, 1, 1}),
             Thread("thread2", 0.25, {1, 0.95, 0.05}, 0.16, 0.3, 18, 32, {0, 0}, {1})),
      Preset("polyester_satin_charmeuse_front",
             "Polyester satin charmeuse, front face: flat threads along x, twisted along y (Tables 2, 3c)", 1.539,
             Thread("thread1", 0.9, {1, 0.37, 0.3}, 0.035, 0.1, 2.5, 5, {-32, -32, -18, 0, 0, 18, 32, 32},
                    {1.33, 0.66, 2, 2, 2, 0.66, 1.33}),
             Thread("thread2", 0.1, {1, 0.37, 0.3}, 0.2, 0.7, 30, 60, {0, 0}, {1})),
      Preset("polyester_satin_charmeuse_back",
             "Polyester satin charmeuse, back face: Table 2 satin threads with the Table 3d curves", 1.539,
             // Table 3d lists six lengths for eight control points: its two curve pieces (the +-30 and the
             // +-5 degree floats of Figure 19d) are joined here by a jump, a zero-length segment.
             Thread("thread1", 0.67, {1, 0.37, 0.3}, 0.035, 0.1, 2.5, 5, {-30, -30, 30, 30, -5, -5, 5, 5},
                    {1.33, 1.33, 1.33, 0, 0.67, 0.67, 0.67}),
             Thread("thread2", 0.33, {1, 0.37, 0.3}, 0.2, 0.7, 30, 60, {0, 0}, {3})),
      Preset("silk_shot", "Silk shot fabric: green-tinted threads along x, red along y (Tables 2, 3e)", 1.345,
             Thread("thread1", 0.86, {0.1, 1, 0.4}, 0.2, 0.1, 4, 8, {-25, -25, 25, 25}, {1.33, 2.67, 1.33}),
             Thread("thread2", 0.14, {1, 0, 0.1}, 0.6, 0.1, 5, 10, {0, 0}, {1})),
      Preset("velvet", "Velvet: near-vertical pile tangents, the second curve with a jump (Tables 2, 3f)", 1.46,
             Thread("thread1", 0.5, {0.05, 0.02, 0}, 0.3, 0.1, 6, 12, {-90, -50}, {1}),
             Thread("thread2", 0.5, {0.05, 0.02, 0}, 0.3, 0.1, 6, 12, {-90, -55, 55, 90}, {0.5, 0, 0.5})),
  };
}

class MicrocylinderModel : public Model {
 public:
  std::string name() const override { return "microcylinder"; }
  std::string description() const override {
    return "Sadeghi et al. 2012 microcylinder cloth BRDF: two orthogonal thread families with tangent curves, "
           "masking and reweighting (reflection only)";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  AccuracyKnob accuracy_knob() const override {
    // Tangent curve samples per thread: 9% at 16 and 1% at 32 against 256 (the satin front:
    // bench/report-kernel.md, section 2).
    return {"tangent_samples", {8, 16, 32, 64, 128, kMaxTangentSamples},
            "Evaluate: relative L1 of the double reference against the last setting over fixed direction pairs "
            "(accuracy::MeasureKnobErrors); Render: relative L1 of the pilot radiance against the last setting",
            16};
  }
  KernelSpec kernel() const override { return {"models/microcylinder.cl", "microcylinder_eval", ""}; }
  // The surface and volume Gaussians' widths in theta_h (SPEC.md section 2), the narrower of both threads'.
  double NarrowestLobe(const ParamValues& v) const override {
    double lobe = 90;
    for (const char* t : {"thread1.", "thread2."})
      lobe = std::min({lobe, v.at(std::string(t) + "gamma_s")[0], v.at(std::string(t) + "gamma_v")[0]});
    return lobe * kDegree;
  }

  std::string Validate(const ParamValues& v) const override {
    for (const char* t : {"thread1", "thread2"}) {
      const std::string offsets = std::string(t) + ".tangent_offsets";
      const std::string lengths = std::string(t) + ".tangent_lengths";
      if (v.at(lengths).size() + 1 != v.at(offsets).size())
        return lengths + ": needs one value fewer than " + offsets + " (" +
               std::to_string(v.at(offsets).size() - 1) + "), got " + std::to_string(v.at(lengths).size());
      const auto& l = v.at(lengths);
      if (std::accumulate(l.begin(), l.end(), 0.0) <= 0.0) return lengths + ": total length must be positive";
    }
    if (v.at("thread1.coverage")[0] + v.at("thread2.coverage")[0] <= 0.0)
      return "thread1.coverage: thread1.coverage + thread2.coverage must be positive";
    return "";
  }

  PackedMaterial PackLayout(const ParamValues& v) const override {
    const int T = static_cast<int>(v.at("tangent_samples")[0]);
    PackedMaterial m;
    m.uniform = T;
    m.data.push_back(v.at("eta")[0]);
    for (const char* t : {"thread1", "thread2"}) {
      const std::string p = std::string(t) + ".";
      const auto& albedo = v.at(p + "albedo");
      m.data.insert(m.data.end(), {v.at(p + "coverage")[0], albedo[0], albedo[1], albedo[2], v.at(p + "kd")[0],
                                   v.at(p + "gamma_s")[0] * kDegree, v.at(p + "gamma_v")[0] * kDegree});
      const auto& offsets = v.at(p + "tangent_offsets");
      const auto& lengths = v.at(p + "tangent_lengths");
      const double total = std::accumulate(lengths.begin(), lengths.end(), 0.0);
      // Arc-length midpoints s_m = (m + 1/2) L / T (SPEC.md section 2); on a flat stretch they are equal, so
      // each distinct one is kept once with how many samples it stands for (kernels/models/microcylinder.h).
      std::vector<double> distinct;
      std::vector<int> counts;
      for (int k = 0; k < T; ++k) {
        const double offset = mc_source::mc_curve_offset(offsets.data(), lengths.data(), static_cast<int>(offsets.size()),
                                                         (k + 0.5) * total / T);
        if (!distinct.empty() && offset == distinct.back()) {
          ++counts.back();
        } else {
          distinct.push_back(offset);
          counts.push_back(1);
        }
      }
      m.data.push_back(static_cast<double>(distinct.size()));
      for (size_t k = 0; k < distinct.size(); ++k) {
        double c, sn;
        CosSinDegrees(distinct[k], &c, &sn);
        m.data.push_back(counts[k] * c);
        m.data.push_back(counts[k] * sn);
      }
    }
    return m;
  }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace

}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(microcylinder, MicrocylinderModel)
