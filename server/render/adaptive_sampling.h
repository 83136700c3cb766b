// Adaptive sampling: a render's samples spent where its pixels are noisy. A first pass gives every pixel a few
// samples; their spread estimates each pixel's noise, and the rest of the work goes to the pixels where a sample
// removes the most squared error per unit of work. For a pixel with one-sample variance v and cost c per sample,
// the image's summed squared error sum v_p / n_p under a work budget sum c_p n_p = B is least at
// n_p proportional to sqrt(v_p / c_p) (a Lagrange multiplier), clamped to [first pass, most]. The background,
// whose samples are cheap and noiseless, keeps its first pass; silhouettes, highlights and shadow edges get more.
// Deterministic: counts depend only on the first pass's values, which depend only on the request and seed.
#pragma once

#include <cstdint>
#include <vector>

namespace loomlight::render {

// The work of a pixel sample that makes no query (a camera ray and a map lookup), in units of one query's work
// (the ray casts, light and material draws and the kernel evaluation behind it).
constexpr double kSampleCostWithoutQueries = 0.1;
// The work of a pixel sample whose environment light comes from a BTF fold (FoldedEnvironment::Radiance on the
// host), in the same units: ~3 us a sample against ~1.5 us per query all told (the cylinders, twill asset, 4 spp).
// Counted as none, the folded cloth looked as cheap as the background and got up to 8 times its samples.
constexpr double kFoldedSampleCost = 2.0;

// The fewest samples per pixel that can be spent adaptively (a first pass of 2, then as many again on average),
// and the fewest at which a render samples adaptively unless asked not to. At 4 (with four material draws per
// hit, 40 dB comes at 4-5 samples per pixel) adaptive left 20% less variance than uniform on the satin
// cylinders for 6% more CPU, 25% on the twill for the same, 14% on the satin sphere for 3% more.
constexpr uint32_t kMinAdaptiveSamples = 4;
constexpr uint32_t kAutoAdaptiveSamples = 4;

// Samples per pixel of the first pass when `samples_per_pixel` (at least kMinAdaptiveSamples) are spent
// adaptively: a power of two (its points are a (0,k,2)-net), at most half the budget, 2 to 16. Most of what
// adaptive sampling buys is the budget the background does not need; within the cloth a variance estimate from
// 2 samples moved samples about at random: at 10 samples per pixel a first pass of 4 instead of 2 left 9% less
// variance on the satin cylinders, 13% on the twill, 6% on the sphere, at the same work (8 instead of 4 at 16: 3%).
uint32_t FirstPassSamples(uint32_t samples_per_pixel);

// What the first pass measured per pixel: the variance of one sample (summed over R, G and B) and the work of
// one sample (kSampleCostWithoutQueries plus its queries, and kFoldedSampleCost for a folded hit).
struct PixelNoise {
  std::vector<double> variance;
  std::vector<double> cost;
};

// The radius of the neighbourhood a pixel's variance is averaged over, for a first pass of `first` samples: 2
// (5 x 5) for 2, whose one-degree-of-freedom estimates need the steadying (at 4 spp against 3 x 3: 6% less
// variance on the satin cylinders, 3% on the satin sphere, 1% on the twill; 7 x 7 lost it again on the twill),
// else 1 (3 x 3; at 16 spp 5 x 5 was no better).
int NoiseNeighbourhoodRadius(uint32_t first);

// Each pixel's total sample count (at least `first`, at most `most`) for the work of `samples_per_pixel` uniform
// samples in every pixel; the variance is first averaged over each pixel's neighbourhood (NoiseNeighbourhoodRadius),
// so an estimate from a few samples is steadied by its neighbours' (and an edge's noise reaches the pixels beside
// it). A noiseless image keeps its first pass (and costs less than the budget).
std::vector<uint32_t> AllocateSamples(int width, int height, const PixelNoise& noise, uint32_t first,
                                      uint32_t samples_per_pixel, uint32_t most);

}  // namespace loomlight::render
