// Inverting a piecewise-constant distribution given by its (unnormalised) cumulative sums: shared by the
// materials' importance sampler and the environment map's.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

namespace loomlight::models {

// The largest double below 1 (std::nextafter(1.0, 0.0), which GCC leaves as a call).
constexpr double kBelowOne = 1.0 - 0x1p-53;

// The remainder of `target` within cell i, in [0, 1) (0.5 for an empty cell).
template <class T>
double CdfRemainder(const T* cdf, int i, double target) {
  const double width = double(cdf[i + 1]) - double(cdf[i]);
  return width > 0 ? std::clamp((target - double(cdf[i])) / width, 0.0, kBelowOne) : 0.5;
}

// The cell i of n with cdf[i] <= target < cdf[i + 1] (cdf holds n + 1 sums from 0), and the target's remainder
// within it in [0, 1): reusing the remainder keeps a stratified number stratified inside the cell.
template <class T>  // double, or float for large tables
int SearchCdf(const T* cdf, int n, double target, double* remainder) {
  const int i = std::clamp(int(std::upper_bound(cdf, cdf + n + 1, target) - cdf) - 1, 0, n - 1);
  *remainder = CdfRemainder(cdf, i, target);
  return i;
}

// SearchCdf's answer for a short CDF (tens of sums): the sums at or below the target counted in one pass
// without branches, where a binary search's branches mispredict on random targets.
template <class T>
int SearchShortCdf(const T* cdf, int n, double target, double* remainder) {
  int count = 0;
  for (int k = 0; k <= n; ++k) count += double(cdf[k]) <= target;
  const int i = std::clamp(count - 1, 0, n - 1);
  *remainder = CdfRemainder(cdf, i, target);
  return i;
}

// A guide table for one CDF (pbrt's and Cycles' "cutpoint" method): the target range cut into equal buckets,
// each knowing where upper_bound lands at its edges, so a search reads a few neighbouring sums instead of
// log2(n) scattered ones. Search gives exactly SearchCdf's answer: the target's bucket is widened by one on
// each side, which covers any rounding in finding it.
class CdfGuide {
 public:
  CdfGuide() = default;
  template <class T>
  CdfGuide(const T* cdf, int n, int buckets) {
    const double total = double(cdf[n]);
    if (!(total > 0) || buckets < 1) return;
    scale_ = buckets / total;
    first_.resize(size_t(buckets) + 1);
    for (int g = 0; g <= buckets; ++g)
      first_[size_t(g)] = int(std::upper_bound(cdf, cdf + n + 1, double(g) * total / buckets) - cdf);
    first_.back() = n + 1;  // targets at the top (rounding) search to the end, as upper_bound does
  }

  template <class T>
  int Search(const T* cdf, int n, double target, double* remainder) const {
    int lo, hi;
    Range(n, target, &lo, &hi);
    return SearchRange(cdf, n, lo, hi, target, remainder);
  }

  // Search in its two dependent reads, for callers that search many CDFs at once and fetch each read ahead
  // (a packet of draws from a map too large for the cache): the guide entries `target` reads (Bucket, to
  // prefetch), the range of sums it narrows the search to (Range), and the search of that range.
  const int* Bucket(double target) const {
    if (first_.empty() || !(target >= 0)) return nullptr;
    const int buckets = int(first_.size()) - 1;
    return &first_[size_t(std::max(int(std::min(target * scale_, double(buckets - 1))) - 1, 0))];
  }
  void Range(int n, double target, int* lo, int* hi) const {
    *lo = 0;
    *hi = n + 1;
    if (first_.empty() || !(target >= 0)) return;
    const int buckets = int(first_.size()) - 1;
    const int g = int(std::min(target * scale_, double(buckets - 1)));
    *lo = first_[size_t(std::max(g - 1, 0))];
    *hi = first_[size_t(std::min(g + 2, buckets))];
  }
  template <class T>
  static int SearchRange(const T* cdf, int n, int lo, int hi, double target, double* remainder) {
    const int i = std::clamp(int(std::upper_bound(cdf + lo, cdf + hi, target) - cdf) - 1, 0, n - 1);
    *remainder = CdfRemainder(cdf, i, target);
    return i;
  }

  size_t bytes() const { return first_.size() * sizeof(int); }

 private:
  std::vector<int> first_;  // per bucket edge g: upper_bound(g total / buckets), an index into the n + 1 sums
  double scale_ = 0;        // buckets / total
};

}  // namespace loomlight::models
