// Meshes clients uploaded, stored by name under the operator's data directory (docs/operations.md "Meshes") and
// shared by replicas as BTF assets are (server/assets/versioned_store.h: versions written whole and synced, then
// published by one atomic link; names case-insensitive; Sync keyed by the files' inode, size and mtime):
//   DATA_DIR/meshes/name                  a link to the mesh's version directory, .v-TAG
//   DATA_DIR/meshes/.v-TAG/manifest.pb    its MeshInfo (binary protobuf: the name as given, format, counts, bytes)
//   DATA_DIR/meshes/.v-TAG/mesh           the file's bytes as uploaded (checked by ParseMesh before they are stored)
//   DATA_DIR/meshes/.v-TAG/owner          the client that stored it
// A mesh is parsed again on first use (Load) and kept in a cache bounded in bytes (TriangleMesh::memory_bytes),
// the least recently used dropped first.
#pragma once

#include <cstdint>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"
#include "server/assets/mesh_file.h"
#include "server/assets/versioned_store.h"

namespace loomlight::assets {

class MeshStore {
 public:
  // Opens DATA_DIR/meshes (creating it) and registers every mesh in it (a broken one is logged and tried again
  // at the next Sync); nullptr and *error when the directory cannot be made. At most max_bytes of files together;
  // parsed meshes kept up to cache_bytes; `limits` are what an upload is checked against (and a stored file parsed
  // with).
  static std::unique_ptr<MeshStore> Open(const std::string& data_dir, uint64_t max_bytes, uint64_t cache_bytes,
                                         const MeshLimits& limits, std::string* error);

  enum class Outcome { kOk, kExists, kFull, kFailed };
  // Stores a mesh file ParseMesh accepted: `info` its MeshInfo (DescribeMesh, with name, format and bytes set),
  // `parsed` the mesh it parsed to (kept in the cache; may be null), `owner` the client storing it. *error says why
  // not: kExists when the name is taken (in any case), also by another server that published it first; kFull over
  // the store's bound; kFailed with the system's reason when a write, sync or link fails (nothing published).
  Outcome Put(const v1::MeshInfo& info, std::string_view bytes, const std::string& owner,
              std::shared_ptr<const TriangleMesh> parsed, std::string* error);
  enum class Removal { kRemoved, kNotFound, kDenied };
  // Removes the mesh when `owner` owns it or is `admin` (a mesh without an owner: anyone).
  Removal Delete(const std::string& name, const std::string& owner, bool admin);

  enum class Found { kOk, kNotFound, kFailed };
  // The parsed mesh of `name` (any case) and its MeshInfo: from the cache, else read and parsed (on the caller's
  // thread; `stop` as ParseMesh asks it). kNotFound when no mesh has that name (or another server deleted it);
  // kFailed with *error when its file
  // cannot be read or parsed, or `stop` stopped the parse ("stopped").
  Found Load(const std::string& name, const std::function<bool()>& stop, std::shared_ptr<const TriangleMesh>* out,
             v1::MeshInfo* info, std::string* error);

  // Registers what the directory holds and this store has not seen (another server's uploads and deletions);
  // returns how many meshes changed; `log` gets a line per change or mesh that could not be loaded.
  // `opening`: the first scan (Open's), which logs only what fails.
  int Sync(const std::function<void(const std::string&)>& log = nullptr, bool opening = false);
  bool Exists(const std::string& name) const;  // registered, or on disk (another server's, not synced yet)
  std::vector<v1::MeshInfo> List() const;       // by name
  uint64_t bytes() const;                       // the files together
  uint64_t max_bytes() const { return max_bytes_; }
  uint64_t cache_bytes() const;                 // parsed meshes kept now
  const MeshLimits& limits() const { return limits_; }
  const std::string& directory() const { return dir_->path(); }
  // Tests only: runs just before Put publishes a written version.
  void set_before_publish_for_test(std::function<void()> f) { dir_->set_before_publish_for_test(std::move(f)); }

 private:
  MeshStore(std::unique_ptr<VersionedDirectory> dir, uint64_t max_bytes, uint64_t cache_bytes, const MeshLimits& limits)
      : dir_(std::move(dir)), max_bytes_(max_bytes), max_cache_bytes_(cache_bytes), limits_(limits) {}
  struct Stored {
    v1::MeshInfo info;
    std::string owner;
    uint64_t generation = 0;  // which registration: a parse of an older one is not cached under a newer one
  };
  // Reads ENTRY's manifest and owner; "" or why not.
  std::string ReadManifest(const std::string& entry, Stored* out) const;
  // Keeps a parsed mesh in the cache (dropping the least recently used over the bound); under mutex_.
  void Cache(const std::string& key, uint64_t generation, std::shared_ptr<const TriangleMesh> mesh);
  void Uncache(const std::string& key);
  uint64_t StoredBytes() const;  // bytes(), under mutex_

  const std::unique_ptr<VersionedDirectory> dir_;
  const uint64_t max_bytes_, max_cache_bytes_;
  const MeshLimits limits_;
  mutable std::mutex mutex_;  // one writer at a time; guards everything below (and dir_'s bookkeeping)
  std::map<std::string, Stored> meshes_;  // by AssetKey
  uint64_t next_generation_ = 0;
  struct Parsed {
    std::string key;
    uint64_t generation;
    std::shared_ptr<const TriangleMesh> mesh;
  };
  std::list<Parsed> lru_;  // most recently used first
  std::map<std::string, std::list<Parsed>::iterator> cached_;
  uint64_t cached_bytes_ = 0;
};

}  // namespace loomlight::assets
