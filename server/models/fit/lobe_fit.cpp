#include "server/models/fit/lobe_fit.h"

#include <Eigen/Dense>
#include <unsupported/Eigen/NonLinearOptimization>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <iterator>
#include <stdexcept>

#include "server/models/quote.h"
#include "server/render/sample_points.h"

namespace loomlight::models::fit {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Region edges: the view's elevation theta_o and the light's azimuth relative to the view's, |phi_i - phi_o|.
constexpr double kElevationEdgesDeg[] = {30, 60, 75};
constexpr double kAzimuthEdgesDeg[] = {60, 120};
const char* const kElevationNames[] = {"near-normal view (0-30 deg)", "oblique view (30-60 deg)",
                                       "low view (60-75 deg)", "grazing view (75-90 deg)"};
const char* const kAzimuthNames[] = {"back-scatter (light within 60 deg of the view's azimuth)",
                                     "side light (60-120 deg round from the view)",
                                     "forward scatter (light beyond 120 deg, facing the viewer)"};
constexpr int kAzimuthBins = 3;

// Malley's method: a uniform point of the unit disk (polar map) lifted to the hemisphere is cosine-distributed.
// z = sqrt(1 - u1) > 0 for every u1 < 1.
void CosineWeighted(double u1, double u2, float* w) {
  const double r = std::sqrt(u1), phi = 2 * kPi * u2;
  w[0] = static_cast<float>(r * std::cos(phi));
  w[1] = static_cast<float>(r * std::sin(phi));
  w[2] = static_cast<float>(std::sqrt(1 - u1));
}

int RegionOf(const float* wi, const float* wo) {
  const double theta_o = std::acos(std::clamp(double(wo[2]), -1.0, 1.0)) * 180 / kPi;
  // The angle between the azimuths, in [0, 180] degrees, from the projections onto the surface.
  const double dphi = std::atan2(std::abs(double(wi[0]) * wo[1] - double(wi[1]) * wo[0]),
                                 double(wi[0]) * wo[0] + double(wi[1]) * wo[1]) * 180 / kPi;
  const int elevation = int(std::upper_bound(std::begin(kElevationEdgesDeg), std::end(kElevationEdgesDeg), theta_o) -
                            std::begin(kElevationEdgesDeg));
  const int azimuth = int(std::upper_bound(std::begin(kAzimuthEdgesDeg), std::end(kAzimuthEdgesDeg), dphi) -
                          std::begin(kAzimuthEdgesDeg));
  return elevation * kAzimuthBins + azimuth;
}

double Finite(double x) { return std::isfinite(x) ? x : 0.0; }

// The stated error's sums over one set of pairs.
struct ErrorSums {
  double abs_diff = 0, abs_f = 0, signed_diff = 0;
  void Add(double fit, double f) {
    const double d = Finite(fit) - Finite(f);
    abs_diff += std::abs(d);
    abs_f += std::abs(Finite(f));
    signed_diff += d;
  }
  // Relative L1; against a black source, 1 when the fit is not black (its sum is then abs_diff's), else 0.
  double Relative() const { return abs_f > 0 ? abs_diff / abs_f : (abs_diff > 0 ? 1.0 : 0.0); }
  double Bias() const { return abs_f > 0 ? signed_diff / abs_f : (signed_diff > 0 ? 1.0 : 0.0); }
};

double StatedError(const double* fit, const double* f, size_t values) {
  ErrorSums sums;
  for (size_t i = 0; i < values; ++i) sums.Add(fit[i], f[i]);
  return sums.Relative();
}

// One free value: a component of a target parameter, within [lo, hi] by a smooth map of an unbounded u.
struct FreeValue {
  std::string param;
  size_t component;
  double lo, hi;
  bool colour;
  double start = std::nan("");  // a real's only start (kStartedAtDefault), else NaN: started on the grid

  double ToValue(double u) const {
    if (std::isfinite(lo) && std::isfinite(hi)) return lo + (hi - lo) / (1 + std::exp(-u));  // logistic
    if (std::isfinite(lo)) return lo + std::exp(u);
    if (std::isfinite(hi)) return hi - std::exp(-u);
    return u;
  }
  // The inverse, for a start: x moved inside the range by a millionth of it, so u is finite.
  double ToFree(double x) const {
    if (std::isfinite(lo) && std::isfinite(hi)) {
      const double margin = 1e-6 * (hi - lo);
      x = std::clamp(x, lo + margin, hi - margin);
      return std::log((x - lo) / (hi - x));
    }
    if (std::isfinite(lo)) return std::log(std::max(x - lo, 1e-6));
    if (std::isfinite(hi)) return -std::log(std::max(hi - x, 1e-6));
    return x;
  }
  // A point of the range at `fraction` of it (a start), or near lo for half-open ranges.
  double AtFraction(double fraction) const {
    if (std::isfinite(lo) && std::isfinite(hi)) return lo + fraction * (hi - lo);
    if (std::isfinite(lo)) return lo + fraction;
    if (std::isfinite(hi)) return hi - fraction;
    return fraction;
  }
};

// Where a fitted value is as good as the end of its range (1e-6 of it: far below a colour's 8-bit step).
constexpr double kSnapToEnd = 1e-6;

std::vector<FreeValue> FreeValues(const Model& target) {
  std::vector<FreeValue> free;
  for (const ParamSpec& p : target.params()) {
    if (p.type != ParamType::kReal && p.type != ParamType::kRgb) continue;
    const size_t components = p.type == ParamType::kRgb ? 3 : 1;
    const bool specular = std::find(kSpecularRoughness.begin(), kSpecularRoughness.end(), p.name) !=
                          kSpecularRoughness.end();
    const bool ior = std::find(kStartedAtDefault.begin(), kStartedAtDefault.end(), p.name) != kStartedAtDefault.end();
    const double lo = specular ? std::max(p.min, kLeastSpecularRoughness) : p.min;
    const double hi = ior ? std::min(p.max, kMostSpecularIor) : p.max;
    for (size_t c = 0; c < components; ++c)
      free.push_back({p.name, c, lo, hi, p.type == ParamType::kRgb, ior ? p.defaults[c] : std::nan("")});
  }
  return free;
}

// The target's f on the first `pairs` fit directions, at free values u, and the stated error's machinery.
class Problem {
 public:
  Problem(const Model& target, const std::vector<double>& source_f)
      : target_(target), free_(FreeValues(target)), base_(target.DefaultValues()), source_(source_f) {
    for (double& v : source_) v = Finite(v);
  }

  const std::vector<FreeValue>& free() const { return free_; }
  const std::vector<double>& source() const { return source_; }

  ParamValues Values(const Eigen::VectorXd& u) const {
    ParamValues values = base_;
    for (size_t j = 0; j < free_.size(); ++j) values[free_[j].param][free_[j].component] = free_[j].ToValue(u[j]);
    return values;
  }

  // f of the target at u on the first `pairs` pairs, non-finite values as 0.
  void Evaluate(const Eigen::VectorXd& u, size_t pairs, double* f) const {
    const FitDirectionSet& d = FitDirections();
    const PackedMaterial material = target_.Pack(Values(u));
    target_.ReferenceEval(material, d.wi.data(), d.wo.data(), nullptr, pairs, f);
    for (size_t i = 0; i < 3 * pairs; ++i) f[i] = Finite(f[i]);
  }

  double Error(const Eigen::VectorXd& u, size_t pairs) const {
    std::vector<double> f(3 * pairs);
    Evaluate(u, pairs, f.data());
    return StatedError(f.data(), source_.data(), f.size());
  }

 private:
  const Model& target_;
  std::vector<FreeValue> free_;
  ParamValues base_;
  std::vector<double> source_;
};

// One round's weighted residuals r_i = weight_i (f_fit,i - f_i) for Eigen's Levenberg-Marquardt, its Jacobian by
// forward differences from the last evaluation (the point LM asks the Jacobian of is the one it evaluated last).
class WeightedResiduals {
 public:
  WeightedResiduals(const Problem& problem, size_t pairs, const Eigen::VectorXd& weight)
      : problem_(problem), pairs_(pairs), weight_(weight), f_(3 * pairs), stepped_(3 * pairs) {}

  int inputs() const { return int(problem_.free().size()); }
  int values() const { return int(3 * pairs_); }

  int operator()(const Eigen::VectorXd& u, Eigen::VectorXd& r) {
    problem_.Evaluate(u, pairs_, f_.data());
    last_u_ = u;
    r = Residual(f_);
    return 0;
  }

  int df(const Eigen::VectorXd& u, Eigen::MatrixXd& jacobian) {
    int evaluations = 0;
    if (last_u_.size() != u.size() || last_u_ != u) {
      problem_.Evaluate(u, pairs_, f_.data());
      last_u_ = u;
      ++evaluations;
    }
    jacobian.resize(values(), inputs());
    for (int j = 0; j < inputs(); ++j) {
      Eigen::VectorXd stepped_u = u;
      const double h = 1e-7 * (1 + std::abs(u[j]));
      stepped_u[j] += h;
      const double actual_h = stepped_u[j] - u[j];  // the step as represented
      problem_.Evaluate(stepped_u, pairs_, stepped_.data());
      ++evaluations;
      for (int i = 0; i < values(); ++i) jacobian(i, j) = weight_[i] * (stepped_[i] - f_[i]) / actual_h;
    }
    return evaluations;
  }

 private:
  Eigen::VectorXd Residual(const std::vector<double>& f) const {
    Eigen::VectorXd r(values());
    for (int i = 0; i < values(); ++i) r[i] = weight_[i] * (f[i] - problem_.source()[i]);
    return r;
  }

  const Problem& problem_;
  size_t pairs_;
  Eigen::VectorXd weight_;
  std::vector<double> f_, stepped_;
  Eigen::VectorXd last_u_;
};

// Runs the reweighted rounds from u on the first `pairs` pairs; returns the best point by the stated error (u
// itself when nothing improves on it) and that error. Asks `stop` before every LM iteration.
struct Solved {
  Eigen::VectorXd u;
  double error;
};
class Solver {
 public:
  Solver(const Problem& problem, const std::function<bool()>& stop) : problem_(problem), stop_(stop) {}

  Solved Solve(const Eigen::VectorXd& start, size_t pairs, int rounds) {
    const size_t n = 3 * pairs;
    const double* f = problem_.source().data();
    double sum_abs = 0;
    for (size_t i = 0; i < n; ++i) sum_abs += std::abs(f[i]);
    // Callers fit only sources with some light on these pairs' prefix; guard the scale all the same.
    const double scale = sum_abs > 0 ? sum_abs : 1.0, mean_abs = scale / n;
    Eigen::VectorXd u = start;
    std::vector<double> fit(n);
    problem_.Evaluate(u, pairs, fit.data());
    Solved best{start, StatedError(fit.data(), f, n)};
    Eigen::VectorXd weight(n);
    // Each round's weights from the residuals d_prev where it starts: |d|^2 / (|d_prev| + delta) is |d| where
    // d = d_prev; delta keeps residuals the fit already meets from dominating; the scale makes the cost about the
    // relative error.
    const auto reweigh = [&] {
      const double delta = kIrlsDelta * mean_abs;
      for (size_t i = 0; i < n; ++i) weight[i] = 1 / std::sqrt(scale * (std::abs(fit[i] - f[i]) + delta));
    };
    reweigh();
    for (int round = 0; round < rounds && !stopped_; ++round) {
      WeightedResiduals residuals(problem_, pairs, weight);
      Eigen::LevenbergMarquardt<WeightedResiduals> lm(residuals);
      lm.parameters.maxfev = kMaxEvaluationsPerRound * (residuals.inputs() + 1);
      lm.parameters.ftol = lm.parameters.xtol = 1e-8;
      Eigen::LevenbergMarquardtSpace::Status status = lm.minimizeInit(u);
      while (status == Eigen::LevenbergMarquardtSpace::NotStarted ||
             status == Eigen::LevenbergMarquardtSpace::Running) {
        if (stop_ && stop_()) {
          stopped_ = true;
          break;
        }
        status = lm.minimizeOneStep(u);
        ++iterations_;
      }
      if (!u.allFinite()) break;  // not expected (every residual is finite); keep the best so far
      problem_.Evaluate(u, pairs, fit.data());
      const double error = StatedError(fit.data(), f, n);
      if (error < best.error) best = {u, error};
      reweigh();
    }
    return best;
  }

  bool stopped() const { return stopped_; }
  int iterations() const { return iterations_; }

 private:
  // Jacobians a round at most (each: free values + 1 evaluations). More rounds of fewer iterations reach a lower
  // L1 error than fewer long ones (each round's weights are only right near where it started).
  static constexpr int kMaxEvaluationsPerRound = 15;
  static constexpr double kIrlsDelta = 0.02;  // of the mean |f|

  const Problem& problem_;
  const std::function<bool()>& stop_;
  bool stopped_ = false;
  int iterations_ = 0;
};

}  // namespace

const FitDirectionSet& FitDirections() {
  static const FitDirectionSet set = [] {
    FitDirectionSet s;
    s.wi.resize(3 * kFitPairs);
    s.wo.resize(3 * kFitPairs);
    s.region.resize(kFitPairs);
    for (size_t k = 0; k < kFitPairs; ++k) {
      const render::SamplePoints points(kFitSeed, 0, static_cast<uint32_t>(k));
      const std::array<double, 2> ui = points.Get2D(0), uo = points.Get2D(1);
      CosineWeighted(ui[0], ui[1], &s.wi[3 * k]);
      CosineWeighted(uo[0], uo[1], &s.wo[3 * k]);
      s.region[k] = RegionOf(&s.wi[3 * k], &s.wo[3 * k]);
    }
    return s;
  }();
  return set;
}

const std::vector<std::string>& FitRegionNames() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n;
    for (const char* elevation : kElevationNames)
      for (const char* azimuth : kAzimuthNames) n.push_back(std::string(elevation) + ", " + azimuth);
    return n;
  }();
  return names;
}

std::vector<double> ReferenceOnFitDirections(const Model& model, const PackedMaterial& material) {
  if (!model.fiber_axis_param().empty())
    throw std::invalid_argument("model '" + model.name() +
                                "' is a fiber model: its f is about a fibre's axis, not a surface's normal");
  const FitDirectionSet& d = FitDirections();
  std::vector<double> f(3 * d.size());
  model.ReferenceEval(material, d.wi.data(), d.wo.data(), nullptr, d.size(), f.data());
  return f;
}

namespace {

void CheckSource(const std::vector<double>& source_f) {
  if (source_f.size() != 3 * FitDirections().size())
    throw std::invalid_argument("source f has " + std::to_string(source_f.size()) + " values, not 3 per fit pair (" +
                                std::to_string(3 * FitDirections().size()) + ")");
}

std::string PoorFitText(double error, std::vector<RegionError> regions) {
  // The regions holding most of the absolute error, where a viewer sees the difference.
  std::stable_sort(regions.begin(), regions.end(),
                   [](const RegionError& a, const RegionError& b) { return a.share > b.share; });
  std::string text = "relative L1 error " + Number(error) + " is above " + Number(kPoorFitError) + "; it misses most at ";
  const size_t named = std::min<size_t>(3, regions.size());
  for (size_t i = 0; i < named; ++i) {
    const RegionError& r = regions[i];
    if (i) text += "; ";
    text += r.region + ": error " + Number(r.error) + ", " + Number(std::round(100 * r.share)) + "% of the total, " +
            (r.bias > 0 ? "too bright" : "too dark");
  }
  return text;
}

// The stated error of fit against source and its regions.
FitResult MeasureValues(const std::vector<double>& fit, const std::vector<double>& source) {
  const FitDirectionSet& d = FitDirections();
  const std::vector<std::string>& names = FitRegionNames();
  ErrorSums total;
  std::vector<ErrorSums> region(names.size());
  for (size_t k = 0; k < d.size(); ++k)
    for (int c = 0; c < 3; ++c) {
      total.Add(fit[3 * k + c], source[3 * k + c]);
      region[d.region[k]].Add(fit[3 * k + c], source[3 * k + c]);
    }
  FitResult result;
  result.error = total.Relative();
  for (size_t r = 0; r < names.size(); ++r)
    result.regions.push_back({names[r], region[r].Relative(),
                              total.abs_diff > 0 ? region[r].abs_diff / total.abs_diff : 0.0, region[r].Bias()});
  std::stable_sort(result.regions.begin(), result.regions.end(),
                   [](const RegionError& a, const RegionError& b) { return a.error > b.error; });
  if (result.error > kPoorFitError) result.poor_fit = PoorFitText(result.error, result.regions);
  return result;
}

}  // namespace

FitResult MeasureFit(const Model& target, const ParamValues& params, const std::vector<double>& source_f) {
  CheckSource(source_f);
  ParamValues values = target.DefaultValues();
  for (const auto& [name, v] : params) values[name] = v;
  FitResult result = MeasureValues(ReferenceOnFitDirections(target, target.Pack(values)), source_f);
  result.params = std::move(values);
  return result;
}

FitResult FitLobe(const Model& target, const std::vector<double>& source_f, const std::function<bool()>& stop) {
  const auto started = std::chrono::steady_clock::now();
  CheckSource(source_f);
  const Problem problem(target, source_f);
  const std::vector<FreeValue>& free = problem.free();
  const std::vector<double>& f = problem.source();

  // The source's albedo per channel: pi times the mean of f over pairs cosine-weighted in both directions.
  double albedo[3] = {0, 0, 0};
  for (size_t i = 0; i < f.size(); ++i) albedo[i % 3] += f[i];
  for (double& a : albedo) a *= kPi / FitDirections().size();
  const bool black = std::all_of(f.begin(), f.end(), [](double v) { return v == 0; });

  // Starts: the real parameters on the grid of kStartFractions, the colours at the albedo (black: at their least).
  std::vector<size_t> reals;
  for (size_t j = 0; j < free.size(); ++j)
    if (!free[j].colour && std::isnan(free[j].start)) reals.push_back(j);
  const size_t grid = std::size(kStartFractions);
  size_t start_count = 1;
  for (size_t i = 0; i < reals.size(); ++i) start_count *= grid;
  std::vector<Eigen::VectorXd> starts;
  for (size_t s = 0; s < start_count; ++s) {
    Eigen::VectorXd u(free.size());
    for (size_t j = 0, digits = s; j < free.size(); ++j) {
      if (free[j].colour) {
        u[j] = free[j].ToFree(black ? free[j].lo : albedo[free[j].component]);
      } else if (!std::isnan(free[j].start)) {
        u[j] = free[j].ToFree(free[j].start);
      } else {
        u[j] = free[j].ToFree(free[j].AtFraction(kStartFractions[digits % grid]));
        digits /= grid;
      }
    }
    starts.push_back(u);
  }

  Solver solver(problem, stop);
  Eigen::VectorXd best = starts[0];
  if (!black) {
    // Every start on the first kStartPairs pairs, then the best few on every pair.
    std::vector<Solved> candidates;
    for (const Eigen::VectorXd& start : starts) {
      if (solver.stopped()) break;
      candidates.push_back(solver.Solve(start, kStartPairs, kStartRounds));
    }
    std::stable_sort(candidates.begin(), candidates.end(),
                     [](const Solved& a, const Solved& b) { return a.error < b.error; });
    double best_error = problem.Error(best, kFitPairs);
    for (size_t c = 0; c < candidates.size() && c < size_t(kRefinedStarts); ++c) {
      const Solved refined = solver.Solve(candidates[c].u, kFitPairs, kRefineRounds);
      if (refined.error < best_error) {
        best = refined.u;
        best_error = refined.error;
      }
    }
  }
  ParamValues values = problem.Values(best);
  // The logistic map only approaches its ends: a value within kSnapToEnd of one (a black source's colours, an
  // unused lobe's, 1e-306 after the optimiser drove it out) is written as the end itself, and the error measured
  // at what is written.
  for (const FreeValue& v : free) {
    double& x = values[v.param][v.component];
    if (black && v.colour) x = v.lo;
    if (std::isfinite(v.lo) && std::isfinite(v.hi)) {
      if (x - v.lo < kSnapToEnd * (v.hi - v.lo)) x = v.lo;
      if (v.hi - x < kSnapToEnd * (v.hi - v.lo)) x = v.hi;
    }
  }
  FitResult result = MeasureFit(target, values, source_f);
  result.iterations = solver.iterations();
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return result;
}

}  // namespace loomlight::models::fit
