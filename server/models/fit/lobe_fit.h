// Fits a standard lobe that other tools render (glTF 2.0 + KHR_materials_sheen: model `gltf_sheen`; OpenPBR
// Surface with fuzz: model `openpbr`) to any surface material's BRDF (docs/materials-out.md). The error is stated
// once, here, and every fit and report uses it:
//
//   error = sum_k sum_c |f_fit,c(k) - f_c(k)| / sum_k sum_c |f_c(k)|
//
// over the fixed direction pairs k of FitDirections() (both wi and wo drawn cosine-weighted over the upper
// hemisphere from a fixed low-discrepancy set, so a plain sum over k is the integral of |f| cos(theta_i)
// cos(theta_o): the relative L1 of f cos, cosine-weighted by the view as a rendered image sees it) and the three
// channels c. The optimiser is Eigen's Levenberg-Marquardt (unsupported/Eigen/NonLinearOptimization) on an
// iteratively reweighted least-squares form of that L1 error, from a fixed set of starts: deterministic.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::models::fit {

// The fixed direction pairs: wi and wo, xyz per pair (unit, z > 0), and each pair's region (an index into
// FitRegionNames()), which names where a fit misses.
struct FitDirectionSet {
  std::vector<float> wi, wo;
  std::vector<int> region;
  size_t size() const { return region.size(); }
};
const FitDirectionSet& FitDirections();
// Regions of pairs by the view's elevation and the light's azimuth relative to the view, e.g. "grazing view
// (theta_o > 70 deg), back-scatter".
const std::vector<std::string>& FitRegionNames();

struct RegionError {
  std::string region;
  double error = 0;  // relative L1 of f cos within the region
  double share = 0;  // the region's share of the whole fit's absolute error
};

struct FitResult {
  ParamValues params;                // the target model's every parameter
  double error = 0;                  // the stated error above
  std::vector<RegionError> regions;  // every region, worst relative error first
  double seconds = 0;
  int iterations = 0;                // all starts together
  std::string poor_fit;              // "" or, when error > kPoorFitError, the regions it misses and how
};

constexpr double kPoorFitError = 0.2;

// f (RGB per pair, double reference build) of a packed material of `model` on FitDirections(): a BTF asset's
// BRDF (its mean over the texture) for spatially varying models; reflection only.
std::vector<double> ReferenceOnFitDirections(const Model& model, const PackedMaterial& material);

// Fits `target` (the registered gltf_sheen or openpbr model) to `source_f` (ReferenceOnFitDirections of the
// source). `stop` is asked between iterations; true ends the fit with what it has.
FitResult FitLobe(const Model& target, const std::vector<double>& source_f,
                  const std::function<bool()>& stop = {});

// The stated error of `target` at `params` against `source_f`, with its regions.
FitResult MeasureFit(const Model& target, const ParamValues& params, const std::vector<double>& source_f);

}  // namespace loomlight::models::fit
