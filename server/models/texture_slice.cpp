#include "server/models/texture_slice.h"

#include <cmath>

#include "server/models/query_means.h"
#include "server/models/rng.h"

namespace loomlight::models {
namespace {

// The R2 sequence's generators: 1/phi2 and 1/phi2^2, phi2 the plastic number (Roberts 2018).
constexpr double kR2[2] = {0.7548776662, 0.5698402910};

double Fraction(double t) { return t - std::floor(t); }  // exact, so always < 1

// The Cranley-Patterson rotation of a pixel's sample set: two numbers in [0, 1) from a hash of its index.
std::array<double, 2> PixelRotation(uint64_t pixel) {
  const uint64_t h = Mix64(pixel);  // a fixed, well-mixed hash of the pixel index
  return {static_cast<double>(h >> 40) * 0x1p-24, static_cast<double>((h >> 16) & 0xffffff) * 0x1p-24};
}

std::array<double, 2> RotatedR2(uint32_t sample, const std::array<double, 2>& rotation) {
  const double i = sample + 0.5;
  return {Fraction(i * kR2[0] + rotation[0]), Fraction(i * kR2[1] + rotation[1])};
}

}  // namespace

std::array<double, 2> PixelSampleOffset(uint64_t pixel, uint32_t sample, uint32_t samples) {
  if (samples <= 1) return {0.5, 0.5};
  return RotatedR2(sample, PixelRotation(pixel));
}

void SliceTexturePositions(const SliceSampling& slice, uint64_t first, size_t count, float* uv) {
  const uint32_t samples = slice.samples;
  const double du = slice.u_max - slice.u_min, dv = slice.v_max - slice.v_min;
  uint64_t pixel = first / samples;
  uint32_t x = static_cast<uint32_t>(pixel % slice.width), y = static_cast<uint32_t>(pixel / slice.width);
  for (size_t p = 0; p < count / samples; ++p, ++pixel) {
    // One rotation per pixel, not per sample: PixelSampleOffset's positions, the hash computed once.
    const std::array<double, 2> rotation = samples > 1 ? PixelRotation(pixel) : std::array<double, 2>{};
    for (uint32_t s = 0; s < samples; ++s) {
      const auto [sx, sy] = samples > 1 ? RotatedR2(s, rotation) : std::array<double, 2>{0.5, 0.5};
      *uv++ = static_cast<float>(slice.u_min + (x + sx) / slice.width * du);
      *uv++ = static_cast<float>(slice.v_max - (y + sy) / slice.height * dv);  // y = 0 is the top row
    }
    if (++x == slice.width) {
      x = 0;
      ++y;
    }
  }
}

std::string AddPixelMeans(uint32_t samples, uint64_t first, size_t count, double* f, imaging::LinearRgbImage* image,
                          std::array<double, 3>* sum) {
  const size_t pixels = count / samples;
  if (GroupMeansInPlace(f, pixels, samples) < pixels) return "the BTF kernel returned a non-finite value";
  float* out = image->rgb.data() + 3 * (first / samples);
  for (size_t i = 0; i < 3 * pixels; ++i) {
    out[i] = static_cast<float>(f[i]);
    (*sum)[i % 3] += f[i];
  }
  return "";
}

std::vector<float> RepeatedDirection(const float xyz[3], size_t count) {
  std::vector<float> repeated(3 * count);
  for (size_t q = 0; q < count; ++q)
    for (int c = 0; c < 3; ++c) repeated[3 * q + c] = xyz[c];
  return repeated;
}

}  // namespace loomlight::models
