// Registry entry of the woven-cotton model (Irawan and Marschner 2006, SPEC.md section 3): schema, the
// paper's twill preset and our plain, sateen and gingham, patterns as cell matrices or WIF drafts (with their
// thread colours), yarn types per thread, validation and packing (kernels/models/woven.h: records, lobes and
// tables). Served as the BTF (queries with uv) and as the BRDF (the mean of the BTF over one pattern repeat).
#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

#include "server/models/material.h"
#include "server/models/registry.h"
#include "server/models/weave/pattern.h"
#include "server/models/weave/wif.h"

namespace loomlight::models {
namespace {
// The packed layout's sizes (WV_HEADER, WV_LOBE_SIZE, WV_RECORD_SIZE) from the shared source.
namespace layout {
typedef double real;
#include "common/shim.h"
#include "common/ellipse_window.h"
#include "models/woven.h"
}  // namespace layout

constexpr double kDegree = M_PI / 180.0;

// Most yarn types one pattern may use (ThunderLoom's bound): every yarns.* list holds at most this many types'
// worth, and a thread's type is below it.
constexpr int kMaxYarnTypes = 256;

// The parameters a yarn type may set, as named after "warp.", "weft." and "yarns.", with their values per type
// and what a whole type's worth of values is called in errors.
struct YarnParam {
  const char* name;
  size_t per_type;
  const char* unit_name;
  const char* description;
};
constexpr YarnParam kYarnParams[] = {
    {"kd", 3, "RGB triples",
     "diffuse BTF value; a WIF draft's thread colour c (linear RGB, the diffuse albedo) sets kd = c / pi"},
    {"ks", 3, "RGB triples", "specular coefficient"},
    {"size", 2, "(s_x, s_y) pairs", "segment window (s_x across, s_y along the thread)"},
    {"alpha", 1, "values", "semi-major axis of the highlight ellipse"},
    {"eccentricity", 1, "values", "eccentricity of the highlight ellipse"},
    {"phi_e", 1, "values", "major-axis angle from segment-local +x"},
    {"k", 2, "(k_x, k_y) pairs", "highlight travel (k_x, k_y) per unit of the local half vector"},
};
// The per-thread yarn type lists, and the pattern count each must match.
constexpr const char* kThreadYarnLists[] = {"pattern.warp_yarns", "pattern.weft_yarns"};

// A client's number for errors: 6 significant digits, so a short string whatever was sent.
std::string Number(double v) {
  std::ostringstream out;
  out << v;
  return out.str();
}

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
       "a WIF (Weaving Information File) draft; its drawdown sets pattern.warps and pattern.cells, its thread "
       "colours pattern.warp_yarns, pattern.weft_yarns and yarns.kd (one yarn type per colour the threads use; "
       "empty when the draft has no colours), and it empties the other yarns.* lists: none of these may also be "
       "given", 1,
       weave::kMaxWifBytes},
  };
  const std::string types = std::to_string(kMaxYarnTypes);
  for (const char* list : kThreadYarnLists) {
    const bool warp = std::string(list) == "pattern.warp_yarns";
    s.push_back({list, ParamType::kRealList, "1", -1.0, kMaxYarnTypes - 1.0, {},
                 std::string("yarn type of each ") + (warp ? "warp thread (one per warp, pattern.warps of them)"
                                                           : "pick (one per row of pattern.cells)") +
                     ": a whole number below the number of types the yarns.* lists give (below kMaxYarnTypes = " +
                     types + " when none is given), or -1 for none (the " + (warp ? "warp" : "weft") +
                     ".* parameters); empty (the default): no types",
                 0, size_t(weave::kMaxRepeat)});
  }
  for (auto& p : ThreadParams("warp", "y, texture v")) s.push_back(p);
  for (auto& p : ThreadParams("weft", "x, texture u")) s.push_back(p);
  // yarns.X: per yarn type, the warp.X / weft.X it replaces, as a list of types (kRgb and pairs flattened).
  for (const YarnParam& y : kYarnParams) {
    const ParamSpec& base = *FindParam(s, std::string("warp.") + y.name);
    s.push_back({std::string("yarns.") + y.name, ParamType::kRealList, base.unit, base.min, base.max, {},
                 std::string(y.description) + ", per yarn type (" + std::to_string(y.per_type) + " value" +
                     (y.per_type > 1 ? "s" : "") + " each, type 0 first). Empty (the default): every type takes warp." +
                     y.name + " on a warp thread, weft." + y.name +
                     " on a pick. The non-empty yarns.* lists must give the same number of types, at most "
                     "kMaxYarnTypes = " + types,
                 0, y.per_type * kMaxYarnTypes});
  }
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

// The gingham's yarn types, ours: 0 = undyed white cotton, 1 = a red dye (linear diffuse albedo 0.80 and
// (0.55, 0.04, 0.05), kd = albedo / pi).
const std::vector<double> kGinghamKd = {0.80 / M_PI, 0.80 / M_PI, 0.80 / M_PI, 0.55 / M_PI, 0.04 / M_PI, 0.05 / M_PI};

// A gingham: a plain weave of `band` white threads then `band` dyed ones, in warp and weft alike, so the check
// shows three tones (white on white, white across red, red on red).
PresetSpec Gingham(int band, const ThreadLook& look) {
  weave::WeavePattern plain;
  plain.warps = plain.picks = 2 * band;
  for (int p = 0; p < plain.picks; ++p)
    for (int w = 0; w < plain.warps; ++w) plain.cells.push_back((w + p) % 2 == 0);  // PlainWeave, tiled
  const std::string threads = std::to_string(band);
  PresetSpec preset = MakePreset("cotton_gingham",
                                 "Woven cotton gingham: a plain weave of " + threads + " white and " + threads +
                                     " red threads in warp and weft, two yarn types (parameters ours)",
                                 plain, look, look);
  std::vector<double> types;
  for (int t = 0; t < 2; ++t) types.insert(types.end(), band, t);
  preset.values["pattern.warp_yarns"] = types;
  preset.values["pattern.weft_yarns"] = types;
  preset.values["yarns.kd"] = kGinghamKd;
  return preset;
}

std::vector<PresetSpec> Presets() {
  weave::WeavePattern sateen;
  weave::MakeSatin(5, 2, weave::SatinFace::kWeftFaced, &sateen);
  const ThreadLook plain_warp = {{0.20, 0.18, 0.15}, {0.45, 0.43, 0.40}, {1, 1.5}, 0.4, 0.85, 90, {2.0, 1.5}};
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
                 weave::PlainWeave(), plain_warp,
                 {{0.19, 0.17, 0.14}, {0.45, 0.43, 0.40}, {1, 1.5}, 0.4, 0.85, 90, {2.0, 1.5}}),
      // Sateen (the paper's Fig. 18, values ours): a weft-faced 5-end satin (move 2), so 80% of the face is
      // weft floats over four warps. Their long straight segments carry elongated, strongly eccentric
      // highlights that sweep far along the float (large k_y): the sheen bands of Fig. 18. The warp shows
      // only at the single tacking cells, short and dull.
      MakePreset("cotton_satin", "Woven cotton 5-end sateen, weft-faced (after Irawan and Marschner Fig. 18; parameters ours)",
                 sateen, {{0.10, 0.09, 0.12}, {0.25, 0.25, 0.28}, {1, 1}, 0.5, 0.6, 90, {2.0, 2.0}},
                 {{0.12, 0.10, 0.14}, {0.80, 0.78, 0.85}, {1, 4}, 2.0, 0.98, 90, {1.5, 3.5}}),
      // Gingham (ours): cotton_plain's threads in two yarn types that differ only in kd, so its BRDF costs
      // what the plain weave's does (one lobe per direction).
      Gingham(8, plain_warp),
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

// The yarn types of a parameter set: how many the yarns.* lists give (0: none given) and the first list giving
// them (for errors), or the reason they disagree.
std::string YarnTypeCount(const ParamValues& v, size_t* types, std::string* named_by) {
  *types = 0;
  for (const YarnParam& y : kYarnParams) {
    const std::string name = std::string("yarns.") + y.name;
    const size_t n = v.at(name).size();
    if (n == 0) continue;
    if (n % y.per_type != 0)
      return name + ": " + std::to_string(n) + " values are not whole " + y.unit_name;
    if (*types == 0) {
      *types = n / y.per_type;
      *named_by = name;
    } else if (n / y.per_type != *types) {
      return name + ": " + std::to_string(n / y.per_type) + " types, but " + *named_by + " has " +
             std::to_string(*types) + " types";
    }
  }
  return "";  // at most kMaxYarnTypes: the lists' schema counts are checked before (Validate)
}

// Every thread's yarn type (-1: none), warps then picks, or the reason they are not valid for the pattern and the
// yarns.* lists.
std::string YarnTypesOf(const ParamValues& v, const weave::WeavePattern& pattern, std::vector<int>* warp_types,
                        std::vector<int>* weft_types) {
  size_t types = 0;
  std::string named_by;
  if (std::string e = YarnTypeCount(v, &types, &named_by); !e.empty()) return e;
  for (const char* list : kThreadYarnLists) {
    const bool warp = std::string(list) == "pattern.warp_yarns";
    const int threads = warp ? pattern.warps : pattern.picks;
    const std::vector<double>& given = v.at(list);
    std::vector<int>& out = warp ? *warp_types : *weft_types;
    out.assign(threads, -1);
    if (given.empty()) continue;
    if (given.size() != size_t(threads))
      return std::string(list) + ": " + std::to_string(given.size()) + " entries, pattern has " +
             std::to_string(threads) + (warp ? " warps" : " picks");
    for (int i = 0; i < threads; ++i) {
      const double t = given[i];
      const std::string field = std::string(list) + "[" + std::to_string(i) + "]: yarn type " + Number(t);
      // The schema's range (-1 .. kMaxYarnTypes - 1) is checked before (Validate).
      if (!(t == std::floor(t))) return field + " is not a whole number";
      if (types > 0 && t >= double(types))
        return field + ", but " + named_by + " has " + std::to_string(types) + " types";
      out[i] = static_cast<int>(t);
    }
  }
  return "";
}

// Parameter X (a yarns.* name's tail) of a thread in direction "warp" or "weft" of yarn type `type`:
// yarns.X[type] where that list is given, else the direction's own.
std::vector<double> ThreadValue(const ParamValues& v, const YarnParam& y, const char* direction, int type) {
  const std::vector<double>& yarns = v.at(std::string("yarns.") + y.name);
  if (type < 0 || yarns.empty()) return v.at(std::string(direction) + "." + y.name);
  return {yarns.begin() + type * y.per_type, yarns.begin() + (type + 1) * y.per_type};
}

// The WV_RECORD_SIZE values of the record (direction 0 warp, 1 weft; yarn type, -1 none), kernels/models/woven.h.
std::vector<double> RecordValues(const ParamValues& v, int direction, int type) {
  const char* d = direction == 0 ? "warp" : "weft";
  std::vector<double> r;
  for (const YarnParam& y : kYarnParams) {
    const std::vector<double> x = ThreadValue(v, y, d, type);
    if (std::string(y.name) != "phi_e") {
      r.insert(r.end(), x.begin(), x.end());
    } else {
      r.push_back(std::cos(x[0] * kDegree));
      r.push_back(std::sin(x[0] * kDegree));
    }
  }
  r.push_back(direction);
  return r;
}

// The BTF's cell table (kernels/models/woven.h, wv_btf): per cell its offset from the start of its float and
// the float's length (negative for weft floats).
void AppendCellTable(const weave::WeavePattern& pattern, std::vector<double>* data) {
  const size_t base = data->size();
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

// The packed material of kernels/models/woven.h: header, lobes, records, thread table, cell table. Records are
// the distinct (direction, type) of the threads, in that order; lobes group the records on top somewhere by
// their geometry (values 6 .. 14), weighted by cell counts.
std::vector<double> PackMaterial(const ParamValues& v, const weave::WeavePattern& pattern,
                                 const std::vector<int>& warp_types, const std::vector<int>& weft_types) {
  std::map<std::pair<int, int>, int> record_index;  // (direction, type) -> record
  for (int t : warp_types) record_index.emplace(std::pair{0, t}, 0);
  for (int t : weft_types) record_index.emplace(std::pair{1, t}, 0);
  std::vector<std::vector<double>> records;
  for (auto& [key, index] : record_index) {
    index = static_cast<int>(records.size());
    records.push_back(RecordValues(v, key.first, key.second));
  }
  std::vector<int> warp_record, weft_record;
  for (int t : warp_types) warp_record.push_back(record_index.at({0, t}));
  for (int t : weft_types) weft_record.push_back(record_index.at({1, t}));
  std::vector<size_t> cells_on_top(records.size(), 0);
  for (int p = 0; p < pattern.picks; ++p)
    for (int w = 0; w < pattern.warps; ++w) ++cells_on_top[pattern.at(w, p) ? warp_record[w] : weft_record[p]];

  // Lobes in the order of their first record; kd and ks the cell-weighted means of their records.
  struct Lobe {
    std::vector<int> records;
    size_t cells = 0;
  };
  std::vector<Lobe> lobes;
  std::map<std::vector<double>, size_t> lobe_of_geometry;
  for (size_t r = 0; r < records.size(); ++r) {
    if (cells_on_top[r] == 0) continue;
    const std::vector<double> geometry(records[r].begin() + 6, records[r].end());
    const auto [it, added] = lobe_of_geometry.emplace(geometry, lobes.size());
    if (added) lobes.emplace_back();
    lobes[it->second].records.push_back(static_cast<int>(r));
    lobes[it->second].cells += cells_on_top[r];
  }

  const size_t record_offset = WV_HEADER + WV_LOBE_SIZE * lobes.size();
  const size_t thread_offset = record_offset + WV_RECORD_SIZE * records.size();
  const size_t cell_offset = thread_offset + pattern.warps + pattern.picks;
  // Per direction, a record whose geometry all of that direction's share (the kernel then selects it per lane
  // instead of gathering), or -1.
  double one_geometry[2] = {-1, -1};
  for (int d = 0; d < 2; ++d) {
    int first = -1;
    bool same = true;
    for (size_t r = 0; r < records.size(); ++r) {
      if (records[r][14] != d) continue;
      if (first < 0) first = static_cast<int>(r);
      same = same && std::equal(records[r].begin() + 6, records[r].begin() + 14, records[first].begin() + 6);
    }
    if (same) one_geometry[d] = double(record_offset + WV_RECORD_SIZE * first);
  }
  std::vector<double> m = {v.at("eta")[0],     double(lobes.size()),  double(record_offset), double(thread_offset),
                           double(cell_offset), double(pattern.warps), double(pattern.picks), double(records.size()),
                           one_geometry[0],     one_geometry[1]};
  const double cells = double(pattern.cells.size());
  for (const Lobe& lobe : lobes) {
    std::vector<double> values = records[lobe.records[0]];
    if (lobe.records.size() > 1)  // a lobe of one record keeps its kd and ks exactly
      for (int c = 0; c < 6; ++c) {
        double sum = 0;
        for (int r : lobe.records) sum += double(cells_on_top[r]) * records[r][c];
        values[c] = sum / double(lobe.cells);
      }
    values.push_back(double(lobe.cells) / cells);
    m.insert(m.end(), values.begin(), values.end());
  }
  for (const std::vector<double>& r : records) m.insert(m.end(), r.begin(), r.end());
  for (int r : warp_record) m.push_back(double(record_offset + WV_RECORD_SIZE * r));
  for (int r : weft_record) m.push_back(double(record_offset + WV_RECORD_SIZE * r));
  AppendCellTable(pattern, &m);
  return m;
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
    weave::WifColors colors;
    const std::string error = weave::ParseWif(text, &pattern, &colors);
    if (!error.empty()) return "WIF " + error;
    // The draft is the whole design: it always sets the same parameters (so which of them a request may also
    // give never depends on the draft's content), its colours or none.
    (*v)["pattern.warps"] = {double(pattern.warps)};
    (*v)["pattern.cells"] = Cells(pattern);
    for (const char* list : kThreadYarnLists) (*v)[list] = {};
    for (const YarnParam& y : kYarnParams) (*v)[std::string("yarns.") + y.name] = {};
    if (colors.table.empty()) return "";
    // One yarn type per colour the threads use, in the table's order (a table may list unused colours).
    std::map<int, int> type_of_color;
    for (const std::vector<int>* threads : {&colors.warp, &colors.weft})
      for (int c : *threads) {
        if (c >= int(colors.table.size()))
          return "WIF: a thread's colour " + std::to_string(c + 1) + " is not in the table";
        if (c >= 0) type_of_color.emplace(c, 0);
      }
    if (type_of_color.size() > size_t(kMaxYarnTypes))
      return "WIF: the threads use " + std::to_string(type_of_color.size()) + " colours, over kMaxYarnTypes = " +
             std::to_string(kMaxYarnTypes);
    std::vector<double>& kd = (*v)["yarns.kd"];
    for (auto& [color, type] : type_of_color) {
      type = static_cast<int>(kd.size() / 3);
      for (double albedo : colors.table[color]) kd.push_back(albedo / M_PI);
    }
    for (const char* list : kThreadYarnLists) {
      const std::vector<int>& threads = std::string(list) == "pattern.warp_yarns" ? colors.warp : colors.weft;
      std::vector<double>& types = (*v)[list];
      for (int c : threads) types.push_back(c >= 0 ? type_of_color.at(c) : -1);
    }
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
    if (std::string e = PatternOf(v, &pattern); !e.empty()) return e;
    // A WIF draft's lists bypass the per-value checks of a request's parameters: checked here as well.
    for (const ParamSpec& spec : schema_) {
      const bool yarn_list = spec.name.rfind("yarns.", 0) == 0 || spec.name == kThreadYarnLists[0] ||
                             spec.name == kThreadYarnLists[1];
      if (!yarn_list) continue;
      if (std::string e = CheckParamValues(spec, v.at(spec.name), spec.name); !e.empty()) return e;
    }
    std::vector<int> warp_types, weft_types;
    return YarnTypesOf(v, pattern, &warp_types, &weft_types);
  }

  std::string WeavePatternOf(const ParamValues& v, weave::WeavePattern* out) const override { return PatternOf(v, out); }

  PackedMaterial PackLayout(const ParamValues& v) const override {
    weave::WeavePattern pattern;
    PatternOf(v, &pattern);
    std::vector<int> warp_types, weft_types;
    YarnTypesOf(v, pattern, &warp_types, &weft_types);
    PackedMaterial m;
    m.data = PackMaterial(v, pattern, warp_types, weft_types);
    return m;
  }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace

}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(woven, WovenModel)
