// BTF assets on disk, by name, under the operator's data directory (docs/btf-assets.md "Storage"), in the
// versioned directory the asset stores share (server/assets/versioned_store.h: versions written whole and synced,
// published by one atomic link, names case-insensitive, replicas sharing the directory kept up to date by Sync):
//   DATA_DIR/btf/name               a symbolic link to the asset's version directory, .v-TAG
//   DATA_DIR/btf/.v-TAG/manifest.pb  the asset's BtfAssetInfo (binary protobuf: name as given, grid, tile, ...)
//   DATA_DIR/btf/.v-TAG/tables.f32   its compressed tables, float32 little-endian (kernels/models/btf.h's layout)
//   DATA_DIR/btf/.v-TAG/owner        the client that stored it (BtfAsset::owner); absent: stored before owners
// (NAME may also be a plain directory holding the two files, as servers before the links wrote it.) Loaded
// assets are registered with models::btf::Assets (what the `btf` model reads). Another server sharing the
// directory cannot overwrite an asset this one wrote unless asked to replace it.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"
#include "server/assets/versioned_store.h"
#include "server/models/btf/btf_asset.h"

namespace loomlight::assets {

// The directions of a request's grid (a preset or rings); "" or "field: reason" (field under `field`).
std::string GridOf(const v1::BtfGrid& grid, const std::string& field, models::btf::DirectionGrid* out);

// What ListBtfs and the manifest say about an asset.
void DescribeAsset(const models::btf::BtfAsset& asset, v1::BtfAssetInfo* out);

class BtfStore {
 public:
  // Opens DATA_DIR/btf (creating it), loads every asset in it (a broken one is logged and skipped) and
  // registers them; nullptr and *error when the directory cannot be made. At most max_bytes of assets.
  static std::unique_ptr<BtfStore> Open(const std::string& data_dir, uint64_t max_bytes, std::string* error);
  // The default data directory: $XDG_STATE_HOME/loomlight, else ~/.local/state/loomlight.
  static std::string DefaultDataDir();

  enum class Outcome { kOk, kExists, kFull, kDenied, kFailed };
  // Writes the asset under its name and registers it (replacing one of that name if `replace`); asset->owner is
  // the client writing it. *error says why not: kExists when the name is taken, also by another server that
  // published it first; kDenied when `replace` names another client's asset and the writer is not `admin`;
  // kFull over the store's bound or the writer's quota; kFailed with the system's reason when a write, sync or
  // rename fails (nothing is published then). A replacement keeps the asset's owner (an admin's too).
  Outcome Put(const std::shared_ptr<models::btf::BtfAsset>& asset, bool replace, std::string* error,
              bool admin = false);
  enum class Removal { kRemoved, kNotFound, kDenied };
  // Removes the asset when `owner` owns it or is `admin` (an asset without an owner: anyone).
  Removal Delete(const std::string& name, const std::string& owner, bool admin);
  // The most bytes of assets one owner may hold (0: only the store's bound).
  void set_client_quota(uint64_t bytes) { client_quota_ = bytes; }
  // Registers what the directory holds and this store has not seen (another server's writes): new and replaced
  // assets loaded, deleted ones dropped. Returns how many assets changed (callers then empty the caches that
  // hold assets' tables); `log` gets a line per change or asset that could not be loaded.
  int Sync(const std::function<void(const std::string&)>& log = nullptr);
  bool Exists(const std::string& name) const;
  std::vector<std::shared_ptr<const models::btf::BtfAsset>> List() const;
  uint64_t bytes() const;
  uint64_t max_bytes() const { return max_bytes_; }
  const std::string& directory() const { return dir_->path(); }
  // Reads the directory entry DATA_DIR/btf/ENTRY (what Sync loads) into *asset, all from one version even while
  // other servers replace it; "" or why not. Reads only the disk: safe beside any other call.
  std::string Load(const std::string& entry, std::shared_ptr<models::btf::BtfAsset>* asset) const;
  // Tests only: runs just before Put publishes a written version (where another writer may get in first).
  void set_before_publish_for_test(std::function<void()> f) { dir_->set_before_publish_for_test(std::move(f)); }

 private:
  BtfStore(std::unique_ptr<VersionedDirectory> dir, uint64_t max_bytes) : dir_(std::move(dir)), max_bytes_(max_bytes) {}
  int Sync(const std::function<void(const std::string&)>& log, bool opening);

  const std::unique_ptr<VersionedDirectory> dir_;  // DATA_DIR/btf
  const uint64_t max_bytes_;
  mutable std::mutex mutex_;  // one writer at a time (and dir_'s bookkeeping); names -> ids live in models::btf::Assets
  uint64_t client_quota_ = 0;
};

}  // namespace loomlight::assets
