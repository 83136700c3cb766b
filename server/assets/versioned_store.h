// The on-disk mechanism the asset stores share (BTF assets: server/assets/btf_store.h; meshes: mesh_store.h), one
// directory per kind of asset under the operator's data directory:
//   DIR/name          a symbolic link to the asset's version directory, .v-TAG; the name in lower case (names
//                     that differ only in case are one name, on every volume)
//   DIR/.v-TAG/FILE   the version's files (each store's own, and `owner`: the client that stored it)
// (NAME may also be a plain directory holding the files, as servers before the links wrote BTF assets.) A version
// is written whole and synced before one atomic step publishes it: symlink(2), which fails when NAME exists, for
// a new asset, and rename(2) of a new link over NAME for a replacement, so a crash or a second writer leaves the
// old asset or the new one, never half of one, nothing, or the loser's bytes under the winner's name. Links and
// renames are atomic on every POSIX filesystem, NFS included. Names are checked (ValidateAssetName) before any
// path is made from them; nothing a client sends becomes a path otherwise.
//
// Several servers may share the directory (replicas on a shared volume): each writes under names unique to its
// host and process, and Sync brings a store up to date with what the others added, replaced or deleted, keyed by
// each asset's files (inode, size, modification time); an asset that does not load is tried again later.
//
// Not thread-safe: its store calls it under its own lock (Read and StampOf only read the disk: safe beside
// anything).
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace loomlight::assets {

// "" or why `name` cannot name an asset: 1-64 of [A-Za-z0-9_.-], not starting with '.'.
std::string ValidateAssetName(const std::string& name);

// Names that differ only in case are one name: this is the one (and its link's name).
std::string AssetKey(std::string name);

class VersionedDirectory {
 public:
  // DIR made (with its parents) where missing, and what a crash left of a write or a delete (hidden entries over
  // an hour old that no link names) removed. `stamp_files`: the files whose (inode, size, mtime) tell versions
  // apart, the first one the version's manifest (no manifest: not there yet). nullptr and *error when DIR cannot
  // be made.
  static std::unique_ptr<VersionedDirectory> Open(const std::string& dir, std::vector<std::string> stamp_files,
                                                  std::string* error);
  const std::string& path() const { return dir_; }

  // The directory entry holding `name` in any case: the lower-case link, else an older server's entry spelled
  // otherwise; "" when there is none.
  std::string EntryOf(const std::string& name) const;
  // Which version of ENTRY's files the directory holds ("" when it has no manifest).
  std::string StampOf(const std::string& entry) const;

  // A file of a version to read, at most max_bytes (larger, absent or unreadable: not read). An optional one's
  // absence is not taken for a version removed while read (the owner file: absent before assets had owners).
  struct FileToRead {
    FileToRead(std::string file, uint64_t max, bool optional_file = false)
        : name(std::move(file)), max_bytes(max), optional(optional_file) {}
    std::string name;
    uint64_t max_bytes;
    bool optional;
    std::string bytes;
    bool read = false;
  };
  // Reads the files of ENTRY, all from one version, named by the link read once, even while other servers
  // replace it; "" or why its directory cannot be opened (each file says whether it was read).
  std::string Read(const std::string& entry, std::vector<FileToRead>* files) const;
  // ENTRY's owner: true with *owner ("" when it has none: stored before assets had owners), false when it cannot
  // be read.
  bool ReadOwner(const std::string& entry, std::string* owner) const;

  struct FileToWrite {
    std::string name;
    const void* data;
    size_t bytes;
  };
  enum class Published { kOk, kExists, kFailed };
  // Writes `files` as a new version and publishes it under `name` (replacing ENTRY of that name if `replace`).
  // kOk, with *error set when the version is in place but its directory's sync failed (it may not survive a
  // crash); kExists when the name is taken (a new name only: another server published it first); kFailed with
  // the system's reason when a write, sync or rename fails (nothing published, nothing left behind).
  Published Publish(const std::string& name, const std::vector<FileToWrite>& files, bool replace,
                    std::string* error);
  // Removes ENTRY: its name in one step (renamed away), then its files. Nothing when it is not there.
  void Remove(const std::string& entry);

  // What Sync asks of its store.
  struct SyncHooks {
    const char* what;  // "BTF asset", "mesh": the log's word for one
    // Drops the asset of this key the store holds (deleted on disk); its name as given, "" when it held none.
    std::function<std::string(const std::string& key)> drop;
    // Loads ENTRY and registers it (replacing the one of its name the store holds); "" or why not (the store's
    // bound included). *replaced: it replaced one.
    std::function<std::string(const std::string& entry, bool* replaced)> load;
  };
  // Registers what the directory holds and the store has not loaded (new and replaced assets, through
  // hooks.load), drops what it loaded and is gone; how many assets changed. `log` gets a line per change or asset
  // that could not be loaded. `opening`: the store's first scan (nothing logged for what loads; what fails is
  // tried again at the next Sync).
  int Sync(const SyncHooks& hooks, const std::function<void(const std::string&)>& log, bool opening = false);
  // The store wrote (or deleted) ENTRY itself: its version is the one loaded (or none).
  void Loaded(const std::string& entry);
  void Forgot(const std::string& name);

  // Tests only: runs just before Publish publishes a written version (where another writer may get in first).
  void set_before_publish_for_test(std::function<void()> f) { before_publish_for_test_ = std::move(f); }

 private:
  VersionedDirectory(std::string dir, std::vector<std::string> stamp_files)
      : dir_(std::move(dir)), stamp_files_(std::move(stamp_files)) {}
  // A name for a hidden entry no other server sharing the directory uses (host, process, counter).
  static std::string UniqueTag();

  const std::string dir_;
  const std::vector<std::string> stamp_files_;
  // Keyed by AssetKey: per asset the store loaded or wrote, StampOf then.
  std::map<std::string, std::string> stamps_;
  // Per asset on disk that did not load: its stamp and reason then, and when Sync tries it again (at once when
  // its files change; else after a delay that doubles, for a reason that is not in the files: a read error, the
  // store's bound).
  struct Failed {
    std::string stamp, why;
    std::chrono::steady_clock::time_point retry;
    std::chrono::seconds delay{0};
  };
  std::map<std::string, Failed> failed_;
  std::function<void()> before_publish_for_test_;
};

}  // namespace loomlight::assets
