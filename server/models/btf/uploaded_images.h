// A client's BTF images (UploadBtf) into the layout of BtfImages, which Compress reads: each image as it arrives
// into its (view, light) pair, then the pairs gathered view-major.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "server/models/btf/btf_asset.h"

namespace loomlight::models::btf {

// One decoded image (rgb: width x height, 3 floats per pixel, the file's top row first, which is v = 1) times
// `scale` into *out in BtfImages' texel order (row iv = 0 at v = 0). False at a value that is negative or not
// finite (f is >= 0); *out is then incomplete.
inline bool StoreUploadedImage(const float* rgb, int width, int height, double scale, std::vector<float>* out) {
  out->resize(3 * size_t(width) * height);
  for (int row = 0; row < height; ++row)
    for (int col = 0; col < width; ++col)
      for (int c = 0; c < 3; ++c) {
        const double v = scale * rgb[(size_t(row) * width + col) * 3 + c];
        if (!std::isfinite(v) || v < 0) return false;
        (*out)[(size_t(height - 1 - row) * width + col) * 3 + c] = float(v);
      }
  return true;
}

// Every pair's image (pairs[view * N + light], each images->image_values() long) into images->f, view-major;
// each pair's image freed once copied, so the two are held together one image at a time.
inline void GatherPairs(std::vector<std::vector<float>>* pairs, BtfImages* images) {
  images->f.resize(pairs->size() * images->image_values());
  for (size_t pair = 0; pair < pairs->size(); ++pair) {
    std::copy((*pairs)[pair].begin(), (*pairs)[pair].end(), images->f.begin() + pair * images->image_values());
    (*pairs)[pair] = {};
  }
}

}  // namespace loomlight::models::btf
