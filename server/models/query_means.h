// Means over groups of consecutive queries (a tabulated cell's phi_h samples, a texture slice's pixel samples),
// computed in place in the kernels' output.
#pragma once

#include <cstddef>
#include <cstdint>

namespace loomlight::models {

// Means over each group of `per_group` consecutive queries of kernel output f (RGB per query, `groups` whole
// groups), written to the front of f: f[3 g + c] is then group g's mean of channel c (a group's queries lie at
// or after its mean's place, so each is read before it is overwritten). Returns the first group whose mean is
// not finite, or `groups`.
size_t GroupMeansInPlace(double* f, size_t groups, uint32_t per_group);

}  // namespace loomlight::models
