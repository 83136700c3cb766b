// Environment lighting: an equirectangular (latitude-longitude) radiance map, decoded with OpenImageIO from
// bytes in memory (OpenEXR or Radiance HDR, told apart by their magic numbers, never by a name) or the built-in
// procedural sky, importance sampled by a 2D CDF over its pixels (luminance x sin theta).
// Convention: column 0.5 W looks along -z, +x at 0.75 W; row 0 is straight up (+y). The map is piecewise
// constant per pixel, so lookups and the sampling density agree exactly.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "server/models/cdf.h"
#include "server/render/vec.h"

namespace loomlight::render {

class Environment {
 public:
  // Documented limits (docs/thumbnails.md "Limits"): encoded bytes, and pixels checked from the header before any
  // pixel is decoded (a small file can declare a huge image). Non-finite or negative values read as 0.
  static constexpr size_t kMaxEncodedBytes = size_t{32} << 20;
  static constexpr long long kMaxPixels = 1LL << 22;  // e.g. 2048 x 2048 or 4096 x 1024: ~80 MB decoded
  // Maps of at least these sizes (a pixel at most pi / 16 across) find drawn directions from tabled pixel-centre
  // angles and a series; smaller ones from the angles' own sines and cosines.
  static constexpr int kCentreTableMinWidth = 32, kCentreTableMinHeight = 16;

  // A blue sky with a warm sun (2.5 degrees across, elevation 35 degrees, behind the default cameras on the
  // left) over a dim ground: lights every scene with a soft key light and a sky fill, no file needed.
  static Environment Builtin();
  // The studio map of the lighting presets (server/render/lighting_presets.h): a soft bright top over neutral grey
  // walls and a darker floor, the same all the way round (a function of elevation alone, so a turntable's views
  // see the same surroundings). Radiance 1.2 at the top, 0.3 on the walls, 0.1 below: irradiance 2.35 facing up,
  // 0.91 facing sideways.
  static Environment Studio();
  // Decodes an OpenEXR or Radiance HDR file's bytes. `stop` is polled while decoding (a passed deadline or a
  // cancelled call); returning true abandons the work. `admit` (may be empty) is asked for the bytes the
  // decoded map and its decoding will hold, once the header is read and before any pixel is; false
  // abandons the work. Returns "" or the reason the bytes cannot be used, which never quotes them.
  static std::string Decode(std::string_view bytes, const std::function<bool()>& stop,
                            const std::function<bool(size_t)>& admit, Environment* out);
  // The bytes Decode asks `admit` for: the map, its sampling tables and the decoder's buffer.
  static size_t DecodeBytes(long long width, long long height, int channels);
  // Decoded bytes held (shared between copies of this environment).
  size_t bytes() const;

  // Radiance scale and a rotation about +y (degrees) applied to the map.
  void SetTransform(double intensity, double rotation_deg);
  // Turns the map a further `degrees` about +y, in the sense SetTransform's rotation turns it (a turntable's view).
  void Turn(double degrees);
  // Which decoded map this is a copy of (shared between copies; valid while one of them lives) and its
  // transform: equal for environments that give the same radiance everywhere.
  std::string Identity() const;

  Rgb Radiance(Vec3 direction) const;

  // The map is sampled as two lights: its small bright regions (the sun; pixels above kBrightFactor times the
  // map's mean luminance, at most kMaxBrightFraction of its pixels) and the rest. A renderer draws one direction
  // from each (so the sun never competes with the sky for a sample) and weighs them against material samples
  // by multiple importance sampling, for which Lookup gives a direction's component and density.
  static constexpr double kBrightFactor = 64;
  static constexpr double kMaxBrightFraction = 1.0 / 64;
  // The rest is drawn in proportion to its luminance less kRestCompensation times its mean over the sphere, but
  // never below kRestDefensiveFraction of its luminance (MIS compensation, Karlik et al. 2019, kept defensive):
  // the material's draws already cover the dim and middling sky, so the map's own draws go where its light
  // stands out. At 4 spp (6 seeds) against plain luminance: 8% less variance on the satin cylinders, 10% on the
  // satin sphere, 5% on the twill, at the same CPU time. Without the floor the twill's variance tripled: its
  // table, a mean over the pattern's tile, misses texels' lobes, and the map's draws must still find those.
  static constexpr double kRestCompensation = 1.5;
  static constexpr double kRestDefensiveFraction = 0.1;
  enum Component { kBright = 0, kRest = 1 };

  struct Sample {
    Vec3 direction;
    Rgb radiance;     // L(direction)
    double pdf = 0;   // per steradian, of the component drawn from; 0 for an unusable sample
  };
  // Draws a direction of `component` with probability proportional to luminance (u1, u2 uniform in [0, 1): one
  // stratified pair; their remainders place the point inside the pixel).
  Sample Draw(Component component, double u1, double u2) const;
  // Draws for a packet of samples, out[k] = Draw(component, u[k][0], u[k][1]) bit for bit: each step's reads of
  // the tables are started for every sample before any is used, so the cache misses of a packet overlap (a
  // 512 x 256 map's tables outgrow the caches; one draw waits for three misses in a row).
  void DrawPacket(Component component, std::span<const std::array<double, 2>> u, std::span<Sample> out) const;
  // Whether the map has the component (a map without bright regions has only the rest).
  bool Has(Component component) const;

  struct Found {
    Rgb radiance;
    Component component = kRest;
    double pdf = 0;  // the density Draw(component, ...) has toward the direction
  };
  Found Lookup(Vec3 direction) const;
  // Lookup in two steps, for a caller with other work to do while the pixel is read: Locate finds the
  // direction's pixel and starts reading it, Lookup(pixel, direction) finishes as Lookup(direction) does.
  struct PixelRef {
    int x = 0, y = 0;
  };
  PixelRef Locate(Vec3 direction) const;
  Found Lookup(PixelRef pixel, Vec3 direction) const;

  // The map as directions for quadrature (e.g. the BTF's folded environment lighting): its pixels box-filtered
  // into a width x height latitude-longitude grid of cells (fewer where the map has fewer pixels), each at its
  // pixels' mean direction weighted by solid angle, with their solid angle and mean radiance (so each cell
  // carries its pixels' power exactly); the bright component's pixels (the sun) each a cell of their own at
  // full resolution when there are at most max_bright of them (else they join the grid). Cells of no solid
  // angle are left out.
  struct Cell {
    Vec3 direction;
    double solid_angle = 0;
    Rgb radiance;
  };
  std::vector<Cell> Cells(int width, int height, size_t max_bright) const;

  bool black() const { return !map_ || map_->total_weight[kBright] + map_->total_weight[kRest] <= 0; }

 private:
  void SetSize(int width, int height);
  // A procedural map of this size: each pixel the mean of radiance(direction) over 4 x 4 points in it.
  static Environment FromFunction(int width, int height, Rgb (*radiance)(Vec3));
  // Pixel coordinates (continuous) of a world direction, and back.
  void ToImage(Vec3 direction, double* x, double* y) const;
  Vec3 FromImage(double x, double y) const;
  // The world direction of map angles theta (from +y) and phi, given their sines and cosines.
  Vec3 WorldDirection(double sin_theta, double cos_theta, double sin_phi, double cos_phi) const;
  // FromImage(x + fx, y + fy) from the pixel centre's tabled angles (maps at least kCentreTableMinWidth x
  // kCentreTableMinHeight: a pixel spans at most pi / 16 each way).
  Vec3 FromPixelPoint(int x, int y, double fx, double fy) const;
  static double SinTheta(Vec3 direction);
  Rgb Pixel(int x, int y) const;
  // A pixel's sampling weight: its luminance times its row's sin(theta) (at the row's centre).
  static double RowSine(int y, int height);
  struct Map;
  static double Weight(const Map& map, const float* rgb, int y);

  // The decoded map and its sampling tables: immutable once built, so copies (each with its own transform)
  // share one, and a cached map costs its bytes once however many renders use it.
  struct Map {
    int width = 0, height = 0;
    std::vector<float> rgb;
    std::vector<double> row_sine;  // RowSine per row
    // cos(theta) per row centre, sin and cos(phi) per column centre (FromPixelPoint), on maps whose pixels are
    // small enough for its series (else empty).
    std::vector<double> row_cosine, column_sine, column_cosine;
    double bright_luminance = INFINITY;  // pixels above it are the bright component
    double rest_floor = 0;  // kRestCompensation x the rest's mean luminance: taken off its sampling weight
    // The rest: rows, then columns within a row (bright pixels weigh 0 here).
    std::vector<double> row_cdf;     // height + 1 values
    std::vector<double> column_cdf;  // height x (width + 1)
    std::vector<double> row_total;   // per row, its column sums' last (a draw's target without reading the row)
    // The bright component: its pixels (y * width + x) and their CDF.
    std::vector<uint32_t> bright_pixels;
    std::vector<double> bright_cdf;  // bright_pixels.size() + 1
    double total_weight[2] = {0, 0};  // kBright, kRest: sampling weights (Weight) summed
    // Guide tables for the three searches (the same cells, found in a few reads).
    models::CdfGuide row_guide, bright_guide;
    std::vector<models::CdfGuide> column_guides;  // per row
  };
  // The density per steradian of a pixel of sampling weight `weight`, at a direction with this sin(theta).
  double PixelDensity(double weight, Component component, double sin_theta) const;
  // A draw's last step: the point (x + fx, y + fy) of a drawn pixel as a sample of `component`.
  Sample DrawnSample(Component component, int x, int y, double fx, double fy) const;
  static std::shared_ptr<const Map> BuildMap(int width, int height, std::vector<float> rgb);

  std::shared_ptr<const Map> map_;
  int width_ = 0, height_ = 0;  // of map_ (ToImage and FromImage need them before the map exists)
  double below_width_ = 0, below_height_ = 0;  // the largest doubles below them (ToImage's clamp)
  double intensity_ = 1, cos_rotation_ = 1, sin_rotation_ = 0;
};

}  // namespace loomlight::render
