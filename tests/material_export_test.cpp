// The glTF and MaterialX writers (server/export/): checked by other tools reading our files, not by our own code.
// The Khronos glTF validator (npm gltf-validator in tests/gltf, run by node; scripts/test.sh installs it) must
// find no error and no warning; tinygltf reads the factors, variants and geometry back as given; Blender's own
// importer (where /usr/bin/blender exists) finds the sheen and the variants; pugixml reads the MaterialX document
// back against the inputs MaterialX's nodedef declares. Bad input gets an error naming it.
#include <google/protobuf/struct.pb.h>
#include <google/protobuf/util/json_util.h>
#include <gtest/gtest.h>
#include <pugixml.hpp>
#include <tiny_gltf.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <sstream>

#include "server/assets/mesh_file.h"
#include "server/export/gltf_export.h"
#include "server/export/mtlx_export.h"

namespace loomlight::exporting {
namespace {

namespace fs = std::filesystem;
using google::protobuf::Struct;
using google::protobuf::Value;

// ---- Files, processes and JSON ----

const fs::path& TempDir() {
  static const fs::path dir = [] {
    std::string pattern = (fs::temp_directory_path() / "material_export_test.XXXXXX").string();
    if (!mkdtemp(pattern.data())) ADD_FAILURE() << "mkdtemp: " << std::strerror(errno);
    return fs::path(pattern);
  }();
  return dir;
}

class RemoveTempDir : public ::testing::Environment {
 public:
  void TearDown() override { fs::remove_all(TempDir()); }
};
const auto* const kRemoveTempDir = ::testing::AddGlobalTestEnvironment(new RemoveTempDir);

std::string WriteTemp(const std::string& name, const std::string& bytes) {
  const fs::path path = TempDir() / name;
  std::ofstream(path, std::ios::binary) << bytes;
  return path.string();
}

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return bytes.str();
}

// Runs a shell command; its exit status, with stdout and stderr together in *output.
int RunCommand(const std::string& command, std::string* output) {
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return -1;
  output->clear();
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, pipe)) > 0) output->append(buf, n);
  const int status = pclose(pipe);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

bool OnPath(const std::string& program) {
  std::string ignored;
  return RunCommand("command -v " + program, &ignored) == 0;
}

std::string Tail(const std::string& text, size_t bytes = 3000) {
  return text.size() <= bytes ? text : "..." + text.substr(text.size() - bytes);
}

const Value& Field(const Struct& object, const std::string& key) {
  static const Value kNull;
  const auto it = object.fields().find(key);
  return it == object.fields().end() ? kNull : it->second;
}

// ---- Inputs ----

models::ParamValues Sheen(std::array<double, 3> base, double roughness, std::array<double, 3> sheen,
                          double sheen_roughness) {
  return {{"base_color", {base[0], base[1], base[2]}},
          {"roughness", {roughness}},
          {"sheen_color", {sheen[0], sheen[1], sheen[2]}},
          {"sheen_roughness", {sheen_roughness}}};
}

std::vector<GltfMaterial> ThreeFabrics() {
  return {{"Linen", Sheen({0.62, 0.11, 0.27}, 0.83, {0.95, 0.41, 0.5}, 0.36)},
          {"Stand", Sheen({0.05, 0.05, 0.06}, 0.4, {0, 0, 0}, 0)},
          {"Velvet", Sheen({0.02, 0.3, 0.12}, 0.61, {0.7, 0.9, 0.2}, 0.77)}};
}

// drape_stand.glb, a product mesh of the render scenes: two slots ("fabric", "stand").
const assets::TriangleMesh& DrapeStand() {
  static const assets::TriangleMesh mesh = [] {
    assets::TriangleMesh out;
    const std::string bytes =
        ReadFile(fs::path(LOOMLIGHT_SOURCE_DIR) / "server/render/scenes/meshes/drape_stand.glb");
    const std::string error = assets::ParseMesh(bytes, v1::MESH_FORMAT_GLB, {}, &out);
    EXPECT_EQ(error, "");
    return out;
  }();
  return mesh;
}

GltfScene TwoSlotScene() {
  GltfScene scene;
  scene.name = "drape stand";
  scene.mesh = &DrapeStand();
  scene.materials = {ThreeFabrics()[0], ThreeFabrics()[1]};
  scene.slot_material = {0, 1};
  return scene;
}

// Three colourways on drape_stand: the fabric slot in each of the three materials, the stand in two of them.
GltfScene ThreeColourwayScene() {
  GltfScene scene = TwoSlotScene();
  scene.materials = ThreeFabrics();
  scene.variants = {{"Rose", {0, 1}}, {"Ebony", {1, 1}}, {"Moss", {2, 0}}};
  return scene;
}

GltfScene SphereScene() {
  GltfScene scene;
  scene.name = "preview";
  scene.materials = {ThreeFabrics()[0]};
  scene.slot_material = {0};
  return scene;
}

std::string Written(const GltfScene& scene, bool binary) {
  std::string bytes;
  EXPECT_EQ(WriteGltf(scene, binary, &bytes), "");
  return bytes;
}

tinygltf::Model ReadBack(const std::string& bytes, bool binary) {
  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string error, warning;
  const bool ok = binary ? loader.LoadBinaryFromMemory(&model, &error, &warning,
                                                       reinterpret_cast<const unsigned char*>(bytes.data()),
                                                       unsigned(bytes.size()))
                         : loader.LoadASCIIFromString(&model, &error, &warning, bytes.data(), unsigned(bytes.size()), "");
  EXPECT_TRUE(ok) << error;
  EXPECT_EQ(warning, "");
  return model;
}

// ---- The Khronos glTF validator ----

// Its report on `path` (tests/gltf/validate.js); fails the test, saying how to install it, when node or the
// validator is missing.
bool Validate(const std::string& path, Struct* report) {
  const fs::path dir = GLTF_VALIDATOR_DIR;
  const std::string install = "install it with scripts/test.sh, or: scripts/install-deps.sh && (cd " + dir.string() +
                              " && npm ci)";
  if (!OnPath("node")) {
    ADD_FAILURE() << "node is not installed; " << install;
    return false;
  }
  if (!fs::exists(dir / "node_modules/gltf-validator/package.json")) {
    ADD_FAILURE() << "the glTF validator is not in " << dir / "node_modules" << "; " << install;
    return false;
  }
  std::string output;
  const int status = RunCommand("node '" + (dir / "validate.js").string() + "' '" + path + "'", &output);
  if (status != 0) {
    ADD_FAILURE() << "validate.js exited with " << status << ": " << Tail(output);
    return false;
  }
  const auto parsed = google::protobuf::util::JsonStringToMessage(output, report);
  if (!parsed.ok()) {
    ADD_FAILURE() << "the validator's report is not JSON (" << parsed.ToString() << "): " << Tail(output);
    return false;
  }
  return true;
}

// The infos we allow, and why: TEXCOORD_0 and TANGENT are written for the textures (a woven pattern, a normal
// map) a client may add to the file; while the fitted material has none, the validator notes of each
// "UNUSED_OBJECT: This object may be unused." (TEXCOORD_0) and "UNUSED_MESH_TANGENT: Tangents are not used because
// the material has no normal texture." (TANGENT). Blender's own drape_stand.glb gets the first on its TEXCOORD_0.
bool AllowedInfo(const Struct& message) {
  const std::string code = Field(message, "code").string_value();
  const std::string pointer = Field(message, "pointer").string_value();
  const auto ends_with = [&](const std::string& tail) {
    return pointer.size() >= tail.size() && pointer.compare(pointer.size() - tail.size(), tail.size(), tail) == 0;
  };
  return Field(message, "severity").number_value() == 2 &&
         ((code == "UNUSED_OBJECT" && ends_with("/attributes/TEXCOORD_0")) ||
          (code == "UNUSED_MESH_TANGENT" && ends_with("/attributes/TANGENT")));
}

// Validates `bytes` written to `name`: no error, no warning, only the infos above. Prints the summary.
void ExpectValid(const std::string& name, const std::string& bytes) {
  ASSERT_FALSE(bytes.empty());
  const std::string path = WriteTemp(name, bytes);
  Struct report;
  if (!Validate(path, &report)) return;
  const Struct& issues = Field(report, "issues").struct_value();
  const Struct& info = Field(report, "info").struct_value();
  std::cout << name << ": " << bytes.size() << " bytes; gltf-validator "
            << Field(report, "validatorVersion").string_value() << ": " << Field(issues, "numErrors").number_value()
            << " errors, " << Field(issues, "numWarnings").number_value() << " warnings, "
            << Field(issues, "numInfos").number_value() << " infos, " << Field(issues, "numHints").number_value()
            << " hints; " << Field(info, "totalVertexCount").number_value() << " vertices, "
            << Field(info, "totalTriangleCount").number_value() << " triangles, "
            << Field(info, "drawCallCount").number_value() << " draw calls, "
            << Field(info, "materialCount").number_value() << " materials\n";
  EXPECT_EQ(Field(issues, "numErrors").number_value(), 0);
  EXPECT_EQ(Field(issues, "numWarnings").number_value(), 0);
  EXPECT_FALSE(Field(issues, "truncated").bool_value());
  for (const Value& message : Field(issues, "messages").list_value().values()) {
    const Struct& m = message.struct_value();
    EXPECT_TRUE(AllowedInfo(m)) << "severity " << Field(m, "severity").number_value() << " "
                                << Field(m, "code").string_value() << " at " << Field(m, "pointer").string_value()
                                << ": " << Field(m, "message").string_value();
  }
  // The validator read our embedded buffer (GLB chunk or data: URI), not a file beside it.
  const auto& resources = Field(info, "resources").list_value().values();
  ASSERT_EQ(resources.size(), 1u);
  const std::string storage = Field(resources[0].struct_value(), "storage").string_value();
  EXPECT_TRUE(storage == "glb" || storage == "data-uri") << storage;
}

TEST(GltfExport, SphereGlbPassesTheKhronosValidator) { ExpectValid("sphere.glb", Written(SphereScene(), true)); }

TEST(GltfExport, SphereGltfPassesTheKhronosValidator) {
  const std::string json = Written(SphereScene(), false);
  EXPECT_EQ(json.front(), '{');
  EXPECT_NE(json.find("data:application/octet-stream;base64,"), std::string::npos);
  ExpectValid("sphere.gltf", json);
}

TEST(GltfExport, ProductMeshWithTwoSlotsPassesTheKhronosValidator) {
  ExpectValid("drape_stand.glb", Written(TwoSlotScene(), true));
}

TEST(GltfExport, ThreeColourwaysPassTheKhronosValidator) {
  ExpectValid("colourways.glb", Written(ThreeColourwayScene(), true));
  ExpectValid("colourways.gltf", Written(ThreeColourwayScene(), false));
}

// ---- Read back with tinygltf ----

void ExpectFactors(const tinygltf::Material& read, const GltfMaterial& given) {
  const auto& p = given.params;
  SCOPED_TRACE(given.name);
  EXPECT_EQ(read.name, given.name);
  const auto& pbr = read.pbrMetallicRoughness;
  ASSERT_EQ(pbr.baseColorFactor.size(), 4u);
  for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(pbr.baseColorFactor[c], p.at("base_color")[c]);
  EXPECT_EQ(pbr.baseColorFactor[3], 1);
  EXPECT_EQ(pbr.metallicFactor, 0);
  EXPECT_DOUBLE_EQ(pbr.roughnessFactor, p.at("roughness")[0]);
  const auto sheen = read.extensions.find("KHR_materials_sheen");
  ASSERT_NE(sheen, read.extensions.end());
  const tinygltf::Value& color = sheen->second.Get("sheenColorFactor");
  ASSERT_TRUE(color.IsArray());
  ASSERT_EQ(color.ArrayLen(), 3u);
  for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(color.Get(c).GetNumberAsDouble(), p.at("sheen_color")[c]);
  EXPECT_DOUBLE_EQ(sheen->second.Get("sheenRoughnessFactor").GetNumberAsDouble(), p.at("sheen_roughness")[0]);
}

TEST(GltfExport, MaterialFactorsReadBackAsGiven) {
  for (bool binary : {true, false}) {
    const GltfScene scene = TwoSlotScene();
    const tinygltf::Model model = ReadBack(Written(scene, binary), binary);
    EXPECT_EQ(model.asset.generator, "Loomlight");
    EXPECT_EQ(model.asset.version, "2.0");
    EXPECT_EQ(model.extensionsUsed, std::vector<std::string>{"KHR_materials_sheen"});
    EXPECT_TRUE(model.extensionsRequired.empty());  // a viewer without sheen still shows the base
    ASSERT_EQ(model.materials.size(), scene.materials.size());
    for (size_t m = 0; m < scene.materials.size(); ++m) ExpectFactors(model.materials[m], scene.materials[m]);
    ASSERT_EQ(model.meshes.size(), 1u);
    ASSERT_EQ(model.meshes[0].primitives.size(), 2u);
    for (size_t slot = 0; slot < 2; ++slot) {
      EXPECT_EQ(model.meshes[0].primitives[slot].material, scene.slot_material[slot]);
    }
  }
}

TEST(GltfExport, VariantsMapAsGiven) {
  const GltfScene scene = ThreeColourwayScene();
  const tinygltf::Model model = ReadBack(Written(scene, true), true);
  EXPECT_EQ(model.extensionsUsed, (std::vector<std::string>{"KHR_materials_sheen", "KHR_materials_variants"}));
  const auto root = model.extensions.find("KHR_materials_variants");
  ASSERT_NE(root, model.extensions.end());
  const tinygltf::Value& variants = root->second.Get("variants");
  ASSERT_EQ(variants.ArrayLen(), scene.variants.size());
  for (size_t v = 0; v < scene.variants.size(); ++v) {
    EXPECT_EQ(variants.Get(int(v)).Get("name").Get<std::string>(), scene.variants[v].name);
  }
  const auto& primitives = model.meshes.at(0).primitives;
  ASSERT_EQ(primitives.size(), 2u);
  for (size_t slot = 0; slot < primitives.size(); ++slot) {
    // The extension's rule: a variant's material is the mapping that lists it; each variant listed once.
    std::map<int, int> material_of_variant;
    const tinygltf::Value& mappings = primitives[slot].extensions.at("KHR_materials_variants").Get("mappings");
    for (size_t i = 0; i < mappings.ArrayLen(); ++i) {
      const tinygltf::Value& mapping = mappings.Get(int(i));
      const tinygltf::Value& listed = mapping.Get("variants");
      for (size_t k = 0; k < listed.ArrayLen(); ++k) {
        const int variant = listed.Get(int(k)).GetNumberAsInt();
        EXPECT_TRUE(material_of_variant.emplace(variant, mapping.Get("material").GetNumberAsInt()).second)
            << "variant " << variant << " mapped twice in slot " << slot;
      }
    }
    ASSERT_EQ(material_of_variant.size(), scene.variants.size()) << "slot " << slot;
    for (size_t v = 0; v < scene.variants.size(); ++v) {
      EXPECT_EQ(material_of_variant[int(v)], scene.variants[v].material_of_slot[slot]) << "slot " << slot << " variant " << v;
    }
  }
}

// An accessor's elements as floats (the writer's attributes are all float).
template <int N>
std::vector<std::array<float, N>> FloatElements(const tinygltf::Model& model, int accessor_index) {
  const tinygltf::Accessor& accessor = model.accessors.at(accessor_index);
  EXPECT_EQ(accessor.componentType, TINYGLTF_COMPONENT_TYPE_FLOAT);
  const tinygltf::BufferView& view = model.bufferViews.at(accessor.bufferView);
  const unsigned char* data = model.buffers.at(view.buffer).data.data() + view.byteOffset + accessor.byteOffset;
  const size_t stride = view.byteStride ? view.byteStride : N * sizeof(float);
  std::vector<std::array<float, N>> out(accessor.count);
  for (size_t i = 0; i < accessor.count; ++i) std::memcpy(out[i].data(), data + i * stride, N * sizeof(float));
  return out;
}

std::vector<uint32_t> Indices(const tinygltf::Model& model, int accessor_index) {
  const tinygltf::Accessor& accessor = model.accessors.at(accessor_index);
  const tinygltf::BufferView& view = model.bufferViews.at(accessor.bufferView);
  const unsigned char* data = model.buffers.at(view.buffer).data.data() + view.byteOffset + accessor.byteOffset;
  std::vector<uint32_t> out(accessor.count);
  for (size_t i = 0; i < accessor.count; ++i) {
    if (accessor.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT) {
      uint16_t v;
      std::memcpy(&v, data + 2 * i, 2);
      out[i] = v;
    } else {
      EXPECT_EQ(accessor.componentType, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT);
      std::memcpy(&out[i], data + 4 * i, 4);
    }
  }
  return out;
}

// A mesh's triangles as their corners' positions and uvs, slot by slot (a reader may number vertices its own way
// and read the slots' triangles one primitive after another).
struct Corner {
  std::array<float, 3> position;
  std::array<float, 2> uv;
};
using SlotTriangles = std::vector<std::vector<std::array<Corner, 3>>>;
SlotTriangles TrianglesBySlot(const assets::TriangleMesh& mesh) {
  std::vector<std::vector<std::array<Corner, 3>>> out(mesh.material_names.size());
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    std::array<Corner, 3> corners;
    for (int k = 0; k < 3; ++k) {
      const uint32_t v = mesh.triangles[t][k];
      corners[k] = {mesh.positions[v], mesh.uvs.empty() ? std::array<float, 2>{} : mesh.uvs[v]};
    }
    out[mesh.triangle_material[t]].push_back(corners);
  }
  return out;
}

// Positions exactly; uvs within float rounding (glTF's v is 1 - ours, rounded, and a reader's 1 - v again).
void ExpectSameTriangles(const SlotTriangles& read, const SlotTriangles& given) {
  ASSERT_EQ(read.size(), given.size());
  for (size_t slot = 0; slot < given.size(); ++slot) {
    ASSERT_EQ(read[slot].size(), given[slot].size()) << "slot " << slot;
    for (size_t t = 0; t < given[slot].size(); ++t) {
      for (int k = 0; k < 3; ++k) {
        const Corner &a = read[slot][t][k], &b = given[slot][t][k];
        ASSERT_EQ(a.position, b.position) << "slot " << slot << " triangle " << t;
        ASSERT_EQ(a.uv[0], b.uv[0]) << "slot " << slot << " triangle " << t;
        ASSERT_NEAR(a.uv[1], b.uv[1], 1e-7) << "slot " << slot << " triangle " << t;
      }
    }
  }
}

TEST(GltfExport, ProductMeshGeometryReadsBackAsGiven) {
  const assets::TriangleMesh& mesh = DrapeStand();
  ASSERT_EQ(mesh.material_names.size(), 2u);
  ASSERT_FALSE(mesh.uvs.empty());
  ASSERT_FALSE(mesh.tangents.empty());
  const std::string bytes = Written(TwoSlotScene(), true);
  const tinygltf::Model model = ReadBack(bytes, true);
  const auto& primitives = model.meshes.at(0).primitives;
  ASSERT_EQ(primitives.size(), 2u);
  for (size_t slot = 0; slot < 2; ++slot) {
    const auto& attributes = primitives[slot].attributes;
    const auto positions = FloatElements<3>(model, attributes.at("POSITION"));
    ASSERT_EQ(positions.size(), mesh.positions.size());
    EXPECT_EQ(positions, mesh.positions);
    const tinygltf::Accessor& position = model.accessors.at(attributes.at("POSITION"));
    for (int c = 0; c < 3; ++c) {  // the bounds glTF requires, against the mesh's own
      EXPECT_FLOAT_EQ(position.minValues.at(c), mesh.bounds_min[c]);
      EXPECT_FLOAT_EQ(position.maxValues.at(c), mesh.bounds_max[c]);
    }
    EXPECT_EQ(FloatElements<3>(model, attributes.at("NORMAL")), mesh.normals);
    EXPECT_EQ(FloatElements<4>(model, attributes.at("TANGENT")), mesh.tangents);
    const auto texcoords = FloatElements<2>(model, attributes.at("TEXCOORD_0"));
    ASSERT_EQ(texcoords.size(), mesh.uvs.size());
    for (size_t v = 0; v < texcoords.size(); ++v) {  // glTF's v runs down the image, TriangleMesh's up
      ASSERT_EQ(texcoords[v][0], mesh.uvs[v][0]);
      ASSERT_NEAR(texcoords[v][1], 1 - double(mesh.uvs[v][1]), 1e-7);
    }
    std::vector<std::array<uint32_t, 3>> expected;
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      if (mesh.triangle_material[t] == slot) expected.push_back(mesh.triangles[t]);
    }
    const auto indices = Indices(model, primitives[slot].indices);
    ASSERT_EQ(indices.size(), 3 * expected.size()) << "slot " << slot;
    for (size_t t = 0; t < expected.size(); ++t) {
      ASSERT_EQ((std::array<uint32_t, 3>{indices[3 * t], indices[3 * t + 1], indices[3 * t + 2]}), expected[t]);
    }
  }
  // And the renderer's own reader gives the mesh back: slots named by our materials, the same triangles.
  assets::TriangleMesh again;
  ASSERT_EQ(assets::ParseMesh(bytes, v1::MESH_FORMAT_GLB, {}, &again), "");
  EXPECT_EQ(again.material_names, (std::vector<std::string>{"Linen", "Stand"}));
  ExpectSameTriangles(TrianglesBySlot(again), TrianglesBySlot(mesh));
  std::cout << "drape_stand: " << mesh.positions.size() << " vertices, " << mesh.triangles.size()
            << " triangles; product GLB " << bytes.size() << " bytes (Blender's own file "
            << fs::file_size(fs::path(LOOMLIGHT_SOURCE_DIR) / "server/render/scenes/meshes/drape_stand.glb")
            << " bytes)\n";
}

TEST(GltfExport, PreviewSphereIsRoundWithOutwardFrames) {
  const std::string bytes = Written(SphereScene(), true);
  const tinygltf::Model model = ReadBack(bytes, true);
  ASSERT_EQ(model.meshes.at(0).primitives.size(), 1u);
  const auto& primitive = model.meshes[0].primitives[0];
  const auto positions = FloatElements<3>(model, primitive.attributes.at("POSITION"));
  const auto normals = FloatElements<3>(model, primitive.attributes.at("NORMAL"));
  const auto tangents = FloatElements<4>(model, primitive.attributes.at("TANGENT"));
  const auto texcoords = FloatElements<2>(model, primitive.attributes.at("TEXCOORD_0"));
  const auto indices = Indices(model, primitive.indices);
  const double radius = 0.1, pi = std::acos(-1.0);
  const auto dot = [](const auto& a, const auto& b) { return double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2]; };
  const auto cross = [](const auto& a, const auto& b) {
    return std::array<double, 3>{double(a[1]) * b[2] - double(a[2]) * b[1], double(a[2]) * b[0] - double(a[0]) * b[2],
                                 double(a[0]) * b[1] - double(a[1]) * b[0]};
  };
  for (size_t v = 0; v < positions.size(); ++v) {
    const auto& p = positions[v];
    const double r = std::sqrt(dot(p, p));
    ASSERT_NEAR(r, radius, 1e-7) << v;
    ASSERT_NEAR(dot(normals[v], p) / r, 1, 1e-6) << v;  // the normal points out along the radius
    const auto& t = tangents[v];
    ASSERT_NEAR(dot(t, t), 1, 1e-6) << v;
    ASSERT_NEAR(dot(t, normals[v]), 0, 1e-6) << v;
    ASSERT_TRUE(t[3] == 1 || t[3] == -1) << v;
    // glTF's v runs down the image: 0 at the north pole (+y), 1 at the south.
    ASSERT_NEAR(texcoords[v][1], std::acos(std::clamp(p[1] / r, -1.0, 1.0)) / pi, 1e-6) << v;
    const double horizontal = std::hypot(p[0], p[2]);
    if (horizontal > 1e-3 * radius) {
      // u runs with the azimuth from +z towards +x (the seam's vertices at u = 0 and u = 1).
      const double azimuth = std::atan2(p[0], p[2]) / (2 * pi);
      const double u = texcoords[v][0];
      ASSERT_NEAR(std::remainder(u - azimuth, 1.0), 0, 1e-6) << v;
      // TANGENT points along +u, and w * (normal x tangent) up the image (towards the north pole), the frame
      // mesh_file.h's reader keeps.
      const std::array<double, 3> east{p[2] / horizontal, 0, -p[0] / horizontal};
      ASSERT_GT(dot(t, east), 0.999) << v;
      const auto bitangent = cross(normals[v], t);
      ASSERT_GT(t[3] * (bitangent[1]), 0) << v;
    }
  }
  // Every triangle faces out (counter-clockwise seen from outside) and has area; its edges' midpoints lie within
  // 0.25% of the radius, so the silhouette looks round.
  ASSERT_EQ(indices.size() % 3, 0u);
  double worst_sag = 0;
  for (size_t i = 0; i < indices.size(); i += 3) {
    const auto& a = positions[indices[i]];
    const auto& b = positions[indices[i + 1]];
    const auto& c = positions[indices[i + 2]];
    const std::array<double, 3> ab{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, ac{c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const std::array<double, 3> centroid{(a[0] + b[0] + c[0]) / 3, (a[1] + b[1] + c[1]) / 3, (a[2] + b[2] + c[2]) / 3};
    ASSERT_GT(dot(cross(ab, ac), centroid), 0) << "triangle " << i / 3;
    for (const auto* e : {&a, &b, &c}) {
      const auto* f = e == &a ? &b : e == &b ? &c : &a;
      const std::array<double, 3> mid{((*e)[0] + (*f)[0]) / 2.0, ((*e)[1] + (*f)[1]) / 2.0, ((*e)[2] + (*f)[2]) / 2.0};
      worst_sag = std::max(worst_sag, 1 - std::sqrt(dot(mid, mid)) / radius);
    }
  }
  EXPECT_LT(worst_sag, 0.0025);
  std::cout << "sphere: " << positions.size() << " vertices, " << indices.size() / 3 << " triangles, worst edge "
            << worst_sag * 100 << "% inside the radius; GLB " << bytes.size() << " bytes, glTF "
            << Written(SphereScene(), false).size() << " bytes\n";
}

// A flat square cloth of side 1 m in the xz-plane facing +y, `cells` x `cells` quads; the left half in slot 0, the
// right half in slot 1, and a third slot no triangle uses.
assets::TriangleMesh Grid(int cells) {
  assets::TriangleMesh mesh;
  for (int i = 0; i <= cells; ++i) {
    for (int j = 0; j <= cells; ++j) {
      const float u = float(j) / cells, v = float(i) / cells;
      mesh.positions.push_back({u - 0.5f, 0, 0.5f - v});  // +v away from the viewer at +z, as +u runs along +x
      mesh.normals.push_back({0, 1, 0});
      mesh.uvs.push_back({u, v});
      mesh.tangents.push_back({1, 0, 0, 1});
    }
  }
  const auto vertex = [&](int i, int j) { return uint32_t(i * (cells + 1) + j); };
  for (int i = 0; i < cells; ++i) {
    for (int j = 0; j < cells; ++j) {
      const uint32_t slot = j < cells / 2 ? 0 : 1;
      mesh.triangles.push_back({vertex(i, j), vertex(i, j + 1), vertex(i + 1, j + 1)});
      mesh.triangles.push_back({vertex(i, j), vertex(i + 1, j + 1), vertex(i + 1, j)});
      mesh.triangle_material.insert(mesh.triangle_material.end(), {slot, slot});
    }
  }
  mesh.material_names = {"left", "right", "unused"};
  return mesh;
}

TEST(GltfExport, LargeMeshTakes32BitIndicesAndAnUnusedSlotNoPrimitive) {
  const assets::TriangleMesh mesh = Grid(300);  // 90,601 vertices: past 16-bit indices
  GltfScene scene;
  scene.name = "grid";
  scene.mesh = &mesh;
  scene.materials = {ThreeFabrics()[0], ThreeFabrics()[2]};
  scene.slot_material = {0, 1, 1};
  const std::string bytes = Written(scene, true);
  ExpectValid("grid.glb", bytes);
  const tinygltf::Model model = ReadBack(bytes, true);
  const auto& primitives = model.meshes.at(0).primitives;
  ASSERT_EQ(primitives.size(), 2u);
  size_t indices = 0;
  for (const auto& primitive : primitives) {
    EXPECT_EQ(model.accessors.at(primitive.indices).componentType, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT);
    indices += Indices(model, primitive.indices).size();
    EXPECT_EQ(model.accessors.at(primitive.attributes.at("POSITION")).count, mesh.positions.size());
  }
  EXPECT_EQ(indices, 3 * mesh.triangles.size());
  assets::TriangleMesh again;
  ASSERT_EQ(assets::ParseMesh(bytes, v1::MESH_FORMAT_GLB, {}, &again), "");
  // Slots by material name: the unused slot is gone, the others read back with their triangles.
  EXPECT_EQ(again.material_names, (std::vector<std::string>{"Linen", "Velvet"}));
  auto expected = TrianglesBySlot(mesh);
  expected.pop_back();
  ExpectSameTriangles(TrianglesBySlot(again), expected);
}

// ---- Names ----

bool WellFormedUtf8(const std::string& s) {
  for (size_t i = 0; i < s.size();) {
    const auto b = static_cast<unsigned char>(s[i]);
    const size_t n = b < 0x80 ? 1 : (b >> 5) == 6 ? 2 : (b >> 4) == 14 ? 3 : (b >> 3) == 30 ? 4 : 0;
    if (n == 0 || i + n > s.size()) return false;
    for (size_t k = 1; k < n; ++k) {
      if ((static_cast<unsigned char>(s[i + k]) & 0xC0) != 0x80) return false;
    }
    i += n;
  }
  return true;
}

const std::vector<std::string>& HostileNames() {
  static const std::vector<std::string> names = {
      "\"quoted\" 'and' \\back\\slash", "<tag attr=\"x\">&amp;</tag>", "Soie \xC3\xA9" "crue \xE7\xB5\xB9 \xF0\x9F\xA7\xB5",
      "", std::string(10000, 'x'), "line\nbreak\ttab\x01\x7F", "bad \xFF\xC0 utf8 \xE2\x82", "]]><!--",
      std::string(5000, '\xE7') /* 5000 lead bytes */, "123 starts with digits", "Linen", "Linen"};
  return names;
}

TEST(GltfExport, HostileNamesStayValidAndBounded) {
  GltfScene scene = ThreeColourwayScene();
  scene.name = HostileNames()[4];
  scene.materials.clear();
  scene.variants.clear();
  for (const std::string& name : HostileNames()) {
    scene.materials.push_back({name, ThreeFabrics()[0].params});
    scene.variants.push_back({name, {int(scene.materials.size()) - 1, 1}});
  }
  const std::string bytes = Written(scene, true);
  ExpectValid("hostile.glb", bytes);
  const tinygltf::Model model = ReadBack(bytes, true);
  ASSERT_EQ(model.materials.size(), HostileNames().size());
  const tinygltf::Value& variants = model.extensions.at("KHR_materials_variants").Get("variants");
  for (size_t i = 0; i < HostileNames().size(); ++i) {
    for (const std::string& name : {model.materials[i].name, variants.Get(int(i)).Get("name").Get<std::string>()}) {
      EXPECT_LE(name.size(), kMaxGltfNameBytes);
      EXPECT_TRUE(WellFormedUtf8(name)) << i;
      for (char c : name) EXPECT_GE(static_cast<unsigned char>(c), 0x20) << i;  // no control characters
    }
  }
  // Printable names within the bound are kept as given, unicode and markup included.
  for (size_t i : {0, 1, 2, 7, 9, 10}) EXPECT_EQ(model.materials[i].name, HostileNames()[i]) << i;
  EXPECT_EQ(model.materials[4].name, std::string(kMaxGltfNameBytes, 'x'));
  EXPECT_EQ(model.meshes[0].name, std::string(kMaxGltfNameBytes, 'x'));
}

// ---- Bad input ----

void ExpectRefused(const GltfScene& scene, const std::string& names) {
  std::string out = "untouched";
  const std::string error = WriteGltf(scene, true, &out);
  EXPECT_NE(error.find(names), std::string::npos) << "error: '" << error << "', expected it to name " << names;
  EXPECT_EQ(out, "untouched");
}

TEST(GltfExport, BadInputGivesAnErrorNamingIt) {
  GltfScene scene = ThreeColourwayScene();
  scene.slot_material = {0, 3};
  ExpectRefused(scene, "slot_material[1]: material 3 of 3");
  scene.slot_material = {-1, 0};
  ExpectRefused(scene, "slot_material[0]: material -1 of 3");
  scene.slot_material = {0};
  ExpectRefused(scene, "slot_material: 1 entries for 2 slots");
  scene = ThreeColourwayScene();
  scene.variants[2].material_of_slot = {0, 7};
  ExpectRefused(scene, "variants[2].material_of_slot[1]: material 7 of 3");
  scene.variants[2].material_of_slot = {0, 1, 2};
  ExpectRefused(scene, "variants[2].material_of_slot: 3 entries for 2 slots");
  scene = SphereScene();
  scene.slot_material = {1};
  ExpectRefused(scene, "slot_material[0]: material 1 of 1");
  scene.slot_material = {0, 0};
  ExpectRefused(scene, "slot_material: 2 entries for 1 slots");
  scene = SphereScene();
  scene.materials.clear();
  scene.slot_material.clear();
  ExpectRefused(scene, "no materials");

  scene = SphereScene();
  scene.materials[0].params.erase("sheen_roughness");
  ExpectRefused(scene, "materials[0]: no parameter 'sheen_roughness'");
  scene = SphereScene();
  scene.materials[0].params["base_color"] = {0.5, 0.5};
  ExpectRefused(scene, "materials[0].base_color: 2 values, not 3");
  scene.materials[0].params["base_color"] = {0.5, NAN, 0.5};
  ExpectRefused(scene, "materials[0].base_color: nan is not within [0, 1]");
  scene.materials[0].params["base_color"] = {0.5, 0.5, 0.5};
  scene.materials[0].params["roughness"] = {1.5};
  ExpectRefused(scene, "materials[0].roughness: 1.5 is not within [0, 1]");

  // A mesh whose arrays disagree (the server's meshes come checked by ParseMesh; this writer checks again).
  assets::TriangleMesh mesh = DrapeStand();
  scene = TwoSlotScene();
  scene.mesh = &mesh;
  mesh.triangle_material[5] = 2;
  ExpectRefused(scene, "mesh: triangle 5 names slot 2 of 2");
  mesh = DrapeStand();
  mesh.triangles[7][1] = uint32_t(mesh.positions.size());
  ExpectRefused(scene, "mesh: triangle 7 names vertex " + std::to_string(mesh.positions.size()));
  mesh = DrapeStand();
  mesh.normals.pop_back();
  ExpectRefused(scene, "normals for");
  mesh = DrapeStand();
  mesh.uvs[3][1] = INFINITY;
  ExpectRefused(scene, "mesh: uv of vertex 3 is not finite");
  mesh = DrapeStand();
  mesh.triangles.clear();
  mesh.triangle_material.clear();
  ExpectRefused(scene, "mesh: no triangles");
}

// ---- Blender ----

// Blender's import of our GLB, as tests/blender/import_gltf.py prints it.
TEST(GltfExport, BlenderImportsTheSheenAndTheVariants) {
  if (!fs::exists("/usr/bin/blender")) {
    GTEST_SKIP() << "blender is not installed: /usr/bin/blender is missing, so Blender's import of our glTF "
                    "(sheen as a Velvet BSDF, KHR_materials_variants) is not checked";
  }
  const GltfScene scene = ThreeColourwayScene();
  const std::string path = WriteTemp("blender.glb", Written(scene, true));
  std::string output;
  const int status = RunCommand("/usr/bin/blender -b --factory-startup --python-exit-code 1 --python '" +
                             std::string(BLENDER_IMPORT_SCRIPT) + "' -- '" + path + "'",
                         &output);
  ASSERT_EQ(status, 0) << Tail(output);
  const std::string marker = "LOOMLIGHT_IMPORT ";
  const size_t at = output.find(marker);
  ASSERT_NE(at, std::string::npos) << Tail(output);
  const std::string json = output.substr(at + marker.size(), output.find('\n', at) - at - marker.size());
  Struct report;
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(json, &report).ok()) << json;
  std::cout << "Blender " << Field(report, "blender").string_value() << " imported: " << json << "\n";

  std::map<std::string, Struct> blender_materials;
  for (const Value& m : Field(report, "materials").list_value().values()) {
    blender_materials[Field(m.struct_value(), "name").string_value()] = m.struct_value();
  }
  for (const GltfMaterial& given : scene.materials) {
    SCOPED_TRACE(given.name);
    ASSERT_EQ(blender_materials.count(given.name), 1u);
    const Struct& m = blender_materials[given.name];
    const auto& base = Field(m, "base_color").list_value().values();
    const auto& velvet = Field(m, "velvet_color").list_value().values();
    ASSERT_EQ(base.size(), 3);
    ASSERT_EQ(velvet.size(), 3);
    for (int c = 0; c < 3; ++c) {  // Blender holds them as float
      EXPECT_NEAR(base[c].number_value(), given.params.at("base_color")[c], 1e-6);
      EXPECT_NEAR(velvet[c].number_value(), given.params.at("sheen_color")[c], 1e-6);
    }
    EXPECT_EQ(Field(m, "metallic").number_value(), 0);
    EXPECT_NEAR(Field(m, "roughness").number_value(), given.params.at("roughness")[0], 1e-6);
    EXPECT_NEAR(Field(m, "velvet_sigma").number_value(), given.params.at("sheen_roughness")[0], 1e-6);
    EXPECT_TRUE(Field(m, "principled_reaches_output").bool_value());
    EXPECT_TRUE(Field(m, "velvet_reaches_output").bool_value());
  }

  const auto& variants = Field(report, "variants").list_value().values();
  ASSERT_EQ(size_t(variants.size()), scene.variants.size());
  for (int v = 0; v < variants.size(); ++v) {
    EXPECT_EQ(Field(variants[v].struct_value(), "index").number_value(), v);
    EXPECT_EQ(Field(variants[v].struct_value(), "name").string_value(), scene.variants[v].name);
  }
  const auto& meshes = Field(report, "meshes").list_value().values();
  ASSERT_EQ(meshes.size(), 1);
  const Struct& mesh = meshes[0].struct_value();
  EXPECT_EQ(Field(mesh, "polygons").number_value(), scene.mesh->triangles.size());
  // Blender gives each primitive of a mesh with variants a material slot of its own, in primitive order.
  std::map<std::pair<int, int>, std::string> material_of;  // (slot, variant) -> material name
  for (const Value& mapping : Field(mesh, "variant_mappings").list_value().values()) {
    const Struct& m = mapping.struct_value();
    for (const Value& v : Field(m, "variants").list_value().values()) {
      material_of[{int(Field(m, "slot").number_value()), int(v.number_value())}] = Field(m, "material").string_value();
    }
  }
  for (size_t v = 0; v < scene.variants.size(); ++v) {
    for (size_t slot = 0; slot < 2; ++slot) {
      EXPECT_EQ((material_of[{int(slot), int(v)}]), scene.materials[scene.variants[v].material_of_slot[slot]].name)
          << "variant " << v << " slot " << slot;
    }
  }
}

// ---- MaterialX ----

// ND_open_pbr_surface_surfaceshader's inputs and their types, as MaterialX declares them in
// libraries/bxdf/open_pbr_surface.mtlx (AcademySoftwareFoundation/MaterialX at 064a3d7, nodedef version 1.1).
const std::map<std::string, std::string>& OpenPbrNodedefInputs() {
  static const std::map<std::string, std::string> inputs = {
      {"base_weight", "float"},
      {"base_color", "color3"},
      {"base_diffuse_roughness", "float"},
      {"base_metalness", "float"},
      {"specular_weight", "float"},
      {"specular_color", "color3"},
      {"specular_roughness", "float"},
      {"specular_ior", "float"},
      {"specular_roughness_anisotropy", "float"},
      {"transmission_weight", "float"},
      {"transmission_color", "color3"},
      {"transmission_depth", "float"},
      {"transmission_scatter", "color3"},
      {"transmission_scatter_anisotropy", "float"},
      {"transmission_dispersion_scale", "float"},
      {"transmission_dispersion_abbe_number", "float"},
      {"subsurface_weight", "float"},
      {"subsurface_color", "color3"},
      {"subsurface_radius", "float"},
      {"subsurface_radius_scale", "color3"},
      {"subsurface_scatter_anisotropy", "float"},
      {"fuzz_weight", "float"},
      {"fuzz_color", "color3"},
      {"fuzz_roughness", "float"},
      {"coat_weight", "float"},
      {"coat_color", "color3"},
      {"coat_roughness", "float"},
      {"coat_roughness_anisotropy", "float"},
      {"coat_ior", "float"},
      {"coat_darkening", "float"},
      {"thin_film_weight", "float"},
      {"thin_film_thickness", "float"},
      {"thin_film_ior", "float"},
      {"emission_luminance", "float"},
      {"emission_color", "color3"},
      {"geometry_opacity", "float"},
      {"geometry_thin_walled", "boolean"},
      {"geometry_normal", "vector3"},
      {"geometry_coat_normal", "vector3"},
      {"geometry_tangent", "vector3"},
      {"geometry_coat_tangent", "vector3"},
  };
  return inputs;
}

models::ParamValues OpenPbr(std::array<double, 3> base, double roughness, double ior, double fuzz_weight,
                            std::array<double, 3> fuzz, double fuzz_roughness) {
  return {{"base_color", {base[0], base[1], base[2]}},
          {"specular_roughness", {roughness}},
          {"specular_ior", {ior}},
          {"fuzz_weight", {fuzz_weight}},
          {"fuzz_color", {fuzz[0], fuzz[1], fuzz[2]}},
          {"fuzz_roughness", {fuzz_roughness}}};
}

std::vector<MtlxMaterial> TwoOpenPbrMaterials() {
  return {{"silk", OpenPbr({0.1, 1.0 / 3, 0.123456789012345}, 0.3, 1.5, 1, {0.9, 0.8, 0.7}, 0.45)},
          {"wool", OpenPbr({1e-7, 0.5, 0.999999999}, 0.87654321, 1.33, 0.25, {0, 1, 0.2}, 2.0 / 3)}};
}

std::vector<double> ParseNumbers(const std::string& text) {
  std::vector<double> out;
  std::stringstream in(text);
  std::string piece;
  while (std::getline(in, piece, ',')) out.push_back(std::strtod(piece.c_str(), nullptr));
  return out;
}

bool ValidMaterialXName(const std::string& name) {
  if (name.empty() || (name[0] >= '0' && name[0] <= '9')) return false;
  for (char c : name) {
    if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_')) return false;
  }
  return true;
}

// Parses the document and checks its structure; the shaders by the name of the material that references them.
std::map<std::string, pugi::xml_node> CheckDocument(const pugi::xml_document& doc, size_t materials) {
  std::map<std::string, pugi::xml_node> shader_of;
  const pugi::xml_node root = doc.child("materialx");
  EXPECT_STREQ(root.attribute("version").value(), "1.39");
  EXPECT_STREQ(root.attribute("colorspace").value(), "lin_rec709");
  std::set<std::string> names;
  for (pugi::xml_node node : root.children()) {
    EXPECT_TRUE(names.insert(node.attribute("name").value()).second) << "name used twice: " << node.attribute("name").value();
    EXPECT_TRUE(ValidMaterialXName(node.attribute("name").value())) << node.attribute("name").value();
  }
  for (pugi::xml_node material : root.children("surfacematerial")) {
    EXPECT_STREQ(material.attribute("type").value(), "material");
    // ND_surfacematerial (libraries/stdlib/stdlib_defs.mtlx): input surfaceshader of type surfaceshader.
    const pugi::xml_node input = material.child("input");
    EXPECT_STREQ(input.attribute("name").value(), "surfaceshader");
    EXPECT_STREQ(input.attribute("type").value(), "surfaceshader");
    const pugi::xml_node shader = root.find_child_by_attribute("open_pbr_surface", "name", input.attribute("nodename").value());
    EXPECT_TRUE(shader) << "no open_pbr_surface named " << input.attribute("nodename").value();
    EXPECT_STREQ(shader.attribute("type").value(), "surfaceshader");
    shader_of[material.attribute("name").value()] = shader;
  }
  EXPECT_EQ(shader_of.size(), materials);
  EXPECT_EQ(std::distance(root.children("open_pbr_surface").begin(), root.children("open_pbr_surface").end()),
            ptrdiff_t(materials));
  return shader_of;
}

TEST(MtlxExport, InputsAreTheOpenPbrNodedefsWithItsTypesAndValuesRoundTrip) {
  const std::vector<MtlxMaterial> materials = TwoOpenPbrMaterials();
  std::string text;
  ASSERT_EQ(WriteMtlx(materials, &text), "");
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(text.c_str())) << text;
  const auto shader_of = CheckDocument(doc, materials.size());
  // The fixed inputs: a dielectric base (OpenPBR's metalness 0) under a white specular of weight 1.
  const std::map<std::string, std::vector<double>> fixed = {{"base_weight", {1}},
                                                            {"base_diffuse_roughness", {0}},
                                                            {"base_metalness", {0}},
                                                            {"specular_weight", {1}},
                                                            {"specular_color", {1, 1, 1}}};
  for (const MtlxMaterial& material : materials) {
    SCOPED_TRACE(material.name);
    ASSERT_EQ(shader_of.count(material.name), 1u);
    std::set<std::string> written;
    for (pugi::xml_node input : shader_of.at(material.name).children("input")) {
      const std::string name = input.attribute("name").value();
      const auto declared = OpenPbrNodedefInputs().find(name);
      ASSERT_NE(declared, OpenPbrNodedefInputs().end()) << name << " is not an input of ND_open_pbr_surface_surfaceshader";
      EXPECT_EQ(input.attribute("type").value(), declared->second) << name;
      EXPECT_TRUE(written.insert(name).second) << name << " twice";
      const std::vector<double> values = ParseNumbers(input.attribute("value").value());
      EXPECT_EQ(values.size(), declared->second == "color3" ? 3u : 1u) << name;
      const auto param = material.params.find(name);
      if (param != material.params.end()) {
        EXPECT_EQ(values, param->second) << name << " = " << input.attribute("value").value();  // exactly
      } else {
        ASSERT_EQ(fixed.count(name), 1u) << name;
        EXPECT_EQ(values, fixed.at(name)) << name;
      }
    }
    for (const auto& [param, values] : material.params) EXPECT_EQ(written.count(param), 1u) << param;
    for (const auto& [name, values] : fixed) EXPECT_EQ(written.count(name), 1u) << name;
  }
}

TEST(MtlxExport, NamesAreValidAndUniqueEvenForHostileNames) {
  std::vector<MtlxMaterial> materials;
  for (const std::string& name : HostileNames()) materials.push_back({name, TwoOpenPbrMaterials()[0].params});
  // Names that collide once made valid, or with another material's shader.
  for (const char* name : {"a b", "a_b", "a-b", "a_b_shader", "a_b_2", "material", "_"}) {
    materials.push_back({name, TwoOpenPbrMaterials()[1].params});
  }
  std::string text;
  ASSERT_EQ(WriteMtlx(materials, &text), "");
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(text.c_str())) << text;
  CheckDocument(doc, materials.size());  // every name valid and unique, every material with its shader
  // In order, each material's own values (a material is not lost or swapped for another of a similar name).
  const pugi::xml_node root = doc.child("materialx");
  size_t i = 0;
  for (pugi::xml_node material : root.children("surfacematerial")) {
    ASSERT_LT(i, materials.size());
    EXPECT_LE(std::strlen(material.attribute("name").value()), 80u);  // bounded, even for the 10 kB name
    const pugi::xml_node shader =
        root.find_child_by_attribute("open_pbr_surface", "name", material.child("input").attribute("nodename").value());
    const pugi::xml_node ior = shader.find_child_by_attribute("input", "name", "specular_ior");
    EXPECT_EQ(ParseNumbers(ior.attribute("value").value()), materials[i].params.at("specular_ior")) << i;
    ++i;
  }
  EXPECT_EQ(i, materials.size());
  EXPECT_NE(text.find("name=\"Linen\""), std::string::npos);  // a plain name stays as it is
  EXPECT_LE(text.size(), materials.size() * 2000);
}

TEST(MtlxExport, BadInputGivesAnErrorNamingIt) {
  const auto refused = [](std::vector<MtlxMaterial> materials, const std::string& names) {
    std::string out = "untouched";
    const std::string error = WriteMtlx(materials, &out);
    EXPECT_NE(error.find(names), std::string::npos) << "error: '" << error << "', expected it to name " << names;
    EXPECT_EQ(out, "untouched");
  };
  refused({}, "no materials");
  std::vector<MtlxMaterial> materials = TwoOpenPbrMaterials();
  materials[1].params.erase("fuzz_roughness");
  refused(materials, "materials[1]: no parameter 'fuzz_roughness'");
  materials = TwoOpenPbrMaterials();
  materials[0].params["fuzz_color"] = {1, 1};
  refused(materials, "materials[0].fuzz_color: 2 values, not 3");
  materials = TwoOpenPbrMaterials();
  materials[1].params["specular_ior"] = {INFINITY};
  refused(materials, "materials[1].specular_ior: inf is not finite");
}

}  // namespace
}  // namespace loomlight::exporting
