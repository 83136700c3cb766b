// The sRGB transfer function (IEC 61966-2-1), shared by the image encoder and the WIF importer's colours.
#pragma once

#include <cmath>

namespace loomlight::imaging {

// The inverse of the sRGB transfer function: an encoded value in [0, 1] to linear, piecewise (a line up to
// 0.04045, the 2.4 power above).
inline double SrgbToLinear(double encoded) {
  return encoded <= 0.04045 ? encoded / 12.92 : std::pow((encoded + 0.055) / 1.055, 2.4);
}

}  // namespace loomlight::imaging
