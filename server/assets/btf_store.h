// BTF assets on disk, by name, under the operator's data directory (README "BTF assets"):
//   DATA_DIR/btf/NAME/manifest.pb   the asset's BtfAssetInfo (binary protobuf: grid, tile, components, errors)
//   DATA_DIR/btf/NAME/tables.f32    its compressed tables, float32 little-endian (kernels/models/btf.h's layout)
// An asset is written into a hidden directory and renamed into place, so a crash leaves the old asset or the
// new one, never half of one. Names are checked before any path is made from them; nothing a client sends
// becomes a path otherwise. Loaded assets are registered with models::btf::Assets (what the `btf` model reads).
//
// Several servers may share one data directory (replicas on a shared volume): each writes under names unique to
// its host and process, refuses to overwrite an asset another wrote unless asked to replace it, and Sync brings
// its registry up to date with the directory (assets another added, replaced or deleted), keyed by each asset's
// manifest file (inode, size, modification time): a replaced asset is a new directory renamed into place.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"
#include "server/models/btf/btf_asset.h"

namespace loomlight::assets {

// "" or why `name` cannot name an asset: 1-64 of [A-Za-z0-9_.-], not starting with '.'.
std::string ValidateAssetName(const std::string& name);

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

  enum class Outcome { kOk, kExists, kFull, kFailed };
  // Writes the asset under its name and registers it (replacing one of that name if `replace`); *error says why
  // not.
  Outcome Put(const std::shared_ptr<models::btf::BtfAsset>& asset, bool replace, std::string* error);
  // Removes the asset; false when there is none of that name.
  bool Delete(const std::string& name);
  // Registers what the directory holds and this store has not seen (another server's writes): new and replaced
  // assets loaded, deleted ones dropped. Returns how many assets changed (callers then empty the caches that
  // hold assets' tables); `log` gets a line per change or asset that could not be loaded.
  int Sync(const std::function<void(const std::string&)>& log = nullptr);
  bool Exists(const std::string& name) const;
  std::vector<std::shared_ptr<const models::btf::BtfAsset>> List() const;
  uint64_t bytes() const;
  uint64_t max_bytes() const { return max_bytes_; }
  const std::string& directory() const { return dir_; }

 private:
  BtfStore(std::string dir, uint64_t max_bytes) : dir_(std::move(dir)), max_bytes_(max_bytes) {}
  // Reads DATA_DIR/btf/NAME into *asset; "" or why not.
  std::string Load(const std::string& name, std::shared_ptr<models::btf::BtfAsset>* asset) const;
  // Which version of NAME's files the directory holds (its manifest's inode, size and modification time; empty
  // when there is none).
  std::string StampOf(const std::string& name) const;
  // A name for a hidden directory no other server sharing the directory uses (host, process, counter).
  std::string UniqueTag();

  const std::string dir_;  // DATA_DIR/btf
  const uint64_t max_bytes_;
  mutable std::mutex mutex_;  // one writer at a time; names -> ids live in models::btf::Assets
  uint64_t counter_ = 0;
  std::map<std::string, std::string> stamps_;  // per registered asset: StampOf when it was loaded or written
};

}  // namespace loomlight::assets
