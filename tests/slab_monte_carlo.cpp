#include "tests/slab_monte_carlo.h"

#include <algorithm>
#include <cmath>

namespace loomlight::testing {
namespace {

// xoshiro256** seeded by splitmix64: fast, and good enough that a fixed seed gives a reproducible test.
class Rng {
 public:
  explicit Rng(uint64_t seed) {
    for (uint64_t& s : s_) {
      seed += 0x9e3779b97f4a7c15ull;
      uint64_t z = seed;
      z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
      z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
      s = z ^ (z >> 31);
    }
  }
  // Uniform in (0, 1]: never 0, so -log(u) is finite.
  double Uniform() { return (static_cast<double>(Next() >> 11) + 1.0) * 0x1.0p-53; }

 private:
  static uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  uint64_t Next() {
    const uint64_t result = Rotl(s_[1] * 5, 7) * 9;
    const uint64_t t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = Rotl(s_[3], 45);
    return result;
  }
  uint64_t s_[4];
};

// Sums of weights and squared weights per bin; each photon adds to at most one bin of one tally.
struct Accumulator {
  explicit Accumulator(int bins) : w(bins, 0.0), w2(bins, 0.0) {}
  void Add(int bin, double weight) {
    w[bin] += weight;
    w2[bin] += weight * weight;
  }
  // Means and standard errors of the per-photon contributions over n photons.
  SlabTallies Finish(uint64_t n) const {
    SlabTallies t;
    double sum = 0, sum2 = 0;
    for (size_t b = 0; b < w.size(); ++b) {
      const double mean = w[b] / n;
      t.mean.push_back(mean);
      t.sigma.push_back(std::sqrt(std::max(0.0, w2[b] / n - mean * mean) / n));
      sum += w[b];
      sum2 += w2[b];
    }
    t.total = sum / n;
    t.total_sigma = std::sqrt(std::max(0.0, sum2 / n - t.total * t.total) / n);
    return t;
  }
  std::vector<double> w, w2;
};

}  // namespace

SlabResult SimulateSlab(double tau, double albedo, double mu0, int bins, uint64_t photons, uint64_t seed) {
  Rng rng(seed);
  Accumulator r1(bins), t1(bins), ra(bins), ta(bins);
  auto bin_of = [bins](double mu) { return std::min(bins - 1, static_cast<int>(std::fabs(mu) * bins)); };
  for (uint64_t n = 0; n < photons; ++n) {
    double depth = 0.0, mu = mu0, weight = 1.0;  // optical depth below the top; mu > 0 heads down
    for (int order = 0; order <= 10000; ++order) {
      depth += -std::log(rng.Uniform()) * mu;
      if (depth < 0.0 || depth > tau) {
        if (order == 0) break;  // the direct beam
        const int b = bin_of(mu);
        (depth < 0.0 ? ra : ta).Add(b, weight);
        if (order == 1) (depth < 0.0 ? r1 : t1).Add(b, weight);
        break;
      }
      weight *= albedo;
      mu = 2.0 * rng.Uniform() - 1.0;  // isotropic: mu uniform in [-1, 1]
    }
  }
  return {r1.Finish(photons), t1.Finish(photons), ra.Finish(photons), ta.Finish(photons)};
}

}  // namespace loomlight::testing
