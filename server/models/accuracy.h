// Accuracy against the double reference (SPEC.md section 8), shared by the tests and the benchmark:
// random direction pairs, percentiles, relative errors and the cosine-weighted log RMSE.
#pragma once

#include <cstddef>
#include <random>
#include <string>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::accuracy {

// Uniform direction on the upper hemisphere (z uniform in [0, 1) gives uniform solid angle), as float.
void RandomHemisphere(std::mt19937& rng, float* w);

// Direction pairs (xyz triples), each uniform on the upper hemisphere.
struct Pairs {
  std::vector<float> wi, wo;
  size_t size() const { return wi.size() / 3; }
  Pairs Head(size_t n) const;  // the first n pairs
};
Pairs RandomPairs(size_t n, unsigned seed);
// n pairs mirrored about half vectors within 0.35 rad of the normal (wo at least 0.01 above the surface): the
// peaks of specular lobes, where highlights lie in their windows.
Pairs NearSpecularPairs(size_t n, unsigned seed);

// The q-quantile (0..1) of the values, nearest rank; 0 when empty.
double Percentile(std::vector<double> values, double q);

// Errors of an evaluation against a reference, both 3 values (RGB) per query.
struct Accuracy {
  double median = 0, p99 = 0, max = 0;  // |f - ref| / ref over the values with ref > floor
  size_t count = 0;                     // values above the floor
  double rel_l1 = 0;                    // sum |f - ref| / sum ref over every value
  double log_rmse = 0;                  // sqrt(mean((log(1 + f cos_o) - log(1 + ref cos_o))^2)), cos_o = |wo.z|
  std::string ToString() const;
};
// Compares the first ref.size() values of got (the reference may cover a prefix of the queries). The log
// RMSE needs the directions: 0 without pairs.
template <class T>
Accuracy Compare(const std::vector<T>& got, const std::vector<double>& ref, double floor,
                 const Pairs* pairs = nullptr);

// The estimated error of each setting of a model's accuracy knob (Model::accuracy_knob) for the material
// `values` describe: sum |f_s - f_exact| / sum f_exact (every channel) of the double reference over kKnobPairs
// seeded direction pairs, both at least 0.1 from the surface's plane (about 84 degrees; nearer the horizon the
// cheap settings' error is real but so is every model's, and a user's error target means the visible range);
// half the pairs back-lit for models with transmission. The exact (last) setting's error is 0. Empty when
// the model has no knob.
constexpr size_t kKnobPairs = 256;
std::vector<double> MeasureKnobErrors(const models::Model& model, const models::ParamValues& values);

}  // namespace loomlight::accuracy
