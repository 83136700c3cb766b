#include "server/api/render_rpc.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <vector>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/mesh_rpc.h"
#include "server/api/stream_call.h"
#include "server/imaging/image_encode.h"
#include "server/models/material.h"
#include "server/assets/mesh_file.h"
#include "server/assets/mesh_store.h"
#include "server/render/adaptive_sampling.h"
#include "server/render/lighting_presets.h"
#include "server/render/mesh_scene.h"
#include "server/render/renderer.h"
#include "server/render/scene_registry.h"
#include "server/models/quote.h"
#include "server/api/yarn_rpc.h"
#include "server/yarn/fiber_scene.h"
#include "server/yarn/visibility.h"

namespace loomlight::api {
namespace {

constexpr const char* kRpc = "Render";
// A chunk is a quarter of one Evaluate call (render/renderer.h).
static_assert(render::kRenderChunkQueries == kMaxQueriesPerCall / 4);

using Clock = batching::Clock;
using render::Vec3;


std::string Indexed(const std::string& field, int i) { return field + "[" + std::to_string(i) + "]"; }

// Exactly three finite values within +-limit (or `optional` and empty). Returns "" or "field: reason".
std::string ValidateTriple(const google::protobuf::RepeatedField<double>& v, const std::string& field, double limit,
                           bool optional = false) {
  if (optional && v.empty()) return "";
  if (v.size() != 3) return field + ": needs 3 values (x, y, z), got " + std::to_string(v.size());
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(v[i]) || std::fabs(v[i]) > limit)
      return Indexed(field, i) + ": " + std::to_string(v[i]) + " is not finite within +-" + std::to_string(limit);
  return "";
}

Vec3 ToVec(const google::protobuf::RepeatedField<double>& v) { return {v[0], v[1], v[2]}; }

std::string ValidateLight(const v1::RenderLight& light, const std::string& field) {
  if (!v1::RenderLight::Type_IsValid(light.type())) return field + ".type: unknown value " + std::to_string(light.type());
  if (std::string e = ValidateTriple(light.rgb(), field + ".rgb", kMaxLightValue); !e.empty()) return e;
  for (int c = 0; c < 3; ++c)
    if (light.rgb(c) < 0) return Indexed(field + ".rgb", c) + ": must be >= 0";
  const bool rect = light.type() == v1::RenderLight::TYPE_RECT;
  if (!rect && !light.size().empty()) return field + ".size: only for TYPE_RECT";
  if (!rect && !light.up().empty()) return field + ".up: only for TYPE_RECT";
  if (light.type() != v1::RenderLight::TYPE_POINT) {  // directional: toward the light; rect: the way it faces
    if (std::string e = ValidateTriple(light.direction(), field + ".direction", kMaxSceneCoordinate); !e.empty()) return e;
    if (render::Length(ToVec(light.direction())) < 1e-9) return field + ".direction: must not be zero";
  }
  if (light.type() != v1::RenderLight::TYPE_DIRECTIONAL)
    if (std::string e = ValidateTriple(light.position(), field + ".position", kMaxSceneCoordinate); !e.empty()) return e;
  if (!rect) return "";
  if (light.size_size() != 2) return field + ".size: needs 2 values (width, height), got " + std::to_string(light.size_size());
  for (int i = 0; i < 2; ++i)
    if (!(std::isfinite(light.size(i)) && light.size(i) > 0 && light.size(i) <= kMaxSceneCoordinate))
      return Indexed(field + ".size", i) + ": " + std::to_string(light.size(i)) + " is not finite in (0, " +
             std::to_string(int(kMaxSceneCoordinate)) + "]";
  if (std::string e = ValidateTriple(light.up(), field + ".up", kMaxSceneCoordinate, true); !e.empty()) return e;
  if (!light.up().empty() && render::Length(render::Cross(render::Normalize(ToVec(light.up())),
                                                          render::Normalize(ToVec(light.direction())))) < 1e-6)
    return field + ".up: must not be zero or parallel to the direction";
  return "";
}

// A validated light as the renderer takes it.
render::Light LightOf(const v1::RenderLight& light) {
  render::Light l;
  l.rgb = ToVec(light.rgb());
  if (light.type() == v1::RenderLight::TYPE_POINT) {
    l.type = render::Light::Type::kPoint;
    l.position = ToVec(light.position());
  } else if (light.type() == v1::RenderLight::TYPE_RECT) {
    l = render::RectLight(ToVec(light.position()), ToVec(light.direction()), light.size(0), light.size(1),
                          light.up().empty() ? Vec3{} : ToVec(light.up()), l.rgb);
  } else {
    l.direction = render::Normalize(ToVec(light.direction()));
  }
  return l;
}

std::string ValidateCamera(const v1::RenderCamera& camera) {
  if (std::string e = ValidateTriple(camera.position(), "camera.position", kMaxSceneCoordinate); !e.empty()) return e;
  if (std::string e = ValidateTriple(camera.look_at(), "camera.look_at", kMaxSceneCoordinate); !e.empty()) return e;
  if (std::string e = ValidateTriple(camera.up(), "camera.up", kMaxSceneCoordinate, true); !e.empty()) return e;
  const Vec3 forward = ToVec(camera.look_at()) - ToVec(camera.position());
  if (render::Length(forward) < 1e-6) return "camera.look_at: must differ from camera.position";
  const Vec3 up = camera.up().empty() ? Vec3{0, 1, 0} : ToVec(camera.up());
  if (render::Length(render::Cross(render::Normalize(forward), render::Normalize(up))) < 1e-6)
    return "camera.up: must not be zero or parallel to the view direction";
  if (camera.fov_deg() != 0 && !(camera.fov_deg() >= kMinFovDeg && camera.fov_deg() <= kMaxFovDeg))
    return "camera.fov_deg: " + std::to_string(camera.fov_deg()) + " is outside " + std::to_string(int(kMinFovDeg)) +
           ".." + std::to_string(int(kMaxFovDeg)) + " degrees (0 = the scene's default)";
  return "";
}

uint32_t SamplesPerPixel(const v1::RenderRequest& r) {
  return r.samples_per_pixel() > 0 ? r.samples_per_pixel() : kDefaultRenderSamplesPerPixel;
}

// The registered scene a validated request names (scene_name, else scene) at its scene_params.
render::ResolvedScene ResolvedSceneOf(const v1::RenderRequest& r) {
  render::ResolvedScene scene;
  render::ResolveScene(r, render::SceneRegistry::Global(), &scene);
  return scene;
}

// What a mesh needs: texture coordinates, which place a spatially varying material's pattern on its UV layout.
constexpr render::SceneNeeds kMeshNeeds{.uv = true};

// What the request's scene needs (nothing for a scene the registry does not know: validation refuses it).
render::SceneNeeds NeedsOf(const v1::RenderRequest& r) {
  if (r.has_mesh()) return kMeshNeeds;
  const render::ResolvedScene scene = ResolvedSceneOf(r);
  return scene.spec ? scene.spec->needs : render::SceneNeeds{};
}

// The scene units per UV unit of a mesh's texture coordinates (RenderRequest.texture_scale_unit).
double UvLength(const v1::RenderRequest& r, const assets::TriangleMesh& mesh) {
  return r.texture_scale_unit() == v1::TEXTURE_SCALE_UNIT_PER_METRE && mesh.metres_per_uv > 0 ? mesh.metres_per_uv
                                                                                              : 1.0;
}

imaging::Background BackgroundOf(const v1::RenderRequest& r) {
  return r.background() == v1::BACKGROUND_WHITE         ? imaging::Background::kWhite
         : r.background() == v1::BACKGROUND_TRANSPARENT ? imaging::Background::kTransparent
                                                        : imaging::Background::kScene;
}

imaging::ImageFormat FormatOf(const v1::RenderRequest& r) {
  switch (r.format()) {
    case v1::RENDER_FORMAT_EXR: return imaging::ImageFormat::kExr;
    case v1::RENDER_FORMAT_JPEG: return imaging::ImageFormat::kJpeg;
    case v1::RENDER_FORMAT_WEBP: return imaging::ImageFormat::kWebp;
    default: return imaging::ImageFormat::kPng;
  }
}

uint32_t ViewsOf(const v1::RenderRequest& r) { return std::max<uint32_t>(1, r.views()); }

// The box a knit's or the curves' yarns fill, for framing: the curves' control points (a B-spline stays in
// their hull), or a knit of at most 4 x 4 stitches built and stretched by the stitches left out (a knit is
// periodic, and the small one keeps this cheap at any size), widened by the yarn's radius. False for other
// layouts.
bool LayoutBox(const YarnJob& job, Vec3* lower, Vec3* upper) {
  const auto widen = [&](yarn::Vec3 lo, yarn::Vec3 hi, double by) {
    *lower = {std::min(lower->x, lo.x - by), std::min(lower->y, lo.y - by), std::min(lower->z, lo.z - by)};
    *upper = {std::max(upper->x, hi.x + by), std::max(upper->y, hi.y + by), std::max(upper->z, hi.z + by)};
  };
  *lower = Vec3{INFINITY, INFINITY, INFINITY};
  *upper = -1.0 * *lower;
  if (job.kind == yarn::YarnLayoutKind::kCurves) {
    for (const yarn::CurveYarn& c : job.curves)
      for (const yarn::Vec3& p : c.points) widen(p, p, c.params.yarn_radius);
  } else if (job.kind == yarn::YarnLayoutKind::kKnit) {
    yarn::KnitParams small = job.knit;
    small.wales = std::min(small.wales, 4);
    small.courses = std::min(small.courses, 4);
    yarn::KnitLayout knit;
    if (!yarn::BuildKnit(small, &knit).empty()) return false;
    const yarn::Vec3 more{(job.knit.wales - small.wales) * knit.wale_spacing,
                          (job.knit.courses - small.courses) * knit.course_spacing, 0};
    widen(knit.lower, knit.upper + more, 0);  // KnitLayout's box is widened already
  } else {
    return false;
  }
  return std::isfinite(lower->x) && std::isfinite(upper->x);
}

// The request's scene (a fiber scene's fibers are generated and built separately). A knit's or curves' scene,
// its camera not given, sees their box whole: the scene's default camera moved along its line of sight to look at
// the box's centre from the nearest distance at which every corner of the box lies in the frame, with a 6%
// margin, at the scene's default field of view (so a narrower fov_deg parameter closes in on the centre).
render::Scene SceneOf(const v1::RenderRequest& r, const YarnJob* fibers = nullptr) {
  const render::ResolvedScene resolved = ResolvedSceneOf(r);
  render::Scene scene = resolved.Build();
  Vec3 lower, upper;
  if (r.has_camera() || !fibers || !LayoutBox(*fibers, &lower, &upper)) return scene;
  const double fov = resolved.spec->build(models::DefaultValues(resolved.spec->params)).default_camera.fov_deg;
  const double tan_v = std::tan(0.5 * fov * std::numbers::pi / 180) / 1.06;
  const double tan_h = tan_v * double(std::max(r.width(), 1u)) / double(std::max(r.height(), 1u));
  render::CameraSpec& camera = scene.default_camera;
  const Vec3 forward = render::Normalize(camera.look_at - camera.position);
  const Vec3 right = render::Normalize(render::Cross(forward, camera.up)), up = render::Cross(right, forward);
  camera.look_at = 0.5 * (lower + upper);
  // A corner q from the centre is seen at depth d + q.forward, and is in the frame while |q.right| and |q.up| are
  // within tan_h and tan_v times that.
  double distance = 0;
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 q = Vec3{corner & 1 ? upper.x : lower.x, corner & 2 ? upper.y : lower.y,
                        corner & 4 ? upper.z : lower.z} - camera.look_at;
    distance = std::max({distance, std::fabs(render::Dot(q, right)) / tan_h - render::Dot(q, forward),
                         std::fabs(render::Dot(q, up)) / tan_v - render::Dot(q, forward)});
  }
  camera.position = camera.look_at - distance * forward;
  return scene;
}

// The camera a request asks for, or its scene's.
render::CameraSpec CameraOf(const v1::RenderRequest& r, const render::Scene& scene) {
  render::CameraSpec camera = scene.default_camera;
  if (r.has_camera()) {
    camera.position = ToVec(r.camera().position());
    camera.look_at = ToVec(r.camera().look_at());
    camera.up = r.camera().up().empty() ? Vec3{0, 1, 0} : ToVec(r.camera().up());
    if (r.camera().fov_deg() > 0) camera.fov_deg = r.camera().fov_deg();
  }
  return camera;
}

// yarn_curves' curves when the request gives none: one yarn arching over another across it (cubic B-splines
// about 1 long; at the crossing, the middle of each, a curve is at half its middle control point's height, so the
// centres pass 0.16 apart: cotton1's plies, 0.045 from their centre at most, stay clear).
v1::CurveYarnLayout DefaultCurves() {
  v1::CurveYarnLayout curves;
  const auto add = [&](std::initializer_list<double> points) {
    v1::YarnCentreCurve* c = curves.add_yarns();
    c->mutable_points()->Add(points.begin(), points.end());
    c->set_bspline(true);
  };
  add({-0.5, 0, -0.04, -0.25, 0, 0.0, 0, 0, 0.16, 0.25, 0, 0.0, 0.5, 0, -0.04});
  add({0, -0.5, 0.04, 0, -0.25, 0.0, 0, 0, -0.16, 0, 0.25, 0.0, 0, 0.5, 0.04});
  return curves;
}

// A fiber scene's yarn: the request's yarn and layout (defaults: the woven patch's cotton_twill, 2 x 2 repeats;
// the knit's jersey, 8 x 8; DefaultCurves), at the detail it asks for. Validation only (cheap); `detail` is
// filled in by ChooseFiberDetail.
std::string FiberJobOf(const models::Registry& registry, const v1::RenderRequest& r, YarnJob* job) {
  const render::SceneNeeds needs = NeedsOf(r);
  v1::WovenYarnLayout woven = r.woven();
  if (needs.woven) {
    if (!woven.has_weave()) woven.mutable_weave()->set_preset("cotton_twill");
    if (woven.repeats_u() == 0) woven.set_repeats_u(2);
    if (woven.repeats_v() == 0) woven.set_repeats_v(2);
  }
  const v1::CurveYarnLayout default_curves = needs.curves && !r.has_curves() ? DefaultCurves() : v1::CurveYarnLayout();
  job->limits.max_fibers = static_cast<int64_t>(kMaxRenderFibers);
  job->limits.max_control_points = static_cast<int64_t>(kMaxRenderFiberPoints);
  YarnLayoutRequest layout;
  if (needs.woven) layout.woven = &woven;
  if (needs.curves) layout.curves = r.has_curves() ? &r.curves() : &default_curves;
  if (needs.knit) layout.knit = &r.knit();  // unset: 8 x 8 jersey (0 = 8 stitches)
  return YarnJobOf(registry, r.yarn(), layout, job);
}

// Eq. 4's level of detail for a fiber scene: from the pixel footprint at the camera's look-at point (AUTO, LOD),
// or as the request says. Sets job->detail and the fidelity report's entry; *check says whether the choice is
// AUTO's thinning, which the fidelity chooser compares with full detail before the render keeps it.
void ChooseFiberDetail(const v1::RenderRequest& r, YarnJob* job, render::RenderSetup::FiberDetail* report,
                       bool* check) {
  *check = false;
  const render::Scene scene = SceneOf(r, job);
  const render::CameraSpec camera = CameraOf(r, scene);
  const render::PinholeCamera pinhole(camera, static_cast<int>(r.height()), static_cast<int>(r.height()));
  const double footprint = pinhole.pixel_angle() * render::Length(camera.look_at - camera.position);
  const yarn::YarnParams& p = job->params;
  const double ply_width = yarn::PlyWidth(p);
  yarn::DetailOptions& d = job->detail;
  d.threads = 2;
  report->full = "full";
  const v1::FiberDetail asked = r.force_full_fidelity() ? v1::FIBER_DETAIL_FULL : r.fiber_detail();
  char text[256];
  if (asked == v1::FIBER_DETAIL_FULL) {
    d.footprint = 0;
    report->chosen = "full";
    report->reason = r.force_full_fidelity() ? "force_full_fidelity" : "fiber_detail FULL";
  } else if (asked == v1::FIBER_DETAIL_CORES) {
    d.footprint = ply_width;
    report->chosen = "cores";
    report->reason = "fiber_detail CORES: one core fiber per ply";
  } else {
    d.footprint = footprint;
    const yarn::LodChoice lod = yarn::ChooseLod(p.fiber_width, ply_width, footprint, p.fibers_per_ply,
                                                d.core_radius, d.points_per_twist);
    report->chosen = lod.lambda >= 1 ? "full" : lod.lambda <= 0 ? "cores" : "lod";
    *check = asked == v1::FIBER_DETAIL_AUTO && lod.lambda < 1;
    std::snprintf(text, sizeof text,
                  "%sa pixel covers %.3g at the look-at point, fibers are %.3g wide (%.3g pixels), plies %.3g: "
                  "Eq. 4 lambda %.3g keeps %d of %d fibers per ply",
                  asked == v1::FIBER_DETAIL_LOD ? "fiber_detail LOD: " : "", footprint, p.fiber_width,
                  p.fiber_width / footprint, ply_width, lod.lambda, lod.fibers, p.fibers_per_ply);
    report->reason = text;
  }
}

// The renderer's inputs from a validated request: its scene (a registered scene's, fibers as generated, or a
// mesh's), cameras, lights, environment (`map`: the loaded one; null: the built-in sky), texture and sampling;
// the materials are the caller's.
render::RenderInputs RenderInputsOf(const v1::RenderRequest& r, render::Scene scene,
                                    std::shared_ptr<const render::Environment> map) {
  render::RenderInputs in;
  render::RenderSetup& s = in.setup;
  s.scene = std::move(scene);
  s.fiber_shadows = r.fiber_shadows() == v1::FIBER_SHADOWS_SLICES ? yarn::ShadowMethod::kSlices : yarn::ShadowMethod::kTraced;
  s.fiber_occlusion = r.fiber_occlusion() == v1::FIBER_OCCLUSION_TEXTURE    ? yarn::OcclusionMethod::kTexture
                      : r.fiber_occlusion() == v1::FIBER_OCCLUSION_DISTANCE ? yarn::OcclusionMethod::kDistance
                                                                            : yarn::OcclusionMethod::kTraced;
  s.choose_fiber_shadows = r.fiber_shadows() == v1::FIBER_SHADOWS_AUTO;
  s.choose_fiber_occlusion = r.fiber_occlusion() == v1::FIBER_OCCLUSION_AUTO;
  const render::CameraSpec camera = CameraOf(r, s.scene);
  for (const render::CameraSpec& view : render::TurntableCameras(camera, int(ViewsOf(r))))
    in.views.push_back({view, static_cast<int>(r.width()), static_cast<int>(r.height()), {}, nullptr});
  in.product_only = r.background() != v1::BACKGROUND_ENVIRONMENT;
  s.samples_per_pixel = SamplesPerPixel(r);
  s.seed = r.seed();
  s.texture_scale = r.texture_scale() > 0 ? r.texture_scale() : s.scene.default_texture_scale;
  s.texture_rotation_deg = r.texture_rotation_deg();
  for (const v1::RenderLight& light : r.lights()) s.lights.push_back(LightOf(light));
  // A mesh without lighting is lit by the studio preset, as a product is photographed.
  const bool mesh_default = r.has_mesh() && r.lighting().empty() && r.lights().empty() && !r.has_environment();
  const render::LightingPreset* preset =
      mesh_default ? render::FindLightingPreset(render::kDefaultMeshLighting)
      : r.lighting().empty() ? nullptr : render::FindLightingPreset(r.lighting());
  const bool default_lighting = r.lights().empty() && !r.has_environment() && !preset;
  if (default_lighting) s.lights = s.scene.default_lights;
  if (preset) {  // placed around the subject as the first view sees it; the request's lights join them
    render::Subject subject;
    render::SubjectSphere(s.scene, camera, &subject.centre, &subject.radius);
    std::vector<render::Light> placed = render::PlaceLights(*preset, subject.centre, subject.radius, camera);
    s.lights.insert(s.lights.begin(), placed.begin(), placed.end());
  }
  s.ambient = r.ambient() > 0 ? r.ambient() : default_lighting ? s.scene.default_ambient : 0.0;
  if ((default_lighting && s.scene.default_environment) || r.has_environment()) {
    // A copy with its own transform; the decoded map itself is shared (a cached map is not copied).
    auto environment = std::make_shared<render::Environment>(map ? *map : render::Environment::Builtin());
    const double intensity = default_lighting ? s.scene.default_environment_intensity
                             : r.environment().intensity() > 0 ? r.environment().intensity() : 1.0;
    environment->SetTransform(intensity, r.has_environment() ? r.environment().rotation_deg() : 0.0);
    s.environment = std::move(environment);
  } else if (preset && preset->environment_intensity > 0) {  // the preset's studio map (a request's map wins)
    auto environment = std::make_shared<render::Environment>(render::Environment::Studio());
    environment->SetTransform(preset->environment_intensity, 0.0);
    s.environment = std::move(environment);
  }
  // A turntable turns the lights and the environment with its camera: the product turns, the studio stays.
  const int views = int(in.views.size());
  for (int k = 1; k < views; ++k) {
    const double angle = render::TurntableAngle(k, views);
    render::RenderView& view = in.views[k];
    view.lights.emplace();
    for (const render::Light& light : s.lights) view.lights->push_back(render::TurnLight(light, camera, angle));
    if (s.environment) {
      auto turned = std::make_shared<render::Environment>(*s.environment);
      turned->Turn(angle * 180 / std::numbers::pi);  // about +y, as a map turns (RenderEnvironment.rotation_deg)
      view.environment = std::move(turned);
    }
  }
  in.error_target = r.error_target() > 0 ? r.error_target() : render::kDefaultErrorTarget;
  in.force_full_fidelity = r.force_full_fidelity();
  in.sampling = r.sampling() == v1::SAMPLING_ADAPTIVE  ? render::Sampling::kAdaptive
                : r.sampling() == v1::SAMPLING_UNIFORM ? render::Sampling::kUniform
                                                       : render::Sampling::kAuto;
  in.btf_environment = r.btf_environment() == v1::BTF_ENVIRONMENT_FOLDED ? render::BtfEnvironmentChoice::kFolded
                       : r.btf_environment() == v1::BTF_ENVIRONMENT_AUTO ? render::BtfEnvironmentChoice::kAuto
                                                                          : render::BtfEnvironmentChoice::kSampled;
  return in;
}

// One Render call in flight, on the host worker (server/api/stream_call.h): it loads what the renderer needs
// (the environment map, the fiber geometry, the material), runs the renderer (server/render/renderer.h) there,
// its chunks going to the batcher through a BatcherEvaluator (completions post back to the worker), and
// streams progress and the encoded image. The call is finished only when no batcher job and no write is
// outstanding.
class RenderCall final : public WorkerStreamCall<v1::RenderUpdate> {
 public:
  RenderCall(const RenderDeps& deps, grpc::CallbackServerContext* context, const v1::RenderRequest& request,
             std::shared_ptr<const models::PreparedMaterial> material, FiberJobs fiber_jobs,
             render::RenderSetup::FiberDetail fiber_detail, Admission admission, Clock::time_point received)
      : WorkerStreamCall(deps, context, kRpc, received, std::move(admission)), request_(request),
        material_(std::move(material)), fp64_(request.precision() == v1::PRECISION_FP64),
        fiber_job_(std::move(fiber_jobs.chosen)), full_fiber_job_(std::move(fiber_jobs.full)),
        fiber_detail_(std::move(fiber_detail)),
        evaluator_({deps_.batcher, deps_.metrics, fp64_, deadline_, context_, client_,
                    [this](std::function<void()> task) { Post(std::move(task)); }, [this] { Pump(); }, true}) {
    const v1::RenderEnvironment& env = request_.environment();
    const bool map = !env.name().empty() || !env.data().empty();
    const bool mesh = request_.has_mesh();
    if (map || fiber_job_ || mesh) {
      // Reading and decoding a map runs on the asset loader, generating fibers, parsing a mesh and their BVHs on
      // the geometry worker, never on the host worker every streaming call shares; the call cannot finish
      // meanwhile (Pump waits for loading_ to clear).
      loading_ = true;
      (fiber_job_ || mesh ? deps_.geometry : deps_.loader)->Post([this, map, mesh] {
        grpc::Status status = map ? LoadEnvironment() : grpc::Status::OK;
        if (status.ok() && fiber_job_) status = BuildFibers();
        if (status.ok() && mesh) status = LoadMesh();
        Post([this, status] {
          loading_ = false;
          if (status.ok()) SetUp();
          else if (status_.ok()) status_ = status;
          Pump();
        });
      }, client_);
      return;
    }
    Post([this] {
      SetUp();
      Pump();
    });
  }

 private:
  // On the asset loader: the request's map (by name or from its bytes) into environment_, within the call's
  // deadline, while the client is there, and within the memory budget.
  grpc::Status LoadEnvironment() {
    const auto stop = ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); });
    bool refused = false;
    const auto admit = [this, &refused](size_t bytes) {
      refused = !admission_.bytes.Grow(bytes);
      return !refused;
    };
    const v1::RenderEnvironment& env = request_.environment();
    std::string error, field;
    if (!env.name().empty()) {
      field = "environment.name";
      error = deps_.environments->Get(env.name(), stop, admit, &environment_);
    } else {
      field = "environment.data";
      auto decoded = std::make_shared<render::Environment>();
      error = render::Environment::Decode(env.data(), stop, admit, decoded.get());
      environment_ = std::move(decoded);
    }
    if (error.empty()) return grpc::Status::OK;
    if (grpc::Status stop = StopStatus(context_, deadline_); !stop.ok()) return stop;
    if (refused) return {grpc::StatusCode::RESOURCE_EXHAUSTED, field + ": " + error};
    return Invalid(field + ": " + error);
  }

  // On the geometry worker: the fiber scene's yarn and its Embree BVH, within the call's deadline, while the
  // client is there, and within the memory budget (the BVH's bytes, estimated before it is built, are
  // admitted first and bound the build).
  grpc::Status BuildFibers() {
    const auto stop = ReportingProgress([this] { return StopStatus(context_, deadline_); });
    const auto grow = [this](size_t bytes) { return admission_.bytes.Grow(bytes); };
    grpc::Status s = BuildFiberScene(fiber_job_.get(), stop, grow, &fibers_, &fiber_visibility_, deps_.fiber_scenes);
    if (s.ok() && full_fiber_job_)  // AUTO's thinning is checked against full detail (both kept in the cache)
      s = BuildFiberScene(full_fiber_job_.get(), stop, grow, &full_fibers_, &full_fiber_visibility_, deps_.fiber_scenes);
    return s;
  }

  // On the geometry worker: the request's mesh (sent with it, or stored by name) and its Embree BVH, within the
  // call's deadline, while the client is there, and within the memory budget: a sent file's parse is admitted at
  // kMeshParseBytesPerFileByte before it starts, the BVH at kMeshBvhBytesPerTriangle before it is built (and
  // bounded by it).
  grpc::Status LoadMesh() {
    const auto stop = ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); });
    const auto stopped_or = [this](grpc::Status status) {
      grpc::Status s = StopStatus(context_, deadline_);
      return s.ok() ? status : s;
    };
    std::shared_ptr<const assets::TriangleMesh> mesh;
    if (grpc::Status s = LoadMeshSource(deps_, request_.mesh(), stop, &admission_, &mesh); !s.ok())
      return stopped_or(s);
    const uint64_t bvh_bytes = kMeshBvhBytesPerTriangle * mesh->triangles.size() + (uint64_t{1} << 20);
    if (!admission_.bytes.Grow(size_t(bvh_bytes)))
      return {grpc::StatusCode::RESOURCE_EXHAUSTED,
              "mesh: its BVH needs up to " + std::to_string(bvh_bytes) + " bytes, over this client's share of the memory budget"};
    if (std::string e = render::MeshGeometry::Build(std::move(mesh), bvh_bytes, stop, &mesh_); !e.empty())
      return stopped_or({grpc::StatusCode::RESOURCE_EXHAUSTED, "mesh: cannot build its BVH: " + e});
    return grpc::Status::OK;
  }

  // Which material each of the mesh's materials wears (RenderRequest.materials, else `material`), packed, into
  // in->object_materials; a spatially varying one needs the mesh's texture coordinates.
  grpc::Status BindMeshMaterials(render::RenderInputs* in) {
    const v1::RenderRequest& r = request_;
    const assets::TriangleMesh& mesh = in->setup.scene.mesh->mesh();
    for (int i = 0; i < r.materials_size(); ++i) {
      const std::string& name = r.materials(i).mesh_material();
      if (std::find(mesh.material_names.begin(), mesh.material_names.end(), name) == mesh.material_names.end()) {
        std::string names;
        for (const std::string& n : mesh.material_names) names += (names.empty() ? "" : ", ") + models::Quote(n);
        return Invalid(Indexed("materials", i) + ".mesh_material: the mesh has no material " + models::Quote(name) +
                       " (it has " + names + ")");
      }
    }
    in->object_materials.resize(mesh.material_names.size());
    for (size_t o = 0; o < mesh.material_names.size(); ++o) {
      const std::string& name = mesh.material_names[o];
      int bound = -1;
      for (int i = 0; i < r.materials_size() && bound < 0; ++i)
        if (r.materials(i).mesh_material() == name) bound = i;
      const v1::Material& material = bound >= 0 ? r.materials(bound).material() : r.material();
      if (bound < 0 && !r.has_material())
        return Invalid("material: unset, and the mesh's material " + models::Quote(name) +
                       " is not named in `materials`: give `material` for the rest");
      render::RenderInputs::ObjectMaterial& slot = in->object_materials[o];
      if (grpc::Status s = PrepareMaterial(deps_, material, &slot.material); !s.ok())
        return bound < 0 ? s : Invalid(Indexed("materials", bound) + ".material: " + s.error_message());
      slot.variants = std::make_unique<render::CachedVariants>(material, *deps_.registry, *deps_.materials);
      if (slot.material->model->spatially_varying() && mesh.uvs.empty())
        return Invalid("mesh: it has no texture coordinates, which the " + slot.material->model->name() +
                       " material of its material " + models::Quote(name) + " needs to place its pattern");
    }
    return grpc::Status::OK;
  }

  // The renderer, given the request's inputs, plans; its builds (a fold, material samplers) run on the asset
  // loader (not on the host worker every streaming call shares), then it renders. On failure status_ says why.
  void SetUp() {
    const v1::RenderRequest& r = request_;
    render::RenderInputs in = RenderInputsOf(
        r,
        mesh_ ? render::MeshScene(mesh_, UvLength(r, mesh_->mesh()), int(r.width()), int(r.height()))
              : SceneOf(r, fiber_job_.get()),
        std::move(environment_));
    if ((mesh_ || r.materials_size() > 0) && !(status_ = BindMeshMaterials(&in)).ok()) return;
    in.setup.scene.fibers = std::move(fibers_);
    in.setup.scene.fiber_visibility = std::move(fiber_visibility_);
    // Held only by the renderer from here: it lets go of the full-detail check's geometry once planned.
    in.setup.full_detail_fibers = std::move(full_fibers_);
    in.setup.full_detail_visibility = std::move(full_fiber_visibility_);
    // A mesh whose every material is bound may leave `material` unset: the first binding's stands for it.
    const v1::Material& main = !r.has_material() && r.materials_size() > 0 ? r.materials(0).material() : r.material();
    if (!material_ && !(status_ = PrepareMaterial(deps_, main, &material_)).ok()) return;
    if (fiber_job_) {
      in.setup.fiber_detail = fiber_detail_;
      in.setup.fiber_detail.reason +=
          "; " + std::to_string(in.setup.scene.fibers->stats().curves) + " fiber curves";
    }
    in.material = material_;
    in.variants = std::make_unique<render::CachedVariants>(main, *deps_.registry, *deps_.materials);
    in.materials = deps_.materials;
    in.folds = deps_.folds;
    renderer_ = std::make_unique<render::Renderer>(
        std::move(in), &evaluator_, [this] { return FromGrpc(StopStatus(context_, deadline_, stream_broken_)); },
        [this] { Pump(); });
    if (render::Status s = renderer_->Plan(); !s.ok()) {
      status_ = ToGrpc(s);
      return;
    }
    if (!renderer_->NeedsBuild()) return Start();
    loading_ = true;
    deps_.loader->Post([this] {
      const auto stop = ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); });
      const auto admit = [this](uint64_t bytes) { return admission_.bytes.Grow(size_t(bytes)); };
      grpc::Status status = ToGrpc(renderer_->Build(stop, admit));
      if (!status.ok())
        if (grpc::Status stopped = StopStatus(context_, deadline_); !stopped.ok()) status = stopped;
      Post([this, status] {
        loading_ = false;
        if (!status.ok()) {
          if (status_.ok()) status_ = status;
        } else {
          Start();
        }
        Pump();
      });
    }, client_);
  }

  void Start() {
    setup_seconds_ = SecondsSince(received_);
    renderer_->Start();
  }

  // The one step of the state machine (as Tabulate's): notice a stop, keep one write in flight while there is
  // news, encode the image once rendered, finish when nothing is outstanding.
  void Pump() override {
    if (finished_ || loading_) return;  // a load in flight still refers to this call
    NoticeStop();
    if (status_.ok() && renderer_ && !renderer_->status().ok()) status_ = ToGrpc(renderer_->status());
    if (status_.ok() && renderer_ && renderer_->done() && !complete_) Encode();
    if (!status_.ok()) {
      if (!(renderer_ && renderer_->InFlight()) && !write_in_flight_) FinishCall(status_);
      return;
    }
    if (write_in_flight_ || !renderer_) return;
    if (complete_ && !final_sent_) return WriteUpdate(true);
    if (final_sent_) return FinishCall(grpc::Status::OK);
    if (!sent_first_ || renderer_->samples_done() > samples_sent_) WriteUpdate(false);
  }

  // Every view encoded; a turntable's exposure is its first view's, so its views match.
  void Encode() {
    const std::vector<render::RenderedImage>& images = renderer_->images();
    const render::RenderedImage& rendered = images.front();
    double exposure = request_.exposure();
    size_t total_bytes = 0;
    for (size_t k = 0; k < images.size(); ++k) {
      std::string bytes;
      double used = 1;
      if (std::string error = render::EncodeRendered(images[k].image, images[k].coverage.empty() ? nullptr : &images[k].coverage,
                                                     BackgroundOf(request_), FormatOf(request_), exposure, &bytes, &used);
          !error.empty()) {
        status_ = {grpc::StatusCode::INTERNAL, "cannot encode the image: " + error};
        return;
      }
      if (k == 0 && FormatOf(request_) != imaging::ImageFormat::kExr) exposure = used;
      if (k == 0) final_.set_exposure(used);
      total_bytes += (images.size() > 1 ? 2 : 1) * bytes.size();
      if (total_bytes > kMaxRenderReplyBytes) {
        status_ = {grpc::StatusCode::RESOURCE_EXHAUSTED,
                   "views: the encoded images pass " + std::to_string(kMaxRenderReplyBytes) +
                       " bytes, one message's limit: ask for fewer views, fewer pixels or a smaller format"};
        return;
      }
      if (images.size() > 1) {
        v1::RenderedView* view = final_.add_views();
        view->set_image(bytes);
        view->set_fill(images[k].fill);
        for (double m : images[k].mean) view->add_mean(m);
        const render::CameraSpec& camera = renderer_->views()[k].camera;
        v1::RenderCamera* out = view->mutable_camera();
        const auto set = [](google::protobuf::RepeatedField<double>* field, render::Vec3 v) { for (double x : {v.x, v.y, v.z}) field->Add(x); };
        set(out->mutable_position(), camera.position);
        set(out->mutable_look_at(), camera.look_at);
        set(out->mutable_up(), camera.up);
        out->set_fov_deg(camera.fov_deg);
      }
      if (k == 0) final_.set_image(std::move(bytes));
    }
    final_.set_fill(rendered.fill);
    final_.set_format(request_.format());
    final_.set_width(request_.width());
    final_.set_height(request_.height());
    for (double m : rendered.mean) final_.add_mean(m);
    final_.set_adaptive_sampling(rendered.adaptive);
    final_.set_min_samples_per_pixel(rendered.min_samples_per_pixel);
    final_.set_max_samples_per_pixel(rendered.max_samples_per_pixel);
    complete_ = true;
  }

  // The fidelity report; the last message's also says which share of each object's samples each rung took.
  void AddFidelity(v1::RenderUpdate* update, bool last) const {
    update->set_error_target(renderer_->error_target());
    const std::vector<std::vector<render::Renderer::RungShare>> rungs =
        last ? renderer_->RungShares() : std::vector<std::vector<render::Renderer::RungShare>>{};
    const auto add_rung = [](const render::Renderer::RungShare& share, const render::ObjectFidelity* of, v1::RungShare* out) {
      out->set_rung(share.rung);
      out->set_share(share.share);
      // The error estimate of a cheaper rung: its object's "path" choice's (the BTF and fibers are the reference).
      if (of && (share.rung == "BRDF"))
        for (const render::FidelityChoice& c : of->choices)
          if (c.aspect == "path") out->set_estimated_error(c.estimated_error);
    };
    if (last)
      for (const render::Renderer::RungShare& share : renderer_->TotalRungShares()) add_rung(share, nullptr, update->add_rungs());
    for (size_t o = 0; o < renderer_->fidelity().size(); ++o) {
      const render::ObjectFidelity& of = renderer_->fidelity()[o];
      v1::ObjectFidelity* out = update->add_fidelity();
      if (o < rungs.size())
        for (const render::Renderer::RungShare& share : rungs[o]) add_rung(share, &of, out->add_rungs());
      out->set_object(of.object);
      out->set_model(of.model);
      out->set_estimated_error(of.estimated_error);
      out->set_pixels_per_thread(of.pixels_per_thread);
      for (const render::FidelityChoice& c : of.choices) {
        v1::FidelityChoice* choice = out->add_choices();
        choice->set_aspect(c.aspect);
        choice->set_chosen(c.chosen);
        choice->set_full(c.full);
        choice->set_estimated_error(c.estimated_error);
        choice->set_reason(c.reason);
      }
    }
  }

  // One write in flight at a time: progress (the first also with the fidelity), or the final message.
  void WriteUpdate(bool last) {
    if (last) {
      update_ = std::move(final_);
      final_sent_ = true;
    } else {
      update_.Clear();
    }
    if (last || !sent_first_) AddFidelity(&update_, last);
    sent_first_ = true;
    update_.set_samples_done(renderer_->samples_done());
    update_.set_samples_total(renderer_->samples_total());
    samples_sent_ = renderer_->samples_done();
    if (last) {
      update_.set_queries(renderer_->queries());
      update_.set_setup_seconds(setup_seconds_);
      update_.set_kernel_seconds(renderer_->kernel_seconds());
      update_.set_total_seconds(SecondsSince(received_));
    }
    write_in_flight_ = true;
    StartWrite(&update_);
  }

  const v1::RenderRequest request_;
  std::shared_ptr<const models::PreparedMaterial> material_;  // set by SetUp
  const bool fp64_;
  std::unique_ptr<YarnJob> fiber_job_;  // fiber scenes: the yarn to generate (null otherwise)
  std::unique_ptr<YarnJob> full_fiber_job_;  // AUTO's thinning: the same yarn at full detail, to check it against
  render::RenderSetup::FiberDetail fiber_detail_;
  // Loaded for the renderer, and handed to it by SetUp.
  std::shared_ptr<const yarn::FiberScene> fibers_, full_fibers_;
  std::shared_ptr<const yarn::YarnVisibility> fiber_visibility_, full_fiber_visibility_;
  std::shared_ptr<const render::Environment> environment_;  // the loaded map (null: the built-in sky)
  std::shared_ptr<const render::MeshGeometry> mesh_;        // the request's mesh, built (null: none)
  bool loading_ = false;  // the asset loader or geometry worker is loading or building for this call

  BatcherEvaluator evaluator_;
  std::unique_ptr<render::Renderer> renderer_;  // set by SetUp
  uint64_t samples_sent_ = 0;
  double setup_seconds_ = 0;
  v1::RenderUpdate update_;  // the write in flight
  v1::RenderUpdate final_;   // the image and its summary, once encoded
  bool sent_first_ = false, complete_ = false, final_sent_ = false;
};

}  // namespace

render::Status FromGrpc(const grpc::Status& s) {
  using batching::JobStatus;
  switch (s.error_code()) {
    case grpc::StatusCode::OK: return {};
    case grpc::StatusCode::DEADLINE_EXCEEDED: return {JobStatus::kDeadlineExceeded, s.error_message()};
    case grpc::StatusCode::CANCELLED: return {JobStatus::kCancelled, s.error_message()};
    case grpc::StatusCode::UNAVAILABLE: return {JobStatus::kUnavailable, s.error_message()};
    case grpc::StatusCode::RESOURCE_EXHAUSTED: return {JobStatus::kResourceExhausted, s.error_message()};
    default: return {JobStatus::kInternal, s.error_message()};
  }
}

grpc::Status ToGrpc(const render::Status& s) { return ToStatus(batching::JobResult{s.code, s.message}); }

struct BatcherEvaluator::ChunkJobs {
  std::function<void(const render::ShadingOutcome&)> done;
  size_t remaining = 0;
  render::ShadingOutcome outcome;
};

void BatcherEvaluator::Submit(std::vector<render::ShadingWork> work,
                              std::function<void(const render::ShadingOutcome&)> done) {
  auto chunk = std::make_shared<ChunkJobs>();
  chunk->done = std::move(done);
  for (const render::ShadingWork& w : work) chunk->remaining += w.plan->parts();
  if (chunk->remaining == 0) {  // nothing to evaluate (e.g. only background): done at once, in the call's turn
    call_.post([chunk] { chunk->done(chunk->outcome); });
    return;
  }
  for (const render::ShadingWork& w : work) {
    const models::EvaluationPlan* plan = w.plan;
    SubmitPlan(call_.batcher, *plan, w.sink, call_.fp64, batching::Priority::kBulk, call_.deadline, call_.context,
               call_.client, [this, chunk, plan](size_t k, batching::JobResult r) {
                 call_.post([this, chunk, plan, k, r = std::move(r)] { OnJobDone(*chunk, *plan, k, r); });
               });
  }
}

void BatcherEvaluator::OnJobDone(ChunkJobs& chunk, const models::EvaluationPlan& plan, size_t part,
                                 const batching::JobResult& result) {
  if (result.status != batching::JobStatus::kOk) {
    if (chunk.outcome.status.ok()) chunk.outcome.status = {result.status, result.message};
  } else {
    const size_t n = plan.size(part);
    if (result.batch_queries > 0)
      call_.metrics->Evaluated(plan.model(part).name(), call_.fp64, n, result.batch_queries, result.batch_requests,
                               result.queue_seconds, result.kernel_seconds);
    if (call_.count_rendered) call_.metrics->Rendered(n);
    chunk.outcome.queries += n;
    chunk.outcome.kernel_seconds += result.kernel_seconds;
  }
  if (--chunk.remaining == 0) return chunk.done(chunk.outcome);  // the renderer pumps
  call_.pump();
}

size_t RenderBytes(const v1::RenderRequest& r) {
  const size_t pixels = size_t{r.width()} * r.height();
  // Per pixel: the sums (24), the linear image (12) and its encoding (at most 16), adaptive sampling's counts,
  // squares, queries and the allocation's arrays (56); two chunk buffers of queries (wi, wo, uv, axis, weight
  // and tag: 60; the kernel's result and its copy: 48) and of pixel samples (a slot each, at most one per query
  // of the chunk's bound: radiance, queries and first slot, 30); the second trace thread's queries before they
  // join a chunk's (60); the plan of the chunk on the device (fibers' turned wi and wo; a curtain's parts with
  // their uv and index, and three transmittances or scales while it is built: at most 64); the request's map
  // bytes. A fiber scene's yarn and BVH are admitted when generated (RenderCall::BuildFibers).
  size_t fibers = 0;
  if (NeedsOf(r).fibers)  // the generated curves, held while the BVH is built
    fibers = kMaxRenderFiberPoints * kYarnBytesPerPoint + kMaxRenderFibers * kYarnBytesPerFiber;
  // Views: each finished image (12), its coverage (4) and encoding (at most 16, twice in the reply) are held until
  // the last is done; the current view's hit counts (4). A sent mesh's parse and BVH are admitted when loaded
  // (RenderCall::LoadMesh); its bytes are the request's.
  const size_t views = ViewsOf(r);
  return pixels * (108 + 4) + (views - 1) * pixels * 48 + 2 * render::kRenderChunkQueries * 138 +
         render::kRenderChunkQueries * (60 + 64) + r.environment().data().size() + fibers;
}

// A mesh request's own fields. "" or "field: reason".
std::string ValidateMeshRequest(const v1::RenderRequest& r) {
  if (!r.scene_name().empty() || r.scene() != v1::SCENE_SPHERE || r.scene_params_size() > 0)
    return "mesh: the mesh is the scene; leave scene, scene_name and scene_params unset";
  return ValidateMeshSource(r.mesh(), "mesh");
}

// RenderRequest.materials: each binding names a mesh material once and gives a material. "" or "field: reason".
std::string ValidateBindings(const v1::RenderRequest& r) {
  if (std::string e = ValidateMaterialBindings(r.materials(), "materials"); !e.empty()) return e;
  if (r.has_mesh() && !r.has_material() && r.materials_size() == 0)
    return "material: unset (a mesh needs `material` or `materials`)";
  return "";
}

std::string ValidateRenderRequest(const v1::RenderRequest& r) {
  render::ResolvedScene scene;
  render::SceneNeeds needs = kMeshNeeds;
  std::string scene_label = "mesh";
  if (r.has_mesh()) {
    if (std::string e = ValidateMeshRequest(r); !e.empty()) return e;
  } else {
    if (std::string e = render::ResolveScene(r, render::SceneRegistry::Global(), &scene); !e.empty()) return e;
    needs = scene.spec->needs;
    scene_label = scene.spec->name;
    if (r.materials_size() > 0 && !scene.Build().mesh)
      return "materials: only for a mesh or a product scene (whose objects are mesh materials); use `material`";
  }
  if (std::string e = ValidateBindings(r); !e.empty()) return e;
  if (!v1::TextureScaleUnit_IsValid(r.texture_scale_unit()))
    return "texture_scale_unit: unknown value " + std::to_string(r.texture_scale_unit());
  if (r.texture_scale_unit() != v1::TEXTURE_SCALE_UNIT_DEFAULT && !r.has_mesh())
    return "texture_scale_unit: only for a mesh (a built-in scene counts repeats per scene unit)";
  if (!v1::Background_IsValid(r.background())) return "background: unknown value " + std::to_string(r.background());
  if (r.views() > kMaxRenderViews)
    return "views: " + std::to_string(r.views()) + " is outside 0.." + std::to_string(kMaxRenderViews);
  if (!std::isfinite(r.texture_scale()) || r.texture_scale() < 0 || r.texture_scale() > kMaxTextureScale)
    return "texture_scale: " + std::to_string(r.texture_scale()) + " is outside 0.." + std::to_string(int(kMaxTextureScale)) +
           " pattern repeats per unit (0 = the scene's default)";
  if (!std::isfinite(r.texture_rotation_deg()) || std::fabs(r.texture_rotation_deg()) > 360)
    return "texture_rotation_deg: " + std::to_string(r.texture_rotation_deg()) + " is not finite within +-360";
  if (r.lights_size() > kMaxRenderLights)
    return "lights: " + std::to_string(r.lights_size()) + " lights exceed the limit of " + std::to_string(kMaxRenderLights);
  for (int i = 0; i < r.lights_size(); ++i)
    if (std::string e = ValidateLight(r.lights(i), Indexed("lights", i)); !e.empty()) return e;
  if (!r.lighting().empty() && !render::FindLightingPreset(r.lighting()))
    return "lighting: no preset named " + models::Quote(r.lighting()) + " (ListScenes lists lighting_presets)";
  if (r.has_environment()) {
    const v1::RenderEnvironment& env = r.environment();
    if (!env.path().empty())
      return "environment.path: server paths are not accepted; name one of the server's maps (environment.name, "
             "listed by ListModels) or send the map's bytes (environment.data)";
    if (!env.name().empty() && !env.data().empty()) return "environment.data: give a map name or its bytes, not both";
    if (!env.name().empty())
      if (std::string e = assets::EnvironmentMaps::CheckName(env.name()); !e.empty()) return "environment.name: " + e;
    if (env.data().size() > render::Environment::kMaxEncodedBytes)
      return "environment.data: " + std::to_string(env.data().size()) + " bytes exceed the limit of " +
             std::to_string(render::Environment::kMaxEncodedBytes);
    if (!std::isfinite(env.intensity()) || env.intensity() < 0 || env.intensity() > kMaxLightValue)
      return "environment.intensity: " + std::to_string(env.intensity()) + " must be finite and >= 0 (0 = 1)";
    if (!std::isfinite(env.rotation_deg()) || std::fabs(env.rotation_deg()) > 360)
      return "environment.rotation_deg: " + std::to_string(env.rotation_deg()) + " is not finite within +-360";
  }
  if (r.has_camera())
    if (std::string e = ValidateCamera(r.camera()); !e.empty()) return e;
  for (const auto& [field, side] : {std::pair{"width", r.width()}, std::pair{"height", r.height()}})
    if (side < 1 || side > kMaxRenderSide)
      return std::string(field) + ": " + std::to_string(side) + " pixels is outside 1.." + std::to_string(kMaxRenderSide);
  if (r.samples_per_pixel() > kMaxRenderSamplesPerPixel)
    return "samples_per_pixel: " + std::to_string(r.samples_per_pixel()) + " is outside 0.." +
           std::to_string(kMaxRenderSamplesPerPixel) + " (0 = " + std::to_string(kDefaultRenderSamplesPerPixel) + ")";
  const uint64_t samples = uint64_t{r.width()} * r.height() * SamplesPerPixel(r);
  if (samples > kMaxRenderSamples)
    return "samples_per_pixel: width x height x samples_per_pixel = " + std::to_string(samples) +
           " exceeds the limit of " + std::to_string(kMaxRenderSamples) + " per call";
  if (!v1::Sampling_IsValid(r.sampling())) return "sampling: unknown value " + std::to_string(r.sampling());
  if (r.sampling() == v1::SAMPLING_ADAPTIVE && SamplesPerPixel(r) < render::kMinAdaptiveSamples)
    return "sampling: ADAPTIVE needs samples_per_pixel >= " + std::to_string(render::kMinAdaptiveSamples) + ", got " +
           std::to_string(SamplesPerPixel(r));
  if (!v1::RenderFormat_IsValid(r.format())) return "format: unknown value " + std::to_string(r.format());
  if (std::string e = imaging::CheckBackground(FormatOf(r), BackgroundOf(r)); !e.empty()) return "background: " + e;
  if (!std::isfinite(r.exposure()) || r.exposure() < 0)
    return "exposure: " + std::to_string(r.exposure()) + " must be finite and >= 0 (0 = automatic)";
  if (!std::isfinite(r.error_target()) || r.error_target() < 0 || r.error_target() > 1)
    return "error_target: " + std::to_string(r.error_target()) + " is outside 0..1 (relative; 0 = the default " +
           std::to_string(render::kDefaultErrorTarget) + ")";
  if (!v1::Precision_IsValid(r.precision())) return "precision: unknown value " + std::to_string(r.precision());
  if (!v1::FiberDetail_IsValid(r.fiber_detail()))
    return "fiber_detail: unknown value " + std::to_string(r.fiber_detail());
  if (!v1::FiberShadows_IsValid(r.fiber_shadows()))
    return "fiber_shadows: unknown value " + std::to_string(r.fiber_shadows());
  if (!v1::FiberOcclusion_IsValid(r.fiber_occlusion()))
    return "fiber_occlusion: unknown value " + std::to_string(r.fiber_occlusion());
  if (!v1::BtfEnvironment_IsValid(r.btf_environment()))
    return "btf_environment: unknown value " + std::to_string(r.btf_environment());
  if (r.btf_environment() == v1::BTF_ENVIRONMENT_FOLDED) {
    if (needs.fibers) return "btf_environment: FOLDED is for `btf` materials, not the fiber scenes";
    if (r.has_mesh()) return "btf_environment: FOLDED is for the built-in scenes, not a mesh (its materials differ)";
    const render::LightingPreset* preset = render::FindLightingPreset(r.lighting());
    const bool studio_map = preset && preset->environment_intensity > 0;
    const bool default_sky =
        r.lighting().empty() && r.lights().empty() && !r.has_environment() && scene.Build().default_environment;
    if (!r.has_environment() && !default_sky && !studio_map)
      return "btf_environment: FOLDED folds the environment map, and this request's lighting has none";
  }
  if (!std::isfinite(r.ambient()) || r.ambient() < 0 || r.ambient() > kMaxLightValue)
    return "ambient: " + std::to_string(r.ambient()) + " must be finite in 0.." + std::to_string(kMaxLightValue);
  if (!needs.fibers) {
    if (r.has_yarn()) return "yarn: only for the fiber scenes (ListScenes: fibers), not '" + scene_label + "'";
    if (r.fiber_detail() != v1::FIBER_DETAIL_AUTO) return "fiber_detail: only for the fiber scenes";
    if (r.fiber_shadows() != v1::FIBER_SHADOWS_AUTO) return "fiber_shadows: only for the fiber scenes";
    if (r.fiber_occlusion() != v1::FIBER_OCCLUSION_AUTO) return "fiber_occlusion: only for the fiber scenes";
  }
  if (r.has_woven() && !needs.woven)
    return "woven: only for the fiber scenes laid out as a weave, not '" + scene_label + "'";
  if (r.has_knit() && !needs.knit) return "knit: only for the fiber scenes laid out as a knit, not '" + scene_label + "'";
  if (r.has_curves() && !needs.curves)
    return "curves: only for the fiber scenes laid out along curves, not '" + scene_label + "'";
  return "";
}

grpc::Status CheckRenderRequest(const models::Registry& registry, const v1::RenderRequest& request,
                                const models::Model& model, bool has_fp64, FiberJobs* fiber_jobs,
                                render::RenderSetup::FiberDetail* detail) {
  std::unique_ptr<YarnJob>* fiber_job = &fiber_jobs->chosen;
  if (std::string error = ValidateRenderRequest(request); !error.empty()) return Invalid(error);
  if (request.precision() == v1::PRECISION_FP64 && !has_fp64)
    return {grpc::StatusCode::FAILED_PRECONDITION, "precision: the OpenCL device has no fp64"};
  if (request.btf_environment() == v1::BTF_ENVIRONMENT_FOLDED &&
      (!model.folds_environment() || request.material().has_transmission()))
    return Invalid("btf_environment: FOLDED needs a material whose model is `btf` (an asset) without a layer, not '" +
                   model.name() + "'" + (request.material().has_transmission() ? " with a layer" : ""));
  if (!NeedsOf(request).fibers) return grpc::Status::OK;
  *fiber_job = std::make_unique<YarnJob>();
  if (std::string error = FiberJobOf(registry, request, fiber_job->get()); !error.empty()) return Invalid(error);
  // Checked before any fiber is generated (after the yarn's own fields): the material's model is known without packing it.
  if (model.fiber_axis_param().empty() || request.material().has_transmission())
    return Invalid("material: the fiber scenes shade each fiber with a fiber model (e.g. preset cotton), not '" +
                   model.name() + "'" + (request.material().has_transmission() ? " with a layer" : ""));
  bool check = false;
  ChooseFiberDetail(request, fiber_job->get(), detail, &check);
  if (check) {
    fiber_jobs->full = std::make_unique<YarnJob>(**fiber_job);
    fiber_jobs->full->detail.footprint = 0;
  }
  return grpc::Status::OK;
}

grpc::ServerWriteReactor<v1::RenderUpdate>* HandleRender(const RenderDeps& deps, grpc::CallbackServerContext* context,
                                                         const v1::RenderRequest* request) {
  const auto received = Clock::now();
  const auto reject = [&](grpc::Status status) {
    return new RejectedStream<v1::RenderUpdate>(deps.metrics, kRpc, received, std::move(status));
  };
  const models::Model* model = nullptr;
  std::shared_ptr<const models::PreparedMaterial> material;  // null until packed, on the host worker
  // A mesh whose every material is bound may leave `material` unset: the first binding's stands for it.
  const bool bound_only = !request->has_material() && request->materials_size() > 0;
  if (std::string error = deps.materials->Peek(bound_only ? request->materials(0).material() : request->material(),
                                               *deps.registry, &model, &material);
      !error.empty())
    return reject(bound_only ? Invalid("materials[0].material: " + error) : MaterialError(error));
  for (int i = 0; i < request->materials_size(); ++i) {  // each binding's material checked before any work
    const models::Model* bound = nullptr;
    std::shared_ptr<const models::PreparedMaterial> unused;
    if (std::string error = deps.materials->Peek(request->materials(i).material(), *deps.registry, &bound, &unused);
        !error.empty())
      return reject(Invalid(Indexed("materials", i) + ".material: " + error));
  }
  FiberJobs fiber_jobs;
  render::RenderSetup::FiberDetail detail;
  if (grpc::Status s = CheckRenderRequest(*deps.registry, *request, *model, deps.has_fp64, &fiber_jobs, &detail); !s.ok())
    return reject(s);
  // A woven patch's centre polylines twice: the layout while its fibers are generated, and the copies the
  // visibility approximations keep for the render (the centre curves and the other yarns' tubes); per detail.
  size_t layout_bytes = 0;
  for (const auto* job : {fiber_jobs.chosen.get(), fiber_jobs.full.get()})
    if (job) layout_bytes += 2 * job->layout_bytes;
  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, RenderBytes(*request) + layout_bytes, &admission); !s.ok())
    return reject(s);
  return new RenderCall(deps, context, *request, std::move(material), std::move(fiber_jobs), std::move(detail),
                        std::move(admission), received);
}

}  // namespace loomlight::api
