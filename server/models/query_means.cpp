#include "server/models/query_means.h"

#include <cmath>

namespace loomlight::models {

size_t GroupMeansInPlace(double* f, size_t groups, uint32_t per_group) {
  for (size_t g = 0; g < groups; ++g)
    for (int c = 0; c < 3; ++c) {
      double sum = 0;
      for (size_t q = g * per_group; q < (g + 1) * per_group; ++q) sum += f[3 * q + c];
      f[3 * g + c] = sum / per_group;
      if (!std::isfinite(f[3 * g + c])) return g;
    }
  return groups;
}

}  // namespace loomlight::models
