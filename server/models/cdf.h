// Inverting a piecewise-constant distribution given by its (unnormalised) cumulative sums: shared by the
// materials' importance sampler and the environment map's.
#pragma once

#include <algorithm>
#include <cmath>

namespace loomlight::models {

// The cell i of n with cdf[i] <= target < cdf[i + 1] (cdf holds n + 1 sums from 0), and the target's remainder
// within it in [0, 1): reusing the remainder keeps a stratified number stratified inside the cell.
template <class T>  // double, or float for large tables
int SearchCdf(const T* cdf, int n, double target, double* remainder) {
  const int i = std::clamp(int(std::upper_bound(cdf, cdf + n + 1, target) - cdf) - 1, 0, n - 1);
  const double width = double(cdf[i + 1]) - double(cdf[i]);
  *remainder = width > 0 ? std::clamp((target - double(cdf[i])) / width, 0.0, std::nextafter(1.0, 0.0)) : 0.5;
  return i;
}

}  // namespace loomlight::models
