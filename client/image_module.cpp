#include "client/image_module.h"

#include <dlfcn.h>

#include <filesystem>
#include <mutex>
#include <stdexcept>

namespace loomlight::client {

const ImageModule& image_module() {
  static std::once_flag once;
  static const ImageModule* module = nullptr;
  static std::string error;
  std::call_once(once, [] {
    std::error_code ec;
    const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
    const std::string path = (ec ? std::filesystem::path(".") : self.parent_path()) / "libloomlight_images.so";
    // RTLD_LOCAL: OpenImageIO's symbols stay the module's.
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      const char* why = dlerror();
      error = "plots and image files need the image module " + path + ", which cannot be loaded: " +
              (why ? why : "unknown error");
      return;
    }
    using Entry = const ImageModule* (*)();
    const auto entry = reinterpret_cast<Entry>(dlsym(handle, LOOMLIGHT_IMAGE_MODULE_ENTRY));
    if (entry == nullptr || (module = entry()) == nullptr)
      error = path + " is not this client's image module (no " LOOMLIGHT_IMAGE_MODULE_ENTRY "): copy the one built with it";
  });
  if (module == nullptr) throw std::runtime_error(error);
  return *module;
}

}  // namespace loomlight::client
