// Studio lighting: a rect light's (softbox's) irradiance against the closed form for parallel planes and a
// brute-force quadrature for a tilted one, nothing behind it or through a blocker, a tiny one as the point light
// of intensity L x area; presets placed around any subject keep the key on the camera's left and above; the studio
// map is the same all the way round; bad rect lights and an unknown preset are refused naming the field; renders
// with each preset are finite, the key side brighter; ListScenes lists the presets as lights Render accepts.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/render_rpc.h"
#include "server/api/server.h"
#include "server/render/environment.h"
#include "server/render/lighting_presets.h"
#include "server/render/sample_points.h"
#include "server/render/shading.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using render::Light;
using render::Vec3;

constexpr double kPi = std::numbers::pi;

// Irradiance from a Lambertian rectangle of radiance L on a receiver in a parallel plane facing it, at height h,
// the rectangle spanning [x0, x1] x [y0, y1] relative to the receiver's foot: the corner-rectangle form factor
// (odd in X and Y, so the signed sum of four corners covers off-axis points; Howell's catalogue, C-11).
double ParallelRectIrradiance(double L, double x0, double x1, double y0, double y1, double h) {
  const auto corner = [h](double x, double y) {
    const double a = std::sqrt(x * x + h * h), b = std::sqrt(y * y + h * h);
    return 0.5 * (x / a * std::atan(y / a) + y / b * std::atan(x / b));
  };
  return L * (corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0));
}

struct Estimate {
  double mean = 0, standard_error = 0;
};

// The irradiance at `point` with normal `normal` by SampleRectLight with n independent uniform pairs.
Estimate EstimateIrradiance(const Light& light, Vec3 point, Vec3 normal, int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  double sum = 0, squares = 0;
  for (int i = 0; i < n; ++i) {
    render::RectLightSample s;
    double e = 0;
    const double u0 = uniform(rng), u1 = uniform(rng);
    if (render::SampleRectLight(light, point, u0, u1, &s)) {
      EXPECT_TRUE(std::isfinite(s.incident.x) && s.incident.x >= 0);
      e = s.incident.x * std::max(0.0, Dot(s.direction, normal));
      // The sampled point lies on the rectangle.
      const Vec3 target = point + s.distance * s.direction - light.position;
      EXPECT_NEAR(Dot(target, light.direction), 0, 1e-9 * (1 + s.distance));
      EXPECT_LE(std::fabs(Dot(target, light.axis_u)), 0.5 * light.width * (1 + 1e-9));
      EXPECT_LE(std::fabs(Dot(target, light.axis_v)), 0.5 * light.height * (1 + 1e-9));
    }
    sum += e;
    squares += e * e;
  }
  const double mean = sum / n;
  return {mean, std::sqrt(std::max(0.0, squares / n - mean * mean) / n)};
}

TEST(RectLight, IrradianceOnAParallelPlaneMatchesTheClosedForm) {
  // A 2 x 1 softbox in z = 0 facing +z, radiance 3; receivers facing it at height h, on and off its axis, near
  // (its solid angle large: sampled by solid angle) and far (below kMinSphericalRectSolidAngle: by area).
  const Light light = render::RectLight({0, 0, 0}, {0, 0, 1}, 2, 1, {0, 1, 0}, {3, 3, 3});
  EXPECT_NEAR(Length(Cross(light.axis_u, light.axis_v) - light.direction), 0, 1e-12);
  struct Case {
    double x, y, h;
  };
  for (const Case c : {Case{0, 0, 0.05}, Case{0, 0, 0.5}, Case{1.5, 0.3, 0.7}, Case{-0.9, -0.45, 0.02},
                       Case{3, 2, 1}, Case{0.2, 0.1, 300}}) {
    const double expected = ParallelRectIrradiance(3, -1 - c.x, 1 - c.x, -0.5 - c.y, 0.5 - c.y, c.h);
    const Estimate e = EstimateIrradiance(light, {c.x, c.y, c.h}, {0, 0, -1}, 20000, 11);
    std::printf("receiver (%g, %g, %g): %.6g +- %.2g, closed form %.6g\n", c.x, c.y, c.h, e.mean, e.standard_error,
                expected);
    EXPECT_NEAR(e.mean, expected, 4 * e.standard_error + 1e-9 * expected) << c.x << " " << c.y << " " << c.h;
  }
}

TEST(RectLight, IrradianceOnATiltedReceiverMatchesQuadrature) {
  // A softbox turned 30 degrees about x and a receiver tilted the other way, beside it: the expected value by the
  // midpoint rule over the rectangle (L cos_receiver cos_light dA / d^2 per cell).
  const Vec3 facing = Normalize(Vec3{0, -0.5, 0.8660254037844386});
  const Light light = render::RectLight({0.3, 0.2, 0}, facing, 1.5, 0.8, {0, 1, 0}, {2, 2, 2});
  const Vec3 point{1.1, -0.4, 0.6}, normal = Normalize(Vec3{-0.4, 0.3, -0.8});
  constexpr int kCells = 600;
  double expected = 0;
  for (int i = 0; i < kCells; ++i)
    for (int j = 0; j < kCells; ++j) {
      const Vec3 q = light.position + ((i + 0.5) / kCells - 0.5) * light.width * light.axis_u +
                     ((j + 0.5) / kCells - 0.5) * light.height * light.axis_v;
      const Vec3 w = q - point;
      const double d2 = Dot(w, w), d = std::sqrt(d2);
      const double cos_receiver = std::max(0.0, Dot(w, normal) / d), cos_light = std::max(0.0, -Dot(w, facing) / d);
      expected += 2 * cos_receiver * cos_light / d2 * (light.width * light.height / (kCells * kCells));
    }
  const Estimate e = EstimateIrradiance(light, point, normal, 40000, 12);
  std::printf("tilted: %.6g +- %.2g, quadrature %.6g\n", e.mean, e.standard_error, expected);
  EXPECT_NEAR(e.mean, expected, 4 * e.standard_error + 1e-5 * expected);
}

TEST(RectLight, NothingBehindItOrInItsPlane) {
  const Light light = render::RectLight({0, 1, 0}, {0, -1, 0}, 1, 1, {}, {5, 5, 5});  // facing down: up falls to +z
  EXPECT_NEAR(Length(light.axis_v - Vec3{0, 0, 1}), 0, 1e-12);
  render::RectLightSample s;
  for (const Vec3 p : {Vec3{0, 1.5, 0}, Vec3{0.2, 1.01, -0.3}, Vec3{3, 2, 3}, Vec3{0.1, 1, 0.1}, Vec3{2, 1, 0}})
    for (double u : {0.0, 0.25, 0.5, 0.999})
      EXPECT_FALSE(render::SampleRectLight(light, p, u, 1 - u, &s)) << p.x << " " << p.y << " " << p.z;
  EXPECT_TRUE(render::SampleRectLight(light, {0, 0, 0}, 0.5, 0.5, &s));
  Light flat = light;
  flat.width = 0;
  EXPECT_FALSE(render::SampleRectLight(flat, {0, 0, 0}, 0.5, 0.5, &s));
}

TEST(RectLight, ATinyOneIsThePointLightOfIntensityRadianceTimesArea) {
  // 1 mm square of radiance 1e6 (intensity 1) 2 units from a receiver tilted 53 degrees away from it.
  const Light light = render::RectLight({0, 0, 2}, {0, 0, -1}, 1e-3, 1e-3, {0, 1, 0}, {1e6, 1e6, 1e6});
  const Vec3 normal{0.8, 0, 0.6};
  const double expected = 1.0 * 0.6 / 4;  // I cos / d^2
  const Estimate e = EstimateIrradiance(light, {0, 0, 0}, normal, 4000, 13);
  EXPECT_NEAR(e.mean, expected, 1e-6 * expected + 4 * e.standard_error);
  EXPECT_LT(e.standard_error, 1e-5 * expected);
}

// A receiving quad in z = 0 facing +z (object 0) and, optionally, a sphere above it (object 1), lit by `lights`.
render::RenderSetup ReceiverSetup(std::vector<Light> lights, bool blocker) {
  render::RenderSetup setup;
  setup.scene.objects.push_back({"receiver", render::QuadShape({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 5, 5)});
  if (blocker) setup.scene.objects.push_back({"blocker", render::SphereShape({0, 0, 1}, 0.5)});
  setup.lights = std::move(lights);
  setup.seed = 5;
  return setup;
}

// The mean irradiance TraceSample's light samples carry at the receiver's centre over n pixel samples, and how
// many samples had a light sample at all.
double ShadedIrradiance(const render::RenderSetup& setup, uint32_t n, int* lit) {
  render::Hit hit = render::PointOnShape(setup.scene.objects[0].shape, 0, 0);
  hit.object = 0;
  hit.distance = 1;
  double sum = 0;
  *lit = 0;
  render::ShadingPoint point;
  for (uint32_t i = 0; i < n; ++i) {
    render::ShadeHit(setup, {0, 0, -1}, 0, render::SamplePoints(setup.seed, 0, i), &hit, &point);
    *lit += !point.lights.empty();
    for (const render::LightSample& l : point.lights) {
      EXPECT_TRUE(std::isfinite(l.weight.x));
      sum += l.weight.x;
    }
  }
  return sum / n;
}

TEST(RectLight, ShadingSamplesItWithAShadowRay) {
  // A 0.2 x 0.2 softbox 2 above the receiver, facing it: through ShadeHit, its irradiance (closed form); a sphere
  // between them (its 30 degrees hide the softbox's 3) leaves no light sample; turned away, none either.
  const Light light = render::RectLight({0, 0, 2}, {0, 0, -1}, 0.2, 0.2, {0, 1, 0}, {50, 50, 50});
  int lit = 0;
  const double open = ShadedIrradiance(ReceiverSetup({light}, false), 1024, &lit);
  EXPECT_EQ(lit, 1024);
  const double expected = ParallelRectIrradiance(50, -0.1, 0.1, -0.1, 0.1, 2);
  EXPECT_NEAR(open, expected, 1e-3 * expected);
  EXPECT_EQ(ShadedIrradiance(ReceiverSetup({light}, true), 256, &lit), 0.0);
  EXPECT_EQ(lit, 0);
  const Light away = render::RectLight({0, 0, 2}, {0, 0, 1}, 0.2, 0.2, {0, 1, 0}, {50, 50, 50});
  EXPECT_EQ(ShadedIrradiance(ReceiverSetup({away}, false), 256, &lit), 0.0);
  EXPECT_EQ(lit, 0);
}

TEST(LightingPresets, KeyLeftAndAboveFillRightRimBehindAroundAnySubject) {
  ASSERT_FALSE(render::LightingPresets().empty());
  EXPECT_EQ(render::LightingPresets()[0].name, "studio");
  for (const char* name : {"studio", "studio_high_key", "softbox_top"}) EXPECT_NE(render::FindLightingPreset(name), nullptr) << name;
  EXPECT_EQ(render::FindLightingPreset("Studio"), nullptr);
  EXPECT_EQ(render::FindLightingPreset(""), nullptr);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Vec3 centre{100 * uniform(rng), 100 * uniform(rng), 100 * uniform(rng)};
    const double radius = std::exp(4 * uniform(rng));  // 0.02 .. 55
    // A camera 2 to 10 radii away, anywhere within 70 degrees of level, up +y or tilted a little.
    const double azimuth = kPi * uniform(rng), elevation = 1.2 * uniform(rng), distance = radius * (6 + 4 * uniform(rng));
    const Vec3 offset{std::cos(elevation) * std::sin(azimuth), std::sin(elevation), std::cos(elevation) * std::cos(azimuth)};
    render::CameraSpec camera{centre + distance * offset, centre + (0.3 * radius) * Vec3{uniform(rng), uniform(rng), uniform(rng)}};
    camera.up = Normalize(Vec3{0.2 * uniform(rng), 1, 0.2 * uniform(rng)});
    // The image's right and the direction toward the camera, as the camera itself draws its pixels.
    const render::PinholeCamera pinhole(camera, 100, 100);
    const Vec3 right = Normalize(pinhole.Direction(100, 50) - pinhole.Direction(0, 50));
    // Toward the camera, level (about its up): a preset's azimuths are around the subject, whatever the camera's
    // height.
    const Vec3 to_camera = camera.position - centre;
    const Vec3 toward_camera = Normalize(to_camera - Dot(to_camera, camera.up) * camera.up);
    for (const render::LightingPreset& preset : render::LightingPresets()) {
      const std::vector<Light> lights = render::PlaceLights(preset, centre, radius, camera);
      ASSERT_EQ(lights.size(), preset.lights.size());
      for (size_t i = 0; i < lights.size(); ++i) {
        const Light& l = lights[i];
        const render::PresetLight& p = preset.lights[i];
        const Vec3 from_centre = l.position - centre;
        ASSERT_EQ(l.type, Light::Type::kRect);
        EXPECT_NEAR(Length(from_centre), p.distance * radius, 1e-9 * radius);
        EXPECT_NEAR(l.width, p.width * radius, 1e-12 * radius);
        EXPECT_NEAR(l.height, p.height * radius, 1e-12 * radius);
        // Facing the subject's centre squarely, which it lights.
        EXPECT_NEAR(Dot(l.direction, Normalize(centre - l.position)), 1, 1e-12);
        render::RectLightSample s;
        EXPECT_TRUE(render::SampleRectLight(l, centre, 0.5, 0.5, &s));
        if (p.role == "key") {
          EXPECT_LT(Dot(from_centre, right), -0.3 * Length(from_centre)) << preset.name << " trial " << trial;
          EXPECT_GT(Dot(from_centre, camera.up), 0.3 * Length(from_centre)) << preset.name << " trial " << trial;
          EXPECT_GT(Dot(from_centre, toward_camera), 0) << preset.name << " trial " << trial;
        } else if (p.role == "fill") {
          EXPECT_GT(Dot(from_centre, right), 0.3 * Length(from_centre)) << preset.name;
        } else if (p.role == "rim") {
          EXPECT_LT(Dot(from_centre, toward_camera), 0) << preset.name;
        } else if (p.role == "top") {
          EXPECT_GT(Dot(from_centre, camera.up), 0.9 * Length(from_centre)) << preset.name;
        }
      }
    }
  }
}

TEST(StudioMap, SameAllTheWayRoundBrightTopGreyWallsDarkerFloor) {
  const render::Environment studio = render::Environment::Studio();
  const auto luminance = [&](Vec3 d) {
    const render::Rgb c = studio.Radiance(Normalize(d));
    EXPECT_EQ(c.x, c.y);  // neutral
    EXPECT_EQ(c.y, c.z);
    return c.y;
  };
  const double top = luminance({0, 1, 0}), wall = luminance({1, 0.2, 0}), floor = luminance({0, -1, 0.1});
  EXPECT_GT(top, 2 * wall);
  EXPECT_GT(wall, 2 * floor);
  EXPECT_GT(floor, 0);
  for (int i = 0; i < 90; ++i) {
    const double elevation = -1.5 + 3.0 * i / 89, azimuth = 0.37 * i;
    const double a = luminance({std::cos(elevation), std::sin(elevation), 0});
    const double b = luminance({std::cos(elevation) * std::cos(azimuth), std::sin(elevation), std::cos(elevation) * std::sin(azimuth)});
    EXPECT_NEAR(a, b, 1e-3 * a) << elevation << " " << azimuth;
  }
}

v1::RenderLight GoodRect() {
  v1::RenderLight l;
  l.set_type(v1::RenderLight::TYPE_RECT);
  for (double v : {1.0, 2.0, 3.0}) l.add_position(v);
  for (double v : {-1.0, -2.0, -3.0}) l.add_direction(v);
  for (double v : {1.0, 1.0, 1.0}) l.add_rgb(v);
  l.add_size(0.5);
  l.add_size(0.8);
  return l;
}

v1::RenderRequest SmallRequest() {
  v1::RenderRequest r;
  r.mutable_material()->set_preset("linen_plain");
  r.set_scene(v1::SCENE_SPHERE);
  r.set_width(8);
  r.set_height(8);
  return r;
}

TEST(RectLightValidation, BadRectLightsAreRefusedNamingTheField) {
  // Two good lights before the bad one: the error names lights[2].
  const auto error = [](const std::function<void(v1::RenderLight*)>& spoil) {
    v1::RenderRequest r = SmallRequest();
    *r.add_lights() = GoodRect();
    *r.add_lights() = GoodRect();
    v1::RenderLight* bad = r.add_lights();
    *bad = GoodRect();
    spoil(bad);
    return api::ValidateRenderRequest(r);
  };
  EXPECT_EQ(error([](v1::RenderLight*) {}), "");
  EXPECT_EQ(error([](v1::RenderLight* l) { for (double v : {0.0, 1.0, 0.0}) l->add_up(v); }), "");
  const auto starts = [](const std::string& message, const std::string& prefix) {
    EXPECT_EQ(message.substr(0, prefix.size()), prefix) << message;
  };
  starts(error([](v1::RenderLight* l) { l->clear_size(); }), "lights[2].size: needs 2 values");
  starts(error([](v1::RenderLight* l) { l->add_size(1); }), "lights[2].size: needs 2 values");
  starts(error([](v1::RenderLight* l) { l->set_size(1, 0); }), "lights[2].size[1]: ");
  starts(error([](v1::RenderLight* l) { l->set_size(0, -1); }), "lights[2].size[0]: ");
  starts(error([](v1::RenderLight* l) { l->set_size(0, NAN); }), "lights[2].size[0]: ");
  starts(error([](v1::RenderLight* l) { l->set_size(1, INFINITY); }), "lights[2].size[1]: ");
  starts(error([](v1::RenderLight* l) { l->set_size(0, 1e300); }), "lights[2].size[0]: ");
  starts(error([](v1::RenderLight* l) { l->clear_direction(); }), "lights[2].direction: needs 3 values");
  starts(error([](v1::RenderLight* l) {
           for (int i = 0; i < 3; ++i) l->set_direction(i, 0);
         }),
         "lights[2].direction: must not be zero");
  starts(error([](v1::RenderLight* l) { l->set_direction(1, NAN); }), "lights[2].direction[1]: ");
  starts(error([](v1::RenderLight* l) { l->clear_position(); }), "lights[2].position: needs 3 values");
  starts(error([](v1::RenderLight* l) { l->set_position(2, -INFINITY); }), "lights[2].position[2]: ");
  starts(error([](v1::RenderLight* l) { for (double v : {2.0, 4.0, 6.0}) l->add_up(v); }), "lights[2].up: must not be zero or parallel");
  starts(error([](v1::RenderLight* l) { for (double v : {0.0, 0.0, 0.0}) l->add_up(v); }), "lights[2].up: must not be zero or parallel");
  starts(error([](v1::RenderLight* l) { l->add_up(0); l->add_up(1); }), "lights[2].up: needs 3 values");
  starts(error([](v1::RenderLight* l) { for (double v : {0.0, double(NAN), 0.0}) l->add_up(v); }), "lights[2].up[1]: ");
  starts(error([](v1::RenderLight* l) { l->set_rgb(0, -1); }), "lights[2].rgb[0]: must be >= 0");
  starts(error([](v1::RenderLight* l) { l->set_type(v1::RenderLight::TYPE_POINT); }), "lights[2].size: only for TYPE_RECT");
  starts(error([](v1::RenderLight* l) {
           l->set_type(v1::RenderLight::TYPE_DIRECTIONAL);
           l->clear_size();
           for (double v : {0.0, 1.0, 0.0}) l->add_up(v);
         }),
         "lights[2].up: only for TYPE_RECT");
  starts(error([](v1::RenderLight* l) { l->set_type(static_cast<v1::RenderLight::Type>(7)); }), "lights[2].type: unknown value 7");
  // More lights than the limit, whatever their kind.
  v1::RenderRequest many = SmallRequest();
  for (int i = 0; i <= api::kMaxRenderLights; ++i) *many.add_lights() = GoodRect();
  starts(api::ValidateRenderRequest(many), "lights: ");
}

TEST(RectLightValidation, UnknownPresetIsRefusedAndItsNameCutShort) {
  v1::RenderRequest r = SmallRequest();
  r.set_lighting("studio");
  EXPECT_EQ(api::ValidateRenderRequest(r), "");
  r.set_lighting("candlelight");
  const std::string e = api::ValidateRenderRequest(r);
  EXPECT_EQ(e.substr(0, 10), "lighting: ") << e;
  EXPECT_NE(e.find("'candlelight'"), std::string::npos) << e;
  r.set_lighting(std::string(100000, 'x'));
  EXPECT_LT(api::ValidateRenderRequest(r).size(), 400u);
}

class StudioRenderTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = testing::StartInProcessServer().release(); }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  static api::LoomlightServer* server_;
  std::unique_ptr<v1::Loomlight::Stub> stub_ = testing::Connect(server_->port());

  // The linear EXR image of a render, which must succeed.
  testing::DecodedImage Render(const v1::RenderRequest& request) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
    auto reader = stub_->Render(&ctx, request);
    v1::RenderUpdate update, last;
    while (reader->Read(&update)) last = update;
    const grpc::Status status = reader->Finish();
    EXPECT_TRUE(status.ok()) << status.error_message();
    if (!status.ok()) return {};
    return testing::DecodeImage(last.image(), "studio.exr");
  }
};
api::LoomlightServer* StudioRenderTest::server_ = nullptr;

TEST_F(StudioRenderTest, EveryPresetRendersFiniteWithTheKeySideBrighter) {
  ASSERT_NE(server_, nullptr);
  for (const render::LightingPreset& preset : render::LightingPresets()) {
    v1::RenderRequest r = SmallRequest();
    r.mutable_material()->set_preset("polyester_satin_charmeuse_front");
    r.set_width(48);
    r.set_height(32);
    r.set_samples_per_pixel(4);
    r.set_format(v1::RENDER_FORMAT_EXR);
    r.set_lighting(std::string(preset.name));
    const testing::DecodedImage image = Render(r);
    ASSERT_EQ(image.width, 48) << preset.name;
    // The sphere (radius 1, 3.24 from the camera: 14 pixels in radius about the image's centre) left and right
    // of its middle, 3 to 10 pixels out and within 5 of its equator.
    double left = 0, right = 0;
    for (int y = 0; y < image.height; ++y)
      for (int x = 0; x < image.width; ++x)
        for (int c = 0; c < 3; ++c) {
          const float v = image.pixels[(size_t(y) * image.width + x) * image.channels + c];
          ASSERT_TRUE(std::isfinite(v) && v >= 0) << preset.name << " pixel " << x << ", " << y;
          const int dx = x - image.width / 2, dy = y - image.height / 2;
          if (std::abs(dy) <= 5 && std::abs(dx) >= 3 && std::abs(dx) <= 10) (dx < 0 ? left : right) += v;
        }
    std::printf("%s: sphere's left %.4g, right %.4g\n", std::string(preset.name).c_str(), left, right);
    EXPECT_GT(left + right, 0) << preset.name;
    if (preset.name == "studio") {
      EXPECT_GT(left, 1.2 * right);  // the key (2.85 at the centre) camera-left, the fill (0.78) right
    }
  }
}

TEST_F(StudioRenderTest, ARequestsOwnSoftboxLightsTheSceneAndListedPresetsAreAccepted) {
  ASSERT_NE(server_, nullptr);
  // A softbox alone, camera-left of the sphere (the sphere scene's camera looks along -z).
  v1::RenderRequest r = SmallRequest();
  r.set_width(32);
  r.set_height(24);
  r.set_samples_per_pixel(4);
  r.set_format(v1::RENDER_FORMAT_EXR);
  v1::RenderLight* softbox = r.add_lights();
  *softbox = GoodRect();
  softbox->clear_position();
  softbox->clear_direction();
  for (double v : {-4.0, 1.0, 2.0}) softbox->add_position(v);
  for (double v : {4.0, -1.0, -2.0}) softbox->add_direction(v);
  softbox->set_size(0, 2);
  softbox->set_size(1, 2);
  const testing::DecodedImage image = Render(r);
  ASSERT_GT(image.width, 0);
  double left = 0, right = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const float v = image.pixels[(size_t(y) * image.width + x) * image.channels + 1];
      ASSERT_TRUE(std::isfinite(v) && v >= 0);
      (x < image.width / 2 ? left : right) += v;
    }
  EXPECT_GT(left, 0);
  EXPECT_GT(left, 3 * right);

  grpc::ClientContext ctx;
  v1::ListScenesResponse scenes;
  ASSERT_TRUE(stub_->ListScenes(&ctx, v1::ListScenesRequest(), &scenes).ok());
  ASSERT_EQ(scenes.lighting_presets_size(), int(render::LightingPresets().size()));
  EXPECT_EQ(scenes.lighting_presets(0).name(), "studio");
  for (const v1::LightingPreset& preset : scenes.lighting_presets()) {
    EXPECT_FALSE(preset.description().empty());
    EXPECT_TRUE(preset.environment()) << preset.name();
    ASSERT_GT(preset.lights_size(), 0) << preset.name();
    v1::RenderRequest listed = SmallRequest();
    for (const v1::RenderLight& light : preset.lights()) {
      EXPECT_EQ(light.type(), v1::RenderLight::TYPE_RECT);
      EXPECT_EQ(light.size_size(), 2);
      *listed.add_lights() = light;
    }
    EXPECT_EQ(api::ValidateRenderRequest(listed), "") << preset.name();
  }
}

}  // namespace
}  // namespace loomlight
