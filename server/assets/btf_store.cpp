#include "server/assets/btf_store.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cctype>
#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <set>

namespace loomlight::assets {
namespace fs = std::filesystem;
using models::btf::Assets;
using models::btf::BtfAsset;

namespace {
constexpr uint64_t kMaxManifestBytes = 1 << 20;
// Tries of a load whose version was replaced (and removed) while it read (BtfStore::Load).
constexpr int kLoadAttempts = 8;

// Why a system call failed, for the operator: what was done, to which file of the store, and errno's text.
std::string Failure(const std::string& what, const fs::path& path) {
  return what + " " + path.filename().string() + ": " + std::strerror(errno);
}

// Writes a new file and syncs it to the disk; "" or why not (a short write, ENOSPC, EFBIG, EIO, a failed fsync).
std::string WriteFile(const fs::path& path, const void* data, size_t bytes) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return Failure("cannot create", path);
  const char* p = static_cast<const char*>(data);
  std::string error;
  while (bytes > 0 && error.empty()) {
    const ssize_t n = ::write(fd, p, bytes);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      if (n == 0) errno = ENOSPC;  // no progress: the device takes no more
      error = Failure("cannot write", path);
    } else {
      p += n, bytes -= size_t(n);
    }
  }
  if (error.empty() && ::fsync(fd) != 0) error = Failure("cannot sync", path);
  if (::close(fd) != 0 && error.empty()) error = Failure("cannot close", path);
  return error;
}

// Syncs a directory's entries (a new file's or link's name survives a crash only once its directory is synced).
std::string SyncDirectory(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return Failure("cannot open", path);
  std::string error;
  if (::fsync(fd) != 0 && errno != EINVAL) error = Failure("cannot sync", path);  // EINVAL: a fs without it
  ::close(fd);
  return error;
}

// Reads `name` within the directory `dir_fd` (at most max_bytes).
bool ReadFileAt(int dir_fd, const char* name, uint64_t max_bytes, std::string* out) {
  const int fd = ::openat(dir_fd, name, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  struct stat st {};
  bool ok = ::fstat(fd, &st) == 0 && uint64_t(st.st_size) <= max_bytes;
  if (ok) out->resize(size_t(st.st_size));
  for (size_t done = 0; ok && done < out->size();) {
    const ssize_t n = ::read(fd, out->data() + done, out->size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) ok = false;  // an error, or the file shrank while read
    else done += size_t(n);
  }
  ::close(fd);
  return ok;
}

// The version directory a link of the store names, or "" when `path` is not such a link (a plain directory of
// an older server, nothing, or a link somewhere else: never followed out of the store to delete).
std::string VersionOf(const fs::path& path) {
  std::error_code ec;
  const fs::path target = fs::read_symlink(path, ec);
  if (ec || target.has_parent_path() || target.string().rfind(".v-", 0) != 0) return "";
  return target.string();
}

// Names that differ only in case are one name: this is the one (and its link's name).
std::string Key(std::string name) {
  for (char& c : name) c = char(std::tolower(static_cast<unsigned char>(c)));
  return name;
}

// The owner file of the asset at `path` (a link or an older server's directory): true with *owner ("" when it
// has none: stored before assets had owners), false when it cannot be read.
bool ReadOwner(const fs::path& path, std::string* owner) {
  owner->clear();
  const int dir_fd = ::open(path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd < 0) return false;
  const bool read = ReadFileAt(dir_fd, "owner", 1024, owner);
  const bool none = !read && errno == ENOENT;
  ::close(dir_fd);
  return read || none;
}

bool OnDisk(const fs::path& path) {  // a link counts even when it dangles
  std::error_code ec;
  return fs::exists(fs::symlink_status(path, ec));
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
  std::set<std::string> published;  // the version directories the store's links name: never swept
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec))
    if (std::string v = VersionOf(entry.path()); !v.empty()) published.insert(v);
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (published.count(name)) continue;
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
      store->failed_[Key(name)] = {store->StampOf(name), why, std::chrono::steady_clock::now(),
                                   std::chrono::seconds(0)};
      continue;
    }
    auto previous = Assets::Global().FindName(name);  // a store opened again in this process, or one name twice
    if (previous && store->stamps_.count(Key(name))) {  // (an older server's entries in two cases)
      std::fprintf(stderr, "loomlight-server: BTF asset '%s' not loaded: its name is taken in another case\n",
                   name.c_str());
      continue;
    }
    total += asset->bytes();
    Assets::Global().Add(asset);
    if (previous) Assets::Global().Remove(previous->id);
    store->stamps_[Key(name)] = store->StampOf(name);
  }
  return store;
}

std::string BtfStore::StampOf(const std::string& name) const {
  std::string stamp;
  for (const char* file : {"manifest.pb", "tables.f32"}) {
    struct stat st {};
    if (::stat((fs::path(dir_) / name / file).c_str(), &st) != 0) {
      if (stamp.empty()) return "";  // no manifest
      continue;
    }
    stamp += std::to_string(st.st_ino) + ":" + std::to_string(st.st_size) + ":" + std::to_string(st.st_mtim.tv_sec) +
             "." + std::to_string(st.st_mtim.tv_nsec) + ";";
  }
  return stamp;
}

std::string BtfStore::UniqueTag() {
  char host[128] = {};
  if (::gethostname(host, sizeof host - 1) != 0) host[0] = 0;
  std::string h;
  for (const char* c = host; *c && h.size() < 64; ++c) h += std::isalnum(static_cast<unsigned char>(*c)) ? *c : '_';
  static std::atomic<uint64_t> counter{0};  // per process: two stores in one process share the directory too
  return h + "-" + std::to_string(::getpid()) + "-" + std::to_string(++counter);
}

int BtfStore::Sync(const std::function<void(const std::string&)>& log) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto say = [&](const std::string& line) {
    if (log) log(line);
  };
  int changes = 0;
  struct Entry {
    std::string name, stamp;
  };
  std::map<std::string, Entry> on_disk;  // by Key
  std::error_code ec;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir_, ec)) {
    const std::string name = entry.path().filename().string();
    if (!ValidateAssetName(name).empty() || !entry.is_directory(ec)) continue;
    on_disk.emplace(Key(name), Entry{name, StampOf(name)});  // one name in two cases (older servers): the first
  }
  if (ec) return 0;  // the directory unreadable for now: keep what is registered
  for (const auto& asset : Assets::Global().List()) {
    const std::string key = Key(asset->name);
    if (on_disk.count(key) || !stamps_.count(key)) continue;  // not this store's (a test's) or kept
    Assets::Global().Remove(asset->id);
    stamps_.erase(key);
    say("BTF asset '" + asset->name + "' deleted by another server: dropped");
    ++changes;
  }
  uint64_t total = 0;
  for (const auto& a : Assets::Global().List()) total += a->bytes();
  const auto now = std::chrono::steady_clock::now();
  for (auto it = failed_.begin(); it != failed_.end();)  // gone from the directory: nothing to retry
    it = on_disk.count(it->first) ? std::next(it) : failed_.erase(it);
  for (const auto& [key, entry] : on_disk) {
    const std::string &name = entry.name, &stamp = entry.stamp;
    if (stamp.empty()) continue;  // no manifest yet
    const auto known = stamps_.find(key);
    if (known != stamps_.end() && known->second == stamp) continue;
    const auto failed = failed_.find(key);
    if (failed != failed_.end() && failed->second.stamp == stamp && now < failed->second.retry) continue;
    std::shared_ptr<BtfAsset> asset;
    std::string why = Load(name, &asset);
    auto old = Assets::Global().FindName(name);
    if (why.empty() && total - (old ? old->bytes() : 0) + asset->bytes() > max_bytes_)
      why = "over the store's bound (--btf-store-mb)";
    if (!why.empty()) {  // tried again: at once when its files change, else after a delay that doubles
      Failed& f = failed_[key];
      if (f.stamp != stamp || f.why != why) say("BTF asset '" + name + "' not loaded (tried again later): " + why);
      using std::chrono::seconds;
      f.delay = f.stamp == stamp ? std::clamp(2 * f.delay, seconds(10), seconds(320)) : seconds(10);
      f.stamp = stamp;
      f.why = why;
      f.retry = now + f.delay;
      continue;
    }
    failed_.erase(key);
    stamps_[key] = stamp;
    total += asset->bytes() - (old ? old->bytes() : 0);
    Assets::Global().Add(asset);
    if (old) Assets::Global().Remove(old->id);
    say("BTF asset '" + name + "' " + (old ? "replaced" : "added") + " by another server: loaded");
    ++changes;
  }
  return changes;
}

std::string BtfStore::Load(const std::string& entry, std::shared_ptr<BtfAsset>* out) const {
  // Every file from one version, named by the link read once. A replacement publishes its link before it removes
  // the version it replaced, so a file gone from the version read means the link has moved on: read it again
  // (each further try lost to one more replacement in between; a few are plenty).
  const fs::path path = fs::path(dir_) / entry;
  std::string bytes, data, owner;
  bool manifest_read = false, tables_read = false;
  for (int attempt = 0;; ++attempt) {
    const std::string version = VersionOf(path);  // "": an older server's plain directory, or gone
    const int dir_fd = ::open((version.empty() ? path : fs::path(dir_) / version).c_str(),
                              O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    const int open_errno = errno;
    bool gone = dir_fd < 0 && open_errno == ENOENT;
    if (dir_fd >= 0) {
      manifest_read = ReadFileAt(dir_fd, "manifest.pb", kMaxManifestBytes, &bytes);
      gone = !manifest_read && errno == ENOENT;
      tables_read = manifest_read && ReadFileAt(dir_fd, "tables.f32", max_bytes_, &data);
      gone = gone || (manifest_read && !tables_read && errno == ENOENT);
      if (!ReadFileAt(dir_fd, "owner", 1024, &owner)) owner.clear();  // none: stored before assets had owners
      ::close(dir_fd);
    }
    if (gone && !version.empty() && attempt < kLoadAttempts && VersionOf(path) != version) continue;
    if (dir_fd < 0) return std::string("cannot open its directory: ") + std::strerror(open_errno);
    break;
  }
  v1::BtfAssetInfo info;
  if (!manifest_read || !info.ParseFromString(bytes)) return "manifest.pb missing or unreadable";
  auto asset = std::make_shared<BtfAsset>();
  // The name as its client gave it (the link is it in lower case).
  asset->name = ValidateAssetName(info.name()).empty() && Key(info.name()) == Key(entry) ? info.name() : entry;
  asset->owner = owner;
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
  if (!tables_read || data.size() % sizeof(float) != 0)
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
  const std::string entry = EntryOf(asset->name);
  const fs::path final_path = fs::path(dir_) / (entry.empty() ? Key(asset->name) : entry);
  const std::string exists = "an asset of that name exists (set replace)";
  if ((old || !entry.empty()) && !replace) {  // early, before writing; publishing checks again, atomically
    *error = exists;
    return Outcome::kExists;
  }
  if (old || !entry.empty()) {  // on disk only: another server's, not loaded here yet
    std::string owner;
    if (old) owner = old->owner;
    else if (!ReadOwner(final_path, &owner)) owner = "?";  // unreadable: only an admin replaces it
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
  // The version, written whole and synced before anything names it.
  const std::string tag = UniqueTag(), version = ".v-" + tag;
  const fs::path version_dir = fs::path(dir_) / version, link = fs::path(dir_) / (".l-" + tag);
  v1::BtfAssetInfo info;
  DescribeAsset(*asset, &info);
  const std::string manifest = info.SerializeAsString();
  const std::vector<float>& tables = asset->tables->data32();
  std::string why;
  if (::mkdir(version_dir.c_str(), 0755) != 0) why = Failure("cannot make", version_dir);
  if (why.empty()) why = WriteFile(version_dir / "tables.f32", tables.data(), tables.size() * sizeof(float));
  if (why.empty()) why = WriteFile(version_dir / "owner", asset->owner.data(), asset->owner.size());
  if (why.empty()) why = WriteFile(version_dir / "manifest.pb", manifest.data(), manifest.size());
  if (why.empty()) why = SyncDirectory(version_dir);
  if (why.empty()) why = SyncDirectory(dir_);
  std::error_code ec;
  const auto fail = [&](const std::string& what) {
    fs::remove_all(version_dir, ec);
    fs::remove(link, ec);
    *error = "cannot store the asset under the data directory: " + what;
    return Outcome::kFailed;
  };
  if (!why.empty()) return fail(why);
  if (before_publish_for_test_) before_publish_for_test_();
  // Published in one atomic step. A new name: symlink(2) fails when the name exists (another server's asset
  // published since the check above is never moved away). A replacement: a new link renamed over the old one.
  std::string retired;  // what the replaced asset's files are now under, removed once the new one is in place
  if (!replace) {
    if (::symlink(version.c_str(), final_path.c_str()) != 0) {
      if (errno != EEXIST) return fail(Failure("cannot link", final_path));
      fail("");
      *error = exists + "; another server stored it first";
      return Outcome::kExists;
    }
  } else {
    const std::string previous = VersionOf(final_path);
    if (::symlink(version.c_str(), link.c_str()) != 0) return fail(Failure("cannot link", link));
    if (::rename(link.c_str(), final_path.c_str()) == 0) {
      retired = previous;
    } else if (errno == EISDIR || errno == ENOTEMPTY || errno == EEXIST) {
      // An older server's plain directory: swapped with the link in one step (Linux's renameat2), then removed.
      if (::renameat2(AT_FDCWD, link.c_str(), AT_FDCWD, final_path.c_str(), RENAME_EXCHANGE) != 0)
        return fail(Failure("cannot replace (an older server's directory; delete it first)", final_path));
      retired = link.filename().string();
    } else {
      return fail(Failure("cannot rename a link over", final_path));
    }
  }
  why = SyncDirectory(dir_);
  if (!retired.empty()) fs::remove_all(fs::path(dir_) / retired, ec);
  Assets::Global().Add(asset);
  if (old) Assets::Global().Remove(old->id);
  stamps_[Key(asset->name)] = StampOf(final_path.filename().string());
  failed_.erase(Key(asset->name));
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
  const std::string entry = EntryOf(name);
  if (!asset && entry.empty()) return Removal::kNotFound;  // neither registered nor on disk
  const fs::path path = fs::path(dir_) / (entry.empty() ? Key(name) : entry),
                 trash = fs::path(dir_) / (".trash-" + UniqueTag());
  std::string holder;
  if (asset) holder = asset->owner;
  else if (!ReadOwner(path, &holder)) holder = "?";  // unreadable: only an admin deletes it
  if (!holder.empty() && holder != owner && !admin) return Removal::kDenied;
  // The name goes in one step (the link, or an older server's directory, renamed away); then its files.
  const std::string version = VersionOf(path);
  if (!entry.empty() && ::rename(path.c_str(), trash.c_str()) == 0) {
    (void)SyncDirectory(dir_);
    std::error_code ec;
    if (!version.empty()) fs::remove_all(fs::path(dir_) / version, ec);
    fs::remove_all(trash, ec);
  }
  if (asset) Assets::Global().Remove(asset->id);
  stamps_.erase(Key(name));
  failed_.erase(Key(name));
  return Removal::kRemoved;
}

std::string BtfStore::EntryOf(const std::string& name) const {
  const std::string key = Key(name);
  if (OnDisk(fs::path(dir_) / key)) return key;
  std::error_code ec;  // an older server wrote names as given
  for (const fs::directory_entry& entry : fs::directory_iterator(dir_, ec)) {
    const std::string n = entry.path().filename().string();
    if (n[0] != '.' && Key(n) == key) return n;
  }
  return "";
}

bool BtfStore::Exists(const std::string& name) const {
  // on disk only: another server sharing the directory wrote it
  return Assets::Global().FindName(name) != nullptr || (ValidateAssetName(name).empty() && !EntryOf(name).empty());
}

std::vector<std::shared_ptr<const BtfAsset>> BtfStore::List() const { return Assets::Global().List(); }

uint64_t BtfStore::bytes() const {
  uint64_t total = 0;
  for (const auto& a : Assets::Global().List()) total += a->bytes();
  return total;
}

}  // namespace loomlight::assets
