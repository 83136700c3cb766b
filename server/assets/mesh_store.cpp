#include "server/assets/mesh_store.h"

#include <cstdio>
#include <filesystem>

namespace loomlight::assets {
namespace {
constexpr uint64_t kMaxManifestBytes = 1 << 20;
constexpr const char* kBound = "--mesh-store-mb";
}  // namespace

std::unique_ptr<MeshStore> MeshStore::Open(const std::string& data_dir, uint64_t max_bytes, uint64_t cache_bytes,
                                           const MeshLimits& limits, std::string* error) {
  auto dir = VersionedDirectory::Open((std::filesystem::path(data_dir) / "meshes").string(), {"manifest.pb", "mesh"},
                                      error);
  if (!dir) {
    *error = "cannot open the mesh store: " + *error;
    return nullptr;
  }
  std::unique_ptr<MeshStore> store(new MeshStore(std::move(dir), max_bytes, cache_bytes, limits));
  store->Sync([](const std::string& line) { std::fprintf(stderr, "loomlight-server: %s\n", line.c_str()); }, true);
  return store;
}

std::string MeshStore::ReadManifest(const std::string& entry, Stored* out) const {
  std::vector<VersionedDirectory::FileToRead> files = {{"manifest.pb", kMaxManifestBytes}, {"owner", 1024, true}};
  if (std::string e = dir_->Read(entry, &files); !e.empty()) return e;
  if (!files[0].read || !out->info.ParseFromString(files[0].bytes)) return "manifest.pb missing or unreadable";
  // The name as its client gave it (the link is it in lower case).
  if (!ValidateAssetName(out->info.name()).empty() || AssetKey(out->info.name()) != AssetKey(entry))
    out->info.set_name(entry);
  if (out->info.bytes() > limits_.max_bytes)
    return "its file's " + std::to_string(out->info.bytes()) + " bytes are over the limit of " +
           std::to_string(limits_.max_bytes);
  out->owner = files[1].bytes;
  return "";
}

int MeshStore::Sync(const std::function<void(const std::string&)>& log, bool opening) {
  std::lock_guard<std::mutex> lock(mutex_);
  VersionedDirectory::SyncHooks hooks;
  hooks.what = "mesh";
  hooks.drop = [this](const std::string& key) -> std::string {
    const auto it = meshes_.find(key);
    if (it == meshes_.end()) return "";
    const std::string name = it->second.info.name();
    meshes_.erase(it);
    Uncache(key);
    return name;
  };
  hooks.load = [this](const std::string& entry, bool* replaced) -> std::string {
    Stored stored;
    if (std::string e = ReadManifest(entry, &stored); !e.empty()) return e;
    const std::string key = AssetKey(entry);
    const auto old = meshes_.find(key);
    *replaced = old != meshes_.end();
    const uint64_t total = StoredBytes() - (*replaced ? old->second.info.bytes() : 0) + stored.info.bytes();
    if (total > max_bytes_) return std::string("over the store's bound (") + kBound + ")";
    stored.generation = ++next_generation_;
    meshes_[key] = std::move(stored);
    Uncache(key);
    return "";
  };
  return dir_->Sync(hooks, log, opening);
}

MeshStore::Outcome MeshStore::Put(const v1::MeshInfo& info, std::string_view bytes, const std::string& owner,
                                  std::shared_ptr<const TriangleMesh> parsed, std::string* error) {
  if (std::string e = ValidateAssetName(info.name()); !e.empty()) {
    *error = "name: " + e;
    return Outcome::kFailed;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  const std::string key = AssetKey(info.name());
  const std::string exists = "a mesh of that name exists (delete it first)";
  if (meshes_.count(key) || !dir_->EntryOf(info.name()).empty()) {  // early; publishing checks again, atomically
    *error = exists;
    return Outcome::kExists;
  }
  const uint64_t total = StoredBytes() + info.bytes();
  if (total > max_bytes_) {
    *error = "the mesh store would hold " + std::to_string(total >> 20) + " MiB, over its bound of " +
             std::to_string(max_bytes_ >> 20) + " MiB (" + kBound + "); delete meshes first";
    return Outcome::kFull;
  }
  const std::string manifest = info.SerializeAsString();
  std::string why;
  switch (dir_->Publish(info.name(),
                        {{"mesh", bytes.data(), bytes.size()},
                         {"owner", owner.data(), owner.size()},
                         {"manifest.pb", manifest.data(), manifest.size()}},
                        false, &why)) {
    case VersionedDirectory::Published::kExists: *error = exists + "; " + why; return Outcome::kExists;
    case VersionedDirectory::Published::kFailed:
      *error = "cannot store the mesh under the data directory: " + why;
      return Outcome::kFailed;
    case VersionedDirectory::Published::kOk: break;
  }
  const uint64_t generation = ++next_generation_;
  meshes_[key] = {info, owner, generation};
  if (parsed) Cache(key, generation, std::move(parsed));
  if (!why.empty()) {  // published (and registered: the directory names it) but maybe not durable
    *error = "the mesh is in place but may not survive a crash: " + why;
    return Outcome::kFailed;
  }
  return Outcome::kOk;
}

MeshStore::Removal MeshStore::Delete(const std::string& name, const std::string& owner, bool admin) {
  if (!ValidateAssetName(name).empty()) return Removal::kNotFound;
  std::lock_guard<std::mutex> lock(mutex_);
  const std::string key = AssetKey(name);
  const auto it = meshes_.find(key);
  const std::string entry = dir_->EntryOf(name);
  if (it == meshes_.end() && entry.empty()) return Removal::kNotFound;  // neither registered nor on disk
  std::string holder;
  if (it != meshes_.end()) holder = it->second.owner;
  else if (!dir_->ReadOwner(entry, &holder)) holder = "?";  // unreadable: only an admin deletes it
  if (!holder.empty() && holder != owner && !admin) return Removal::kDenied;
  dir_->Remove(name);
  if (it != meshes_.end()) meshes_.erase(it);
  Uncache(key);
  return Removal::kRemoved;
}

MeshStore::Found MeshStore::Load(const std::string& name, const std::function<bool()>& stop,
                                 std::shared_ptr<const TriangleMesh>* out, v1::MeshInfo* info, std::string* error) {
  if (!ValidateAssetName(name).empty()) return Found::kNotFound;
  const std::string key = AssetKey(name);
  Stored stored;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = meshes_.find(key);
    if (it == meshes_.end()) return Found::kNotFound;
    stored = it->second;
    if (const auto c = cached_.find(key); c != cached_.end() && c->second->generation == stored.generation) {
      lru_.splice(lru_.begin(), lru_, c->second);
      *out = c->second->mesh;
      if (info) *info = stored.info;
      return Found::kOk;
    }
  }
  // Read and parsed without the lock (seconds for a large file); the manifest read with the file, so the two are
  // one version even if another server replaced the mesh since this one registered it.
  std::vector<VersionedDirectory::FileToRead> files = {{"manifest.pb", kMaxManifestBytes}, {"mesh", limits_.max_bytes}};
  std::string why = dir_->Read(AssetKey(name), &files);
  v1::MeshInfo on_disk;
  if (why.empty() && !(files[0].read && on_disk.ParseFromString(files[0].bytes) && files[1].read))
    why = "its files are missing or unreadable";
  if (!why.empty()) {
    if (dir_->EntryOf(name).empty()) return Found::kNotFound;  // another server deleted it (not synced here yet)
    *error = "the stored mesh " + name + " cannot be read: " + why;
    return Found::kFailed;
  }
  on_disk.set_name(stored.info.name());
  auto mesh = std::make_shared<TriangleMesh>();
  if (std::string e = ParseMesh(files[1].bytes, on_disk.format(), limits_, mesh.get(), nullptr, stop); !e.empty()) {
    *error = e == "stopped" ? e : "the stored mesh " + name + " does not parse: " + e;
    return Found::kFailed;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = meshes_.find(key);
    if (it != meshes_.end() && it->second.generation == stored.generation &&
        it->second.info.SerializeAsString() == on_disk.SerializeAsString())
      Cache(key, stored.generation, mesh);
  }
  *out = std::move(mesh);
  if (info) *info = on_disk;
  return Found::kOk;
}

void MeshStore::Cache(const std::string& key, uint64_t generation, std::shared_ptr<const TriangleMesh> mesh) {
  Uncache(key);
  const uint64_t size = mesh->memory_bytes();
  if (size > max_cache_bytes_) return;  // would push out everything and still not fit
  while (cached_bytes_ + size > max_cache_bytes_ && !lru_.empty()) Uncache(lru_.back().key);
  lru_.push_front({key, generation, std::move(mesh)});
  cached_[key] = lru_.begin();
  cached_bytes_ += size;
}

void MeshStore::Uncache(const std::string& key) {
  const auto it = cached_.find(key);
  if (it == cached_.end()) return;
  cached_bytes_ -= it->second->mesh->memory_bytes();
  lru_.erase(it->second);
  cached_.erase(it);
}

bool MeshStore::Exists(const std::string& name) const {
  if (!ValidateAssetName(name).empty()) return false;
  std::lock_guard<std::mutex> lock(mutex_);
  return meshes_.count(AssetKey(name)) || !dir_->EntryOf(name).empty();
}

std::vector<v1::MeshInfo> MeshStore::List() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<v1::MeshInfo> out;
  for (const auto& [key, stored] : meshes_) out.push_back(stored.info);
  return out;
}

uint64_t MeshStore::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return StoredBytes();
}

uint64_t MeshStore::StoredBytes() const {
  uint64_t total = 0;
  for (const auto& [key, stored] : meshes_) total += stored.info.bytes();
  return total;
}

uint64_t MeshStore::cache_bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return cached_bytes_;
}

}  // namespace loomlight::assets
