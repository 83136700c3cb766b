// Monte Carlo radiative transfer in a plane-parallel slab: isotropic scattering, single-scattering albedo,
// optical thickness tau, collimated light entering the top at incidence cosine mu0, every scattering order
// tracked. The reference for the thin-layer model's single-scattering formulas (SPEC.md section 4) and for
// its all-orders excess.
#pragma once

#include <cstdint>
#include <vector>

namespace loomlight::testing {

// Fractions of the incident photons leaving the slab, by exit cosine |mu| in `bins` equal bins of (0, 1]
// (bin b covers (b/bins, (b+1)/bins]), each with its standard error. Photons that never scattered (the
// direct beam) are not counted.
struct SlabTallies {
  std::vector<double> mean, sigma;
  double total = 0, total_sigma = 0;
};
struct SlabResult {
  SlabTallies reflected_once, transmitted_once;  // exactly one scattering event
  SlabTallies reflected_all, transmitted_all;    // one or more
};

// Photon weights carry the albedo (weight *= albedo per scattering: no absorption sampling noise); photons
// beyond 10,000 scattering events (never reached for the slabs tested) are dropped.
SlabResult SimulateSlab(double tau, double albedo, double mu0, int bins, uint64_t photons, uint64_t seed);

}  // namespace loomlight::testing
