#include "server/render/shading.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "server/models/material_plan.h"
#include "server/models/tabulated_brdf.h"
#include "server/render/folded_environment.h"
#include "server/render/lighting_presets.h"

namespace loomlight::render {
namespace {

constexpr double kDegree = std::numbers::pi / 180;
// Light samples this close to the surface plane carry no light (f is 0 there for every model).
constexpr double kMinCosine = 1e-6;
// SamplePoints' dimension pairs: the pixel position, then one per sampling strategy.
enum Pair : uint32_t { kPixelPair, kBrightPair, kRestPair, kMaterialPair, kMaterialChoicePair, kAmbientPair, kCoreDepthPair, kCoreNormalPair };
// Area lights' pairs: light i's point on the light is pair kFirstLightPair + i (clear of the strategies' pairs).
constexpr uint32_t kFirstLightPair = 64;

float WrapUnit(double t) {
  const float f = static_cast<float>(t - std::floor(t));
  return f < 1.0f ? f : 0.0f;  // rounding up to 1 wraps to 0
}

// The direct transmittance toward w of what lets light straight through the material: its curtain layer, or
// the material itself when it transmits (0 when neither does).
double SeeThrough(const models::PreparedMaterial& m, const Vec3& w) {
  const models::PreparedMaterial& through = m.transmission ? *m.transmission : m;
  const float dir[3] = {float(w.x), float(w.y), float(w.z)};
  double t = 0;
  through.model->DirectTransmittance(through.packed, dir, 1, &t);
  return std::isfinite(t) ? std::clamp(t, 0.0, 1.0) : 0.0;
}

// Veach's balance heuristic with sample counts, as the factor a sample's f L cos is multiplied by: w / (n p) =
// 1 / (n p + n' p'), `drawn` = n p for the strategy that drew the sample (its density times its samples per hit),
// `other` = n' p' for the other one toward the same direction. Measured against the power heuristic (SPEC.md
// section 8's default, beta = 2) at 10 spp, 6 seeds: 10% less variance on the satin cylinders, 6% on the twill, 5%
// on the satin sphere (beta 1.5: -7%, 0.75: +3% on the satin); the tabulated material density is close enough to
// f cos that sharpening the weights only adds the table's own error.
double BalanceOverDensity(double drawn, double other) {
  if (!(drawn > 0)) return 0;
  const double sum = drawn + std::max(other, 0.0);
  return std::isfinite(sum) ? 1 / sum : 0;
}

// Material draws per hit (with one from each environment component), a power of two (SamplePoints::Subsample).
// The material's draws carry most of the noise left on cloth under a sky (doubling them, independent: -36%
// variance on the satin cylinders at 10 spp; the map's rest: -17%; the sun's: -2%), and a hit's own work (camera
// ray, frame, the material's density at wo) is shared by them. Stratified together, at the same CPU time, 2
// against 1 left 32% less variance on the satin cylinders, 26% on the twill, 36% on the satin sphere; 4 against 2
// 18%, 9%, 24%; 8 against 4 4% more, 13% more, 5% more (6 seeds, interleaved servers).
constexpr uint32_t kMaterialSamples = 4;

// Whether hits on `object` take their environment light from the fold (no environment or material samples).
bool EnvironmentFolded(const RenderSetup& setup, int object) {
  return setup.folded_environment && setup.folded_environment->Covers(object);
}

uint32_t EnvironmentPair(Environment::Component component) {
  return component == Environment::kBright ? kBrightPair : kRestPair;
}

Environment::Sample DrawEnvironment(const RenderSetup& setup, const SamplePoints& points, Environment::Component component) {
  const std::array<double, 2> u = points.Get2D(EnvironmentPair(component));
  return setup.environment->Draw(component, u[0], u[1]);
}

// Calls add(direction toward the light, distance to it, incident radiance over pdf times the MIS weight, index of
// the light in setup.lights or -1) for every light (a rect light: one point on it, by light sampling alone; weighed
// against the material's draws finding it too, the studio preset's error at 16 samples grew 1.2 to 3.4 times on
// satin and linen, balance or power heuristic: the draws hit or miss a softbox, its solid angle's points never
// do), and (with_environment) one direction from each component of the environment (its bright regions,
// the rest) as seen from `position`. material_density(direction) is the material sampling strategy's density
// toward a direction times its draws per hit (0 where there is none), against which the environment's samples are
// weighed. `drawn`: the environment's directions drawn ahead (null: drawn here from `points`).
template <class MaterialDensity, class Add>
void ForEachLight(const RenderSetup& setup, Vec3 position, const SamplePoints& points, MaterialDensity material_density, Add add,
                  bool with_environment, const EnvironmentDraws* drawn) {
  for (size_t index = 0; index < setup.lights.size(); ++index) {
    const Light& light = setup.lights[index];
    if (light.type == Light::Type::kDirectional) {
      add(light.direction, INFINITY, light.rgb, int(index));
    } else if (light.type == Light::Type::kRect) {  // one point of the softbox per sample, its own Sobol pair
      const std::array<double, 2> u = points.Get2D(kFirstLightPair + uint32_t(index));
      RectLightSample sample;
      if (SampleRectLight(light, position, u[0], u[1], &sample)) add(sample.direction, sample.distance, sample.incident, int(index));
    } else {
      const Vec3 to_light = light.position - position;
      const double d2 = Dot(to_light, to_light);
      if (d2 < 1e-12) continue;  // a light on the surface itself: no defined direction
      const double d = std::sqrt(d2);
      add((1.0 / d) * to_light, d, (1.0 / d2) * light.rgb, int(index));
    }
  }
  if (!setup.environment || !with_environment) return;
  for (const Environment::Component component : {Environment::kBright, Environment::kRest}) {
    if (!setup.environment->Has(component)) continue;
    const Environment::Sample sample = drawn ? drawn->component[component] : DrawEnvironment(setup, points, component);
    if (sample.pdf <= 0) continue;
    const double weight = BalanceOverDensity(sample.pdf, material_density(sample.direction));
    if (weight > 0) add(sample.direction, INFINITY, weight * sample.radiance, -1);
  }
}

// A fiber is a line to its scattering model (far field): light leaves and arrives at its axis, from the whole
// sphere. Shadow and occlusion rays therefore start on the axis and skip the fiber's own tube: the distance
// from the axis to the tube's surface along w is r / sin(angle to the axis), bounded for w near the axis
// (there cos(theta_i) -> 0 and the sample carries almost nothing).
struct FiberRayStart {
  Vec3 origin;
  Vec3 axis;
  double radius;
  double MinDistance(Vec3 w) const {
    const double along = Dot(w, axis);
    const double sine = std::sqrt(std::max(0.0, 1.0 - along * along));
    return 1.001 * radius / std::max(sine, 0.05) + kRayOffset;
  }
};

// A core stands for the bundle of fibers inside it (Sec. 3.2, whose core texture, a height map with holes,
// shows them at depth). Its fibers are parallel, so only paths across them (in the cross-section) count: a
// camera ray reaching the core's surface meets one at a path length across drawn from the exponential
// distribution of the bundle's mean free path l, and light reaches that fiber through the rest of the bundle
// with the gap probability of randomly placed parallel fibers of width w (l = 1 / (density w)): exp(-(s - o) / l),
// s the path across to the surface and o the part of its strip of width w that the camera ray's own strip
// already showed empty (the hot spot: light arriving back along the view sees the gap the view came through).
// Shaded as an opaque rod instead, a thick core was lit where the fibers it replaces sit in each other's shade:
// the benchmark's distant cotton1 view with cores only rendered 46% brighter than full detail, 28% with the
// bundle, whose light without the R highlight agrees within 5% (the rest is cotton's 1-degree, C_R 0.99 highlight
// on the core's one helix of fiber directions). A core without a free path (no fibers counted) stays an opaque
// rod: its side away from a direction is in its own shadow.
class CoreBundle {
 public:
  CoreBundle() = default;
  // direction: the camera ray's; u uniform in [0, 1), for the depth.
  CoreBundle(const Hit& hit, Vec3 direction, double u)
      : axis_(hit.fiber_core_axis), radius_(hit.fiber_radius), free_path_(hit.fiber_core_free_path),
        width_(hit.fiber_core_fiber_width) {
    normal_ = hit.normal;  // faces the ray: outward on a ray from outside
    centre_ = hit.position - radius_ * normal_;
    at_ = hit.position;
    const Vec3 across = Across(direction);
    const double m = Length(across);
    if (!(free_path_ > 0) || !(m > 1e-9)) return;
    view_ = (1 / m) * across;
    // The exponential's inverse CDF (log1p keeps small u exact), within the chord (beyond it in e^(-chord / l)).
    const double chord = Chord(Across(hit.position - centre_), view_);
    depth_ = std::min(0.999 * chord, -free_path_ * std::log1p(-u));
    at_ = hit.position + (depth_ / m) * direction;
  }
  Vec3 at() const { return at_; }
  // A rod's own shade: the side of it away from w (decided by the normal, not a chord: Embree misses the
  // near-tangent chords of a ray started on the surface).
  bool RodShades(Vec3 w) const { return !(free_path_ > 0) && Dot(w, normal_) <= 0; }
  // Transmittance toward w from the fiber met, and in *exit where the ray leaves the core (just outside).
  double Leave(Vec3 w, Vec3* exit) const {
    if (!(free_path_ > 0)) {
      *exit = at_ + (1e-4 * radius_) * normal_;
      return RodShades(w) ? 0.0 : 1.0;
    }
    const Vec3 q = Across(at_ - centre_), w_across = Across(w);
    const double m = Length(w_across);
    if (!(m > 1e-9)) {  // along the fibers: crosses none (the scattering's cos(theta_i) is 0 there anyway)
      *exit = at_;
      return 1.0;
    }
    const Vec3 d = (1 / m) * w_across;
    const double s = Chord(q, d);
    const Vec3 surface = q + s * d;  // relative to the centre line
    *exit = at_ + (s / m) * w + (1e-4 / std::max(Length(surface), 1e-30) * radius_) * surface;
    // Fibers block the ray when their centres lie within w/2 of its path (area s w), save those whose tubes hold
    // its start (an explicit fiber's ray starts on its own tube's surface, and a ray leaving a tube is not blocked
    // by it: a disc of area pi w^2 / 4) and those the camera ray's path showed absent: for the two half-strips at
    // angle gamma, (w^2 / 4)(cot(gamma / 2) - (pi - gamma) / 2), at most w min(s, depth). Against explicit random
    // fibers traced the same way (2D, packing 0.2-0.6, lights 17-90 degrees from the view): within 6%.
    const double cos_gamma = std::clamp(-Dot(d, view_), -1.0, 1.0), sin_gamma = std::sqrt(1 - cos_gamma * cos_gamma);
    double shown = width_ * std::min(s, depth_);
    if (sin_gamma > 0) {
      const double cot_half = (1 + cos_gamma) / sin_gamma;
      shown = std::min(shown, 0.25 * width_ * width_ * (cot_half - 0.5 * (std::numbers::pi - std::acos(cos_gamma))));
    }
    const double shown_path = width_ > 0 ? shown / width_ : 0.0;
    const double blocking = std::max(0.0, s - 0.25 * std::numbers::pi * width_ - shown_path);
    return std::exp(-blocking / free_path_);
  }

 private:
  Vec3 Across(Vec3 v) const { return v - Dot(v, axis_) * axis_; }
  // From q (across, relative to the centre line) along the unit d (across) to the core's surface.
  double Chord(Vec3 q, Vec3 d) const {
    const double b = Dot(q, d), c = Dot(q, q) - radius_ * radius_;
    return std::max(0.0, -b + std::sqrt(std::max(0.0, b * b - c)));
  }

  Vec3 axis_, normal_, centre_, at_, view_;
  double radius_ = 0, free_path_ = 0, width_ = 0, depth_ = 0;
};

// Bundle transmittances below this are played by Russian roulette (kept at this value with probability t / it),
// so the rays toward a core's far side (e^-10 through it) are rarely traced, without bias (one random number for
// all of a sample's rays: each estimate stays unbiased).
constexpr double kRouletteTransmittance = 0.05;

// The frame of a thin fiber along `axis` met by a ray along `direction` at offset h (uniform in [-1, 1])
// across it: its normal on the side facing the ray, sqrt(1 - h^2) of the way toward the ray, h sideways.
Frame ThinFiberFrame(Vec3 axis, Vec3 direction, double h) {
  Vec3 toward = -direction + Dot(direction, axis) * axis;
  const double m = Length(toward);
  toward = m > 1e-9 ? (1 / m) * toward : AnyPerpendicular(axis);
  const Vec3 side = Cross(axis, toward);
  const Vec3 n = std::sqrt(std::max(0.0, 1 - h * h)) * toward + h * side;
  return {axis, Cross(n, axis), n};
}

void ShadeFiber(const RenderSetup& setup, const Hit& hit, Vec3 direction, const SamplePoints& points,
                const EnvironmentDraws* drawn, ShadingPoint* point) {
  // A core's fiber met inside the bundle is shaded about its own surface normal, drawn as a ray meets a thin
  // fiber, not the rod's outer normal: on the rod the side facing the light is also the one its light reaches
  // through the least of the bundle, a correlation the fibers it stands for do not have.
  const Frame frame = hit.fiber_core && hit.fiber_core_free_path > 0
                          ? ThinFiberFrame(hit.fiber_axis, direction, 2 * points.Get1D(kCoreNormalPair) - 1)
                          : Frame{hit.tangent_s, hit.tangent_t, hit.normal};
  point->wo = frame.ToLocal(-direction);
  point->wo.z = std::max(point->wo.z, 0.0);  // the normal faces the ray
  point->axis = frame.ToLocal(hit.fiber_axis);
  point->u = point->v = 0;
  const bool core = hit.fiber_core;
  const std::array<double, 2> core_u = core ? points.Get2D(kCoreDepthPair) : std::array<double, 2>{0, 0};
  const CoreBundle bundle = core ? CoreBundle(hit, direction, core_u[0]) : CoreBundle();
  const FiberRayStart start = core ? FiberRayStart{bundle.at(), hit.fiber_axis, 0}
                                   : FiberRayStart{hit.position - hit.fiber_radius * hit.normal, hit.fiber_axis, hit.fiber_radius};
  // Where a ray toward w starts, how far it skips, and the light that gets that far (from a core: through its
  // bundle; 0 when the roulette drops it).
  struct Departure {
    Vec3 origin;
    double skip = 0;
    double transmittance = 1;
  };
  const auto depart = [&](Vec3 w) -> Departure {
    if (!core) return {start.origin, start.MinDistance(w), 1};
    Departure out{{}, kRayOffset, 0};
    out.transmittance = bundle.Leave(w, &out.origin);
    if (out.transmittance < kRouletteTransmittance)
      out.transmittance = core_u[1] * kRouletteTransmittance < out.transmittance ? kRouletteTransmittance : 0.0;
    return out;
  };
  // The approximations stand for the fibers only (a fiber scene has no other shapes to block light).
  const yarn::YarnVisibility* approximate = setup.scene.fiber_visibility.get();
  const bool slices = approximate && setup.fiber_shadows == yarn::ShadowMethod::kSlices;
  const bool occlusion = approximate && setup.fiber_occlusion != yarn::OcclusionMethod::kTraced;
  const auto to_yarn = [&](Vec3 v) { return yarn::Vec3{v.x, v.y, v.z}; };
  const yarn::CrossSectionPoint in_yarn =
      slices || occlusion ? approximate->Locate(hit.fiber_yarn, to_yarn(start.origin)) : yarn::CrossSectionPoint{};
  // A fiber's light comes from light sampling alone (its scattering is not sampled: the weights stay 1).
  const auto no_material_density = [](Vec3) { return 0.0; };
  ForEachLight(setup, hit.position, points, no_material_density, [&](Vec3 wi_world, double max_distance, Rgb incident, int light) {
    const Vec3 wi = frame.ToLocal(wi_world);
    const double along = Dot(wi, point->axis);
    const double cos_theta = std::sqrt(std::max(0.0, 1.0 - along * along));  // SPEC.md section 5's cos(theta_i)
    if (cos_theta < kMinCosine) return;
    double transmittance = 1;
    if (slices) {  // the slices hold the whole yarn's density, a core's fibers too: from the fiber met
      if (core && bundle.RodShades(wi_world)) return;
      if (approximate->OtherYarnsBlock(hit.fiber_yarn, to_yarn(start.origin), to_yarn(wi_world), max_distance)) return;
      transmittance = approximate->SelfShadow(in_yarn, to_yarn(wi_world), start.radius);
    } else {
      const Departure from = depart(wi_world);
      if (!(from.transmittance > 0) || setup.scene.Occluded(from.origin, wi_world, max_distance, from.skip)) return;
      transmittance = from.transmittance;
    }
    point->lights.push_back({wi, (cos_theta * transmittance) * incident, light});
  }, true, drawn);
  point->ambient = {};
  if (setup.ambient > 0) {
    // Ambient visibility: traced, one uniformly distributed direction on the sphere per sample through the
    // fibers; approximated, the yarn's own occlusion times the other yarns' tabulated openness (at a core, those
    // of the fiber met inside it).
    double visibility = 0;
    if (occlusion) {
      visibility = approximate->OtherYarnsOpenness(in_yarn) * approximate->Occlusion(in_yarn, setup.fiber_occlusion);
    } else {
      const std::array<double, 2> u = points.Get2D(kAmbientPair);
      const double z = 1 - 2 * u[0], phi = 2 * std::numbers::pi * u[1];
      const double r = std::sqrt(std::max(0.0, 1 - z * z));
      const Vec3 w{r * std::cos(phi), r * std::sin(phi), z};
      const Departure from = depart(w);
      if (from.transmittance > 0 && !setup.scene.Occluded(from.origin, w, INFINITY, from.skip))
        visibility = from.transmittance;
    }
    point->ambient = (setup.ambient * visibility) * Rgb{1, 1, 1};
  }
}

}  // namespace

Frame ShadingFrame(const RenderSetup& setup, int object, const Hit& hit, float* u, float* v) {
  const double angle = (setup.scene.objects[object].thread_angle_deg + setup.texture_rotation_deg) * kDegree;
  // The same few angles come hit after hit: each thread keeps the last one's cosine and sine (sincos was 2% of
  // a render's time).
  thread_local double last_angle = 0, last_c = 1, last_s = 0;
  if (angle != last_angle) {
    last_angle = angle;
    last_c = std::cos(angle);
    last_s = std::sin(angle);
  }
  const double c = last_c, s = last_s;
  if (u) *u = WrapUnit(setup.texture_scale * (c * hit.s + s * hit.t));
  if (v) *v = WrapUnit(setup.texture_scale * (-s * hit.s + c * hit.t));
  return {c * hit.tangent_s + s * hit.tangent_t, -s * hit.tangent_s + c * hit.tangent_t, hit.normal};
}

void TraceSample(const RenderSetup& setup, double px, double py, const SamplePoints& points, ShadingPoint* point) {
  TraceRay(setup, setup.camera.position(), setup.camera.Direction(px, py), setup.camera.pixel_angle(), points, point);
}

void TraceRay(const RenderSetup& setup, Vec3 origin, Vec3 direction, double pixel_angle, const SamplePoints& points,
              ShadingPoint* point) {
  Hit hit;
  const bool found = setup.scene.Intersect(origin, direction, 0.0, INFINITY, &hit);
  ShadeHit(setup, direction, pixel_angle, points, found ? &hit : nullptr, point);
}

void ShadeHit(const RenderSetup& setup, Vec3 direction, double pixel_angle, const SamplePoints& points, const Hit* found,
              ShadingPoint* point, const EnvironmentDraws* drawn) {
  point->object = -1;
  point->environment_folded = false;
  point->background = {};
  point->lights.clear();
  point->fiber = false;
  point->ambient = {};
  if (found == nullptr) {
    if (setup.environment) point->background = setup.environment->Radiance(direction);
    return;
  }
  const Hit& hit = *found;
  point->object = hit.object;
  point->fiber = hit.fiber;
  point->footprint = hit.distance * pixel_angle;
  if (hit.fiber) return ShadeFiber(setup, hit, direction, points, drawn, point);
  const Frame frame = ShadingFrame(setup, hit.object, hit, &point->u, &point->v);

  // The cloth is two-sided: seen from behind, both directions are mirrored through the surface (as
  // Evaluate does for a curtain's back), so wo is always in the upper hemisphere.
  Vec3 wo = frame.ToLocal(-direction);
  const double mirror = wo.z < 0 ? -1.0 : 1.0;
  wo.z *= mirror;
  point->wo = wo;
  // A folded object's environment light comes from the fold (added by the renderer), not from samples.
  const bool folded = EnvironmentFolded(setup, hit.object);
  point->environment_folded = folded;
  point->back = mirror < 0;
  point->s = hit.s;
  point->t = hit.t;

  const bool transmits = hit.object < static_cast<int>(setup.object_transmits.size()) && setup.object_transmits[hit.object];
  if (transmits) {
    Hit behind;  // what the camera sees through the cloth: the environment, or nothing past another object
    if (setup.environment && !setup.scene.Intersect(hit.position + kRayOffset * direction, direction, 0.0, INFINITY, &behind))
      point->background = setup.environment->Radiance(direction);
  }

  const auto to_local = [&](Vec3 w) {
    Vec3 l = frame.ToLocal(w);
    l.z *= mirror;
    return l;
  };
  const auto add = [&](Vec3 wi_world, double max_distance, Rgb incident, int light) {
    const double side = Dot(wi_world, hit.normal) >= 0 ? 1.0 : -1.0;
    const Vec3 wi = to_local(wi_world);
    if (std::fabs(wi.z) < kMinCosine || (wi.z < 0 && !transmits)) return;  // light behind opaque cloth: no ray
    if (setup.scene.Occluded(hit.position + (side * kRayOffset) * hit.normal, wi_world, max_distance)) return;
    point->lights.push_back({wi, std::fabs(wi.z) * incident, light});
  };
  // The material's own sampling strategy (when the object has one and there is an environment to find).
  const models::DirectionSampler* sampler =
      setup.environment && !folded && hit.object < static_cast<int>(setup.object_samplers.size()) ? setup.object_samplers[hit.object]
                                                                                                   : nullptr;
  models::DirectionSampler::Conditional material;
  if (sampler) material = sampler->At({wo.x, wo.y, wo.z}, models::DirectionSampler::kMisCosineFraction);
  const auto material_density = [&](Vec3 wi_world) {
    if (!sampler) return 0.0;
    const Vec3 wi = to_local(wi_world);
    return kMaterialSamples * material.Pdf({wi.x, wi.y, wi.z});
  };
  // The material's directions are drawn first and their pixels of the map read while the lights are sampled
  // (their queries still come after the lights'). Each draw's points are its own of the pixel's kMaterialSamples x
  // spp, so a pixel's material draws stay stratified together.
  struct MaterialDraw {
    models::DirectionSampler::Sample sample;
    Vec3 wi_world;
    Environment::PixelRef seen;
  };
  std::array<MaterialDraw, kMaterialSamples> draws{};
  std::array<models::DirectionSampler::Conditional::Started, kMaterialSamples> started;
  for (uint32_t j = 0; sampler && j < kMaterialSamples; ++j) {
    const SamplePoints own = points.Subsample(j, kMaterialSamples);
    const std::array<double, 2> u = own.Get2D(kMaterialPair);
    started[j] = material.Start(own.Get1D(kMaterialChoicePair), u[0], u[1]);
  }
  for (uint32_t j = 0; sampler && j < kMaterialSamples; ++j) {
    MaterialDraw& d = draws[j];
    d.sample = material.Finish(started[j]);
    if (d.sample.pdf > 0) {
      const Vec3 local{d.sample.wi[0], d.sample.wi[1], mirror * d.sample.wi[2]};
      d.wi_world = local.x * frame.x + local.y * frame.y + local.z * frame.n;
      d.seen = setup.environment->Locate(d.wi_world);
    }
  }
  ForEachLight(setup, hit.position, points, material_density, add, !folded, drawn);
  for (const MaterialDraw& d : draws) {
    if (!(d.sample.pdf > 0)) continue;
    const Environment::Found light = setup.environment->Lookup(d.seen, d.wi_world);  // one draw per component
    const double weight = BalanceOverDensity(kMaterialSamples * d.sample.pdf, light.pdf);
    if (weight > 0 && (light.radiance.x > 0 || light.radiance.y > 0 || light.radiance.z > 0))
      add(d.wi_world, INFINITY, weight * light.radiance, -1);
  }
}

void TracePixelSample(const RenderSetup& setup, uint64_t pixel, uint32_t sample, ShadingPoint* point) {
  const PixelSample one{pixel, sample};
  TracePixelSamples(setup, {&one, 1}, point);
}

void TracePixelSamples(const RenderSetup& setup, std::span<const PixelSample> samples, ShadingPoint* points) {
  std::array<Vec3, Scene::kMaxPacket> directions;
  std::array<Hit, Scene::kMaxPacket> hits;
  std::array<uint8_t, Scene::kMaxPacket> found;
  std::array<std::array<double, 2>, Scene::kMaxPacket> environment_u[2];
  std::array<Environment::Sample, Scene::kMaxPacket> environment_drawn[2];
  std::array<uint8_t, Scene::kMaxPacket> lit_index;
  for (size_t done = 0; done < samples.size(); done += Scene::kMaxPacket) {
    const size_t n = std::min(samples.size() - done, Scene::kMaxPacket);
    for (size_t k = 0; k < n; ++k) {
      const PixelSample& p = samples[done + k];
      const std::array<double, 2> u = SamplePoints(setup.seed, p.pixel, p.sample).Get2D(kPixelPair);
      const double x = static_cast<double>(p.pixel % setup.width), y = static_cast<double>(p.pixel / setup.width);
      directions[k] = setup.camera.Direction(x + u[0], y + u[1]);
    }
    // Cast together: neighbouring pixels' camera rays are as coherent as rays get (Embree packets, for fibers).
    setup.scene.IntersectFrom(setup.camera.position(), {directions.data(), n}, {hits.data(), n}, {found.data(), n});
    // The environment's directions of the hits that sample it, drawn together (their cache misses overlap).
    size_t lit = 0;
    for (size_t k = 0; k < n; ++k) {
      if (!found[k] || !setup.environment || EnvironmentFolded(setup, hits[k].object)) continue;
      const PixelSample& p = samples[done + k];
      const SamplePoints points(setup.seed, p.pixel, p.sample);
      for (const Environment::Component c : {Environment::kBright, Environment::kRest})
        environment_u[c][lit] = points.Get2D(EnvironmentPair(c));
      lit_index[lit++] = uint8_t(k);
    }
    for (const Environment::Component c : {Environment::kBright, Environment::kRest})
      if (lit > 0) setup.environment->DrawPacket(c, {environment_u[c].data(), lit}, {environment_drawn[c].data(), lit});
    for (size_t k = 0, next_lit = 0; k < n; ++k) {
      const PixelSample& p = samples[done + k];
      EnvironmentDraws drawn;
      const bool has_drawn = next_lit < lit && lit_index[next_lit] == k;
      if (has_drawn) {
        for (const Environment::Component c : {Environment::kBright, Environment::kRest})
          drawn.component[c] = environment_drawn[c][next_lit];
        ++next_lit;
      }
      ShadeHit(setup, directions[k], setup.camera.pixel_angle(), SamplePoints(setup.seed, p.pixel, p.sample),
               found[k] ? &hits[k] : nullptr, &points[done + k], has_drawn ? &drawn : nullptr);
    }
  }
}

void QueryBucket::Clear() {
  wi.clear();
  wo.clear();
  uv.clear();
  weight.clear();
  axis.clear();
  tag.clear();
}

void QueryBucket::Append(const QueryBucket& other) {
  wi.insert(wi.end(), other.wi.begin(), other.wi.end());
  wo.insert(wo.end(), other.wo.begin(), other.wo.end());
  uv.insert(uv.end(), other.uv.begin(), other.uv.end());
  weight.insert(weight.end(), other.weight.begin(), other.weight.end());
  axis.insert(axis.end(), other.axis.begin(), other.axis.end());
  tag.insert(tag.end(), other.tag.begin(), other.tag.end());
}

Rgb AppendQueries(const ShadingPoint& point, const ObjectShading& shading, const std::vector<Evaluator>& evaluators,
                  uint32_t tag, std::vector<QueryBucket>* buckets) {
  const int chosen = EvaluatorFor(point, shading);
  if (chosen < 0) return {};
  const Evaluator& evaluator = evaluators[chosen];
  if (evaluator.table) {  // looked up here: f x weight, no query
    Rgb sum;
    const double wo[3] = {point.wo.x, point.wo.y, point.wo.z};
    for (const LightSample& light : point.lights) {
      if (light.wi.z < 0) continue;  // light through the cloth: the table is of reflection
      const double wi[3] = {light.wi.x, light.wi.y, light.wi.z};
      const std::array<double, 3> f = evaluator.table->Evaluate(wi, wo);
      sum = sum + Rgb{f[0] * light.weight.x, f[1] * light.weight.y, f[2] * light.weight.z};
    }
    return sum;
  }
  QueryBucket& bucket = (*buckets)[chosen];
  const auto push = [&](QueryBucket& b, const Evaluator& e, Vec3 wi, Rgb weight) {
    b.wi.insert(b.wi.end(), {float(wi.x), float(wi.y), float(wi.z)});
    b.wo.insert(b.wo.end(), {float(point.wo.x), float(point.wo.y), float(point.wo.z)});
    if (e.with_uv) b.uv.insert(b.uv.end(), {point.u, point.v});
    if (e.fiber_axis) b.axis.insert(b.axis.end(), {float(point.axis.x), float(point.axis.y), float(point.axis.z)});
    b.weight.insert(b.weight.end(), {float(weight.x), float(weight.y), float(weight.z)});
    b.tag.push_back(tag);
  };
  for (const LightSample& light : point.lights) {
    // Light through the cloth, not modelled (a fiber scatters from the whole sphere).
    if (light.wi.z < 0 && !evaluator.transmission && !point.fiber) continue;
    push(bucket, evaluator, light.wi, light.weight);
  }
  if (point.fiber && shading.ambient_evaluator >= 0 && (point.ambient.x > 0 || point.ambient.y > 0 || point.ambient.z > 0))
    push((*buckets)[shading.ambient_evaluator], evaluators[shading.ambient_evaluator], point.wo, point.ambient);
  if (!evaluator.transmission) return {};
  return SeeThrough(*evaluator.material, point.wo) * point.background;
}

std::unique_ptr<models::EvaluationPlan> PlanOf(const Evaluator& evaluator, const QueryBucket& bucket) {
  return std::make_unique<models::EvaluationPlan>(*evaluator.material, bucket.wi.data(), bucket.wo.data(),
                                                  evaluator.with_uv ? bucket.uv.data() : nullptr, bucket.size(),
                                                  evaluator.fiber_axis ? bucket.axis.data() : nullptr,
                                                  evaluator.quantity);
}

void EvaluateOnHost(const Evaluator& evaluator, const QueryBucket& bucket, std::vector<double>* f) {
  f->assign(3 * bucket.size(), 0.0);
  models::EvaluateNative(*PlanOf(evaluator, bucket), f->data());
}

size_t MaxQueriesPerSample(const RenderSetup& setup) {
  bool material_sampling = false;
  for (const models::DirectionSampler* sampler : setup.object_samplers) material_sampling |= sampler != nullptr;
  // Two environment components, and the material's draws when an object has a sampler.
  return setup.lights.size() + (setup.environment ? 2 + (material_sampling ? kMaterialSamples : 0) : 0) +
         (setup.scene.fibers ? 1 : 0);
}

}  // namespace loomlight::render
