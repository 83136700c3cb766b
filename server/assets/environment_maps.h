// Environment maps by name from the operator's directory (--environment-dir). A client names a map; it never
// gives a path: a name is a plain file name (letters, digits, '.', '_', '-'; no separator, not starting with
// '.'), looked up only inside the directory opened at start-up, opened without following links and used only
// when it is a regular file within the byte cap; the bytes are then decoded from memory (render::Environment).
// Unknown, badly formed and unusable names all get the same kind of answer, so nothing outside the directory
// can be probed. Decoded maps are cached by name, bounded in bytes and charged to the service's memory budget.
#pragma once

#include <sys/stat.h>

#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "server/batching/budget.h"
#include "server/render/environment.h"

namespace loomlight::assets {

class EnvironmentMaps {
 public:
  static constexpr size_t kMaxNameBytes = 128;

  // `dir` "" configures no directory (only the built-in sky and maps sent as bytes). Returns nullptr with
  // *error set when the directory cannot be opened.
  static std::unique_ptr<EnvironmentMaps> Open(const std::string& dir, size_t cache_bytes,
                                               batching::Budget* budget, std::string* error);
  ~EnvironmentMaps();

  // The names a client may use, sorted: regular files in the directory with well-formed names, within the
  // byte cap.
  std::vector<std::string> Names() const;
  // "" when `name` is well formed, else why not (never looks at the file system).
  static std::string CheckName(std::string_view name);
  // The decoded map named `name` (thread-safe; reads and decodes on the caller's thread, polling `stop` and
  // asking `admit` for the decoding's bytes as render::Environment::Decode does). Returns "" or the reason.
  std::string Get(std::string_view name, const std::function<bool()>& stop, const std::function<bool(size_t)>& admit,
                  std::shared_ptr<const render::Environment>* out);

 private:
  struct Cached {
    std::string name;
    dev_t device;
    ino_t inode;
    off_t size;
    timespec modified;
    std::shared_ptr<const render::Environment> environment;
    batching::Budget::Reservation bytes;
  };
  EnvironmentMaps(int dir_fd, size_t cache_bytes, batching::Budget* budget)
      : dir_fd_(dir_fd), cache_bytes_(cache_bytes), budget_(budget) {}
  // Opens a regular file of the directory; -1 with *error set otherwise.
  int OpenMap(std::string_view name, struct stat* st, std::string* error) const;

  const int dir_fd_;  // -1: no directory configured
  const size_t cache_bytes_;
  batching::Budget* const budget_;
  std::mutex mutex_;
  std::list<Cached> cache_;  // most recently used first
  size_t cached_bytes_ = 0;
};

}  // namespace loomlight::assets
