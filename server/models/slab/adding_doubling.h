// Exact (all scattering orders) reflection and transmission of a homogeneous plane-parallel slab with
// isotropic scattering and no boundary refraction, by adding-doubling: the exact mode of the thin-layer model
// (SPEC.md section 4, issue 4 item 6). Host code, double precision.
//
// f follows SPEC.md section 1, as kernels/models/thin_layer.h: f(mu, mu0) is the radiance leaving at cosine mu
// per unit irradiance E_perp of a collimated beam entering at cosine mu0, so single scattering gives exactly
// SPEC section 4's formulas. Scattering is isotropic, so the scattered field does not depend on azimuth and
// f(mu, mu0) is already the azimuthal average. The direct (unscattered) beam exp(-tau / mu0) is never part of
// the transmission f. Reciprocity makes both functions symmetric: f(mu, mu0) = f(mu0, mu).
#pragma once

#include <cstddef>
#include <vector>

namespace loomlight::slab {

// Gauss-Legendre nodes and weights on [0, 1] (ascending nodes).
void GaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights);

// Single-scattering f (SPEC.md section 4) including its limits at mu or mu0 = 0, for tau >= 0 and cosines
// in [0, 1]. Reflection diverges like 1 / (mu + mu0) as both cosines go to 0: at mu = mu0 = 0 it returns
// the largest double (never Inf).
double SingleScatteringReflection(double tau, double albedo, double mu, double mu0);
double SingleScatteringTransmission(double tau, double albedo, double mu, double mu0);

struct AddingDoublingOptions {
  // Gauss-Legendre nodes on [0, 1] for every integral over intermediate directions (the "double-Gauss"
  // quadrature: one Gauss rule per hemisphere keeps the rule's nodes off the horizon's kink).
  int gauss_nodes = 32;
  // The starting layer is tau / 2^n, the thickest at most max_initial_tau / max(1, tau^2). Single scattering
  // misses the light scattered more than once inside that layer, an error proportional to its thickness that
  // doubling carries to the whole slab, and that a thick conservative slab amplifies about like tau^2
  // (measured: ~16 x the layer's thickness up to tau = 1, ~1.4 tau^2 x it beyond): about 1e-5 relative or
  // less with the default, at 14 doublings for tau = 0.01, 20 for tau = 1, 27 for 5, 40 for 100.
  double max_initial_tau = 1e-6;
};

// f at every pair of the requested cosines (in [0, 1], any order; they need not be quadrature nodes):
// row-major n x n, entry [i * n + j] = f(mu[i], mu0 = mu[j]).
struct SlabFunctions {
  std::vector<double> mu;
  std::vector<double> reflection, transmission;                    // all orders (diffuse)
  std::vector<double> reflection_multiple, transmission_multiple;  // all orders minus single scattering
  int doublings = 0;
  double initial_tau = 0;
  size_t index(size_t i, size_t j) const { return i * mu.size() + j; }
};

// The slab of optical thickness tau >= 0 and single-scattering albedo in [0, 1]. At mu = mu0 = 0 the
// reflection holds the largest double (single scattering's divergence) and reflection_multiple a finite
// value: the multiply scattered part diverges there too, but only like log(1 / mu), which the quadrature
// resolves down to its smallest node (mu ~ 1.4e-3 for 32 nodes) and no further.
SlabFunctions SolveSlab(double tau, double albedo, const std::vector<double>& mu,
                        const AddingDoublingOptions& options = {});

}  // namespace loomlight::slab
