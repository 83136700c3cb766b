#include "server/api/service.h"

#include <algorithm>
#include <cmath>
#include <mutex>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/render_rpc.h"
#include "server/api/tabulate.h"
#include "server/api/texture_slice.h"
#include "server/models/material.h"
#include "server/models/material_plan.h"

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

void AddParams(const models::ParamValues& values, google::protobuf::RepeatedPtrField<v1::Param>* out) {
  for (const auto& [name, v] : values) {
    v1::Param* p = out->Add();
    p->set_name(name);
    p->mutable_values()->Add(v.begin(), v.end());
  }
}

double SecondsSince(batching::Clock::time_point t) {
  return std::chrono::duration<double>(batching::Clock::now() - t).count();
}

// One Evaluate call: its plan's parts (server/models/material_plan.h) joined into the response when the
// last is done. Parts complete on the batcher's thread; a part that never reaches a kernel (queue full, no
// queries) completes at once.
struct EvaluateCall {
  Admission admission;  // the call's bytes, held until the last part is done
  std::shared_ptr<const models::PreparedMaterial> material;
  std::unique_ptr<models::EvaluationPlan> plan;  // refers to the request's arrays (alive until Finish)
  std::vector<double> f;              // 3 per query
  std::string approximation;          // what the parts' models approximated (EvaluateResponse.approximation)
  grpc::ServerUnaryReactor* reactor = nullptr;
  v1::EvaluateResponse* response = nullptr;
  Metrics* metrics = nullptr;
  batching::Clock::time_point received;
  bool fp64 = false;

  std::mutex mutex;
  size_t remaining = 0;
  batching::JobResult outcome;  // the first failure; the slowest part's timing; the largest launch

  void PartDone(size_t k, batching::JobResult r) {
    if (r.status == batching::JobStatus::kOk && r.f.size() == 3 * plan->size(k)) {
      plan->Merge(k, r.f.data(), f.data());
      if (r.batch_queries > 0)
        metrics->Evaluated(plan->model(k).name(), fp64, plan->size(k), r.batch_queries, r.batch_requests,
                           r.queue_seconds, r.kernel_seconds);
    } else if (r.status == batching::JobStatus::kOk) {
      r.status = batching::JobStatus::kInternal;
      r.message = "kernel returned " + std::to_string(r.f.size()) + " values for " +
                  std::to_string(plan->size(k)) + " queries";
    }
    std::lock_guard<std::mutex> lock(mutex);
    if (r.status != batching::JobStatus::kOk && outcome.status == batching::JobStatus::kOk) {
      outcome.status = r.status;
      outcome.message = r.message;
    }
    outcome.queue_seconds = std::max(outcome.queue_seconds, r.queue_seconds);
    outcome.kernel_seconds = std::max(outcome.kernel_seconds, r.kernel_seconds);
    if (r.batch_queries > outcome.batch_queries) {
      outcome.batch_queries = r.batch_queries;
      outcome.batch_requests = r.batch_requests;
    }
    if (--remaining == 0) Finish();
  }

  void Finish() {
    if (outcome.status == batching::JobStatus::kOk) {
      auto* out = response->mutable_f();
      out->Resize(static_cast<int>(f.size()), 0.0f);
      std::copy(f.begin(), f.end(), out->mutable_data());  // double to float: rounded once
      response->mutable_transmittance()->Add(plan->transmittance().begin(), plan->transmittance().end());
      response->set_model(material->model->name());
      response->set_approximation(approximation);
      response->set_precision(fp64 ? v1::PRECISION_FP64 : v1::PRECISION_FP32);
      response->set_queue_seconds(outcome.queue_seconds);
      response->set_kernel_seconds(outcome.kernel_seconds);
      response->set_batch_queries(static_cast<uint32_t>(outcome.batch_queries));
      response->set_batch_requests(static_cast<uint32_t>(outcome.batch_requests));
      response->set_total_seconds(SecondsSince(received));
    }
    const grpc::Status status = ToStatus(outcome);
    metrics->Call("Evaluate", status.error_code(), SecondsSince(received));
    reactor->Finish(status);
  }
};

}  // namespace

LoomlightService::LoomlightService(const ServiceDeps& deps, const ServiceLimits& limits)
    : deps_(deps), materials_(limits.material_cache_bytes) {
  deps_.materials = &materials_;
  deps_.worker = &worker_;
  deps_.loader = &loader_;
}

grpc::Status LoomlightService::Serving() const {
  if (serving_) return grpc::Status::OK;
  return {grpc::StatusCode::UNAVAILABLE, "the server is not serving (starting up or shutting down); retry"};
}

grpc::ServerUnaryReactor* LoomlightService::Reply(grpc::CallbackServerContext* context, const char* rpc,
                                                  batching::Clock::time_point received, grpc::Status status) {
  deps_.metrics->Call(rpc, status.error_code(), SecondsSince(received));
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  reactor->Finish(std::move(status));
  return reactor;
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

grpc::ServerUnaryReactor* LoomlightService::ListModels(grpc::CallbackServerContext* context,
                                                       const v1::ListModelsRequest*,
                                                       v1::ListModelsResponse* response) {
  const auto received = batching::Clock::now();
  if (grpc::Status s = Serving(); !s.ok()) return Reply(context, "ListModels", received, s);
  for (const auto& model : deps_.registry->models()) {
    v1::ModelInfo* info = response->add_models();
    info->set_name(model->name());
    info->set_description(model->description());
    info->set_spatially_varying(model->spatially_varying());
    info->set_transmission(model->transmission());
    info->set_reciprocal(model->reciprocal());
    info->set_energy_conserving(model->energy_conserving());
    info->set_fiber_axis_param(model->fiber_axis_param());
    if (const models::AccuracyKnob knob = model->accuracy_knob(); !knob.param.empty()) {
      info->mutable_accuracy_knob()->set_param(knob.param);
      info->mutable_accuracy_knob()->mutable_settings()->Add(knob.settings.begin(), knob.settings.end());
      info->mutable_accuracy_knob()->set_error_estimate(knob.error_estimate);
    }
    for (const models::ParamSpec& p : model->params()) {
      v1::ParamSchema* s = info->add_params();
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
  return Reply(context, "ListModels", received, grpc::Status::OK);
}

grpc::ServerUnaryReactor* LoomlightService::Evaluate(grpc::CallbackServerContext* context,
                                                     const v1::EvaluateRequest* request,
                                                     v1::EvaluateResponse* response) {
  const auto received = batching::Clock::now();
  if (grpc::Status s = Serving(); !s.ok()) return Reply(context, "Evaluate", received, s);
  std::shared_ptr<const models::PreparedMaterial> material;
  std::string error = materials_.Get(request->material(), *deps_.registry, &material);
  if (!error.empty()) return Reply(context, "Evaluate", received, Invalid(error));
  if (!v1::Precision_IsValid(request->precision()))
    return Reply(context, "Evaluate", received, Invalid("precision: unknown value " + std::to_string(request->precision())));
  const bool fp64 = request->precision() == v1::PRECISION_FP64;
  if (fp64 && !deps_.has_fp64)
    return Reply(context, "Evaluate", received, {grpc::StatusCode::FAILED_PRECONDITION, "precision: the OpenCL device has no fp64"});
  if (request->wi_size() != request->wo_size())
    return Reply(context, "Evaluate", received, Invalid("wo: length " + std::to_string(request->wo_size()) + " differs from wi length " +
                                   std::to_string(request->wi_size())));
  const size_t n = request->wi_size() / 3;
  if (n > kMaxQueriesPerCall)
    return Reply(context, "Evaluate", received, Invalid("wi: " + std::to_string(n) + " queries exceed the limit of " +
                                   std::to_string(kMaxQueriesPerCall) + " per call"));
  for (const auto& [field, w] : {std::pair{"wi", &request->wi()}, std::pair{"wo", &request->wo()}}) {
    error = ValidateDirections(*w, field);
    if (!error.empty()) return Reply(context, "Evaluate", received, Invalid(error));
  }
  if (!std::isfinite(request->error_target()) || request->error_target() < 0)
    return Reply(context, "Evaluate", received, Invalid("error_target: must be a finite relative error >= 0"));
  if (request->uv_size() > 0) {
    if (!material->model->spatially_varying())
      return Reply(context, "Evaluate", received, Invalid("uv: model '" + material->model->name() +
                                     "' is not spatially varying; send no uv"));
    error = ValidateTextureCoordinates(request->uv(), n, "uv");
    if (!error.empty()) return Reply(context, "Evaluate", received, Invalid(error));
  }

  auto call = std::make_shared<EvaluateCall>();
  if (grpc::Status s = Admit(deps_.memory, nullptr, n * kEvaluateBytesPerQuery, &call->admission); !s.ok())
    return Reply(context, "Evaluate", received, s);
  call->material = material;
  call->f.assign(3 * n, 0.0);
  call->plan = std::make_unique<models::EvaluationPlan>(*material, request->wi().data(), request->wo().data(),
                                                        request->uv_size() > 0 ? request->uv().data() : nullptr, n);
  call->reactor = context->DefaultReactor();
  call->response = response;
  call->metrics = deps_.metrics;
  call->received = received;
  call->fp64 = fp64;
  call->remaining = call->plan->parts();
  const batching::Clock::time_point job_deadline = CallDeadline(context, received);
  const models::EvaluationPlan& plan = *call->plan;
  for (size_t k = 0; k < plan.parts(); ++k) {
    auto job = NewJob(&plan.model(k), plan.packed(k), fp64, job_deadline, context, plan.wi(k), plan.wo(k),
                      plan.uv(k), plan.size(k));
    const std::string approximation = job->model->ChooseApproximation(request->error_target(), &job->material);
    if (!approximation.empty())
      call->approximation += (call->approximation.empty() ? "" : "; ") + approximation;
    job->done = [call, k](batching::JobResult r) { call->PartDone(k, std::move(r)); };
    if (job->n == 0) {
      call->PartDone(k, batching::JobResult{});  // nothing to launch (e.g. a curtain seen only from one side)
    } else if (grpc::Status s = SubmitJob(deps_.batcher, job); !s.ok()) {
      batching::JobResult refused;
      refused.status = s.error_code() == grpc::StatusCode::UNAVAILABLE ? batching::JobStatus::kUnavailable
                                                                      : batching::JobStatus::kResourceExhausted;
      refused.message = s.error_message();
      call->PartDone(k, std::move(refused));
    }
  }
  return call->reactor;
}

grpc::ServerUnaryReactor* LoomlightService::TextureSlice(grpc::CallbackServerContext* context,
                                                         const v1::TextureSliceRequest* request,
                                                         v1::TextureSliceResponse* response) {
  if (grpc::Status s = Serving(); !s.ok()) return Reply(context, "TextureSlice", batching::Clock::now(), s);
  return HandleTextureSlice(deps_, context, request, response);
}

grpc::ServerWriteReactor<v1::TabulateChunk>* LoomlightService::Tabulate(grpc::CallbackServerContext* context,
                                                                        const v1::TabulateRequest* request) {
  if (grpc::Status s = Serving(); !s.ok()) {
    deps_.metrics->Call("Tabulate", s.error_code(), 0);
    return new RejectedStream<v1::TabulateChunk>(s);
  }
  return HandleTabulate(deps_, context, request);
}

grpc::ServerWriteReactor<v1::RenderUpdate>* LoomlightService::Render(grpc::CallbackServerContext* context,
                                                                    const v1::RenderRequest* request) {
  if (grpc::Status s = Serving(); !s.ok()) {
    deps_.metrics->Call("Render", s.error_code(), 0);
    return new RejectedStream<v1::RenderUpdate>(s);
  }
  return HandleRender(deps_, context, request);
}

}  // namespace loomlight::api
