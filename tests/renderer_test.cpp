// The renderer alone (server/render/renderer.h), with no server: a fake evaluator gives a Lambertian's constant f,
// so that the image can be checked against the closed-form radiance; the cancellation token stops the loop
// within one chunk; an evaluator's failure ends the render with its status; several views render each their own
// image.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <numbers>

#include "server/models/material_cache.h"
#include "server/models/registry.h"
#include "server/render/renderer.h"
#include "tests/renderer_testing.h"

namespace loomlight {
namespace {

using render::Vec3;
using testing::LambertianEvaluator;
using testing::Rendered;
using testing::RenderWith;

constexpr double kAlbedo = 0.6;
const Vec3 kTowardLight = render::Normalize({1.0, 0.4, 0.1});  // from the side: the sphere is half lit
constexpr double kIrradiance = 2.0;  // per channel, perpendicular to the beam

models::MaterialCache& Cache() {
  static models::MaterialCache cache(size_t{256} << 20);
  return cache;
}

// The sphere scene lit by one white directional light alone (no environment, no ambient), uniform sampling.
render::RenderInputs SphereInputs(int width, int height, uint32_t samples_per_pixel) {
  render::RenderInputs in;
  render::RenderSetup& s = in.setup;
  s.scene = render::MakeScene(render::SceneKind::kSphere);
  render::Light light;
  light.direction = kTowardLight;
  light.rgb = {kIrradiance, kIrradiance, kIrradiance};
  s.lights = {light};
  s.samples_per_pixel = samples_per_pixel;
  s.seed = 3;
  s.texture_scale = s.scene.default_texture_scale;
  in.views.push_back({s.scene.default_camera, width, height, {}, nullptr});
  v1::Material material;
  material.set_preset("velvet");
  std::shared_ptr<const models::PreparedMaterial> prepared;
  EXPECT_EQ(Cache().Get(material, models::Registry::Global(), &prepared), "");
  in.material = prepared;
  in.variants = std::make_unique<render::CachedVariants>(material, models::Registry::Global(), Cache());
  in.materials = &Cache();
  in.sampling = render::Sampling::kUniform;
  return in;
}

// The radiance along the camera ray through image position (px, py), computed here: the nearest hit on the
// unit sphere at the origin (the sphere scene's shape), L = albedo / pi x E x max(0, n . l); -1 for a miss.
double ExpectedRadiance(const render::PinholeCamera& camera, double px, double py) {
  const Vec3 o = camera.position(), d = camera.Direction(px, py);
  const double b = render::Dot(o, d), c = render::Dot(o, o) - 1, disc = b * b - c;
  if (disc < 0) return -1;
  const double t = -b - std::sqrt(disc);
  if (t <= 0) return -1;
  const Vec3 n = render::Normalize(o + t * d);
  return kAlbedo / std::numbers::pi * kIrradiance * std::max(0.0, render::Dot(n, kTowardLight));
}

TEST(Renderer, LambertianSphereMatchesTheClosedFormRadiance) {
  constexpr int kSide = 24;
  render::RenderInputs in = SphereInputs(kSide, kSide, 16);
  const render::Shape& sphere = in.setup.scene.objects.at(0).shape;
  ASSERT_EQ(sphere.kind, render::Shape::Kind::kSphere);
  ASSERT_EQ(sphere.radius, 1);
  ASSERT_EQ(render::Length(sphere.centre), 0);
  const render::PinholeCamera camera(in.views[0].camera, kSide, kSide);
  LambertianEvaluator evaluator(kAlbedo);
  const Rendered run = RenderWith(std::move(in), &evaluator);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  ASSERT_TRUE(run.done);
  ASSERT_EQ(run.images.size(), 1u);
  const imaging::LinearRgbImage& image = run.images[0].image;
  ASSERT_EQ(image.width, kSide);
  ASSERT_EQ(image.height, kSide);
  ASSERT_EQ(image.rgb.size(), size_t{3} * kSide * kSide);
  for (float v : image.rgb) ASSERT_TRUE(std::isfinite(v) && v >= 0) << v;

  // A pixel's value is the mean of its samples, each the radiance at a point of the pixel: within the range of
  // the radiance over the pixel (a 9 x 9 grid of its points, corners included, for a pixel wholly on the sphere).
  // Over all the pixels wholly on the sphere, the samples' mean is the mean radiance over their area (16 x 16
  // points a pixel here) to within the sampling's error, far below 1% over a few hundred pixels.
  int lit = 0, dark = 0, sky = 0;
  double rendered_sum = 0, expected_sum = 0;
  for (int y = 0; y < kSide; ++y)
    for (int x = 0; x < kSide; ++x) {
      double lo = 1e30, hi = -1e30;
      bool on_sphere = true, off_sphere = true;
      for (int j = 0; j <= 8; ++j)
        for (int i = 0; i <= 8; ++i) {
          const double l = ExpectedRadiance(camera, x + i / 8.0, y + j / 8.0);
          on_sphere &= l >= 0;
          off_sphere &= l < 0;
          lo = std::min(lo, l);
          hi = std::max(hi, l);
        }
      double area_mean = 0;
      if (on_sphere)
        for (int j = 0; j < 16; ++j)
          for (int i = 0; i < 16; ++i) area_mean += ExpectedRadiance(camera, x + (i + 0.5) / 16, y + (j + 0.5) / 16) / 256;
      for (int c = 0; c < 3; ++c) {
        const double value = image.rgb[3 * (size_t(y) * kSide + x) + c];
        if (off_sphere) {
          EXPECT_EQ(value, 0) << "pixel " << x << ", " << y << " sees only the black background";
        } else if (on_sphere) {
          const double slack = 1e-4 + 0.02 * (hi - lo);  // float directions; the grid between its points
          EXPECT_GE(value, lo - slack) << "pixel " << x << ", " << y;
          EXPECT_LE(value, hi + slack) << "pixel " << x << ", " << y;
          rendered_sum += value;
          expected_sum += area_mean;
        }
      }
      if (off_sphere) ++sky;
      else if (on_sphere && lo > 0.05) ++lit;
      else if (on_sphere && hi == 0) ++dark;
    }
  std::printf("rendered / closed-form radiance over the pixels wholly on the sphere: %.5f\n", rendered_sum / expected_sum);
  EXPECT_NEAR(rendered_sum / expected_sum, 1, 0.005);
  // The check covered each kind of pixel: the lit side, the side turned from the light, and the background.
  EXPECT_GT(lit, 50);
  EXPECT_GT(dark, 5);
  EXPECT_GT(sky, 50);
  EXPECT_GT(evaluator.chunks(), 0);
}

// Enough samples for several chunks: kRenderChunkQueries / MaxQueriesPerSample pixel samples each.
render::RenderInputs ManyChunkInputs() { return SphereInputs(128, 128, 64); }

TEST(Renderer, CancellationStopsTheLoopWithinOneChunk) {
  LambertianEvaluator whole(kAlbedo);
  const Rendered uncancelled = RenderWith(ManyChunkInputs(), &whole);
  ASSERT_TRUE(uncancelled.status.ok());
  ASSERT_GE(whole.chunks(), 4) << "the render must take several chunks for the test to mean anything";

  LambertianEvaluator evaluator(kAlbedo);
  bool cancelled = false;
  int cancelled_at = 0;
  evaluator.on_submit = [&](int chunk) {
    if (chunk == 2) {
      cancelled = true;
      cancelled_at = chunk;
    }
  };
  const Rendered run = RenderWith(ManyChunkInputs(), &evaluator, [&] {
    return cancelled ? render::Status{batching::JobStatus::kCancelled, "call cancelled"} : render::Status{};
  });
  EXPECT_EQ(run.status.code, batching::JobStatus::kCancelled);
  EXPECT_EQ(run.status.message, "call cancelled");
  EXPECT_FALSE(run.done);
  EXPECT_TRUE(run.images.empty());
  EXPECT_LE(evaluator.chunks() - cancelled_at, 1) << "chunks submitted after the token was cancelled";
  EXPECT_LT(evaluator.chunks(), whole.chunks());
}

TEST(Renderer, EvaluatorFailureEndsTheRenderWithItsStatus) {
  LambertianEvaluator evaluator(kAlbedo);
  evaluator.fail_chunk = 2;
  const Rendered run = RenderWith(ManyChunkInputs(), &evaluator);
  EXPECT_EQ(run.status.code, batching::JobStatus::kInternal);
  EXPECT_EQ(run.status.message, "the device fell over");
  EXPECT_FALSE(run.done);
  EXPECT_TRUE(run.images.empty());
  // One chunk is with the evaluator at a time: nothing was submitted after the failing chunk.
  EXPECT_EQ(evaluator.chunks(), 2);
}

// Two views of one scene: each its own image, the same as a render of that view alone (same seed).
TEST(Renderer, EachViewIsItsOwnImage) {
  render::RenderInputs one = SphereInputs(20, 14, 4);
  LambertianEvaluator alone(kAlbedo);
  const Rendered single = RenderWith(std::move(one), &alone);
  ASSERT_TRUE(single.done);

  render::RenderInputs two = SphereInputs(20, 14, 4);
  render::RenderView side = two.views[0];
  side.camera.position = {3.2, 0.5, 0};
  side.width = 10;
  side.height = 12;
  two.views.push_back(side);
  two.views.push_back(two.views[0]);
  LambertianEvaluator evaluator(kAlbedo);
  const Rendered run = RenderWith(std::move(two), &evaluator);
  ASSERT_TRUE(run.status.ok());
  ASSERT_TRUE(run.done);
  ASSERT_EQ(run.images.size(), 3u);
  EXPECT_EQ(run.images[1].image.width, 10);
  EXPECT_EQ(run.images[1].image.height, 12);
  EXPECT_EQ(run.images[0].image.rgb, single.images[0].image.rgb);
  EXPECT_EQ(run.images[2].image.rgb, single.images[0].image.rgb);
  EXPECT_NE(run.images[1].image.rgb, std::vector<float>(run.images[1].image.rgb.size(), 0.0f));
}

}  // namespace
}  // namespace loomlight
