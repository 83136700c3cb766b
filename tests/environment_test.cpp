// The environment map as two lights (server/render/environment.h): what Draw samples is what Lookup says, and
// its density is the density of its samples. For the built-in sky and a decoded map with a hot spot, detail and
// black pixels: a drawn direction looks up to the same component, radiance and density; the mean of g / pdf over
// a component's draws is the integral of g over the directions it can draw (sphere minus the bright pixels for
// the rest, the bright pixels for the bright one), computed independently from the pixels' exact solid angles;
// the rest's draws, compensated, go less to dim light but never leave it.
#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include <cmath>
#include <fstream>
#include <numbers>
#include <random>
#include <sstream>

#include "server/render/environment.h"

namespace loomlight {
namespace {

constexpr double kPi = std::numbers::pi;
using render::Environment;
using render::Vec3;

struct Map {
  int width = 0, height = 0;
  std::vector<float> rgb;
};

// A map with a smooth gradient, per-pixel detail, a black band and a small hot spot (the bright component):
// a square of (2 sun_radius + 1)^2 pixels.
Map DetailedMap(int width, int height, int sun_radius = 1) {
  Map m{width, height, std::vector<float>(size_t(3) * width * height)};
  std::mt19937 random(7);
  std::uniform_real_distribution<float> detail(0.5f, 1.5f);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      float* p = &m.rgb[3 * (size_t(y) * width + x)];
      const float base = (y > height * 3 / 4 && y < height * 7 / 8) ? 0.0f : (1.0f + float(y) / height) * detail(random);
      p[0] = base;
      p[1] = 0.8f * base;
      p[2] = 0.6f * base;
      if (std::abs(x - width / 3) <= sun_radius && std::abs(y - height / 4) <= sun_radius) p[0] = p[1] = p[2] = 5000.0f;
    }
  return m;
}

Environment Decoded(const Map& m) {
  const std::string path = ::testing::TempDir() + "/environment_test.exr";
  auto out = OIIO::ImageOutput::create(path);
  EXPECT_TRUE(out && out->open(path, OIIO::ImageSpec(m.width, m.height, 3, OIIO::TypeDesc::FLOAT)));
  EXPECT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, m.rgb.data()));
  out->close();
  std::ifstream file(path, std::ios::binary);
  std::stringstream bytes;
  bytes << file.rdbuf();
  Environment env;
  const std::string error = Environment::Decode(bytes.str(), [] { return false; }, nullptr, &env);
  EXPECT_EQ(error, "");
  return env;
}

double Luminance(const float* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }

// The integral of g over the directions of each component, from the pixels' exact solid angles (quadrature at
// 8 x 8 points per pixel): [0] the bright pixels (luminance above `threshold`), [1] the others that are not black.
template <class G>
std::array<double, 2> Integrals(const Map& m, double threshold, G g) {
  std::array<double, 2> sum{0, 0};
  constexpr int kSub = 8;
  for (int y = 0; y < m.height; ++y)
    for (int x = 0; x < m.width; ++x) {
      const float* p = &m.rgb[3 * (size_t(y) * m.width + x)];
      const double lum = Luminance(p);
      if (lum <= 0) continue;
      double pixel = 0;
      for (int j = 0; j < kSub; ++j)
        for (int i = 0; i < kSub; ++i) {
          const double theta = (y + (j + 0.5) / kSub) / m.height * kPi;
          const double phi = ((x + (i + 0.5) / kSub) / m.width - 0.5) * 2 * kPi;
          const Vec3 d{std::sin(theta) * std::sin(phi), std::cos(theta), -std::sin(theta) * std::cos(phi)};
          pixel += g(d) * std::sin(theta);
        }
      sum[lum > threshold ? 0 : 1] += pixel / (kSub * kSub) * (2 * kPi / m.width) * (kPi / m.height);
    }
  return sum;
}

// Draws n directions of `component` and checks each against Lookup; returns the mean of g / pdf (unusable
// draws count 0, as the renderer drops them) and its standard error.
template <class G>
std::pair<double, double> MeanOverDraws(const Environment& env, Environment::Component component, int n, G g) {
  std::mt19937_64 random(11 + component);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  double sum = 0, squares = 0;
  int checked = 0;
  for (int i = 0; i < n; ++i) {
    const Environment::Sample s = env.Draw(component, u(random), u(random));
    if (!(s.pdf > 0)) continue;
    const Environment::Found found = env.Lookup(s.direction);
    if (checked++ < 20000) {
      EXPECT_EQ(found.component, component);
      EXPECT_NEAR(found.pdf, s.pdf, 1e-5 * s.pdf);
      EXPECT_EQ(found.radiance.x, s.radiance.x);
      EXPECT_EQ(found.radiance.z, s.radiance.z);
    }
    const double v = g(s.direction) / s.pdf;
    sum += v;
    squares += v * v;
  }
  const double mean = sum / n;
  return {mean, std::sqrt(std::max(0.0, squares / n - mean * mean) / n)};
}

void ExpectDensityIsTheDraws(const Environment& env, const Map& m, double threshold) {
  const auto g = [](Vec3 d) { return 1.5 + d.y + 0.5 * d.x * d.z; };
  const std::array<double, 2> integral = Integrals(m, threshold, g);
  for (const Environment::Component c : {Environment::kBright, Environment::kRest}) {
    SCOPED_TRACE(c == Environment::kBright ? "bright" : "rest");
    ASSERT_TRUE(env.Has(c));
    const auto [mean, error] = MeanOverDraws(env, c, 400000, g);
    const double expected = integral[c == Environment::kBright ? 0 : 1];
    ASSERT_GT(expected, 0);
    // Within 4 standard errors, and the quadrature's own error (relative 1e-3).
    EXPECT_NEAR(mean, expected, 4 * error + 1e-3 * expected);
  }
}

// The bright component's threshold: kBrightFactor times the map's mean luminance (weighted by sin theta).
double BrightThreshold(const Map& m) {
  double total = 0, weights = 0;
  for (int y = 0; y < m.height; ++y) {
    const double s = std::sin((y + 0.5) / m.height * kPi);
    for (int x = 0; x < m.width; ++x) total += Luminance(&m.rgb[3 * (size_t(y) * m.width + x)]) * s;
    weights += s * m.width;
  }
  return Environment::kBrightFactor * total / weights;
}

TEST(EnvironmentSampling, DecodedMapDrawsWhatItsDensitySays) {
  const Map m = DetailedMap(1024, 512);
  ExpectDensityIsTheDraws(Decoded(m), m, BrightThreshold(m));
}

TEST(EnvironmentSampling, SmallMapDrawsWhatItsDensitySays) {
  const Map m = DetailedMap(40, 20);
  ExpectDensityIsTheDraws(Decoded(m), m, BrightThreshold(m));
}

// Below Environment::kCentreTableMinWidth x kCentreTableMinHeight a drawn point's direction comes from its angles'
// sines and cosines, not the pixel centres' tables and a series: both ways must draw what the density says.
TEST(EnvironmentSampling, MapTooCoarseForCentreTablesDrawsWhatItsDensitySays) {
  // A one-pixel sun: a 3 x 3 one would be more than kMaxBrightFraction of so few pixels.
  const Map m = DetailedMap(Environment::kCentreTableMinWidth - 8, Environment::kCentreTableMinHeight - 4, 0);
  ExpectDensityIsTheDraws(Decoded(m), m, BrightThreshold(m));
}

TEST(EnvironmentSampling, BuiltinSkyDrawAgreesWithLookup) {
  const Environment sky = Environment::Builtin();
  for (const Environment::Component c : {Environment::kBright, Environment::kRest}) {
    ASSERT_TRUE(sky.Has(c));
    // g = 1: the mean of 1 / pdf is the component's solid angle: the sun's disk (2 degrees in radius, soft
    // edge) is about 4e-3 sr; the rest is the sphere less that.
    const auto [mean, error] = MeanOverDraws(sky, c, 200000, [](Vec3) { return 1.0; });
    if (c == Environment::kBright) {
      EXPECT_GT(mean, 2e-3);
      EXPECT_LT(mean, 8e-3);
    } else {
      EXPECT_NEAR(mean, 4 * kPi, 4 * error + 0.01);
    }
  }
}

TEST(EnvironmentSampling, RestDrawsFavourWhatStandsOutButCoverTheDim) {
  // Upper hemisphere at luminance 1, lower at 0.1: drawn in proportion to luminance (times sin theta), 1/11 of
  // the draws would go down. Compensated, fewer do (the material's draws cover dim light), but never fewer than
  // kRestDefensiveFraction of that share, so every lit direction keeps a density.
  Map m{256, 128, std::vector<float>(size_t(3) * 256 * 128)};
  for (int y = 0; y < m.height; ++y)
    for (int x = 0; x < m.width; ++x)
      for (int c = 0; c < 3; ++c) m.rgb[3 * (size_t(y) * m.width + x) + c] = y < m.height / 2 ? 1.0f : 0.1f;
  const Environment env = Decoded(m);
  ASSERT_FALSE(env.Has(Environment::kBright));
  std::mt19937_64 random(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  constexpr int kDraws = 200000;
  int down = 0;
  for (int i = 0; i < kDraws; ++i) {
    const Environment::Sample s = env.Draw(Environment::kRest, u(random), u(random));
    ASSERT_GT(s.pdf, 0);
    down += s.direction.y < 0;
  }
  const double plain_share = 0.1 / 1.1, share = double(down) / kDraws;
  EXPECT_LT(share, 0.8 * plain_share);
  EXPECT_GT(share, Environment::kRestDefensiveFraction * plain_share);
}

}  // namespace
}  // namespace loomlight
