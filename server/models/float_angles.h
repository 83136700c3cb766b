// Angles in float for the host's sampling tables (the materials' direction sampler, the environment map): the
// kernels' own branch-free atan2 (kernels/common/shim.h's ll_atan2_poly, about 1 ulp in float), shared rather
// than written again. A table cell or pixel needs ~1e-7 rad; glibc's double atan2 and acos took 7% of a satin
// thumbnail's CPU time in light sampling (its atan2f about as much).
#pragma once

namespace loomlight::models::float_angles {

// atan2(y, x) in [-pi, pi].
float Atan2(float y, float x);
// acos(c) for c in [-1, 1] (clamped), as the angle of (c, sqrt(1 - c^2)).
float Acos(float c);

}  // namespace loomlight::models::float_angles
