// FitMaterial end to end (docs/materials-out.md): real calls to an in-process server on loopback. The fits
// themselves are checked against their references in lobe_fit_test, the files by other tools in
// material_export_test; here: that the RPC fits what it is asked, writes files that parse as what they claim,
// maps colourways and panels as asked, and refuses hostile requests by the field, without disturbing other calls.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <pugixml.hpp>

#include <chrono>
#include <cmath>
#include <fstream>
#include <iterator>
#include <memory>
#include <sstream>
#include <string>

#include "server/api/fit_rpc.h"
#include "server/assets/mesh_file.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

// A product mesh the server ships (Blender's cloth simulation of a draped fabric on a stand: two materials).
std::string ProductMesh() {
  std::ifstream in(std::string(LOOMLIGHT_SOURCE_DIR) + "/server/render/scenes/meshes/drape_stand.glb",
                   std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

class FitRpcTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = testing::StartInProcessServer().release(); }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }

  grpc::Status Fit(const v1::FitMaterialRequest& request, v1::FitMaterialResponse* response,
                   std::chrono::milliseconds timeout = std::chrono::minutes(5)) {
    auto stub = testing::Connect(server_->port());
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + timeout);
    return stub->FitMaterial(&context, request, response);
  }

  // The request's status must be INVALID_ARGUMENT with `field` in its message.
  void ExpectRefused(const v1::FitMaterialRequest& request, const std::string& field) {
    v1::FitMaterialResponse response;
    const grpc::Status s = Fit(request, &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find(field), std::string::npos) << s.error_message();
  }

  static api::LoomlightServer* server_;
};
api::LoomlightServer* FitRpcTest::server_ = nullptr;

v1::FitMaterialRequest Request(const std::string& preset, v1::FitTarget target, v1::ExportFormat format) {
  v1::FitMaterialRequest request;
  request.mutable_material()->set_preset(preset);
  request.set_target(target);
  request.set_format(format);
  return request;
}

double ParamValue(const v1::Material& m, const std::string& name, int i = 0) {
  for (const v1::Param& p : m.params())
    if (p.name() == name) return p.values(i);
  ADD_FAILURE() << "no parameter " << name;
  return NAN;
}

TEST_F(FitRpcTest, FitsAPresetToGlbWithItsErrorAndRegions) {
  v1::FitMaterialResponse response;
  const grpc::Status s = Fit(Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB), &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(response.fits_size(), 1);
  const v1::MaterialFit& fit = response.fits(0);
  EXPECT_EQ(fit.fitted().model(), "gltf_sheen");
  EXPECT_TRUE(std::isfinite(fit.error()) && fit.error() > 0 && fit.error() < 1) << fit.error();
  ASSERT_GT(fit.regions_size(), 1);
  double share = 0;
  for (int r = 0; r < fit.regions_size(); ++r) {
    share += fit.regions(r).share();
    if (r > 0) {
      EXPECT_LE(fit.regions(r).error(), fit.regions(r - 1).error()) << "worst first";
    }
  }
  EXPECT_NEAR(share, 1.0, 1e-9);
  for (const char* name : {"base_color", "roughness", "sheen_color", "sheen_roughness"}) {
    const double v = ParamValue(fit.fitted(), name);
    EXPECT_TRUE(v >= 0 && v <= 1) << name << " " << v;
  }
  EXPECT_EQ(response.file_extension(), ".glb");
  ASSERT_GE(response.file().size(), 12u);
  EXPECT_EQ(response.file().substr(0, 4), "glTF");
  // The file is the preview sphere our own mesh reader accepts (one material slot).
  assets::TriangleMesh mesh;
  EXPECT_EQ(assets::ParseMesh(response.file(), v1::MESH_FORMAT_GLB, {}, &mesh), "");
  EXPECT_EQ(mesh.material_names.size(), 1u);
  EXPECT_GT(mesh.triangles.size(), 100u);
}

TEST_F(FitRpcTest, SameRequestFitsTheSameParameters) {
  v1::FitMaterialResponse a, b;
  ASSERT_TRUE(Fit(Request("cotton_twill", v1::FIT_TARGET_OPENPBR, v1::EXPORT_FORMAT_NONE), &a).ok());
  ASSERT_TRUE(Fit(Request("cotton_twill", v1::FIT_TARGET_OPENPBR, v1::EXPORT_FORMAT_NONE), &b).ok());
  ASSERT_EQ(a.fits_size(), 1);
  ASSERT_EQ(b.fits_size(), 1);
  EXPECT_EQ(a.fits(0).fitted().SerializeAsString(), b.fits(0).fitted().SerializeAsString());
  EXPECT_EQ(a.fits(0).error(), b.fits(0).error());
  EXPECT_TRUE(a.file().empty());
}

TEST_F(FitRpcTest, MaterialXDocumentHasOneOpenPbrSurfacePerFabric) {
  v1::FitMaterialResponse response;
  ASSERT_TRUE(Fit(Request("silk_shot", v1::FIT_TARGET_OPENPBR, v1::EXPORT_FORMAT_MTLX), &response).ok());
  EXPECT_EQ(response.file_extension(), ".mtlx");
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(response.file().c_str())) << response.file().substr(0, 200);
  const pugi::xml_node root = doc.child("materialx");
  ASSERT_TRUE(root);
  int shaders = 0;
  for (pugi::xml_node n : root.children("open_pbr_surface")) {
    ++shaders;
    const pugi::xml_node roughness = n.find_child_by_attribute("input", "name", "fuzz_roughness");
    ASSERT_TRUE(roughness);
    EXPECT_NEAR(roughness.attribute("value").as_double(), ParamValue(response.fits(0).fitted(), "fuzz_roughness"),
                1e-6);
  }
  EXPECT_EQ(shaders, 1);
}

TEST_F(FitRpcTest, ColourwaysOnAProductMeshBecomeVariantsPerPanel) {
  const std::string glb = ProductMesh();
  ASSERT_FALSE(glb.empty());
  assets::TriangleMesh product;
  ASSERT_EQ(assets::ParseMesh(glb, v1::MESH_FORMAT_GLB, {}, &product), "");
  ASSERT_GE(product.material_names.size(), 1u);
  v1::FitMaterialRequest request;
  request.set_target(v1::FIT_TARGET_GLTF_SHEEN);
  request.set_format(v1::EXPORT_FORMAT_GLB);
  request.set_name("drape");
  request.mutable_mesh()->mutable_data()->set_data(glb);
  for (const char* preset : {"silk_shot", "cotton_gingham"}) {
    v1::Colourway* way = request.add_colourways();
    way->set_name(std::string("way ") + preset);
    way->mutable_material()->set_preset(preset);
  }
  // The first colourway dresses the last panel in velvet: the file's default shows two fabrics.
  v1::MaterialBinding* binding = request.mutable_colourways(0)->add_bindings();
  binding->set_mesh_material(product.material_names.back());
  binding->mutable_material()->set_preset("velvet");
  v1::FitMaterialResponse response;
  const grpc::Status s = Fit(request, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  // One fit per colourway and panel; three distinct fabrics.
  ASSERT_GE(product.material_names.size(), 2u);
  ASSERT_EQ(size_t(response.fits_size()), 2 * product.material_names.size());
  EXPECT_EQ(response.fits(product.material_names.size() - 1).mesh_material(), product.material_names.back());
  EXPECT_NE(response.fits(0).fitted().SerializeAsString(),
            response.fits(product.material_names.size() - 1).fitted().SerializeAsString());
  EXPECT_EQ(response.fits(0).colourway(), "way silk_shot");
  EXPECT_EQ(response.fits(response.fits_size() - 1).colourway(), "way cotton_gingham");
  EXPECT_NE(response.fits(0).fitted().SerializeAsString(),
            response.fits(response.fits_size() - 1).fitted().SerializeAsString());
  // The file carries the product's own triangles, panel by panel (the default colourway's two fabrics), and a
  // variant per colourway.
  assets::TriangleMesh written;
  ASSERT_EQ(assets::ParseMesh(response.file(), v1::MESH_FORMAT_GLB, {}, &written), "");
  EXPECT_EQ(written.triangles.size(), product.triangles.size());
  EXPECT_EQ(written.material_names.size(), product.material_names.size());
  EXPECT_NE(response.file().find("KHR_materials_variants"), std::string::npos);
  EXPECT_NE(response.file().find("way cotton_gingham"), std::string::npos);
}

TEST_F(FitRpcTest, RefusesBadRequestsByField) {
  v1::FitMaterialRequest r = Request("silk_shot", v1::FIT_TARGET_UNSPECIFIED, v1::EXPORT_FORMAT_NONE);
  ExpectRefused(r, "target");
  ExpectRefused(Request("silk_shot", v1::FIT_TARGET_OPENPBR, v1::EXPORT_FORMAT_GLB), "format");
  ExpectRefused(Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_MTLX), "format");
  ExpectRefused(Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::ExportFormat(99)), "format");
  ExpectRefused(Request("no_such_preset", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_NONE), "material");
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_NONE);
  r.mutable_material()->Clear();
  r.mutable_material()->set_model("fiber");
  ExpectRefused(r, "fibre's axis");
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_NONE);
  r.clear_material();
  ExpectRefused(r, "material: unset");
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB);
  r.set_name(std::string(10000, 'x'));
  ExpectRefused(r, "name");
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB);
  v1::MaterialBinding* b = r.add_bindings();
  b->set_mesh_material("body");
  b->mutable_material()->set_preset("silk_shot");
  ExpectRefused(r, "bindings: bindings name mesh materials; give a mesh");
  r = Request("silk_shot", v1::FIT_TARGET_OPENPBR, v1::EXPORT_FORMAT_MTLX);
  r.mutable_mesh()->set_name("garment");
  ExpectRefused(r, "mesh");
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB);
  r.mutable_mesh()->set_name("../../etc/passwd");
  ExpectRefused(r, "mesh.name");
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB);
  r.mutable_mesh()->mutable_data()->set_data("not a mesh at all");
  ExpectRefused(r, "mesh.data");
  // Colourways: at most kMaxColourways, named once each, and they replace material.
  r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB);
  r.add_colourways()->set_name("red");
  ExpectRefused(r, "colourways: each colourway gives its fabrics");
  r.clear_material();
  r.clear_colourways();
  for (int c = 0; c <= api::kMaxColourways; ++c) {
    v1::Colourway* way = r.add_colourways();
    way->set_name("way " + std::to_string(c));
    way->mutable_material()->set_preset("silk_shot");
  }
  ExpectRefused(r, "colourways");
  r.mutable_colourways()->DeleteSubrange(2, r.colourways_size() - 2);
  r.mutable_colourways(1)->set_name("way 0");
  ExpectRefused(r, "colourways[1].name");
  r.mutable_colourways(1)->set_name("");
  ExpectRefused(r, "colourways[1].name: empty");
}

TEST_F(FitRpcTest, ABindingOfAMaterialTheMeshLacksIsRefusedByName) {
  v1::FitMaterialRequest r = Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_GLB);
  r.mutable_mesh()->mutable_data()->set_data(ProductMesh());
  v1::MaterialBinding* b = r.add_bindings();
  b->set_mesh_material("no such panel");
  b->mutable_material()->set_preset("cotton_twill");
  ExpectRefused(r, "bindings[0].mesh_material");
}

TEST_F(FitRpcTest, AnExpiredDeadlineStopsTheCallAndTheServerServesTheNext) {
  v1::FitMaterialRequest request;
  request.set_target(v1::FIT_TARGET_GLTF_SHEEN);
  for (int c = 0; c < api::kMaxColourways; ++c) {
    v1::Colourway* way = request.add_colourways();
    way->set_name("way " + std::to_string(c));
    way->mutable_material()->set_preset("silk_shot");
    v1::Param* p = way->mutable_material()->add_params();
    p->set_name("eta");
    p->add_values(1.3 + 0.01 * c);  // distinct fabrics: sixteen fits
  }
  v1::FitMaterialResponse response;
  const grpc::Status s = Fit(request, &response, std::chrono::milliseconds(1));
  EXPECT_EQ(s.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << s.error_message();
  v1::FitMaterialResponse next;
  EXPECT_TRUE(Fit(Request("silk_shot", v1::FIT_TARGET_GLTF_SHEEN, v1::EXPORT_FORMAT_NONE), &next).ok());
  EXPECT_EQ(next.fits_size(), 1);
}

}  // namespace
}  // namespace loomlight
