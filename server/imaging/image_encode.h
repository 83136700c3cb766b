// Encoding linear float RGB images into file bytes in memory (OpenImageIO; WebP through libwebp), shared by
// every RPC that returns an image (TextureSlice, Render). No protobuf or gRPC here, so no header-order clash
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
  kWebp, // as kPng, as a lossy WebP of quality 90 (its alpha, when written, lossless)
};

// What shows where an image's object (a product) does not cover a pixel; with kWhite and kTransparent the
// encoder is given each pixel's coverage, the share of it the object covers, in [0, 1].
enum class Background {
  kScene,        // the image as it is, opaque (no coverage)
  kWhite,        // white, exactly (sRGB 255; EXR 1.0) where the coverage is 0, edges blended by coverage (below)
  kTransparent,  // an alpha channel equal to the coverage: PNG, WebP and EXR; JPEG and raw have none (refused)
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

// A coverage as the encoder and exposure use it: clamped to [0, 1], a non-finite one as 0.
float ClampedCoverage(float coverage);

// "" when `format` can show `background`, else why not (JPEG and raw have no alpha channel for kTransparent):
// a request asking for both is refused with this before anything is rendered.
std::string CheckBackground(ImageFormat format, Background background);

// Encodes the image; `exposure` (finite, > 0) is used by the 8-bit formats (PNG, JPEG, WebP) only. Non-finite
// pixel values are written as 0.
// With kWhite or kTransparent, `coverage` holds width x height values (clamped to [0, 1]) and `image` the
// object's own colour, unassociated (not multiplied by coverage; any value where the coverage is 0):
//  - kTransparent: PNG and WebP write it with alpha = round(255 coverage) (their convention: unassociated
//    alpha); EXR writes colour x coverage with A = coverage (OpenEXR's convention: associated alpha).
//  - kWhite: 8-bit formats blend the colour's 8-bit sRGB code c over white in display space,
//    round(c coverage + 255 (1 - coverage)): what an image editor or a browser shows for the kTransparent PNG
//    on a white page, so the two agree, and 255 exactly where the coverage is 0. (Blending linear light
//    instead would draw a black product's half-covered edge pixel at 188, not 128: edges that look thinner
//    and lighter than the same PNG on white.) EXR is linear: colour x coverage + (1 - coverage).
// Returns "" on success, else the reason (an encoder's error or a bad argument: the caller reports it as
// internal, having refused what CheckBackground refuses).
std::string EncodeImage(const LinearRgbImage& image, ImageFormat format, double exposure, std::string* bytes,
                        Background background = Background::kScene, const std::vector<float>* coverage = nullptr);

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
