// The contract every registered render scene passes without test code of its own (issue 45, item 2), as every
// model passes tests/model_contract_test.cpp: GoogleTest parameterised over the scene registry
// (render::SceneRegistry::Global()), each case reading its scene as a real server's ListScenes describes it, so a
// new scene file is tested the moment it registers. Nothing here knows a scene's or a parameter's name: the
// material comes from what the scene needs (ListScenes: fibers, uv, transmission) and ListModels' capabilities, the
// parameters from the scene's schema.
//
// Per scene (suite SceneContract):
//   RendersFiniteAndDeterministic    a small render: every pixel finite and >= 0; the same seed the same bytes,
//                                    another seed other bytes.
//   NameAndPresetGiveIdenticalBytes  the scene by name (scene_name) and by its ScenePreset value: the same image.
//   EveryParameterAtItsBoundsRendersFinite  each declared parameter at its min and at its max, the two images
//                                    different (the scene uses it).
//   BadParametersAreRefusedNamingTheField   out of range, unknown, given twice: INVALID_ARGUMENT naming
//                                    scene_params[i] and the parameter.
//   CancellableAndTheServerServesOn  cancelled once samples are done, and past a deadline: the server ends the
//                                    call (counted CANCELLED / DEADLINE_EXCEEDED) and then renders another.
// And (suite ListScenesContract): ListScenes lists each registered scene once with its declarations, defaults
// within range, preset values that find the same scene; unknown scene names are refused echoing the name cut
// short; `loomlight scenes` lists them and `loomlight render --scene-param` reaches the server's checks.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/render/scene_registry.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using v1::RenderRequest;
using v1::RenderUpdate;

// One server for every case (kernels built once).
class ServerEnvironment : public ::testing::Environment {
 public:
  void SetUp() override {
    api::ServerOptions options;
    options.address = "127.0.0.1:0";
    options.metrics_address = "127.0.0.1:0";  // how calls ended (testing::WaitForCallsEnded)
    std::string error;
    server = api::LoomlightServer::Start(options, &error).release();
    ASSERT_NE(server, nullptr) << error;
  }
  void TearDown() override {
    delete server;
    server = nullptr;
  }
  static api::LoomlightServer* server;
};
api::LoomlightServer* ServerEnvironment::server = nullptr;
const auto* const kEnvironment = ::testing::AddGlobalTestEnvironment(new ServerEnvironment);

api::LoomlightServer& Server() { return *ServerEnvironment::server; }

struct Rendered {
  grpc::Status status;
  std::string image;  // the last update's
};

// Streams a render; `on_update` may cancel the call (it sees every update as it arrives).
Rendered Render(const RenderRequest& request, std::chrono::milliseconds timeout = std::chrono::seconds(300),
                std::function<void(grpc::ClientContext&, const RenderUpdate&)> on_update = {}) {
  const auto stub = testing::Connect(Server().port());
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + timeout);
  auto reader = stub->Render(&ctx, request);
  Rendered out;
  RenderUpdate update;
  while (reader->Read(&update)) {
    if (on_update) on_update(ctx, update);
    if (!update.image().empty()) out.image = update.image();
  }
  out.status = reader->Finish();
  return out;
}

v1::ListScenesResponse ListScenes() {
  grpc::ClientContext ctx;
  v1::ListScenesResponse response;
  const grpc::Status status = testing::Connect(Server().port())->ListScenes(&ctx, v1::ListScenesRequest(), &response);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return response;
}

// The first preset of the first model (ListModels' order) that `fits`, or "".
std::string PresetOf(const std::function<bool(const v1::ModelInfo&)>& fits) {
  grpc::ClientContext ctx;
  v1::ListModelsResponse models;
  EXPECT_TRUE(testing::Connect(Server().port())->ListModels(&ctx, v1::ListModelsRequest(), &models).ok());
  for (const v1::ModelInfo& model : models.models())
    if (fits(model) && !model.presets().empty()) return model.presets(0).name();
  return "";
}

// A material suited to what the scene shows: a fiber model on fibers; else a spatially varying one (its pattern
// shows) without transmission, with a transmitting layer where the scene is lit from behind.
v1::Material MaterialFor(const v1::SceneInfo& scene) {
  v1::Material material;
  if (scene.fibers()) {
    material.set_preset(PresetOf([](const v1::ModelInfo& m) { return !m.fiber_axis_param().empty(); }));
    return material;
  }
  material.set_preset(PresetOf([&](const v1::ModelInfo& m) {
    return m.fiber_axis_param().empty() && !m.transmission() && m.spatially_varying() == scene.needs_uv();
  }));
  if (scene.shows_transmission())
    material.mutable_transmission()->set_preset(PresetOf([](const v1::ModelInfo& m) { return m.transmission(); }));
  return material;
}

// ---- The registry's scenes ----

std::vector<std::string> RegisteredScenes() {
  std::vector<std::string> names;
  for (const render::SceneSpec& scene : render::SceneRegistry::Global().scenes()) names.push_back(scene.name);
  return names;
}

class SceneContract : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    const v1::ListScenesResponse scenes = ListScenes();
    for (const v1::SceneInfo& s : scenes.scenes())
      if (s.name() == GetParam()) scene_ = s;
    ASSERT_EQ(scene_.name(), GetParam()) << "ListScenes does not list the registered scene";
    material_ = MaterialFor(scene_);
    ASSERT_FALSE(material_.preset().empty()) << "no registered model suits the scene";
  }

  // The scene by name at 24 x 16, 2 samples per pixel, linear EXR.
  RenderRequest Request(uint64_t seed = 7) const {
    RenderRequest r;
    *r.mutable_material() = material_;
    r.set_scene_name(scene_.name());
    r.set_width(24);
    r.set_height(16);
    r.set_samples_per_pixel(2);
    r.set_format(v1::RENDER_FORMAT_EXR);
    r.set_seed(seed);
    return r;
  }

  // Renders; the status must be OK and every pixel finite and >= 0. Returns the image's bytes.
  std::string RenderFinite(const RenderRequest& request, const std::string& what) const {
    const Rendered r = Render(request);
    EXPECT_TRUE(r.status.ok()) << what << ": " << r.status.error_message();
    if (!r.status.ok()) return "";
    const testing::DecodedImage image = testing::DecodeImage(r.image, "scene.exr");
    EXPECT_EQ(image.width, 24);
    EXPECT_EQ(image.height, 16);
    size_t bad = 0;
    for (float v : image.pixels) bad += !(std::isfinite(v) && v >= 0);
    EXPECT_EQ(bad, 0u) << what << ": pixel values not finite or negative";
    return r.image;
  }

  v1::SceneInfo scene_;
  v1::Material material_;
};

TEST_P(SceneContract, RendersFiniteAndDeterministic) {
  const std::string first = RenderFinite(Request(7), "seed 7");
  ASSERT_FALSE(first.empty());
  EXPECT_EQ(RenderFinite(Request(7), "seed 7 again"), first) << "the same seed gave other bytes";
  EXPECT_NE(RenderFinite(Request(8), "seed 8"), first) << "another seed gave the same bytes";
}

TEST_P(SceneContract, NameAndPresetGiveIdenticalBytes) {
  if (render::SceneRegistry::Global().Find(scene_.name())->preset == render::SceneSpec::kNoPreset)
    GTEST_SKIP() << "named by scene_name only";
  RenderRequest by_preset = Request();
  by_preset.clear_scene_name();
  by_preset.set_scene(scene_.preset());
  const std::string by_name = RenderFinite(Request(), "by name");
  ASSERT_FALSE(by_name.empty());
  EXPECT_EQ(RenderFinite(by_preset, "by preset"), by_name);
}

TEST_P(SceneContract, EveryParameterAtItsBoundsRendersFinite) {
  for (const v1::ParamSchema& p : scene_.params()) {
    std::vector<std::string> images;
    for (double value : {p.min(), p.max()}) {
      RenderRequest r = Request();
      v1::Param* param = r.add_scene_params();
      param->set_name(p.name());
      for (uint32_t i = 0; i < std::max(p.min_count(), 1u); ++i) param->add_values(value);
      images.push_back(RenderFinite(r, p.name() + " = " + std::to_string(value)));
    }
    EXPECT_NE(images[0], images[1]) << p.name() << " at its min and its max gives the same image: unused";
  }
}

TEST_P(SceneContract, BadParametersAreRefusedNamingTheField) {
  const auto expect_refused = [&](const RenderRequest& r, const std::vector<std::string>& named) {
    const Rendered out = Render(r);
    EXPECT_EQ(out.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << out.status.error_message();
    for (const std::string& text : named)
      EXPECT_NE(out.status.error_message().find(text), std::string::npos)
          << "'" << out.status.error_message() << "' does not name " << text;
  };
  for (const v1::ParamSchema& p : scene_.params()) {
    const double span = std::max(p.max() - p.min(), 1.0);
    for (double value : {p.min() - span, p.max() + span, double(NAN)}) {
      RenderRequest bad = Request();
      v1::Param* param = bad.add_scene_params();
      param->set_name(p.name());
      param->add_values(value);
      expect_refused(bad, {"scene_params[0]", "'" + p.name() + "'"});
    }
    RenderRequest twice = Request();
    for (int i = 0; i < 2; ++i) {
      v1::Param* param = twice.add_scene_params();
      param->set_name(p.name());
      param->add_values(p.default_values(0));
    }
    expect_refused(twice, {"scene_params[1].name", "'" + p.name() + "'", "twice"});
  }
  RenderRequest unknown = Request();
  unknown.add_scene_params()->set_name(std::string(300, 'x'));
  unknown.mutable_scene_params(0)->add_values(1);
  expect_refused(unknown, {"scene_params[0].name", "'" + scene_.name() + "'", "(300 bytes)"});
}

TEST_P(SceneContract, CancellableAndTheServerServesOn) {
  // A render of kMaxRenderSamples (1024 x 1024 x 64), cancelled once the server reports samples done: the call
  // ends CANCELLED mid-render, and the server counts it ended.
  RenderRequest big = Request();
  big.set_width(1024);
  big.set_height(1024);
  big.set_samples_per_pixel(64);
  const int metrics = Server().metrics_port();
  const double cancelled = testing::CallsEnded(metrics, "Render", "CANCELLED");
  const Rendered cut = Render(big, std::chrono::seconds(300), [](grpc::ClientContext& ctx, const RenderUpdate& u) {
    if (u.samples_done() > 0) ctx.TryCancel();
  });
  EXPECT_EQ(cut.status.error_code(), grpc::StatusCode::CANCELLED) << cut.status.error_message();
  EXPECT_TRUE(testing::WaitForCallsEnded(metrics, "Render", "CANCELLED", cancelled + 1));
  // Its deadline passing ends it too (a second is a small part of 67 million samples traced on the host).
  const double late = testing::CallsEnded(metrics, "Render", "DEADLINE_EXCEEDED");
  const Rendered expired = Render(big, std::chrono::seconds(1));
  EXPECT_EQ(expired.status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << expired.status.error_message();
  EXPECT_TRUE(testing::WaitForCallsEnded(metrics, "Render", "DEADLINE_EXCEEDED", late + 1));
  RenderFinite(Request(), "after the cut calls");
}

std::string SceneName(const ::testing::TestParamInfo<std::string>& info) { return info.param; }

INSTANTIATE_TEST_SUITE_P(Registry, SceneContract, ::testing::ValuesIn(RegisteredScenes()), SceneName);

// ---- ListScenes ----

TEST(ListScenesContract, ListsEachRegisteredSceneOnceWithItsDeclarations) {
  const v1::ListScenesResponse response = ListScenes();
  std::vector<std::string> listed;
  std::set<int> presets;
  for (const v1::SceneInfo& scene : response.scenes()) {
    SCOPED_TRACE(scene.name());
    listed.push_back(scene.name());
    EXPECT_FALSE(scene.description().empty());
    EXPECT_FALSE(scene.objects().empty());
    EXPECT_EQ(scene.default_camera().position_size(), 3);
    EXPECT_GT(scene.default_camera().fov_deg(), 0);
    EXPECT_GT(scene.default_texture_scale(), 0);
    EXPECT_TRUE(scene.default_environment() || !scene.default_lights().empty()) << "no default lighting";
    EXPECT_FALSE(scene.fibers() && scene.needs_uv()) << "fibers have no texture coordinates";
    const render::SceneSpec* spec = render::SceneRegistry::Global().Find(scene.name());
    ASSERT_NE(spec, nullptr);
    // The preset is present exactly when the scene declares one (an absent one must not read as SCENE_SPHERE).
    EXPECT_EQ(scene.has_preset(), spec->preset != render::SceneSpec::kNoPreset);
    if (scene.has_preset()) {
      EXPECT_EQ(scene.preset(), spec->preset);
      const render::SceneSpec* by_preset = render::SceneRegistry::Global().FindPreset(scene.preset());
      ASSERT_NE(by_preset, nullptr);
      EXPECT_EQ(by_preset->name, scene.name()) << "the preset value names another scene";
      EXPECT_TRUE(presets.insert(scene.preset()).second) << "preset value listed twice";
      EXPECT_TRUE(v1::ScenePreset_IsValid(scene.preset()));
    }
    std::set<std::string> names;
    for (const v1::ParamSchema& p : scene.params()) {
      SCOPED_TRACE(p.name());
      EXPECT_TRUE(names.insert(p.name()).second) << "parameter declared twice";
      EXPECT_FALSE(p.description().empty());
      EXPECT_NE(p.type(), v1::ParamSchema::TYPE_TEXT);  // scene parameters are values
      EXPECT_LE(p.min_count(), static_cast<uint32_t>(p.default_values_size()));
      EXPECT_GE(p.max_count(), static_cast<uint32_t>(p.default_values_size()));
      EXPECT_LE(p.min(), p.max());
      for (double v : p.default_values()) {
        EXPECT_LE(p.min(), v);
        EXPECT_LE(v, p.max());
        if (p.type() == v1::ParamSchema::TYPE_INT) {
          EXPECT_EQ(v, std::floor(v));
        }
      }
    }
  }
  EXPECT_EQ(listed, RegisteredScenes()) << "ListScenes lists the registry's scenes once each, in its order";
  // Every ScenePreset value (the older RenderRequest.scene) is a listed scene's preset, present (has_preset()).
  const auto* preset_values = v1::ScenePreset_descriptor();
  for (int i = 0; i < preset_values->value_count(); ++i)
    EXPECT_EQ(presets.count(preset_values->value(i)->number()), 1u) << preset_values->value(i)->name();
  std::vector<std::string> sorted = listed;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(std::adjacent_find(sorted.begin(), sorted.end()), sorted.end()) << "a scene name listed twice";
}

TEST(ListScenesContract, UnknownSceneNamesAreRefusedCutShort) {
  RenderRequest r;
  r.mutable_material()->set_preset(PresetOf([](const v1::ModelInfo& m) { return m.fiber_axis_param().empty(); }));
  r.set_width(8);
  r.set_height(8);
  r.set_scene_name(std::string(5000, 'q'));
  const Rendered out = Render(r);
  EXPECT_EQ(out.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(out.status.error_message().rfind("scene_name: ", 0), 0u) << out.status.error_message();
  EXPECT_NE(out.status.error_message().find("(5000 bytes)"), std::string::npos) << out.status.error_message();
  EXPECT_LT(out.status.error_message().size(), 400u);
}

TEST(ListScenesContract, ClientListsScenesAndSendsSceneParameters) {
  std::string output;
  ASSERT_EQ(testing::RunClient(Server().port(), "scenes", &output), 0) << output;
  for (const std::string& name : RegisteredScenes()) EXPECT_NE(output.find("scene " + name + " "), std::string::npos) << output;
  // A scene parameter goes to the server, whose check names it.
  const render::SceneSpec& scene = render::SceneRegistry::Global().scenes().front();
  ASSERT_FALSE(scene.params.empty());
  const std::string bad = scene.params[0].name + "=" + std::to_string(scene.params[0].max + 1);
  EXPECT_EQ(testing::RunClient(Server().port(),
                               "render --preset " + PresetOf([](const v1::ModelInfo& m) { return m.fiber_axis_param().empty(); }) +
                                   " --scene " + scene.name + " --scene-param " + bad + " --size 8x8 --out /dev/null.png",
                               &output),
            1)
      << output;
  EXPECT_NE(output.find("scene_params[0]"), std::string::npos) << output;
}

}  // namespace
}  // namespace loomlight
