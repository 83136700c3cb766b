#include "server/yarn/yarn.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <random>

#include "server/models/quote.h"
#include "server/models/rng.h"
#include "server/runtime/parallel_for.h"

namespace loomlight::yarn {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2 * kPi;
constexpr double kE = 2.71828182845904523536;

// Flyaway shapes (ours; see the header's readings).
constexpr double kLoopReachMin = 1.1;  // loop peak, in ply radii
constexpr double kLoopReachMax = 1.5;
constexpr double kHairReachMin = 1.5;  // hair tip, in ply radii
constexpr double kHairReachMax = 3.0;
constexpr double kHairPortionMin = 0.25;  // of the period
constexpr double kHairPortionMax = 0.75;
constexpr double kHairPitchScale = 4;  // alpha_hair = 4 alpha

constexpr int kMaxThreads = 64;
// Rejection sampling accepts at least ~2% of draws within the validated ranges; this only guarantees an end.
constexpr int kMaxRejectionDraws = 1 << 24;

using models::Number;

// "" or "name: is v, must be in [lo, hi]" (NaN fails every comparison, so it is caught here too).
std::string InRange(const char* name, double v, double lo, double hi) {
  if (v >= lo && v <= hi) return "";
  return std::string(name) + ": is " + Number(v) + ", must be a finite number in [" + Number(lo) + ", " + Number(hi) +
         "]";
}

std::string IntInRange(const char* name, int64_t v, int64_t lo, int64_t hi) {
  if (v >= lo && v <= hi) return "";
  return std::string(name) + ": is " + std::to_string(v) + ", must be in " + std::to_string(lo) + ".." +
         std::to_string(hi);
}

// ---- Random numbers ----
// Counter-based: each (fiber, stream) has its own SplitMix64 sequence, keyed by (seed, ply, fiber, stream),
// so a fiber's draws depend neither on which other fibers were drawn first nor on which thread builds it,
// and a generator is 8 bytes (a std::mt19937_64 per fiber would be 2.5 KB, 250 MB at the fiber limit).
// SplitMix64 (models::Mix64 is its output function) passes BigCrush.

// The draws of one fiber: kCrossSection for its place in the ply (R_i, theta_i, theta_i^0), kFlyaways for
// its loops and hairs, so changing a density changes no fiber's place.
enum Stream : uint64_t { kCrossSection = 0, kFlyaways = 1 };

class FiberRandom {
 public:
  FiberRandom(uint64_t seed, int ply, int fiber, Stream stream)
      : state_(models::Mix64(seed ^ models::Mix64((uint64_t(uint32_t(ply)) << 40) |
                                                  (uint64_t(uint32_t(fiber)) << 8) | stream))) {}
  // Uniform in [0, 1) from the top 53 bits (the same on every standard library, unlike
  // std::uniform_real_distribution).
  double Uniform() { return double(Next() >> 11) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }

 private:
  // SplitMix64's step: the state advances by its increment, and the output is Mix64 of the state before.
  uint64_t Next() {
    const uint64_t z = models::Mix64(state_);
    state_ += 0x9E3779B97F4A7C15ull;
    return z;
  }
  uint64_t state_;
};

// ---- One fiber's plan: everything random about it, drawn before any geometry ----

struct Flyaway {
  int64_t period = 0;  // index of the full period (twist) it takes
  FiberType type = FiberType::kLoop;
  double reach = 0;       // loop peak or hair tip, ply radii
  double portion = 0;     // hair: fraction of the period that is hair
  bool root_at_end = false;  // hair: root at the period's end (tip inside the period) or at its start
};

struct FiberPlan {
  int ply = 0;
  int index = 0;
  double r = 0;       // R_i, ply radii
  double theta = 0;   // theta_i, initial polar angle in the ply frame
  double phase = 0;   // theta_i^0 of Eq. 2
  double first_boundary = 0;  // arc length of the first period boundary, in [0, alpha)
  bool regular = false;       // generated whole
  bool flyaways = false;      // its loops and hairs are generated
  std::vector<Flyaway> flyaway_list;
};

// A piece of a fiber that becomes one curve.
struct Piece {
  FiberType type = FiberType::kMigration;
  double start = 0;
  double end = 0;
  int flyaway = -1;  // index into the plan's flyaway_list for loops and hairs
};

// Draws a point of the unit disk with density proportional to D(R): uniform in the disk (uniform in the
// square, kept when inside), accepted with probability D(R) / max D. D is monotone in R, so its maximum is
// at R = 0 or R = 1: max(1 - eps, eps).
void SampleCrossSection(FiberRandom& rng, double eps, double beta, double* r, double* theta) {
  const double d_max = std::max(1 - eps, eps);
  for (int i = 0; i < kMaxRejectionDraws; ++i) {
    const double x = rng.Uniform(-1, 1);
    const double y = rng.Uniform(-1, 1);
    const double rr = x * x + y * y;
    if (rr >= 1) continue;
    const double radius = std::sqrt(rr);
    if (rng.Uniform() * d_max < FiberDensity(radius, eps, beta)) {
      *r = radius;
      *theta = std::atan2(y, x);
      return;
    }
  }
  *r = 0;  // not reached within the validated ranges
  *theta = 0;
}

// The yarn's sampling grid and the frame arithmetic shared by every curve.
class Geometry {
 public:
  Geometry(const YarnParams& p, const YarnCurve& curve, double length, int64_t intervals)
      : p_(p), curve_(curve), length_(length), intervals_(intervals), step_(length / double(intervals)) {}

  int64_t intervals() const { return intervals_; }
  // Arc length of grid point k; exact at both ends.
  double Arc(int64_t k) const { return k == intervals_ ? length_ : double(k) * step_; }

  // Grid points strictly inside (a, b): [*first, *last).
  void Interior(double a, double b, int64_t* first, int64_t* last) const {
    *first = Above(a);
    *last = std::max(*first, AtOrAbove(b));
  }

  void PrecomputeFrames() {
    frames_.resize(size_t(intervals_ + 1));
    for (int64_t k = 0; k <= intervals_; ++k) frames_[size_t(k)] = curve_.At(Arc(k));
  }

  // The paper's c_yarn + Delta c_ply and the ply's (N_ply, B_ply) at one arc length, in the cross-section
  // plane (see the header's readings).
  struct PlyFrame {
    Vec3 centre, n, b;
  };
  PlyFrame Ply(const CurveFrame& f, int ply, double arc) const {
    const double phi = kTwoPi * ply / p_.plies + kTwoPi * arc / p_.alpha_yarn;  // theta_j^ply + theta
    const Vec3 b_yarn = Cross(f.tangent, f.normal);
    const double c = std::cos(phi), s = std::sin(phi);
    PlyFrame out;
    out.n = c * f.normal + s * b_yarn;
    out.b = c * b_yarn - s * f.normal;  // T_yarn x N_ply
    out.centre = f.position + (0.5 * p_.yarn_radius) * out.n;  // Delta c_ply = R_ply / 2 (cos N + sin B)
    return out;
  }
  // Delta c_i = R (cos psi e_N N_ply + sin psi e_B B_ply), R in ply radii.
  Vec3 FiberPoint(const PlyFrame& f, double r, double psi) const {
    return f.centre + (r * std::cos(psi) * p_.ellipse_n) * f.n + (r * std::sin(psi) * p_.ellipse_b) * f.b;
  }

  // Fills `out` with the piece's control points: its two ends and the grid points between. `shape(arc, &r,
  // &psi)` gives the fiber's radius (ply radii) and angle in the ply frame; r = 0 is the ply centre.
  template <typename Shape>
  void Trace(int ply, double a, double b, Shape shape, std::vector<Vec3>* out) const {
    int64_t first = 0, last = 0;
    Interior(a, b, &first, &last);
    out->clear();
    out->reserve(size_t(last - first + 2));
    const auto point = [&](const CurveFrame& frame, double arc) {
      const PlyFrame f = Ply(frame, ply, arc);
      double r = 0, psi = 0;
      shape(arc, &r, &psi);
      out->push_back(FiberPoint(f, r, psi));
    };
    point(curve_.At(a), a);
    for (int64_t k = first; k < last; ++k) point(frames_[size_t(k)], Arc(k));
    point(curve_.At(b), b);
  }

  int64_t PointsBetween(double a, double b) const {
    int64_t first = 0, last = 0;
    Interior(a, b, &first, &last);
    return last - first + 2;
  }

 private:
  // First grid index whose arc is > a (resp. >= b), found from the estimate and corrected against Arc()
  // itself, so counting and tracing agree exactly.
  int64_t Above(double a) const {
    int64_t k = std::clamp<int64_t>(int64_t(std::floor(a / step_)), 0, intervals_);
    while (k > 0 && Arc(k - 1) > a) --k;
    while (k <= intervals_ && Arc(k) <= a) ++k;
    return k;
  }
  int64_t AtOrAbove(double b) const {
    int64_t k = std::clamp<int64_t>(int64_t(std::floor(b / step_)), 0, intervals_);
    while (k > 0 && Arc(k - 1) >= b) --k;
    while (k <= intervals_ && Arc(k) < b) ++k;
    return k;
  }

  const YarnParams& p_;
  const YarnCurve& curve_;
  double length_;
  int64_t intervals_;
  double step_;
  std::vector<CurveFrame> frames_;
};

// The fiber's functions of arc length (Eq. 1 and Eq. 2 in arc length instead of theta).
struct FiberShape {
  const YarnParams& p;
  const FiberPlan& plan;
  double twist_sign;

  double Theta(double arc) const { return kTwoPi * arc / p.alpha; }  // theta of Eq. 1: z = alpha theta / 2 pi
  double Psi(double arc) const { return plan.theta + twist_sign * Theta(arc); }  // theta_i + theta
  // Eq. 2: R_i (rho_min + (rho_max - rho_min)(cos(s theta + theta_i^0) + 1) / 2).
  double Migration(double arc) const {
    return plan.r * (p.rho_min + (p.rho_max - p.rho_min) * 0.5 * (std::cos(p.s * Theta(arc) + plan.phase) + 1));
  }
  double PeriodStart(int64_t k) const { return plan.first_boundary + double(k) * p.alpha; }
  double PeriodEnd(int64_t k) const { return plan.first_boundary + double(k + 1) * p.alpha; }
  // A hair's root and tip arcs.
  void HairEnds(const Flyaway& f, double* root, double* tip) const {
    const double a = PeriodStart(f.period), b = PeriodEnd(f.period), hair = f.portion * p.alpha;
    if (f.root_at_end) *root = b, *tip = b - hair;
    else *root = a, *tip = a + hair;
  }
};

// Full periods (twists) of a fiber that lie inside [0, length].
int64_t FullPeriods(const YarnParams& p, const FiberPlan& plan, double length) {
  if (length < plan.first_boundary + p.alpha) return 0;
  int64_t n = int64_t(std::floor((length - plan.first_boundary) / p.alpha));
  while (n > 0 && plan.first_boundary + double(n) * p.alpha > length) --n;
  return n;
}

// Draws the fiber's loops and hairs. The gap to the next flyaway period is geometric (inverse CDF), so the
// work is proportional to the flyaways, not to the periods; every flyaway takes exactly five draws.
// Returns false when more than `budget` flyaways would be drawn.
bool PlanFlyaways(const YarnParams& p, double length, FiberRandom& rng, FiberPlan* plan, int64_t budget) {
  const double p_loop = p.loop_density * p.alpha / p.fibers_per_ply;
  const double p_hair = p.hair_density * p.alpha / p.fibers_per_ply;
  const double p_any = p_loop + p_hair;  // <= 1 by validation
  const int64_t periods = FullPeriods(p, *plan, length);
  if (!(p_any > 0)) return true;
  const double log_miss = std::log1p(-std::min(p_any, 1.0));  // -inf when p_any = 1: every period
  int64_t k = -1;
  while (true) {
    const double u_gap = 1 - rng.Uniform();  // (0, 1]
    const double u_type = rng.Uniform(), u_reach = rng.Uniform(), u_portion = rng.Uniform(), u_root = rng.Uniform();
    const double gap = p_any >= 1 ? 0 : std::floor(std::log(u_gap) / log_miss);  // periods skipped
    if (!(gap < double(periods - 1 - k))) break;
    k += 1 + int64_t(gap);
    if (int64_t(plan->flyaway_list.size()) >= budget) return false;
    Flyaway f;
    f.period = k;
    if (u_type * p_any < p_loop) {
      f.type = FiberType::kLoop;
      f.reach = kLoopReachMin + (kLoopReachMax - kLoopReachMin) * u_reach;
    } else {
      f.type = FiberType::kHair;
      f.reach = kHairReachMin + (kHairReachMax - kHairReachMin) * u_reach;
      f.portion = kHairPortionMin + (kHairPortionMax - kHairPortionMin) * u_portion;
      f.root_at_end = u_root < 0.5;
    }
    plan->flyaway_list.push_back(f);
  }
  return true;
}

// The curves one fiber becomes, in arc order.
std::vector<Piece> Pieces(const YarnParams& p, const FiberPlan& plan, double length) {
  std::vector<Piece> pieces;
  const FiberShape shape{p, plan, 1};
  double run_start = 0;  // start of the migration run being built
  const auto migration = [&](double end) {
    if (plan.regular && end > run_start) pieces.push_back({FiberType::kMigration, run_start, end, -1});
  };
  if (plan.flyaways) {
    for (size_t i = 0; i < plan.flyaway_list.size(); ++i) {
      const Flyaway& f = plan.flyaway_list[i];
      const double a = shape.PeriodStart(f.period), b = shape.PeriodEnd(f.period);
      if (f.type == FiberType::kLoop) {
        migration(a);
        pieces.push_back({FiberType::kLoop, a, b, int(i)});
        run_start = b;
        continue;
      }
      double root = 0, tip = 0;
      shape.HairEnds(f, &root, &tip);
      if (f.root_at_end) {  // migration up to the break, then the hair from its tip back to the root at b
        migration(tip);
        pieces.push_back({FiberType::kHair, tip, root, int(i)});
        run_start = b;
      } else {  // the hair from its root at a out to its tip, then migration from the break
        migration(a);
        pieces.push_back({FiberType::kHair, root, tip, int(i)});
        run_start = tip;
      }
    }
  }
  migration(length);
  return pieces;
}

// One task of the geometry phase: a ply's core, or one fiber's pieces, written to their own slots.
struct Task {
  int ply = 0;
  int plan = -1;  // -1: the core
  size_t first_curve = 0;
  std::vector<Piece> pieces;
};

}  // namespace

// ---- Parameters ----

double FiberDensity(double r, double eps, double beta) {
  // Past R = 1 the base would turn negative (pow of it NaN); clamping it to 0 gives D = eps there.
  return (1 - 2 * eps) * std::pow(std::max(0.0, (kE - std::exp(r)) / (kE - 1)), beta) + eps;
}

std::string ValidateYarnParams(const YarnParams& p) {
  std::string e;
  if (!(e = IntInRange("plies", p.plies, 1, kMaxPlies)).empty()) return e;
  if (!(e = IntInRange("fibers_per_ply", p.fibers_per_ply, 1, kMaxFibersPerPly)).empty()) return e;
  const std::pair<const char*, double> lengths[] = {
      {"yarn_radius", p.yarn_radius}, {"ellipse_n", p.ellipse_n}, {"ellipse_b", p.ellipse_b},
      {"alpha", p.alpha},             {"alpha_yarn", p.alpha_yarn}, {"fiber_width", p.fiber_width},
      {"length", p.length}};
  for (const auto& [name, v] : lengths)
    if (!(e = InRange(name, v, kMinLength, kMaxLength)).empty()) return e;
  if (!(e = InRange("eps", p.eps, 0, 1)).empty()) return e;
  if (!(e = InRange("beta", p.beta, 0, kMaxBeta)).empty()) return e;
  if (!(e = InRange("s", p.s, 0, kMaxS)).empty()) return e;
  if (!(p.rho_max > 0 && p.rho_max <= 1)) return "rho_max: is " + Number(p.rho_max) + ", must be in (0, 1]";
  if (!(p.rho_min >= 0 && p.rho_min <= p.rho_max))
    return "rho_min: is " + Number(p.rho_min) + ", must be in [0, rho_max = " + Number(p.rho_max) + "]";
  if (!(e = InRange("hair_density", p.hair_density, 0, kMaxDensity)).empty()) return e;
  if (!(e = InRange("loop_density", p.loop_density, 0, kMaxDensity)).empty()) return e;
  const double per_twist = (p.hair_density + p.loop_density) * p.alpha / p.fibers_per_ply;
  if (per_twist > 1)
    return "hair_density: hair_density + loop_density = " + Number(p.hair_density + p.loop_density) +
           " per unit length per ply needs " + Number(per_twist) +
           " flyaways per fiber twist (times alpha / fibers_per_ply), more than 1";
  return "";
}

std::vector<std::string> YarnPresetNames() { return {"cotton1", "cotton2", "polyester1", "rayon2", "silk1"}; }

std::string YarnPreset(std::string_view name, YarnParams* out) {
  // SPEC.md section 6, in its order: K, fibers per ply, yarn radius, ply ellipse long/short, alpha (fiber),
  // alpha_yarn, eps, beta, s, rho_min, hair density, loop density.
  struct Row {
    const char* name;
    int plies, fibers;
    double radius, ellipse_long, ellipse_short, alpha, alpha_yarn, eps, beta, s, rho_min, hair, loop;
  };
  static constexpr Row kRows[] = {
      {"cotton1", 3, 75, .0378, .0257, .0200, .366, .453, 0, .201, 1.0, .85, 30.36, 19.10},
      {"cotton2", 3, 36, .0330, .0247, .0180, .435, .336, .0109, .417, 1.9, .95, 20.53, 15.39},
      {"polyester1", 2, 60, .0287, .0285, .0211, .380, .370, .339, .423, 1.1, .70, 31.49, 34.11},
      {"rayon2", 2, 79, .0287, .0283, .0209, .378, .372, .242, .389, 1.5, .80, 47.31, 36.51},
      {"silk1", 3, 33, .0376, .0253, .0216, .460, .526, 0, .485, 0.1, .95, 24.87, 20.67},
  };
  for (const Row& r : kRows) {
    if (name != r.name) continue;
    YarnParams p;
    p.plies = r.plies;
    p.fibers_per_ply = r.fibers;
    p.yarn_radius = r.radius;
    p.ellipse_n = r.ellipse_short;  // the ply is flattened towards the yarn centre (Sec. 3.1)
    p.ellipse_b = r.ellipse_long;
    p.alpha = r.alpha;
    p.alpha_yarn = r.alpha_yarn;
    p.eps = r.eps;
    p.beta = r.beta;
    p.s = r.s;
    p.rho_min = r.rho_min;
    p.rho_max = 1;
    p.hair_density = r.hair;
    p.loop_density = r.loop;
    p.fiber_width = 2 * std::sqrt(r.ellipse_long * r.ellipse_short / r.fibers);
    *out = p;
    return "";
  }
  std::string known;
  for (const std::string& n : YarnPresetNames()) known += (known.empty() ? "" : ", ") + n;
  return "preset: unknown yarn preset " + models::Quote(name) + " (known: " + known + ")";
}

// ---- Level of detail ----

double LodLambda(double fiber_width, double ply_width, double footprint) {
  if (footprint <= fiber_width) return 1;  // omega^LoD <= omega_fiber
  if (ply_width <= footprint) return 0;    // omega^ply <= omega^LoD
  // (omega_fiber / omega^LoD) ((omega^ply - omega^LoD) / (omega^ply - omega_fiber)); here
  // fiber_width < footprint < ply_width, so the denominator is positive.
  return (fiber_width / footprint) * ((ply_width - footprint) / (ply_width - fiber_width));
}

double PlyWidth(const YarnParams& p) { return 2 * p.rho_max * std::max(p.ellipse_n, p.ellipse_b); }

double SamplingIntervals(const YarnParams& p, const DetailOptions& options, double length) {
  const LodChoice lod = ChooseLod(p.fiber_width, PlyWidth(p), options.footprint, 0, 0, options.points_per_twist);
  double shortest = std::min(p.alpha, p.alpha_yarn);
  if (p.s > 1) shortest = std::min(shortest, p.alpha / p.s);
  return std::max(1.0, std::ceil(length / (shortest / lod.points_per_twist)));
}

double MinControlPoints(const YarnParams& p, const DetailOptions& options, double length) {
  return double(p.plies) * (SamplingIntervals(p, options, length) + 1);
}

LodChoice ChooseLod(double fiber_width, double ply_width, double footprint, int max_fibers, double core_radius_full,
                    int points_per_twist) {
  LodChoice c;
  c.lambda = LodLambda(fiber_width, ply_width, footprint);
  c.scale = c.lambda * c.lambda;                             // the paper's lambda^2
  c.fibers = int(std::llround(c.scale * max_fibers));        // lambda^2 n_max^fiber
  const double ply_radius = 0.5 * ply_width;
  c.core_radius = c.scale * core_radius_full + (1 - c.scale) * ply_radius;  // original at 1, the ply's at 0
  c.points_per_twist = std::max(kMinPointsPerTwist, int(std::lround(c.scale * points_per_twist)));
  return c;
}

// ---- Generation ----

const char* ToString(FiberType type) {
  switch (type) {
    case FiberType::kCore: return "core";
    case FiberType::kMigration: return "migration";
    case FiberType::kLoop: return "loop";
    case FiberType::kHair: return "hair";
  }
  return "?";
}

std::string ValidateDetailOptions(const DetailOptions& o) {
  std::string e;
  if (!(e = InRange("core_radius", o.core_radius, 0, 1)).empty()) return e;
  if (!(e = InRange("footprint", o.footprint, 0, kMaxLength)).empty()) return e;
  if (o.footprint > 0 && !o.core) return "footprint: a level of detail needs core fibers (core = true)";
  if (!(e = IntInRange("points_per_twist", o.points_per_twist, kMinPointsPerTwist, kMaxPointsPerTwist)).empty())
    return e;
  if (!(e = IntInRange("threads", o.threads, 1, kMaxThreads)).empty()) return e;
  return "";
}

std::string GenerateYarn(const YarnParams& p, const YarnCurve& curve, const DetailOptions& options,
                         const YarnLimits& limits, YarnGeometry* out) {
  *out = YarnGeometry();
  std::string e;
  if (!(e = ValidateYarnParams(p)).empty()) return e;
  if (!(e = ValidateDetailOptions(options)).empty()) return e;
  if (limits.max_fibers < 0) return "max_fibers: is " + std::to_string(limits.max_fibers) + ", must be >= 0";
  if (limits.max_control_points < 0)
    return "max_control_points: is " + std::to_string(limits.max_control_points) + ", must be >= 0";
  const double length = curve.Length();
  if (!(length >= kMinLength && length <= kMaxLength))
    return "curve: its length is " + Number(length) + ", must be a finite number in [" + Number(kMinLength) + ", " +
           Number(kMaxLength) + "]";

  // Work bounds first, from the parameters alone.
  const int64_t fibers = int64_t(p.plies) * p.fibers_per_ply;
  if (fibers > limits.max_fibers)
    return "max_fibers: the yarn has " + std::to_string(p.plies) + " x " + std::to_string(p.fibers_per_ply) + " = " +
           std::to_string(fibers) + " fibers, more than the limit " + std::to_string(limits.max_fibers);
  const double ply_width = PlyWidth(p);
  const LodChoice lod = ChooseLod(p.fiber_width, ply_width, options.footprint, 0, 0, options.points_per_twist);
  const double intervals_needed = SamplingIntervals(p, options, length);
  const double min_points = MinControlPoints(p, options, length);
  if (min_points > double(limits.max_control_points))
    return "max_control_points: the yarn needs at least " + Number(min_points) + " control points (" +
           std::to_string(p.plies) + " plies x " + Number(intervals_needed + 1) + " along it), more than the limit " +
           std::to_string(limits.max_control_points);
  Geometry geometry(p, curve, length, int64_t(intervals_needed));

  // Every fiber's place in its ply's cross-section (Sec. 2.2, D(R) by rejection from the disk).
  std::vector<FiberPlan> plans(static_cast<size_t>(fibers));
  runtime::ParallelFor(plans.size(), options.threads, {}, [&](size_t f) {
    FiberPlan& plan = plans[f];
    plan.ply = int(f / size_t(p.fibers_per_ply));
    plan.index = int(f % size_t(p.fibers_per_ply));
    FiberRandom rng(p.seed, plan.ply, plan.index, kCrossSection);
    SampleCrossSection(rng, p.eps, p.beta, &plan.r, &plan.theta);
    plan.phase = rng.Uniform(0, kTwoPi);
    // Periods start where Eq. 2's cosine is -1: s theta + theta_i^0 = pi, taken with s = 1 (see header).
    const double turns = (kPi - plan.phase) / kTwoPi;
    plan.first_boundary = p.alpha * (turns - std::floor(turns));
    if (plan.first_boundary >= p.alpha) plan.first_boundary = 0;
  });

  // Level of detail per ply: which fibers stay whole and which keep their flyaways (outermost first).
  out->plies.resize(size_t(p.plies));
  std::vector<double> core_radius(size_t(p.plies), 0.0);
  for (int j = 0; j < p.plies; ++j) {
    FiberPlan* ply_plans = &plans[size_t(j) * p.fibers_per_ply];
    std::vector<int> rank(size_t(p.fibers_per_ply));
    std::iota(rank.begin(), rank.end(), 0);
    std::stable_sort(rank.begin(), rank.end(), [&](int a, int b) { return ply_plans[a].r > ply_plans[b].r; });
    int explicit_fibers = 0;
    double farthest = 0;  // of the fibers the core stands for at full detail
    for (int i = 0; i < p.fibers_per_ply; ++i) {
      if (options.core && ply_plans[i].r <= options.core_radius) farthest = std::max(farthest, ply_plans[i].r);
      else ++explicit_fibers;
    }
    const double core_full = farthest * p.rho_max * std::max(p.ellipse_n, p.ellipse_b);
    const LodChoice ply_lod =
        ChooseLod(p.fiber_width, ply_width, options.footprint, explicit_fibers, core_full, options.points_per_twist);
    const int keep_flyaways = int(std::llround(ply_lod.scale * p.fibers_per_ply));
    for (int k = 0; k < p.fibers_per_ply; ++k) {
      FiberPlan& plan = ply_plans[rank[size_t(k)]];
      plan.regular = k < ply_lod.fibers;  // the explicit fibers come first in the ranking
      plan.flyaways = k < keep_flyaways;
    }
    PlyDetail& detail = out->plies[size_t(j)];
    detail.regular_fibers = ply_lod.fibers;
    if (options.core) {
      detail.core_fibers = p.fibers_per_ply - ply_lod.fibers;
      core_radius[size_t(j)] = detail.core_radius = ply_lod.core_radius;
      // The ply's fibers fill its ellipse; the core, a circle of its long semi-axis, holds them at that density.
      const double area = kPi * detail.core_radius * detail.core_radius * std::min(p.ellipse_n, p.ellipse_b) /
                          std::max(p.ellipse_n, p.ellipse_b);
      if (detail.core_radius > 0 && detail.core_fibers > 0)
        detail.core_free_path = area / (detail.core_fibers * p.fiber_width);
      if (detail.core_radius > 0) detail.core_fiber_width = p.fiber_width;
    }
  }

  // Flyaways and the pieces each fiber becomes; counted against the limits before any geometry.
  std::vector<Task> tasks;
  int64_t curves = 0, points = 0;
  const auto over_limits = [&]() -> std::string {
    if (curves > limits.max_fibers)
      return "max_fibers: the yarn needs more than " + std::to_string(limits.max_fibers) + " fiber curves";
    if (points > limits.max_control_points)
      return "max_control_points: the yarn needs more than " + std::to_string(limits.max_control_points) +
             " control points";
    return "";
  };
  for (int j = 0; j < p.plies; ++j) {
    if (core_radius[size_t(j)] > 0) {
      tasks.push_back({j, -1, size_t(curves), {{FiberType::kCore, 0, length, -1}}});
      curves += 1;
      points += geometry.PointsBetween(0, length);
    }
    for (int i = 0; i < p.fibers_per_ply; ++i) {
      const int index = j * p.fibers_per_ply + i;
      FiberPlan& plan = plans[size_t(index)];
      if (!plan.regular && !plan.flyaways) continue;
      FiberRandom rng(p.seed, j, i, kFlyaways);
      if (plan.flyaways && !PlanFlyaways(p, length, rng, &plan, limits.max_fibers - curves))
        return "max_fibers: the yarn needs more than " + std::to_string(limits.max_fibers) + " fiber curves";
      Task task{j, index, size_t(curves), Pieces(p, plan, length)};
      curves += int64_t(task.pieces.size());
      for (const Piece& piece : task.pieces) points += geometry.PointsBetween(piece.start, piece.end);
      if (!(e = over_limits()).empty()) return e;
      if (!task.pieces.empty()) tasks.push_back(std::move(task));
    }
  }
  if (!(e = over_limits()).empty()) return e;

  // Geometry: each task writes its own curves, so threads cannot change the result.
  geometry.PrecomputeFrames();
  std::vector<FiberCurve> result(static_cast<size_t>(curves));
  const double twist_sign = p.counter_twist ? -1 : 1;
  const auto run_task = [&](const Task& task) {
    size_t slot = task.first_curve;
    if (task.plan < 0) {
      FiberCurve& c = result[slot];
      c.type = FiberType::kCore;
      c.ply = task.ply;
      c.width = 2 * core_radius[size_t(task.ply)];
      geometry.Trace(task.ply, 0, length, [](double, double* r, double* psi) { *r = 0, *psi = 0; }, &c.points);
      return;
    }
    const FiberPlan& plan = plans[size_t(task.plan)];
    const FiberShape shape{p, plan, twist_sign};
    for (const Piece& piece : task.pieces) {
      FiberCurve& c = result[slot++];
      c.type = piece.type;
      c.ply = plan.ply;
      c.fiber = plan.index;
      c.width = p.fiber_width;
      if (piece.type == FiberType::kMigration) {
        geometry.Trace(plan.ply, piece.start, piece.end,
                       [&](double arc, double* r, double* psi) { *r = shape.Migration(arc), *psi = shape.Psi(arc); },
                       &c.points);
      } else if (piece.type == FiberType::kLoop) {
        // Eq. 2 with rho_max R_i replaced by the loop's reach over its period (a bump that is 0 at the ends).
        const Flyaway& f = plan.flyaway_list[size_t(piece.flyaway)];
        const double start = piece.start, extra = f.reach - plan.r * p.rho_max;
        geometry.Trace(plan.ply, piece.start, piece.end,
                       [&](double arc, double* r, double* psi) {
                         const double bump = 0.5 * (1 - std::cos(kTwoPi * (arc - start) / p.alpha));
                         *r = shape.Migration(arc) + extra * bump;
                         *psi = shape.Psi(arc);
                       },
                       &c.points);
      } else {
        // Hair: radius linear from the fiber's at the root to the tip's reach; twist pitch kHairPitchScale alpha.
        const Flyaway& f = plan.flyaway_list[size_t(piece.flyaway)];
        double root = 0, tip = 0;
        shape.HairEnds(f, &root, &tip);
        const double r_root = shape.Migration(root), psi_root = shape.Psi(root);
        const double hair_alpha = kHairPitchScale * p.alpha;
        geometry.Trace(plan.ply, piece.start, piece.end,
                       [&](double arc, double* r, double* psi) {
                         const double t = (arc - root) / (tip - root);
                         *r = r_root + (f.reach - r_root) * t;
                         *psi = psi_root + twist_sign * kTwoPi * (arc - root) / hair_alpha;
                       },
                       &c.points);
      }
    }
  };
  if (!runtime::ParallelFor(tasks.size(), options.threads, options.stop, [&](size_t t) { run_task(tasks[t]); }))
    return "cancelled";
  out->fibers = std::move(result);
  out->control_points = points;
  out->lambda = lod.lambda;
  out->points_per_twist = lod.points_per_twist;
  // Psi (twist_sign 2 pi / alpha) and the ply frame's angle (2 pi / alpha_yarn) both turn about the tangent.
  out->core_turn_rate = kTwoPi * (twist_sign / p.alpha + 1 / p.alpha_yarn);
  return "";
}

std::string GenerateStraightYarn(const YarnParams& p, const DetailOptions& options, const YarnLimits& limits,
                                 YarnGeometry* out) {
  if (std::string e = ValidateYarnParams(p); !e.empty()) {
    *out = YarnGeometry();
    return e;
  }
  return GenerateYarn(p, StraightYarnCurve(p.length), options, limits, out);
}

}  // namespace loomlight::yarn
