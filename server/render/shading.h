// From pixel samples to shading queries. TraceSample casts a camera ray, samples every light and the
// environment (shadow rays included) and expresses the directions in the hit's shading frame (SPEC.md
// section 1: x = thread 1 = texture u, y = thread 2 = texture v, z = the normal facing the viewer). The
// fidelity chosen per object then decides which kernel path (Evaluator) its light samples go to:
// AppendQueries. Each evaluator's queries are evaluated through the material plan (server/models/
// material_plan.h), which splits a curtain into its reflection and its layer and scales the reflection, as
// Evaluate and Tabulate do. The render and the fidelity pilot share all of it, so they shade identically.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <span>
#include <vector>

#include "server/models/material_plan.h"
#include "server/models/registry.h"
#include "server/render/environment.h"
#include "server/render/sample_points.h"
#include "server/render/scene.h"
#include "server/yarn/visibility.h"

namespace loomlight::render {

class FoldedEnvironment;  // server/render/folded_environment.h

// Shadow rays start this far off the surface (scene units ~1), on the light's side.
constexpr double kRayOffset = 1e-6;

// A shading frame in world space: x = thread 1 = texture u, y = thread 2 = texture v, z = n (SPEC.md section 1).
struct Frame {
  Vec3 x, y, n;
  Vec3 ToLocal(Vec3 w) const { return {Dot(w, x), Dot(w, y), Dot(w, n)}; }
};

// Everything a render needs that does not change while it runs.
struct RenderSetup {
  Scene scene;
  PinholeCamera camera{CameraSpec{{0, 0, 1}, {0, 0, 0}}, 1, 1};
  std::vector<Light> lights;
  std::shared_ptr<const Environment> environment;  // null: no environment (black background)
  std::vector<bool> object_transmits;              // per object: light can pass through its cloth
  // Per object: its material's importance sampler, combined with the environment's by multiple importance
  // sampling; null (or missing): environment light is sampled from the map alone.
  std::vector<const models::DirectionSampler*> object_samplers;
  double texture_scale = 1;                        // pattern repeats per unit
  double texture_rotation_deg = 0;
  uint64_t seed = 0;
  int width = 1, height = 1;
  uint32_t samples_per_pixel = 1;
  // Fiber scenes: constant ambient radiance (Wu and Yuksel Eq. 7's L_amb), times each fiber hit's visibility
  // (one occlusion direction per sample).
  double ambient = 0;
  // Fiber scenes: how light and ambient visibility reach a fiber: rays traced through the fibers, or the
  // yarn's cross-section approximations (scene.fiber_visibility) with other yarns as tubes.
  yarn::ShadowMethod fiber_shadows = yarn::ShadowMethod::kTraced;
  yarn::OcclusionMethod fiber_occlusion = yarn::OcclusionMethod::kTraced;
  // The request left the method to the fidelity chooser (FidelityPlan says which it took).
  bool choose_fiber_shadows = false, choose_fiber_occlusion = false;
  // Objects whose environment light is folded into their material (a `btf` asset; server/render/
  // folded_environment.h): their hits draw no environment or material samples (analytic lights as ever), and
  // the renderer adds FoldedEnvironment::Radiance instead. Null: every object samples the environment.
  std::shared_ptr<const FoldedEnvironment> folded_environment;
  // Fiber scenes: the level of detail the geometry was generated at, for the fidelity report.
  struct FiberDetail {
    std::string chosen, full, reason;
  } fiber_detail;
  // Fiber scenes where Eq. 4 thinned the fibers for AUTO: the same yarn at full detail, which the fidelity
  // chooser's pilot compares the thinned geometry with (FidelityPlan::fiber_full_detail: which one the render
  // keeps). Null otherwise.
  std::shared_ptr<const yarn::FiberScene> full_detail_fibers;
  std::shared_ptr<const yarn::YarnVisibility> full_detail_visibility;
};

struct LightSample {
  Vec3 wi;     // toward the light, shading frame (z < 0: behind the cloth)
  Rgb weight;  // L_o = f(wi, wo) * weight: incident radiance (or irradiance) x |cos theta_i| / pdf
  int light = -1;  // its light's index in RenderSetup::lights; -1: an environment or material sample
};

struct ShadingPoint {
  int object = -1;       // the object hit; -1 when the ray missed
  Rgb background;        // a miss: the environment; a hit on transmitting cloth: the radiance behind it
  Vec3 wo;               // toward the camera, shading frame, z >= 0 (the cloth is two-sided)
  float u = 0, v = 0;    // texture coordinates in pattern repeats, wrapped into [0, 1) (the pattern tiles)
  double footprint = 0;  // world size of the pixel at the hit (its shorter axis)
  std::vector<LightSample> lights;
  // A fiber hit: the frame's x is the fiber's axis made perpendicular to the normal; `axis` is the axis itself
  // in the shading frame (each query's fiber axis), and light samples weigh cos(theta_i) about it (SPEC.md
  // section 5), from the whole sphere. `ambient` is L_amb times the hit's ambient visibility.
  bool fiber = false;
  Vec3 axis;
  Rgb ambient;
  // A hit on an object whose environment light is folded (setup.folded_environment): its surface coordinates
  // and the side seen (back: wo was mirrored), for FoldedEnvironment::Radiance.
  bool environment_folded = false;
  bool back = false;
  double s = 0, t = 0;
};

// The shading frame of a hit on (non-fiber) object `object`, the threads turned by the object's and the request's
// angle; with u and v, its texture coordinates (pattern repeats, wrapped into [0, 1)).
Frame ShadingFrame(const RenderSetup& setup, int object, const Hit& hit, float* u = nullptr, float* v = nullptr);

// Casts the ray through image position (px, py) and samples the lights: point and directional lights, one
// direction from each of the environment's components and four from the hit's material (setup.object_samplers),
// weighed by multiple importance sampling; `points` supplies the sample's random numbers (its pairs 1 and up).
void TraceSample(const RenderSetup& setup, double px, double py, const SamplePoints& points, ShadingPoint* point);
// The same for any ray (unit direction): TraceSample's camera ray, or a BTF capture's parallel rays
// (server/render/btf_capture.h). pixel_angle: the footprint's growth per unit distance (0 for parallel rays).
void TraceRay(const RenderSetup& setup, Vec3 origin, Vec3 direction, double pixel_angle, const SamplePoints& points,
              ShadingPoint* point);

// The pixel sample `sample` of pixel `pixel` (index y * width + x): its position in the pixel and its points
// (Owen-scrambled Sobol), a pure function of (seed, pixel, sample).
void TracePixelSample(const RenderSetup& setup, uint64_t pixel, uint32_t sample, ShadingPoint* point);
// Several pixel samples into points[0, samples.size()): each as TracePixelSample traces it, the camera rays
// cast together (neighbouring pixels' samples make coherent packets).
struct PixelSample {
  uint64_t pixel = 0;
  uint32_t sample = 0;
};
void TracePixelSamples(const RenderSetup& setup, std::span<const PixelSample> samples, ShadingPoint* points);
// A sample's directions from the environment's two components (Environment::Component order), drawn ahead of
// its shading: TracePixelSamples draws a packet's together (Environment::DrawPacket).
struct EnvironmentDraws {
  Environment::Sample component[2];
};
// TraceRay's shading of what the ray found: `hit` (null: a miss) on the ray along unit `direction`. `drawn`: the
// sample's environment directions, drawn from `points` already (null: drawn here).
void ShadeHit(const RenderSetup& setup, Vec3 direction, double pixel_angle, const SamplePoints& points, const Hit* hit,
              ShadingPoint* point, const EnvironmentDraws* drawn = nullptr);

// One kernel path: a prepared material (with a curtain's layer), evaluated with texture coordinates (its BTF)
// or without, with light through the cloth (pairs on opposite sides, and what is seen through it) or without.
// A fiber object's evaluators carry each query's fiber axis; its ambient evaluator computes the ambient factor
// (models::Quantity::kAmbient) toward wo.
// A tabulated BRDF (`table`, the material's: the fidelity ladder's cheapest rung) is looked up on the host as
// the sample is traced: its light samples make no queries.
struct Evaluator {
  const models::PreparedMaterial* material = nullptr;
  bool with_uv = false;
  bool transmission = false;
  bool fiber_axis = false;
  models::Quantity quantity = models::Quantity::kScattering;
  const models::TabulatedBrdf* table = nullptr;
};

// How one object's light samples are evaluated: the index of its evaluator (and, on fibers, of its ambient
// evaluator; -1: none). The fidelity ladder per pixel: a hit whose footprint is smaller than near_footprint
// (its threads span more than the fidelity chooser's threshold of pixels) takes near_evaluator, the BTF,
// instead of `evaluator`, the BRDF (-1: every hit takes `evaluator`).
struct ObjectShading {
  int evaluator = -1;
  int ambient_evaluator = -1;
  int near_evaluator = -1;
  double near_footprint = 0;
};

// The evaluator a hit on an object takes (ObjectShading's rule; -1: none).
inline int EvaluatorFor(const ShadingPoint& point, const ObjectShading& shading) {
  return shading.near_evaluator >= 0 && point.footprint < shading.near_footprint ? shading.near_evaluator
                                                                                  : shading.evaluator;
}

// Queries of one evaluator, structure of arrays; `tag` says whose radiance each query adds to.
struct QueryBucket {
  std::vector<float> wi, wo, uv, weight;  // 3, 3, 2 (with_uv only), 3 per query
  std::vector<float> axis;                // 3 per query (fiber_axis only)
  std::vector<uint32_t> tag;
  size_t size() const { return tag.size(); }
  void Clear();
  void Append(const QueryBucket& other);  // other's queries after these
};

// Appends the queries of a shading point on an object to buckets[evaluator]; returns the radiance that
// needs no query (the background seen straight through transmitting cloth).
Rgb AppendQueries(const ShadingPoint& point, const ObjectShading& shading, const std::vector<Evaluator>& evaluators,
                  uint32_t tag, std::vector<QueryBucket>* buckets);

// The kernel work of one evaluator's bucket (the bucket must outlive it).
std::unique_ptr<models::EvaluationPlan> PlanOf(const Evaluator& evaluator, const QueryBucket& bucket);

// f (3 per query) of one evaluator's bucket on the host (the native build; the fidelity pilot).
void EvaluateOnHost(const Evaluator& evaluator, const QueryBucket& bucket, std::vector<double>* f);

// The most queries one pixel sample can produce: one per light, two for the environment, the material's draws
// (four per hit), one for a fiber's ambient term.
size_t MaxQueriesPerSample(const RenderSetup& setup);

}  // namespace loomlight::render
