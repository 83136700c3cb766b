#include "server/imaging/image_encode.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <webp/encode.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>

#include "server/imaging/srgb.h"

namespace loomlight::imaging {
namespace {

float FiniteOrZero(float v) { return std::isfinite(v) ? v : 0.0f; }

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

// Pixels of `channels` 8-bit values each: RGB sRGB codes of image x exposure, with kWhite blended over 255 by
// coverage, and with kTransparent (channels 4) an alpha of round(255 coverage). See EncodeImage.
std::vector<unsigned char> ToSrgb8(const LinearRgbImage& image, double exposure, Background background,
                                   const std::vector<float>* coverage, int channels) {
  const std::array<double, 255>& thresholds = SrgbCodeThresholds();
  const size_t pixels = image.rgb.size() / 3;
  std::vector<unsigned char> out(pixels * channels);
  for (size_t p = 0; p < pixels; ++p) {
    const double alpha = background == Background::kScene ? 1.0 : ClampedCoverage((*coverage)[p]);
    for (int c = 0; c < 3; ++c) {
      const double scaled = static_cast<double>(FiniteOrZero(image.rgb[3 * p + c])) * exposure;  // clamped below
      const long code = std::upper_bound(thresholds.begin(), thresholds.end(), scaled) - thresholds.begin();
      out[p * channels + c] = static_cast<unsigned char>(
          background == Background::kWhite ? std::lround(code * alpha + 255.0 * (1.0 - alpha)) : code);
    }
    if (channels == 4) out[p * channels + 3] = static_cast<unsigned char>(std::lround(255.0 * alpha));
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

// The linear pixels EXR and raw write, `channels` floats each: the image itself with kScene (no copy unless a
// value is not finite); with kWhite colour x coverage + (1 - coverage); with kTransparent (channels 4) colour x
// coverage and the coverage (associated alpha).
const std::vector<float>& LinearPixels(const LinearRgbImage& image, Background background,
                                       const std::vector<float>* coverage, int channels, std::vector<float>* storage) {
  if (background == Background::kScene) return FinitePixels(image, storage);
  const size_t pixels = image.rgb.size() / 3;
  storage->resize(pixels * channels);
  for (size_t p = 0; p < pixels; ++p) {
    const float alpha = ClampedCoverage((*coverage)[p]);
    const float behind = background == Background::kWhite ? 1.0f - alpha : 0.0f;
    for (int c = 0; c < 3; ++c) (*storage)[p * channels + c] = FiniteOrZero(image.rgb[3 * p + c]) * alpha + behind;
    if (channels == 4) (*storage)[p * channels + 3] = alpha;
  }
  return *storage;
}

// Lossy WebP of quality 90 through libwebp itself: OpenImageIO 2.4's WebP writer takes four channels as
// associated alpha and unassociates them through 8-bit intermediates (x^2.2 first, which turns every code
// below 15 into 0), so the product's dark colours came out black. Its alpha is compressed losslessly (libwebp's
// default alpha_quality 100), so it reads back exactly.
std::string EncodeWebp(const std::vector<unsigned char>& pixels, int width, int height, int channels,
                       std::string* bytes) {
  struct Encoding {  // zeroed, so freeing is safe whatever step failed
    WebPConfig config{};
    WebPPicture picture{};
    WebPMemoryWriter writer{};
    ~Encoding() {
      WebPPictureFree(&picture);
      WebPMemoryWriterClear(&writer);
    }
  } e;
  if (!WebPConfigInit(&e.config) || !WebPPictureInit(&e.picture)) return "libwebp version mismatch";
  e.config.quality = 90;
  e.picture.width = width;
  e.picture.height = height;
  WebPMemoryWriterInit(&e.writer);
  e.picture.writer = WebPMemoryWrite;
  e.picture.custom_ptr = &e.writer;
  const int imported = channels == 4 ? WebPPictureImportRGBA(&e.picture, pixels.data(), width * 4)
                                     : WebPPictureImportRGB(&e.picture, pixels.data(), width * 3);
  if (!imported || !WebPEncode(&e.config, &e.picture))
    return "cannot encode image.webp: libwebp error " + std::to_string(static_cast<int>(e.picture.error_code));
  bytes->assign(reinterpret_cast<const char*>(e.writer.mem), e.writer.size);
  return "";
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

float ClampedCoverage(float coverage) { return std::isfinite(coverage) ? std::clamp(coverage, 0.0f, 1.0f) : 0.0f; }

std::string CheckBackground(ImageFormat format, Background background) {
  if (background == Background::kTransparent && (format == ImageFormat::kJpeg || format == ImageFormat::kRaw))
    return std::string(format == ImageFormat::kJpeg ? "JPEG" : "raw") +
           " has no alpha channel: a transparent background needs PNG, WebP or EXR";
  return "";
}

std::string EncodeImage(const LinearRgbImage& image, ImageFormat format, double exposure, std::string* bytes,
                        Background background, const std::vector<float>* coverage) {
  if (image.width <= 0 || image.height <= 0 || image.rgb.size() != size_t(image.width) * image.height * 3)
    return "image size does not match its pixels";
  if (std::string error = CheckBackground(format, background); !error.empty()) return error;
  if (background != Background::kScene && (!coverage || coverage->size() != size_t(image.width) * image.height))
    return "the coverage does not match the image";
  const int channels = background == Background::kTransparent ? 4 : 3;
  std::vector<float> storage;
  switch (format) {
    case ImageFormat::kRaw:
      *bytes = RawFloats(LinearPixels(image, background, coverage, channels, &storage));
      return "";
    case ImageFormat::kExr: {
      OIIO::ImageSpec spec(image.width, image.height, channels, OIIO::TypeDesc::FLOAT);  // RGB or RGBA
      spec.attribute("compression", "zip");
      spec.attribute("oiio:ColorSpace", "Linear");
      // OpenImageIO's EXR writer stamps the wall-clock time (capDate) when DateTime is not given, so identical
      // images would differ by the second they were encoded; an empty DateTime keeps the bytes a function of
      // the pixels (the PNG and JPEG writers add no date of their own).
      spec.attribute("DateTime", "");
      return WriteInMemory("image.exr", spec, OIIO::TypeDesc::FLOAT,
                           LinearPixels(image, background, coverage, channels, &storage).data(), bytes);
    }
    case ImageFormat::kPng:
    case ImageFormat::kJpeg:
    case ImageFormat::kWebp: {
      const std::vector<unsigned char> srgb = ToSrgb8(image, exposure, background, coverage, channels);
      if (format == ImageFormat::kWebp) return EncodeWebp(srgb, image.width, image.height, channels, bytes);
      OIIO::ImageSpec spec(image.width, image.height, channels, OIIO::TypeDesc::UINT8);
      spec.attribute("oiio:ColorSpace", "sRGB");
      // Written as given: the PNG writer would otherwise take the alpha as associated and unassociate it.
      if (channels == 4) spec.attribute("oiio:UnassociatedAlpha", 1);
      if (format == ImageFormat::kJpeg) spec.attribute("Compression", "jpeg:90");
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
