// Procedural yarn geometry (SPEC.md section 6; Wu and Yuksel Sec. 2.2-3.3, after Zhao, Luan and Bala 2016):
// plies twisting around a yarn centre curve, fibers twisting and migrating around each ply centre, loop and
// hair flyaways, core fibers and the level of detail of Eq. 4. The output is fiber curves (polylines of
// control points with a width and a type), deterministic for a seed whatever the thread count.
//
// Readings of the paper that SPEC.md does not pin (ours):
// - Twist: alpha and alpha_yarn are pitches (length along the yarn per full turn; Eq. 1 has z = alpha theta /
//   2 pi). Plies turn counterclockwise about the yarn tangent (N_yarn towards B_yarn). Fibers turn about their
//   ply centre in the ply's own frame (N_ply, B_ply), which turns with the ply: by default the opposite way
//   (counter_twist), as in real plied yarn (SPEC gives the pitches unsigned).
// - Ply frame: N_ply is the unit displacement from the yarn centre to the ply centre and B_ply = T_yarn x
//   N_ply, both in the yarn's cross-section plane (Fig. 3: "the computation of fiber positions takes place on
//   the cross-section plane perpendicular to the yarn curve"), rather than T_ply x N_ply, which would tilt the
//   cross-section out of that plane.
// - Ellipse: the ply is elongated across its displacement (Sec. 3.1), so the preset's short semi-axis is e_N
//   (along N_ply) and the long one e_B.
// - Flyaway periods: Sec. 3.1 splits each fiber into periods "of alpha (see Equation 1)" and gives each a
//   type; we take that literally, a period is one fiber twist (length alpha), starting where Eq. 2's cosine is
//   -1, so that for s = 1 (the case the paper describes) a period runs from one radius minimum to the next.
//   Eq. 2's own period, alpha / s, would not do for silk1 (s = 0.1): a 4.6-long period would need 6 flyaways
//   per fiber per period to reach the preset's densities with 33 fibers.
// - Densities: hair_density and loop_density count flyaways per unit length of yarn per ply (as in Zhao et
//   al.'s generator), so a period becomes a loop with probability loop_density * alpha / fibers_per_ply and a
//   hair with probability hair_density * alpha / fibers_per_ply. Partial periods at the yarn's ends stay
//   migration, so a yarn of length L has plies * density * (L - alpha) flyaways of each kind on average.
// - Loop: Eq. 2 with rho_max R_i replaced by a reach drawn uniformly in [1.1, 1.5] (in ply radii, so the
//   loop stands out of the ply like Fig. 4's green curve); added as a bump (reach - rho_max R_i)(1 - cos)/2
//   over the period, which is exactly that replacement when s = 1 and joins the neighbouring periods at
//   their ends for any s.
// - Hair: a fraction in [0.25, 0.75] of the period (uniform) is the hair, the rest stays a migration fiber
//   broken at the split. The hair's root is at one end of the period (either, with equal odds), where it
//   joins the neighbouring period; its radius goes linearly from there to a tip reach drawn uniformly in
//   [1.5, 3] ply radii ("from a random radius R_max^hair ... to R_min, or the opposite direction"). Its twist
//   pitch alpha_hair is 4 alpha, same sense as the fiber: "distinctly different", nearly straight strands.
// - Fiber width: not a SPEC parameter; the presets use the diameter of a disk with the ply's cross-section
//   area per fiber, 2 sqrt(e_N e_B / fibers_per_ply), so omega_ply / omega_fiber is a constant of the model
//   as Sec. 3.3 says.
// - Core: the fibers whose R_i is at most DetailOptions::core_radius (ply radii) are represented by one core
//   fiber per ply along the ply centre; its radius is the farthest they reach, max R_i * rho_max * max(e_N,
//   e_B). Their loops and hairs are still generated ("the loop and hair fibers are represented by other
//   fibers that are explicitly generated").
// - Level of detail (Eq. 4): see ChooseLod. The fibers kept whole are the outermost (largest R_i); the loops
//   and hairs kept are those of the outermost round(lambda^2 fibers_per_ply) fibers, so flyaways thin out
//   with the fibers and are gone when only the cores remain.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "server/yarn/curve.h"

namespace loomlight::yarn {

// ---- Parameters ----

// One yarn. Defaults are the cotton1 preset. Lengths in the presets' unit (see Vec3).
struct YarnParams {
  int plies = 3;             // K, n_ply
  int fibers_per_ply = 75;   // including those a core fiber stands for
  double yarn_radius = 0.0378;  // R_ply: ply centres sit at yarn_radius / 2 from the yarn centre
  double ellipse_n = 0.0200;    // e_N: the ply's semi-axis along N_ply (towards the yarn centre), the short one
  double ellipse_b = 0.0257;    // e_B: the ply's semi-axis along B_ply, the long one
  double alpha = 0.366;         // fiber twist pitch around the ply centre (length per turn)
  double alpha_yarn = 0.453;    // ply twist pitch around the yarn centre
  bool counter_twist = true;    // fibers turn in their ply the opposite way to the plies in the yarn
  double eps = 0;               // D(R) = (1 - 2 eps) ((e - e^R) / (e - 1))^beta + eps
  double beta = 0.201;
  double s = 1.0;               // Eq. 2: migration phase runs s times as fast as the twist angle
  double rho_min = 0.85;        // Eq. 2: radius multipliers, R(theta) in [rho_min, rho_max] R_i
  double rho_max = 1.0;
  double hair_density = 30.36;  // hairs per unit length of yarn per ply
  double loop_density = 19.10;  // loops per unit length of yarn per ply
  double fiber_width = 0.005235774377619163;  // diameter of a regular fiber, 2 sqrt(e_N e_B / fibers_per_ply)
  uint64_t seed = 1;
  double length = 1.0;          // of the straight yarn (GenerateStraightYarn)

  bool operator==(const YarnParams&) const = default;
};

// Ranges ValidateYarnParams enforces (lengths are yarn_radius, ellipse_n, ellipse_b, alpha, alpha_yarn,
// fiber_width and length). They bound the work one yarn can ask for; the presets sit well inside.
inline constexpr int kMaxPlies = 12;
inline constexpr int kMaxFibersPerPly = 20'000;
inline constexpr double kMinLength = 1e-6;
inline constexpr double kMaxLength = 1e3;
inline constexpr double kMaxBeta = 10;  // rejection sampling still accepts ~3% of draws at beta = 10
inline constexpr double kMaxS = 100;
inline constexpr double kMaxDensity = 1e6;

// Returns "" or "field: reason" for the first problem. Rules: 1 <= plies <= kMaxPlies; 1 <= fibers_per_ply
// <= kMaxFibersPerPly; every length finite in [kMinLength, kMaxLength]; eps in [0, 1]; beta in [0, kMaxBeta];
// s in [0, kMaxS]; 0 < rho_max <= 1 and 0 <= rho_min <= rho_max; densities finite in [0, kMaxDensity] and
// (hair_density + loop_density) * alpha / fibers_per_ply <= 1 (at most one flyaway per fiber twist).
std::string ValidateYarnParams(const YarnParams& p);

// The five presets of SPEC.md section 6: cotton1, cotton2, polyester1, rayon2, silk1.
std::vector<std::string> YarnPresetNames();
// Sets *out to the named preset (seed and length at their defaults). Returns "" or "preset: unknown ...".
std::string YarnPreset(std::string_view name, YarnParams* out);

// The fiber cross-section density D(R) of SPEC.md section 6, R in ply radii (unnormalised: D(0) = 1 - eps,
// D(1) = eps).
double FiberDensity(double r, double eps, double beta);

// ---- Level of detail (Sec. 3.3, Eq. 4) ----

// Eq. 4 with widths in world units instead of screen units (the ratios are the same): fiber_width is
// omega_fiber, ply_width omega^ply and footprint omega^LoD, the width the threshold covers at the yarn (a
// pixel's footprint when the threshold is one pixel). 1 when footprint <= fiber_width, 0 when footprint >=
// ply_width, else (fiber_width / footprint) (ply_width - footprint) / (ply_width - fiber_width).
double LodLambda(double fiber_width, double ply_width, double footprint);

// What a ply keeps at one footprint. scale is the paper's lambda^2.
struct LodChoice {
  double lambda = 1;
  double scale = 1;
  int fibers = 0;            // regular fibers generated: round(lambda^2 n_max)
  double core_radius = 0;    // ply_radius + lambda^2 (core_radius_full - ply_radius)
  int points_per_twist = 0;  // subdivisions: max(kMinPointsPerTwist, round(lambda^2 points_per_twist))
};

// Most and fewest control points per shortest period (fiber twist, ply twist or migration period).
inline constexpr int kMinPointsPerTwist = 8;
inline constexpr int kMaxPointsPerTwist = 256;

// Eq. 4 for one ply: lambda from LodLambda; the regular fibers kept are round(lambda^2 max_fibers) (the paper's
// lambda^2 n_max^fiber); the core radius goes from its full-detail value (lambda = 1) to the ply radius
// (lambda = 0) linearly in lambda^2 ("scaled between its original thickness and the thickness of the ply
// using the same scaling factor"); the points per twist scale by lambda^2 too, down to kMinPointsPerTwist.
LodChoice ChooseLod(double fiber_width, double ply_width, double footprint, int max_fibers, double core_radius_full,
                    int points_per_twist);

// The ply's width for Eq. 4 (omega^ply): 2 rho_max max(e_N, e_B), the widest the ply's fibers reach.
double PlyWidth(const YarnParams& p);

// ---- Generation ----

// How much of the yarn to generate. The defaults are the paper's method at full detail.
struct DetailOptions {
  bool core = true;          // one core fiber per ply stands for the fibers within core_radius
  double core_radius = 0.5;  // in ply radii, [0, 1] (ours: the inner half radius, ~30% of cotton1's fibers)
  double footprint = 0;      // Eq. 4's omega^LoD in world units; 0 = full detail. Needs core.
  int points_per_twist = 16; // control points per shortest period, [kMinPointsPerTwist, kMaxPointsPerTwist]
  int threads = 1;           // [1, 64]; the output does not depend on it
  // Polled between fibers (from the generating threads); once it returns true, generation ends with
  // "cancelled" and no geometry. Unset: never. For deadlines and clients that go away.
  std::function<bool()> stop;
  // Whether `o` generates the same fibers: every field but threads and stop (a new field belongs here too).
  bool SameOutput(const DetailOptions& o) const {
    return core == o.core && core_radius == o.core_radius && footprint == o.footprint &&
           points_per_twist == o.points_per_twist;
  }
};
std::string ValidateDetailOptions(const DetailOptions& o);

// Bounds on one generation, for a server handling client parameters. Both are checked before the
// geometry is built (and before most of the sampling), so a request over them costs little.
struct YarnLimits {
  int64_t max_fibers = 100'000;           // fiber curves returned; the yarn's plies * fibers_per_ply too
  int64_t max_control_points = 4'000'000; // control points returned, all curves together
  bool operator==(const YarnLimits&) const = default;
};

// The sampling intervals GenerateYarn puts along a yarn `length` long: its shortest period (a fiber twist, a ply
// twist, or Eq. 2's migration period alpha / s) split into the points per twist the level of detail leaves, at
// least 1. Every ply has a curve along the whole yarn (its core or its fibers' pieces), so MinControlPoints,
// plies x (intervals + 1), is the fewest control points it returns: the bound a layout checks before generating.
double SamplingIntervals(const YarnParams& p, const DetailOptions& options, double length);
double MinControlPoints(const YarnParams& p, const DetailOptions& options, double length);

enum class FiberType : uint8_t {
  kCore,       // one per ply, along the ply centre, standing for its inner fibers
  kMigration,  // a regular fiber (Eq. 2), or a run of one between flyaways
  kLoop,       // one period with a larger reach, joined to its neighbours
  kHair,       // one open-ended piece of a period
};
const char* ToString(FiberType type);

// One fiber curve: a polyline through its control points, in order of arc length along the yarn.
struct FiberCurve {
  FiberType type = FiberType::kMigration;
  int ply = 0;
  int fiber = -1;      // index within the ply (-1 for a core); the pieces of one fiber share it
  double width = 0;    // diameter
  std::vector<Vec3> points;

  bool operator==(const FiberCurve&) const = default;
};

// What the level of detail chose for one ply.
struct PlyDetail {
  int regular_fibers = 0;  // fibers generated whole (as migration runs between their flyaways)
  int core_fibers = 0;     // fibers the core stands for (all the others when there is a core)
  double core_radius = 0;  // 0 when there is no core curve
  // The mean free path of a line across the core's fibers (parallel, spread evenly over the ply's ellipse
  // scaled to the core): its area over core_fibers x fiber width. 0 when there is no core curve.
  double core_free_path = 0;
  double core_fiber_width = 0;  // the width of the fibers it stands for (0 when there is no core curve)

  bool operator==(const PlyDetail&) const = default;
};

struct YarnGeometry {
  std::vector<FiberCurve> fibers;  // per ply: its core, then its fibers by index, each fiber's pieces in order
  int64_t control_points = 0;
  double lambda = 1;               // Eq. 4 at the options' footprint
  int points_per_twist = 0;        // after the level of detail
  std::vector<PlyDetail> plies;
  // How fast the fibers a core stands for turn about it, radians per unit length along the curve (signed,
  // right-handed about the curve's direction): their twist in the ply plus the ply's turn in the yarn. At the
  // core's surface (radius r, outward normal n) they run along t + rate r (t x n): the "surface direction" of
  // Sec. 3.2's core texture, which the core's shading needs (its highlight is theirs, not a smooth rod's).
  double core_turn_rate = 0;

  bool operator==(const YarnGeometry&) const = default;
};

// Generates the yarn along `curve` (over its whole length, which must be finite in [kMinLength, kMaxLength]).
// Returns "" and fills *out, or "field: reason" naming the parameter, option or limit ("max_fibers: ...",
// "max_control_points: ...") that stopped it, leaving *out empty.
std::string GenerateYarn(const YarnParams& p, const YarnCurve& curve, const DetailOptions& options,
                         const YarnLimits& limits, YarnGeometry* out);

// The straight yarn of Fig. 7: along +z from the origin, p.length long.
std::string GenerateStraightYarn(const YarnParams& p, const DetailOptions& options, const YarnLimits& limits,
                                 YarnGeometry* out);

}  // namespace loomlight::yarn
