// Registry entry of the woven-cotton model (Irawan and Marschner 2006, SPEC.md section 3): schema, the
// paper's twill preset and our plain and sateen, patterns as cell matrices or WIF drafts, validation and
// packing. Served as the BTF (queries with uv) and as the BRDF (the mean of the BTF over one pattern repeat).
#include <cmath>

#include "server/models/registry.h"
#include "server/models/weave/pattern.h"
#include "server/models/weave/wif.h"

namespace loomlight::models {
namespace {

constexpr double kDegree = M_PI / 180.0;

std::vector<ParamSpec> ThreadParams(const std::string& t, const std::string& along) {
  const std::string p = t + ".";
  return {
      {p + "kd", ParamType::kRgb, "1/sr", 0.0, 10.0, {0.05, 0.05, 0.05}, "diffuse BTF value of the " + t, 3, 3},
      {p + "ks", ParamType::kRgb, "1", 0.0, 10.0, {0.5, 0.5, 0.5}, "specular coefficient of the " + t, 3, 3},
      {p + "size", ParamType::kRealList, "1", 0.01, 100.0, {1.0, 2.0},
       "segment window (s_x across, s_y along the " + t + ", which runs along " + along + ")", 2, 2},
      {p + "alpha", ParamType::kReal, "1", 0.001, 100.0, {1.0}, "semi-major axis of the highlight ellipse", 1, 1},
      {p + "eccentricity", ParamType::kReal, "1", 0.0, 0.9999, {0.9}, "eccentricity of the highlight ellipse", 1, 1},
      {p + "phi_e", ParamType::kReal, "deg", -360.0, 360.0, {90.0}, "major-axis angle from segment-local +x", 1, 1},
      {p + "k", ParamType::kRealList, "1", -100.0, 100.0, {1.0, 1.0},
       "highlight travel (k_x, k_y) per unit of the local half vector", 2, 2},
  };
}

weave::WeavePattern Twill31() {
  weave::WeavePattern p;
  weave::MakeTwill(3, 1, weave::TwillDirection::kRightward, &p);
  return p;
}

std::vector<double> Cells(const weave::WeavePattern& p) { return {p.cells.begin(), p.cells.end()}; }

std::vector<ParamSpec> Schema() {
  const weave::WeavePattern twill = Twill31();
  std::vector<ParamSpec> s = {
      {"eta", ParamType::kReal, "1", 1.0, 3.0, {1.5}, "refractive index for the Fresnel term", 1, 1},
      {"pattern.warps", ParamType::kInt, "1", 1, weave::kMaxRepeat, {double(twill.warps)},
       "warp threads in one repeat (columns of pattern.cells)", 1, 1},
      {"pattern.cells", ParamType::kRealList, "1", 0.0, 1.0, Cells(twill),
       "weave pattern, row by row (one row per pick): 1 = warp on top, 0 = weft on top", 1,
       size_t(weave::kMaxRepeat) * weave::kMaxRepeat},
      {"pattern.wif", ParamType::kText, "", 0, 0, {},
       "a WIF (Weaving Information File) draft; its drawdown sets pattern.warps and pattern.cells", 1,
       weave::kMaxWifBytes},
  };
  for (auto& p : ThreadParams("warp", "y, texture v")) s.push_back(p);
  for (auto& p : ThreadParams("weft", "x, texture u")) s.push_back(p);
  return s;
}

// The thread-type parameters of a preset, in schema order.
struct ThreadLook {
  std::vector<double> kd, ks, size;
  double alpha, eccentricity, phi_e;
  std::vector<double> k;
};

void AddThread(const std::string& t, const ThreadLook& look, ParamValues* v) {
  const std::string p = t + ".";
  (*v)[p + "kd"] = look.kd;
  (*v)[p + "ks"] = look.ks;
  (*v)[p + "size"] = look.size;
  (*v)[p + "alpha"] = {look.alpha};
  (*v)[p + "eccentricity"] = {look.eccentricity};
  (*v)[p + "phi_e"] = {look.phi_e};
  (*v)[p + "k"] = look.k;
}

PresetSpec MakePreset(std::string name, std::string description, const weave::WeavePattern& pattern,
                      const ThreadLook& warp, const ThreadLook& weft) {
  PresetSpec preset{std::move(name), std::move(description), {}};
  preset.values["pattern.warps"] = {double(pattern.warps)};
  preset.values["pattern.cells"] = Cells(pattern);
  AddThread("warp", warp, &preset.values);
  AddThread("weft", weft, &preset.values);
  return preset;
}

std::vector<PresetSpec> Presets() {
  weave::WeavePattern sateen;
  weave::MakeSatin(5, 2, weave::SatinFace::kWeftFaced, &sateen);
  return {
      // The paper's twill ellipse parameters (Sec. 6) on a 3/1 twill; kd and ks are ours (a dark cotton, the
      // paper measured black cloth and gives no colours).
      MakePreset("cotton_twill", "Woven cotton 3/1 twill with the paper's ellipse parameters (Irawan and Marschner Sec. 6)",
                 Twill31(), {{0.05, 0.04, 0.03}, {0.70, 0.65, 0.60}, {1, 6}, 3, 0.995, 95, {1.5, 3.1}},
                 {{0.03, 0.04, 0.06}, {0.50, 0.55, 0.62}, {1, 2}, 1, 0.9, 80, {3.7, 1.6}}),
      // Plain weave (the paper's Fig. 16, values ours): every float is one cell, so both thread types show
      // short, nearly round segments of equal area; the highlight is a small ellipse along each thread
      // that travels less than the twill's (the thread crimps over every crossing), giving the even
      // checker of small glints of Fig. 16. Undyed cotton: light, warm kd.
      MakePreset("cotton_plain", "Woven cotton plain weave, undyed (after Irawan and Marschner Fig. 16; parameters ours)",
                 weave::PlainWeave(), {{0.20, 0.18, 0.15}, {0.45, 0.43, 0.40}, {1, 1.5}, 0.4, 0.85, 90, {2.0, 1.5}},
                 {{0.19, 0.17, 0.14}, {0.45, 0.43, 0.40}, {1, 1.5}, 0.4, 0.85, 90, {2.0, 1.5}}),
      // Sateen (the paper's Fig. 18, values ours): a weft-faced 5-end satin (move 2), so 80% of the face is
      // weft floats over four warps. Their long straight segments carry elongated, strongly eccentric
      // highlights that sweep far along the float (large k_y): the sheen bands of Fig. 18. The warp shows
      // only at the single tacking cells, short and dull.
      MakePreset("cotton_satin", "Woven cotton 5-end sateen, weft-faced (after Irawan and Marschner Fig. 18; parameters ours)",
                 sateen, {{0.10, 0.09, 0.12}, {0.25, 0.25, 0.28}, {1, 1}, 0.5, 0.6, 90, {2.0, 2.0}},
                 {{0.12, 0.10, 0.14}, {0.80, 0.78, 0.85}, {1, 4}, 2.0, 0.98, 90, {1.5, 3.5}}),
  };
}

// The pattern of a parameter set, or the reason it is not one.
std::string PatternOf(const ParamValues& v, weave::WeavePattern* out) {
  const auto& cells = v.at("pattern.cells");
  const int warps = static_cast<int>(v.at("pattern.warps")[0]);
  if (cells.size() % warps != 0)
    return "pattern.cells: " + std::to_string(cells.size()) + " cells are not whole rows of pattern.warps = " +
           std::to_string(warps);
  out->warps = warps;
  out->picks = static_cast<int>(cells.size()) / warps;
  out->cells.clear();
  for (double c : cells) {
    if (c != 0.0 && c != 1.0) return "pattern.cells: cells must be 0 or 1";
    out->cells.push_back(static_cast<uint8_t>(c));
  }
  const std::string error = weave::ValidatePattern(*out);
  return error.empty() ? "" : "pattern.cells: " + error;
}

// The BTF's cell table (kernels/models/woven.h, wv_btf): warps, picks, then per cell its offset from the
// start of its float and the float's length (negative for weft floats).
void AppendCellTable(const weave::WeavePattern& pattern, std::vector<double>* data) {
  const size_t base = data->size() + 2;
  data->push_back(pattern.warps);
  data->push_back(pattern.picks);
  data->resize(base + 2 * pattern.cells.size(), 0.0);
  for (const weave::Float& fl : weave::ExtractFloats(pattern)) {
    for (int k = 0; k < fl.length; ++k) {
      const int warp = fl.warp ? fl.start_warp : (fl.start_warp + k) % pattern.warps;
      const int pick = fl.warp ? (fl.start_pick + k) % pattern.picks : fl.start_pick;
      const size_t cell = size_t(pick) * pattern.warps + warp;
      (*data)[base + 2 * cell] = k;
      (*data)[base + 2 * cell + 1] = fl.warp ? fl.length : -fl.length;
    }
  }
}

class WovenModel : public Model {
 public:
  std::string name() const override { return "woven"; }
  std::string description() const override {
    return "Irawan and Marschner 2006 woven cotton: elliptical highlights clipped by the weave's thread "
           "segments: the BTF at uv (pattern repeats), or without uv the BRDF, its mean over a repeat";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override { return {"models/woven.cl", "woven_brdf", "woven_btf"}; }
  // BTF and BRDF: h, Fresnel and the masking term come from the commutative wi + wo, the rest from both
  // directions alike (bit-exact). Not energy conserving: kd alone may reach 10 / sr, and the paper's specular
  // term ks Fr G / (n.wi n.wo) is not normalised (cotton_satin's albedo exceeds 1 at grazing light).
  bool reciprocal() const override { return true; }

  std::string ApplyText(const std::string& name, const std::string& text, ParamValues* v) const override {
    if (name != "pattern.wif") return Model::ApplyText(name, text, v);
    weave::WeavePattern pattern;
    const std::string error = weave::ParseWif(text, &pattern);
    if (!error.empty()) return "WIF " + error;
    (*v)["pattern.warps"] = {double(pattern.warps)};
    (*v)["pattern.cells"] = Cells(pattern);
    return "";
  }

  size_t TextParseBytes(const std::string& name, size_t text_bytes) const override {
    return name == "pattern.wif" ? weave::WifParseBytes(text_bytes) : text_bytes;
  }

  double ThreadsPerRepeat(const ParamValues& v) const override {
    weave::WeavePattern pattern;
    if (!PatternOf(v, &pattern).empty()) return 1;
    return std::max(pattern.warps, pattern.picks);
  }

  std::string Validate(const ParamValues& v) const override {
    weave::WeavePattern pattern;
    return PatternOf(v, &pattern);
  }

  std::string WeavePatternOf(const ParamValues& v, weave::WeavePattern* out) const override { return PatternOf(v, out); }

  PackedMaterial PackLayout(const ParamValues& v) const override {
    weave::WeavePattern pattern;
    PatternOf(v, &pattern);
    PackedMaterial m;
    m.data = {v.at("eta")[0], weave::ComputeAreaFractions(pattern).warp};
    for (const char* t : {"warp", "weft"}) {
      const std::string p = std::string(t) + ".";
      for (const char* rgb : {"kd", "ks"}) m.data.insert(m.data.end(), v.at(p + rgb).begin(), v.at(p + rgb).end());
      m.data.insert(m.data.end(), v.at(p + "size").begin(), v.at(p + "size").end());
      m.data.push_back(v.at(p + "alpha")[0]);
      m.data.push_back(v.at(p + "eccentricity")[0]);
      const double phi_e = v.at(p + "phi_e")[0] * kDegree;
      m.data.push_back(std::cos(phi_e));
      m.data.push_back(std::sin(phi_e));
      m.data.insert(m.data.end(), v.at(p + "k").begin(), v.at(p + "k").end());
    }
    AppendCellTable(pattern, &m.data);
    return m;
  }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace

}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(woven, WovenModel)
