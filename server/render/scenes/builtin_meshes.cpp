#include "server/render/scenes/builtin_meshes.h"

#include <map>

namespace loomlight::render {

// Generated from the files CMakeLists.txt lists (cmake/EmbedFiles.cmake).
const std::map<std::string_view, std::string_view>& EmbeddedProductMeshes();

std::string_view BuiltinMesh(std::string_view name) {
  const auto& meshes = EmbeddedProductMeshes();
  const auto found = meshes.find(name);
  return found == meshes.end() ? std::string_view() : found->second;
}

std::vector<std::string> BuiltinMeshNames() {
  std::vector<std::string> names;
  for (const auto& [name, bytes] : EmbeddedProductMeshes()) names.emplace_back(name);
  return names;
}

}  // namespace loomlight::render
