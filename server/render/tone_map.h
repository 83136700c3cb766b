// Tone mapping for the Render RPC's 8-bit outputs: linear radiance x exposure, then the ACES filmic curve
// (Narkowicz 2015 fit) per channel into [0, 1]; the encoder then applies the sRGB transfer function.
#pragma once

#include "server/imaging/image_encode.h"

namespace loomlight::render {

// 0.18 / (geometric mean of the luminance of the pixels that are not black), Reinhard et al. 2002's "key"
// exposure; 1 when every pixel is black.
double AutomaticExposure(const imaging::LinearRgbImage& image);

// ACES filmic fit: f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), clamped to [0, 1]; f(0) = 0.
double AcesFilmic(double x);

// The display-referred image (values in [0, 1], still linear light) of `image` at `exposure`.
imaging::LinearRgbImage ToneMap(const imaging::LinearRgbImage& image, double exposure);

}  // namespace loomlight::render
