#include "server/assets/btf_store.h"

#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cctype>
#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace loomlight::assets {
namespace fs = std::filesystem;
using models::btf::Assets;
using models::btf::BtfAsset;

namespace {
constexpr uint64_t kMaxManifestBytes = 1 << 20;

bool WriteFile(const fs::path& path, const void* data, size_t bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(static_cast<const char*>(data), std::streamsize(bytes));
  out.flush();
  return bool(out);
}

bool ReadFile(const fs::path& path, uint64_t max_bytes, std::string* out) {
  std::error_code ec;
  const uintmax_t size = fs::file_size(path, ec);
  if (ec || size > max_bytes) return false;
  std::ifstream in(path, std::ios::binary);
  out->resize(size);
  in.read(out->data(), std::streamsize(size));
  return bool(in);
}
}  // namespace

std::string ValidateAssetName(const std::string& name) {
  if (name.empty() || name.size() > 64) return "must be 1 to 64 characters";
  if (name[0] == '.') return "must not start with '.'";
  for (char c : name)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == '-'))
      return "may hold only letters, digits, '_', '.' and '-'";
  return "";
}

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
  const fs::path dir = fs::path(data_dir) / "btf";
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir)) {
    *error = "cannot make the BTF asset directory " + dir.string() + ": " + ec.message();
    return nullptr;
  }
  std::unique_ptr<BtfStore> store(new BtfStore(dir.string(), max_bytes));
  uint64_t total = 0;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind(".", 0) == 0) {  // what a crash left of a write or a delete, or another server's write in flight
      const auto age = fs::file_time_type::clock::now() - fs::last_write_time(entry.path(), ec);
      if (!ec && age > std::chrono::hours(1)) fs::remove_all(entry.path(), ec);
      continue;
    }
    if (!ValidateAssetName(name).empty() || !entry.is_directory()) continue;
    std::shared_ptr<BtfAsset> asset;
    std::string why = store->Load(name, &asset);
    if (why.empty() && total + asset->bytes() > max_bytes) why = "over the store's bound (--btf-store-mb)";
    if (!why.empty()) {
      std::fprintf(stderr, "loomlight-server: BTF asset '%s' not loaded: %s\n", name.c_str(), why.c_str());
      continue;
    }
    total += asset->bytes();
    auto previous = Assets::Global().FindName(name);  // a store opened again in this process
    Assets::Global().Add(asset);
    if (previous) Assets::Global().Remove(previous->id);
    store->stamps_[name] = store->StampOf(name);
  }
  return store;
}

std::string BtfStore::StampOf(const std::string& name) const {
  struct stat st {};
  if (::stat((fs::path(dir_) / name / "manifest.pb").c_str(), &st) != 0) return "";
  return std::to_string(st.st_ino) + ":" + std::to_string(st.st_size) + ":" + std::to_string(st.st_mtim.tv_sec) + "." +
         std::to_string(st.st_mtim.tv_nsec);
}

std::string BtfStore::UniqueTag() {
  char host[128] = {};
  if (::gethostname(host, sizeof host - 1) != 0) host[0] = 0;
  std::string h;
  for (const char* c = host; *c && h.size() < 64; ++c) h += std::isalnum(static_cast<unsigned char>(*c)) ? *c : '_';
  return h + "-" + std::to_string(::getpid()) + "-" + std::to_string(++counter_);
}

int BtfStore::Sync(const std::function<void(const std::string&)>& log) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto say = [&](const std::string& line) {
    if (log) log(line);
  };
  int changes = 0;
  std::map<std::string, std::string> on_disk;
  std::error_code ec;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir_, ec)) {
    const std::string name = entry.path().filename().string();
    if (!ValidateAssetName(name).empty() || !entry.is_directory(ec)) continue;
    on_disk[name] = StampOf(name);
  }
  if (ec) return 0;  // the directory unreadable for now: keep what is registered
  for (const auto& asset : Assets::Global().List()) {
    if (on_disk.count(asset->name) || !stamps_.count(asset->name)) continue;  // not this store's (a test's) or kept
    Assets::Global().Remove(asset->id);
    stamps_.erase(asset->name);
    say("BTF asset '" + asset->name + "' deleted by another server: dropped");
    ++changes;
  }
  uint64_t total = 0;
  for (const auto& a : Assets::Global().List()) total += a->bytes();
  for (const auto& [name, stamp] : on_disk) {
    if (stamp.empty()) continue;  // no manifest yet
    const auto known = stamps_.find(name);
    if (known != stamps_.end() && known->second == stamp) continue;
    std::shared_ptr<BtfAsset> asset;
    std::string why = Load(name, &asset);
    auto old = Assets::Global().FindName(name);
    if (why.empty() && total - (old ? old->bytes() : 0) + asset->bytes() > max_bytes_)
      why = "over the store's bound (--btf-store-mb)";
    stamps_[name] = stamp;  // tried once per version, loaded or not
    if (!why.empty()) {
      say("BTF asset '" + name + "' not loaded: " + why);
      continue;
    }
    total += asset->bytes() - (old ? old->bytes() : 0);
    Assets::Global().Add(asset);
    if (old) Assets::Global().Remove(old->id);
    say("BTF asset '" + name + "' " + (old ? "replaced" : "added") + " by another server: loaded");
    ++changes;
  }
  return changes;
}

std::string BtfStore::Load(const std::string& name, std::shared_ptr<BtfAsset>* out) const {
  const fs::path dir = fs::path(dir_) / name;
  std::string bytes;
  v1::BtfAssetInfo info;
  if (!ReadFile(dir / "manifest.pb", kMaxManifestBytes, &bytes) || !info.ParseFromString(bytes))
    return "manifest.pb missing or unreadable";
  auto asset = std::make_shared<BtfAsset>();
  asset->name = name;
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
  std::string data;
  if (!ReadFile(dir / "tables.f32", max_bytes_, &data) || data.size() % sizeof(float) != 0)
    return "tables.f32 missing, unreadable or too large";
  std::vector<float> tables(data.size() / sizeof(float));
  std::memcpy(tables.data(), data.data(), data.size());
  if (std::string e = models::btf::AssembleAsset(std::move(tables), asset.get()); !e.empty()) return e;
  *out = asset;
  return "";
}

BtfStore::Outcome BtfStore::Put(const std::shared_ptr<BtfAsset>& asset, bool replace, std::string* error) {
  if (std::string e = ValidateAssetName(asset->name); !e.empty()) {
    *error = "name: " + e;
    return Outcome::kFailed;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  auto old = Assets::Global().FindName(asset->name);
  const fs::path final_dir = fs::path(dir_) / asset->name;
  std::error_code exists_error;
  if ((old || fs::exists(final_dir, exists_error)) && !replace) {  // on disk only: another server's
    *error = "an asset of that name exists (set replace)";
    return Outcome::kExists;
  }
  uint64_t total = asset->bytes();
  for (const auto& a : Assets::Global().List())
    if (a != old) total += a->bytes();
  if (total > max_bytes_) {
    *error = "the asset store would hold " + std::to_string(total >> 20) + " MiB, over its bound of " +
             std::to_string(max_bytes_ >> 20) + " MiB (--btf-store-mb); delete assets first";
    return Outcome::kFull;
  }
  const std::string tag = UniqueTag();
  const fs::path incoming = fs::path(dir_) / (".incoming-" + tag), trash = fs::path(dir_) / (".trash-" + tag);
  v1::BtfAssetInfo info;
  DescribeAsset(*asset, &info);
  const std::string manifest = info.SerializeAsString();
  std::error_code ec;
  fs::create_directories(incoming, ec);
  const std::vector<float>& tables = asset->tables->data32();
  if (ec || !WriteFile(incoming / "tables.f32", tables.data(), tables.size() * sizeof(float)) ||
      !WriteFile(incoming / "manifest.pb", manifest.data(), manifest.size())) {
    fs::remove_all(incoming, ec);
    *error = "cannot write the asset under the data directory";
    return Outcome::kFailed;
  }
  if (fs::exists(final_dir)) fs::rename(final_dir, trash, ec);
  if (!ec) fs::rename(incoming, final_dir, ec);
  if (ec) {
    fs::remove_all(incoming, ec);
    *error = "cannot move the asset into place";
    return Outcome::kFailed;
  }
  fs::remove_all(trash, ec);
  Assets::Global().Add(asset);
  if (old) Assets::Global().Remove(old->id);
  stamps_[asset->name] = StampOf(asset->name);
  return Outcome::kOk;
}

bool BtfStore::Delete(const std::string& name) {
  if (!ValidateAssetName(name).empty()) return false;
  std::lock_guard<std::mutex> lock(mutex_);
  auto asset = Assets::Global().FindName(name);
  std::error_code exists_error;
  if (!asset && !fs::exists(fs::path(dir_) / name, exists_error)) return false;  // on disk only: another server's
  const fs::path trash = fs::path(dir_) / (".trash-" + UniqueTag());
  std::error_code ec;
  fs::rename(fs::path(dir_) / name, trash, ec);
  fs::remove_all(trash, ec);
  if (asset) Assets::Global().Remove(asset->id);
  stamps_.erase(name);
  return true;
}

bool BtfStore::Exists(const std::string& name) const {
  std::error_code ec;  // on disk only: another server sharing the directory wrote it
  return Assets::Global().FindName(name) != nullptr ||
         (ValidateAssetName(name).empty() && fs::exists(fs::path(dir_) / name, ec));
}

std::vector<std::shared_ptr<const BtfAsset>> BtfStore::List() const { return Assets::Global().List(); }

uint64_t BtfStore::bytes() const {
  uint64_t total = 0;
  for (const auto& a : Assets::Global().List()) total += a->bytes();
  return total;
}

}  // namespace loomlight::assets
