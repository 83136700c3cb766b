#include "server/imaging/image_encode.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>

namespace loomlight::imaging {
namespace {

float FiniteOrZero(float v) { return std::isfinite(v) ? v : 0.0f; }

// The inverse of the sRGB transfer function (IEC 61966-2-1).
double SrgbToLinear(double encoded) {
  return encoded <= 0.04045 ? encoded / 12.92 : std::pow((encoded + 0.055) / 1.055, 2.4);
}

// The linear values at which the 8-bit code round(255 srgb(x)) steps from k to k + 1: a code is then the
// number of thresholds at or below x, found by binary search instead of a pow per channel (5x faster).
const std::array<double, 255>& SrgbCodeThresholds() {
  static const std::array<double, 255> thresholds = [] {
    std::array<double, 255> t;
    for (int k = 0; k < 255; ++k) t[k] = SrgbToLinear((k + 0.5) / 255.0);
    return t;
  }();
  return thresholds;
}

std::vector<unsigned char> ToSrgb8(const LinearRgbImage& image, double exposure) {
  const std::array<double, 255>& thresholds = SrgbCodeThresholds();
  std::vector<unsigned char> out(image.rgb.size());
  for (size_t i = 0; i < image.rgb.size(); ++i) {
    const double scaled = static_cast<double>(FiniteOrZero(image.rgb[i])) * exposure;  // clamped by the search
    out[i] = static_cast<unsigned char>(std::upper_bound(thresholds.begin(), thresholds.end(), scaled) -
                                        thresholds.begin());
  }
  return out;
}

// The pixels with any non-finite value replaced by 0; the image itself when all are finite (no copy).
const std::vector<float>& FinitePixels(const LinearRgbImage& image, std::vector<float>* storage) {
  if (std::all_of(image.rgb.begin(), image.rgb.end(), [](float v) { return std::isfinite(v); })) return image.rgb;
  storage->resize(image.rgb.size());
  std::transform(image.rgb.begin(), image.rgb.end(), storage->begin(), FiniteOrZero);
  return *storage;
}

// Little-endian whatever the host's byte order.
std::string RawFloats(const std::vector<float>& values) {
  std::string bytes(4 * values.size(), '\0');
  for (size_t i = 0; i < values.size(); ++i) {
    const uint32_t bits = std::bit_cast<uint32_t>(values[i]);
    for (int b = 0; b < 4; ++b) bytes[4 * i + b] = static_cast<char>((bits >> (8 * b)) & 0xffu);
  }
  return bytes;
}

// Writes one image through OpenImageIO into memory: the plugin is chosen by `name`'s extension, and the
// bytes go to an in-memory IOProxy instead of a file.
std::string WriteInMemory(const char* name, const OIIO::ImageSpec& spec, OIIO::TypeDesc data_type, const void* data,
                          std::string* bytes) {
  OIIO::Filesystem::IOVecOutput proxy;
  auto out = OIIO::ImageOutput::create(name, &proxy);
  if (!out) return std::string("no OpenImageIO writer for ") + name + ": " + OIIO::geterror();
  if (!out->supports("ioproxy")) return std::string("the OpenImageIO writer for ") + name + " cannot write to memory";
  if (!out->open(name, spec) || !out->write_image(data_type, data) || !out->close())
    return std::string("cannot encode ") + name + ": " + out->geterror();
  const std::vector<unsigned char>& buffer = proxy.buffer();
  bytes->assign(buffer.begin(), buffer.end());
  return "";
}

}  // namespace

double AutomaticExposure(const LinearRgbImage& image) {
  const size_t pixels = image.rgb.size() / 3;
  if (pixels == 0) return 1.0;
  std::vector<float> brightest(pixels);
  for (size_t p = 0; p < pixels; ++p)
    brightest[p] = FiniteOrZero(std::max({image.rgb[3 * p], image.rgb[3 * p + 1], image.rgb[3 * p + 2]}));
  const size_t rank = static_cast<size_t>(0.99 * static_cast<double>(pixels - 1));
  std::nth_element(brightest.begin(), brightest.begin() + rank, brightest.end());
  const double p99 = brightest[rank];
  const double exposure = 1.0 / p99;
  return p99 > 0.0 && std::isfinite(exposure) ? exposure : 1.0;
}

std::string EncodeImage(const LinearRgbImage& image, ImageFormat format, double exposure, std::string* bytes) {
  if (image.width <= 0 || image.height <= 0 || image.rgb.size() != size_t(image.width) * image.height * 3)
    return "image size does not match its pixels";
  std::vector<float> storage;
  switch (format) {
    case ImageFormat::kRaw:
      *bytes = RawFloats(FinitePixels(image, &storage));
      return "";
    case ImageFormat::kExr: {
      OIIO::ImageSpec spec(image.width, image.height, 3, OIIO::TypeDesc::FLOAT);
      spec.attribute("compression", "zip");
      spec.attribute("oiio:ColorSpace", "Linear");
      // OpenImageIO's EXR writer stamps the wall-clock time (capDate) when DateTime is not given, so identical
      // images would differ by the second they were encoded; an empty DateTime keeps the bytes a function of
      // the pixels (the PNG and JPEG writers add no date of their own).
      spec.attribute("DateTime", "");
      return WriteInMemory("image.exr", spec, OIIO::TypeDesc::FLOAT, FinitePixels(image, &storage).data(), bytes);
    }
    case ImageFormat::kPng:
    case ImageFormat::kJpeg: {
      OIIO::ImageSpec spec(image.width, image.height, 3, OIIO::TypeDesc::UINT8);
      spec.attribute("oiio:ColorSpace", "sRGB");
      if (format == ImageFormat::kJpeg) spec.attribute("Compression", "jpeg:90");
      const std::vector<unsigned char> srgb = ToSrgb8(image, exposure);
      return WriteInMemory(format == ImageFormat::kJpeg ? "image.jpg" : "image.png", spec, OIIO::TypeDesc::UINT8,
                           srgb.data(), bytes);
    }
  }
  return "unknown image format";
}

std::string DecodeImage(const std::string& bytes, size_t max_pixels, LinearRgbImage* image,
                        const std::function<std::string(int, int, int)>& admit) {
  // The reader is chosen by the bytes' signature; OpenImageIO picks a reader by the name's extension.
  const char* name = nullptr;
  if (bytes.rfind("\x89PNG\r\n\x1a\n", 0) == 0) name = "image.png";
  else if (bytes.rfind("\xff\xd8\xff", 0) == 0) name = "image.jpg";
  else if (bytes.rfind(std::string("\x76\x2f\x31\x01", 4), 0) == 0) name = "image.exr";
  if (!name) return "not a PNG, JPEG or OpenEXR image";
  OIIO::Filesystem::IOMemReader reader(const_cast<char*>(bytes.data()), bytes.size());
  auto in = OIIO::ImageInput::open(name, nullptr, &reader);
  if (!in) {
    (void)OIIO::geterror();  // cleared: the library's message may quote the bytes
    return std::string("undecodable ") + (name + 6) + " data";
  }
  const OIIO::ImageSpec& spec = in->spec();
  const int channels = spec.nchannels;
  if (spec.width < 1 || spec.height < 1 || uint64_t(spec.width) * uint64_t(spec.height) > max_pixels)
    return "its " + std::to_string(spec.width) + " x " + std::to_string(spec.height) + " pixels are out of range";
  if (channels != 1 && channels != 3 && channels != 4)
    return std::to_string(channels) + " channels (1, 3 or 4 are read)";
  if (admit)
    if (std::string e = admit(spec.width, spec.height, channels); !e.empty()) return e;
  std::vector<float> pixels(size_t(spec.width) * spec.height * channels);
  if (!in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, pixels.data())) {
    (void)in->geterror();
    return std::string("undecodable ") + (name + 6) + " data";
  }
  const bool srgb = std::string(name) != "image.exr";  // 8-bit formats carry sRGB codes, EXR linear values
  image->width = spec.width;
  image->height = spec.height;
  image->rgb.resize(size_t(spec.width) * spec.height * 3);
  for (size_t p = 0; p < size_t(spec.width) * spec.height; ++p)
    for (int c = 0; c < 3; ++c) {
      const float v = pixels[p * channels + (channels == 1 ? 0 : c)];
      image->rgb[3 * p + c] = srgb ? float(SrgbToLinear(v)) : v;
    }
  return "";
}

}  // namespace loomlight::imaging
