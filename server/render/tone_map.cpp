#include "server/render/tone_map.h"

#include <algorithm>
#include <cmath>

namespace loomlight::render {
double AutomaticExposure(const imaging::LinearRgbImage& image, const std::vector<float>* coverage) {
  double log_sum = 0, weight_sum = 0;
  const size_t pixels = image.rgb.size() / 3;
  for (size_t p = 0; p < pixels; ++p) {
    const double weight = coverage ? (p < coverage->size() ? imaging::ClampedCoverage((*coverage)[p]) : 0.0) : 1.0;
    const double y = 0.2126 * image.rgb[3 * p] + 0.7152 * image.rgb[3 * p + 1] + 0.0722 * image.rgb[3 * p + 2];
    if (weight > 0 && y > 1e-8 && std::isfinite(y)) {
      log_sum += weight * std::log(y);
      weight_sum += weight;
    }
  }
  if (weight_sum == 0) return 1.0;
  const double exposure = 0.18 / std::exp(log_sum / weight_sum);
  return std::isfinite(exposure) && exposure > 0 ? exposure : 1.0;
}

void ProductColour(const std::vector<float>& coverage, imaging::LinearRgbImage* image) {
  const size_t pixels = std::min(image->rgb.size() / 3, coverage.size());
  for (size_t p = 0; p < pixels; ++p) {
    const float c = imaging::ClampedCoverage(coverage[p]);
    for (int k = 0; k < 3; ++k) image->rgb[3 * p + k] = c > 0 ? image->rgb[3 * p + k] / c : 0.0f;
  }
}

double Fill(const std::vector<float>& coverage) {
  if (coverage.empty()) return 0;
  double sum = 0;
  for (float c : coverage) sum += imaging::ClampedCoverage(c);
  return sum / static_cast<double>(coverage.size());
}

double AcesFilmic(double x) {
  if (!(x > 0)) return 0.0;  // also NaN
  if (!std::isfinite(x)) return 1.0;
  return std::clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

void ToneMap(double exposure, imaging::LinearRgbImage* image) {
  for (float& v : image->rgb) v = static_cast<float>(AcesFilmic(exposure * v));
}

}  // namespace loomlight::render
