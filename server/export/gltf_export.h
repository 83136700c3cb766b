// Writes fitted materials as glTF 2.0 (docs/materials-out.md "glTF"): the metallic-roughness material of a
// `gltf_sheen` fit (metallic 0) with KHR_materials_sheen, one per fabric; with colourways KHR_materials_variants
// (one variant per colourway); on the product's mesh when one is given (its panels, one primitive per mesh
// material), else on a preview sphere. Written with tinygltf, as .glb or as .gltf with its buffer embedded.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "server/assets/mesh_file.h"
#include "server/models/registry.h"

namespace loomlight::exporting {

struct GltfMaterial {
  std::string name;
  models::ParamValues params;  // a gltf_sheen material's every parameter
};

struct GltfVariant {
  std::string name;
  std::vector<int> material_of_slot;  // per slot (as GltfScene::slot_material), an index into materials
};

struct GltfScene {
  std::string name;                    // the scene's and the mesh's name
  const assets::TriangleMesh* mesh = nullptr;  // null: a UV sphere of radius 0.1 m with one slot
  std::vector<GltfMaterial> materials;
  // Per slot (the mesh's material_names, in order; one for the sphere): the material it shows by default.
  std::vector<int> slot_material;
  std::vector<GltfVariant> variants;   // empty: no KHR_materials_variants
};

// "" with *out the file's bytes, or why not (a slot or material index out of range, a parameter missing or out of
// glTF's [0, 1], a mesh whose arrays disagree). One mesh of one primitive per slot that has triangles, every
// primitive on the one set of vertex attributes (POSITION, NORMAL, TEXCOORD_0 and TANGENT when the mesh has them).
std::string WriteGltf(const GltfScene& scene, bool binary, std::string* out);

// The most bytes of a name (the scene's, a material's, a variant's) the file keeps.
inline constexpr size_t kMaxGltfNameBytes = 128;

// A client's text as a name in the file: well-formed UTF-8 with every ill-formed byte and every control or
// display-reordering character (models::Quote's unprintables) replaced by U+FFFD, cut at a whole character to at
// most kMaxGltfNameBytes bytes (tinygltf escapes the rest for JSON).
std::string GltfName(std::string_view text);

}  // namespace loomlight::exporting
