#include "server/render/environment.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "server/models/cdf.h"
#include "server/models/float_angles.h"

namespace loomlight::render {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDegree = kPi / 180;

double Luminance(Rgb c) { return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z; }

double SmoothStep(double edge0, double edge1, double x) {
  const double t = std::clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

Rgb Mix(Rgb a, Rgb b, double t) { return (1 - t) * a + t * b; }

// The built-in sky's radiance toward `d` (unit, world space).
Rgb SkyRadiance(Vec3 d) {
  const Rgb horizon{0.95, 0.97, 1.0}, zenith{0.22, 0.38, 0.85}, ground{0.10, 0.095, 0.085};
  const Rgb sky = Mix(horizon, zenith, std::pow(std::max(d.y, 0.0), 0.4));
  Rgb radiance = Mix(ground, sky, SmoothStep(-0.02, 0.02, d.y));
  // The sun: 2 degrees in radius, irradiance about 3 at normal incidence, with a soft edge.
  const double elevation = 35 * kDegree, azimuth = -40 * kDegree;
  const Vec3 sun{std::cos(elevation) * std::sin(azimuth), std::sin(elevation), std::cos(elevation) * std::cos(azimuth)};
  const double angle = std::acos(std::clamp(Dot(d, sun), -1.0, 1.0));
  const double radius = 2 * kDegree;
  const double disk = 1 - SmoothStep(radius - 0.3 * kDegree, radius + 0.3 * kDegree, angle);
  if (disk > 0) radiance = radiance + (disk * 780.0) * Rgb{1.0, 0.92, 0.80};
  return radiance;
}

// The studio map's radiance toward `d`: floor, walls and a soft top, blended over a few degrees.
Rgb StudioRadiance(Vec3 d) {
  const double floor = 0.1, wall = 0.3, top = 1.2;
  const double above = SmoothStep(-0.04, 0.04, d.y), overhead = SmoothStep(0.45, 0.95, d.y);
  const double radiance = (1 - above) * floor + above * ((1 - overhead) * wall + overhead * top);
  return {radiance, radiance, radiance};
}

}  // namespace

Environment Environment::FromFunction(int width, int height, Rgb (*radiance)(Vec3)) {
  Environment env;
  env.SetSize(width, height);
  std::vector<float> rgb(size_t{3} * env.width_ * env.height_);
  constexpr int kSuper = 4;  // 4 x 4 samples per pixel: a small sun gets smooth pixel values
  for (int y = 0; y < env.height_; ++y)
    for (int x = 0; x < env.width_; ++x) {
      Rgb sum;
      for (int j = 0; j < kSuper; ++j)
        for (int i = 0; i < kSuper; ++i)
          sum = sum + radiance(env.FromImage(x + (i + 0.5) / kSuper, y + (j + 0.5) / kSuper));
      for (int c = 0; c < 3; ++c)
        rgb[3 * (size_t(y) * env.width_ + x) + c] = static_cast<float>(sum[c] / (kSuper * kSuper));
    }
  env.map_ = BuildMap(env.width_, env.height_, std::move(rgb));
  return env;
}

Environment Environment::Builtin() {
  static const Environment prototype = FromFunction(512, 256, SkyRadiance);
  return prototype;
}

Environment Environment::Studio() {
  static const Environment prototype = FromFunction(256, 128, StudioRadiance);
  return prototype;
}

size_t Environment::DecodeBytes(long long width, long long height, int channels) {
  const size_t pixels = size_t(width) * size_t(height);
  const size_t bright = size_t(double(pixels) * kMaxBrightFraction) + 1;
  // Per pixel: the map, the column sums, the decoder's buffer and the column guides' (a bucket per 4 pixels);
  // per row: the row sums, totals, sines, cosines and a column guide; per column a sine and a cosine; the bright
  // pixels and their sums.
  return pixels * (3 * sizeof(float) + sizeof(double) + std::min(channels, 3) * sizeof(float) + sizeof(int)) +
         size_t(height) * (5 * sizeof(double) + sizeof(models::CdfGuide) + 2 * sizeof(int)) +
         size_t(width) * 2 * sizeof(double) + bright * (sizeof(uint32_t) + sizeof(double));
}

std::string Environment::Decode(std::string_view bytes, const std::function<bool()>& stop,
                                const std::function<bool(size_t)>& admit, Environment* out) {
  if (bytes.size() > kMaxEncodedBytes)
    return std::to_string(bytes.size()) + " bytes exceed the limit of " + std::to_string(kMaxEncodedBytes);
  // The format comes from the magic number: a name or extension never picks a reader (OpenImageIO's
  // pseudo-formats such as "null" would invent an image of any size).
  const char* format = nullptr;
  if (bytes.size() >= 4 && bytes.substr(0, 4) == std::string_view("\x76\x2f\x31\x01", 4))
    format = "openexr";
  else if (bytes.substr(0, 2) == "#?")
    format = "hdr";
  else
    return "not an OpenEXR or Radiance HDR file";
  OIIO::Filesystem::IOMemReader memory(bytes.data(), bytes.size());
  auto in = OIIO::ImageInput::create(format);
  if (!in || !in->supports("ioproxy") || !in->set_ioproxy(&memory))
    return std::string("no in-memory ") + format + " reader in OpenImageIO";
  OIIO::ImageSpec spec;
  if (!in->open("environment map", spec))
    return std::string("cannot decode the ") + format + " header: " + in->geterror();
  // Checked from the header, before any pixel is decoded.
  if (spec.width < 2 || spec.height < 1 || spec.nchannels < 1 || spec.depth != 1)
    return "not a 2D image of at least 2 x 1 pixels";
  const long long pixels = static_cast<long long>(spec.width) * spec.height;
  if (pixels > kMaxPixels)
    return std::to_string(spec.width) + " x " + std::to_string(spec.height) + " pixels exceed the limit of " +
           std::to_string(kMaxPixels);
  const int channels = std::min(spec.nchannels, 3);
  if (admit && !admit(DecodeBytes(spec.width, spec.height, channels)))
    return "the server's memory budget cannot take the decoded map now; retry later";
  std::vector<float> pixels_in(size_t(pixels) * channels);
  struct Progress {
    const std::function<bool()>* stop;
    bool stopped = false;
  } progress{&stop};
  // OpenImageIO polls this between scanlines or tiles; true abandons the read.
  const OIIO::ProgressCallback poll = [](void* data, float) {
    auto* p = static_cast<Progress*>(data);
    if (*p->stop && (*p->stop)()) p->stopped = true;
    return p->stopped;
  };
  const bool ok = in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, pixels_in.data(), OIIO::AutoStride,
                                 OIIO::AutoStride, OIIO::AutoStride, poll, &progress);
  if (progress.stopped) return "stopped while decoding (deadline or cancellation)";
  if (!ok) return std::string("cannot decode the ") + format + " pixels: " + in->geterror();
  std::vector<float> rgb(size_t{3} * pixels);
  for (size_t p = 0; p < size_t(pixels); ++p)
    for (int c = 0; c < 3; ++c) {
      const float v = pixels_in[p * channels + std::min(c, channels - 1)];  // grey maps replicate their channel
      rgb[3 * p + c] = std::isfinite(v) && v > 0 ? v : 0.0f;
    }
  Environment env;
  env.SetSize(spec.width, spec.height);
  env.map_ = BuildMap(env.width_, env.height_, std::move(rgb));
  *out = std::move(env);
  return "";
}

size_t Environment::bytes() const {
  if (!map_) return 0;
  size_t guides = map_->row_guide.bytes() + map_->bright_guide.bytes();
  for (const models::CdfGuide& g : map_->column_guides) guides += sizeof g + g.bytes();
  return map_->rgb.size() * sizeof(float) + map_->bright_pixels.size() * sizeof(uint32_t) +
         (map_->row_cdf.size() + map_->row_total.size() + map_->column_cdf.size() + map_->bright_cdf.size() + map_->row_sine.size() +
          map_->row_cosine.size() + map_->column_sine.size() + map_->column_cosine.size()) *
             sizeof(double) +
         guides;
}

std::string Environment::Identity() const {
  char text[160];
  std::snprintf(text, sizeof text, "%p %a %a %a", static_cast<const void*>(map_.get()), intensity_, cos_rotation_,
                sin_rotation_);
  return text;
}

void Environment::SetSize(int width, int height) {
  width_ = width;
  height_ = height;
  below_width_ = std::nextafter(double(width), 0.0);  // once here: GCC leaves nextafter as a library call
  below_height_ = std::nextafter(double(height), 0.0);
}

void Environment::SetTransform(double intensity, double rotation_deg) {
  intensity_ = intensity;
  cos_rotation_ = std::cos(rotation_deg * kDegree);
  sin_rotation_ = std::sin(rotation_deg * kDegree);
}

void Environment::Turn(double degrees) {
  const double c = std::cos(degrees * kDegree), s = std::sin(degrees * kDegree);
  const double cos_rotation = cos_rotation_ * c - sin_rotation_ * s;  // the angle sum, without atan2
  sin_rotation_ = sin_rotation_ * c + cos_rotation_ * s;
  cos_rotation_ = cos_rotation;
}

void Environment::ToImage(Vec3 d, double* x, double* y) const {
  // World to map: rotate by -rotation about +y.
  const Vec3 m{d.x * cos_rotation_ - d.z * sin_rotation_, d.y, d.x * sin_rotation_ + d.z * cos_rotation_};
  // The angles in float (~1e-7 rad, a millionth of a pixel here), without library calls.
  const double u = 0.5 + models::float_angles::Atan2(float(m.x), float(-m.z)) / (2 * kPi);
  const double v = models::float_angles::Acos(float(m.y)) / kPi;
  // Below width and height: a pixel index, never one past the end (u = 1 or v = 1 to rounding).
  *x = std::clamp(u * width_, 0.0, below_width_);
  *y = std::clamp(v * height_, 0.0, below_height_);
}

Vec3 Environment::WorldDirection(double sin_theta, double cos_theta, double sin_phi, double cos_phi) const {
  const Vec3 m{sin_theta * sin_phi, cos_theta, -sin_theta * cos_phi};
  // Map to world: rotate by +rotation about +y.
  return {m.x * cos_rotation_ + m.z * sin_rotation_, m.y, -m.x * sin_rotation_ + m.z * cos_rotation_};
}

Vec3 Environment::FromImage(double x, double y) const {
  // The angles' sines and cosines in float (directions to ~1e-7, as rays and kernels take them), for speed.
  const float phi = float((x / width_ - 0.5) * 2 * kPi), theta = float(y / height_ * kPi);
  const double st = std::sin(theta), ct = std::cos(theta), sp = std::sin(phi), cp = std::cos(phi);
  return WorldDirection(st, ct, sp, cp);
}

namespace {

// sin and cos of a small angle d (|d| <= pi / 32 where used) by their Taylor series to d^7 and d^8: the first
// term left out is below 3e-15 there (FromImage's float angles are good to ~1e-7).
void SmallAngleSinCos(double d, double* sine, double* cosine) {
  const double d2 = d * d;
  *sine = d * (1 - d2 / 6 * (1 - d2 / 20 * (1 - d2 / 42)));
  *cosine = 1 - d2 / 2 * (1 - d2 / 12 * (1 - d2 / 30 * (1 - d2 / 56)));
}

}  // namespace

Vec3 Environment::FromPixelPoint(int x, int y, double fx, double fy) const {
  // The angles as the pixel centre's (tabled sines and cosines) plus a small offset: angle-sum identities and a
  // short series instead of two library sincos calls per drawn direction (2% of a render's CPU).
  const Map& map = *map_;
  double sd, cd, se, ce;
  SmallAngleSinCos((fy - 0.5) / height_ * kPi, &sd, &cd);
  SmallAngleSinCos((fx - 0.5) / width_ * 2 * kPi, &se, &ce);
  const double st0 = map.row_sine[size_t(y)], ct0 = map.row_cosine[size_t(y)];
  const double sp0 = map.column_sine[size_t(x)], cp0 = map.column_cosine[size_t(x)];
  const double st = st0 * cd + ct0 * sd, ct = ct0 * cd - st0 * sd;
  const double sp = sp0 * ce + cp0 * se, cp = cp0 * ce - sp0 * se;
  return WorldDirection(st, ct, sp, cp);
}

Rgb Environment::Pixel(int x, int y) const {
  const float* p = &map_->rgb[3 * (size_t(y) * width_ + x)];
  return intensity_ * Rgb{p[0], p[1], p[2]};
}

Rgb Environment::Radiance(Vec3 direction) const {
  double x, y;
  ToImage(direction, &x, &y);
  return Pixel(static_cast<int>(x), static_cast<int>(y));
}

// sin(theta) of a direction (the map turns about +y): Draw and Lookup compute a direction's density alike.
double Environment::SinTheta(Vec3 direction) { return std::sqrt(std::max(0.0, 1 - direction.y * direction.y)); }

double Environment::RowSine(int y, int height) { return std::sin((y + 0.5) / height * kPi); }

double Environment::Weight(const Map& map, const float* p, int y) {
  const double l = Luminance({p[0], p[1], p[2]});
  const double sampled = l > map.bright_luminance ? l : std::max(kRestDefensiveFraction * l, l - map.rest_floor);
  return sampled * map.row_sine[size_t(y)];
}

std::shared_ptr<const Environment::Map> Environment::BuildMap(int width, int height, std::vector<float> rgb) {
  auto map = std::make_shared<Map>();
  map->width = width;
  map->height = height;
  map->rgb = std::move(rgb);
  const size_t pixels = size_t(width) * height;
  map->row_sine.resize(size_t(height));
  for (int y = 0; y < height; ++y) map->row_sine[size_t(y)] = RowSine(y, height);
  if (width >= kCentreTableMinWidth && height >= kCentreTableMinHeight) {
    map->row_cosine.resize(size_t(height));
    for (int y = 0; y < height; ++y) map->row_cosine[size_t(y)] = std::cos((y + 0.5) / height * kPi);
    map->column_sine.resize(size_t(width));
    map->column_cosine.resize(size_t(width));
    for (int x = 0; x < width; ++x) {
      const double phi = ((x + 0.5) / width - 0.5) * 2 * kPi;
      map->column_sine[size_t(x)] = std::sin(phi);
      map->column_cosine[size_t(x)] = std::cos(phi);
    }
  }
  const auto weight = [&](size_t p) { return Weight(*map, &map->rgb[3 * p], int(p / size_t(width))); };
  double total = 0;  // of plain luminance: the rest's compensation (rest_floor) is set from it below
  for (size_t p = 0; p < pixels; ++p) total += weight(p);
  // The bright component: pixels far above the map's mean radiance, unless there are too many of them to be
  // small lights.
  std::vector<double> luminance(pixels);
  for (size_t p = 0; p < pixels; ++p) luminance[p] = Luminance({map->rgb[3 * p], map->rgb[3 * p + 1], map->rgb[3 * p + 2]});
  const double threshold = kBrightFactor * total / (pixels * 2 / kPi);  // mean luminance: total / sum of sin
  size_t bright = 0;
  for (size_t p = 0; p < pixels; ++p) bright += luminance[p] > threshold;
  if (bright > 0 && double(bright) <= kMaxBrightFraction * double(pixels)) map->bright_luminance = threshold;
  // The rest's mean luminance over the sphere (bright pixels count as 0), for its compensated weights.
  double rest = 0, sines = 0;
  for (size_t p = 0; p < pixels; ++p) {
    const double sine = map->row_sine[p / size_t(width)];
    sines += sine;
    if (luminance[p] <= map->bright_luminance) rest += luminance[p] * sine;
  }
  map->rest_floor = sines > 0 ? kRestCompensation * rest / sines : 0.0;
  map->bright_cdf.push_back(0);
  map->row_cdf.assign(height + 1, 0.0);
  map->row_total.assign(height, 0.0);
  map->column_cdf.assign(size_t(height) * (width + 1), 0.0);
  for (int y = 0; y < height; ++y) {
    double* cdf = &map->column_cdf[size_t(y) * (width + 1)];
    for (int x = 0; x < width; ++x) {
      const size_t p = size_t(y) * width + x;
      const double w = weight(p);
      const bool is_bright = luminance[p] > map->bright_luminance;
      cdf[x + 1] = cdf[x] + (is_bright ? 0.0 : w);
      if (is_bright) {
        map->bright_pixels.push_back(uint32_t(p));
        map->bright_cdf.push_back(map->bright_cdf.back() + w);
      }
    }
    map->row_total[y] = cdf[width];
    map->row_cdf[y + 1] = map->row_cdf[y] + cdf[width];
  }
  map->total_weight[kRest] = map->row_cdf[height];
  map->total_weight[kBright] = map->bright_cdf.back();
  // A row's guide has a bucket per 4 pixels: a search then reads about 12 neighbouring sums (2 cache lines).
  map->row_guide = models::CdfGuide(map->row_cdf.data(), height, height);
  map->bright_guide = models::CdfGuide(map->bright_cdf.data(), int(map->bright_pixels.size()), int(map->bright_pixels.size()));
  map->column_guides.reserve(size_t(height));
  for (int y = 0; y < height; ++y)
    map->column_guides.emplace_back(&map->column_cdf[size_t(y) * (width + 1)], width, std::max(1, width / 4));
  return map;
}

bool Environment::Has(Component component) const {
  return map_ && intensity_ > 0 && map_->total_weight[component] > 0;
}

double Environment::PixelDensity(double weight, Component component, double sin_theta) const {
  if (sin_theta < 1e-6) return 0;  // at a pole the density is singular: such samples are dropped
  // pdf(pixel) W H over the pixel's (u, v) area, divided by the Jacobian 2 pi^2 sin(theta) to steradians.
  return weight / map_->total_weight[component] * width_ * height_ / (2 * kPi * kPi * sin_theta);
}


Environment::Sample Environment::Draw(Component component, double u1, double u2) const {
  const std::array<double, 2> u{u1, u2};
  Sample sample;
  DrawPacket(component, {&u, 1}, {&sample, 1});
  return sample;
}

void Environment::DrawPacket(Component component, std::span<const std::array<double, 2>> u, std::span<Sample> out) const {
  if (!Has(component)) {
    std::fill(out.begin(), out.end(), Sample{});
    return;
  }
  const Map& map = *map_;
  if (component == kBright) {  // a few pixels' sums, in the cache: one draw at a time
    for (size_t k = 0; k < u.size(); ++k) {
      // The pixel from u1 (its remainder places the point across the pixel), u2 down it.
      double fx;
      const int i = map.bright_guide.Search(map.bright_cdf.data(), int(map.bright_pixels.size()),
                                            u[k][0] * map.total_weight[kBright], &fx);
      out[k] = DrawnSample(component, int(map.bright_pixels[i] % width_), int(map.bright_pixels[i] / width_), fx, u[k][1]);
    }
    return;
  }
  // The row from u1, the column within it from u2; their remainders place the point inside the pixel. In
  // steps over the packet, each prefetching what the next reads: the row's guide entry, its sums, the pixel.
  constexpr size_t kStep = 16;
  for (size_t first = 0; first < u.size(); first += kStep) {
    const size_t n = std::min(kStep, u.size() - first);
    std::array<int, kStep> x, y, lo, hi;
    std::array<double, kStep> fx, fy, target;
    for (size_t k = 0; k < n; ++k) {
      y[k] = map.row_guide.Search(map.row_cdf.data(), height_, u[first + k][0] * map.total_weight[kRest], &fy[k]);
      target[k] = u[first + k][1] * map.row_total[size_t(y[k])];
      if (const int* bucket = map.column_guides[size_t(y[k])].Bucket(target[k])) __builtin_prefetch(bucket);
    }
    for (size_t k = 0; k < n; ++k) {
      map.column_guides[size_t(y[k])].Range(width_, target[k], &lo[k], &hi[k]);
      __builtin_prefetch(&map.column_cdf[size_t(y[k]) * (width_ + 1) + size_t(lo[k])]);
    }
    for (size_t k = 0; k < n; ++k) {
      if (!(map.row_total[size_t(y[k])] > 0)) continue;
      x[k] = models::CdfGuide::SearchRange(&map.column_cdf[size_t(y[k]) * (width_ + 1)], width_, lo[k], hi[k],
                                           target[k], &fx[k]);
      __builtin_prefetch(&map.rgb[3 * (size_t(y[k]) * width_ + size_t(x[k]))]);
    }
    for (size_t k = 0; k < n; ++k)
      out[first + k] = map.row_total[size_t(y[k])] > 0 ? DrawnSample(component, x[k], y[k], fx[k], fy[k]) : Sample{};
  }
}

Environment::Sample Environment::DrawnSample(Component component, int x, int y, double fx, double fy) const {
  Sample sample;
  const double weight = Weight(*map_, &map_->rgb[3 * (size_t(y) * width_ + x)], y);
  if (weight <= 0) return sample;
  sample.direction = map_->row_cosine.empty() ? FromImage(x + fx, y + fy) : FromPixelPoint(x, y, fx, fy);
  sample.radiance = Pixel(x, y);
  sample.pdf = PixelDensity(weight, component, SinTheta(sample.direction));
  return sample;
}

std::vector<Environment::Cell> Environment::Cells(int width, int height, size_t max_bright) const {
  std::vector<Cell> out;
  if (!map_) return out;
  const Map& map = *map_;
  const int cw = std::clamp(width, 1, width_), ch = std::clamp(height, 1, height_);
  const bool bright_apart = map.bright_pixels.size() <= max_bright;
  std::vector<Cell> grid(size_t(cw) * ch);  // sums: direction and radiance times solid angle
  for (int y = 0; y < height_; ++y) {
    // The pixel's exact solid angle: its longitude span times the difference of cos(theta) over its row.
    const double solid_angle = 2 * kPi / width_ * (std::cos(kPi * y / height_) - std::cos(kPi * (y + 1) / height_));
    for (int x = 0; x < width_; ++x) {
      const float* p = &map.rgb[3 * (size_t(y) * width_ + x)];
      const Vec3 direction = FromImage(x + 0.5, y + 0.5);
      const Rgb radiance = Pixel(x, y);
      if (bright_apart && Luminance({p[0], p[1], p[2]}) > map.bright_luminance) {
        out.push_back({direction, solid_angle, radiance});
        continue;
      }
      Cell& cell = grid[size_t(y) * ch / height_ * cw + size_t(x) * cw / width_];
      cell.direction = cell.direction + solid_angle * direction;
      cell.solid_angle += solid_angle;
      cell.radiance = cell.radiance + solid_angle * radiance;
    }
  }
  for (Cell& cell : grid) {
    if (!(cell.solid_angle > 0) || Length(cell.direction) <= 0) continue;
    out.push_back({Normalize(cell.direction), cell.solid_angle, (1 / cell.solid_angle) * cell.radiance});
  }
  return out;
}

Environment::Found Environment::Lookup(Vec3 direction) const { return Lookup(Locate(direction), direction); }

Environment::PixelRef Environment::Locate(Vec3 direction) const {
  if (!map_) return {};
  double px, py;
  ToImage(direction, &px, &py);
  const PixelRef pixel{static_cast<int>(px), static_cast<int>(py)};
  __builtin_prefetch(&map_->rgb[3 * (size_t(pixel.y) * width_ + pixel.x)]);
  return pixel;
}

Environment::Found Environment::Lookup(PixelRef pixel, Vec3 direction) const {
  Found found;
  if (!map_) return found;
  const float* p = &map_->rgb[3 * (size_t(pixel.y) * width_ + pixel.x)];
  found.radiance = Pixel(pixel.x, pixel.y);
  found.component = Luminance({p[0], p[1], p[2]}) > map_->bright_luminance ? kBright : kRest;
  if (Has(found.component)) found.pdf = PixelDensity(Weight(*map_, p, pixel.y), found.component, SinTheta(direction));
  return found;
}

}  // namespace loomlight::render
