// Counter-based random numbers: each value is a hash of (seed, stream, dimension), so any pixel sample can be
// drawn in any order, on any thread, in any chunk, and the same request gives the same image.
#pragma once

#include <cstdint>

namespace loomlight::models {

// splitmix64's finaliser (Steele, Lea and Flood 2014; passes BigCrush): a bijective, well-mixed 64-bit hash.
// The one copy: render samples, Sample's seeds, texture slices' pixel offsets and the yarns' fibers use it.
inline uint64_t Mix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// Uniform numbers in [0, 1) for one stream (e.g. one pixel sample) of one seed.
class CounterRng {
 public:
  CounterRng(uint64_t seed, uint64_t stream) : key_(Mix64(seed ^ Mix64(stream))) {}
  // The dimension-th number of the stream: 53 random bits, so always < 1.
  double Uniform(uint32_t dimension) const {
    return static_cast<double>(Mix64(key_ + 0x632be59bd9b4e019ull * (dimension + 1)) >> 11) * 0x1p-53;
  }

 private:
  uint64_t key_;
};

}  // namespace loomlight::models
