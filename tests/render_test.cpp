// Render end to end against an in-process server: images decode at the requested size in every format,
// the same seed gives the same bytes, the error against a many-sample reference falls with samples, a
// back-lit curtain is brighter with transmission, the fidelity chooser picks the BRDF far away and the
// BTF close up (and fewer tangent samples within the target; a curtain layer's knob too), cancellation stops the work, concurrent
// Evaluate calls are served during a render, every bad field is named; and `loomlight render`.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <future>
#include <numbers>
#include <random>
#include <sstream>
#include <thread>
#include <type_traits>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/render_rpc.h"
#include "server/api/server.h"
#include "server/models/material_cache.h"
#include "server/render/environment.h"
#include "server/render/fidelity.h"
#include "server/render/shading.h"
#include "server/yarn/fiber_scene.h"
#include "tests/testing.h"

// After the protobuf headers: OpenImageIO's byte-swap macros clash with protobuf's port.h.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace loomlight {
namespace {

using v1::RenderRequest;
using v1::RenderUpdate;

// Appends values to a repeated field (this protobuf has no initializer-list Add).
template <class T>
void Append(google::protobuf::RepeatedField<T>* field, std::type_identity_t<std::initializer_list<T>> values) {
  for (T v : values) field->Add(v);
}

RenderRequest Request(const std::string& preset, v1::ScenePreset scene, uint32_t width, uint32_t height, uint32_t spp,
                      v1::RenderFormat format = v1::RENDER_FORMAT_EXR) {
  RenderRequest r;
  r.mutable_material()->set_preset(preset);
  r.set_scene(scene);
  r.set_width(width);
  r.set_height(height);
  r.set_samples_per_pixel(spp);
  r.set_format(format);
  r.set_seed(7);
  return r;
}

struct Rendered {
  grpc::Status status;
  std::vector<RenderUpdate> updates;  // without the image bytes, except the last
  const RenderUpdate& last() const { return updates.back(); }
};

// Streams a render; `on_update` may cancel the call (it sees every update as it arrives).
Rendered Render(v1::Loomlight::Stub& stub, const RenderRequest& request,
                std::chrono::milliseconds timeout = std::chrono::seconds(300),
                std::function<void(grpc::ClientContext&, const RenderUpdate&)> on_update = {}) {
  Rendered out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + timeout);
  auto reader = stub.Render(&ctx, request);
  RenderUpdate update;
  while (reader->Read(&update)) {
    if (on_update) on_update(ctx, update);
    out.updates.push_back(update);
  }
  out.status = reader->Finish();
  return out;
}

// The linear image of an EXR render.
std::vector<float> Linear(v1::Loomlight::Stub& stub, const RenderRequest& request) {
  const Rendered r = Render(stub, request);
  EXPECT_TRUE(r.status.ok()) << r.status.error_message();
  if (!r.status.ok()) return {};
  return testing::DecodeImage(r.last().image(), "render.exr").pixels;
}

double RelativeRmse(const std::vector<float>& image, const std::vector<float>& reference) {
  double diff = 0, total = 0;
  for (size_t i = 0; i < reference.size(); ++i) {
    diff += (image[i] - reference[i]) * double(image[i] - reference[i]);
    total += reference[i] * double(reference[i]);
  }
  return std::sqrt(diff / total);
}

const v1::FidelityChoice* Choice(const v1::ObjectFidelity& object, const std::string& aspect) {
  for (const v1::FidelityChoice& c : object.choices())
    if (c.aspect() == aspect) return &c;
  return nullptr;
}

class RenderTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    api::ServerOptions options;
    options.address = "127.0.0.1:0";
    options.metrics_address = "127.0.0.1:0";  // tests read how calls ended (testing::WaitForCallsEnded)
    std::string error;
    server_ = api::LoomlightServer::Start(options, &error).release();
    ASSERT_NE(server_, nullptr) << error;
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  static api::LoomlightServer* server_;
  std::unique_ptr<v1::Loomlight::Stub> stub_ = testing::Connect(server_->port());
};
api::LoomlightServer* RenderTest::server_ = nullptr;

TEST_F(RenderTest, ImagesDecodeAtTheRequestedSizeWithProgress) {
  const std::pair<v1::RenderFormat, const char*> formats[] = {
      {v1::RENDER_FORMAT_PNG, "r.png"}, {v1::RENDER_FORMAT_JPEG, "r.jpg"}, {v1::RENDER_FORMAT_EXR, "r.exr"}};
  for (const auto& [format, name] : formats) {
    const Rendered r = Render(*stub_, Request("silk_shot", v1::SCENE_SPHERE, 40, 28, 2, format));
    ASSERT_TRUE(r.status.ok()) << name << ": " << r.status.error_message();
    const RenderUpdate& last = r.last();
    const testing::DecodedImage image = testing::DecodeImage(last.image(), name);
    EXPECT_EQ(image.width, 40) << name;
    EXPECT_EQ(image.height, 28) << name;
    EXPECT_EQ(image.channels, 3) << name;
    EXPECT_EQ(last.samples_total(), 40u * 28 * 2);
    EXPECT_EQ(last.samples_done(), last.samples_total());
    uint64_t previous = 0;
    for (const RenderUpdate& u : r.updates) {
      EXPECT_GE(u.samples_done(), previous);
      previous = u.samples_done();
    }
    EXPECT_EQ(r.updates.front().fidelity_size(), 1);  // the sphere
    EXPECT_EQ(last.fidelity_size(), 1);
    EXPECT_GT(last.queries(), 0u);
    EXPECT_GT(last.total_seconds(), 0);
    ASSERT_EQ(last.mean_size(), 3);
    for (double m : last.mean()) EXPECT_TRUE(std::isfinite(m) && m > 0) << m;
    if (format == v1::RENDER_FORMAT_EXR) {
      for (float v : image.pixels) ASSERT_TRUE(std::isfinite(v) && v >= 0) << v;
      EXPECT_EQ(last.exposure(), 1.0);
    } else {
      EXPECT_GT(last.exposure(), 0);
    }
  }
}

TEST_F(RenderTest, SameSeedGivesIdenticalBytesAndAnotherSeedDoesNot) {
  RenderRequest request = Request("polyester_satin_charmeuse_front", v1::SCENE_CYLINDERS, 48, 32, 3, v1::RENDER_FORMAT_PNG);
  const Rendered a = Render(*stub_, request), b = Render(*stub_, request);
  ASSERT_TRUE(a.status.ok() && b.status.ok()) << a.status.error_message() << b.status.error_message();
  EXPECT_EQ(a.last().image(), b.last().image());
  request.set_seed(8);
  const Rendered c = Render(*stub_, request);
  ASSERT_TRUE(c.status.ok());
  EXPECT_NE(a.last().image(), c.last().image());
}

TEST_F(RenderTest, ErrorAgainstAReferenceFallsAsSamplesGrow) {
  // The swatch under the built-in sky (environment importance sampling and pixel jitter are the noise).
  RenderRequest request = Request("linen_plain", v1::SCENE_SWATCH, 32, 32, 256);
  const std::vector<float> reference = Linear(*stub_, request);
  ASSERT_FALSE(reference.empty());
  double errors[3];
  const uint32_t samples[3] = {4, 16, 64};
  for (int i = 0; i < 3; ++i) {
    request.set_samples_per_pixel(samples[i]);
    request.set_seed(100 + i);  // independent of the reference's samples
    const std::vector<float> image = Linear(*stub_, request);
    ASSERT_EQ(image.size(), reference.size());
    errors[i] = RelativeRmse(image, reference);
    std::printf("%u samples per pixel: relative RMSE %.4f against 256\n", samples[i], errors[i]);
  }
  EXPECT_LT(errors[1], errors[0]);
  EXPECT_LT(errors[2], errors[1]);
  // Monte Carlo: the error of N samples against an independent reference of 256 falls like
  // sqrt(1/N + 1/256); from 4 to 64 samples that is a factor of about 3.5. Ask for 2.
  EXPECT_LT(errors[2], errors[0] / 2);
}

TEST_F(RenderTest, BackLitCurtainIsBrighterWithTransmission) {
  RenderRequest with_layer = Request("linen_plain", v1::SCENE_CURTAIN, 32, 40, 4);
  with_layer.mutable_material()->mutable_transmission()->set_preset("cotton_curtain");
  const Rendered lit = Render(*stub_, with_layer);
  ASSERT_TRUE(lit.status.ok()) << lit.status.error_message();
  RenderRequest without = with_layer;
  without.mutable_material()->clear_transmission();
  const Rendered unlit = Render(*stub_, without);
  ASSERT_TRUE(unlit.status.ok()) << unlit.status.error_message();
  const v1::FidelityChoice* transmission = Choice(lit.last().fidelity(0), "transmission");
  ASSERT_NE(transmission, nullptr);
  EXPECT_EQ(transmission->chosen(), "on") << transmission->reason();
  double brighter = 0, darker = 0;
  for (int c = 0; c < 3; ++c) {
    brighter += lit.last().mean(c);
    darker += unlit.last().mean(c);
  }
  std::printf("curtain mean radiance: %.4f with transmission, %.4f without\n", brighter, darker);
  EXPECT_GT(brighter, 1.5 * darker);

  // Lit only from the front, the chooser leaves the transmission out and says why.
  RenderRequest front = with_layer;
  v1::RenderLight* light = front.add_lights();
  light->add_direction(0.2);
  light->add_direction(0.3);
  light->add_direction(1);
  for (int c = 0; c < 3; ++c) light->add_rgb(3);
  const Rendered front_lit = Render(*stub_, front);
  ASSERT_TRUE(front_lit.status.ok()) << front_lit.status.error_message();
  const v1::FidelityChoice* off = Choice(front_lit.last().fidelity(0), "transmission");
  ASSERT_NE(off, nullptr);
  EXPECT_EQ(off->chosen(), "off");
  EXPECT_EQ(off->estimated_error(), 0);
  EXPECT_NE(off->reason().find("back"), std::string::npos) << off->reason();
}

// The curtain scene with its default lighting (a low sun behind it and the built-in sky), as Render sets it up.
render::RenderSetup CurtainSetup(int width, int height) {
  render::RenderSetup setup;
  setup.scene = render::MakeScene(render::SceneKind::kCurtain);
  setup.width = width;
  setup.height = height;
  setup.camera = render::PinholeCamera(setup.scene.default_camera, width, height);
  setup.lights = setup.scene.default_lights;
  auto sky = std::make_shared<render::Environment>(render::Environment::Builtin());
  sky->SetTransform(setup.scene.default_environment_intensity, 0);
  setup.environment = std::move(sky);
  setup.texture_scale = setup.scene.default_texture_scale;
  setup.seed = 7;
  setup.object_transmits.assign(setup.scene.objects.size(), true);
  return setup;
}

// A back-lit curtain's layer knob (its model's declared accuracy knob, whichever it is): within a loose target
// the chooser takes a setting cheaper than the exact one, reports it with its measured error within the target,
// and renders with it; force_full_fidelity keeps the exact setting.
TEST(FidelityChooser, CurtainLayerKnobIsTheCheapestWithinTheTarget) {
  v1::Material material;
  material.set_preset("linen_plain");
  material.mutable_transmission()->set_preset("cotton_curtain");
  models::MaterialCache cache(size_t{256} << 20);
  render::CachedVariants variants(material, models::Registry::Global(), cache);
  const models::PreparedMaterial* requested = variants.Requested();
  ASSERT_NE(requested, nullptr);
  ASSERT_NE(requested->transmission, nullptr);
  const models::AccuracyKnob knob = requested->transmission->model->accuracy_knob();
  ASSERT_GE(knob.settings.size(), 2u) << "the layer's model declares no knob to choose from";
  const std::string aspect = "transmission." + knob.param;
  const render::MaterialInfo info{requested->model, requested->values, true};
  const render::RenderSetup setup = CurtainSetup(32, 40);
  // The index of the setting the plan renders the (only) object's layer with.
  const auto rendered_setting = [&](const render::FidelityPlan& plan) {
    const models::PreparedMaterial* m = plan.evaluators[plan.objects[0].evaluator].material;
    const double value = m->transmission->values.at(knob.param).at(0);
    return std::find(knob.settings.begin(), knob.settings.end(), value) - knob.settings.begin();
  };
  const auto layer_choice = [&](const render::FidelityPlan& plan) -> const render::FidelityChoice* {
    for (const render::FidelityChoice& c : plan.fidelity[0].choices)
      if (c.aspect == aspect) return &c;
    return nullptr;
  };

  constexpr double kLooseTarget = 0.5;
  render::FidelityPlan loose;
  ASSERT_EQ(render::ChooseFidelity(setup, info, variants, kLooseTarget, false, &loose), "");
  const render::FidelityChoice* chosen = layer_choice(loose);
  ASSERT_NE(chosen, nullptr);
  for (const render::FidelityChoice& c : loose.fidelity[0].choices)
    std::printf("%s: %s (full %s), estimated error %.3g: %s\n", c.aspect.c_str(), c.chosen.c_str(), c.full.c_str(),
                c.estimated_error, c.reason.c_str());
  EXPECT_LT(rendered_setting(loose), static_cast<long>(knob.settings.size()) - 1);
  EXPECT_NE(chosen->chosen, chosen->full);
  EXPECT_GT(chosen->estimated_error, 0);  // the back-lit curtain's light goes through the layer
  EXPECT_LE(chosen->estimated_error, kLooseTarget);

  // A target below that error takes a costlier setting: the choice is measured, not assumed.
  render::FidelityPlan tight;
  ASSERT_EQ(render::ChooseFidelity(setup, info, variants, chosen->estimated_error / 2, false, &tight), "");
  EXPECT_GT(rendered_setting(tight), rendered_setting(loose));

  render::FidelityPlan full;
  ASSERT_EQ(render::ChooseFidelity(setup, info, variants, kLooseTarget, true, &full), "");
  ASSERT_NE(layer_choice(full), nullptr);
  EXPECT_EQ(layer_choice(full)->chosen, layer_choice(full)->full);
  EXPECT_EQ(layer_choice(full)->estimated_error, 0);
  EXPECT_EQ(rendered_setting(full), static_cast<long>(knob.settings.size()) - 1);
}

// End to end: a curtain render reports its layer's knob choice, and force_full_fidelity keeps it exact.
TEST_F(RenderTest, CurtainRenderReportsItsLayerKnob) {
  RenderRequest request = Request("linen_plain", v1::SCENE_CURTAIN, 32, 40, 2);
  request.mutable_material()->mutable_transmission()->set_preset("cotton_curtain");
  request.set_error_target(0.5);
  for (const bool force_full : {false, true}) {
    request.set_force_full_fidelity(force_full);
    const Rendered r = Render(*stub_, request);
    ASSERT_TRUE(r.status.ok()) << r.status.error_message();
    ASSERT_EQ(r.last().fidelity_size(), 1);
    const v1::FidelityChoice* layer = nullptr;
    for (const v1::FidelityChoice& c : r.last().fidelity(0).choices())
      if (c.aspect().rfind("transmission.", 0) == 0) layer = &c;
    ASSERT_NE(layer, nullptr) << "no transmission.<knob> choice reported";
    if (force_full) {
      EXPECT_EQ(layer->chosen(), layer->full());
    } else {
      EXPECT_NE(layer->chosen(), layer->full()) << layer->reason();
      EXPECT_LE(layer->estimated_error(), 0.5);
    }
  }
}

TEST_F(RenderTest, ChooserPicksTheBrdfForADistantSwatchAndTheBtfForACloseUp) {
  RenderRequest distant = Request("cotton_twill", v1::SCENE_SWATCH, 64, 64, 1);
  distant.set_texture_scale(40);  // 160 threads per unit; the swatch covers about 40 pixels
  Append(distant.mutable_camera()->mutable_position(), {0, 3.5, 4});
  Append(distant.mutable_camera()->mutable_look_at(), {0, 0, 0});
  const Rendered far = Render(*stub_, distant);
  ASSERT_TRUE(far.status.ok()) << far.status.error_message();
  const v1::ObjectFidelity& far_fidelity = far.last().fidelity(0);
  std::printf("distant: %.3g pixels per thread, %s\n", far_fidelity.pixels_per_thread(),
              Choice(far_fidelity, "path")->reason().c_str());
  EXPECT_LT(far_fidelity.pixels_per_thread(), 1);
  EXPECT_EQ(Choice(far_fidelity, "path")->chosen(), "BRDF");
  EXPECT_LE(far_fidelity.estimated_error(), far.last().error_target());

  RenderRequest close = Request("cotton_twill", v1::SCENE_SWATCH, 64, 64, 1);
  close.set_texture_scale(2);
  Append(close.mutable_camera()->mutable_position(), {0, 0.5, 0.6});
  Append(close.mutable_camera()->mutable_look_at(), {0, 0, 0});
  const Rendered near = Render(*stub_, close);
  ASSERT_TRUE(near.status.ok()) << near.status.error_message();
  const v1::ObjectFidelity& near_fidelity = near.last().fidelity(0);
  std::printf("close-up: %.3g pixels per thread, %s\n", near_fidelity.pixels_per_thread(),
              Choice(near_fidelity, "path")->reason().c_str());
  EXPECT_GT(near_fidelity.pixels_per_thread(), 1);
  EXPECT_EQ(Choice(near_fidelity, "path")->chosen(), "BTF");

  // Forcing full fidelity renders the far swatch with the BTF as well, and costs BTF queries.
  distant.set_force_full_fidelity(true);
  const Rendered forced = Render(*stub_, distant);
  ASSERT_TRUE(forced.status.ok());
  EXPECT_EQ(Choice(forced.last().fidelity(0), "path")->chosen(), "BTF");
  EXPECT_EQ(forced.last().fidelity(0).estimated_error(), 0);
}

TEST_F(RenderTest, ChooserUsesFewerTangentSamplesWithinTheTarget) {
  RenderRequest request = Request("polyester_satin_charmeuse_front", v1::SCENE_CYLINDERS, 64, 48, 1);
  const Rendered chosen = Render(*stub_, request);
  ASSERT_TRUE(chosen.status.ok()) << chosen.status.error_message();
  ASSERT_EQ(chosen.last().fidelity_size(), 3);  // three cylinders
  for (const v1::ObjectFidelity& object : chosen.last().fidelity()) {
    const v1::FidelityChoice* t = Choice(object, "tangent_samples");
    ASSERT_NE(t, nullptr) << object.object();
    std::printf("%s: tangent samples %s (%s)\n", object.object().c_str(), t->chosen().c_str(), t->reason().c_str());
    EXPECT_EQ(t->full(), "256");
    EXPECT_LT(std::stoi(t->chosen()), 256);
    EXPECT_LE(t->estimated_error(), chosen.last().error_target());
    EXPECT_GT(t->estimated_error(), 0);
  }
  // A tighter target takes more samples; force_full_fidelity takes the schema's maximum.
  request.set_error_target(0.002);
  const Rendered tight = Render(*stub_, request);
  ASSERT_TRUE(tight.status.ok());
  EXPECT_GT(std::stoi(Choice(tight.last().fidelity(0), "tangent_samples")->chosen()),
            std::stoi(Choice(chosen.last().fidelity(0), "tangent_samples")->chosen()));
  request.set_force_full_fidelity(true);
  const Rendered full = Render(*stub_, request);
  ASSERT_TRUE(full.status.ok());
  for (const v1::ObjectFidelity& object : full.last().fidelity())
    EXPECT_EQ(Choice(object, "tangent_samples")->chosen(), "256");
}

TEST_F(RenderTest, CancelledRenderStopsEarly) {
  // 512 x 512 x 64 samples, cancelled once a fifth of the samples are done (the top rows are background, which
  // needs no queries). The whole render's queries: 64 times those of the same view at 1 sample per pixel.
  const RenderRequest big = Request("linen_plain", v1::SCENE_CYLINDERS, 512, 512, 64);
  uint64_t before = server_->metrics().rendered_queries();
  RenderRequest one = big;
  one.set_samples_per_pixel(1);
  one.set_sampling(v1::SAMPLING_UNIFORM);
  ASSERT_TRUE(Render(*stub_, one).status.ok());
  const uint64_t total = 64 * (server_->metrics().rendered_queries() - before);
  before = server_->metrics().rendered_queries();
  // Cancelled at the first update past a fifth that follows some shading work (the first fifth may be all
  // background, which the server skips without queries). What the mechanism guarantees, whatever the machine's
  // speed: the server ends the call once its chunk in flight is back and counts nothing after, so once the call
  // is counted CANCELLED the query count never grows again, short of the whole render.
  const double cancelled_before = testing::CallsEnded(server_->metrics_port(), "Render", "CANCELLED");
  const Rendered r = Render(*stub_, big, std::chrono::seconds(300), [&](grpc::ClientContext& ctx, const RenderUpdate& u) {
    if (u.samples_done() * 5 >= u.samples_total() && server_->metrics().rendered_queries() > before) ctx.TryCancel();
  });
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::CANCELLED) << r.status.error_message();
  ASSERT_TRUE(testing::WaitForCallsEnded(server_->metrics_port(), "Render", "CANCELLED", cancelled_before + 1));
  const uint64_t done = server_->metrics().rendered_queries() - before;
  std::printf("cancelled render: %llu queries of about %llu\n", (unsigned long long)done, (unsigned long long)total);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_EQ(server_->metrics().rendered_queries() - before, done) << "queries counted after the call ended";
  EXPECT_GT(done, 0u);
  EXPECT_LT(done, total);

  // A short deadline ends a render too, and the server keeps serving.
  const Rendered late = Render(*stub_, big, std::chrono::milliseconds(300));
  EXPECT_EQ(late.status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << late.status.error_message();
  EXPECT_TRUE(Render(*stub_, Request("velvet", v1::SCENE_SPHERE, 8, 8, 1)).status.ok());
}

// A fiber scene's deadline stops its yarn's generation and BVH build, not only the tracing: a heavy woven
// patch (14,400 fibers, about 1.4 million control points) asked with a 30 ms deadline ends well before its set-up
// alone would, without a single query, and the server keeps serving.
TEST_F(RenderTest, FiberSceneDeadlineStopsGenerationAndTheBuild) {
  RenderRequest heavy = Request("cotton", v1::SCENE_WOVEN_PATCH, 16, 16, 1);
  heavy.set_fiber_detail(v1::FIBER_DETAIL_FULL);
  v1::Param* fibers = heavy.mutable_yarn()->add_params();
  fibers->set_name("fibers_per_ply");
  fibers->add_values(400);
  const Rendered whole = Render(*stub_, heavy);
  ASSERT_TRUE(whole.status.ok()) << whole.status.error_message();
  const double setup = whole.last().setup_seconds();
  std::printf("heavy fiber scene: set-up %.3f s\n", setup);  // ~1 s here: the deadline lands inside it

  const uint64_t before = server_->metrics().rendered_queries();
  const double late_before = testing::CallsEnded(server_->metrics_port(), "Render", "DEADLINE_EXCEEDED");
  heavy.mutable_yarn()->set_seed(2);  // other fibers: the first call's scene is kept (FiberSceneCache)
  const Rendered late = Render(*stub_, heavy, std::chrono::milliseconds(30));
  EXPECT_EQ(late.status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << late.status.error_message();
  // Right after, a small fiber scene: its set-up waits for the geometry worker, which would still be busy with
  // the heavy yarn had the deadline not stopped it.
  const Rendered next = Render(*stub_, Request("cotton", v1::SCENE_YARN, 8, 8, 1));
  ASSERT_TRUE(next.status.ok()) << next.status.error_message();
  std::printf("after the deadline: the next fiber scene's set-up %.3f s\n", next.last().setup_seconds());
  // And the heavy scene never traced a ray: the only queries since are the small one's, once the server has
  // ended the late call (it does when its set-up task has stopped).
  ASSERT_TRUE(testing::WaitForCallsEnded(server_->metrics_port(), "Render", "DEADLINE_EXCEEDED", late_before + 1));
  EXPECT_EQ(server_->metrics().rendered_queries() - before, next.last().queries());
}

TEST_F(RenderTest, EvaluateIsServedWhileARenderRuns) {
  std::atomic<bool> stop{false};
  auto render = std::async(std::launch::async, [&] {
    return Render(*stub_, Request("linen_plain", v1::SCENE_CYLINDERS, 512, 512, 64), std::chrono::seconds(300),
                  [&](grpc::ClientContext& ctx, const RenderUpdate&) {
                    if (stop) ctx.TryCancel();
                  });
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  v1::EvaluateRequest e;
  e.mutable_material()->set_preset("silk_shot");
  for (int q = 0; q < 64; ++q) Append(e.mutable_wi(), {0, 0, 1}), Append(e.mutable_wo(), {0.6f, 0, 0.8f});
  double slowest = 0;
  for (int i = 0; i < 10; ++i) {
    grpc::ClientContext ctx;
    v1::EvaluateResponse response;
    const auto start = std::chrono::steady_clock::now();
    ASSERT_TRUE(testing::Connect(server_->port())->Evaluate(&ctx, e, &response).ok());
    slowest = std::max(slowest, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  stop = true;
  const Rendered r = render.get();
  // Reported, not asserted (a time): one render chunk (at most 262,144 queries, ~0.1 s here) runs ahead of a
  // call at most; batcher_test asserts the order that guarantees it.
  std::printf("slowest of 10 Evaluate calls during a render: %.3f s\n", slowest);
  EXPECT_NE(r.status.error_code(), grpc::StatusCode::INTERNAL);
}

TEST_F(RenderTest, EveryInvalidFieldIsNamed) {
  struct Case {
    const char* field;
    std::function<void(RenderRequest&)> change;
  };
  const Case cases[] = {
      {"material.preset", [](auto& r) { r.mutable_material()->set_preset("no_such_cloth"); }},
      {"material.transmission", [](auto& r) { r.mutable_material()->mutable_transmission()->set_preset("velvet"); }},
      {"scene", [](auto& r) { r.set_scene(static_cast<v1::ScenePreset>(9)); }},
      {"texture_scale", [](auto& r) { r.set_texture_scale(-1); }},
      {"texture_scale", [](auto& r) { r.set_texture_scale(NAN); }},
      {"texture_rotation_deg", [](auto& r) { r.set_texture_rotation_deg(INFINITY); }},
      {"lights", [](auto& r) { for (int i = 0; i < 17; ++i) Append(r.add_lights()->mutable_rgb(), {1, 1, 1}); }},
      {"lights[0].rgb", [](auto& r) { Append(r.add_lights()->mutable_rgb(), {1, 1}); }},
      {"lights[0].rgb[1]", [](auto& r) { Append(r.add_lights()->mutable_rgb(), {1, -1, 1}); }},
      {"lights[0].direction", [](auto& r) {
         auto* l = r.add_lights();
         Append(l->mutable_rgb(), {1, 1, 1});
         Append(l->mutable_direction(), {0, 0, 0});
       }},
      {"lights[0].position[2]", [](auto& r) {
         auto* l = r.add_lights();
         l->set_type(v1::RenderLight::TYPE_POINT);
         Append(l->mutable_rgb(), {1, 1, 1});
         Append(l->mutable_position(), {0, 0, NAN});
       }},
      {"lights[0].type", [](auto& r) { r.add_lights()->set_type(static_cast<v1::RenderLight::Type>(5)); }},
      {"environment.intensity", [](auto& r) { r.mutable_environment()->set_intensity(-2); }},
      {"environment.rotation_deg", [](auto& r) { r.mutable_environment()->set_rotation_deg(NAN); }},
      {"environment.path", [](auto& r) { r.mutable_environment()->set_path("/no/such/sky.exr"); }},
      {"camera.position", [](auto& r) { Append(r.mutable_camera()->mutable_look_at(), {0, 0, 0}); }},
      {"camera.look_at", [](auto& r) {
         Append(r.mutable_camera()->mutable_position(), {1, 2, 3});
         Append(r.mutable_camera()->mutable_look_at(), {1, 2, 3});
       }},
      {"camera.up", [](auto& r) {
         Append(r.mutable_camera()->mutable_position(), {0, 5, 0});
         Append(r.mutable_camera()->mutable_look_at(), {0, 0, 0});
       }},
      {"camera.fov_deg", [](auto& r) {
         Append(r.mutable_camera()->mutable_position(), {0, 0, 5});
         Append(r.mutable_camera()->mutable_look_at(), {0, 0, 0});
         r.mutable_camera()->set_fov_deg(179);
       }},
      {"width", [](auto& r) { r.set_width(0); }},
      {"width", [](auto& r) { r.set_width(api::kMaxRenderSide + 1); }},
      {"height", [](auto& r) { r.set_height(100000); }},
      {"samples_per_pixel", [](auto& r) { r.set_samples_per_pixel(api::kMaxRenderSamplesPerPixel + 1); }},
      {"samples_per_pixel", [](auto& r) {  // each within its limit, the product not
         r.set_width(2048);
         r.set_height(2048);
         r.set_samples_per_pixel(32);
       }},
      {"format", [](auto& r) { r.set_format(static_cast<v1::RenderFormat>(7)); }},
      {"exposure", [](auto& r) { r.set_exposure(-1); }},
      {"error_target", [](auto& r) { r.set_error_target(2); }},
      {"error_target", [](auto& r) { r.set_error_target(NAN); }},
      {"precision", [](auto& r) { r.set_precision(static_cast<v1::Precision>(5)); }},
      {"fiber_detail", [](auto& r) { r.set_fiber_detail(static_cast<v1::FiberDetail>(9)); }},
      {"fiber_detail", [](auto& r) { r.set_fiber_detail(v1::FIBER_DETAIL_CORES); }},  // not a fiber scene
      {"fiber_shadows", [](auto& r) { r.set_fiber_shadows(static_cast<v1::FiberShadows>(9)); }},
      {"fiber_shadows", [](auto& r) { r.set_fiber_shadows(v1::FIBER_SHADOWS_SLICES); }},  // not a fiber scene
      {"fiber_occlusion", [](auto& r) { r.set_fiber_occlusion(static_cast<v1::FiberOcclusion>(-2)); }},
      {"fiber_occlusion", [](auto& r) { r.set_fiber_occlusion(v1::FIBER_OCCLUSION_TEXTURE); }},
      {"ambient", [](auto& r) { r.set_ambient(NAN); }},
      {"yarn", [](auto& r) { r.mutable_yarn()->set_preset("cotton1"); }},  // not a fiber scene
      {"woven", [](auto& r) { r.mutable_woven()->mutable_weave()->set_preset("cotton_twill"); }},
      // Fiber scenes: the yarn's own fields, its layout's, and a material that is not a fiber model.
      {"yarn.preset", [](auto& r) {
         r.set_scene(v1::SCENE_YARN);
         r.mutable_yarn()->set_preset("no_such_yarn");
       }},
      {"woven.weave.preset", [](auto& r) {
         r.set_scene(v1::SCENE_WOVEN_PATCH);
         r.mutable_woven()->mutable_weave()->set_preset("no_such_weave");
       }},
      {"woven", [](auto& r) {
         r.set_scene(v1::SCENE_YARN);
         r.mutable_woven()->mutable_weave()->set_preset("cotton_twill");
       }},
      {"yarn", [](auto& r) {  // more fibers than Render generates
         r.set_scene(v1::SCENE_YARN);
         r.mutable_material()->set_preset("cotton");
         v1::Param* p = r.mutable_yarn()->add_params();
         p->set_name("fibers_per_ply");
         p->add_values(20000);
         p = r.mutable_yarn()->add_params();
         p->set_name("plies");
         p->add_values(12);
         r.set_fiber_detail(v1::FIBER_DETAIL_FULL);
       }},
      {"material", [](auto& r) { r.set_scene(v1::SCENE_YARN); }},  // linen_plain is a surface model
  };
  for (const Case& c : cases) {
    RenderRequest request = Request("linen_plain", v1::SCENE_SPHERE, 8, 8, 1);
    c.change(request);
    const Rendered r = Render(*stub_, request);
    EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field << ": " << r.status.error_message();
    EXPECT_EQ(r.status.error_message().rfind(std::string(c.field) + ":", 0), 0u)
        << "expected the message to start with '" << c.field << ":', got: " << r.status.error_message();
  }
  // The limits themselves are accepted: the most samples per pixel, 16 lights.
  RenderRequest edge = Request("linen_plain", v1::SCENE_SPHERE, 2, 1, api::kMaxRenderSamplesPerPixel);
  for (int i = 0; i < api::kMaxRenderLights; ++i) {
    v1::RenderLight* l = edge.add_lights();
    Append(l->mutable_rgb(), {0.1, 0.1, 0.1});
    Append(l->mutable_direction(), {0, 0, 1});
  }
  EXPECT_TRUE(Render(*stub_, edge).status.ok());
}

TEST_F(RenderTest, EnvironmentMapSentAsBytesLightsTheScene) {
  // A small EXR sky written with OpenImageIO: bright top half, black bottom half; its bytes go in the request.
  const std::string path = ::testing::TempDir() + "/render_sky.exr";
  std::vector<float> sky(16 * 8 * 3, 0.0f);
  for (int i = 0; i < 16 * 4 * 3; ++i) sky[i] = 1.0f;
  auto out = OIIO::ImageOutput::create(path);
  ASSERT_TRUE(out);
  ASSERT_TRUE(out->open(path, OIIO::ImageSpec(16, 8, 3, OIIO::TypeDesc::FLOAT)));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, sky.data()));
  out->close();
  RenderRequest request = Request("linen_plain", v1::SCENE_SPHERE, 24, 24, 4);
  std::ifstream file(path, std::ios::binary);
  std::stringstream bytes;
  bytes << file.rdbuf();
  request.mutable_environment()->set_data(bytes.str());
  const Rendered r = Render(*stub_, request);
  ASSERT_TRUE(r.status.ok()) << r.status.error_message();
  const testing::DecodedImage image = testing::DecodeImage(r.last().image(), "r.exr");
  // The top of the sphere faces the sky, its bottom the black ground (means over 5 x 3 pixels: single pixels at
  // 4 samples are too noisy to compare).
  const auto patch = [&](int y0) {
    double sum = 0;
    for (int y = y0; y < y0 + 3; ++y)
      for (int x = 10; x < 15; ++x) sum += image.pixels[3 * (y * 24 + x) + 1];
    return sum / 15;
  };
  EXPECT_GT(patch(3), 4 * patch(19) + 1e-4);  // converged: 0.22 and 0.04
}

TEST_F(RenderTest, ClientWritesTheImageWithProgress) {
  const std::string path = ::testing::TempDir() + "/render_client.png";
  std::remove(path.c_str());
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->port(),
                      "render --preset silk_shot --scene cylinders --size 64x40 --spp 2 --out " + path, &out), 0)
      << out;
  EXPECT_NE(out.find("64x40"), std::string::npos) << out;
  EXPECT_NE(out.find("tangent_samples"), std::string::npos) << out;  // the fidelity report
  EXPECT_NE(out.find("100%"), std::string::npos) << out;              // the plain progress line (not a terminal)
  auto in = OIIO::ImageInput::open(path);
  ASSERT_TRUE(in) << OIIO::geterror();
  EXPECT_EQ(in->spec().width, 64);
  EXPECT_EQ(in->spec().height, 40);
  EXPECT_EQ(testing::RunClient(server_->port(), "render --preset velvet --size 8x8 --width 3 --out x.png", &out), 2) << out;
  EXPECT_EQ(testing::RunClient(server_->port(), "render --preset no_such --out " + path, &out), 1) << out;
  EXPECT_NE(out.find("INVALID_ARGUMENT: material.preset"), std::string::npos) << out;
}

}  // namespace

// The fiber scenes (Wu and Yuksel Fig. 7's straight yarn; a woven patch close-up): images decode at the requested
// size with finite, positive radiance; the same seed gives the same bytes; the fidelity report names the
// geometry's level of detail, which follows the pixel footprint (Eq. 4) unless the request fixes it.
TEST_F(RenderTest, FiberScenesRenderDeterministicallyWithTheirDetailReported) {
  for (v1::ScenePreset scene : {v1::SCENE_YARN, v1::SCENE_WOVEN_PATCH}) {
    SCOPED_TRACE(scene);
    RenderRequest request = Request("cotton", scene, 48, 32, 2, v1::RENDER_FORMAT_PNG);
    const Rendered a = Render(*stub_, request), b = Render(*stub_, request);
    ASSERT_TRUE(a.status.ok()) << a.status.error_message();
    ASSERT_TRUE(b.status.ok()) << b.status.error_message();
    EXPECT_EQ(a.last().image(), b.last().image());
    const testing::DecodedImage image = testing::DecodeImage(a.last().image(), "fibers.png");
    EXPECT_EQ(image.width, 48);
    EXPECT_EQ(image.height, 32);
    ASSERT_EQ(a.last().mean_size(), 3);
    for (double m : a.last().mean()) EXPECT_TRUE(std::isfinite(m) && m > 0) << m;
    ASSERT_EQ(a.last().fidelity_size(), 1);
    const v1::FidelityChoice* geometry = Choice(a.last().fidelity(0), "geometry");
    ASSERT_NE(geometry, nullptr);
    EXPECT_EQ(geometry->full(), "full");
    EXPECT_NE(geometry->reason().find("fiber curves"), std::string::npos) << geometry->reason();
  }
  // Close up (the default camera, 512 pixels high) every fiber is kept; from 20 times as far at 32 pixels,
  // fibers are far below a pixel and Eq. 4 thins them; CORES and force_full_fidelity are obeyed.
  RenderRequest request = Request("cotton", v1::SCENE_YARN, 8, 512, 1);
  auto chosen = [&](const RenderRequest& r) {
    const Rendered out = Render(*stub_, r);
    EXPECT_TRUE(out.status.ok()) << out.status.error_message();
    const v1::FidelityChoice* c = out.status.ok() ? Choice(out.last().fidelity(0), "geometry") : nullptr;
    return c ? c->chosen() : std::string("none");
  };
  EXPECT_EQ(chosen(request), "full");
  request.set_height(32);
  Append(request.mutable_camera()->mutable_position(), {7, 0, 0.5});
  Append(request.mutable_camera()->mutable_look_at(), {0, 0, 0.5});
  request.set_fiber_detail(v1::FIBER_DETAIL_LOD);
  const std::string far = chosen(request);
  EXPECT_TRUE(far == "lod" || far == "cores") << far;
  request.set_fiber_detail(v1::FIBER_DETAIL_AUTO);  // Eq. 4 as LOD, or full detail where the pilot says so
  const std::string checked = chosen(request);
  EXPECT_TRUE(checked == far || checked == "full") << checked;
  request.set_force_full_fidelity(true);
  EXPECT_EQ(chosen(request), "full");
  request.set_force_full_fidelity(false);
  request.set_fiber_detail(v1::FIBER_DETAIL_CORES);
  EXPECT_EQ(chosen(request), "cores");
}

// Shadows and occlusion by the yarn cross-section's approximations (Wu and Yuksel Sec. 4.1-4.2): obeyed when
// requested, each reported with its pilot error against the traced rays; AUTO takes them only within the
// target, force_full_fidelity never. Their image is within 15% of the traced one's mean (measured: see
// docs/fibers.md "Shadows, ambient occlusion and level of detail").
TEST_F(RenderTest, FiberShadowAndOcclusionApproximationsAreChosenAndReported) {
  const auto render = [&](const RenderRequest& r, std::string* shadows, std::string* occlusion, double* mean) {
    const Rendered out = Render(*stub_, r);
    ASSERT_TRUE(out.status.ok()) << out.status.error_message();
    const v1::FidelityChoice* s = Choice(out.last().fidelity(0), "fiber_shadows");
    const v1::FidelityChoice* o = Choice(out.last().fidelity(0), "fiber_occlusion");
    ASSERT_TRUE(s && o);
    EXPECT_EQ(s->full(), "traced");
    EXPECT_EQ(o->full(), "traced");
    *shadows = s->chosen();
    *occlusion = o->chosen();
    *mean = out.last().mean(0) + out.last().mean(1) + out.last().mean(2);
    if (!r.force_full_fidelity()) {
      EXPECT_NE(s->reason().find("from traced"), std::string::npos) << s->reason();
      EXPECT_NE(o->reason().find("from traced"), std::string::npos) << o->reason();
    }
  };
  RenderRequest request = Request("cotton", v1::SCENE_WOVEN_PATCH, 96, 96, 8);
  std::string shadows, occlusion;
  double traced = 0, approximated = 0;
  request.set_fiber_shadows(v1::FIBER_SHADOWS_TRACED);
  request.set_fiber_occlusion(v1::FIBER_OCCLUSION_TRACED);
  render(request, &shadows, &occlusion, &traced);
  EXPECT_EQ(shadows + "/" + occlusion, "traced/traced");
  ASSERT_GT(traced, 0);
  for (auto [method, name] : {std::pair{v1::FIBER_OCCLUSION_TEXTURE, "texture"}, {v1::FIBER_OCCLUSION_DISTANCE, "distance"}}) {
    request.set_fiber_shadows(v1::FIBER_SHADOWS_SLICES);
    request.set_fiber_occlusion(method);
    render(request, &shadows, &occlusion, &approximated);
    EXPECT_EQ(shadows + "/" + occlusion, std::string("slices/") + name);
    EXPECT_NEAR(approximated / traced, 1.0, 0.15) << name;
  }
  // AUTO: a loose target takes the approximations, a tight one keeps the rays; force_full_fidelity traces.
  request.set_fiber_shadows(v1::FIBER_SHADOWS_AUTO);
  request.set_fiber_occlusion(v1::FIBER_OCCLUSION_AUTO);
  request.set_error_target(0.5);
  render(request, &shadows, &occlusion, &approximated);
  EXPECT_EQ(shadows, "slices");
  EXPECT_NE(occlusion, "traced");
  request.set_error_target(1e-9);
  render(request, &shadows, &occlusion, &approximated);
  EXPECT_EQ(shadows + "/" + occlusion, "traced/traced");
  request.set_error_target(0.5);
  request.set_force_full_fidelity(true);
  render(request, &shadows, &occlusion, &approximated);
  EXPECT_EQ(shadows + "/" + occlusion, "traced/traced");
}

// A core stands for the fibers inside a ply as a bundle; the fiber it meets inside is shaded about a thin
// fiber's normal, not the rod's. Lambertian fibers under one light, seen from where a fiber is under half a
// pixel: the cores alone within 15% of full detail's mean (measured 10%; shaded about the rod's normal, whose
// lit side is also the side the light reaches through the least bundle, they were 26% brighter).
TEST_F(RenderTest, CoresShadeLambertianFibersLikeTheFibersTheyStandFor) {
  RenderRequest request = Request("cotton", v1::SCENE_WOVEN_PATCH, 96, 96, 16);
  const auto set = [&](const char* name, std::initializer_list<double> values) {
    v1::Param* p = request.mutable_material()->add_params();
    p->set_name(name);
    for (double v : values) p->add_values(v);
  };
  set("kd", {0.5, 0.5, 0.5});
  set("c_r", {0, 0, 0});
  set("c_tt", {0, 0, 0});
  v1::RenderLight* light = request.add_lights();
  Append(light->mutable_direction(), {-0.5, 0.4, 0.8});
  Append(light->mutable_rgb(), {3, 3, 3});
  Append(request.mutable_camera()->mutable_position(), {0.51, 0.2, 3.0});
  Append(request.mutable_camera()->mutable_look_at(), {0.51, 0.51, 0});
  request.set_fiber_shadows(v1::FIBER_SHADOWS_TRACED);
  double mean[2] = {0, 0};
  for (int i = 0; i < 2; ++i) {
    request.set_fiber_detail(i == 0 ? v1::FIBER_DETAIL_FULL : v1::FIBER_DETAIL_CORES);
    const Rendered out = Render(*stub_, request);
    ASSERT_TRUE(out.status.ok()) << out.status.error_message();
    for (int c = 0; c < 3; ++c) mean[i] += out.last().mean(c);
  }
  ASSERT_GT(mean[0], 0);
  std::printf("Lambertian fibers, mean radiance: full detail %.5f, cores %.5f\n", mean[0], mean[1]);
  EXPECT_NEAR(mean[1] / mean[0], 1.0, 0.15);
}

// AUTO's level of detail is checked against full detail (the pilot's radiance through both): on the distant woven
// patch of the render benchmark, cotton's thinned fibers are brighter than full detail by more than the 2% target
// (docs/fibers.md "Shadows, ambient occlusion and level of detail": their R highlight), so AUTO renders full detail
// and says why; with a loose target it keeps the thinning and reports the estimate, which agrees in sign and size
// with the images' own difference (LOD against FULL, rendered).
TEST_F(RenderTest, AutoFiberDetailIsCheckedAgainstFullDetail) {
  RenderRequest request = Request("cotton", v1::SCENE_WOVEN_PATCH, 96, 96, 8);
  Append(request.mutable_camera()->mutable_position(), {0.51, 0.2, 3.0});
  Append(request.mutable_camera()->mutable_look_at(), {0.51, 0.51, 0});
  request.set_fiber_shadows(v1::FIBER_SHADOWS_TRACED);
  request.set_fiber_occlusion(v1::FIBER_OCCLUSION_TRACED);
  const auto render = [&](const RenderRequest& r, v1::FidelityChoice* geometry) {
    const Rendered out = Render(*stub_, r);
    EXPECT_TRUE(out.status.ok()) << out.status.error_message();
    if (!out.status.ok()) return 0.0;
    if (const v1::FidelityChoice* c = Choice(out.last().fidelity(0), "geometry")) *geometry = *c;
    return out.last().mean(0) + out.last().mean(1) + out.last().mean(2);
  };
  v1::FidelityChoice geometry;
  render(request, &geometry);
  EXPECT_EQ(geometry.chosen(), "full") << geometry.reason();
  EXPECT_NE(geometry.reason().find("from full detail"), std::string::npos) << geometry.reason();
  EXPECT_NE(geometry.reason().find("over the target: full detail"), std::string::npos) << geometry.reason();

  request.set_error_target(0.5);
  render(request, &geometry);
  EXPECT_TRUE(geometry.chosen() == "lod" || geometry.chosen() == "cores") << geometry.reason();
  const double estimate = geometry.estimated_error();
  EXPECT_GT(estimate, 0.02) << geometry.reason();
  EXPECT_LE(estimate, 0.5) << geometry.reason();

  request.set_error_target(0);
  request.set_samples_per_pixel(32);
  request.set_fiber_detail(v1::FIBER_DETAIL_FULL);
  const double full = render(request, &geometry);
  request.set_fiber_detail(v1::FIBER_DETAIL_LOD);
  const double lod = render(request, &geometry);
  ASSERT_GT(full, 0);
  const double measured = std::fabs(lod / full - 1);
  std::printf("distant woven patch: LoD against full detail, pilot %.3f, images %.3f\n", estimate, measured);
  EXPECT_GT(measured, 0.02);
  EXPECT_NEAR(estimate, measured, 0.5 * measured);
}

// Ambient light alone (a black light, ambient radiance 1): each pixel averages the fiber's ambient factor
// (Evaluate's AMBIENT, Eqs. 7-10) times the traced visibility, so no pixel exceeds the largest ambient factor
// over wo, and the yarn is not black (its outer fibers see much of the sky).
TEST_F(RenderTest, FiberAmbientTermIsBoundedByTheAmbientFactor) {
  v1::EvaluateRequest ambient;
  ambient.mutable_material()->set_preset("cotton");
  ambient.set_quantity(v1::QUANTITY_AMBIENT);
  for (int k = 0; k <= 90; ++k) {
    const double a = k * M_PI / 180;  // wo from along the axis (+x) to across it
    for (float v : {float(std::cos(a)), 0.f, float(std::sin(a))}) ambient.add_wo(v);
  }
  v1::EvaluateResponse factors;
  grpc::ClientContext ctx;
  ASSERT_TRUE(stub_->Evaluate(&ctx, ambient, &factors).ok());
  float most = 0;
  for (float f : factors.f()) most = std::max(most, f);
  ASSERT_GT(most, 0.1f);

  RenderRequest request = Request("cotton", v1::SCENE_YARN, 64, 32, 16);
  v1::RenderLight* dark = request.add_lights();
  Append(dark->mutable_direction(), {0, 1, 0});
  Append(dark->mutable_rgb(), {0, 0, 0});
  request.set_ambient(1);
  const std::vector<float> image = Linear(*stub_, request);
  ASSERT_EQ(image.size(), 64u * 32 * 3);
  double sum = 0;
  for (float v : image) {
    EXPECT_LE(v, most * 1.0001f);
    sum += v;
  }
  EXPECT_GT(sum / image.size(), 0.05 * most);
}

// A straight fiber shades like an analytic cylinder: every camera ray through a thin round fiber along +z hits
// where the ray meets the cylinder x^2 + y^2 = r^2, the shading frame's normal is the cylinder's, the light
// sample weighs cos(theta_i) = sqrt(1 - (wi.t)^2) about the axis (SPEC.md section 5) and is never shadowed by
// the fiber itself, and the shaded f (per-query axis, through the material plan) equals the fiber model's f of
// the world-space pair about the world axis.
// One straight fiber of radius r along z (from -1 to 1), seen close up at 48 x 48, lit by one directional light.
render::RenderSetup FiberSetup(const yarn::YarnGeometry& geometry, render::Vec3 light, int side = 48) {
  const yarn::YarnGeometry* yarns[] = {&geometry};
  auto fibers = std::make_shared<yarn::FiberScene>();
  EXPECT_EQ(yarn::FiberScene::Build(yarns, {}, fibers.get()), "");
  render::RenderSetup setup;
  setup.scene = render::MakeScene(render::SceneKind::kYarn);
  setup.scene.fibers = fibers;
  setup.width = setup.height = side;
  setup.camera = render::PinholeCamera({{0.2, 0.05, 0.1}, {0, 0, 0}, {0, 1, 0}, 8}, side, side);
  setup.lights = {{render::Light::Type::kDirectional, light, {}, {2, 2, 2}, {}, {}, 0, 0}};
  return setup;
}
render::RenderSetup OneFiberSetup(yarn::FiberType type, double r, render::Vec3 light) {
  yarn::YarnGeometry geometry;
  yarn::FiberCurve& curve = geometry.fibers.emplace_back();
  curve.type = type;
  curve.width = 2 * r;
  curve.points = {{0, 0, -1}, {0, 0, 1}};
  return FiberSetup(geometry, light);
}

// A render traces its pixel samples in packets (TracePixelSamples: camera rays cast together, Embree packets
// for fibers): each sample must come out as when traced alone.
TEST(FiberShading, PacketsTraceAsSingleSamples) {
  const render::RenderSetup setup = OneFiberSetup(yarn::FiberType::kMigration, 0.01, render::Normalize({0.3, 0.8, -0.5}));
  std::vector<render::PixelSample> samples;
  for (uint64_t pixel = 0; pixel < 48 * 48; pixel += 5)
    for (uint32_t s = 0; s < 3; ++s) samples.push_back({pixel, s});
  std::vector<render::ShadingPoint> packed(samples.size());
  render::TracePixelSamples(setup, samples, packed.data());
  int fibers = 0;
  for (size_t i = 0; i < samples.size(); ++i) {
    render::ShadingPoint single;
    render::TracePixelSample(setup, samples[i].pixel, samples[i].sample, &single);
    const render::ShadingPoint& p = packed[i];
    ASSERT_EQ(p.object, single.object) << i;
    ASSERT_EQ(p.fiber, single.fiber) << i;
    fibers += p.fiber;
    EXPECT_NEAR(p.background.x, single.background.x, 1e-12) << i;
    EXPECT_LT(render::Length(p.wo - single.wo), 1e-3) << i;
    EXPECT_LT(render::Length(p.axis - single.axis), 1e-3) << i;
    ASSERT_EQ(p.lights.size(), single.lights.size()) << i;
  }
  EXPECT_GT(fibers, 20);
}

// A core fiber with no free path (no fibers counted for it, as here) is a thick opaque cylinder: lit where its
// surface faces the light and in its own shadow on the far side (a regular fiber, a line to its far-field model, is lit all round: the
// test below).
TEST(FiberShading, CoreFiberShadowsItsOwnFarSide) {
  using render::Vec3;
  constexpr double r = 0.01;
  const Vec3 light = render::Normalize({0.3, 0.8, -0.5});
  const render::RenderSetup setup = OneFiberSetup(yarn::FiberType::kCore, r, light);
  int lit = 0, dark = 0;
  for (int j = 0; j < 48; ++j)
    for (int i = 0; i < 48; ++i) {
      render::ShadingPoint point;
      render::TraceSample(setup, i + 0.5, j + 0.5, render::SamplePoints(1, j * 48 + i, 0), &point);
      if (point.object < 0) continue;
      const double facing = point.lights.empty() ? 0 : 1;
      // The hit's normal toward the light, from the camera ray (the frame's z is the normal).
      const Vec3 o = setup.camera.position(), d = setup.camera.Direction(i + 0.5, j + 0.5);
      const double a = d.x * d.x + d.y * d.y, b = o.x * d.x + o.y * d.y, c = o.x * o.x + o.y * o.y - r * r;
      const double disc = b * b - a * c;
      if (disc < 1e-3 * b * b) continue;
      const Vec3 p = o + ((-b - std::sqrt(disc)) / a) * d, n{p.x / r, p.y / r, 0};
      const double cosine = render::Dot(n, light);
      if (std::fabs(cosine) < 0.02) continue;  // at the terminator
      EXPECT_EQ(facing, cosine > 0 ? 1 : 0) << i << "," << j << " cos " << cosine;
      (cosine > 0 ? lit : dark)++;
    }
  EXPECT_GT(lit, 50);
  EXPECT_GT(dark, 50);
}

// A core with a free path stands for the fibers inside it: light reaches the fiber a camera ray meets in it as it
// reaches the first fiber a ray meets among randomly placed parallel fibers. Expected: `fibers` explicit fibers
// placed uniformly in the core's disc, traced; the mean light on their hits against that on the core's, for a
// light near the view (where the hot spot matters) and across it.
TEST(FiberShading, CoreBundleLetsLightThroughLikeTheFibersItStandsFor) {
  using render::Vec3;
  constexpr double radius = 0.02, width = 0.002;
  constexpr int fibers = 240;  // packing 0.6 (cotton1's plies: ~1)
  yarn::YarnGeometry loose, core;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uni(-1, 1);
  while (static_cast<int>(loose.fibers.size()) < fibers) {
    const double x = uni(rng), y = uni(rng);
    if (x * x + y * y > 1) continue;
    const double reach = radius - width / 2;  // whole fibers inside the disc
    loose.fibers.push_back({yarn::FiberType::kMigration, 0, 0, width, {{reach * x, reach * y, -1}, {reach * x, reach * y, 1}}});
  }
  core.fibers.push_back({yarn::FiberType::kCore, 0, -1, 2 * radius, {{0, 0, -1}, {0, 0, 1}}});
  yarn::PlyDetail& ply = core.plies.emplace_back();
  ply.core_fibers = fibers;
  ply.core_radius = radius;
  ply.core_free_path = std::numbers::pi * radius * radius / (fibers * width);
  ply.core_fiber_width = width;
  const auto mean_light = [](const render::RenderSetup& setup) {
    double sum = 0;
    int hits = 0;
    for (int j = 0; j < setup.height; ++j)
      for (int i = 0; i < setup.width; ++i)
        for (uint32_t k = 0; k < 4; ++k) {
          render::ShadingPoint point;
          const uint64_t pixel = uint64_t(j) * setup.width + i;
          render::TraceSample(setup, i + 0.5, j + 0.5, render::SamplePoints(1, pixel, k), &point);
          if (point.object < 0) continue;
          ++hits;
          for (const render::LightSample& l : point.lights) sum += l.weight.x;
        }
    EXPECT_GT(hits, 1000);
    return sum / std::max(hits, 1);
  };
  const Vec3 camera = render::Normalize({0.2, 0.05, 0.1});
  for (const Vec3 light : {render::Normalize({0.2, 0.12, 0.08}), render::Normalize({-0.05, 0.2, 0.04})}) {
    const double expected = mean_light(FiberSetup(loose, light, 96)), bundle = mean_light(FiberSetup(core, light, 96));
    std::printf("light %.2f from the view: explicit fibers %.4f, core %.4f (%+.1f%%)\n",
                std::acos(render::Dot(light, camera)), expected, bundle, 100 * (bundle / expected - 1));
    EXPECT_NEAR(bundle / expected, 1, 0.08);  // measured -0.6% and -4.3%
  }
}

TEST(FiberShading, StraightFiberShadesLikeAnAnalyticCylinder) {
  using render::Vec3;
  constexpr double r = 0.01;
  const Vec3 light = render::Normalize({0.3, 0.8, -0.5});
  const render::RenderSetup setup = OneFiberSetup(yarn::FiberType::kMigration, r, light);

  const models::PresetSpec* preset = nullptr;
  const models::Model* model = models::Registry::Global().FindPreset("cotton", &preset);
  ASSERT_NE(model, nullptr);
  models::PreparedMaterial material;
  material.model = model;
  material.values = model->PresetValues(*preset);
  material.values["axis"] = {0, 0, 1};  // the world's fiber axis, for the world-space reference
  material.packed = model->Pack(material.values);
  models::PreparedMaterial shading_material;
  shading_material.model = model;
  shading_material.values = material.values;
  shading_material.values["axis"] = {1, 0, 0};
  shading_material.packed = model->Pack(shading_material.values);
  const render::Evaluator evaluator{&shading_material, false, false, true};

  int hits = 0;
  for (int j = 0; j < 48; ++j)
    for (int i = 0; i < 48; ++i) {
      const Vec3 o = setup.camera.position(), d = setup.camera.Direction(i + 0.5, j + 0.5);
      const double a = d.x * d.x + d.y * d.y, b = o.x * d.x + o.y * d.y, c = o.x * o.x + o.y * o.y - r * r;
      const double disc = b * b - a * c;
      render::ShadingPoint point;
      render::TraceSample(setup, i + 0.5, j + 0.5, render::SamplePoints(1, j * 48 + i, 0), &point);
      if (disc < 1e-3 * b * b) {  // a miss, or too near the silhouette to tell
        if (disc < -1e-3 * b * b) {
          EXPECT_LT(point.object, 0) << i << "," << j;
        }
        continue;
      }
      ASSERT_EQ(point.object, 0) << i << "," << j;
      ASSERT_TRUE(point.fiber);
      ++hits;
      const double t = (-b - std::sqrt(disc)) / a;
      const Vec3 p = o + t * d, n{p.x / r, p.y / r, 0};
      EXPECT_NEAR(point.wo.z, render::Dot(n, -1.0 * d), 2e-3);  // the frame's normal is the cylinder's
      EXPECT_NEAR(render::Length(point.axis), 1, 1e-5);
      const double side = point.wo.x * point.axis.x + point.wo.y * point.axis.y + point.wo.z * point.axis.z;
      EXPECT_NEAR(std::fabs(side), std::fabs(d.z), 1e-4);
      ASSERT_EQ(point.lights.size(), 1u) << "the fiber shadowed itself at " << i << "," << j;
      const render::LightSample& l = point.lights[0];
      EXPECT_NEAR(l.weight.x, 2 * std::sqrt(1 - light.z * light.z), 1e-6);
      EXPECT_NEAR(l.wi.z, render::Dot(n, light), 2e-3);

      std::vector<render::QueryBucket> buckets(1);
      render::AppendQueries(point, {0, -1}, {evaluator}, 0, &buckets);
      ASSERT_EQ(buckets[0].size(), 1u);
      std::vector<double> shaded;
      render::EvaluateOnHost(evaluator, buckets[0], &shaded);
      const float wi[3] = {float(light.x), float(light.y), float(light.z)};
      const float wo[3] = {float(-d.x), float(-d.y), float(-d.z)};
      float expected[3];
      model->NativeEval(material.packed, wi, wo, nullptr, 1, expected);
      for (int ch = 0; ch < 3; ++ch)
        EXPECT_NEAR(shaded[ch], expected[ch], 2e-3 * std::fabs(expected[ch]) + 1e-6) << i << "," << j << " ch " << ch;
    }
  EXPECT_GT(hits, 100);
}
}  // namespace loomlight
