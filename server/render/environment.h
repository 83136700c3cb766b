// Environment lighting: an equirectangular (latitude-longitude) radiance map, read with OpenImageIO (EXR, HDR)
// or the built-in procedural sky, importance sampled by a 2D CDF over its pixels (luminance x sin theta).
// Convention: column 0.5 W looks along -z, +x at 0.75 W; row 0 is straight up (+y). The map is piecewise
// constant per pixel, so lookups and the sampling density agree exactly.
#pragma once

#include <string>
#include <vector>

#include "server/render/vec.h"

namespace loomlight::render {

class Environment {
 public:
  // Documented limits for files: at most kMaxPixels pixels; non-finite or negative values read as 0.
  static constexpr long long kMaxPixels = 1LL << 26;

  // A blue sky with a warm sun (2.5 degrees across, elevation 35 degrees, behind the default cameras on the
  // left) over a dim ground: lights every scene with a soft key light and a sky fill, no file needed.
  static Environment Builtin();
  // Reads `path`. Returns "" or the reason it cannot be used.
  static std::string Load(const std::string& path, Environment* out);

  // Radiance scale and a rotation about +y (degrees) applied to the map.
  void SetTransform(double intensity, double rotation_deg);

  Rgb Radiance(Vec3 direction) const;

  struct Sample {
    Vec3 direction;
    Rgb radiance_over_pdf;  // L(direction) / pdf(direction), pdf per steradian; 0 for an unusable sample
  };
  // Draws a direction with probability proportional to the map's luminance (u1, u2, u3 uniform in [0, 1)).
  Sample Draw(double u1, double u2, double u3) const;
  bool black() const { return total_weight_ <= 0; }

 private:
  void BuildDistribution();
  // Pixel coordinates (continuous) of a world direction, and back.
  void ToImage(Vec3 direction, double* x, double* y) const;
  Vec3 FromImage(double x, double y) const;
  Rgb Pixel(int x, int y) const;

  int width_ = 0, height_ = 0;
  std::vector<float> rgb_;
  double intensity_ = 1, cos_rotation_ = 1, sin_rotation_ = 0;
  std::vector<double> row_cdf_;     // height + 1 values
  std::vector<double> column_cdf_;  // height x (width + 1)
  double total_weight_ = 0;
};

}  // namespace loomlight::render
