// Encoding linear float RGB images into file bytes in memory (OpenImageIO), shared by every RPC that
// returns an image (TextureSlice today, Render later). No protobuf or gRPC here, so no header-order clash
// with OpenImageIO for its users.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

namespace loomlight::imaging {

enum class ImageFormat {
  kPng,  // 8-bit sRGB: linear * exposure, clamped to [0, 1], then the sRGB transfer function (IEC 61966-2-1)
  kExr,  // float RGB OpenEXR, linear, unscaled
  kRaw,  // float32 RGB, little-endian, row-major, top row first, no header, unscaled
  kJpeg, // as kPng, as a baseline JPEG of quality 90
};

// width x height pixels of linear RGB, row-major, top row first (3 floats per pixel).
struct LinearRgbImage {
  int width = 0;
  int height = 0;
  std::vector<float> rgb;
};

// 1 / (99th percentile over pixels of max(r, g, b)), or 1 when that is 0 (or its inverse is not finite):
// the brightest 1% of pixels clip in a PNG, the rest keep their gradation.
double AutomaticExposure(const LinearRgbImage& image);

// Encodes the image; `exposure` (finite, > 0) is used by PNG and JPEG only. Non-finite pixel values are written as 0.
// Returns "" on success, else the reason (an OpenImageIO error: the caller reports it as internal).
std::string EncodeImage(const LinearRgbImage& image, ImageFormat format, double exposure, std::string* bytes);

// Bytes DecodeImage holds while decoding an image of this header: its pixels in float as stored, and as RGB.
inline size_t DecodeBytes(int width, int height, int channels) {
  return size_t(width) * size_t(height) * (size_t(channels) + 3) * sizeof(float);
}

// Decodes PNG, JPEG or OpenEXR bytes (recognised by their first bytes, never by a name a client gives) into linear
// RGB, top row first: 8-bit PNG and JPEG through the inverse sRGB transfer function, EXR as stored; one channel
// is grey, a fourth (alpha) is dropped. At most max_pixels pixels and 4 channels, checked from the header before
// anything is decoded; then `admit` (when given) is asked with the header's width, height and channels and may
// refuse (its "" or reason is returned) before the DecodeBytes are allocated. Returns "" or why not ("not a PNG,
// JPEG or OpenEXR image", "2 channels", ...).
std::string DecodeImage(const std::string& bytes, size_t max_pixels, LinearRgbImage* image,
                        const std::function<std::string(int width, int height, int channels)>& admit = nullptr);

}  // namespace loomlight::imaging
