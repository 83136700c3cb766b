#include "server/render/adaptive_sampling.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace loomlight::render {
namespace {

// The mean of `v` over each pixel's (2 r + 1) x (2 r + 1) neighbourhood (the part inside the image), as two 1D
// passes.
std::vector<double> BoxMean(int width, int height, int r, const std::vector<double>& v) {
  std::vector<double> rows(v.size()), out(v.size());
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const int x0 = std::max(x - r, 0), x1 = std::min(x + r, width - 1);
      double sum = 0;
      for (int i = x0; i <= x1; ++i) sum += v[size_t(y) * width + i];
      rows[size_t(y) * width + x] = sum / (x1 - x0 + 1);
    }
  for (int y = 0; y < height; ++y) {
    const int y0 = std::max(y - r, 0), y1 = std::min(y + r, height - 1);
    for (int x = 0; x < width; ++x) {
      double sum = 0;
      for (int j = y0; j <= y1; ++j) sum += rows[size_t(j) * width + x];
      out[size_t(y) * width + x] = sum / (y1 - y0 + 1);
    }
  }
  return out;
}

}  // namespace

int NoiseNeighbourhoodRadius(uint32_t first) { return first <= 2 ? 2 : 1; }

uint32_t FirstPassSamples(uint32_t samples_per_pixel) {
  uint32_t first = 2;
  while (first * 2 <= samples_per_pixel / 2 && first < 16) first *= 2;
  return first;
}

std::vector<uint32_t> AllocateSamples(int width, int height, const PixelNoise& noise, uint32_t first,
                                      uint32_t samples_per_pixel, uint32_t most) {
  const size_t n = size_t(width) * height;
  std::vector<uint32_t> counts(n, first);
  if (n == 0 || most <= first) return counts;
  const std::vector<double> variance = BoxMean(width, height, NoiseNeighbourhoodRadius(first), noise.variance);
  // score_p = sqrt(v_p / c_p): the optimum gives pixel p lambda * score_p samples.
  std::vector<double> score(n);
  double budget = 0, most_work = 0;
  for (size_t p = 0; p < n; ++p) {
    const double cost = noise.cost[p];
    // A variance that is not a number says nothing (the first pass only); an infinite one asks for the most.
    const double s = std::sqrt(std::max(variance[p], 0.0) / cost);
    score[p] = std::isnan(s) ? 0.0 : std::min(s, std::numeric_limits<double>::max());
    budget += cost * samples_per_pixel;
    most_work += cost * (score[p] > 0 ? most : first);
  }
  const auto noisy_count = [&](double lambda, double s) { return std::clamp(lambda * s, double(first), double(most)); };
  const auto count = [&](double lambda, size_t p) { return score[p] > 0 ? noisy_count(lambda, score[p]) : double(first); };
  // The work as a function of lambda, over the noisy pixels alone (the rest keep their first pass: a constant):
  // the bisection below reads them ~50 times, and the render waits for it with a core idle.
  double quiet_work = 0;
  std::vector<double> noisy_score, noisy_cost;
  for (size_t p = 0; p < n; ++p) {
    if (score[p] > 0) {
      noisy_score.push_back(score[p]);
      noisy_cost.push_back(noise.cost[p]);
    } else {
      quiet_work += noise.cost[p] * first;
    }
  }
  const auto work = [&](double lambda) {
    // Eight running sums, not one: a single sum waits for each addition before the next (the compiler keeps
    // floating-point order), which made this loop latency-bound; the order is still fixed, so still
    // deterministic.
    constexpr size_t kLanes = 8;
    std::array<double, kLanes> sums{};
    const size_t m = noisy_score.size(), whole = m / kLanes * kLanes;
    for (size_t i = 0; i < whole; i += kLanes)
      for (size_t k = 0; k < kLanes; ++k) sums[k] += noisy_cost[i + k] * noisy_count(lambda, noisy_score[i + k]);
    for (size_t i = whole; i < m; ++i) sums[i - whole] += noisy_cost[i] * noisy_count(lambda, noisy_score[i]);
    double sum = quiet_work;
    for (double s : sums) sum += s;
    return sum;
  };
  double lambda = 0;
  if (most_work <= budget) {
    lambda = HUGE_VAL;  // every noisy pixel gets the most (an image almost all background)
  } else if (work(0) < budget) {
    // Bisection on the multiplier: work(lambda) is continuous and nondecreasing, work(0) < budget < work(hi).
    double lo = 0, hi = 1;
    while (work(hi) < budget) hi *= 2;
    for (int i = 0; i < 48; ++i) {
      const double mid = 0.5 * (lo + hi);
      (work(mid) < budget ? lo : hi) = mid;
    }
    lambda = lo;
  }
  // Rounded with the remainder carried in pixel order, so the counts add up to the real-valued total.
  double carry = 0;
  for (size_t p = 0; p < n; ++p) {
    carry += count(lambda, p);
    const double whole = std::floor(carry);
    carry -= whole;
    counts[p] = static_cast<uint32_t>(std::clamp(whole, double(first), double(most)));
  }
  return counts;
}

}  // namespace loomlight::render
