// Adaptive sampling (server/render/adaptive_sampling.h): the allocation spends the budget's work, gives each pixel
// samples in proportion to sqrt(variance / cost), keeps a noiseless image at its first pass and lets an isolated
// noisy pixel's neighbours share its samples; and end to end, an adaptive render reports its sample range, is
// deterministic, stays on the converged image and is not noisier than a uniform one of the same budget.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <cstdio>
#include <numeric>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/render/adaptive_sampling.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using render::AllocateSamples;
using render::PixelNoise;

PixelNoise Uniform(int width, int height, double variance, double cost) {
  PixelNoise noise;
  noise.variance.assign(size_t(width) * height, variance);
  noise.cost.assign(size_t(width) * height, cost);
  return noise;
}

double Work(const PixelNoise& noise, const std::vector<uint32_t>& counts) {
  double work = 0;
  for (size_t p = 0; p < counts.size(); ++p) work += noise.cost[p] * counts[p];
  return work;
}

TEST(AllocateSamples, FirstPassSamplesArePowersOfTwoAtMostHalf) {
  EXPECT_EQ(render::FirstPassSamples(4), 2u);
  EXPECT_EQ(render::FirstPassSamples(8), 4u);
  EXPECT_EQ(render::FirstPassSamples(10), 4u);
  EXPECT_EQ(render::FirstPassSamples(16), 8u);
  EXPECT_EQ(render::FirstPassSamples(64), 16u);
  EXPECT_EQ(render::FirstPassSamples(1024), 16u);
}

TEST(AllocateSamples, NoiselessImageKeepsItsFirstPass) {
  const PixelNoise noise = Uniform(20, 10, 0.0, 1.0);
  for (uint32_t n : AllocateSamples(20, 10, noise, 4, 16, 128)) EXPECT_EQ(n, 4u);
}

TEST(AllocateSamples, EqualNoiseAndCostGetTheBudgetEvenly) {
  const PixelNoise noise = Uniform(16, 16, 0.3, 2.0);
  for (uint32_t n : AllocateSamples(16, 16, noise, 4, 16, 128)) EXPECT_NEAR(n, 16.0, 1.0);
}

// Left half variance v and cost c, right half 4v (or cost 4c): away from the seam the right gets twice (half)
// the left's samples, sqrt(variance / cost); the whole spends the budget's work.
TEST(AllocateSamples, SamplesFollowTheSquareRootOfVarianceOverCost) {
  const int w = 40, h = 8;
  for (const bool by_cost : {false, true}) {
    PixelNoise noise = Uniform(w, h, 1.0, 1.0);
    for (int y = 0; y < h; ++y)
      for (int x = w / 2; x < w; ++x) (by_cost ? noise.cost : noise.variance)[size_t(y) * w + x] = 4.0;
    const std::vector<uint32_t> counts = AllocateSamples(w, h, noise, 2, 16, 128);
    // Means over each side away from the seam (a single pixel's whole count rounds by up to 1 in ~10).
    double left = 0, right = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 3; x < w - 3; ++x) {
        if (x < w / 2 - 3) left += counts[size_t(y) * w + x];
        if (x >= w / 2 + 3) right += counts[size_t(y) * w + x];
      }
    EXPECT_NEAR(right / left, by_cost ? 0.5 : 2.0, 0.15) << "left " << left << ", right " << right;
    double budget = 0;
    for (double c : noise.cost) budget += c * 16;
    EXPECT_NEAR(Work(noise, counts), budget, 0.01 * budget);
    for (uint32_t n : counts) EXPECT_TRUE(n >= 2 && n <= 128) << n;
  }
}

// One noisy pixel in a noiseless image: the most go to it and its neighbourhood (3 x 3 after a first pass of 4,
// 5 x 5 after one of 2), nothing elsewhere, and the cap holds (the rest of the budget stays unspent).
TEST(AllocateSamples, IsolatedNoiseReachesItsNeighboursUpToTheCap) {
  const int w = 9, h = 9;
  PixelNoise noise = Uniform(w, h, 0.0, 1.0);
  noise.variance[size_t(4) * w + 4] = 1.0;
  for (const auto& [first, radius] : {std::pair{4u, 1}, std::pair{2u, 2}}) {
    ASSERT_EQ(render::NoiseNeighbourhoodRadius(first), radius);
    const std::vector<uint32_t> counts = AllocateSamples(w, h, noise, first, 32, 64);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const bool near = std::abs(x - 4) <= radius && std::abs(y - 4) <= radius;
        EXPECT_EQ(counts[size_t(y) * w + x], near ? 64u : first) << x << "," << y << ", first pass " << first;
      }
  }
}

// Variances that are not finite (a radiance overflow upstream) never make a count that is not a number.
TEST(AllocateSamples, NonFiniteVariancesGiveCountsInRange) {
  PixelNoise noise = Uniform(8, 8, 1.0, 1.0);
  noise.variance[10] = std::numeric_limits<double>::infinity();
  noise.variance[40] = std::numeric_limits<double>::quiet_NaN();
  for (const uint32_t first : {2u, 16u}) {  // 16: the first pass alone spends the budget (the multiplier is 0)
    const std::vector<uint32_t> counts = AllocateSamples(8, 8, noise, first, 16, 128);
    for (uint32_t n : counts) EXPECT_TRUE(n >= first && n <= 128) << n;
  }
}

// ---- End to end ----

v1::RenderRequest Request(uint32_t size, uint32_t spp, v1::Sampling sampling, uint64_t seed) {
  v1::RenderRequest r;
  r.mutable_material()->set_preset("polyester_satin_charmeuse_front");
  r.set_scene(v1::SCENE_CYLINDERS);
  r.set_width(size);
  r.set_height(size);
  r.set_samples_per_pixel(spp);
  r.set_sampling(sampling);
  r.set_format(v1::RENDER_FORMAT_EXR);
  r.set_seed(seed);
  return r;
}

class AdaptiveRender : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = testing::StartInProcessServer().release(); }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  // The last update of a render (its image and summary); a failed call is a test failure.
  v1::RenderUpdate Render(const v1::RenderRequest& request, grpc::Status* status = nullptr) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
    auto reader = stub_->Render(&ctx, request);
    v1::RenderUpdate update, last;
    uint64_t done = 0;
    while (reader->Read(&update)) {
      EXPECT_GE(update.samples_done(), done);  // monotone, also across the passes
      done = update.samples_done();
      last = update;
    }
    const grpc::Status s = reader->Finish();
    if (status) *status = s;
    else EXPECT_TRUE(s.ok()) << s.error_message();
    return last;
  }
  std::vector<float> Image(const v1::RenderUpdate& last) {
    return testing::DecodeImage(last.image(), "render.exr").pixels;
  }
  static api::LoomlightServer* server_;
  std::unique_ptr<v1::Loomlight::Stub> stub_ = testing::Connect(server_->port());
};
api::LoomlightServer* AdaptiveRender::server_ = nullptr;

double Rmse(const std::vector<float>& image, const std::vector<float>& reference) {
  double sum = 0;
  for (size_t i = 0; i < reference.size(); ++i) sum += (image[i] - reference[i]) * double(image[i] - reference[i]);
  return std::sqrt(sum / reference.size());
}

TEST_F(AdaptiveRender, ReportsItsSampleRangeAndIsDeterministic) {
  const v1::RenderUpdate adaptive = Render(Request(48, 16, v1::SAMPLING_AUTO, 3));
  EXPECT_TRUE(adaptive.adaptive_sampling());
  EXPECT_EQ(adaptive.min_samples_per_pixel(), render::FirstPassSamples(16));  // the sky behind the cylinders keeps its first pass
  EXPECT_GT(adaptive.max_samples_per_pixel(), 16u);
  EXPECT_LE(adaptive.max_samples_per_pixel(), 8u * 16);
  EXPECT_EQ(adaptive.samples_done(), adaptive.samples_total());
  EXPECT_EQ(Render(Request(48, 16, v1::SAMPLING_AUTO, 3)).image(), adaptive.image());

  const v1::RenderUpdate uniform = Render(Request(48, 16, v1::SAMPLING_UNIFORM, 3));
  EXPECT_FALSE(uniform.adaptive_sampling());
  EXPECT_EQ(uniform.min_samples_per_pixel(), 16u);
  EXPECT_EQ(uniform.max_samples_per_pixel(), 16u);
  EXPECT_EQ(uniform.samples_total(), 48u * 48 * 16);
  EXPECT_FALSE(Render(Request(48, 3, v1::SAMPLING_AUTO, 3)).adaptive_sampling());  // AUTO: uniform below 4
  EXPECT_TRUE(Render(Request(48, 4, v1::SAMPLING_AUTO, 3)).adaptive_sampling());
}

// Against a converged uniform reference, adaptive renders of two seeds: their mean image is as close as a
// uniform render's noise allows (no bias from choosing the counts by the first pass), and their error is no
// more than a uniform render's of the same budget (the allocation is not backwards).
TEST_F(AdaptiveRender, StaysOnTheConvergedImageAndIsNoNoisierThanUniform) {
  const uint32_t size = 64;
  const std::vector<float> reference = Image(Render(Request(size, 1024, v1::SAMPLING_UNIFORM, 1000)));
  double adaptive_error = 0, uniform_error = 0;
  std::vector<double> mean(reference.size(), 0.0);
  for (uint64_t seed : {1, 2}) {
    const std::vector<float> a = Image(Render(Request(size, 16, v1::SAMPLING_ADAPTIVE, seed)));
    const std::vector<float> u = Image(Render(Request(size, 16, v1::SAMPLING_UNIFORM, seed)));
    ASSERT_EQ(a.size(), reference.size());
    adaptive_error += Rmse(a, reference) / 2;
    uniform_error += Rmse(u, reference) / 2;
    for (size_t i = 0; i < a.size(); ++i) mean[i] += a[i] / 2.0;
  }
  double ref_sum = 0, mean_sum = 0;
  for (size_t i = 0; i < reference.size(); ++i) {
    ref_sum += reference[i];
    mean_sum += mean[i];
  }
  std::printf("RMSE against 1024 uniform: adaptive %.5f, uniform %.5f; image mean %.5f vs %.5f\n", adaptive_error,
              uniform_error, mean_sum / reference.size(), ref_sum / reference.size());
  EXPECT_LT(adaptive_error, 1.05 * uniform_error);
  // The image's mean: the sum of ~4,000 noisy pixels; its relative error is far below one pixel's.
  EXPECT_NEAR(mean_sum / ref_sum, 1.0, 0.01);
}

TEST_F(AdaptiveRender, BadSamplingIsNamed) {
  grpc::Status status;
  Render(Request(16, 2, v1::SAMPLING_ADAPTIVE, 1), &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("sampling"), std::string::npos) << status.error_message();
  Render(Request(16, 16, static_cast<v1::Sampling>(9), 1), &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("sampling"), std::string::npos) << status.error_message();
}

}  // namespace
}  // namespace loomlight
