#include "server/api/render_rpc.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <memory>
#include <thread>
#include <vector>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/stream_call.h"
#include "server/imaging/image_encode.h"
#include "server/models/material.h"
#include "server/models/btf/environment_fold.h"
#include "server/render/adaptive_sampling.h"
#include "server/render/fidelity.h"
#include "server/render/folded_environment.h"
#include "server/render/shading.h"
#include "server/render/tone_map.h"
#include "server/api/yarn_rpc.h"
#include "server/yarn/fiber_scene.h"
#include "server/yarn/visibility.h"

namespace loomlight::api {
namespace {

constexpr const char* kRpc = "Render";

using Clock = batching::Clock;
using render::Rgb;
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
  if (light.type() == v1::RenderLight::TYPE_DIRECTIONAL) {
    if (std::string e = ValidateTriple(light.direction(), field + ".direction", kMaxSceneCoordinate); !e.empty()) return e;
    if (render::Length(ToVec(light.direction())) < 1e-9) return field + ".direction: must not be zero";
  } else {
    if (std::string e = ValidateTriple(light.position(), field + ".position", kMaxSceneCoordinate); !e.empty()) return e;
  }
  return "";
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

render::SceneKind ToSceneKind(v1::ScenePreset scene) {
  switch (scene) {
    case v1::SCENE_CYLINDERS: return render::SceneKind::kCylinders;
    case v1::SCENE_SWATCH: return render::SceneKind::kSwatch;
    case v1::SCENE_CURTAIN: return render::SceneKind::kCurtain;
    case v1::SCENE_YARN: return render::SceneKind::kYarn;
    case v1::SCENE_WOVEN_PATCH: return render::SceneKind::kWovenPatch;
    default: return render::SceneKind::kSphere;
  }
}

bool IsFiberScene(v1::ScenePreset scene) { return scene == v1::SCENE_YARN || scene == v1::SCENE_WOVEN_PATCH; }

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

// A fiber scene's yarn: the request's yarn and layout (the woven patch's default: cotton_twill, 2 x 2 repeats),
// at the detail it asks for. Validation only (cheap); `detail` is filled in by ChooseFiberDetail.
std::string FiberJobOf(const models::Registry& registry, const v1::RenderRequest& r, YarnJob* job) {
  v1::WovenYarnLayout woven = r.woven();
  if (r.scene() == v1::SCENE_WOVEN_PATCH) {
    if (!woven.has_weave()) woven.mutable_weave()->set_preset("cotton_twill");
    if (woven.repeats_u() == 0) woven.set_repeats_u(2);
    if (woven.repeats_v() == 0) woven.set_repeats_v(2);
  }
  job->limits.max_fibers = static_cast<int64_t>(kMaxRenderFibers);
  job->limits.max_control_points = static_cast<int64_t>(kMaxRenderFiberPoints);
  return YarnJobOf(registry, r.yarn(), r.scene() == v1::SCENE_WOVEN_PATCH ? &woven : nullptr, 0, job);
}

// Eq. 4's level of detail for a fiber scene: from the pixel footprint at the camera's look-at point (AUTO, LOD),
// or as the request says. Sets job->detail and the fidelity report's entry; *check says whether the choice is
// AUTO's thinning, which the fidelity chooser compares with full detail before the render keeps it.
void ChooseFiberDetail(const v1::RenderRequest& r, YarnJob* job, render::RenderSetup::FiberDetail* report,
                       bool* check) {
  *check = false;
  const render::Scene scene = render::MakeScene(ToSceneKind(r.scene()));
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

// One Render call in flight, on the host worker (server/api/stream_call.h); batcher completions post there
// too. The call is finished only when no batcher job and no write is outstanding.
//
// Pixels are rendered in chunks of whole pixels (all of a pixel's samples of the pass); two chunk buffers
// alternate: while one chunk's jobs are on the device, the worker accumulates the previous chunk and traces the
// next. Every pixel sample's sum is taken in a fixed order (evaluators in order, then queries in order), and a
// pixel's in sample order, so the image does not depend on timing or on how launches were batched. Sampling
// uniformly is one pass of samples_per_pixel; adaptively (server/render/adaptive_sampling.h), a first pass of a
// few samples per pixel measures each pixel's noise, and a second gives pixel p its samples up to counts_[p].
class RenderCall final : public WorkerStreamCall<v1::RenderUpdate> {
 public:
  RenderCall(const RenderDeps& deps, grpc::CallbackServerContext* context, const v1::RenderRequest& request,
             std::shared_ptr<const models::PreparedMaterial> material, FiberJobs fiber_jobs,
             render::RenderSetup::FiberDetail fiber_detail, Admission admission, Clock::time_point received)
      : WorkerStreamCall(deps, context, kRpc, received, std::move(admission)), request_(request),
        material_(std::move(material)), fp64_(request.precision() == v1::PRECISION_FP64),
        fiber_job_(std::move(fiber_jobs.chosen)), full_fiber_job_(std::move(fiber_jobs.full)),
        fiber_detail_(std::move(fiber_detail)) {
    const v1::RenderEnvironment& env = request_.environment();
    const bool map = !env.name().empty() || !env.data().empty();
    if (map || fiber_job_) {
      // Reading and decoding a map runs on the asset loader, generating fibers and their BVH on the geometry
      // worker, never on the host worker every streaming call shares; the call cannot finish meanwhile (Pump
      // waits for loading_ to clear).
      loading_ = true;
      (fiber_job_ ? deps_.geometry : deps_.loader)->Post([this, map] {
        grpc::Status status = map ? LoadEnvironment() : grpc::Status::OK;
        if (status.ok() && fiber_job_) status = BuildFibers();
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
  struct Chunk {
    uint64_t first_pixel = 0, pixels = 0;     // pixels 0: nothing prepared
    // Per pixel of the chunk (and one past the last): its first slot, one slot per pixel sample.
    std::vector<uint32_t> slot_begin;
    std::vector<render::QueryBucket> buckets;  // per evaluator; tag = slot
    std::vector<Rgb> value;                    // per slot: the radiance needing no query, then the sample's all
    std::vector<uint16_t> slot_queries;        // adaptive first pass: per slot, its queries (the sample's work)
    std::vector<uint8_t> slot_folded;          // adaptive first pass: per slot, 1 for a hit shaded by the fold
    std::vector<std::vector<double>> f;        // per evaluator: the kernel's results
    std::vector<std::unique_ptr<models::EvaluationPlan>> plans;  // per evaluator: its kernel parts
    size_t jobs_in_flight = 0;
    uint64_t queries = 0;
  };

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
    if (s.ok()) fiber_count_ = static_cast<uint64_t>(fibers_->stats().curves);
    return s;
  }

  // Scene, camera, lights, environment and the fidelity choice; on failure status_ says why.
  void SetUp() {
    const v1::RenderRequest& r = request_;
    render::RenderSetup& s = setup_;
    s.scene = render::MakeScene(ToSceneKind(r.scene()));
    s.scene.fibers = fibers_;
    s.scene.fiber_visibility = fiber_visibility_;
    s.full_detail_fibers = full_fibers_;
    s.full_detail_visibility = full_fiber_visibility_;
    s.fiber_shadows = r.fiber_shadows() == v1::FIBER_SHADOWS_SLICES ? yarn::ShadowMethod::kSlices : yarn::ShadowMethod::kTraced;
    s.fiber_occlusion = r.fiber_occlusion() == v1::FIBER_OCCLUSION_TEXTURE    ? yarn::OcclusionMethod::kTexture
                        : r.fiber_occlusion() == v1::FIBER_OCCLUSION_DISTANCE ? yarn::OcclusionMethod::kDistance
                                                                              : yarn::OcclusionMethod::kTraced;
    s.choose_fiber_shadows = r.fiber_shadows() == v1::FIBER_SHADOWS_AUTO;
    s.choose_fiber_occlusion = r.fiber_occlusion() == v1::FIBER_OCCLUSION_AUTO;
    const render::CameraSpec camera = CameraOf(r, s.scene);
    s.width = static_cast<int>(r.width());
    s.height = static_cast<int>(r.height());
    s.samples_per_pixel = SamplesPerPixel(r);
    s.seed = r.seed();
    s.camera = render::PinholeCamera(camera, s.width, s.height);
    s.texture_scale = r.texture_scale() > 0 ? r.texture_scale() : s.scene.default_texture_scale;
    s.texture_rotation_deg = r.texture_rotation_deg();
    for (const v1::RenderLight& light : r.lights()) {
      render::Light l;
      l.rgb = ToVec(light.rgb());
      if (light.type() == v1::RenderLight::TYPE_POINT) {
        l.type = render::Light::Type::kPoint;
        l.position = ToVec(light.position());
      } else {
        l.direction = render::Normalize(ToVec(light.direction()));
      }
      s.lights.push_back(l);
    }
    const bool default_lighting = r.lights().empty() && !r.has_environment();
    if (default_lighting) s.lights = s.scene.default_lights;
    s.ambient = r.ambient() > 0 ? r.ambient() : default_lighting ? s.scene.default_ambient : 0.0;
    if ((default_lighting && s.scene.default_environment) || r.has_environment()) {
      // A copy with its own transform; the decoded map itself is shared (a cached map is not copied).
      auto environment = std::make_shared<render::Environment>(environment_ ? *environment_
                                                                            : render::Environment::Builtin());
      const double intensity = default_lighting ? s.scene.default_environment_intensity
                               : r.environment().intensity() > 0 ? r.environment().intensity() : 1.0;
      environment->SetTransform(intensity, r.has_environment() ? r.environment().rotation_deg() : 0.0);
      s.environment = std::move(environment);
    }

    if (!material_ && !(status_ = PrepareMaterial(deps_, r.material(), &material_)).ok()) return;
    if (fiber_job_) {
      s.fiber_detail = fiber_detail_;
      s.fiber_detail.reason += "; " + std::to_string(fiber_count_) + " fiber curves";
    }
    render::MaterialInfo info;
    info.model = material_->model;
    info.values = material_->values;
    info.layered = material_->transmission != nullptr;
    s.object_transmits.assign(s.scene.objects.size(), render::Transmits(info));
    variants_ = std::make_unique<render::CachedVariants>(r.material(), *deps_.registry, *deps_.materials);
    error_target_ = r.error_target() > 0 ? r.error_target() : render::kDefaultErrorTarget;
    if (std::string e = render::ChooseFidelity(s, info, *variants_, error_target_, r.force_full_fidelity(), &plan_,
                                                int(kTraceThreads));
        !e.empty()) {
      status_ = {grpc::StatusCode::INTERNAL, e};
      return;
    }
    if (plan_.fiber_full_detail) {  // AUTO's thinning was over the target: the render is at full detail
      s.scene.fibers = full_fibers_;
      s.scene.fiber_visibility = full_fiber_visibility_;
      fiber_count_ = static_cast<uint64_t>(full_fibers_->stats().curves);
    }
    // The check's full-detail geometry is held only by s.scene from here (when chosen): otherwise the render
    // does not keep it alive, and the scene cache may let it go.
    s.full_detail_fibers.reset();
    s.full_detail_visibility.reset();
    full_fibers_.reset();
    full_fiber_visibility_.reset();
    s.fiber_shadows = plan_.fiber_shadows;
    s.fiber_occlusion = plan_.fiber_occlusion;
    ChooseBtfEnvironment();
    // Surfaces sample their material too (weighed against the environment's samples by MIS), unless their
    // environment light is folded. A material's table is built on its first render, on the asset loader (not on
    // the host worker every streaming call shares), and kept with it in the material cache; the fold, when
    // requested or a candidate, is built and chosen there first.
    if (!folding_) {
      bool built = true;
      for (size_t o = 0; o < plan_.objects.size() && s.environment; ++o)
        if (const models::PreparedMaterial* m = SampledMaterial(o, nullptr); m && !m->SamplerBuilt()) built = false;
      if (built) return StartRendering();
    }
    loading_ = true;
    deps_.loader->Post([this] {
      std::shared_ptr<const render::FoldedEnvironment> folded;
      std::vector<render::FidelityChoice> choices;
      grpc::Status status = folding_ ? FoldEnvironment(&folded, &choices) : grpc::Status::OK;
      for (size_t o = 0; o < plan_.objects.size() && status.ok() && setup_.environment; ++o)
        if (const models::PreparedMaterial* m = SampledMaterial(o, folded.get()); m && !m->SamplerBuilt()) {
          m->Sampler();
          deps_.materials->ChargeSampler(*m);
        }
      Post([this, status, folded, choices] {
        loading_ = false;
        if (!status.ok()) {
          if (status_.ok()) status_ = status;
        } else {
          setup_.folded_environment = folded;
          for (size_t o = 0; o < choices.size() && o < plan_.fidelity.size(); ++o)
            if (!choices[o].aspect.empty()) {
              plan_.fidelity[o].choices.push_back(choices[o]);
              plan_.fidelity[o].estimated_error += choices[o].estimated_error;
            }
          StartRendering();
        }
        Pump();
      });
    }, client_);
  }

  // Whether the environment light of the `btf` objects may be folded (btf_environment FOLDED, or AUTO where the
  // fold's estimated error is within the target: render::FoldEnvironment decides, once folded) or is sampled,
  // in the fidelity report of every object whose material is a `btf` asset lit by an environment. FOLDED is
  // validated: a `btf` material without a layer, environment lighting, not a fiber scene.
  void ChooseBtfEnvironment() {
    const v1::RenderRequest& r = request_;
    if (!setup_.environment || !material_->model->folds_environment() || fiber_job_) return;
    const bool asked = r.btf_environment() == v1::BTF_ENVIRONMENT_FOLDED || r.btf_environment() == v1::BTF_ENVIRONMENT_AUTO;
    folding_ = asked && !r.force_full_fidelity() && !material_->transmission;
    if (folding_) return;
    const std::string reason = r.force_full_fidelity() ? "force_full_fidelity"
                               : material_->transmission
                                   ? "the material lets light through its layer: the fold is of reflected light only"
                                   : "requested";
    for (size_t o = 0; o < plan_.fidelity.size(); ++o)
      if (!setup_.scene.objects[o].fibers)
        plan_.fidelity[o].choices.push_back({"btf_environment", "sampled", "sampled", 0, reason});
  }

  // On the asset loader: each object's `btf` material (as its kernel path reads it: the chosen components, BTF
  // or BRDF) folded with the environment, within the deadline, while the client is there, and within the
  // memory budget.
  grpc::Status FoldEnvironment(std::shared_ptr<const render::FoldedEnvironment>* out,
                               std::vector<render::FidelityChoice>* choices) {
    std::vector<render::FoldedEnvironment::Material> materials(plan_.objects.size());
    for (size_t o = 0; o < plan_.objects.size(); ++o) {
      const int e = plan_.objects[o].evaluator;
      if (e < 0) continue;
      const render::Evaluator& evaluator = plan_.evaluators[e];
      materials[o] = {evaluator.material->packed.tables, evaluator.material->packed.uniform, evaluator.with_uv};
    }
    const auto stop = ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); });
    const auto admit = [this](uint64_t bytes) { return admission_.bytes.Grow(size_t(bytes)); };
    bool refused = false;
    const std::string e = render::FoldEnvironment(setup_, materials, deps_.folds, error_target_,
                                                  request_.btf_environment() == v1::BTF_ENVIRONMENT_FOLDED,
                                                  int(kTraceThreads), stop, admit, &refused, out, choices);
    if (e.empty()) return grpc::Status::OK;
    if (grpc::Status stopped = StopStatus(context_, deadline_); !stopped.ok()) return stopped;
    if (refused) return {grpc::StatusCode::RESOURCE_EXHAUSTED, "btf_environment: " + e};
    return {grpc::StatusCode::INTERNAL, "btf_environment: " + e};
  }

  // The material whose sampler object o's hits draw from (null: it samples lights only, as fibers do and as
  // objects whose environment light is in `folded` do).
  const models::PreparedMaterial* SampledMaterial(size_t o, const render::FoldedEnvironment* folded) const {
    if (folded && folded->Covers(int(o))) return nullptr;
    const int e = plan_.objects[o].evaluator;
    return e >= 0 && !plan_.evaluators[e].fiber_axis ? plan_.evaluators[e].material : nullptr;
  }

  // Once every sampler is built: the chunk size and the first chunks.
  void StartRendering() {
    render::RenderSetup& s = setup_;
    s.object_samplers.assign(s.scene.objects.size(), nullptr);
    for (size_t o = 0; o < plan_.objects.size() && s.environment; ++o)
      if (const models::PreparedMaterial* m = SampledMaterial(o, s.folded_environment.get()))
        s.object_samplers[o] = &m->Sampler();
    total_pixels_ = uint64_t(s.width) * s.height;
    chunk_slots_ = std::max<uint64_t>(1, kRenderChunkQueries / std::max<size_t>(1, render::MaxQueriesPerSample(s)));
    sums_.assign(total_pixels_, Rgb{});
    const uint32_t spp = s.samples_per_pixel;
    adaptive_ = request_.sampling() == v1::SAMPLING_ADAPTIVE ||
                (request_.sampling() == v1::SAMPLING_AUTO && spp >= render::kAutoAdaptiveSamples);
    first_pass_ = adaptive_ ? render::FirstPassSamples(spp) : spp;
    samples_total_ = total_pixels_ * spp;
    if (adaptive_) {
      squares_.assign(total_pixels_, 0.0);
      pixel_queries_.assign(total_pixels_, 0.0f);
    }
    setup_seconds_ = SecondsSince(received_);
    // The first chunk goes to the device before the second is traced, so the two overlap from the start.
    Prepare(chunks_[next_chunk_]);
    MaybeSubmit();
    Prepare(chunks_[1 - next_chunk_]);
  }

  // The one step of the state machine (as Tabulate's): notice a stop, keep one chunk in flight, keep one
  // write in flight while there is news, finish when nothing is outstanding.
  void Pump() override {
    if (finished_ || loading_) return;  // a load in flight still refers to this call
    NoticeStop();
    MaybeSubmit();  // does nothing once stopping
    if (!status_.ok()) {
      if (!JobsInFlight() && !write_in_flight_) FinishCall(status_);
      return;
    }
    if (write_in_flight_) return;
    if (complete_ && !final_sent_) return WriteUpdate(true);
    if (final_sent_) return FinishCall(grpc::Status::OK);
    if (!sent_first_ || samples_done_ > samples_sent_) WriteUpdate(false);
  }

  bool JobsInFlight() const { return chunks_[0].jobs_in_flight + chunks_[1].jobs_in_flight > 0; }

  // The samples of `pixel` this pass traces: [begin, end).
  std::pair<uint32_t, uint32_t> PassSamples(uint64_t pixel) const {
    return pass_ == 0 ? std::pair{0u, first_pass_} : std::pair{first_pass_, counts_[pixel]};
  }

  // Traces the next pixels of the pass (at most chunk_slots_ samples, or one pixel) into a free chunk buffer
  // (none left: pixels = 0).
  void Prepare(Chunk& chunk) {
    chunk.first_pixel = next_pixel_;
    chunk.slot_begin.assign(1, 0);
    uint64_t slots = 0;
    for (; next_pixel_ < total_pixels_; ++next_pixel_) {
      const auto [begin, end] = PassSamples(next_pixel_);
      if (chunk.slot_begin.size() > 1 && slots + (end - begin) > chunk_slots_) break;
      slots += end - begin;
      chunk.slot_begin.push_back(static_cast<uint32_t>(slots));
    }
    chunk.pixels = next_pixel_ - chunk.first_pixel;
    chunk.buckets.resize(plan_.evaluators.size());
    for (render::QueryBucket& b : chunk.buckets) b.Clear();
    chunk.value.assign(slots, Rgb{});
    chunk.slot_folded.assign(adaptive_ && pass_ == 0 ? slots : 0, 0);
    chunk.queries = 0;
    // Chunks are traced on kTraceThreads threads (casting rays and sampling lights and materials is the host's
    // share of a render), each taking the next block of kTraceBlockPixels pixels into its own buckets, appended
    // in thread order. Blocks are handed out as threads come for them, not fixed per thread: beside the device's
    // threads the two trace threads do not get equal CPU, and with every other block fixed to each, one thread
    // waited 10-27 ms per chunk for the other (a fifth of the satin cylinders' render with a core idle). Which
    // thread traces a block changes only where its queries sit in the batch; each sample's queries stay
    // together and in order, every query is evaluated alone, and a sample's value goes to its own slot, so the
    // image does not depend on the threads' timing.
    const uint64_t threads = std::clamp<uint64_t>(chunk.pixels, 1, kTraceThreads);
    // The other threads' buckets are kept from chunk to chunk, and through a chunk of one pixel or none (a
    // pass's end): filled afresh each time, they page-faulted their memory in again, which made the second
    // thread 15-25% slower than the first.
    trace_parts_.resize(std::max<size_t>(trace_parts_.size(), threads - 1));
    for (std::vector<render::QueryBucket>& part : trace_parts_) {
      part.resize(plan_.evaluators.size());
      for (render::QueryBucket& b : part) b.Clear();
    }
    std::atomic<uint64_t> next_block{0};
    std::vector<std::thread> workers;
    for (uint64_t t = 1; t < threads; ++t)
      workers.emplace_back([this, &chunk, &next_block, t] { TraceBlocks(chunk, &next_block, &trace_parts_[t - 1]); });
    TraceBlocks(chunk, &next_block, &chunk.buckets);
    for (std::thread& w : workers) w.join();
    for (const std::vector<render::QueryBucket>& part : trace_parts_)
      for (size_t e = 0; e < part.size(); ++e) chunk.buckets[e].Append(part[e]);
    for (const render::QueryBucket& b : chunk.buckets) chunk.queries += b.size();
  }

  // Traces the chunk's pixel blocks (of kTraceBlockPixels) this thread takes from *next_block: their queries
  // into `buckets`, what needs none into chunk.value. Hits on objects with a folded environment get its radiance
  // too, evaluated on the host for all the thread's blocks at once.
  void TraceBlocks(Chunk& chunk, std::atomic<uint64_t>* next_block, std::vector<render::QueryBucket>* buckets) const {
    std::array<render::ShadingPoint, render::Scene::kMaxPacket> points;
    std::array<render::PixelSample, render::Scene::kMaxPacket> batch;
    std::array<uint32_t, render::Scene::kMaxPacket> batch_slot;
    size_t queued = 0;
    std::vector<render::FoldedEnvironment::Query> folded;
    std::vector<uint32_t> folded_slot;
    // Samples are traced a packet at a time, in pixel order (a pixel's queries stay in sample order).
    const auto flush = [&] {
      render::TracePixelSamples(setup_, {batch.data(), queued}, points.data());
      for (size_t k = 0; k < queued; ++k) {
        const render::ShadingPoint& point = points[k];
        const uint32_t slot = batch_slot[k];
        if (point.object < 0) {
          chunk.value[slot] = point.background;
          continue;
        }
        chunk.value[slot] = render::AppendQueries(point, plan_.objects[point.object], plan_.evaluators, slot, buckets);
        if (point.environment_folded) {
          folded.push_back(setup_.folded_environment->QueryOf(point));
          folded_slot.push_back(slot);
          if (!chunk.slot_folded.empty()) chunk.slot_folded[slot] = 1;
        }
      }
      queued = 0;
    };
    for (uint64_t block = next_block->fetch_add(1, std::memory_order_relaxed); block * kTraceBlockPixels < chunk.pixels;
         block = next_block->fetch_add(1, std::memory_order_relaxed)) {
      const uint64_t end = std::min<uint64_t>((block + 1) * kTraceBlockPixels, chunk.pixels);
      for (uint64_t p = block * kTraceBlockPixels; p < end; ++p) {
        const uint64_t pixel = chunk.first_pixel + p;
        uint32_t slot = chunk.slot_begin[p];
        const auto [first_sample, last_sample] = PassSamples(pixel);
        for (uint32_t s = first_sample; s < last_sample; ++s, ++slot) {
          batch[queued] = {pixel, s};
          batch_slot[queued] = slot;
          if (++queued == batch.size()) flush();
        }
      }
      flush();  // a packet holds one block's samples, whichever thread traces it
    }
    if (folded.empty()) return;
    std::vector<Rgb> radiance;
    setup_.folded_environment->Radiance(folded, &radiance);
    for (size_t q = 0; q < folded.size(); ++q) chunk.value[folded_slot[q]] = chunk.value[folded_slot[q]] + radiance[q];
  }

  // Sends the next chunk's jobs when none is in flight.
  void MaybeSubmit() {
    Chunk& chunk = chunks_[next_chunk_];
    if (!status_.ok() || JobsInFlight() || chunk.pixels == 0 || submitted_[next_chunk_]) return;
    submitted_[next_chunk_] = true;
    const int index = next_chunk_;
    chunk.f.assign(plan_.evaluators.size(), {});
    chunk.plans.clear();
    chunk.plans.resize(plan_.evaluators.size());
    for (size_t e = 0; e < plan_.evaluators.size(); ++e) {
      const render::QueryBucket& b = chunk.buckets[e];
      if (b.size() == 0) continue;
      const render::Evaluator& evaluator = plan_.evaluators[e];
      chunk.f[e].resize(3 * b.size());
      chunk.plans[e] = render::PlanOf(evaluator, b);
      chunk.jobs_in_flight += chunk.plans[e]->parts();
    }
    if (chunk.jobs_in_flight == 0) {  // nothing to evaluate (e.g. only background): the chunk is done at once
      Post([this, index] { OnChunkDone(index); });
      chunk.jobs_in_flight = 1;  // held until OnChunkDone, so the call does not finish under it
      return;
    }
    for (size_t e = 0; e < plan_.evaluators.size(); ++e) {
      if (!chunk.plans[e]) continue;
      SubmitPlan(deps_.batcher, *chunk.plans[e], runtime::ResultSink{.f64 = chunk.f[e].data()}, fp64_,
                 batching::Priority::kBulk, deadline_, context_, client_, [this, index, e](size_t k, batching::JobResult r) {
                   Post([this, index, e, k, r = std::move(r)] { OnJobDone(index, e, k, r); });
                 });
    }
  }

  void OnJobDone(int index, size_t evaluator, size_t part, const batching::JobResult& result) {
    Chunk& chunk = chunks_[index];
    if (result.status != batching::JobStatus::kOk) {
      if (status_.ok()) status_ = ToStatus(result);
    } else {
      const models::EvaluationPlan& plan = *chunk.plans[evaluator];
      const size_t n = plan.size(part);
      if (result.batch_queries > 0)
        deps_.metrics->Evaluated(plan.model(part).name(), fp64_, n, result.batch_queries, result.batch_requests,
                                 result.queue_seconds, result.kernel_seconds);
      deps_.metrics->Rendered(n);
      queries_ += n;
      kernel_seconds_ += result.kernel_seconds;
    }
    if (--chunk.jobs_in_flight == 0) return OnChunkDone(index);
    Pump();
  }

  // The next chunk goes to the device first; this one is then accumulated and its buffer refilled.
  void OnChunkDone(int index) {
    Chunk& chunk = chunks_[index];
    chunk.jobs_in_flight = 0;
    submitted_[index] = false;
    next_chunk_ = 1 - index;
    NoticeStop();
    if (status_.ok()) {
      MaybeSubmit();
      Accumulate(chunk);
      if (pass_pixels_done_ == total_pixels_ && pass_ == 0 && adaptive_) {
        // Both buffers are free: the other holds nothing (the pass is done), and this one was just accumulated.
        AllocateSamples();
        Prepare(chunks_[next_chunk_]);
        MaybeSubmit();  // on the device while this buffer is traced
        Prepare(chunk);
      } else {
        Prepare(chunk);
      }
      if (pass_pixels_done_ == total_pixels_) Encode();
    }
    Pump();
  }

  // After an adaptive render's first pass: each pixel's samples (render::AllocateSamples), from the spread of
  // its first samples and their work (queries, folded hits); then the second pass begins.
  void AllocateSamples() {
    render::PixelNoise noise;
    noise.variance.resize(total_pixels_);
    noise.cost.resize(total_pixels_);
    const double n = first_pass_;
    for (uint64_t p = 0; p < total_pixels_; ++p) {
      const Rgb& sum = sums_[p];
      // The unbiased sample variance, summed over the channels: (sum x^2 - (sum x)^2 / n) / (n - 1).
      noise.variance[p] = std::max(0.0, squares_[p] - (sum.x * sum.x + sum.y * sum.y + sum.z * sum.z) / n) / (n - 1);
      noise.cost[p] = render::kSampleCostWithoutQueries + pixel_queries_[p] / n;
    }
    counts_ = render::AllocateSamples(setup_.width, setup_.height, noise, first_pass_, setup_.samples_per_pixel,
                                      MostSamples());
    samples_total_ = 0;
    for (uint32_t c : counts_) samples_total_ += c;
    squares_ = {};
    pixel_queries_ = {};
    pass_ = 1;
    next_pixel_ = 0;
    pass_pixels_done_ = 0;
  }

  // The most samples an adaptive render gives one pixel.
  uint32_t MostSamples() const {
    return static_cast<uint32_t>(std::min<uint64_t>(8 * uint64_t{setup_.samples_per_pixel}, chunk_slots_));
  }

  uint32_t PixelSamples(uint64_t pixel) const { return pass_ == 1 ? counts_[pixel] : setup_.samples_per_pixel; }

  // Each sample's radiance (its queries' weight x f added to what needed none), then each pixel's sum; the first
  // pass of an adaptive render also keeps each pixel's sum of squares and its queries.
  void Accumulate(Chunk& chunk) {
    const bool measure = adaptive_ && pass_ == 0;
    if (measure) chunk.slot_queries.assign(chunk.value.size(), 0);
    for (size_t e = 0; e < chunk.buckets.size(); ++e) {
      const render::QueryBucket& b = chunk.buckets[e];
      const std::vector<double>& f = chunk.f[e];
      for (size_t q = 0; q < b.size(); ++q) {
        Rgb& sample = chunk.value[b.tag[q]];
        for (int c = 0; c < 3; ++c) {
          const double value = double(b.weight[3 * q + c]) * f[3 * q + c];
          if (std::isfinite(value)) (c == 0 ? sample.x : c == 1 ? sample.y : sample.z) += value;
        }
        if (measure) ++chunk.slot_queries[b.tag[q]];
      }
    }
    for (uint64_t p = 0; p < chunk.pixels; ++p) {
      const uint64_t pixel = chunk.first_pixel + p;
      Rgb& sum = sums_[pixel];
      for (uint32_t slot = chunk.slot_begin[p]; slot < chunk.slot_begin[p + 1]; ++slot) {
        const Rgb& v = chunk.value[slot];
        sum = sum + v;
        if (!measure) continue;
        squares_[pixel] += v.x * v.x + v.y * v.y + v.z * v.z;
        pixel_queries_[pixel] += chunk.slot_queries[slot] + (chunk.slot_folded[slot] ? render::kFoldedSampleCost : 0.0);
      }
    }
    samples_done_ += chunk.value.size();
    pass_pixels_done_ += chunk.pixels;
  }

  void Encode() {
    imaging::LinearRgbImage image;
    image.width = setup_.width;
    image.height = setup_.height;
    image.rgb.resize(3 * total_pixels_);
    double mean[3] = {0, 0, 0};
    for (uint64_t p = 0; p < total_pixels_; ++p)
      for (int c = 0; c < 3; ++c) {
        double v = sums_[p][c] / PixelSamples(p);
        if (!std::isfinite(v) || v < 0) v = 0;  // never NaN or Inf in an image
        image.rgb[3 * p + c] = static_cast<float>(v);
        mean[c] += v / total_pixels_;
      }
    double exposure = 1;
    std::string bytes, error;
    if (request_.format() == v1::RENDER_FORMAT_EXR) {
      error = imaging::EncodeImage(image, imaging::ImageFormat::kExr, 1.0, &bytes);
    } else {
      exposure = request_.exposure() > 0 ? request_.exposure() : render::AutomaticExposure(image);
      const imaging::ImageFormat format =
          request_.format() == v1::RENDER_FORMAT_JPEG ? imaging::ImageFormat::kJpeg : imaging::ImageFormat::kPng;
      error = imaging::EncodeImage(render::ToneMap(image, exposure), format, 1.0, &bytes);
    }
    if (!error.empty()) {
      status_ = {grpc::StatusCode::INTERNAL, "cannot encode the image: " + error};
      return;
    }
    final_.set_image(std::move(bytes));
    final_.set_format(request_.format());
    final_.set_width(request_.width());
    final_.set_height(request_.height());
    final_.set_exposure(exposure);
    for (double m : mean) final_.add_mean(m);
    complete_ = true;
  }

  void AddFidelity(v1::RenderUpdate* update) const {
    update->set_error_target(error_target_);
    for (const render::ObjectFidelity& of : plan_.fidelity) {
      v1::ObjectFidelity* out = update->add_fidelity();
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
    if (last || !sent_first_) AddFidelity(&update_);
    sent_first_ = true;
    update_.set_samples_done(samples_done_);
    update_.set_samples_total(samples_total_);
    samples_sent_ = samples_done_;
    if (last) {
      update_.set_adaptive_sampling(adaptive_);
      uint32_t fewest = setup_.samples_per_pixel, most = fewest;
      if (adaptive_) {
        const auto range = std::minmax_element(counts_.begin(), counts_.end());
        fewest = *range.first;
        most = *range.second;
      }
      update_.set_min_samples_per_pixel(fewest);
      update_.set_max_samples_per_pixel(most);
      update_.set_queries(queries_);
      update_.set_setup_seconds(setup_seconds_);
      update_.set_kernel_seconds(kernel_seconds_);
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
  std::shared_ptr<const yarn::FiberScene> full_fibers_;
  std::shared_ptr<const yarn::YarnVisibility> full_fiber_visibility_;
  render::RenderSetup::FiberDetail fiber_detail_;
  std::shared_ptr<const yarn::FiberScene> fibers_;
  std::shared_ptr<const yarn::YarnVisibility> fiber_visibility_;
  uint64_t fiber_count_ = 0;
  bool loading_ = false;  // the asset loader is reading the environment map
  bool folding_ = false;  // the `btf` objects' environment light is folded or a candidate (ChooseBtfEnvironment)
  std::shared_ptr<const render::Environment> environment_;  // the loaded map (null: the built-in sky)

  render::RenderSetup setup_;
  std::unique_ptr<render::CachedVariants> variants_;  // owns the packed variants the plan points at
  render::FidelityPlan plan_;
  double error_target_ = render::kDefaultErrorTarget;
  Chunk chunks_[2];
  bool submitted_[2] = {false, false};
  int next_chunk_ = 0;  // the chunk to submit next (chunks alternate)
  uint64_t total_pixels_ = 0, chunk_slots_ = 1, next_pixel_ = 0, pass_pixels_done_ = 0;
  uint64_t samples_done_ = 0, samples_sent_ = 0, samples_total_ = 0;
  std::vector<Rgb> sums_;  // per pixel: the sum over its samples
  // Prepare: the queries of trace threads 1.. (per evaluator), before they join the chunk's buckets.
  std::vector<std::vector<render::QueryBucket>> trace_parts_;
  // Sampling: pass 0 gives every pixel first_pass_ samples (all of samples_per_pixel when uniform); an adaptive
  // render's pass 1 then gives pixel p its samples up to counts_[p].
  bool adaptive_ = false;
  uint32_t first_pass_ = 0;
  int pass_ = 0;
  std::vector<uint32_t> counts_;
  std::vector<double> squares_;      // adaptive, pass 0: per pixel, its samples' squared radiance summed over channels
  std::vector<float> pixel_queries_;  // adaptive, pass 0: per pixel, its samples' queries
  uint64_t queries_ = 0;
  double setup_seconds_ = 0, kernel_seconds_ = 0;
  v1::RenderUpdate update_;  // the write in flight
  v1::RenderUpdate final_;   // the image and its summary, once encoded
  bool sent_first_ = false, complete_ = false, final_sent_ = false;
};

}  // namespace

size_t RenderBytes(const v1::RenderRequest& r) {
  const size_t pixels = size_t{r.width()} * r.height();
  // Per pixel: the sums (24), the linear image (12) and its encoding (at most 16), adaptive sampling's counts,
  // squares, queries and the allocation's arrays (56); two chunk buffers of queries (wi, wo, uv, axis, weight
  // and tag: 60; the kernel's result and its copy: 48) and of pixel samples (a slot each, at most one per query
  // of the chunk's bound: radiance, queries and first slot, 30); the second trace thread's queries before they
  // join a chunk's (60); the plan of the chunk on the device (fibers' turned wi and wo; a curtain's parts with
  // their uv and index, and three transmittances or scales while it is built: at most 64); the request's map
  // bytes. A fiber scene's yarn
  // and BVH are admitted when generated (RenderCall::BuildFibers).
  size_t fibers = 0;
  if (IsFiberScene(r.scene()))  // the generated curves, held while the BVH is built
    fibers = kMaxRenderFiberPoints * kYarnBytesPerPoint + kMaxRenderFibers * kYarnBytesPerFiber;
  return pixels * 108 + 2 * kRenderChunkQueries * 138 + kRenderChunkQueries * (60 + 64) + r.environment().data().size() +
         fibers;
}

std::string ValidateRenderRequest(const v1::RenderRequest& r) {
  if (!v1::ScenePreset_IsValid(r.scene())) return "scene: unknown value " + std::to_string(r.scene());
  if (!std::isfinite(r.texture_scale()) || r.texture_scale() < 0 || r.texture_scale() > kMaxTextureScale)
    return "texture_scale: " + std::to_string(r.texture_scale()) + " is outside 0.." + std::to_string(int(kMaxTextureScale)) +
           " pattern repeats per unit (0 = the scene's default)";
  if (!std::isfinite(r.texture_rotation_deg()) || std::fabs(r.texture_rotation_deg()) > 360)
    return "texture_rotation_deg: " + std::to_string(r.texture_rotation_deg()) + " is not finite within +-360";
  if (r.lights_size() > kMaxRenderLights)
    return "lights: " + std::to_string(r.lights_size()) + " lights exceed the limit of " + std::to_string(kMaxRenderLights);
  for (int i = 0; i < r.lights_size(); ++i)
    if (std::string e = ValidateLight(r.lights(i), Indexed("lights", i)); !e.empty()) return e;
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
    if (IsFiberScene(r.scene())) return "btf_environment: FOLDED is for `btf` materials, not the fiber scenes";
    const bool default_sky = r.lights().empty() && !r.has_environment() &&
                             render::MakeScene(ToSceneKind(r.scene())).default_environment;
    if (!r.has_environment() && !default_sky)
      return "btf_environment: FOLDED folds the environment map, and this request's lighting has none";
  }
  if (!std::isfinite(r.ambient()) || r.ambient() < 0 || r.ambient() > kMaxLightValue)
    return "ambient: " + std::to_string(r.ambient()) + " must be finite in 0.." + std::to_string(kMaxLightValue);
  if (!IsFiberScene(r.scene())) {
    if (r.has_yarn()) return "yarn: only for the fiber scenes (SCENE_YARN, SCENE_WOVEN_PATCH)";
    if (r.fiber_detail() != v1::FIBER_DETAIL_AUTO) return "fiber_detail: only for the fiber scenes";
    if (r.fiber_shadows() != v1::FIBER_SHADOWS_AUTO) return "fiber_shadows: only for the fiber scenes";
    if (r.fiber_occlusion() != v1::FIBER_OCCLUSION_AUTO) return "fiber_occlusion: only for the fiber scenes";
  }
  if (r.has_woven() && r.scene() != v1::SCENE_WOVEN_PATCH) return "woven: only for SCENE_WOVEN_PATCH";
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
  if (!IsFiberScene(request.scene())) return grpc::Status::OK;
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
  if (std::string error = deps.materials->Peek(request->material(), *deps.registry, &model, &material); !error.empty())
    return reject(MaterialError(error));
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
