// The thin layer's formulas as printed (SPEC.md section 4 before its stable rewrite), in float: what the
// stable kernel replaces. The tests show them failing the hard cases; the benchmark reports their error.
#pragma once

#include <cmath>
#include <vector>

#include "server/models/accuracy.h"
#include "server/models/registry.h"

namespace loomlight::naive {

// f for each pair (RGB), packed thin-layer material ([0] tau, [1..3] albedo / (4 pi)).
inline std::vector<double> ThinLayerFloat(const models::PackedMaterial& m, const accuracy::Pairs& p) {
  std::vector<double> f(3 * p.size());
  const float tau = float(m.data[0]);
  for (size_t q = 0; q < p.size(); ++q) {
    const float* a = &p.wi[3 * q];
    const float* b = &p.wo[3 * q];
    const float mu0 = std::fabs(a[2]), mu = std::fabs(b[2]);
    const bool same = (a[2] > 0) == (b[2] > 0);
    const float s = same ? (1.0f - std::exp(-tau * (mu + mu0) / (mu * mu0))) / (mu + mu0)
                         : (std::exp(-tau / mu) - std::exp(-tau / mu0)) / (mu - mu0);
    for (int c = 0; c < 3; ++c) f[3 * q + c] = float(m.data[1 + c]) * s;
  }
  return f;
}

}  // namespace loomlight::naive
