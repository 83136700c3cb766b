// Mesh files (server/assets/mesh_file.h): glTF written with tinygltf's own writer (JSON with embedded buffers, and
// GLB) and OBJ text written here, parsed and checked against geometry worked out by hand; every hostile or broken
// file refused with a message naming what is wrong, and nothing a file names ever read.
#include "server/assets/mesh_file.h"

#include <gtest/gtest.h>
#include <tiny_gltf.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>

#include <unistd.h>

namespace loomlight::assets {
namespace {

using Vec3 = std::array<float, 3>;
using Vec2 = std::array<float, 2>;

struct PrimitiveData {
  std::vector<Vec3> positions, normals;
  std::vector<std::array<float, 4>> tangents;
  std::vector<Vec2> uvs;  // glTF's convention: v down
  std::vector<uint32_t> indices;
  int mode = TINYGLTF_MODE_TRIANGLES;
  int material = -1;
};

// Appends `bytes` to buffer 0 with a buffer view and an accessor over them; the accessor's index.
int AddAccessor(tinygltf::Model* model, const void* data, size_t bytes, size_t count, int component_type,
                int type) {
  auto& buffer = model->buffers[0].data;
  while (buffer.size() % 4) buffer.push_back(0);
  tinygltf::BufferView view;
  view.buffer = 0;
  view.byteOffset = buffer.size();
  view.byteLength = bytes;
  const auto* p = static_cast<const unsigned char*>(data);
  buffer.insert(buffer.end(), p, p + bytes);
  model->bufferViews.push_back(view);
  tinygltf::Accessor accessor;
  accessor.bufferView = int(model->bufferViews.size()) - 1;
  accessor.componentType = component_type;
  accessor.type = type;
  accessor.count = count;
  model->accessors.push_back(accessor);
  return int(model->accessors.size()) - 1;
}

int AddMesh(tinygltf::Model* model, const std::vector<PrimitiveData>& primitives) {
  tinygltf::Mesh mesh;
  for (const PrimitiveData& data : primitives) {
    tinygltf::Primitive primitive;
    primitive.mode = data.mode;
    primitive.material = data.material;
    primitive.attributes["POSITION"] =
        AddAccessor(model, data.positions.data(), data.positions.size() * 12, data.positions.size(),
                    TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3);
    if (!data.normals.empty()) {
      primitive.attributes["NORMAL"] = AddAccessor(model, data.normals.data(), data.normals.size() * 12,
                                                   data.normals.size(), TINYGLTF_COMPONENT_TYPE_FLOAT,
                                                   TINYGLTF_TYPE_VEC3);
    }
    if (!data.tangents.empty()) {
      primitive.attributes["TANGENT"] = AddAccessor(model, data.tangents.data(), data.tangents.size() * 16,
                                                    data.tangents.size(), TINYGLTF_COMPONENT_TYPE_FLOAT,
                                                    TINYGLTF_TYPE_VEC4);
    }
    if (!data.uvs.empty()) {
      primitive.attributes["TEXCOORD_0"] = AddAccessor(model, data.uvs.data(), data.uvs.size() * 8, data.uvs.size(),
                                                       TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC2);
    }
    if (!data.indices.empty()) {
      primitive.indices = AddAccessor(model, data.indices.data(), data.indices.size() * 4, data.indices.size(),
                                      TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT, TINYGLTF_TYPE_SCALAR);
    }
    mesh.primitives.push_back(primitive);
  }
  model->meshes.push_back(mesh);
  return int(model->meshes.size()) - 1;
}

// One mesh of `primitives` under one node, in the default scene.
tinygltf::Model OneMeshModel(const std::vector<PrimitiveData>& primitives) {
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.buffers.resize(1);
  tinygltf::Node node;
  node.mesh = AddMesh(&model, primitives);
  model.nodes.push_back(node);
  model.scenes.resize(1);
  model.scenes[0].nodes = {0};
  model.defaultScene = 0;
  return model;
}

std::string Write(const tinygltf::Model& model, bool binary) {
  tinygltf::TinyGLTF writer;
  std::ostringstream out;
  EXPECT_TRUE(writer.WriteGltfSceneToStream(&model, out, false, binary));
  return out.str();
}

// A 2 x 3 rectangle in z = 0 facing +z, its UVs the unit square (glTF's v down: (0, 0) at the top left corner
// (0, 3, 0)).
PrimitiveData Rectangle() {
  PrimitiveData quad;
  quad.positions = {{0, 0, 0}, {2, 0, 0}, {2, 3, 0}, {0, 3, 0}};
  quad.uvs = {{0, 1}, {1, 1}, {1, 0}, {0, 0}};
  quad.indices = {0, 1, 2, 0, 2, 3};
  return quad;
}

std::string Parse(const std::string& bytes, TriangleMesh* mesh, MeshLimits limits = {}, uint64_t* dropped = nullptr,
                  v1::MeshFormat format = v1::MESH_FORMAT_AUTO, const std::function<bool()>& stop = {}) {
  return ParseMesh(bytes, format, limits, mesh, dropped, stop);
}

std::string ParseError(const std::string& bytes, MeshLimits limits = {},
                       v1::MeshFormat format = v1::MESH_FORMAT_AUTO) {
  TriangleMesh mesh;
  const std::string error = Parse(bytes, &mesh, limits, nullptr, format);
  EXPECT_FALSE(error.empty()) << "parsed a bad file";
  EXPECT_LT(error.size(), 1024u) << error;
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  return error;
}

::testing::AssertionResult Contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << text << "\" does not contain \"" << part << "\"";
}

// A file of this test process's own under GoogleTest's temporary directory.
std::string TempPath(const std::string& name) {
  return ::testing::TempDir() + "mesh_file_test." + std::to_string(getpid()) + "." + name;
}

void ExpectNear3(const Vec3& got, const Vec3& expected, double tolerance, const std::string& what) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], expected[c], tolerance) << what << " component " << c;
}

// The index of the vertex at `position` (the parser may order vertices its own way).
size_t VertexAt(const TriangleMesh& mesh, const Vec3& position) {
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    if (std::fabs(mesh.positions[i][0] - position[0]) < 1e-5 && std::fabs(mesh.positions[i][1] - position[1]) < 1e-5 &&
        std::fabs(mesh.positions[i][2] - position[2]) < 1e-5) {
      return i;
    }
  }
  ADD_FAILURE() << "no vertex at " << position[0] << " " << position[1] << " " << position[2];
  return 0;
}

TEST(MeshFile, DetectsFormatsFromTheirBytes) {
  EXPECT_EQ(DetectMeshFormat("glTF\x02", v1::MESH_FORMAT_AUTO), v1::MESH_FORMAT_GLB);
  EXPECT_EQ(DetectMeshFormat("  \n{\"asset\"", v1::MESH_FORMAT_AUTO), v1::MESH_FORMAT_GLTF);
  EXPECT_EQ(DetectMeshFormat("v 0 0 0\n", v1::MESH_FORMAT_AUTO), v1::MESH_FORMAT_OBJ);
  EXPECT_EQ(DetectMeshFormat("glTF", v1::MESH_FORMAT_OBJ), v1::MESH_FORMAT_OBJ);
}

TEST(MeshFile, RectangleInGlbAndGltfHasItsAreaBoundsAndUvs) {
  for (bool binary : {true, false}) {
    SCOPED_TRACE(binary ? "GLB" : "glTF JSON");
    const std::string bytes = Write(OneMeshModel({Rectangle()}), binary);
    EXPECT_EQ(DetectMeshFormat(bytes, v1::MESH_FORMAT_AUTO), binary ? v1::MESH_FORMAT_GLB : v1::MESH_FORMAT_GLTF);
    TriangleMesh mesh;
    uint64_t dropped = 99;
    ASSERT_EQ(Parse(bytes, &mesh, {}, &dropped), "");
    EXPECT_EQ(dropped, 0u);
    EXPECT_EQ(mesh.triangles.size(), 2u);
    EXPECT_EQ(mesh.positions.size(), 4u);
    EXPECT_DOUBLE_EQ(mesh.surface_area, 6);
    EXPECT_EQ(mesh.bounds_min, (std::array<double, 3>{0, 0, 0}));
    EXPECT_EQ(mesh.bounds_max, (std::array<double, 3>{2, 3, 0}));
    EXPECT_FALSE(mesh.file_normals);
    EXPECT_TRUE(mesh.file_uvs);
    EXPECT_FALSE(mesh.file_tangents);
    // TriangleMesh's v runs up: the bottom left corner is (0, 0), the top right (1, 1).
    EXPECT_EQ(mesh.uvs[VertexAt(mesh, {0, 0, 0})], (Vec2{0, 0}));
    EXPECT_EQ(mesh.uvs[VertexAt(mesh, {2, 3, 0})], (Vec2{1, 1}));
    EXPECT_EQ(mesh.uvs[VertexAt(mesh, {0, 3, 0})], (Vec2{0, 1}));
    // 6 square units of surface over 1 square UV unit.
    EXPECT_NEAR(mesh.metres_per_uv, std::sqrt(6.0), 1e-12);
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      ExpectNear3(mesh.normals[v], {0, 0, 1}, 1e-6, "normal");
      // u grows along +x, v along +y: tangent +x, bitangent +y = w (+z x +x), so w = +1.
      EXPECT_EQ(mesh.tangents[v], (std::array<float, 4>{1, 0, 0, 1}));
    }
    EXPECT_EQ(mesh.material_names, std::vector<std::string>{""});
    EXPECT_EQ(mesh.triangle_material, (std::vector<uint32_t>{0, 0}));

    v1::MeshInfo info;
    DescribeMesh(mesh, &info);
    EXPECT_EQ(info.triangles(), 2u);
    EXPECT_EQ(info.vertices(), 4u);
    EXPECT_TRUE(info.has_uvs());
    EXPECT_FALSE(info.has_normals());
    ASSERT_EQ(info.bounds_max_size(), 3);
    EXPECT_EQ(info.bounds_max(1), 3);
    EXPECT_DOUBLE_EQ(info.surface_area(), 6);
    EXPECT_NEAR(info.metres_per_uv(), std::sqrt(6.0), 1e-12);
    ASSERT_EQ(info.materials_size(), 1);
    EXPECT_GT(mesh.memory_bytes(), 4 * (12 + 12 + 8 + 16) + 2 * 12u);
  }
}

TEST(MeshFile, ObjCubeHasOutwardNormalsAndItsArea) {
  const std::string cube =
      "# unit cube, corners at 0 and 1\n"
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
      "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";
  TriangleMesh mesh;
  ASSERT_EQ(Parse(cube, &mesh), "");
  EXPECT_EQ(mesh.triangles.size(), 12u);
  EXPECT_EQ(mesh.positions.size(), 8u);
  EXPECT_DOUBLE_EQ(mesh.surface_area, 6);
  EXPECT_EQ(mesh.bounds_min, (std::array<double, 3>{0, 0, 0}));
  EXPECT_EQ(mesh.bounds_max, (std::array<double, 3>{1, 1, 1}));
  EXPECT_TRUE(mesh.uvs.empty());
  EXPECT_TRUE(mesh.tangents.empty());
  EXPECT_EQ(mesh.metres_per_uv, 0);
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    const Vec3& p = mesh.positions[v];
    const Vec3& n = mesh.normals[v];
    EXPECT_NEAR(std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), 1, 1e-6);
    // Every corner's normal points away from the centre, into the corner's octant.
    for (int c = 0; c < 3; ++c) EXPECT_GT(n[c] * (p[c] - 0.5f), 0) << "vertex " << v << " axis " << c;
  }
}

TEST(MeshFile, NodeTransformsMoveTheMeshAndItsNormals) {
  // A parent translated by (10, 0, 0); its child scaled by (2, 3, 5), rotated 90 degrees about +x, translated by
  // (1, 2, 3). The rectangle's corner (x, y, 0) goes to (2x, 3y, 0), then (2x, 0, 3y), then (2x + 11, 2, 3y + 3).
  // The same child once more as a matrix (column-major): columns (2, 0, 0), (0, 0, 3), (0, -5, 0), (1, 2, 3).
  for (bool matrix : {false, true}) {
    SCOPED_TRACE(matrix ? "matrix" : "translation, rotation, scale");
    tinygltf::Model model = OneMeshModel({Rectangle()});
    if (matrix) {
      model.nodes[0].matrix = {2, 0, 0, 0, 0, 0, 3, 0, 0, -5, 0, 0, 1, 2, 3, 1};
    } else {
      model.nodes[0].scale = {2, 3, 5};
      model.nodes[0].rotation = {std::sin(M_PI / 4), 0, 0, std::cos(M_PI / 4)};
      model.nodes[0].translation = {1, 2, 3};
    }
    tinygltf::Node parent;
    parent.translation = {10, 0, 0};
    parent.children = {0};
    model.nodes.push_back(parent);
    model.scenes[0].nodes = {1};
    TriangleMesh mesh;
    ASSERT_EQ(Parse(Write(model, true), &mesh), "");
    EXPECT_NEAR(mesh.surface_area, 6 * 2 * 3, 1e-5);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(mesh.bounds_min[c], (std::array<double, 3>{11, 2, 3})[c], 1e-5);
      EXPECT_NEAR(mesh.bounds_max[c], (std::array<double, 3>{15, 2, 12})[c], 1e-5);
    }
    // The face normal +z turns with the rotation to -y (y' = -z).
    for (const Vec3& n : mesh.normals) ExpectNear3(n, {0, -1, 0}, 1e-6, "normal");
    // u along +x still (scaled), v along +y became +z.
    for (const auto& t : mesh.tangents) {
      ExpectNear3({t[0], t[1], t[2]}, {1, 0, 0}, 1e-6, "tangent");
      EXPECT_EQ(t[3], 1);
    }
    EXPECT_NEAR(mesh.metres_per_uv, std::sqrt(36.0), 1e-5);
  }
}

TEST(MeshFile, FileNormalsTransformByTheInverseTranspose) {
  // A tilted triangle with its true normal given; after a non-uniform scale the normal must still be
  // perpendicular to the scaled triangle (the transform itself would tilt it off).
  PrimitiveData tilted;
  tilted.positions = {{0, 0, 0}, {1, 0, 1}, {0, 1, 0}};
  const float s = float(1 / std::sqrt(2.0));
  tilted.normals = {{-s, 0, s}, {-s, 0, s}, {-s, 0, s}};
  tilted.indices = {0, 1, 2};
  tinygltf::Model model = OneMeshModel({tilted});
  model.nodes[0].scale = {1, 1, 4};
  TriangleMesh mesh;
  ASSERT_EQ(Parse(Write(model, false), &mesh), "");
  EXPECT_TRUE(mesh.file_normals);
  // Scaled: (0,0,0), (1,0,4), (0,1,0); their normal is (1,0,4) x (0,1,0) = (-4, 0, 1), normalised.
  const float length = std::sqrt(17.0f);
  for (const Vec3& n : mesh.normals) ExpectNear3(n, {-4 / length, 0, 1 / length}, 1e-6, "normal");
}

TEST(MeshFile, MirroringNodeKeepsNormalsOutsideAndFlipsTangentHandedness) {
  tinygltf::Model model = OneMeshModel({Rectangle()});
  model.nodes[0].scale = {-1, 1, 1};
  TriangleMesh mesh;
  ASSERT_EQ(Parse(Write(model, true), &mesh), "");
  EXPECT_DOUBLE_EQ(mesh.surface_area, 6);
  // Mirrored in x the rectangle still faces +z, its triangles wound counter-clockwise seen from +z.
  for (const Vec3& n : mesh.normals) ExpectNear3(n, {0, 0, 1}, 1e-6, "normal");
  for (const auto& tri : mesh.triangles) {
    const Vec3 &a = mesh.positions[tri[0]], &b = mesh.positions[tri[1]], &c = mesh.positions[tri[2]];
    EXPECT_GT((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]), 0);
  }
  // u now grows along -x; v along +y = w (+z x -x) = w (0, -1, 0): w = -1.
  for (const auto& t : mesh.tangents) EXPECT_EQ(t, (std::array<float, 4>{-1, 0, 0, -1}));
}

TEST(MeshFile, TangentsFollowUvsRotatedANinetyDegrees) {
  // The unit square in z = 0 with its UVs turned: u grows along +y and v along -x. The tangent (along +u) is +y;
  // the bitangent (along +v) is -x = w (+z x +y) = w (-1, 0, 0): w = +1. Mirrored UVs (v along +x): w = -1.
  for (bool mirrored : {false, true}) {
    SCOPED_TRACE(mirrored ? "mirrored" : "rotated");
    std::string obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";
    obj += mirrored ? "vt 0 0\nvt 0 1\nvt 1 1\nvt 1 0\n" : "vt 0 1\nvt 0 0\nvt 1 0\nvt 1 1\n";
    obj += "f 1/1 2/2 3/3 4/4\n";
    TriangleMesh mesh;
    ASSERT_EQ(Parse(obj, &mesh), "");
    ASSERT_EQ(mesh.tangents.size(), 4u);
    for (const auto& t : mesh.tangents) {
      ExpectNear3({t[0], t[1], t[2]}, {0, 1, 0}, 1e-6, "tangent");
      EXPECT_EQ(t[3], mirrored ? -1 : 1);
    }
  }
}

TEST(MeshFile, GltfAndObjOfTheSameMeshGiveTheSameUvsAndTangents) {
  // One mesh as an exporter writes it both ways: OBJ with v up, glTF with v' = 1 - v.
  const std::vector<Vec3> positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0.5f}, {0, 1, 0.25f}};
  const std::vector<Vec2> uvs = {{0.1f, 0.2f}, {0.7f, 0.25f}, {0.75f, 0.9f}, {0.125f, 0.75f}};
  std::ostringstream obj;
  for (const Vec3& p : positions) obj << "v " << p[0] << " " << p[1] << " " << p[2] << "\n";
  for (const Vec2& uv : uvs) obj << "vt " << uv[0] << " " << uv[1] << "\n";
  obj << "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
  PrimitiveData gltf;
  gltf.positions = positions;
  for (const Vec2& uv : uvs) gltf.uvs.push_back({uv[0], 1 - uv[1]});
  gltf.indices = {0, 1, 2, 0, 2, 3};
  TriangleMesh from_obj, from_gltf;
  ASSERT_EQ(Parse(obj.str(), &from_obj), "");
  ASSERT_EQ(Parse(Write(OneMeshModel({gltf}), true), &from_gltf), "");
  ASSERT_EQ(from_obj.positions.size(), 4u);
  ASSERT_EQ(from_gltf.positions.size(), 4u);
  for (size_t i = 0; i < positions.size(); ++i) {
    const size_t a = VertexAt(from_obj, positions[i]), b = VertexAt(from_gltf, positions[i]);
    EXPECT_NEAR(from_obj.uvs[a][0], uvs[i][0], 1e-6);
    EXPECT_NEAR(from_obj.uvs[a][1], uvs[i][1], 1e-6);
    EXPECT_NEAR(from_gltf.uvs[b][0], uvs[i][0], 1e-6);
    EXPECT_NEAR(from_gltf.uvs[b][1], uvs[i][1], 1e-6);
    for (int c = 0; c < 4; ++c) EXPECT_NEAR(from_obj.tangents[a][c], from_gltf.tangents[b][c], 1e-5);
  }
  EXPECT_NEAR(from_obj.metres_per_uv, from_gltf.metres_per_uv, 1e-6);
}

TEST(MeshFile, StripsAndFansBecomeTriangles) {
  // The unit square as a strip (0,0) (1,0) (0,1) (1,1) and as a fan around (0,0): two triangles, both facing +z.
  PrimitiveData strip, fan;
  strip.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  strip.mode = TINYGLTF_MODE_TRIANGLE_STRIP;
  fan.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  fan.mode = TINYGLTF_MODE_TRIANGLE_FAN;
  PrimitiveData line = strip;
  line.mode = TINYGLTF_MODE_LINE_STRIP;  // no surface: skipped
  for (const PrimitiveData& primitive : {strip, fan}) {
    TriangleMesh mesh;
    ASSERT_EQ(Parse(Write(OneMeshModel({primitive, line}), true), &mesh), "");
    EXPECT_EQ(mesh.triangles.size(), 2u);
    EXPECT_DOUBLE_EQ(mesh.surface_area, 1);
    for (const Vec3& n : mesh.normals) ExpectNear3(n, {0, 0, 1}, 1e-6, "normal");
  }
  EXPECT_TRUE(Contains(ParseError(Write(OneMeshModel({line}), true)), "no triangles"));
}

TEST(MeshFile, ZeroNormalsAreFixedAndDegenerateTrianglesDropped) {
  PrimitiveData quad = Rectangle();
  quad.normals = {{0, 0, 1}, {0, 0, 0}, {0, 0, 1}, {0, 0, 1}};
  quad.indices.insert(quad.indices.end(), {0, 1, 1, 0, 2, 0});  // two zero-area triangles
  TriangleMesh mesh;
  uint64_t dropped = 0;
  ASSERT_EQ(Parse(Write(OneMeshModel({quad}), false), &mesh, {}, &dropped), "");
  EXPECT_EQ(dropped, 2u);
  EXPECT_EQ(mesh.triangles.size(), 2u);
  EXPECT_FALSE(mesh.file_normals);
  for (const Vec3& n : mesh.normals) ExpectNear3(n, {0, 0, 1}, 1e-6, "normal");
}

TEST(MeshFile, MaterialNamesComeInOrderOfFirstUse) {
  const std::string obj =
      "mtllib /etc/hostname\n"
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\n"
      "f 1 2 3\n"
      "usemtl collar\nf 1 3 4\n"
      "usemtl unused\n"
      "usemtl body\nf 1 2 5\n"
      "usemtl collar\nf 2 3 5\n"
      "usemtl never_used_at_the_end\n";
  TriangleMesh mesh;
  ASSERT_EQ(Parse(obj, &mesh), "");
  EXPECT_EQ(mesh.material_names, (std::vector<std::string>{"", "collar", "body"}));
  EXPECT_EQ(mesh.triangle_material, (std::vector<uint32_t>{0, 1, 2, 1}));

  PrimitiveData a = Rectangle(), b = Rectangle(), c = Rectangle();
  a.material = 1;
  b.material = 0;
  c.material = 1;
  tinygltf::Model model = OneMeshModel({a, b, c});
  model.materials.resize(2);
  model.materials[1].name = "lining";
  ASSERT_EQ(Parse(Write(model, true), &mesh), "");
  EXPECT_EQ(mesh.material_names, (std::vector<std::string>{"lining", "materials[0]"}));
  EXPECT_EQ(mesh.triangle_material, (std::vector<uint32_t>{0, 0, 1, 1, 0, 0}));
}

TEST(MeshFile, ObjVerticesAreUniquePerPositionUvNormalTriple) {
  // Two triangles sharing the edge 1-3: the same positions, but vertex 3 with two UVs makes one more vertex.
  const std::string obj =
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
      "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
      "vn 0 0 2\n"
      "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/5/1 4/4/1\n";
  TriangleMesh mesh;
  ASSERT_EQ(Parse(obj, &mesh), "");
  EXPECT_EQ(mesh.positions.size(), 5u);
  EXPECT_TRUE(mesh.file_normals);
  for (const Vec3& n : mesh.normals) EXPECT_EQ(n, (Vec3{0, 0, 1}));
}

TEST(MeshFile, InstancesAreCountedBeforeTheyAreExpanded) {
  // The rectangle (2 triangles) under 3000 nodes: 6000 triangles.
  tinygltf::Model model = OneMeshModel({Rectangle()});
  model.scenes[0].nodes.clear();
  model.nodes.resize(3000, model.nodes[0]);
  for (int i = 0; i < 3000; ++i) model.scenes[0].nodes.push_back(i);
  const std::string bytes = Write(model, true);
  MeshLimits limits;
  limits.max_triangles = 5999;
  limits.max_vertices = 3;  // would fail first if instances were expanded before the count
  EXPECT_TRUE(Contains(ParseError(bytes, limits), "triangles: 6000, more than the limit of 5999"));
  limits.max_triangles = 6000;
  limits.max_vertices = 12000;
  TriangleMesh mesh;
  ASSERT_EQ(Parse(bytes, &mesh, limits), "");
  EXPECT_EQ(mesh.triangles.size(), 6000u);
  EXPECT_DOUBLE_EQ(mesh.surface_area, 6 * 3000);
  limits.max_vertices = 11999;
  EXPECT_TRUE(Contains(ParseError(bytes, limits), "vertices: at least 12000, more than the limit of 11999"));
}

TEST(MeshFile, LimitsNameTheirCounts) {
  const std::string bytes = Write(OneMeshModel({Rectangle()}), true);
  MeshLimits limits;
  limits.max_bytes = bytes.size() - 1;
  EXPECT_TRUE(Contains(ParseError(bytes, limits),
              "file bytes: " + std::to_string(bytes.size()) + ", more than the limit of " +
                        std::to_string(bytes.size() - 1)));
  limits = {};
  limits.max_triangles = 1;
  EXPECT_TRUE(Contains(ParseError(bytes, limits), "triangles: 2, more than the limit of 1"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\n", limits),
              "triangles: 2, more than the limit of 1"));
  limits = {};
  limits.max_materials = 1;
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 1 2 3\n", limits),
              "materials: more than the limit of 1"));
  PrimitiveData quad = Rectangle();
  tinygltf::Model model = OneMeshModel({quad});
  for (int set = 1; set <= 2; ++set) {
    model.meshes[0].primitives[0].attributes["TEXCOORD_" + std::to_string(set)] =
        model.meshes[0].primitives[0].attributes["TEXCOORD_0"];
  }
  limits = {};
  limits.max_uv_sets = 2;
  EXPECT_TRUE(Contains(ParseError(Write(model, true), limits), "UV sets: 3, more than the limit of 2"));
}

TEST(MeshFile, ExternalBufferIsRefusedNeverRead) {
  // The buffer's file exists and holds exactly the bytes the accessors want: only a refusal explains a failure.
  tinygltf::Model model = OneMeshModel({Rectangle()});
  const std::string path = TempPath("buffer.bin");
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(model.buffers[0].data.data()), std::streamsize(model.buffers[0].data.size()));
  std::string json = Write(model, false);
  const size_t data_uri = json.find("data:application/octet-stream;base64,");
  ASSERT_NE(data_uri, std::string::npos);
  json.replace(data_uri, json.find('"', data_uri) - data_uri, path);
  std::string error = ParseError(json);
  EXPECT_TRUE(Contains(error, "buffers[0].uri: external files are refused"));
  EXPECT_TRUE(Contains(error, path));
  std::remove(path.c_str());

  // A second buffer, naming a file in /etc.
  model.buffers.resize(2);
  model.buffers[1].data.assign(4, 0);
  json = Write(model, false);
  const size_t second = json.find("data:application/octet-stream;base64,", json.find("data:") + 1);
  ASSERT_NE(second, std::string::npos);
  json.replace(second, json.find('"', second) - second, "/etc/hostname");
  EXPECT_TRUE(Contains(ParseError(json), "buffers[1].uri: external files are refused ('/etc/hostname')"));
}

TEST(MeshFile, ExternalImageIsRefused) {
  std::string json = Write(OneMeshModel({Rectangle()}), false);
  json.resize(json.find_last_of('}'));
  json += ",\"images\":[{\"uri\":\"/etc/passwd\"}]}";
  EXPECT_TRUE(Contains(ParseError(json), "images[0].uri: external files are refused ('/etc/passwd')"));
}

TEST(MeshFile, BadValuesAreRefusedByName) {
  PrimitiveData nan = Rectangle();
  nan.positions[2][1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(Contains(ParseError(Write(OneMeshModel({nan}), true)),
              "meshes[0].primitives[0].POSITION[2] is not finite"));
  PrimitiveData infinite_uv = Rectangle();
  infinite_uv.uvs[1][0] = std::numeric_limits<float>::infinity();
  EXPECT_TRUE(Contains(ParseError(Write(OneMeshModel({infinite_uv}), true)), "TEXCOORD_0[1] is not finite"));
  // tinyobjloader would read an overflowing number as infinity and "nan" or "1,5" as 0 (a vertex silently
  // moved): every OBJ value is checked as a finite number first, by its line.
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1e400 0 0\nv 0 1 0\nf 1 2 3\n"), "line 2: v value '1e400' is not a finite number"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"), "line 2: v value 'nan' is not a finite number"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1,5 0\nf 1 2 3\n"), "line 3: v value '1,5' is not a finite number"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1e39\nf 1//1 2//1 3//1\n"), "vn 1 is not finite"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt inf 0\nf 1/1 2/1 3/1\n"), "line 4: vt value 'inf'"));
  TriangleMesh signed_mesh;  // what strtod reads, this reads
  EXPECT_EQ(Parse("v +1 0 0\nv 2. 0 0\nv .5 1 0\nf 1 2 3\n", &signed_mesh, {}, nullptr, v1::MESH_FORMAT_AUTO), "");

  PrimitiveData out_of_range = Rectangle();
  out_of_range.indices[4] = 7;
  EXPECT_TRUE(Contains(ParseError(Write(OneMeshModel({out_of_range}), true)),
              "meshes[0].primitives[0]: index 7 (indices[4]) is out of range: 4 vertices"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"), "vertex index 9 is out of range"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n"), "line 4: '0' is not a vertex reference"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n"),
              "texture coordinate index 2 is out of range"));

  PrimitiveData collinear;
  collinear.positions = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {5, 5, 5}};
  collinear.indices = {0, 1, 2, 1, 2, 3, 3, 3, 0};
  EXPECT_TRUE(Contains(ParseError(Write(OneMeshModel({collinear}), false)),
              "every triangle is degenerate (zero area): 3 of them"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nf 1 2 2\n"), "every triangle is degenerate"));
}

TEST(MeshFile, SparseAccessorsAndRequiredExtensionsAreRefused) {
  std::string json = Write(OneMeshModel({Rectangle()}), false);
  const std::string accessors = "\"accessors\":[{";
  ASSERT_NE(json.find(accessors), std::string::npos);
  json.insert(json.find(accessors) + accessors.size(),
              "\"sparse\":{\"count\":1,\"indices\":{\"bufferView\":0,\"componentType\":5125},"
              "\"values\":{\"bufferView\":0}},");
  EXPECT_TRUE(Contains(ParseError(json), "POSITION (accessors[0]): sparse accessors are not supported"));

  tinygltf::Model model = OneMeshModel({Rectangle()});
  model.extensionsUsed = model.extensionsRequired = {"KHR_draco_mesh_compression"};
  EXPECT_TRUE(Contains(ParseError(Write(model, true)),
                       "extensionsRequired: 'KHR_draco_mesh_compression' is not supported"));
  model.extensionsUsed = model.extensionsRequired = {"KHR_materials_sheen"};  // looks only: ignored
  TriangleMesh mesh;
  EXPECT_EQ(Parse(Write(model, true), &mesh), "");
}

TEST(MeshFile, NodeCyclesAndDeepHierarchiesAreRefused) {
  tinygltf::Model cycle = OneMeshModel({Rectangle()});
  cycle.nodes.resize(2);
  cycle.nodes[0].children = {1};
  cycle.nodes[1].children = {0};
  EXPECT_TRUE(Contains(ParseError(Write(cycle, true)), "nodes[0] is reached twice"));

  tinygltf::Model deep = OneMeshModel({Rectangle()});
  deep.nodes.resize(100);
  for (int i = 0; i < 100; ++i) {
    deep.nodes[i].name = "level " + std::to_string(i + 1);  // tinygltf writes an empty node as null
    if (i + 1 < 100) deep.nodes[i].children = {i + 1};
  }
  EXPECT_TRUE(Contains(ParseError(Write(deep, true)), "nodes[64] is deeper than 64 levels"));

  tinygltf::Model missing_child = OneMeshModel({Rectangle()});
  missing_child.nodes[0].children = {5};
  EXPECT_TRUE(Contains(ParseError(Write(missing_child, true)), "nodes[0].children: node 5 does not exist"));
}

TEST(MeshFile, BrokenAndForeignBytesAreRefused) {
  const std::string glb = Write(OneMeshModel({Rectangle()}), true);
  TriangleMesh mesh;
  ASSERT_EQ(Parse(glb, &mesh), "");
  for (size_t size = 0; size < glb.size(); ++size) {
    SCOPED_TRACE(size);
    const std::string error = ParseError(glb.substr(0, size), {}, v1::MESH_FORMAT_GLB);
  }
  const std::string json = Write(OneMeshModel({Rectangle()}), false);
  for (size_t size = 0; size < json.size(); size += 7) {
    SCOPED_TRACE(size);
    ParseError(json.substr(0, size), {}, v1::MESH_FORMAT_GLTF);
  }
  std::mt19937 random(46);
  std::string garbage(4096, '\0');
  for (char& c : garbage) c = char(random());
  for (auto format : {v1::MESH_FORMAT_AUTO, v1::MESH_FORMAT_GLB, v1::MESH_FORMAT_GLTF, v1::MESH_FORMAT_OBJ}) {
    ParseError(garbage, {}, format);
  }
  EXPECT_TRUE(Contains(ParseError("glTF garbage that is long enough", {}, v1::MESH_FORMAT_AUTO), "GLB"));
  EXPECT_TRUE(Contains(ParseError("{\"asset\": [", {}, v1::MESH_FORMAT_AUTO), "not a glTF 2.0 file"));
  EXPECT_TRUE(Contains(ParseError("{\"asset\":{\"version\":\"2.0\"},\"extras\":" + std::string(100000, '[')),
              "nested more than 64 levels"));
  EXPECT_TRUE(Contains(ParseError("just some text\n"), "no triangles"));
}

TEST(MeshFile, ObjMaterialLibrariesAreNeverRead) {
  // The library exists and would name its material otherwise; no material comes from it, only usemtl names.
  const std::string library = TempPath("library.mtl");
  std::ofstream(library) << "newmtl from_the_library\nKd 1 0 0\n";
  const std::string obj = "mtllib " + library + "\nmtllib /etc/hostname\nv 0 0 0\nv 1 0 0\nv 0 1 0\n" +
                          "usemtl from_the_file\nf 1 2 3\n";
  TriangleMesh mesh;
  ASSERT_EQ(Parse(obj, &mesh), "");
  EXPECT_EQ(mesh.material_names, std::vector<std::string>{"from_the_file"});
  std::remove(library.c_str());
}

TEST(MeshFile, ObjRefusesHugePolygonsTagLinesAndNamesThatAreNotText) {
  std::string obj = "v 0 0 0\nf";
  for (int i = 1; i <= 65; ++i) obj.append(" ").append(std::to_string(i));
  EXPECT_TRUE(Contains(ParseError(obj), "line 2: a face of more than 64 vertices"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nt crease 8192/8192/8192\n"),
                       "line 5: 't' lines (subdivision surface tags) are not read"));
  EXPECT_TRUE(Contains(ParseError("v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl bad\xff\nf 1 2 3\n"),
              "line 5: usemtl 'bad\\xff' is not printable UTF-8 text"));
}

TEST(MeshFile, StopEndsTheParse) {
  TriangleMesh mesh;
  const std::string bytes = Write(OneMeshModel({Rectangle()}), true);
  EXPECT_EQ(Parse(bytes, &mesh, {}, nullptr, v1::MESH_FORMAT_AUTO, [] { return true; }), "stopped");
  // A grid of 2 x 200 x 200 triangles: asked again while the elements are read, a stop that comes later still
  // ends the parse.
  std::ostringstream obj;
  for (int y = 0; y <= 200; ++y) {
    for (int x = 0; x <= 200; ++x) obj << "v " << x << " " << y << " 0\n";
  }
  for (int y = 0; y < 200; ++y) {
    for (int x = 0; x < 200; ++x) {
      const int a = y * 201 + x + 1;
      obj << "f " << a << " " << a + 1 << " " << a + 202 << " " << a + 201 << "\n";
    }
  }
  ASSERT_EQ(Parse(obj.str(), &mesh), "");
  EXPECT_EQ(mesh.triangles.size(), 80000u);
  int asked = 0;
  EXPECT_EQ(Parse(obj.str(), &mesh, {}, nullptr, v1::MESH_FORMAT_AUTO, [&] { return ++asked > 2; }), "stopped");
  EXPECT_GT(asked, 2);
}

}  // namespace
}  // namespace loomlight::assets
