// The built-in product scenes' meshes: glTF 2.0 binary files in server/render/scenes/meshes/, made once by
// Blender's cloth simulator (scripts/blender/make_product_meshes.py; their PROVENANCE.md says how) and embedded in
// the server binary at build time (cmake/EmbedFiles.cmake), so a server needs no source tree to render them.
#pragma once

#include <string>
#include <string_view>
#include <vector>

namespace loomlight::render {

// The named mesh's file bytes (a .glb), or an empty view when no built-in mesh has that name. The bytes live as
// long as the program.
std::string_view BuiltinMesh(std::string_view name);

// The built-in meshes' names (each file's name without .glb), sorted.
std::vector<std::string> BuiltinMeshNames();

}  // namespace loomlight::render
