#include "server/export/gltf_export.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>
#include <map>
#include <sstream>
#include <string_view>

#include "server/models/quote.h"

namespace loomlight::exporting {
namespace {

using models::Number;

constexpr char kSheenExtension[] = "KHR_materials_sheen";
constexpr char kVariantsExtension[] = "KHR_materials_variants";

// The preview sphere: 64 segments around and 32 rings from pole to pole (its outline within 0.12% of a circle).
constexpr double kSphereRadius = 0.1;
constexpr int kSphereSegments = 64, kSphereRings = 32;

// A gltf_sheen material's parameters and how many numbers each holds; every one lies in [0, 1] (the glTF
// schema's range for baseColorFactor, roughnessFactor and KHR_materials_sheen's factors).
struct SheenParam {
  const char* name;
  size_t size;
};
constexpr SheenParam kSheenParams[] = {{"base_color", 3}, {"roughness", 1}, {"sheen_color", 3}, {"sheen_roughness", 1}};

std::string CheckMaterial(const GltfMaterial& material, size_t index) {
  const std::string where = "materials[" + std::to_string(index) + "]";
  for (const SheenParam& param : kSheenParams) {
    const auto it = material.params.find(param.name);
    if (it == material.params.end()) return where + ": no parameter '" + param.name + "'";
    if (it->second.size() != param.size) {
      return where + "." + param.name + ": " + std::to_string(it->second.size()) + " values, not " +
             std::to_string(param.size);
    }
    for (double v : it->second) {
      if (!(v >= 0 && v <= 1)) return where + "." + param.name + ": " + Number(v) + " is not within [0, 1]";
    }
  }
  return "";
}

std::string CheckMesh(const assets::TriangleMesh& mesh) {
  const size_t n = mesh.positions.size();
  if (mesh.triangles.empty()) return "mesh: no triangles";
  if (n > std::numeric_limits<uint32_t>::max()) return "mesh: more vertices than 32-bit indices address";
  if (mesh.normals.size() != n) return "mesh: " + std::to_string(mesh.normals.size()) + " normals for " +
                                       std::to_string(n) + " vertices";
  if (!mesh.uvs.empty() && mesh.uvs.size() != n) return "mesh: uvs are not one per vertex";
  if (!mesh.tangents.empty() && mesh.tangents.size() != n) return "mesh: tangents are not one per vertex";
  if (mesh.triangle_material.size() != mesh.triangles.size()) return "mesh: triangle_material is not one per triangle";
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (uint32_t v : mesh.triangles[t]) {
      if (v >= n) return "mesh: triangle " + std::to_string(t) + " names vertex " + std::to_string(v) + " of " +
                         std::to_string(n);
    }
    if (mesh.triangle_material[t] >= mesh.material_names.size()) {
      return "mesh: triangle " + std::to_string(t) + " names slot " + std::to_string(mesh.triangle_material[t]) +
             " of " + std::to_string(mesh.material_names.size());
    }
  }
  const auto finite = [](const auto& values, const char* name) -> std::string {
    for (size_t v = 0; v < values.size(); ++v) {
      for (float c : values[v]) {
        if (!std::isfinite(c)) return std::string("mesh: ") + name + " of vertex " + std::to_string(v) + " is not finite";
      }
    }
    return "";
  };
  std::string error = finite(mesh.positions, "position");
  if (error.empty()) error = finite(mesh.normals, "normal");
  if (error.empty()) error = finite(mesh.uvs, "uv");
  if (error.empty()) error = finite(mesh.tangents, "tangent");
  return error;
}

// Every slot's material index (scene.slot_material or a variant's material_of_slot) within materials.
std::string CheckSlots(const std::vector<int>& material_of_slot, const std::string& where, size_t slots,
                       size_t materials) {
  if (material_of_slot.size() != slots) {
    return where + ": " + std::to_string(material_of_slot.size()) + " entries for " + std::to_string(slots) +
           " slots";
  }
  for (size_t s = 0; s < slots; ++s) {
    const int m = material_of_slot[s];
    if (m < 0 || size_t(m) >= materials) {
      return where + "[" + std::to_string(s) + "]: material " + std::to_string(m) + " of " +
             std::to_string(materials);
    }
  }
  return "";
}

// A UV sphere about the origin: seam and pole vertices repeated so each has its own uv; u runs with the azimuth
// phi, stored v (TriangleMesh's, up) from 0 at the south pole to 1 at the north pole (glTF's +y up).
assets::TriangleMesh PreviewSphere() {
  assets::TriangleMesh mesh;
  const double pi = std::acos(-1.0);
  for (int ring = 0; ring <= kSphereRings; ++ring) {
    const double theta = pi * ring / kSphereRings;  // from the north pole
    for (int segment = 0; segment <= kSphereSegments; ++segment) {
      const double phi = 2 * pi * segment / kSphereSegments;
      const std::array<double, 3> n{std::sin(theta) * std::sin(phi), std::cos(theta), std::sin(theta) * std::cos(phi)};
      mesh.positions.push_back({float(kSphereRadius * n[0]), float(kSphereRadius * n[1]), float(kSphereRadius * n[2])});
      mesh.normals.push_back({float(n[0]), float(n[1]), float(n[2])});
      mesh.uvs.push_back({float(double(segment) / kSphereSegments), float(1 - double(ring) / kSphereRings)});
      // dP/dphi's direction (defined at the poles too); normal x tangent points north, along +v: w = 1.
      mesh.tangents.push_back({float(std::cos(phi)), 0.0f, float(-std::sin(phi)), 1.0f});
    }
  }
  const auto vertex = [](int ring, int segment) { return uint32_t(ring * (kSphereSegments + 1) + segment); };
  for (int ring = 0; ring < kSphereRings; ++ring) {
    for (int segment = 0; segment < kSphereSegments; ++segment) {
      const uint32_t a = vertex(ring, segment), b = vertex(ring + 1, segment), c = vertex(ring + 1, segment + 1),
                     d = vertex(ring, segment + 1);
      // Counter-clockwise seen from outside; the pole rows' other triangle would have no area.
      if (ring > 0) mesh.triangles.push_back({a, b, d});
      if (ring < kSphereRings - 1) mesh.triangles.push_back({d, b, c});
    }
  }
  mesh.triangle_material.assign(mesh.triangles.size(), 0);
  mesh.material_names = {""};
  return mesh;
}

// Builds the one buffer: each view 4-byte aligned (glTF 2.0 section 3.6.2.4 for vertex attributes).
class BufferBuilder {
 public:
  explicit BufferBuilder(tinygltf::Model* model) : model_(model) { model_->buffers.resize(1); }

  // An accessor over `count` elements of `type` at `data`; its index.
  int Add(const void* data, size_t count, int component_type, int type, int target) {
    auto& bytes = model_->buffers[0].data;
    const size_t size = count * size_t(tinygltf::GetComponentSizeInBytes(component_type)) *
                        size_t(tinygltf::GetNumComponentsInType(type));
    tinygltf::BufferView view;
    view.buffer = 0;
    view.byteOffset = bytes.size();
    view.byteLength = size;
    view.target = target;
    const auto* p = static_cast<const unsigned char*>(data);
    bytes.insert(bytes.end(), p, p + size);
    bytes.resize((bytes.size() + 3) / 4 * 4, 0);
    model_->bufferViews.push_back(view);
    tinygltf::Accessor accessor;
    accessor.bufferView = int(model_->bufferViews.size()) - 1;
    accessor.componentType = component_type;
    accessor.type = type;
    accessor.count = count;
    model_->accessors.push_back(accessor);
    return int(model_->accessors.size()) - 1;
  }

 private:
  tinygltf::Model* model_;
};

tinygltf::Value NumberArray(const std::vector<double>& values) {
  tinygltf::Value::Array array;
  for (double v : values) array.emplace_back(v);
  return tinygltf::Value(std::move(array));
}

tinygltf::Material SheenMaterial(const GltfMaterial& material) {
  tinygltf::Material out;
  out.name = GltfName(material.name);
  const auto& p = material.params;
  const std::vector<double>& base = p.at("base_color");
  out.pbrMetallicRoughness.baseColorFactor = {base[0], base[1], base[2], 1.0};
  out.pbrMetallicRoughness.metallicFactor = 0;  // gltf_sheen's base is a dielectric
  out.pbrMetallicRoughness.roughnessFactor = p.at("roughness")[0];
  out.emissiveFactor = {0, 0, 0};  // tinygltf writes an empty vector as [], which the schema refuses
  tinygltf::Value::Object sheen;
  sheen["sheenColorFactor"] = NumberArray(p.at("sheen_color"));
  sheen["sheenRoughnessFactor"] = tinygltf::Value(p.at("sheen_roughness")[0]);
  out.extensions[kSheenExtension] = tinygltf::Value(std::move(sheen));
  return out;
}

// KHR_materials_variants' mappings for one slot: one per material the variants give it, listing those variants
// (so no variant appears twice in a primitive's mappings, as the extension requires).
tinygltf::Value VariantMappings(const std::vector<GltfVariant>& variants, size_t slot) {
  std::map<int, std::vector<int>> variants_of_material;
  for (size_t v = 0; v < variants.size(); ++v) {
    variants_of_material[variants[v].material_of_slot[slot]].push_back(int(v));
  }
  tinygltf::Value::Array mappings;
  for (const auto& [material, indices] : variants_of_material) {
    tinygltf::Value::Object mapping;
    mapping["material"] = tinygltf::Value(material);
    tinygltf::Value::Array list;
    for (int v : indices) list.emplace_back(v);
    mapping["variants"] = tinygltf::Value(std::move(list));
    mappings.emplace_back(std::move(mapping));
  }
  tinygltf::Value::Object extension;
  extension["mappings"] = tinygltf::Value(std::move(mappings));
  return tinygltf::Value(std::move(extension));
}

}  // namespace

std::string GltfName(std::string_view text) {
  using models::quote_detail::Unprintable;
  using models::quote_detail::Utf8Sequence;
  static const std::string kReplacement = "\xEF\xBF\xBD";  // U+FFFD
  std::string out;
  size_t i = 0;
  while (i < text.size()) {
    uint32_t cp = 0;
    size_t n = Utf8Sequence(text.substr(i), &cp);
    std::string_view piece = text.substr(i, n);
    if (n == 0 || Unprintable(cp)) {
      n = std::max<size_t>(n, 1);
      piece = kReplacement;
    }
    if (out.size() + piece.size() > kMaxGltfNameBytes) break;
    out += piece;
    i += n;
  }
  return out;
}

std::string WriteGltf(const GltfScene& scene, bool binary, std::string* out) {
  if (scene.materials.empty()) return "no materials";
  for (size_t m = 0; m < scene.materials.size(); ++m) {
    std::string error = CheckMaterial(scene.materials[m], m);
    if (!error.empty()) return error;
  }
  assets::TriangleMesh sphere;
  if (!scene.mesh) sphere = PreviewSphere();
  const assets::TriangleMesh& mesh = scene.mesh ? *scene.mesh : sphere;
  std::string error = CheckMesh(mesh);
  if (!error.empty()) return error;
  const size_t slots = mesh.material_names.size();
  error = CheckSlots(scene.slot_material, "slot_material", slots, scene.materials.size());
  for (size_t v = 0; v < scene.variants.size() && error.empty(); ++v) {
    error = CheckSlots(scene.variants[v].material_of_slot, "variants[" + std::to_string(v) + "].material_of_slot",
                       slots, scene.materials.size());
  }
  if (!error.empty()) return error;

  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "Loomlight";
  for (const GltfMaterial& material : scene.materials) model.materials.push_back(SheenMaterial(material));
  model.extensionsUsed.push_back(kSheenExtension);
  if (!scene.variants.empty()) {
    tinygltf::Value::Array variants;
    for (const GltfVariant& variant : scene.variants) {
      tinygltf::Value::Object entry;
      entry["name"] = tinygltf::Value(GltfName(variant.name));
      variants.emplace_back(std::move(entry));
    }
    tinygltf::Value::Object extension;
    extension["variants"] = tinygltf::Value(std::move(variants));
    model.extensions[kVariantsExtension] = tinygltf::Value(std::move(extension));
    model.extensionsUsed.push_back(kVariantsExtension);
  }

  BufferBuilder buffer(&model);
  const size_t n = mesh.positions.size();
  std::map<std::string, int> attributes;
  attributes["POSITION"] = buffer.Add(mesh.positions.data(), n, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3,
                                      TINYGLTF_TARGET_ARRAY_BUFFER);
  auto& position = model.accessors.back();
  position.minValues.assign(3, std::numeric_limits<double>::infinity());
  position.maxValues.assign(3, -std::numeric_limits<double>::infinity());
  for (const auto& p : mesh.positions) {
    for (int c = 0; c < 3; ++c) {
      position.minValues[c] = std::min<double>(position.minValues[c], p[c]);
      position.maxValues[c] = std::max<double>(position.maxValues[c], p[c]);
    }
  }
  attributes["NORMAL"] = buffer.Add(mesh.normals.data(), n, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3,
                                    TINYGLTF_TARGET_ARRAY_BUFFER);
  if (!mesh.uvs.empty()) {
    std::vector<std::array<float, 2>> texcoords(n);
    for (size_t v = 0; v < n; ++v) texcoords[v] = {mesh.uvs[v][0], 1 - mesh.uvs[v][1]};  // glTF's v runs down
    attributes["TEXCOORD_0"] = buffer.Add(texcoords.data(), n, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC2,
                                          TINYGLTF_TARGET_ARRAY_BUFFER);
  }
  if (!mesh.tangents.empty()) {
    attributes["TANGENT"] = buffer.Add(mesh.tangents.data(), n, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC4,
                                       TINYGLTF_TARGET_ARRAY_BUFFER);
  }

  tinygltf::Mesh gltf_mesh;
  gltf_mesh.name = GltfName(scene.name);
  // 16-bit indices when every index fits below 65535 (the primitive-restart value glTF forbids as an index).
  const bool short_indices = n < 65535;
  std::vector<std::vector<uint32_t>> indices_of_slot(slots);
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    auto& indices = indices_of_slot[mesh.triangle_material[t]];
    indices.insert(indices.end(), mesh.triangles[t].begin(), mesh.triangles[t].end());
  }
  for (size_t slot = 0; slot < slots; ++slot) {
    const std::vector<uint32_t>& indices = indices_of_slot[slot];
    if (indices.empty()) continue;  // a slot no triangle uses has no primitive (glTF refuses empty accessors)
    tinygltf::Primitive primitive;
    primitive.attributes = attributes;
    primitive.mode = TINYGLTF_MODE_TRIANGLES;
    primitive.material = scene.slot_material[slot];
    if (short_indices) {
      const std::vector<uint16_t> narrow(indices.begin(), indices.end());
      primitive.indices = buffer.Add(narrow.data(), narrow.size(), TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT,
                                     TINYGLTF_TYPE_SCALAR, TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    } else {
      primitive.indices = buffer.Add(indices.data(), indices.size(), TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT,
                                     TINYGLTF_TYPE_SCALAR, TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    }
    if (!scene.variants.empty()) primitive.extensions[kVariantsExtension] = VariantMappings(scene.variants, slot);
    gltf_mesh.primitives.push_back(std::move(primitive));
  }
  model.meshes.push_back(std::move(gltf_mesh));
  tinygltf::Node node;
  node.mesh = 0;
  node.name = model.meshes[0].name;
  model.nodes.push_back(std::move(node));
  tinygltf::Scene gltf_scene;
  gltf_scene.name = model.meshes[0].name;
  gltf_scene.nodes = {0};
  model.scenes.push_back(std::move(gltf_scene));
  model.defaultScene = 0;

  // To a stream: tinygltf embeds the buffer (GLB's BIN chunk, or a data: URI) and opens no file.
  std::ostringstream stream;
  try {
    tinygltf::TinyGLTF writer;
    if (!writer.WriteGltfSceneToStream(&model, stream, !binary, binary)) return "tinygltf could not write the file";
  } catch (const std::exception& e) {
    return std::string("tinygltf could not write the file: ") + e.what();
  }
  *out = stream.str();
  return "";
}

}  // namespace loomlight::exporting
