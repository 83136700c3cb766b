#include "server/api/service.h"

#include <cstdio>

#include <algorithm>
#include <cmath>
#include <mutex>

#include "server/api/admission.h"
#include "server/api/btf_rpc.h"
#include "server/api/fit_rpc.h"
#include "server/api/job_status.h"
#include "server/api/mesh_rpc.h"
#include "server/api/render_rpc.h"
#include "server/api/sample_rpc.h"
#include "server/api/tabulate.h"
#include "server/api/texture_slice.h"
#include "server/api/unary_call.h"
#include "server/api/yarn_rpc.h"
#include "server/models/material.h"
#include "server/models/material_plan.h"
#include "server/render/lighting_presets.h"
#include "server/render/scene_registry.h"

namespace loomlight::api {
namespace {

v1::ParamSchema::Type ToProto(models::ParamType t) {
  switch (t) {
    case models::ParamType::kReal: return v1::ParamSchema::TYPE_REAL;
    case models::ParamType::kInt: return v1::ParamSchema::TYPE_INT;
    case models::ParamType::kRgb: return v1::ParamSchema::TYPE_RGB;
    case models::ParamType::kRealList: return v1::ParamSchema::TYPE_REAL_LIST;
    case models::ParamType::kText: return v1::ParamSchema::TYPE_TEXT;
  }
  return v1::ParamSchema::TYPE_UNSPECIFIED;
}

void AddSchema(const std::vector<models::ParamSpec>& params, google::protobuf::RepeatedPtrField<v1::ParamSchema>* out) {
  for (const models::ParamSpec& p : params) {
    v1::ParamSchema* s = out->Add();
    s->set_name(p.name);
    s->set_type(ToProto(p.type));
    s->set_unit(p.unit);
    s->set_min(p.min);
    s->set_max(p.max);
    s->mutable_default_values()->Add(p.defaults.begin(), p.defaults.end());
    s->set_description(p.description);
    s->set_min_count(p.min_count);
    s->set_max_count(p.max_count);
  }
}

void SetTriple(render::Vec3 v, google::protobuf::RepeatedField<double>* out) {
  out->Clear();
  out->Add(v.x);
  out->Add(v.y);
  out->Add(v.z);
}

void ToProto(const render::Light& l, v1::RenderLight* light) {
  switch (l.type) {
    case render::Light::Type::kPoint:
      light->set_type(v1::RenderLight::TYPE_POINT);
      SetTriple(l.position, light->mutable_position());
      break;
    case render::Light::Type::kRect:
      light->set_type(v1::RenderLight::TYPE_RECT);
      SetTriple(l.position, light->mutable_position());
      SetTriple(l.direction, light->mutable_direction());
      light->add_size(l.width);
      light->add_size(l.height);
      SetTriple(l.axis_v, light->mutable_up());
      break;
    case render::Light::Type::kDirectional:
      light->set_type(v1::RenderLight::TYPE_DIRECTIONAL);
      SetTriple(l.direction, light->mutable_direction());
      break;
  }
  SetTriple(l.rgb, light->mutable_rgb());
}

// A lighting preset as ListScenes describes it: its softboxes placed around a sphere of radius 1 at the origin,
// seen from +z (the camera at (0, 0, 4) looking at the origin, +y up).
void DescribeLightingPreset(const render::LightingPreset& preset, v1::LightingPreset* info) {
  info->set_name(std::string(preset.name));
  info->set_description(std::string(preset.description));
  const render::CameraSpec camera{{0, 0, 4}, {0, 0, 0}};
  for (const render::Light& l : render::PlaceLights(preset, {0, 0, 0}, 1, camera)) ToProto(l, info->add_lights());
  info->set_environment(preset.environment_intensity > 0);
}

// A registered scene as ListScenes describes it: its declarations, and its camera and lighting at its defaults.
void DescribeScene(const render::SceneSpec& spec, v1::SceneInfo* info) {
  const render::Scene scene = spec.build(models::DefaultValues(spec.params));
  info->set_name(spec.name);
  // A scene without a ScenePreset value leaves `preset` absent (has_preset() false; the enum's 0 is SCENE_SPHERE):
  // such a scene is named by scene_name only.
  if (spec.preset != render::SceneSpec::kNoPreset) info->set_preset(static_cast<v1::ScenePreset>(spec.preset));
  info->set_description(spec.description);
  AddSchema(spec.params, info->mutable_params());
  v1::RenderCamera* camera = info->mutable_default_camera();
  SetTriple(scene.default_camera.position, camera->mutable_position());
  SetTriple(scene.default_camera.look_at, camera->mutable_look_at());
  SetTriple(scene.default_camera.up, camera->mutable_up());
  camera->set_fov_deg(scene.default_camera.fov_deg);
  for (const render::Light& l : scene.default_lights) ToProto(l, info->add_default_lights());
  info->set_default_environment(scene.default_environment);
  info->set_default_texture_scale(scene.default_texture_scale);
  for (const render::SceneObject& object : scene.objects) info->add_objects(object.name);
  info->set_needs_uv(spec.needs.uv);
  info->set_shows_transmission(spec.needs.transmission);
  info->set_fibers(spec.needs.fibers);
}

void AddParams(const models::ParamValues& values, google::protobuf::RepeatedPtrField<v1::Param>* out) {
  for (const auto& [name, v] : values) {
    v1::Param* p = out->Add();
    p->set_name(name);
    p->mutable_values()->Add(v.begin(), v.end());
  }
}

// One Evaluate call (server/api/unary_call.h). Start (inline on the gRPC thread for a small request of a cached
// material, else on the preparer) checks what needs the material, builds the plan (server/models/material_plan.h)
// and submits one job per part; the kernels write f straight into the response (float; fp64 kernels are rounded
// there once); Complete adds the direct transmittance and finishes.
struct EvaluateCall : PlanCall<v1::EvaluateRequest, v1::EvaluateResponse> {
  using PlanCall::PlanCall;

  // `material` may be null (not cached, or an error target to resolve): it is prepared here.
  static void Start(const std::shared_ptr<EvaluateCall>& call) {
    const v1::EvaluateRequest& request = *call->request;
    if (!call->material || request.error_target() > 0) {
      std::string error = call->deps->materials->GetWithin(request.material(), *call->deps->registry,
                                                            request.error_target(), &call->material,
                                                            &call->approximation);
      if (!error.empty()) return call->Finish(MaterialError(error));
    } else {
      call->approximation = call->material->own_settings;
    }
    if (std::string error = CheckEvaluateQueries(request, *call->material->model, call->material->transmission != nullptr);
        !error.empty())
      return call->Finish(Invalid(error));
    const bool ambient = request.quantity() == v1::QUANTITY_AMBIENT;
    const size_t n = request.wo_size() / 3;
    call->response->mutable_f()->Resize(static_cast<int>(3 * n), 0.0f);
    call->plan = std::make_unique<models::EvaluationPlan>(
        *call->material, request.wi().data(), request.wo().data(), request.uv_size() > 0 ? request.uv().data() : nullptr,
        n, request.fiber_axis_size() > 0 ? request.fiber_axis().data() : nullptr,
        ambient ? models::Quantity::kAmbient : models::Quantity::kScattering);
    SubmitParts(call, call->response->mutable_f()->mutable_data(), n <= kInlineEvaluateQueries, &EvaluateCall::Complete);
  }

  void Complete() {
    response->mutable_transmittance()->Add(plan->transmittance().begin(), plan->transmittance().end());
    Finish(grpc::Status::OK);
  }
};

}  // namespace

LoomlightService::LoomlightService(const ServiceDeps& deps, const ServiceLimits& limits)
    : deps_(deps),
      materials_(limits.material_cache_bytes),
      folds_(limits.fold_cache_bytes),
      fiber_scenes_(std::make_unique<yarn::FiberSceneCache>(limits.fiber_cache_bytes)),
      client_long_calls_(limits.max_long_calls_per_client),
      idle_uploads_(limits.upload_idle_timeout) {
  deps_.materials = &materials_;
  materials_.ChargeParsesTo(deps_.memory);  // a WIF draft's parse holds up to its size + 1 MiB
  deps_.folds = &folds_;
  deps_.fiber_scenes = fiber_scenes_.get();
  deps_.idle_uploads = &idle_uploads_;
  deps_.max_upload_duration = limits.upload_max_duration;
  deps_.client_long_calls = &client_long_calls_;
  deps_.worker = &worker_;
  deps_.loader = &loader_;
  deps_.geometry = &geometry_;
  deps_.preparer = &preparer_;
}

LoomlightService::~LoomlightService() = default;

void LoomlightService::SyncBtfAssets() {
  if ((!deps_.btf_store && !deps_.mesh_store) || sync_queued_.exchange(true)) return;
  loader_.Post([this] {
    sync_queued_ = false;
    const auto log = [this](const std::string& line) {
      loader_.Progress();  // a line per asset loaded, failed or removed: one bounded step each
      std::fprintf(stderr, "loomlight-server: %s\n", line.c_str());
    };
    if (deps_.mesh_store) deps_.mesh_store->Sync(log);  // parsed again on first use: no cache to empty
    if (!deps_.btf_store) return;
    const int changes = deps_.btf_store->Sync(log);
    if (changes == 0) return;
    materials_.Clear();  // no material may keep a replaced or deleted asset's packing
    folds_.Clear();
  });
}

grpc::Status LoomlightService::Serving() const {
  if (serving_) return grpc::Status::OK;
  return {grpc::StatusCode::UNAVAILABLE, "the server is not serving (starting up or shutting down); retry"};
}

grpc::Status AdmitLongCall(const ServiceDeps& deps, const grpc::ServerContextBase& context, size_t bytes,
                           Admission* out) {
  // The key is the caller's own name or address (a proxy's client: as the proxy forwarded it), cut short.
  const std::string client = FairShareKey(context, *deps.trusted_proxies);
  if (!deps.client_long_calls->TryTake(client, &out->client_slot))
    return {grpc::StatusCode::RESOURCE_EXHAUSTED,
            "this client (" + client.substr(0, 80) + ") is running its limit of " +
                std::to_string(deps.client_long_calls->per_client()) +
                " long-running calls (TextureSlice, Tabulate, Render, YarnGeometry) at once; retry when one ends"};
  return Admit(deps.memory, deps.long_calls, bytes, out, client);
}

grpc::Status PrepareMaterial(const ServiceDeps& deps, const v1::Material& material,
                             std::shared_ptr<const models::PreparedMaterial>* out) {
  if (std::string error = deps.materials->Get(material, *deps.registry, out); !error.empty())
    return MaterialError(error);
  return grpc::Status::OK;
}

grpc::Status CheckPrecision(int precision, bool has_fp64) {
  if (!v1::Precision_IsValid(precision)) return Invalid("precision: unknown value " + std::to_string(precision));
  if (precision == v1::PRECISION_FP64 && !has_fp64)
    return {grpc::StatusCode::FAILED_PRECONDITION, "precision: the OpenCL device has no fp64"};
  return grpc::Status::OK;
}

grpc::Status CheckQueriesAndTarget(size_t n, const std::string& count_field, double error_target) {
  if (n > kMaxQueriesPerCall)
    return Invalid(count_field + ": " + std::to_string(n) + " queries exceed the limit of " +
                   std::to_string(kMaxQueriesPerCall) + " per call");
  if (!std::isfinite(error_target) || error_target < 0)
    return Invalid("error_target: must be a finite relative error >= 0");
  return grpc::Status::OK;
}

std::string ValidateDirections(const google::protobuf::RepeatedField<float>& w, const std::string& field) {
  if (w.size() % 3 != 0)
    return field + ": length " + std::to_string(w.size()) + " is not a multiple of 3 (packed xyz triples)";
  auto at = [&](int q) { return field + "[" + std::to_string(q) + "]"; };  // only built for the error
  for (int q = 0; q < w.size() / 3; ++q) {
    const double x = w[3 * q], y = w[3 * q + 1], z = w[3 * q + 2];
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) return at(q) + ": direction is not finite";
    const double len = std::sqrt(x * x + y * y + z * z);
    if (std::fabs(len - 1.0) > kUnitTolerance)
      return at(q) + ": direction has length " + std::to_string(len) + ", not unit (tolerance " +
             std::to_string(kUnitTolerance) + ")";
  }
  return "";
}

std::string ValidateTextureCoordinates(const google::protobuf::RepeatedField<float>& uv, size_t n,
                                       const std::string& field) {
  if (static_cast<size_t>(uv.size()) != 2 * n)
    return field + ": length " + std::to_string(uv.size()) + " is not 2 per query (" + std::to_string(2 * n) +
           " for " + std::to_string(n) + " queries)";
  for (int i = 0; i < uv.size(); ++i)
    if (!std::isfinite(uv[i]) || std::fabs(uv[i]) > kMaxTextureCoordinate)
      return field + "[" + std::to_string(i) + "]: " + std::to_string(uv[i]) + " is not finite within +-" +
             std::to_string(static_cast<int>(kMaxTextureCoordinate)) + " pattern repeats";
  return "";
}

grpc::Status CheckEvaluateRequest(const v1::EvaluateRequest& request, bool has_fp64) {
  if (grpc::Status s = CheckPrecision(request.precision(), has_fp64); !s.ok()) return s;
  if (!v1::Quantity_IsValid(request.quantity()))
    return Invalid("quantity: unknown value " + std::to_string(request.quantity()));
  const bool ambient = request.quantity() == v1::QUANTITY_AMBIENT;
  if (ambient && request.wi_size() > 0)
    return Invalid("wi: the ambient factor depends on wo only; send no wi with quantity AMBIENT");
  if (ambient && request.uv_size() > 0)
    return Invalid("uv: the ambient factor takes no texture coordinates; send no uv with quantity AMBIENT");
  if (!ambient && request.wi_size() != request.wo_size())
    return Invalid("wo: length " + std::to_string(request.wo_size()) + " differs from wi length " +
                   std::to_string(request.wi_size()));
  return CheckQueriesAndTarget(request.wo_size() / 3, "wi", request.error_target());
}

std::string CheckEvaluateQueries(const v1::EvaluateRequest& request, const models::Model& model, bool has_layer) {
  const size_t n = request.wo_size() / 3;
  for (const auto& [field, w] : {std::pair{"wi", &request.wi()}, std::pair{"wo", &request.wo()}})
    if (std::string error = ValidateDirections(*w, field); !error.empty()) return error;
  if (request.quantity() == v1::QUANTITY_AMBIENT) {
    if (!model.has_ambient()) return "quantity: model '" + model.name() + "' has no ambient factor (ModelInfo.ambient)";
    if (has_layer) return "quantity: the ambient factor is not served with material.transmission";
  }
  if (request.uv_size() > 0) {
    if (!model.spatially_varying()) return "uv: model '" + model.name() + "' is not spatially varying; send no uv";
    if (std::string error = ValidateTextureCoordinates(request.uv(), n, "uv"); !error.empty()) return error;
  }
  if (request.fiber_axis_size() > 0) {
    if (model.fiber_axis_param().empty())
      return "fiber_axis: model '" + model.name() + "' is not a fiber model; send no fiber_axis";
    if (has_layer) return "fiber_axis: not with material.transmission (a fiber is not a curtain)";
    if (request.fiber_axis_size() != request.wo_size())
      return "fiber_axis: length " + std::to_string(request.fiber_axis_size()) + " differs from wo length " +
             std::to_string(request.wo_size());
    if (std::string error = ValidateDirections(request.fiber_axis(), "fiber_axis"); !error.empty()) return error;
  }
  return "";
}

grpc::ServerUnaryReactor* LoomlightService::ListModels(grpc::CallbackServerContext* context,
                                                       const v1::ListModelsRequest*,
                                                       v1::ListModelsResponse* response) {
  const auto received = batching::Clock::now();
  if (grpc::Status s = Serving(); !s.ok()) return AnswerNow(deps_.metrics, context, "ListModels", received, s);
  for (const auto& model : deps_.registry->models()) {
    v1::ModelInfo* info = response->add_models();
    info->set_name(model->name());
    info->set_description(model->description());
    info->set_spatially_varying(model->spatially_varying());
    info->set_transmission(model->transmission());
    info->set_reciprocal(model->reciprocal());
    info->set_energy_conserving(model->energy_conserving());
    info->set_fiber_axis_param(model->fiber_axis_param());
    info->set_ambient(model->has_ambient());
    if (const models::AccuracyKnob knob = model->accuracy_knob(); !knob.param.empty()) {
      info->mutable_accuracy_knob()->set_param(knob.param);
      info->mutable_accuracy_knob()->mutable_settings()->Add(knob.settings.begin(), knob.settings.end());
      info->mutable_accuracy_knob()->set_error_estimate(knob.error_estimate);
    }
    AddSchema(model->params(), info->mutable_params());
    for (const models::PresetSpec& preset : model->presets()) {
      v1::Preset* out = info->add_presets();
      out->set_name(preset.name);
      out->set_description(preset.description);
      AddParams(model->PresetValues(preset), out->mutable_params());
    }
  }
  response->set_max_queries_per_call(kMaxQueriesPerCall);
  response->set_unit_tolerance(kUnitTolerance);
  for (const std::string& name : deps_.environments->Names()) response->add_environment_maps(name);
  DescribeYarnModel(response->mutable_yarn());
  return AnswerNow(deps_.metrics, context, "ListModels", received, grpc::Status::OK);
}

grpc::ServerUnaryReactor* LoomlightService::ListScenes(grpc::CallbackServerContext* context,
                                                       const v1::ListScenesRequest*,
                                                       v1::ListScenesResponse* response) {
  const auto received = batching::Clock::now();
  if (grpc::Status s = Serving(); !s.ok()) return AnswerNow(deps_.metrics, context, "ListScenes", received, s);
  for (const render::SceneSpec& spec : render::SceneRegistry::Global().scenes()) DescribeScene(spec, response->add_scenes());
  for (const render::LightingPreset& preset : render::LightingPresets())
    DescribeLightingPreset(preset, response->add_lighting_presets());
  return AnswerNow(deps_.metrics, context, "ListScenes", received, grpc::Status::OK);
}

grpc::ServerUnaryReactor* LoomlightService::Evaluate(grpc::CallbackServerContext* context,
                                                     const v1::EvaluateRequest* request,
                                                     v1::EvaluateResponse* response) {
  const auto received = batching::Clock::now();
  const auto reject = [&](const grpc::Status& status) {
    return AnswerNow(deps_.metrics, context, "Evaluate", received, status);
  };
  if (grpc::Status s = Serving(); !s.ok()) return reject(s);
  if (grpc::Status s = CheckEvaluateRequest(*request, deps_.has_fp64); !s.ok()) return reject(s);
  const size_t n = request->wo_size() / 3;

  auto call = std::make_shared<EvaluateCall>(deps_, "Evaluate", context, request, response, received,
                                             request->precision() == v1::PRECISION_FP64);
  if (grpc::Status s = Admit(deps_.memory, nullptr, n * kEvaluateBytesPerQuery, &call->admission, call->client);
      !s.ok())
    return reject(s);
  // A small request of a cached material starts here; packing, knob errors and large requests' validation
  // and planning go to the preparer, off gRPC's threads.
  if (n <= kInlineEvaluateQueries && request->error_target() == 0 &&
      materials_.Find(request->material(), &call->material))
    EvaluateCall::Start(call);
  else
    preparer_.Post([call] { EvaluateCall::Start(call); }, call->client);
  return call->reactor;
}

grpc::ServerUnaryReactor* LoomlightService::TextureSlice(grpc::CallbackServerContext* context,
                                                         const v1::TextureSliceRequest* request,
                                                         v1::TextureSliceResponse* response) {
  if (grpc::Status s = Serving(); !s.ok()) return AnswerNow(deps_.metrics, context, "TextureSlice", batching::Clock::now(), s);
  return HandleTextureSlice(deps_, context, request, response);
}

grpc::ServerWriteReactor<v1::TabulateChunk>* LoomlightService::Tabulate(grpc::CallbackServerContext* context,
                                                                        const v1::TabulateRequest* request) {
  if (grpc::Status s = Serving(); !s.ok())
    return new RejectedStream<v1::TabulateChunk>(deps_.metrics, "Tabulate", batching::Clock::now(), s);
  return HandleTabulate(deps_, context, request);
}

grpc::ServerWriteReactor<v1::RenderUpdate>* LoomlightService::Render(grpc::CallbackServerContext* context,
                                                                    const v1::RenderRequest* request) {
  if (grpc::Status s = Serving(); !s.ok())
    return new RejectedStream<v1::RenderUpdate>(deps_.metrics, "Render", batching::Clock::now(), s);
  return HandleRender(deps_, context, request);
}

grpc::ServerWriteReactor<v1::YarnGeometryChunk>* LoomlightService::YarnGeometry(grpc::CallbackServerContext* context,
                                                                               const v1::YarnGeometryRequest* request) {
  if (grpc::Status s = Serving(); !s.ok())
    return new RejectedStream<v1::YarnGeometryChunk>(deps_.metrics, "YarnGeometry", batching::Clock::now(), s);
  return HandleYarnGeometry(deps_, context, request);
}

grpc::ServerUnaryReactor* LoomlightService::Sample(grpc::CallbackServerContext* context,
                                                   const v1::SampleRequest* request, v1::SampleResponse* response) {
  if (grpc::Status s = Serving(); !s.ok()) return AnswerNow(deps_.metrics, context, "Sample", batching::Clock::now(), s);
  return HandleSample(deps_, context, request, response);
}

grpc::ServerUnaryReactor* LoomlightService::FitMaterial(grpc::CallbackServerContext* context,
                                                        const v1::FitMaterialRequest* request,
                                                        v1::FitMaterialResponse* response) {
  if (grpc::Status s = Serving(); !s.ok())
    return AnswerNow(deps_.metrics, context, "FitMaterial", batching::Clock::now(), s);
  return HandleFitMaterial(deps_, context, request, response);
}

grpc::ServerWriteReactor<v1::CreateBtfProgress>* LoomlightService::CreateBtf(grpc::CallbackServerContext* context,
                                                                            const v1::CreateBtfRequest* request) {
  if (grpc::Status s = Serving(); !s.ok())
    return new RejectedStream<v1::CreateBtfProgress>(deps_.metrics, "CreateBtf", batching::Clock::now(), s);
  return HandleCreateBtf(deps_, context, request);
}

grpc::ServerReadReactor<v1::UploadBtfMessage>* LoomlightService::UploadBtf(grpc::CallbackServerContext* context,
                                                                           v1::BtfAssetInfo* response) {
  return HandleUploadBtf(deps_, context, response, Serving());
}

grpc::ServerUnaryReactor* LoomlightService::ListBtfs(grpc::CallbackServerContext* context,
                                                     const v1::ListBtfsRequest*, v1::ListBtfsResponse* response) {
  const auto received = batching::Clock::now();
  grpc::Status s = Serving();
  if (s.ok()) s = HandleListBtfs(deps_, response);
  return AnswerNow(deps_.metrics, context, "ListBtfs", received, s);
}

grpc::ServerUnaryReactor* LoomlightService::DeleteBtf(grpc::CallbackServerContext* context,
                                                      const v1::DeleteBtfRequest* request, v1::DeleteBtfResponse*) {
  const auto received = batching::Clock::now();
  grpc::Status s = Serving();
  if (s.ok()) s = HandleDeleteBtf(deps_, *context, *request);
  return AnswerNow(deps_.metrics, context, "DeleteBtf", received, s);
}

grpc::ServerReadReactor<v1::UploadMeshMessage>* LoomlightService::UploadMesh(grpc::CallbackServerContext* context,
                                                                             v1::MeshInfo* response) {
  return HandleUploadMesh(deps_, context, response, Serving());
}

grpc::ServerUnaryReactor* LoomlightService::ListMeshes(grpc::CallbackServerContext* context,
                                                       const v1::ListMeshesRequest*, v1::ListMeshesResponse* response) {
  const auto received = batching::Clock::now();
  grpc::Status s = Serving();
  if (s.ok()) s = HandleListMeshes(deps_, response);
  return AnswerNow(deps_.metrics, context, "ListMeshes", received, s);
}

grpc::ServerUnaryReactor* LoomlightService::DeleteMesh(grpc::CallbackServerContext* context,
                                                       const v1::DeleteMeshRequest* request, v1::DeleteMeshResponse*) {
  const auto received = batching::Clock::now();
  grpc::Status s = Serving();
  if (s.ok()) s = HandleDeleteMesh(deps_, *context, *request);
  return AnswerNow(deps_.metrics, context, "DeleteMesh", received, s);
}

}  // namespace loomlight::api
