#include "server/render/tone_map.h"

#include <algorithm>
#include <cmath>

namespace loomlight::render {

double AutomaticExposure(const imaging::LinearRgbImage& image) {
  double log_sum = 0;
  size_t count = 0;
  for (size_t p = 0; p + 2 < image.rgb.size(); p += 3) {
    const double y = 0.2126 * image.rgb[p] + 0.7152 * image.rgb[p + 1] + 0.0722 * image.rgb[p + 2];
    if (y > 1e-8 && std::isfinite(y)) {
      log_sum += std::log(y);
      ++count;
    }
  }
  if (count == 0) return 1.0;
  const double exposure = 0.18 / std::exp(log_sum / count);
  return std::isfinite(exposure) && exposure > 0 ? exposure : 1.0;
}

double AcesFilmic(double x) {
  if (!(x > 0)) return 0.0;  // also NaN
  if (!std::isfinite(x)) return 1.0;
  return std::clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

imaging::LinearRgbImage ToneMap(const imaging::LinearRgbImage& image, double exposure) {
  imaging::LinearRgbImage out = image;
  for (float& v : out.rgb) v = static_cast<float>(AcesFilmic(exposure * v));
  return out;
}

}  // namespace loomlight::render
