#include "server/assets/environment_maps.h"

#include <dirent.h>
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace loomlight::assets {
namespace {

bool SameFile(const struct stat& st, dev_t device, ino_t inode, off_t size, timespec modified) {
  return st.st_dev == device && st.st_ino == inode && st.st_size == size &&
         st.st_mtim.tv_sec == modified.tv_sec && st.st_mtim.tv_nsec == modified.tv_nsec;
}

}  // namespace

std::unique_ptr<EnvironmentMaps> EnvironmentMaps::Open(const std::string& dir, size_t cache_bytes,
                                                       batching::Budget* budget, std::string* error) {
  int fd = -1;
  if (!dir.empty()) {
    fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) {
      *error = "--environment-dir " + dir + ": " + std::strerror(errno);
      return nullptr;
    }
  }
  return std::unique_ptr<EnvironmentMaps>(new EnvironmentMaps(fd, cache_bytes, budget));
}

EnvironmentMaps::~EnvironmentMaps() {
  if (dir_fd_ >= 0) ::close(dir_fd_);
}

std::string EnvironmentMaps::CheckName(std::string_view name) {
  const auto allowed = [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
           c == '-';
  };
  if (name.empty() || name.size() > kMaxNameBytes || name.front() == '.' ||
      !std::all_of(name.begin(), name.end(), allowed))
    return "must be a map name as ListModels lists it: 1 to " + std::to_string(kMaxNameBytes) +
           " letters, digits, '.', '_' or '-', not starting with '.' (never a path or URL)";
  return "";
}

std::vector<std::string> EnvironmentMaps::Names() const {
  std::vector<std::string> names;
  if (dir_fd_ < 0) return names;
  const int fd = ::dup(dir_fd_);
  if (fd < 0) return names;
  DIR* dir = ::fdopendir(fd);
  if (!dir) {
    ::close(fd);
    return names;
  }
  ::rewinddir(dir);
  while (const dirent* entry = ::readdir(dir)) {
    struct stat st;
    if (!CheckName(entry->d_name).empty()) continue;
    if (::fstatat(dir_fd_, entry->d_name, &st, AT_SYMLINK_NOFOLLOW) != 0 || !S_ISREG(st.st_mode) ||
        static_cast<unsigned long long>(st.st_size) > render::Environment::kMaxEncodedBytes)
      continue;
    names.emplace_back(entry->d_name);
  }
  ::closedir(dir);
  std::sort(names.begin(), names.end());
  return names;
}

int EnvironmentMaps::OpenMap(std::string_view name, struct stat* st, std::string* error) const {
  if (std::string e = CheckName(name); !e.empty()) {
    *error = e;
    return -1;
  }
  const std::string no_such = "no map named '" + std::string(name) + "' in the server's environment directory";
  if (dir_fd_ < 0) {
    *error = "the server has no environment directory (--environment-dir); send the map's bytes in `data`";
    return -1;
  }
  // O_NOFOLLOW: a link is never followed, even one placed inside the directory; O_NONBLOCK: opening a FIFO
  // does not wait for a writer (it is then refused as not a regular file).
  const int fd = ::openat(dir_fd_, std::string(name).c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) {
    *error = no_such;
    return -1;
  }
  if (::fstat(fd, st) != 0 || !S_ISREG(st->st_mode)) {
    ::close(fd);
    *error = no_such;
    return -1;
  }
  if (static_cast<unsigned long long>(st->st_size) > render::Environment::kMaxEncodedBytes) {
    ::close(fd);
    *error = "map '" + std::string(name) + "' has " + std::to_string(st->st_size) + " bytes, more than the limit of " +
             std::to_string(render::Environment::kMaxEncodedBytes);
    return -1;
  }
  return fd;
}

std::string EnvironmentMaps::Get(std::string_view name, const std::function<bool()>& stop,
                                 const std::function<bool(size_t)>& admit,
                                 std::shared_ptr<const render::Environment>* out) {
  struct stat st;
  std::string error;
  const int fd = OpenMap(name, &st, &error);
  if (fd < 0) return error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto it = cache_.begin(); it != cache_.end(); ++it)
      if (it->name == name && SameFile(st, it->device, it->inode, it->size, it->modified)) {
        cache_.splice(cache_.begin(), cache_, it);
        *out = it->environment;
        ::close(fd);
        return "";
      }
  }
  // Read the file whole (it is within the byte cap), checking for a stop between blocks.
  if (admit && !admit(static_cast<size_t>(st.st_size))) {
    ::close(fd);
    return "the server's memory budget cannot take the map's bytes now; retry later";
  }
  std::string bytes(static_cast<size_t>(st.st_size), '\0');
  size_t done = 0;
  while (done < bytes.size()) {
    if (stop && stop()) {
      ::close(fd);
      return "stopped while reading (deadline or cancellation)";
    }
    const ssize_t n = ::read(fd, bytes.data() + done, std::min<size_t>(bytes.size() - done, size_t{1} << 20));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += static_cast<size_t>(n);
  }
  ::close(fd);
  if (done != bytes.size()) return "map '" + std::string(name) + "' changed while it was read";
  auto environment = std::make_shared<render::Environment>();
  if (std::string e = render::Environment::Decode(bytes, stop, admit, environment.get()); !e.empty())
    return "map '" + std::string(name) + "': " + e;
  *out = environment;

  // Cache it when its bytes fit both the cache and the service's budget; otherwise it is used uncached.
  const size_t size = environment->bytes();
  std::lock_guard<std::mutex> lock(mutex_);
  cache_.remove_if([&](const Cached& c) {
    const bool stale = c.name == name;
    if (stale) cached_bytes_ -= c.bytes.bytes();
    return stale;
  });
  while (!cache_.empty() && cached_bytes_ + size > cache_bytes_) {
    cached_bytes_ -= cache_.back().bytes.bytes();
    cache_.pop_back();
  }
  batching::Budget::Reservation reservation;
  if (size <= cache_bytes_ && budget_->TryReserve(size, &reservation)) {
    cache_.push_front(Cached{std::string(name), st.st_dev, st.st_ino, st.st_size, st.st_mtim, environment,
                             std::move(reservation)});
    cached_bytes_ += size;
  }
  return "";
}

}  // namespace loomlight::assets
