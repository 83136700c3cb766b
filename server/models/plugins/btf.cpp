// Registry entry of PCA-compressed BTF assets (Sattler et al. 2003, SPEC.md section 7): a material names an
// asset (server/models/btf/btf_asset.h; made by the CreateBtf and UploadBtf RPCs) and how many of its
// components to use, the model's accuracy knob. Served as the BTF (queries with uv, in tile repeats) and as
// the BRDF (the tile's mean). The asset's tables are shared, not copied, into every material naming it.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "server/models/btf/btf_asset.h"
#include "server/models/quote.h"
#include "server/models/registry.h"

namespace loomlight::models {
namespace {

constexpr double kMaxAssetId = 9007199254740992.0;  // 2^53: ids are whole doubles

class BtfModel : public Model {
 public:
  std::string name() const override { return "btf"; }
  std::string description() const override {
    return "a measured or synthesised BTF asset compressed per view with PCA (Sattler et al. 2003): f from the "
           "4 nearest light directions and the 4 nearest view slots, texels filtered bilinearly; the BTF at uv "
           "(tile repeats), or without uv the BRDF, its mean over the tile";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override { return {"models/btf.cl", "btf_brdf", "btf_btf"}; }

  std::string ApplyText(const std::string& name, const std::string& text, ParamValues* v) const override {
    if (name != "asset") return Model::ApplyText(name, text, v);
    auto asset = btf::Assets::Global().FindName(text);
    if (!asset) return "no BTF asset named " + Quote(text) + " (ListBtfs lists them)";
    (*v)["asset_id"] = {double(asset->id)};
    return "";
  }

  std::string Validate(const ParamValues& v) const override {
    if (!btf::Assets::Global().Find(uint64_t(v.at("asset_id")[0])))
      return "asset_id: no such BTF asset (it was deleted or replaced)";
    return "";
  }

  double ThreadsPerRepeat(const ParamValues& v) const override {
    auto asset = btf::Assets::Global().Find(uint64_t(v.at("asset_id")[0]));
    return asset ? asset->threads_per_tile : 1;
  }

  bool folds_environment() const override { return true; }

  // Random queries wait on memory (bench section 11: ~130 cache lines each, from four view slots' eigen-images
  // of up to a few MB each). Lanes grouped by wo read the same view slots one after another, from cache: a
  // stable counting sort on a 32 x 32 grid over wo's (x, y), whose cells are smaller than the view grids'
  // spacing, and within a cell on 8 bands of the tile in v, so neighbours read nearby texel rows. Only for
  // large launches whose neighbours mostly differ in group: a render's or a texture slice's queries come
  // grouped already, and without uv the tile means are a few KB, always in cache.
  bool LocalityOrder(const float* wo, const float* uv, size_t n, size_t* position) const override {
    constexpr size_t kMinQueries = 16384;
    constexpr int kCells = 32, kBands = 8, kGroups = kCells * kCells * kBands;
    if (!uv || n < kMinQueries) return false;
    std::vector<uint16_t> group(n);
    size_t changes = 0;
    // Non-finite values go to bin 0 (such queries evaluate to 0 wherever they run); casts stay in range.
    const auto bin = [](float t, int bins) { return std::isfinite(t) ? std::clamp(int(t * bins), 0, bins - 1) : 0; };
    for (size_t q = 0; q < n; ++q) {
      const int cx = bin(wo[3 * q] * 0.5f + 0.5f, kCells), cy = bin(wo[3 * q + 1] * 0.5f + 0.5f, kCells);
      const int band = bin(uv[2 * q + 1] - std::floor(uv[2 * q + 1]), kBands);
      group[q] = uint16_t((cy * kCells + cx) * kBands + band);
      changes += q > 0 && group[q] != group[q - 1];
    }
    if (changes * 4 < n) return false;  // grouped already (three in four neighbours share a group)
    std::vector<size_t> start(kGroups + 1, 0);
    for (uint16_t g : group) ++start[g + 1];
    for (int g = 0; g < kGroups; ++g) start[g + 1] += start[g];
    for (size_t q = 0; q < n; ++q) position[q] = start[group[q]]++;
    return true;
  }

  AccuracyKnob accuracy_knob() const override {
    return {"components", {1, 2, 4, 8, 16, 32, 64},
            "RMSE of the reconstruction against the asset's stored images relative to their RMS, recorded when "
            "the asset was compressed (from the discarded eigenvalues)"};
  }

  // From the asset's own error table: exact for its images, at no cost.
  std::vector<double> KnobErrors(const ParamValues& v) const override {
    auto asset = btf::Assets::Global().Find(uint64_t(v.at("asset_id")[0]));
    std::vector<double> errors;
    for (double s : accuracy_knob().settings) {
      if (!asset || asset->rms <= 0 || int(s) >= asset->components) {
        errors.push_back(0);
        continue;
      }
      errors.push_back(asset->errors[size_t(s)].rmse / asset->rms);
    }
    errors.back() = 0;
    return errors;
  }

 protected:
  PackedMaterial PackLayout(const ParamValues& v) const override {
    auto asset = btf::Assets::Global().Find(uint64_t(v.at("asset_id")[0]));
    if (!asset) asset = btf::Assets::Global().Find(0);  // removed since Validate: the built-in asset
    PackedMaterial m;
    m.tables = asset->tables;
    m.uniform = std::min(int(v.at("components")[0]), asset->components);
    return m;
  }

 private:
  std::vector<ParamSpec> schema_ = {
      {"asset", ParamType::kText, "", 0, 0, {}, "the name of a BTF asset (ListBtfs); sets asset_id", 1, 64},
      {"asset_id", ParamType::kInt, "1", 0, kMaxAssetId, {0},
       "the asset's id, set by `asset` (0: the built-in demonstration asset, preset btf_demo_checker)", 1, 1},
      {"components", ParamType::kInt, "1", 0, btf::kMaxComponents, {double(btf::kMaxComponents)},
       "PCA components used per view slot (at most the asset's; fewer: faster, less accurate)", 1, 1},
  };
  // The built-in demonstration asset, so the model has a preset (and the contract harness covers it) on a
  // server with no assets yet; real assets are named by `asset`.
  std::vector<PresetSpec> presets_ = {
      {"btf_demo_checker", "the built-in demonstration asset (asset_id 0): a 15-direction, 4 x 4-texel grey checker "
                           "whose contrast follows the light; assets of your own come from CreateBtf or UploadBtf",
       {{"asset_id", {0}}}}};
};

}  // namespace
}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(btf, BtfModel)
