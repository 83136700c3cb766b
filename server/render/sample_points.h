// Low-discrepancy sample points for a pixel: Owen-scrambled 2D Sobol points, their index shuffled per pixel and
// per dimension pair (Burley 2020, "Practical Hash-based Owen Scrambling"; pbrt-v4's padded Sobol sampler).
// Each dimension pair (pixel position, a light, the material) gets its own scramble, so the pairs are
// independent of one another while each pair's n = 2^k samples of a pixel form a (0, k, 2)-net: one point in
// every elementary interval of area 1/n (e.g. each cell of a 4 x 4 grid for 16 samples). A pure function of
// (seed, pixel, sample, pair): any sample is drawn in any order, on any thread, and the same request gives the
// same image.
#pragma once

#include <array>
#include <cstdint>

#include "server/models/rng.h"

namespace loomlight::render {

namespace sobol {

inline uint32_t ReverseBits(uint32_t x) {
  x = __builtin_bswap32(x);  // the bytes reversed in one instruction, then the bits within each byte
  x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
  x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
  return ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
}

// Laine and Karras' hash: a permutation in which every bit depends only on the bits below it, so applied to
// bit-reversed numbers it is a nested uniform (Owen) scramble.
inline uint32_t LaineKarras(uint32_t x, uint32_t seed) {
  x += seed;
  x ^= x * 0x6c50b47cu;
  x ^= x * 0xb82f1e52u;
  x ^= x * 0xc7afe638u;
  x ^= x * 0x8d22f6e6u;
  return x;
}

inline uint32_t OwenScramble(uint32_t x, uint32_t seed) { return ReverseBits(LaineKarras(ReverseBits(x), seed)); }

// Sobol's first two dimensions: the van der Corput sequence (bit reversal) and the one from the Pascal
// matrix mod 2 (direction numbers v_0 = 2^31, v_k = v_{k-1} ^ (v_{k-1} >> 1)), the latter by bytes of the index
// (a linear map over GF(2): the XOR of each byte's table entry; the shuffled indices use all 32 bits).
struct PascalTables {
  uint32_t byte[4][256];
  PascalTables() {
    uint32_t v[32];
    v[0] = 0x80000000u;
    for (int k = 1; k < 32; ++k) v[k] = v[k - 1] ^ (v[k - 1] >> 1);
    for (int b = 0; b < 4; ++b)
      for (uint32_t x = 0; x < 256; ++x) {
        uint32_t y = 0;
        for (int k = 0; k < 8; ++k)
          if (x >> k & 1) y ^= v[8 * b + k];
        byte[b][x] = y;
      }
  }
};

inline std::array<uint32_t, 2> Sobol2D(uint32_t index) {
  static const PascalTables tables;
  const uint32_t y = tables.byte[0][index & 0xff] ^ tables.byte[1][(index >> 8) & 0xff] ^
                     tables.byte[2][(index >> 16) & 0xff] ^ tables.byte[3][index >> 24];
  return {ReverseBits(index), y};
}

}  // namespace sobol

class SamplePoints {
 public:
  SamplePoints(uint64_t seed, uint64_t pixel, uint32_t sample)
      : key_(models::Mix64(seed ^ models::Mix64(pixel))), sample_(sample) {}

  // The sample's point in dimension pair `pair`, both coordinates in [0, 1).
  std::array<double, 2> Get2D(uint32_t pair) const {
    const uint64_t h = PairHash(pair);
    const std::array<uint32_t, 2> p = sobol::Sobol2D(ShuffledIndex(h));
    const uint32_t x = sobol::OwenScramble(p[0], static_cast<uint32_t>(h >> 32));
    const uint32_t y = sobol::OwenScramble(p[1], static_cast<uint32_t>(models::Mix64(h)));
    // 32 bits each, so always < 1.
    return {x * 0x1p-32, y * 0x1p-32};
  }

  // Get2D(pair)[0] alone (the same number), for a strategy that needs one: half the scrambling. Sobol's first
  // dimension is the index's bit reversal.
  double Get1D(uint32_t pair) const {
    const uint64_t h = PairHash(pair);
    return sobol::OwenScramble(sobol::ReverseBits(ShuffledIndex(h)), static_cast<uint32_t>(h >> 32)) * 0x1p-32;
  }

  // Point j of `count` (a power of two) that this sample draws in one pair: the sample's index becomes
  // count * sample + j, so a pixel's n samples x count points of a pair stay one (0, k, 2)-net.
  SamplePoints Subsample(uint32_t j, uint32_t count) const {
    SamplePoints points = *this;
    points.sample_ = sample_ * count + j;
    return points;
  }

 private:
  // The pair's scrambling seeds (low half: the index's shuffle, high half: x's scramble).
  uint64_t PairHash(uint32_t pair) const { return models::Mix64(key_ + 0x9e3779b97f4a7c15ull * (pair + 1)); }
  // The shuffled index: samples 0..2^k-1 of the pixel become one aligned block of 2^k Sobol indices.
  uint32_t ShuffledIndex(uint64_t h) const { return sobol::OwenScramble(sample_, static_cast<uint32_t>(h)); }

  uint64_t key_;
  uint32_t sample_;
};

}  // namespace loomlight::render
