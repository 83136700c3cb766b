#include "server/api/render_rpc.h"

#include <cmath>
#include <memory>
#include <vector>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/stream_call.h"
#include "server/imaging/image_encode.h"
#include "server/models/material.h"
#include "server/render/adaptive_sampling.h"
#include "server/render/renderer.h"
#include "server/render/scene_registry.h"
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

// The registered scene a validated request names (scene_name, else scene) at its scene_params.
render::ResolvedScene ResolvedSceneOf(const v1::RenderRequest& r) {
  render::ResolvedScene scene;
  render::ResolveScene(r, render::SceneRegistry::Global(), &scene);
  return scene;
}

// What the request's scene needs (nothing for a scene the registry does not know: validation refuses it).
render::SceneNeeds NeedsOf(const v1::RenderRequest& r) {
  const render::ResolvedScene scene = ResolvedSceneOf(r);
  return scene.spec ? scene.spec->needs : render::SceneNeeds{};
}

// The request's scene (a fiber scene's fibers are generated and built separately).
render::Scene SceneOf(const v1::RenderRequest& r) { return ResolvedSceneOf(r).Build(); }

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
  const bool woven_layout = NeedsOf(r).woven;
  if (woven_layout) {
    if (!woven.has_weave()) woven.mutable_weave()->set_preset("cotton_twill");
    if (woven.repeats_u() == 0) woven.set_repeats_u(2);
    if (woven.repeats_v() == 0) woven.set_repeats_v(2);
  }
  job->limits.max_fibers = static_cast<int64_t>(kMaxRenderFibers);
  job->limits.max_control_points = static_cast<int64_t>(kMaxRenderFiberPoints);
  return YarnJobOf(registry, r.yarn(), woven_layout ? &woven : nullptr, 0, job);
}

// Eq. 4's level of detail for a fiber scene: from the pixel footprint at the camera's look-at point (AUTO, LOD),
// or as the request says. Sets job->detail and the fidelity report's entry; *check says whether the choice is
// AUTO's thinning, which the fidelity chooser compares with full detail before the render keeps it.
void ChooseFiberDetail(const v1::RenderRequest& r, YarnJob* job, render::RenderSetup::FiberDetail* report,
                       bool* check) {
  *check = false;
  const render::Scene scene = SceneOf(r);
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

// The renderer's inputs from a validated request: its scene (fibers as generated), camera, lights, environment
// (`map`: the loaded one; null: the built-in sky), texture and sampling; the material is the caller's.
render::RenderInputs RenderInputsOf(const v1::RenderRequest& r, std::shared_ptr<const render::Environment> map) {
  render::RenderInputs in;
  render::RenderSetup& s = in.setup;
  s.scene = SceneOf(r);
  s.fiber_shadows = r.fiber_shadows() == v1::FIBER_SHADOWS_SLICES ? yarn::ShadowMethod::kSlices : yarn::ShadowMethod::kTraced;
  s.fiber_occlusion = r.fiber_occlusion() == v1::FIBER_OCCLUSION_TEXTURE    ? yarn::OcclusionMethod::kTexture
                      : r.fiber_occlusion() == v1::FIBER_OCCLUSION_DISTANCE ? yarn::OcclusionMethod::kDistance
                                                                            : yarn::OcclusionMethod::kTraced;
  s.choose_fiber_shadows = r.fiber_shadows() == v1::FIBER_SHADOWS_AUTO;
  s.choose_fiber_occlusion = r.fiber_occlusion() == v1::FIBER_OCCLUSION_AUTO;
  in.views.push_back({CameraOf(r, s.scene), static_cast<int>(r.width()), static_cast<int>(r.height())});
  s.samples_per_pixel = SamplesPerPixel(r);
  s.seed = r.seed();
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
    auto environment = std::make_shared<render::Environment>(map ? *map : render::Environment::Builtin());
    const double intensity = default_lighting ? s.scene.default_environment_intensity
                             : r.environment().intensity() > 0 ? r.environment().intensity() : 1.0;
    environment->SetTransform(intensity, r.has_environment() ? r.environment().rotation_deg() : 0.0);
    s.environment = std::move(environment);
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

  // The renderer, given the request's inputs, plans; its builds (a fold, material samplers) run on the asset
  // loader (not on the host worker every streaming call shares), then it renders. On failure status_ says why.
  void SetUp() {
    const v1::RenderRequest& r = request_;
    render::RenderInputs in = RenderInputsOf(r, std::move(environment_));
    in.setup.scene.fibers = std::move(fibers_);
    in.setup.scene.fiber_visibility = std::move(fiber_visibility_);
    // Held only by the renderer from here: it lets go of the full-detail check's geometry once planned.
    in.setup.full_detail_fibers = std::move(full_fibers_);
    in.setup.full_detail_visibility = std::move(full_fiber_visibility_);
    if (!material_ && !(status_ = PrepareMaterial(deps_, r.material(), &material_)).ok()) return;
    if (fiber_job_) {
      in.setup.fiber_detail = fiber_detail_;
      in.setup.fiber_detail.reason +=
          "; " + std::to_string(in.setup.scene.fibers->stats().curves) + " fiber curves";
    }
    in.material = material_;
    in.variants = std::make_unique<render::CachedVariants>(r.material(), *deps_.registry, *deps_.materials);
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

  void Encode() {
    const render::RenderedImage& rendered = renderer_->images().front();
    const imaging::ImageFormat format = request_.format() == v1::RENDER_FORMAT_EXR    ? imaging::ImageFormat::kExr
                                        : request_.format() == v1::RENDER_FORMAT_JPEG ? imaging::ImageFormat::kJpeg
                                                                                      : imaging::ImageFormat::kPng;
    double exposure = 1;
    std::string bytes;
    if (std::string error = render::EncodeRendered(rendered.image, format, request_.exposure(), &bytes, &exposure);
        !error.empty()) {
      status_ = {grpc::StatusCode::INTERNAL, "cannot encode the image: " + error};
      return;
    }
    final_.set_image(std::move(bytes));
    final_.set_format(request_.format());
    final_.set_width(request_.width());
    final_.set_height(request_.height());
    final_.set_exposure(exposure);
    for (double m : rendered.mean) final_.add_mean(m);
    final_.set_adaptive_sampling(rendered.adaptive);
    final_.set_min_samples_per_pixel(rendered.min_samples_per_pixel);
    final_.set_max_samples_per_pixel(rendered.max_samples_per_pixel);
    complete_ = true;
  }

  void AddFidelity(v1::RenderUpdate* update) const {
    update->set_error_target(renderer_->error_target());
    for (const render::ObjectFidelity& of : renderer_->fidelity()) {
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
  return pixels * 108 + 2 * render::kRenderChunkQueries * 138 + render::kRenderChunkQueries * (60 + 64) +
         r.environment().data().size() + fibers;
}

std::string ValidateRenderRequest(const v1::RenderRequest& r) {
  render::ResolvedScene scene;
  if (std::string e = render::ResolveScene(r, render::SceneRegistry::Global(), &scene); !e.empty()) return e;
  const render::SceneNeeds& needs = scene.spec->needs;
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
    if (needs.fibers) return "btf_environment: FOLDED is for `btf` materials, not the fiber scenes";
    const bool default_sky = r.lights().empty() && !r.has_environment() && scene.Build().default_environment;
    if (!r.has_environment() && !default_sky)
      return "btf_environment: FOLDED folds the environment map, and this request's lighting has none";
  }
  if (!std::isfinite(r.ambient()) || r.ambient() < 0 || r.ambient() > kMaxLightValue)
    return "ambient: " + std::to_string(r.ambient()) + " must be finite in 0.." + std::to_string(kMaxLightValue);
  if (!needs.fibers) {
    if (r.has_yarn()) return "yarn: only for the fiber scenes (ListScenes: fibers), not '" + scene.spec->name + "'";
    if (r.fiber_detail() != v1::FIBER_DETAIL_AUTO) return "fiber_detail: only for the fiber scenes";
    if (r.fiber_shadows() != v1::FIBER_SHADOWS_AUTO) return "fiber_shadows: only for the fiber scenes";
    if (r.fiber_occlusion() != v1::FIBER_OCCLUSION_AUTO) return "fiber_occlusion: only for the fiber scenes";
  }
  if (r.has_woven() && !needs.woven)
    return "woven: only for the fiber scenes laid out as a weave, not '" + scene.spec->name + "'";
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
