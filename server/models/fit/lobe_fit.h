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
//
// The pairs: kFitPairs, pair k is sample k of the render's padded Owen-scrambled Sobol points
// (server/render/sample_points.h, fixed seed kFitSeed), dimension pair 0 giving wi and pair 1 giving wo, each
// mapped to the hemisphere by Malley's method (a uniform point of the unit disk, lifted), full azimuth range for
// both (woven and microcylinder materials are anisotropic). Any power-of-two prefix of the pairs is itself a
// stratified set, which the fit's start stage uses.
//
// A black source (sum_k sum_c |f_c(k)| = 0) has error 0 against a black fit and 1 against any other (the sum is
// then over |f_fit|): nothing divides by zero. Non-finite values of either f count as 0.
//
// The fit: every component of the target's kReal and kRgb parameters is free, each kept
// within its schema's [min, max] by a logistic map of an unbounded variable. Starts: the target's real
// (roughness-like) parameters on a grid of kStartFractions of their ranges, every colour at the source's albedo
// (pi times its mean f over the pairs, a Lambertian's albedo exactly). Each start runs kStartRounds of the
// reweighted least squares on the first kStartPairs pairs; the kRefinedStarts best by the stated error there run
// kRefineRounds on every pair, and the best of those by the stated error is the fit. Each round weighs each
// residual by 1 / sqrt(|residual where the round starts| + delta), which makes its square the L1 term near there
// (with a first round of plain least squares instead, the 13 cloth presets' summed glTF error was 4.18 against
// 3.96, microcylinder velvet's 0.92 against 0.72). The Jacobian is by forward differences (one target evaluation a free value).
// The target is evaluated only through target.Pack and target.ReferenceEval: each lobe is implemented once.
#pragma once

#include <cstddef>
#include <cstdint>
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
  double bias = 0;   // signed: sum (f_fit - f) / sum |f| within the region; > 0 the fit is too bright there
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

constexpr size_t kFitPairs = 4096;
constexpr uint64_t kFitSeed = 48;
// OpenPBR's specular_ior is fitted within [1, kMostSpecularIor], started at its default 1.5 (a textile fibre's:
// cotton, silk and polyester lie near 1.5 to 1.6): OpenPBR dims a dielectric's specular by specular_weight, which
// scales F0 = ((ior - 1) / (ior + 1))^2 and so is the same lobe as a lower ior, and cloth that shows less specular
// than a smooth fibre (a dark velvet, albedo 0.05 against F0's 0.04) needs it. glTF's base has no such freedom (its
// F0 is 0.04 without KHR_materials_specular).
constexpr double kMostSpecularIor = 1.5;
inline const std::vector<std::string> kStartedAtDefault = {"specular_ior"};
// The specular lobes' roughness is fitted no lower than this: the pairs resolve a GGX lobe only down to
// alpha = 0.09 (about 4096 alpha^2 / pi = 10 pairs fall in it); below, a near-mirror specular (4% of light a
// viewer's environment shows as a gloss) costs the sampled error almost nothing, and fits of dark velvets took it.
constexpr double kLeastSpecularRoughness = 0.3;
inline const std::vector<std::string> kSpecularRoughness = {"roughness", "specular_roughness"};
// The fit's schedule (see above): bounded work, ~ starts x rounds x LM iterations x (free values + 1) evaluations.
constexpr double kStartFractions[] = {0.3, 0.7};
constexpr size_t kStartPairs = 512;
constexpr int kStartRounds = 4;
constexpr int kRefinedStarts = 2;
constexpr int kRefineRounds = 5;

// f (RGB per pair, double reference build) of a packed material of `model` on FitDirections(): a BTF asset's
// BRDF (its mean over the texture) for spatially varying models; reflection only. Throws std::invalid_argument for
// a fiber model (its f is about a fibre's axis).
std::vector<double> ReferenceOnFitDirections(const Model& model, const PackedMaterial& material);

// Fits `target` (the registered gltf_sheen or openpbr model) to `source_f` (ReferenceOnFitDirections of the
// source; std::invalid_argument unless 3 values a pair). `stop` is asked between iterations; true ends the fit with
// the best it has. A fit is kStartFractions^reals starts x (kStartRounds on kStartPairs) + kRefinedStarts x
// kRefineRounds on every pair, each round at most 15 LM Jacobians.
FitResult FitLobe(const Model& target, const std::vector<double>& source_f,
                  const std::function<bool()>& stop = {});

// The stated error of `target` at `params` (completed with the target's defaults) against `source_f`, with its
// regions; std::invalid_argument unless `source_f` has 3 values a pair.
FitResult MeasureFit(const Model& target, const ParamValues& params, const std::vector<double>& source_f);

}  // namespace loomlight::models::fit
