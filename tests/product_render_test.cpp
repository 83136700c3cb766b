// Product shots end to end against an in-process server (docs/products.md): a client's mesh sent with the
// request or stored by name renders on white or transparent with the fill it reports; the weave follows the
// mesh's UV layout (a quarter-turned layout with a quarter-turned texture renders the same); each mesh material
// wears its own material; a turntable's views are the mesh turned; the fidelity ladder's rungs are reported per
// pixel; every bad mesh request is refused naming what is wrong.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using v1::RenderRequest;
using v1::RenderUpdate;

struct Rendered {
  grpc::Status status;
  RenderUpdate last;
};

Rendered Render(v1::Loomlight::Stub& stub, const RenderRequest& request) {
  Rendered out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
  auto reader = stub.Render(&ctx, request);
  RenderUpdate update;
  while (reader->Read(&update)) out.last = update;
  out.status = reader->Finish();
  return out;
}

// One quad per material: corners in order (counter-clockwise seen from +z), each with its uv.
struct Quad {
  std::string material;
  double corners[4][3];
  double uv[4][2];
};

// An OBJ file of the quads (each its own four vertices and two triangles).
std::string Obj(const std::vector<Quad>& quads, bool with_uv = true) {
  std::ostringstream out;
  out.precision(17);
  int base = 1;
  for (const Quad& q : quads) {
    for (const auto& c : q.corners) out << "v " << c[0] << " " << c[1] << " " << c[2] << "\n";
    if (with_uv)
      for (const auto& t : q.uv) out << "vt " << t[0] << " " << t[1] << "\n";
    out << "usemtl " << q.material << "\n";
    for (int tri : {0, 1}) {
      const int a = base, b = base + 1 + tri, c = base + 2 + tri;
      if (with_uv)
        out << "f " << a << "/" << a << " " << b << "/" << b << " " << c << "/" << c << "\n";
      else
        out << "f " << a << " " << b << " " << c << "\n";
    }
    base += 4;
  }
  return out.str();
}

// A unit square in the xy plane centred at (cx, cy), facing +z, its u along +x and v along +y.
Quad Square(const std::string& material, double cx, double cy, double half = 0.5) {
  return {material,
          {{cx - half, cy - half, 0}, {cx + half, cy - half, 0}, {cx + half, cy + half, 0}, {cx - half, cy + half, 0}},
          {{0, 0}, {1, 0}, {1, 1}, {0, 1}}};
}

RenderRequest MeshRequest(const std::string& obj, uint32_t size, uint32_t spp) {
  RenderRequest r;
  r.mutable_mesh()->mutable_data()->set_data(obj);
  r.mutable_material()->set_preset("silk_shot");
  r.set_width(size);
  r.set_height(size);
  r.set_samples_per_pixel(spp);
  r.set_sampling(v1::SAMPLING_UNIFORM);
  r.set_seed(3);
  r.set_format(v1::RENDER_FORMAT_EXR);
  // Looking straight at the xy plane from +z.
  for (double v : {0.0, 0.0, 3.0}) r.mutable_camera()->add_position(v);
  for (double v : {0.0, 0.0, 0.0}) r.mutable_camera()->add_look_at(v);
  r.mutable_camera()->set_fov_deg(40);
  v1::RenderLight* light = r.add_lights();
  light->set_type(v1::RenderLight::TYPE_DIRECTIONAL);
  for (double v : {0.3, 0.5, 1.0}) light->add_direction(v);
  for (double v : {3.0, 3.0, 3.0}) light->add_rgb(v);
  return r;
}

double RelativeRmse(const std::vector<float>& a, const std::vector<float>& b) {
  double diff = 0, total = 0;
  for (size_t i = 0; i < a.size() && i < b.size(); ++i) {
    diff += (a[i] - b[i]) * double(a[i] - b[i]);
    total += b[i] * double(b[i]);
  }
  return total > 0 ? std::sqrt(diff / total) : 0;
}

class ProductRenderTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    data_dir_ = new std::string(std::filesystem::temp_directory_path() / "loomlight-product-render-test");
    std::filesystem::remove_all(*data_dir_);
    api::ServerOptions options;
    options.data_dir = *data_dir_;
    server_ = testing::StartInProcessServer(options).release();
    ASSERT_NE(server_, nullptr);
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
    std::filesystem::remove_all(*data_dir_);
    delete data_dir_;
  }
  std::vector<float> Linear(const RenderRequest& request, RenderUpdate* last = nullptr) {
    const Rendered r = Render(*stub_, request);
    EXPECT_TRUE(r.status.ok()) << r.status.error_message();
    if (!r.status.ok()) return {};
    if (last) *last = r.last;
    return testing::DecodeImage(r.last.image(), "render.exr").pixels;
  }
  static api::LoomlightServer* server_;
  static std::string* data_dir_;
  std::unique_ptr<v1::Loomlight::Stub> stub_ = testing::Connect(server_->port());
};
api::LoomlightServer* ProductRenderTest::server_ = nullptr;
std::string* ProductRenderTest::data_dir_ = nullptr;

TEST_F(ProductRenderTest, WhiteBackgroundIsPureWhiteAndTheFillIsTheProductsShare) {
  RenderRequest r = MeshRequest(Obj({Square("cloth", 0, 0)}), 64, 4);
  r.set_background(v1::BACKGROUND_WHITE);
  r.set_format(v1::RENDER_FORMAT_PNG);
  const Rendered rendered = Render(*stub_, r);
  ASSERT_TRUE(rendered.status.ok()) << rendered.status.error_message();
  const testing::DecodedImage image = testing::DecodeImage(rendered.last.image(), "shot.png");
  ASSERT_EQ(image.width, 64);
  // The square's side seen from 3 units at 40 degrees: 1 / (2 x 3 tan 20 degrees) of the frame's height.
  const double side = 1 / (2 * 3 * std::tan(20 * std::numbers::pi / 180));
  EXPECT_NEAR(rendered.last.fill(), side * side, 0.02);
  // Corners: the background, pure white; the centre: the cloth, not white.
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(image.pixels[c], 1.0f);
    EXPECT_EQ(image.pixels[(64 * 64 - 1) * image.channels + c], 1.0f);
  }
  const float* centre = &image.pixels[(32 * 64 + 32) * image.channels];
  EXPECT_LT(centre[0] + centre[1] + centre[2], 2.9f);
}

TEST_F(ProductRenderTest, TransparentBackgroundCarriesTheCoverageAsAlpha) {
  RenderRequest r = MeshRequest(Obj({Square("cloth", 0, 0)}), 48, 4);
  r.set_background(v1::BACKGROUND_TRANSPARENT);
  r.set_format(v1::RENDER_FORMAT_PNG);
  const Rendered rendered = Render(*stub_, r);
  ASSERT_TRUE(rendered.status.ok()) << rendered.status.error_message();
  const testing::DecodedImage image = testing::DecodeImage(rendered.last.image(), "shot.png");
  ASSERT_EQ(image.channels, 4);
  EXPECT_EQ(image.pixels[3], 0.0f);                                 // a corner: nothing there
  EXPECT_EQ(image.pixels[(24 * 48 + 24) * 4 + 3], 1.0f);            // the centre: all cloth
  r.set_format(v1::RENDER_FORMAT_JPEG);                             // JPEG has no alpha: refused up front
  const Rendered jpeg = Render(*stub_, r);
  EXPECT_EQ(jpeg.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(jpeg.status.error_message().find("background"), std::string::npos) << jpeg.status.error_message();
}

TEST_F(ProductRenderTest, TheWeaveFollowsTheUvLayout) {
  // A close-up of a square whose threads span many pixels: the BTF shows the weave.
  Quad turned = Square("cloth", 0, 0);
  // The same square with its UV layout turned a quarter: u along -y, v along +x.
  const double uv_turned[4][2] = {{1, 0}, {1, 1}, {0, 1}, {0, 0}};
  for (int i = 0; i < 4; ++i)
    for (int k = 0; k < 2; ++k) turned.uv[i][k] = uv_turned[i][k];
  RenderRequest plain = MeshRequest(Obj({Square("cloth", 0, 0)}), 96, 4);
  plain.mutable_material()->set_preset("cotton_twill");
  plain.set_texture_scale(4);  // repeats per UV unit: a repeat spans ~11 pixels
  plain.set_force_full_fidelity(true);  // the BTF everywhere: the pattern itself shows
  plain.set_background(v1::BACKGROUND_WHITE);
  RenderRequest quarter = plain;
  quarter.mutable_mesh()->mutable_data()->set_data(Obj({turned}));
  const std::vector<float> a = Linear(plain), b = Linear(quarter);
  // Turned threads show: the twill's diagonal and the warp's direction differ.
  EXPECT_GT(RelativeRmse(b, a), 0.01);  // 0.026 measured: the twill's diagonal and the warp's sheen turned
  // Turning the texture back a quarter (threads and pattern together: the frame's x from -y to +x) gives the
  // same image.
  quarter.set_texture_rotation_deg(90);
  const std::vector<float> back = Linear(quarter);
  ASSERT_EQ(back.size(), a.size());
  EXPECT_LT(RelativeRmse(back, a), 2e-3);
}

TEST_F(ProductRenderTest, EachMeshMaterialWearsItsOwnMaterial) {
  const std::string obj = Obj({Square("left", -0.55, 0), Square("right", 0.55, 0)});
  RenderRequest one = MeshRequest(obj, 64, 2);
  one.mutable_camera()->set_fov_deg(60);
  RenderRequest two = one;
  v1::MaterialBinding* binding = two.add_materials();
  binding->set_mesh_material("right");
  binding->mutable_material()->set_preset("velvet");
  RenderUpdate last;
  const std::vector<float> a = Linear(one), b = Linear(two, &last);
  ASSERT_EQ(a.size(), b.size());
  // Columns 0-31 see the left square (silk_shot in both), 32-63 the right (velvet in the second).
  const auto half_rmse = [&](int x0, int x1) {
    std::vector<float> ha, hb;
    for (int y = 0; y < 64; ++y)
      for (int x = x0; x < x1; ++x)
        for (int c = 0; c < 4 && c < 3; ++c) {
          ha.push_back(a[(y * 64 + x) * 3 + c]);
          hb.push_back(b[(y * 64 + x) * 3 + c]);
        }
    return RelativeRmse(hb, ha);
  };
  EXPECT_LT(half_rmse(0, 30), 1e-6);
  EXPECT_GT(half_rmse(34, 64), 0.1);
  ASSERT_EQ(last.fidelity_size(), 2);
  EXPECT_EQ(last.fidelity(1).object(), "mesh material 'right'");
}

TEST_F(ProductRenderTest, TurntableViewsAreTheMeshTurned) {
  // Something with no symmetry about +y: two squares at different depths and heights, one tilted.
  const std::vector<Quad> quads = {
      Square("a", -0.3, 0.2, 0.4),
      {"b", {{0.1, -0.6, -0.5}, {0.7, -0.6, -0.2}, {0.7, 0.1, -0.2}, {0.1, 0.1, -0.5}}, {{0, 0}, {1, 0}, {1, 1}, {0, 1}}}};
  RenderRequest r = MeshRequest(Obj(quads), 48, 2);
  r.set_background(v1::BACKGROUND_WHITE);
  r.set_views(4);
  v1::RenderLight* point = r.add_lights();
  point->set_type(v1::RenderLight::TYPE_POINT);
  for (double v : {1.0, 2.0, 2.0}) point->add_position(v);
  for (double v : {4.0, 4.0, 4.0}) point->add_rgb(v);
  const Rendered turntable = Render(*stub_, r);
  ASSERT_TRUE(turntable.status.ok()) << turntable.status.error_message();
  ASSERT_EQ(turntable.last.views_size(), 4);
  for (int k = 0; k < 4; ++k) {
    // View k sees the mesh turned by -k quarter turns about +y (the camera turned by +k quarters), under lights
    // that turn with the camera: the same as one view of the mesh turned, from the first camera, under the
    // first lights. Quarter turns are exact in floating point: (x, z) -> (-z, x) k times.
    std::vector<Quad> turned = quads;
    for (Quad& q : turned)
      for (auto& c : q.corners)
        for (int i = 0; i < k; ++i) {
          const double x = c[0], z = c[2];
          c[0] = -z;
          c[2] = x;
        }
    RenderRequest single = r;
    single.set_views(1);
    single.mutable_mesh()->mutable_data()->set_data(Obj(turned));
    const std::vector<float> expected = Linear(single);
    const std::vector<float> view = testing::DecodeImage(turntable.last.views(k).image(), "view.exr").pixels;
    ASSERT_EQ(view.size(), expected.size());
    // (Edge pixels' coverage may flip where a ray grazes a turned triangle's edge: rounding, not the rotation.)
    EXPECT_LT(RelativeRmse(view, expected), 5e-3) << "view " << k;
    if (k > 0) {
      const std::vector<float> first = testing::DecodeImage(turntable.last.views(0).image(), "view.exr").pixels;
      EXPECT_GT(RelativeRmse(view, first), 0.05) << "view " << k << " is not turned";
    }
  }
}

TEST_F(ProductRenderTest, StudioLightingIsTheMeshDefault) {
  RenderRequest r = MeshRequest(Obj({Square("cloth", 0, 0)}), 32, 2);
  r.clear_lights();
  r.set_background(v1::BACKGROUND_WHITE);
  RenderUpdate last;
  const std::vector<float> image = Linear(r, &last);
  ASSERT_FALSE(image.empty());
  EXPECT_GT(last.mean(0), 0);  // lit
  for (float v : image) ASSERT_TRUE(std::isfinite(v));
}

TEST_F(ProductRenderTest, FidelityLadderReportsEachRungsShare) {
  // A long strip seen at a grazing angle: near its threads span pixels (BTF), far they do not (BRDF).
  RenderRequest r = MeshRequest(
      Obj({{"cloth", {{-0.5, 0, 2}, {0.5, 0, 2}, {0.5, 0, -30}, {-0.5, 0, -30}}, {{0, 0}, {1, 0}, {1, 32}, {0, 32}}}}),
      64, 2);
  r.mutable_material()->set_preset("cotton_twill");
  r.set_texture_scale(5);  // repeats per metre: threads span ~4 pixels at the near end, ~0.1 at the far
  r.clear_camera();
  for (double v : {0.0, 0.4, 3.0}) r.mutable_camera()->add_position(v);
  for (double v : {0.0, 0.0, 0.0}) r.mutable_camera()->add_look_at(v);
  RenderUpdate last;
  ASSERT_FALSE(Linear(r, &last).empty());
  ASSERT_EQ(last.fidelity_size(), 1);
  double total = 0;
  bool btf = false, brdf = false;
  for (const v1::RungShare& rung : last.fidelity(0).rungs()) {
    total += rung.share();
    btf |= rung.rung() == "BTF" && rung.share() > 0.01;
    brdf |= rung.rung() == "BRDF" && rung.share() > 0.01;
  }
  EXPECT_NEAR(total, 1.0, 1e-9);
  EXPECT_TRUE(btf && brdf) << last.fidelity(0).DebugString();
  ASSERT_GE(last.rungs_size(), 2);
}

TEST_F(ProductRenderTest, EveryBadMeshRequestIsRefusedNamingTheProblem) {
  const std::string good = Obj({Square("cloth", 0, 0)});
  struct Case {
    std::string what;
    std::function<void(RenderRequest&)> change;
    grpc::StatusCode code;
    std::string needle;
  };
  const std::string external_gltf =
      R"({"asset":{"version":"2.0"},"buffers":[{"uri":"/etc/passwd","byteLength":12}],"bufferViews":[{"buffer":0,"byteLength":12}],)"
      R"("accessors":[{"bufferView":0,"componentType":5126,"count":1,"type":"VEC3"}],)"
      R"("meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]})";
  const std::vector<Case> cases = {
      {"garbage", [](RenderRequest& r) { r.mutable_mesh()->mutable_data()->set_data(std::string("\x01\x02garbage", 9)); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.data"},
      {"external uri", [&](RenderRequest& r) { r.mutable_mesh()->mutable_data()->set_data(external_gltf); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.data"},
      {"NaN position", [](RenderRequest& r) { r.mutable_mesh()->mutable_data()->set_data("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.data"},
      {"index out of range", [](RenderRequest& r) { r.mutable_mesh()->mutable_data()->set_data("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.data"},
      {"degenerate", [](RenderRequest& r) { r.mutable_mesh()->mutable_data()->set_data("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.data"},
      {"empty", [](RenderRequest& r) { r.mutable_mesh()->mutable_data()->set_data(""); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.data.data"},
      {"woven without uvs", [](RenderRequest& r) {
         r.mutable_mesh()->mutable_data()->set_data(Obj({Square("cloth", 0, 0)}, false));
         r.mutable_material()->set_preset("cotton_twill");
       }, grpc::StatusCode::INVALID_ARGUMENT, "texture coordinates"},
      {"unknown mesh material", [](RenderRequest& r) {
         v1::MaterialBinding* b = r.add_materials();
         b->set_mesh_material("sleeve");
         b->mutable_material()->set_preset("velvet");
       }, grpc::StatusCode::INVALID_ARGUMENT, "materials[0].mesh_material"},
      {"bad binding material", [](RenderRequest& r) {
         v1::MaterialBinding* b = r.add_materials();
         b->set_mesh_material("cloth");
         b->mutable_material()->set_preset("no_such_preset");
       }, grpc::StatusCode::INVALID_ARGUMENT, "materials[0].material"},
      {"a scene too", [](RenderRequest& r) { r.set_scene_name("sphere"); }, grpc::StatusCode::INVALID_ARGUMENT, "mesh:"},
      {"too many views", [](RenderRequest& r) { r.set_views(1000); }, grpc::StatusCode::INVALID_ARGUMENT, "views"},
      {"unknown lighting", [](RenderRequest& r) { r.set_lighting("disco"); }, grpc::StatusCode::INVALID_ARGUMENT, "lighting"},
      {"not stored", [](RenderRequest& r) { r.mutable_mesh()->set_name("nothing_here"); }, grpc::StatusCode::NOT_FOUND,
       "mesh.name"},
      {"bad name", [](RenderRequest& r) { r.mutable_mesh()->set_name("../etc"); }, grpc::StatusCode::INVALID_ARGUMENT,
       "mesh.name"},
      {"absolute path", [](RenderRequest& r) { r.mutable_mesh()->set_name("/etc/passwd"); },
       grpc::StatusCode::INVALID_ARGUMENT, "mesh.name"},
      {"too large", [](RenderRequest& r) { r.set_width(4097); }, grpc::StatusCode::INVALID_ARGUMENT, "width"},
  };
  for (const Case& c : cases) {
    RenderRequest r = MeshRequest(good, 16, 1);
    c.change(r);
    const Rendered rendered = Render(*stub_, r);
    EXPECT_EQ(rendered.status.error_code(), c.code) << c.what << ": " << rendered.status.error_message();
    EXPECT_NE(rendered.status.error_message().find(c.needle), std::string::npos)
        << c.what << ": " << rendered.status.error_message();
  }
  // And the server renders on.
  EXPECT_TRUE(Render(*stub_, MeshRequest(good, 16, 1)).status.ok());
}

}  // namespace
}  // namespace loomlight
