// Meshes uploaded once and stored by name (UploadMesh, ListMeshes, DeleteMesh; assets::MeshStore): end to end
// against real servers on loopback, and the store on disk (two stores on one directory are two replicas).
#include <gtest/gtest.h>
#include <tiny_gltf.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "server/assets/mesh_file.h"
#include "server/assets/mesh_store.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

namespace fs = std::filesystem;

// Two quads of two triangles each, textured, one per material.
const char* kObj =
    "# two panels\n"
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "usemtl body\n"
    "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    "usemtl collar\n"
    "f 1/1 2/2 6/3\nf 1/1 6/3 5/4\n";

// A binary glTF written by tinygltf: one mesh of two primitives (one triangle each) wearing materials "silk" and
// "wool", positions and indices in one buffer.
std::string Glb() {
  tinygltf::Model model;
  model.asset.version = "2.0";
  const float positions[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
  const uint16_t indices[] = {0, 1, 2, 1, 3, 2};
  tinygltf::Buffer buffer;
  buffer.data.resize(sizeof positions + sizeof indices);
  std::memcpy(buffer.data.data(), positions, sizeof positions);
  std::memcpy(buffer.data.data() + sizeof positions, indices, sizeof indices);
  model.buffers.push_back(buffer);
  tinygltf::BufferView vertex_view;
  vertex_view.buffer = 0;
  vertex_view.byteLength = sizeof positions;
  vertex_view.target = TINYGLTF_TARGET_ARRAY_BUFFER;
  tinygltf::BufferView index_view;
  index_view.buffer = 0;
  index_view.byteOffset = sizeof positions;
  index_view.byteLength = sizeof indices;
  index_view.target = TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER;
  model.bufferViews = {vertex_view, index_view};
  tinygltf::Accessor position;
  position.bufferView = 0;
  position.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
  position.count = 4;
  position.type = TINYGLTF_TYPE_VEC3;
  position.minValues = {0, 0, 0};
  position.maxValues = {1, 1, 0};
  model.accessors.push_back(position);
  for (int t = 0; t < 2; ++t) {
    tinygltf::Accessor index;
    index.bufferView = 1;
    index.byteOffset = size_t(t) * 3 * sizeof(uint16_t);
    index.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT;
    index.count = 3;
    index.type = TINYGLTF_TYPE_SCALAR;
    model.accessors.push_back(index);
  }
  tinygltf::Mesh mesh;
  for (int t = 0; t < 2; ++t) {
    tinygltf::Material material;
    material.name = t == 0 ? "silk" : "wool";
    model.materials.push_back(material);
    tinygltf::Primitive primitive;
    primitive.attributes["POSITION"] = 0;
    primitive.indices = 1 + t;
    primitive.material = t;
    primitive.mode = TINYGLTF_MODE_TRIANGLES;
    mesh.primitives.push_back(primitive);
  }
  model.meshes.push_back(mesh);
  tinygltf::Node node;
  node.mesh = 0;
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes = {0};
  model.scenes.push_back(scene);
  model.defaultScene = 0;
  std::ostringstream out;
  tinygltf::TinyGLTF writer;
  EXPECT_TRUE(writer.WriteGltfSceneToStream(&model, out, false, true));
  return out.str();
}

// glTF JSON whose buffer names a file on the server's disk.
const char* kExternalUriGltf =
    R"({"asset":{"version":"2.0"},"buffers":[{"uri":"../../etc/passwd","byteLength":36}],)"
    R"("bufferViews":[{"buffer":0,"byteLength":36}],)"
    R"("accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],)"
    R"("meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]})";

// Sends a header and the chunks; the call's status, *info the stored mesh.
grpc::Status Upload(v1::Loomlight::Stub& stub, const std::string& name, v1::MeshFormat format,
                    const std::string& bytes, v1::MeshInfo* info = nullptr, uint64_t declared = 0,
                    size_t chunk_bytes = 100) {
  grpc::ClientContext ctx;
  v1::MeshInfo out;
  auto writer = stub.UploadMesh(&ctx, &out);
  v1::UploadMeshMessage m;
  m.mutable_header()->set_name(name);
  m.mutable_header()->set_format(format);
  m.mutable_header()->set_size(declared ? declared : bytes.size());
  bool open = writer->Write(m);
  for (size_t at = 0; open && at < bytes.size(); at += chunk_bytes) {
    m.set_chunk(bytes.substr(at, chunk_bytes));
    open = writer->Write(m);
  }
  if (open) writer->WritesDone();
  const grpc::Status s = writer->Finish();
  if (info) *info = out;
  return s;
}

std::vector<v1::MeshInfo> List(v1::Loomlight::Stub& stub, uint64_t* max_bytes = nullptr) {
  grpc::ClientContext ctx;
  v1::ListMeshesResponse out;
  const grpc::Status s = stub.ListMeshes(&ctx, v1::ListMeshesRequest(), &out);
  EXPECT_TRUE(s.ok()) << s.error_message();
  if (max_bytes) *max_bytes = out.max_bytes();
  return {out.meshes().begin(), out.meshes().end()};
}

const v1::MeshInfo* Find(const std::vector<v1::MeshInfo>& list, const std::string& name) {
  for (const v1::MeshInfo& m : list)
    if (m.name() == name) return &m;
  return nullptr;
}

grpc::Status Delete(v1::Loomlight::Stub& stub, const std::string& name) {
  grpc::ClientContext ctx;
  v1::DeleteMeshRequest r;
  r.set_name(name);
  v1::DeleteMeshResponse out;
  return stub.DeleteMesh(&ctx, r, &out);
}

// Polls until `ok` (a guard of 60 s against a hang, not a bound on how fast).
bool WaitUntil(const std::function<bool()>& ok) {
  for (int i = 0; i < 600; ++i) {
    if (ok()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return false;
}

std::vector<std::string> Materials(const v1::MeshInfo& info) {
  return {info.materials().begin(), info.materials().end()};
}

class MeshRpcTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("loomlight-mesh-rpc-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::unique_ptr<api::LoomlightServer> Start(uint64_t store_bytes = 0) {
    api::ServerOptions options;
    options.data_dir = dir_.string();
    options.btf_sync_period = std::chrono::seconds(0);  // syncs when the test asks
    if (store_bytes) options.mesh_store_bytes = store_bytes;
    return testing::StartInProcessServer(options);
  }
  fs::path dir_;
};

TEST_F(MeshRpcTest, UploadedObjAndGlbAreListedWithTheirTrianglesAndMaterialsAndDeleted) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::MeshInfo obj, glb;
  grpc::Status s = Upload(*stub, "Shirt", v1::MESH_FORMAT_AUTO, kObj, &obj);
  ASSERT_TRUE(s.ok()) << s.error_message();
  const std::string glb_bytes = Glb();
  s = Upload(*stub, "panel.v2", v1::MESH_FORMAT_GLB, glb_bytes, &glb);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(obj.format(), v1::MESH_FORMAT_OBJ);  // detected
  EXPECT_EQ(obj.triangles(), 4u);
  EXPECT_EQ(Materials(obj), (std::vector<std::string>{"body", "collar"}));
  EXPECT_TRUE(obj.has_uvs());
  EXPECT_EQ(obj.bytes(), std::strlen(kObj));
  EXPECT_EQ(glb.triangles(), 2u);
  EXPECT_EQ(Materials(glb), (std::vector<std::string>{"silk", "wool"}));
  EXPECT_FALSE(glb.has_uvs());
  EXPECT_EQ(glb.bytes(), glb_bytes.size());

  uint64_t max_bytes = 0;
  const auto list = List(*stub, &max_bytes);
  EXPECT_EQ(max_bytes, api::ServerOptions().mesh_store_bytes);
  ASSERT_EQ(list.size(), 2u);
  ASSERT_TRUE(Find(list, "Shirt") && Find(list, "panel.v2"));
  EXPECT_EQ(Find(list, "Shirt")->SerializeAsString(), obj.SerializeAsString());
  EXPECT_EQ(Find(list, "panel.v2")->SerializeAsString(), glb.SerializeAsString());

  // What a render loads: the parsed mesh, the same description.
  std::shared_ptr<const assets::TriangleMesh> mesh;
  v1::MeshInfo loaded;
  std::string error;
  ASSERT_EQ(server->mesh_store()->Load("SHIRT", nullptr, &mesh, &loaded, &error), assets::MeshStore::Found::kOk)
      << error;
  EXPECT_EQ(mesh->triangles.size(), 4u);
  EXPECT_EQ(loaded.name(), "Shirt");
  EXPECT_EQ(server->mesh_store()->Load("nothing", nullptr, &mesh, &loaded, &error),
            assets::MeshStore::Found::kNotFound);

  s = Delete(*stub, "shirt");  // any case
  EXPECT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(Find(List(*stub), "Shirt"), nullptr);
  EXPECT_EQ(server->mesh_store()->Load("Shirt", nullptr, &mesh, &loaded, &error),
            assets::MeshStore::Found::kNotFound);
  s = Delete(*stub, "Shirt");
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();
  EXPECT_NE(s.error_message().find("name"), std::string::npos) << s.error_message();
  // Its name is free again.
  s = Upload(*stub, "shirt", v1::MESH_FORMAT_OBJ, kObj);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

TEST_F(MeshRpcTest, AMeshSurvivesARestartOnTheSameDataDirectory) {
  v1::MeshInfo uploaded;
  {
    auto server = Start();
    ASSERT_TRUE(server);
    auto stub = testing::Connect(server->port());
    const grpc::Status s = Upload(*stub, "kept", v1::MESH_FORMAT_GLB, Glb(), &uploaded);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  const auto list = List(*stub);
  ASSERT_EQ(list.size(), 1u);
  EXPECT_EQ(list[0].SerializeAsString(), uploaded.SerializeAsString());
  std::shared_ptr<const assets::TriangleMesh> mesh;
  std::string error;
  ASSERT_EQ(server->mesh_store()->Load("kept", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kOk)
      << error;
  EXPECT_EQ(mesh->triangles.size(), 2u);
  EXPECT_EQ(mesh->material_names, (std::vector<std::string>{"silk", "wool"}));
}

TEST_F(MeshRpcTest, TwoServersOnOneDirectorySeeEachOthersUploadsAndDeletions) {
  auto a = Start(), b = Start();
  ASSERT_TRUE(a && b);
  auto on_a = testing::Connect(a->port()), on_b = testing::Connect(b->port());
  grpc::Status s = Upload(*on_a, "shared", v1::MESH_FORMAT_OBJ, kObj);
  ASSERT_TRUE(s.ok()) << s.error_message();
  // B has not synced, yet the name is taken there too (in any case).
  s = Upload(*on_b, "SHARED", v1::MESH_FORMAT_GLB, Glb());
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS) << s.error_message();
  EXPECT_NE(s.error_message().find("header.name"), std::string::npos) << s.error_message();
  b->SyncBtfAssets();
  ASSERT_TRUE(WaitUntil([&] { return Find(List(*on_b), "shared") != nullptr; }));
  EXPECT_EQ(Find(List(*on_b), "shared")->triangles(), 4u);
  std::shared_ptr<const assets::TriangleMesh> mesh;
  std::string error;
  ASSERT_EQ(b->mesh_store()->Load("shared", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kOk) << error;
  EXPECT_EQ(mesh->material_names, (std::vector<std::string>{"body", "collar"}));
  // Deleted on B (the owner is the same client: this test's host): gone from A once it syncs.
  s = Delete(*on_b, "shared");
  ASSERT_TRUE(s.ok()) << s.error_message();
  a->SyncBtfAssets();
  ASSERT_TRUE(WaitUntil([&] { return Find(List(*on_a), "shared") == nullptr; }));
  EXPECT_EQ(a->mesh_store()->Load("shared", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kNotFound);
}

TEST_F(MeshRpcTest, BadUploadsAreRefusedNamingTheField) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  const uint64_t limit = assets::MeshLimits().max_bytes;
  struct Case {
    const char* what;
    std::string name;
    v1::MeshFormat format;
    std::string bytes;
    uint64_t declared;
    grpc::StatusCode code;
    const char* says;
  };
  const std::vector<Case> cases = {
      {"a name that could escape", "../x", v1::MESH_FORMAT_OBJ, kObj, 0, grpc::StatusCode::INVALID_ARGUMENT,
       "header.name"},
      {"a hidden name", ".x", v1::MESH_FORMAT_OBJ, kObj, 0, grpc::StatusCode::INVALID_ARGUMENT, "header.name"},
      {"an unknown format", "x", static_cast<v1::MeshFormat>(9), kObj, 0, grpc::StatusCode::INVALID_ARGUMENT,
       "header.format"},
      {"fewer bytes than declared", "x", v1::MESH_FORMAT_OBJ, kObj, std::strlen(kObj) + 10,
       grpc::StatusCode::INVALID_ARGUMENT, "chunk: the chunks hold"},
      {"a size over the limit", "x", v1::MESH_FORMAT_OBJ, "", limit + 1, grpc::StatusCode::INVALID_ARGUMENT,
       "header.size"},
      {"a glTF naming a file", "x", v1::MESH_FORMAT_AUTO, kExternalUriGltf, 0, grpc::StatusCode::INVALID_ARGUMENT,
       "buffers[0].uri: external files are refused"},
      {"garbage as GLB", "x", v1::MESH_FORMAT_GLB, "\x01\x02 not a mesh at all", 0,
       grpc::StatusCode::INVALID_ARGUMENT, "not a GLB"},
      {"garbage as OBJ", "x", v1::MESH_FORMAT_AUTO, "hello, world\n", 0, grpc::StatusCode::INVALID_ARGUMENT,
       "no triangles"},
  };
  for (const Case& c : cases) {
    const grpc::Status s = Upload(*stub, c.name, c.format, c.bytes, nullptr, c.declared);
    EXPECT_EQ(s.error_code(), c.code) << c.what << ": " << s.error_message();
    EXPECT_NE(s.error_message().find(c.says), std::string::npos) << c.what << ": " << s.error_message();
  }
  {  // a chunk first
    grpc::ClientContext ctx;
    v1::MeshInfo out;
    auto writer = stub->UploadMesh(&ctx, &out);
    v1::UploadMeshMessage m;
    m.set_chunk(kObj);
    writer->Write(m);
    writer->WritesDone();
    const grpc::Status s = writer->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("header"), std::string::npos) << s.error_message();
  }
  EXPECT_TRUE(List(*stub).empty());  // nothing of them stored
  EXPECT_TRUE(fs::is_empty(dir_ / "meshes"));
  // A name taken, in another case.
  ASSERT_TRUE(Upload(*stub, "Taken", v1::MESH_FORMAT_OBJ, kObj).ok());
  grpc::Status s = Upload(*stub, "tAKEN", v1::MESH_FORMAT_OBJ, kObj);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS) << s.error_message();
  EXPECT_NE(s.error_message().find("header.name"), std::string::npos) << s.error_message();
  s = Delete(*stub, "a/b");
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
}

TEST_F(MeshRpcTest, UploadsBeyondTheStoresBoundAreResourceExhausted) {
  // Room for one copy of the OBJ, not two.
  auto server = Start(2 * std::strlen(kObj) - 1);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  grpc::Status s = Upload(*stub, "first", v1::MESH_FORMAT_OBJ, kObj);
  ASSERT_TRUE(s.ok()) << s.error_message();
  s = Upload(*stub, "second", v1::MESH_FORMAT_OBJ, kObj);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_NE(s.error_message().find("--mesh-store-mb"), std::string::npos) << s.error_message();
  ASSERT_TRUE(Delete(*stub, "first").ok());
  s = Upload(*stub, "second", v1::MESH_FORMAT_OBJ, kObj);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

// A client that streams more than its header declared is refused at the first chunk past the size, the bytes
// over it never kept; its later writes fail (the server reads no more) and the call holds nothing afterwards.
TEST_F(MeshRpcTest, AClientStreamingMoreThanItDeclaredIsCutOff) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  grpc::ClientContext ctx;
  v1::MeshInfo out;
  auto writer = stub->UploadMesh(&ctx, &out);
  v1::UploadMeshMessage m;
  m.mutable_header()->set_name("liar");
  m.mutable_header()->set_size(1000);
  ASSERT_TRUE(writer->Write(m));
  m.set_chunk(std::string(1 << 20, 'v'));
  // 100 MiB, more than any mesh file may be: the writes stop long before (flow control stalls a stream nobody
  // reads, and it ends when the server finishes the call).
  int writes = 0;
  while (writes < 100 && writer->Write(m)) ++writes;
  EXPECT_LT(writes, 100);
  const grpc::Status s = writer->Finish();
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("chunk: the chunks hold more than the header's size of 1000"), std::string::npos)
      << s.error_message();
  EXPECT_TRUE(WaitUntil([&] { return server->memory_in_use() == 0 && server->long_calls_in_use() == 0; }));
  EXPECT_TRUE(List(*stub).empty());
}

// An upload that declares a large file and stalls holds the bytes it sent, not the ones it declared.
TEST_F(MeshRpcTest, AStalledUploadHoldsOnlyWhatItSent) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  grpc::ClientContext ctx;
  v1::MeshInfo out;
  auto writer = stub->UploadMesh(&ctx, &out);
  v1::UploadMeshMessage m;
  m.mutable_header()->set_name("slow");
  m.mutable_header()->set_size(assets::MeshLimits().max_bytes);
  ASSERT_TRUE(writer->Write(m));
  m.set_chunk(std::string(4096, 'v'));
  ASSERT_TRUE(writer->Write(m));
  ASSERT_TRUE(WaitUntil([&] { return server->memory_in_use() >= 4096; }));
  EXPECT_LT(server->memory_in_use(), size_t{64} << 10);
  ctx.TryCancel();
  writer->Finish();
  EXPECT_TRUE(WaitUntil([&] { return server->memory_in_use() == 0 && server->long_calls_in_use() == 0; }));
}

// An upload whose client stops sending is cancelled by the idle bound (UploadBtf's, server/api/upload_bounds.h),
// which the server counts as DEADLINE_EXCEEDED (its client sees the cancellation), and gives back its slot.
TEST_F(MeshRpcTest, AnUploadThatStopsSendingIsCancelled) {
  api::ServerOptions options;
  options.data_dir = dir_.string();
  options.limits.upload_idle_timeout = std::chrono::milliseconds(300);
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  grpc::ClientContext ctx;
  v1::MeshInfo out;
  auto writer = stub->UploadMesh(&ctx, &out);
  v1::UploadMeshMessage m;
  m.mutable_header()->set_name("silent");
  m.mutable_header()->set_size(1000);
  ASSERT_TRUE(writer->Write(m));
  EXPECT_EQ(writer->Finish().error_code(), grpc::StatusCode::CANCELLED);  // returns once the server cancelled it
  EXPECT_TRUE(testing::WaitForCallsEnded(server->metrics_port(), "UploadMesh", "DEADLINE_EXCEEDED", 1));
  EXPECT_TRUE(WaitUntil([&] { return server->memory_in_use() == 0 && server->long_calls_in_use() == 0; }));
  EXPECT_TRUE(List(*stub).empty());
}

TEST_F(MeshRpcTest, TheClientUploadsListsAndDeletesMeshes) {
  auto server = Start();
  ASSERT_TRUE(server);
  const fs::path file = dir_ / "garment.obj";
  fs::create_directories(dir_);
  std::ofstream(file) << kObj;
  std::string output;
  ASSERT_EQ(testing::RunClient(server->port(), "mesh upload " + file.string(), &output), 0) << output;
  EXPECT_NE(output.find("garment: obj, 4 triangles"), std::string::npos) << output;
  ASSERT_EQ(testing::RunClient(server->port(), "mesh upload " + file.string() + " --name collar --format obj", &output),
            0)
      << output;
  ASSERT_EQ(testing::RunClient(server->port(), "mesh list", &output), 0) << output;
  // One row per mesh: name, format, triangles, vertices, materials, bytes.
  std::istringstream rows(output);
  std::string line;
  int found = 0;
  while (std::getline(rows, line)) {
    std::istringstream row(line);
    std::string name, format;
    uint64_t triangles = 0, vertices = 0, materials = 0, bytes = 0;
    if (!(row >> name >> format >> triangles >> vertices >> materials >> bytes)) continue;
    if (name != "garment" && name != "collar") continue;
    ++found;
    EXPECT_EQ(format, "obj");
    EXPECT_EQ(triangles, 4u);
    EXPECT_EQ(materials, 2u);
    EXPECT_EQ(bytes, std::strlen(kObj));
  }
  EXPECT_EQ(found, 2) << output;
  ASSERT_EQ(testing::RunClient(server->port(), "mesh delete garment", &output), 0) << output;
  EXPECT_EQ(testing::RunClient(server->port(), "mesh delete garment", &output), 1) << output;
  EXPECT_NE(output.find("NOT_FOUND"), std::string::npos) << output;
  EXPECT_EQ(testing::RunClient(server->port(), "mesh upload " + file.string() + " --format stl", &output), 2) << output;
  ASSERT_EQ(testing::RunClient(server->port(), "mesh list", &output), 0) << output;
  EXPECT_EQ(output.find("garment"), std::string::npos) << output;
  EXPECT_NE(output.find("collar"), std::string::npos) << output;
}

// ---- The store on disk ----

class MeshStoreOnDisk : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("loomlight-mesh-store-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::unique_ptr<assets::MeshStore> Open(uint64_t cache_bytes = uint64_t{1} << 30) {
    std::string error;
    auto store = assets::MeshStore::Open(dir_.string(), uint64_t{1} << 30, cache_bytes, {}, &error);
    EXPECT_TRUE(store) << error;
    return store;
  }
  // The OBJ's description as an upload makes it, under `name`.
  static v1::MeshInfo Info(const std::string& name, const std::string& bytes = kObj) {
    assets::TriangleMesh mesh;
    EXPECT_EQ(assets::ParseMesh(bytes, v1::MESH_FORMAT_OBJ, {}, &mesh), "");
    v1::MeshInfo info;
    assets::DescribeMesh(mesh, &info);
    info.set_name(name);
    info.set_format(v1::MESH_FORMAT_OBJ);
    info.set_bytes(bytes.size());
    return info;
  }
  fs::path dir_;
};

// Store B checks the name, writes, and before it publishes, store A (another replica) stores the same name: B gets
// kExists, A's mesh stays, and nothing of B's write is left.
TEST_F(MeshStoreOnDisk, ACreateThatLosesTheRaceIsExistsAndKeepsTheWinnersMesh) {
  auto a = Open(), b = Open();
  ASSERT_TRUE(a && b);
  std::string error_a, error_b;
  auto won = assets::MeshStore::Outcome::kFailed;
  const std::string one_quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n";
  b->set_before_publish_for_test([&] { won = a->Put(Info("race", one_quad), one_quad, "a", nullptr, &error_a); });
  EXPECT_EQ(b->Put(Info("Race"), kObj, "b", nullptr, &error_b), assets::MeshStore::Outcome::kExists) << error_b;
  EXPECT_EQ(won, assets::MeshStore::Outcome::kOk) << error_a;
  EXPECT_TRUE(b->List().empty());
  EXPECT_EQ(b->Sync(), 1);
  std::shared_ptr<const assets::TriangleMesh> mesh;
  std::string error;
  ASSERT_EQ(b->Load("RACE", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kOk) << error;
  EXPECT_EQ(mesh->triangles.size(), 1u);  // A's
  size_t entries = 0;
  for (const auto& entry : fs::directory_iterator(dir_ / "meshes")) ++entries, (void)entry;
  EXPECT_EQ(entries, 2u);  // the link and its version
}

// Parsed meshes are kept up to the cache's bytes, the least recently used dropped first; a load after a drop
// parses again (a new object); a stored file that no longer parses is kFailed, not kNotFound.
TEST_F(MeshStoreOnDisk, ParsedMeshesAreCachedWithinTheirBytesLeastRecentlyUsedDroppedFirst) {
  assets::TriangleMesh parsed;
  ASSERT_EQ(assets::ParseMesh(kObj, v1::MESH_FORMAT_OBJ, {}, &parsed), "");
  const uint64_t one = parsed.memory_bytes();
  ASSERT_GT(one, 0u);
  auto store = Open(2 * one + one / 2);  // room for two
  ASSERT_TRUE(store);
  std::string error;
  for (const char* name : {"m1", "m2", "m3"})
    ASSERT_EQ(store->Put(Info(name), kObj, "me", nullptr, &error), assets::MeshStore::Outcome::kOk) << error;
  EXPECT_EQ(store->cache_bytes(), 0u);  // put without a parse: parsed on first use
  const auto load = [&](const std::string& name) {
    std::shared_ptr<const assets::TriangleMesh> mesh;
    EXPECT_EQ(store->Load(name, nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kOk) << error;
    return mesh;
  };
  const auto m1 = load("m1"), m2 = load("m2");
  EXPECT_EQ(load("m1"), m1);  // cached (and now the most recently used)
  EXPECT_EQ(store->cache_bytes(), 2 * one);
  load("m3");  // drops m2, the least recently used
  EXPECT_EQ(store->cache_bytes(), 2 * one);
  EXPECT_EQ(load("m1"), m1);
  EXPECT_NE(load("m2"), m2);  // parsed again
  // A mesh file damaged on disk: found, and failed with the parser's reason.
  store->Delete("m3", "me", false);
  ASSERT_EQ(store->Put(Info("damaged"), kObj, "me", nullptr, &error), assets::MeshStore::Outcome::kOk) << error;
  {
    std::ofstream out(dir_ / "meshes" / "damaged" / "mesh", std::ios::binary | std::ios::trunc);
    out << "nothing here\n";
  }
  std::shared_ptr<const assets::TriangleMesh> mesh;
  EXPECT_EQ(store->Load("damaged", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kFailed);
  EXPECT_NE(error.find("no triangles"), std::string::npos) << error;
  EXPECT_EQ(store->Load("m3", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kNotFound);  // deleted
  // A parse that is stopped says so (and keeps nothing).
  ASSERT_EQ(store->Put(Info("m4"), kObj, "me", nullptr, &error), assets::MeshStore::Outcome::kOk) << error;
  const uint64_t cached = store->cache_bytes();
  EXPECT_EQ(store->Load("m4", [] { return true; }, &mesh, nullptr, &error), assets::MeshStore::Found::kFailed);
  EXPECT_EQ(error, "stopped");
  EXPECT_EQ(store->cache_bytes(), cached);
}

// A mesh belongs to the client that stored it: another cannot delete it, whether the store loaded it or finds it
// only on disk; an admin can.
TEST_F(MeshStoreOnDisk, OnlyTheOwnerOrAnAdminDeletesAMesh) {
  auto a = Open(), b = Open();
  ASSERT_TRUE(a && b);
  std::string error;
  ASSERT_EQ(a->Put(Info("owned"), kObj, "host:alice", nullptr, &error), assets::MeshStore::Outcome::kOk) << error;
  EXPECT_EQ(b->Delete("owned", "host:bob", false), assets::MeshStore::Removal::kDenied);  // on disk only
  EXPECT_EQ(a->Delete("owned", "host:bob", false), assets::MeshStore::Removal::kDenied);
  EXPECT_EQ(b->Delete("OWNED", "client:operator", true), assets::MeshStore::Removal::kRemoved);
  EXPECT_FALSE(b->Exists("owned"));
  EXPECT_EQ(a->List().size(), 1u);  // registered, but gone from disk: dropped at its next Sync
  std::shared_ptr<const assets::TriangleMesh> mesh;
  EXPECT_EQ(a->Load("owned", nullptr, &mesh, nullptr, &error), assets::MeshStore::Found::kNotFound) << error;
  EXPECT_EQ(a->Sync(), 1);
  EXPECT_TRUE(a->List().empty());
  EXPECT_EQ(a->Delete("owned", "host:alice", false), assets::MeshStore::Removal::kNotFound);
}

}  // namespace
}  // namespace loomlight
