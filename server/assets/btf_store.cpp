#include "server/assets/btf_store.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

namespace loomlight::assets {
using models::btf::Assets;
using models::btf::BtfAsset;

namespace {
constexpr uint64_t kMaxManifestBytes = 1 << 20;
}  // namespace

std::string GridOf(const v1::BtfGrid& grid, const std::string& field, models::btf::DirectionGrid* out) {
  if (!grid.preset().empty() || grid.rings_size() == 0) {
    if (grid.rings_size() > 0) return field + ": give a preset or rings, not both";
    bool found = false;
    *out = models::btf::DirectionGrid::Preset(grid.preset().empty() ? "h1" : grid.preset(), &found);
    if (!found) return field + ".preset: unknown (h1 or h2)";
    return "";
  }
  out->rings.clear();
  for (const v1::BtfRing& r : grid.rings()) {
    if (r.count() > models::btf::kMaxGridDirections)
      return field + ".rings: a ring holds at most " + std::to_string(models::btf::kMaxGridDirections);
    out->rings.push_back({r.theta(), int(r.count())});
  }
  if (std::string e = out->Validate(); !e.empty()) return field + "." + e;
  return "";
}

void DescribeAsset(const BtfAsset& a, v1::BtfAssetInfo* out) {
  out->set_name(a.name);
  out->set_source(a.source);
  for (const models::btf::Ring& r : a.grid.rings) {
    v1::BtfRing* ring = out->mutable_grid()->add_rings();
    ring->set_theta(r.theta_deg);
    ring->set_count(uint32_t(r.count));
  }
  out->set_width(uint32_t(a.width));
  out->set_height(uint32_t(a.height));
  out->set_components(uint32_t(a.components));
  out->set_bytes(a.bytes());
  for (const models::btf::ErrorRow& e : a.errors) {
    v1::BtfErrorRow* row = out->add_errors();
    row->set_components(uint32_t(e.components));
    row->set_rmse(e.rmse);
    row->set_psnr_db(e.psnr_db);
    row->set_bytes(e.bytes);
  }
  out->set_peak(a.peak);
  out->set_rms(a.rms);
  out->set_images_float16_bytes(a.images_float16_bytes());
  out->set_synthesis_seconds(a.synthesis_seconds);
  out->set_compression_seconds(a.compression_seconds);
  out->set_threads_per_tile(a.threads_per_tile);
}

std::string BtfStore::DefaultDataDir() {
  if (const char* state = std::getenv("XDG_STATE_HOME"); state && *state) return std::string(state) + "/loomlight";
  const char* home = std::getenv("HOME");
  return std::string(home && *home ? home : ".") + "/.local/state/loomlight";
}

std::unique_ptr<BtfStore> BtfStore::Open(const std::string& data_dir, uint64_t max_bytes, std::string* error) {
  auto dir = VersionedDirectory::Open((std::filesystem::path(data_dir) / "btf").string(), {"manifest.pb", "tables.f32"},
                                      error);
  if (!dir) {
    *error = "cannot open the BTF asset store: " + *error;
    return nullptr;
  }
  std::unique_ptr<BtfStore> store(new BtfStore(std::move(dir), max_bytes));
  store->Sync([](const std::string& line) { std::fprintf(stderr, "loomlight-server: %s\n", line.c_str()); }, true);
  return store;
}

int BtfStore::Sync(const std::function<void(const std::string&)>& log) { return Sync(log, false); }

int BtfStore::Sync(const std::function<void(const std::string&)>& log, bool opening) {
  std::lock_guard<std::mutex> lock(mutex_);
  uint64_t total = 0;
  for (const auto& a : Assets::Global().List()) total += a->bytes();
  VersionedDirectory::SyncHooks hooks;
  hooks.what = "BTF asset";
  hooks.drop = [](const std::string& key) -> std::string {
    const auto asset = Assets::Global().FindName(key);
    if (!asset) return "";
    Assets::Global().Remove(asset->id);
    return asset->name;
  };
  hooks.load = [&](const std::string& entry, bool* replaced) -> std::string {
    std::shared_ptr<BtfAsset> asset;
    if (std::string why = Load(entry, &asset); !why.empty()) return why;
    const auto old = Assets::Global().FindName(entry);
    if (total - (old ? old->bytes() : 0) + asset->bytes() > max_bytes_)
      return "over the store's bound (--btf-store-mb)";
    total += asset->bytes() - (old ? old->bytes() : 0);
    Assets::Global().Add(asset);
    if (old) Assets::Global().Remove(old->id);
    *replaced = old != nullptr;
    return "";
  };
  return dir_->Sync(hooks, log, opening);
}

std::string BtfStore::Load(const std::string& entry, std::shared_ptr<BtfAsset>* out) const {
  std::vector<VersionedDirectory::FileToRead> files = {
      {"manifest.pb", kMaxManifestBytes}, {"tables.f32", max_bytes_}, {"owner", 1024, true}};
  if (std::string e = dir_->Read(entry, &files); !e.empty()) return e;
  const std::string &bytes = files[0].bytes, &data = files[1].bytes;
  v1::BtfAssetInfo info;
  if (!files[0].read || !info.ParseFromString(bytes)) return "manifest.pb missing or unreadable";
  auto asset = std::make_shared<BtfAsset>();
  // The name as its client gave it (the link is it in lower case).
  const bool same_name = ValidateAssetName(info.name()).empty() && AssetKey(info.name()) == AssetKey(entry);
  asset->name = same_name ? info.name() : entry;
  asset->owner = files[2].bytes;  // none: stored before assets had owners
  asset->source = info.source();
  if (std::string e = GridOf(info.grid(), "grid", &asset->grid); !e.empty()) return e;
  asset->width = int(std::min<uint32_t>(info.width(), 1u << 16));
  asset->height = int(std::min<uint32_t>(info.height(), 1u << 16));
  asset->components = int(std::min<uint32_t>(info.components(), 1u << 16));
  asset->peak = info.peak();
  asset->rms = info.rms();
  asset->synthesis_seconds = info.synthesis_seconds();
  asset->compression_seconds = info.compression_seconds();
  asset->threads_per_tile = std::clamp(info.threads_per_tile(), 1.0, 1024.0);  // NaN: 1
  if (!(asset->threads_per_tile >= 1)) asset->threads_per_tile = 1;
  for (const v1::BtfErrorRow& r : info.errors())
    asset->errors.push_back({int(r.components()), r.rmse(), r.psnr_db(), r.bytes()});
  if (asset->errors.size() != size_t(asset->components) + 1) return "manifest's error table does not match its components";
  if (!files[1].read || data.size() % sizeof(float) != 0)
    return "tables.f32 missing, unreadable or too large";
  std::vector<float> tables(data.size() / sizeof(float));
  std::memcpy(tables.data(), data.data(), data.size());
  if (std::string e = models::btf::AssembleAsset(std::move(tables), asset.get()); !e.empty()) return e;
  *out = asset;
  return "";
}

BtfStore::Outcome BtfStore::Put(const std::shared_ptr<BtfAsset>& asset, bool replace, std::string* error,
                                bool admin) {
  if (std::string e = ValidateAssetName(asset->name); !e.empty()) {
    *error = "name: " + e;
    return Outcome::kFailed;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  auto old = Assets::Global().FindName(asset->name);
  const std::string entry = dir_->EntryOf(asset->name);
  const std::string exists = "an asset of that name exists (set replace)";
  if ((old || !entry.empty()) && !replace) {  // early, before writing; publishing checks again, atomically
    *error = exists;
    return Outcome::kExists;
  }
  if (old || !entry.empty()) {  // on disk only: another server's, not loaded here yet
    std::string owner;
    if (old) owner = old->owner;
    else if (!dir_->ReadOwner(entry, &owner)) owner = "?";  // unreadable: only an admin replaces it
    if (!owner.empty() && owner != asset->owner && !admin) {
      *error = "the asset belongs to another client (its owner, or a token with the admin right, may replace it)";
      return Outcome::kDenied;
    }
    if (!owner.empty()) asset->owner = owner;  // an admin's replacement is still its owner's asset
  }
  uint64_t total = asset->bytes(), owners = asset->bytes();
  for (const auto& a : Assets::Global().List())
    if (a != old) total += a->bytes(), owners += a->owner == asset->owner ? a->bytes() : 0;
  if (total > max_bytes_) {
    *error = "the asset store would hold " + std::to_string(total >> 20) + " MiB, over its bound of " +
             std::to_string(max_bytes_ >> 20) + " MiB (--btf-store-mb); delete assets first";
    return Outcome::kFull;
  }
  if (client_quota_ > 0 && owners > client_quota_) {
    *error = "the client's assets would hold " + std::to_string(owners >> 20) + " MiB, over its quota of " +
             std::to_string(client_quota_ >> 20) + " MiB (--btf-client-quota-mb); delete some of them first";
    return Outcome::kFull;
  }
  v1::BtfAssetInfo info;
  DescribeAsset(*asset, &info);
  const std::string manifest = info.SerializeAsString();
  const std::vector<float>& tables = asset->tables->data32();
  std::string why;
  switch (dir_->Publish(asset->name,
                        {{"tables.f32", tables.data(), tables.size() * sizeof(float)},
                         {"owner", asset->owner.data(), asset->owner.size()},
                         {"manifest.pb", manifest.data(), manifest.size()}},
                        replace, &why)) {
    case VersionedDirectory::Published::kExists: *error = exists + "; " + why; return Outcome::kExists;
    case VersionedDirectory::Published::kFailed:
      *error = "cannot store the asset under the data directory: " + why;
      return Outcome::kFailed;
    case VersionedDirectory::Published::kOk: break;
  }
  Assets::Global().Add(asset);
  if (old) Assets::Global().Remove(old->id);
  if (!why.empty()) {  // published (and registered: the directory names it) but maybe not durable
    *error = "the asset is in place but may not survive a crash: " + why;
    return Outcome::kFailed;
  }
  return Outcome::kOk;
}

BtfStore::Removal BtfStore::Delete(const std::string& name, const std::string& owner, bool admin) {
  if (!ValidateAssetName(name).empty()) return Removal::kNotFound;
  std::lock_guard<std::mutex> lock(mutex_);
  auto asset = Assets::Global().FindName(name);
  const std::string entry = dir_->EntryOf(name);
  if (!asset && entry.empty()) return Removal::kNotFound;  // neither registered nor on disk
  std::string holder;
  if (asset) holder = asset->owner;
  else if (!dir_->ReadOwner(entry, &holder)) holder = "?";  // unreadable: only an admin deletes it
  if (!holder.empty() && holder != owner && !admin) return Removal::kDenied;
  dir_->Remove(name);
  if (asset) Assets::Global().Remove(asset->id);
  return Removal::kRemoved;
}

bool BtfStore::Exists(const std::string& name) const {
  // on disk only: another server sharing the directory wrote it
  return Assets::Global().FindName(name) != nullptr ||
         (ValidateAssetName(name).empty() && !dir_->EntryOf(name).empty());
}

std::vector<std::shared_ptr<const BtfAsset>> BtfStore::List() const { return Assets::Global().List(); }

uint64_t BtfStore::bytes() const {
  uint64_t total = 0;
  for (const auto& a : Assets::Global().List()) total += a->bytes();
  return total;
}

}  // namespace loomlight::assets
