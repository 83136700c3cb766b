// Tone mapping for the Render RPC's 8-bit outputs: linear radiance x exposure, then the ACES filmic curve
// (Narkowicz 2015 fit) per channel into [0, 1]; the encoder then applies the sRGB transfer function. And what a
// product shot on an empty background needs before that: the product's own colour, its exposure and its fill.
#pragma once

#include <vector>

#include "server/imaging/image_encode.h"

namespace loomlight::render {

// 0.18 / (geometric mean of the luminance of the pixels that are not black), Reinhard et al. 2002's "key"
// exposure; 1 when every pixel is black. With `coverage` (a product on an empty background), `image` holds the
// product's colour (ProductColour) and each pixel counts in proportion to its coverage: the empty part of the
// frame counts not at all, so a product is exposed the same whatever share of the frame it fills.
double AutomaticExposure(const imaging::LinearRgbImage& image, const std::vector<float>* coverage = nullptr);

// The product's own colour from a render over an empty background, in place: each pixel's radiance averaged
// over all its samples, misses adding 0, divided by its coverage (0 where the coverage is 0).
void ProductColour(const std::vector<float>& coverage, imaging::LinearRgbImage* image);

// The share of the frame the product covers: the mean coverage, each clamped to [0, 1] (0 for no pixels).
double Fill(const std::vector<float>& coverage);

// ACES filmic fit: f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), clamped to [0, 1]; f(0) = 0.
double AcesFilmic(double x);

// The display-referred image (values in [0, 1], still linear light) of `image` at `exposure`, in place.
void ToneMap(double exposure, imaging::LinearRgbImage* image);

}  // namespace loomlight::render
