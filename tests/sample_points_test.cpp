// The renderer's low-discrepancy points (server/render/sample_points.h): each pixel's 2^k samples of a dimension
// pair form a (0, k, 2)-net, pairs and pixels are decorrelated, and the points are uniform overall.
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "server/render/sample_points.h"

namespace loomlight::render {
namespace {

// One point in each elementary interval of area 1 / n: every split of n into 2^a x 2^b cells.
TEST(SamplePoints, EachPixelsSamplesFormANet) {
  for (uint32_t n : {4u, 16u, 64u, 256u})
    for (uint64_t pixel : {0ull, 1ull, 77ull, 123456ull})
      for (uint32_t pair : {0u, 1u, 5u}) {
        std::vector<std::array<double, 2>> points;
        for (uint32_t s = 0; s < n; ++s) points.push_back(SamplePoints(42, pixel, s).Get2D(pair));
        for (uint32_t cx = 1; cx <= n; cx *= 2) {
          const uint32_t cy = n / cx;
          std::set<uint32_t> cells;
          for (const auto& p : points) cells.insert(uint32_t(p[0] * cx) * cy + uint32_t(p[1] * cy));
          EXPECT_EQ(cells.size(), n) << n << " samples, " << cx << " x " << cy << " cells, pixel " << pixel
                                     << ", pair " << pair;
        }
      }
}

TEST(SamplePoints, PairsAndPixelsAreScrambledApart) {
  // Different pairs (and pixels) of the same sample must not repeat one another's points.
  int same_pair = 0, same_pixel = 0;
  for (uint32_t s = 0; s < 64; ++s) {
    const auto a = SamplePoints(1, 9, s).Get2D(0), b = SamplePoints(1, 9, s).Get2D(1), c = SamplePoints(1, 10, s).Get2D(0);
    same_pair += std::fabs(a[0] - b[0]) < 1e-6;
    same_pixel += std::fabs(a[0] - c[0]) < 1e-6;
  }
  EXPECT_LT(same_pair, 3);
  EXPECT_LT(same_pixel, 3);
  // Deterministic: a pure function of its arguments.
  EXPECT_EQ(SamplePoints(5, 6, 7).Get2D(3), SamplePoints(5, 6, 7).Get2D(3));
  EXPECT_NE(SamplePoints(5, 6, 7).Get2D(3), SamplePoints(6, 6, 7).Get2D(3));
}

TEST(SamplePoints, OneDimensionIsTheFirstOfThePair) {
  // Get1D is Get2D's first coordinate, so a strategy that needs one number keeps the pair's stratification.
  for (uint64_t pixel = 0; pixel < 64; ++pixel)
    for (uint32_t s = 0; s < 8; ++s)
      for (uint32_t pair = 0; pair < 6; ++pair) {
        const SamplePoints points(11, pixel, s);
        ASSERT_EQ(points.Get1D(pair), points.Get2D(pair)[0]);
        ASSERT_EQ(points.Subsample(s % 4, 4).Get1D(pair), points.Subsample(s % 4, 4).Get2D(pair)[0]);
      }
}

TEST(SamplePoints, UniformOverManyPixels) {
  // Mean and variance of each coordinate over 4096 pixels x 3 samples (a non-power-of-two count too) are those
  // of U(0, 1): 1/2 and 1/12, within a few standard errors; the coordinates are uncorrelated.
  double sum[2] = {0, 0}, sum2[2] = {0, 0}, cross = 0;
  const int n = 4096 * 3;
  for (uint64_t pixel = 0; pixel < 4096; ++pixel)
    for (uint32_t s = 0; s < 3; ++s) {
      const auto p = SamplePoints(3, pixel, s).Get2D(2);
      for (int i = 0; i < 2; ++i) {
        ASSERT_GE(p[i], 0.0);
        ASSERT_LT(p[i], 1.0);
        sum[i] += p[i];
        sum2[i] += p[i] * p[i];
      }
      cross += (p[0] - 0.5) * (p[1] - 0.5);
    }
  for (int i = 0; i < 2; ++i) {
    EXPECT_NEAR(sum[i] / n, 0.5, 4 * std::sqrt(1.0 / 12 / n));
    EXPECT_NEAR(sum2[i] / n - (sum[i] / n) * (sum[i] / n), 1.0 / 12, 0.01);
  }
  EXPECT_NEAR(cross / n, 0.0, 4 * std::sqrt(1.0 / 144 / n));
}

}  // namespace
}  // namespace loomlight::render
