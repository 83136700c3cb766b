#include "server/render/shading.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "server/models/material_plan.h"

namespace loomlight::render {
namespace {

constexpr double kDegree = std::numbers::pi / 180;
// Shadow rays start this far off the surface (scene units ~1), on the light's side.
constexpr double kRayOffset = 1e-6;
// Light samples this close to the surface plane carry no light (f is 0 there for every model).
constexpr double kMinCosine = 1e-6;

struct Frame {
  Vec3 x, y, n;
  Vec3 ToLocal(Vec3 w) const { return {Dot(w, x), Dot(w, y), Dot(w, n)}; }
};

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

// Calls add(direction toward the light, distance to it, incident radiance over pdf) for every light and one
// environment sample (rng dimensions 2..4) as seen from `position`.
template <class Add>
void ForEachLight(const RenderSetup& setup, Vec3 position, const CounterRng& rng, Add add) {
  for (const Light& light : setup.lights) {
    if (light.type == Light::Type::kDirectional) {
      add(light.direction, INFINITY, light.rgb);
    } else {
      const Vec3 to_light = light.position - position;
      const double d2 = Dot(to_light, to_light);
      if (d2 < 1e-12) continue;  // a light on the surface itself: no defined direction
      const double d = std::sqrt(d2);
      add((1.0 / d) * to_light, d, (1.0 / d2) * light.rgb);
    }
  }
  if (setup.environment) {
    const Environment::Sample sample = setup.environment->Draw(rng.Uniform(2), rng.Uniform(3), rng.Uniform(4));
    if (sample.radiance_over_pdf.x > 0 || sample.radiance_over_pdf.y > 0 || sample.radiance_over_pdf.z > 0)
      add(sample.direction, INFINITY, sample.radiance_over_pdf);
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

void ShadeFiber(const RenderSetup& setup, const Hit& hit, Vec3 direction, const CounterRng& rng, ShadingPoint* point) {
  const Frame frame{hit.tangent_s, hit.tangent_t, hit.normal};
  point->wo = frame.ToLocal(-direction);
  point->wo.z = std::max(point->wo.z, 0.0);  // the normal faces the ray
  point->axis = frame.ToLocal(hit.fiber_axis);
  point->u = point->v = 0;
  // A core fiber stands for a bundle of fibers (Sec. 3.2), a thick opaque cylinder rather than a line: its side
  // away from a direction is in its own shadow (decided by the normal: Embree misses the near-tangent chords of a
  // ray started on the surface), and its rays start on its surface.
  const bool core = hit.fiber_core;
  const FiberRayStart start = core ? FiberRayStart{hit.position + (1e-4 * hit.fiber_radius) * hit.normal, hit.fiber_axis, 0}
                                   : FiberRayStart{hit.position - hit.fiber_radius * hit.normal, hit.fiber_axis, hit.fiber_radius};
  const auto behind_core = [&](Vec3 w) { return core && Dot(w, hit.normal) <= 0; };
  // The approximations stand for the fibers only (a fiber scene has no other shapes to block light).
  const yarn::YarnVisibility* approximate = setup.scene.fiber_visibility.get();
  const bool slices = approximate && setup.fiber_shadows == yarn::ShadowMethod::kSlices;
  const bool occlusion = approximate && setup.fiber_occlusion != yarn::OcclusionMethod::kTraced;
  const auto to_yarn = [&](Vec3 v) { return yarn::Vec3{v.x, v.y, v.z}; };
  const yarn::CrossSectionPoint in_yarn =
      slices || occlusion ? approximate->Locate(hit.fiber_yarn, to_yarn(start.origin)) : yarn::CrossSectionPoint{};
  ForEachLight(setup, hit.position, rng, [&](Vec3 wi_world, double max_distance, Rgb incident) {
    const Vec3 wi = frame.ToLocal(wi_world);
    const double along = Dot(wi, point->axis);
    const double cos_theta = std::sqrt(std::max(0.0, 1.0 - along * along));  // SPEC.md section 5's cos(theta_i)
    if (cos_theta < kMinCosine || behind_core(wi_world)) return;
    double transmittance = 1;
    if (slices) {
      if (approximate->OtherYarnsBlock(hit.fiber_yarn, to_yarn(start.origin), to_yarn(wi_world), max_distance)) return;
      transmittance = approximate->SelfShadow(in_yarn, to_yarn(wi_world), hit.fiber_radius);
    } else if (setup.scene.Occluded(start.origin, wi_world, max_distance, start.MinDistance(wi_world))) {
      return;
    }
    point->lights.push_back({wi, (cos_theta * transmittance) * incident});
  });
  point->ambient = {};
  if (setup.ambient > 0) {
    // Ambient visibility: one uniformly distributed direction on the sphere per sample (rng dimensions 5, 6),
    // traced through the fibers, or through the other yarns' tubes times the yarn's own occlusion.
    const double z = 1 - 2 * rng.Uniform(5), phi = 2 * std::numbers::pi * rng.Uniform(6);
    const double r = std::sqrt(std::max(0.0, 1 - z * z));
    const Vec3 w{r * std::cos(phi), r * std::sin(phi), z};
    double visibility = 0;
    if (behind_core(w)) {
      // in the core's own shadow
    } else if (occlusion) {
      if (!approximate->OtherYarnsBlock(hit.fiber_yarn, to_yarn(start.origin), to_yarn(w), INFINITY))
        visibility = approximate->Occlusion(in_yarn, setup.fiber_occlusion);
    } else if (!setup.scene.Occluded(start.origin, w, INFINITY, start.MinDistance(w))) {
      visibility = 1;
    }
    point->ambient = (setup.ambient * visibility) * Rgb{1, 1, 1};
  }
}

}  // namespace

void TraceSample(const RenderSetup& setup, double px, double py, const CounterRng& rng, ShadingPoint* point) {
  point->object = -1;
  point->background = {};
  point->lights.clear();
  point->fiber = false;
  point->ambient = {};
  const Vec3 origin = setup.camera.position();
  const Vec3 direction = setup.camera.Direction(px, py);
  Hit hit;
  if (!setup.scene.Intersect(origin, direction, 0.0, INFINITY, &hit)) {
    if (setup.environment) point->background = setup.environment->Radiance(direction);
    return;
  }
  point->object = hit.object;
  point->fiber = hit.fiber;
  point->footprint = hit.distance * setup.camera.pixel_angle();
  if (hit.fiber) return ShadeFiber(setup, hit, direction, rng, point);
  const SceneObject& object = setup.scene.objects[hit.object];
  const double angle = (object.thread_angle_deg + setup.texture_rotation_deg) * kDegree;
  const double c = std::cos(angle), s = std::sin(angle);
  const Frame frame{c * hit.tangent_s + s * hit.tangent_t, -s * hit.tangent_s + c * hit.tangent_t, hit.normal};
  point->u = WrapUnit(setup.texture_scale * (c * hit.s + s * hit.t));
  point->v = WrapUnit(setup.texture_scale * (-s * hit.s + c * hit.t));

  // The cloth is two-sided: seen from behind, both directions are mirrored through the surface (as
  // Evaluate does for a curtain's back), so wo is always in the upper hemisphere.
  Vec3 wo = frame.ToLocal(-direction);
  const double mirror = wo.z < 0 ? -1.0 : 1.0;
  wo.z *= mirror;
  point->wo = wo;

  if (hit.object < static_cast<int>(setup.object_transmits.size()) && setup.object_transmits[hit.object]) {
    Hit behind;  // what the camera sees through the cloth: the environment, or nothing past another object
    if (setup.environment && !setup.scene.Intersect(hit.position + kRayOffset * direction, direction, 0.0, INFINITY, &behind))
      point->background = setup.environment->Radiance(direction);
  }

  ForEachLight(setup, hit.position, rng, [&](Vec3 wi_world, double max_distance, Rgb incident) {
    const double side = Dot(wi_world, hit.normal) >= 0 ? 1.0 : -1.0;
    Vec3 wi = frame.ToLocal(wi_world);
    wi.z *= mirror;
    if (std::fabs(wi.z) < kMinCosine) return;
    if (setup.scene.Occluded(hit.position + (side * kRayOffset) * hit.normal, wi_world, max_distance)) return;
    point->lights.push_back({wi, std::fabs(wi.z) * incident});
  });
}

void TracePixelSample(const RenderSetup& setup, uint64_t pixel, uint32_t sample, ShadingPoint* point) {
  const CounterRng rng(setup.seed, pixel * setup.samples_per_pixel + sample);
  const double x = static_cast<double>(pixel % setup.width), y = static_cast<double>(pixel / setup.width);
  TraceSample(setup, x + rng.Uniform(0), y + rng.Uniform(1), rng, point);
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
  if (shading.evaluator < 0) return {};
  const Evaluator& evaluator = evaluators[shading.evaluator];
  QueryBucket& bucket = (*buckets)[shading.evaluator];
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
  const std::unique_ptr<models::EvaluationPlan> plan = PlanOf(evaluator, bucket);
  std::vector<float> part;
  for (size_t k = 0; k < plan->parts(); ++k) {
    part.assign(3 * plan->size(k), 0.0f);
    if (plan->quantity() == models::Quantity::kAmbient)
      plan->model(k).NativeAmbient(plan->packed(k), plan->wo(k), plan->size(k), part.data());
    else
      plan->model(k).NativeEval(plan->packed(k), plan->wi(k), plan->wo(k), plan->uv(k), plan->size(k), part.data());
    const size_t* slots = plan->slots(k);
    const double* scale = plan->scale(k);
    for (size_t i = 0; i < plan->size(k); ++i) {
      const size_t q = slots ? slots[i] : i;
      for (int c = 0; c < 3; ++c) (*f)[3 * q + c] = (scale ? scale[q] : 1.0) * part[3 * i + c];
    }
  }
}

size_t MaxQueriesPerSample(const RenderSetup& setup) {
  return setup.lights.size() + (setup.environment ? 1 : 0) + (setup.scene.fibers ? 1 : 0);
}

}  // namespace loomlight::render
