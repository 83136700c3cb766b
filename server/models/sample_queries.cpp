#include "server/models/sample_queries.h"

#include <algorithm>
#include <cmath>

#include "server/models/rng.h"

namespace loomlight::models {

void DrawSampleQueries(const DirectionSampler& sampler, const float* wo, const float* random, uint64_t seed,
                       size_t begin, size_t end, float* wi, float* pdf) {
  for (size_t q = begin; q < end; ++q) {
    double u[3];
    if (random) {
      for (int d = 0; d < 3; ++d) u[d] = random[3 * q + d];
    } else {  // the numbers a client would send: floats (below 1)
      const CounterRng rng(seed, q);
      for (int d = 0; d < 3; ++d) u[d] = std::min(static_cast<float>(rng.Uniform(d)), 0x1.fffffep-1f);
    }
    const double x = wo[3 * q], y = wo[3 * q + 1], z = wo[3 * q + 2];
    const double length = std::sqrt(x * x + y * y + z * z);  // unit within the API's tolerance (validated)
    const DirectionSampler::Sample s = sampler.Draw({x / length, y / length, z / length}, u[0], u[1], u[2]);
    const double wl = std::sqrt(s.wi[0] * s.wi[0] + s.wi[1] * s.wi[1] + s.wi[2] * s.wi[2]);
    for (int c = 0; c < 3; ++c) wi[3 * q + c] = wl > 0 ? static_cast<float>(s.wi[c] / wl) : 0.0f;
    pdf[q] = std::isfinite(s.pdf) && s.pdf > 0 ? static_cast<float>(s.pdf) : 0.0f;
  }
}

void SampleWeights(const DirectionSampler& sampler, size_t n, const float* wi, const float* pdf, const float* f,
                   float* weight) {
  for (size_t q = 0; q < n; ++q) {
    const double cosine = sampler.Cosine({wi[3 * q], wi[3 * q + 1], wi[3 * q + 2]});
    for (int c = 0; c < 3; ++c) {
      const double w = pdf[q] > 0 ? f[3 * q + c] * cosine / pdf[q] : 0.0;
      weight[3 * q + c] = std::isfinite(w) ? static_cast<float>(w) : 0.0f;
    }
  }
}

}  // namespace loomlight::models
