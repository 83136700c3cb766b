#include "server/assets/versioned_store.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <set>

namespace loomlight::assets {
namespace fs = std::filesystem;

namespace {
// Tries of a read whose version was replaced (and removed) while it read (VersionedDirectory::Read).
constexpr int kReadAttempts = 8;

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

std::string AssetKey(std::string name) {
  for (char& c : name) c = char(std::tolower(static_cast<unsigned char>(c)));
  return name;
}

std::unique_ptr<VersionedDirectory> VersionedDirectory::Open(const std::string& dir_name,
                                                             std::vector<std::string> stamp_files,
                                                             std::string* error) {
  const fs::path dir = dir_name;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir)) {
    *error = "cannot make the directory " + dir.string() + ": " + ec.message();
    return nullptr;
  }
  std::set<std::string> published;  // the version directories the store's links name: never swept
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec))
    if (std::string v = VersionOf(entry.path()); !v.empty()) published.insert(v);
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind(".", 0) != 0 || published.count(name)) continue;
    // What a crash left of a write or a delete, or another server's write in flight (young: left alone).
    const auto age = fs::file_time_type::clock::now() - fs::last_write_time(entry.path(), ec);
    if (!ec && age > std::chrono::hours(1)) fs::remove_all(entry.path(), ec);
  }
  return std::unique_ptr<VersionedDirectory>(new VersionedDirectory(dir.string(), std::move(stamp_files)));
}

std::string VersionedDirectory::StampOf(const std::string& entry) const {
  std::string stamp;
  for (const std::string& file : stamp_files_) {
    struct stat st {};
    if (::stat((fs::path(dir_) / entry / file).c_str(), &st) != 0) {
      if (stamp.empty()) return "";  // no manifest
      continue;
    }
    stamp += std::to_string(st.st_ino) + ":" + std::to_string(st.st_size) + ":" + std::to_string(st.st_mtim.tv_sec) +
             "." + std::to_string(st.st_mtim.tv_nsec) + ";";
  }
  return stamp;
}

std::string VersionedDirectory::UniqueTag() {
  char host[128] = {};
  if (::gethostname(host, sizeof host - 1) != 0) host[0] = 0;
  std::string h;
  for (const char* c = host; *c && h.size() < 64; ++c) h += std::isalnum(static_cast<unsigned char>(*c)) ? *c : '_';
  static std::atomic<uint64_t> counter{0};  // per process: two stores in one process share the directory too
  return h + "-" + std::to_string(::getpid()) + "-" + std::to_string(++counter);
}

std::string VersionedDirectory::EntryOf(const std::string& name) const {
  const std::string key = AssetKey(name);
  if (OnDisk(fs::path(dir_) / key)) return key;
  std::error_code ec;  // an older server wrote names as given
  for (const fs::directory_entry& entry : fs::directory_iterator(dir_, ec)) {
    const std::string n = entry.path().filename().string();
    if (n[0] != '.' && AssetKey(n) == key) return n;
  }
  return "";
}

std::string VersionedDirectory::Read(const std::string& entry, std::vector<FileToRead>* files) const {
  // A replacement publishes its link before it removes the version it replaced, so a file gone from the version
  // read means the link has moved on: read it again (each further try lost to one more replacement in between; a
  // few are plenty).
  const fs::path path = fs::path(dir_) / entry;
  for (int attempt = 0;; ++attempt) {
    for (FileToRead& f : *files) f.read = false;
    const std::string version = VersionOf(path);  // "": an older server's plain directory, or gone
    const int dir_fd = ::open((version.empty() ? path : fs::path(dir_) / version).c_str(),
                              O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    const int open_errno = errno;
    bool gone = dir_fd < 0 && open_errno == ENOENT;
    if (dir_fd >= 0) {
      for (FileToRead& f : *files) {
        f.read = ReadFileAt(dir_fd, f.name.c_str(), f.max_bytes, &f.bytes);
        gone = gone || (!f.read && errno == ENOENT && !f.optional);
        if (!f.read) f.bytes.clear();
      }
      ::close(dir_fd);
    }
    if (gone && !version.empty() && attempt < kReadAttempts && VersionOf(path) != version) continue;
    if (dir_fd < 0) return std::string("cannot open its directory: ") + std::strerror(open_errno);
    return "";
  }
}

bool VersionedDirectory::ReadOwner(const std::string& entry, std::string* owner) const {
  owner->clear();
  const int dir_fd = ::open((fs::path(dir_) / entry).c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd < 0) return false;
  const bool read = ReadFileAt(dir_fd, "owner", 1024, owner);
  const bool none = !read && errno == ENOENT;
  ::close(dir_fd);
  return read || none;
}

VersionedDirectory::Published VersionedDirectory::Publish(const std::string& name,
                                                          const std::vector<FileToWrite>& files, bool replace,
                                                          std::string* error) {
  error->clear();
  const std::string entry = EntryOf(name);
  const fs::path final_path = fs::path(dir_) / (entry.empty() ? AssetKey(name) : entry);
  // The version, written whole and synced before anything names it.
  const std::string tag = UniqueTag(), version = ".v-" + tag;
  const fs::path version_dir = fs::path(dir_) / version, link = fs::path(dir_) / (".l-" + tag);
  std::string why;
  if (::mkdir(version_dir.c_str(), 0755) != 0) why = Failure("cannot make", version_dir);
  for (const FileToWrite& f : files)
    if (why.empty()) why = WriteFile(version_dir / f.name, f.data, f.bytes);
  if (why.empty()) why = SyncDirectory(version_dir);
  if (why.empty()) why = SyncDirectory(dir_);
  std::error_code ec;
  const auto fail = [&](const std::string& what) {
    fs::remove_all(version_dir, ec);
    fs::remove(link, ec);
    *error = what;
    return Published::kFailed;
  };
  if (!why.empty()) return fail(why);
  if (before_publish_for_test_) before_publish_for_test_();
  // Published in one atomic step. A new name: symlink(2) fails when the name exists (another server's asset
  // published since the caller's check is never moved away). A replacement: a new link renamed over the old one.
  std::string retired;  // what the replaced asset's files are now under, removed once the new one is in place
  if (!replace) {
    if (::symlink(version.c_str(), final_path.c_str()) != 0) {
      if (errno != EEXIST) return fail(Failure("cannot link", final_path));
      fail("another server stored it first");
      return Published::kExists;
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
  *error = SyncDirectory(dir_);
  if (!retired.empty()) fs::remove_all(fs::path(dir_) / retired, ec);
  Loaded(final_path.filename().string());
  return Published::kOk;
}

void VersionedDirectory::Remove(const std::string& name) {
  const std::string entry = EntryOf(name);
  Forgot(name);
  if (entry.empty()) return;
  const fs::path path = fs::path(dir_) / entry, trash = fs::path(dir_) / (".trash-" + UniqueTag());
  // The name goes in one step (the link, or an older server's directory, renamed away); then its files.
  const std::string version = VersionOf(path);
  if (::rename(path.c_str(), trash.c_str()) != 0) return;
  (void)SyncDirectory(dir_);
  std::error_code ec;
  if (!version.empty()) fs::remove_all(fs::path(dir_) / version, ec);
  fs::remove_all(trash, ec);
}

void VersionedDirectory::Loaded(const std::string& entry) {
  stamps_[AssetKey(entry)] = StampOf(entry);
  failed_.erase(AssetKey(entry));
}

void VersionedDirectory::Forgot(const std::string& name) {
  stamps_.erase(AssetKey(name));
  failed_.erase(AssetKey(name));
}

int VersionedDirectory::Sync(const SyncHooks& hooks, const std::function<void(const std::string&)>& log,
                             bool opening) {
  const auto say = [&](const std::string& line) {
    if (log) log(line);
  };
  const std::string what = hooks.what;
  int changes = 0;
  struct Entry {
    std::string name, stamp;
  };
  std::map<std::string, Entry> on_disk;  // by AssetKey
  std::error_code ec;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir_, ec)) {
    const std::string name = entry.path().filename().string();
    if (!ValidateAssetName(name).empty() || !entry.is_directory(ec)) continue;
    on_disk.emplace(AssetKey(name), Entry{name, StampOf(name)});  // one name in two cases (older servers): the first
  }
  if (ec) return 0;  // the directory unreadable for now: keep what is registered
  for (auto it = stamps_.begin(); it != stamps_.end();) {
    if (on_disk.count(it->first)) {
      ++it;
      continue;
    }
    if (const std::string name = hooks.drop(it->first); !name.empty()) {
      say(what + " '" + name + "' deleted by another server: dropped");
      ++changes;
    }
    it = stamps_.erase(it);
  }
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
    bool replaced = false;
    const std::string why = hooks.load(name, &replaced);
    if (!why.empty()) {  // tried again: at once when its files change, else after a delay that doubles
      Failed& f = failed_[key];
      using std::chrono::seconds;
      if (opening) {
        say(what + " '" + name + "' not loaded: " + why);
        f = {stamp, why, now, seconds(0)};  // the next Sync tries it again
        continue;
      }
      if (f.stamp != stamp || f.why != why) say(what + " '" + name + "' not loaded (tried again later): " + why);
      f.delay = f.stamp == stamp ? std::clamp(2 * f.delay, seconds(10), seconds(320)) : seconds(10);
      f.stamp = stamp;
      f.why = why;
      f.retry = now + f.delay;
      continue;
    }
    failed_.erase(key);
    stamps_[key] = stamp;
    if (!opening) say(what + " '" + name + "' " + (replaced ? "replaced" : "added") + " by another server: loaded");
    ++changes;
  }
  return changes;
}

}  // namespace loomlight::assets
