#include "server/models/accuracy.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace loomlight::accuracy {

void RandomHemisphere(std::mt19937& rng, float* w) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double z = u(rng), phi = 2 * M_PI * u(rng), s = std::sqrt(std::max(0.0, 1 - z * z));
  w[0] = static_cast<float>(s * std::cos(phi));
  w[1] = static_cast<float>(s * std::sin(phi));
  w[2] = static_cast<float>(z);
}

Pairs Pairs::Head(size_t n) const {
  n = std::min(n, size());
  return {std::vector<float>(wi.begin(), wi.begin() + 3 * n), std::vector<float>(wo.begin(), wo.begin() + 3 * n)};
}

Pairs RandomPairs(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  Pairs p;
  p.wi.resize(3 * n);
  p.wo.resize(3 * n);
  for (size_t q = 0; q < n; ++q) {
    RandomHemisphere(rng, &p.wi[3 * q]);
    RandomHemisphere(rng, &p.wo[3 * q]);
  }
  return p;
}

Pairs NearSpecularPairs(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Pairs p;
  while (p.size() < n) {
    const double tilt = 0.35 * u(rng), az = 2 * M_PI * u(rng);
    const double h[3] = {std::sin(tilt) * std::cos(az), std::sin(tilt) * std::sin(az), std::cos(tilt)};
    float wi[3];
    RandomHemisphere(rng, wi);
    const double d = 2 * (wi[0] * h[0] + wi[1] * h[1] + wi[2] * h[2]);
    const float wo[3] = {float(d * h[0] - wi[0]), float(d * h[1] - wi[1]), float(d * h[2] - wi[2])};
    if (wo[2] <= 0.01f) continue;
    p.wi.insert(p.wi.end(), wi, wi + 3);
    p.wo.insert(p.wo.end(), wo, wo + 3);
  }
  return p;
}

double Percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0;
  const size_t k = std::min(values.size() - 1, static_cast<size_t>(q * static_cast<double>(values.size())));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

std::string Accuracy::ToString() const {
  std::ostringstream s;
  s << "median " << median << ", p99 " << p99 << ", max " << max << " over " << count << " values";
  return s.str();
}

template <class T>
Accuracy Compare(const std::vector<T>& got, const std::vector<double>& ref, double floor, const Pairs* pairs) {
  Accuracy a;
  std::vector<double> rel;
  double abs_sum = 0, ref_sum = 0, log_sq = 0;
  for (size_t i = 0; i < ref.size(); ++i) {
    const double f = static_cast<double>(got[i]), r = ref[i];
    const double diff = std::fabs(f - r);
    if (r > floor) rel.push_back(diff / r);
    abs_sum += diff;
    ref_sum += std::fabs(r);
    if (pairs) {
      const double cos_o = std::fabs(pairs->wo[3 * (i / 3) + 2]);  // wo below the surface: transmission
      const double d = std::log1p(f * cos_o) - std::log1p(r * cos_o);
      log_sq += d * d;
    }
  }
  a.count = rel.size();
  a.median = Percentile(rel, 0.5);
  a.p99 = Percentile(rel, 0.99);
  a.max = rel.empty() ? 0 : *std::max_element(rel.begin(), rel.end());
  a.rel_l1 = ref_sum > 0 ? abs_sum / ref_sum : 0;
  a.log_rmse = pairs && !ref.empty() ? std::sqrt(log_sq / static_cast<double>(ref.size())) : 0;
  return a;
}

template Accuracy Compare<float>(const std::vector<float>&, const std::vector<double>&, double, const Pairs*);
template Accuracy Compare<double>(const std::vector<double>&, const std::vector<double>&, double, const Pairs*);

std::vector<double> MeasureKnobErrors(const models::Model& model, const models::ParamValues& values) {
  const models::AccuracyKnob knob = model.accuracy_knob();
  if (knob.param.empty() || knob.settings.empty()) return {};
  std::mt19937 rng(20261201);
  Pairs pairs;
  while (pairs.size() < kKnobPairs) {
    float wi[3], wo[3];
    RandomHemisphere(rng, wi);
    RandomHemisphere(rng, wo);
    if (wi[2] < 0.1f || wo[2] < 0.1f) continue;
    if (model.transmission() && pairs.size() % 2 == 1) wi[2] = -wi[2];  // back-lit
    pairs.wi.insert(pairs.wi.end(), wi, wi + 3);
    pairs.wo.insert(pairs.wo.end(), wo, wo + 3);
  }
  std::vector<std::vector<double>> f(knob.settings.size(), std::vector<double>(3 * pairs.size()));
  for (size_t s = 0; s < knob.settings.size(); ++s) {
    models::ParamValues v = values;
    v[knob.param] = {knob.settings[s]};
    model.ReferenceEval(model.Pack(v), pairs.wi.data(), pairs.wo.data(), nullptr, pairs.size(), f[s].data());
  }
  const std::vector<double>& exact = f.back();
  double total = 0;
  for (double x : exact) total += std::fabs(x);
  std::vector<double> errors;
  for (const std::vector<double>& got : f) {
    double diff = 0;
    for (size_t i = 0; i < got.size(); ++i) diff += std::fabs(got[i] - exact[i]);
    errors.push_back(total > 0 ? diff / total : 0.0);
  }
  return errors;
}

}  // namespace loomlight::accuracy
