#include "server/api/service.h"

#include <google/protobuf/io/coded_stream.h>
#include <google/protobuf/io/zero_copy_stream_impl_lite.h>

#include <algorithm>
#include <cmath>

#include "server/models/material.h"

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

grpc::Status ToStatus(const batching::JobResult& r) {
  switch (r.status) {
    case batching::JobStatus::kOk: return grpc::Status::OK;
    case batching::JobStatus::kDeadlineExceeded: return {grpc::StatusCode::DEADLINE_EXCEEDED, r.message};
    case batching::JobStatus::kCancelled: return {grpc::StatusCode::CANCELLED, r.message};
    case batching::JobStatus::kUnavailable: return {grpc::StatusCode::UNAVAILABLE, r.message};
    case batching::JobStatus::kInternal: return {grpc::StatusCode::INTERNAL, r.message};
  }
  return {grpc::StatusCode::INTERNAL, "unknown job status"};
}

double SecondsSince(batching::Clock::time_point t) {
  return std::chrono::duration<double>(batching::Clock::now() - t).count();
}

grpc::Status Invalid(const std::string& message) { return {grpc::StatusCode::INVALID_ARGUMENT, message}; }

}  // namespace

std::string MaterialCache::Get(const v1::Material& material, const models::Registry& registry,
                               std::shared_ptr<const Entry>* out) {
  std::string key;
  {
    google::protobuf::io::StringOutputStream stream(&key);
    google::protobuf::io::CodedOutputStream coded(&stream);
    coded.SetSerializationDeterministic(true);
    material.SerializeToCodedStream(&coded);
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = map_.find(key);
    if (it != map_.end()) {
      order_.splice(order_.begin(), order_, it->second.second);
      *out = it->second.first;
      return "";
    }
  }
  models::ResolvedMaterial resolved;
  std::string error = models::ResolveMaterial(material, registry, &resolved);
  if (!error.empty()) return error;  // bad materials are not cached: they are cheap to reject again
  auto entry = std::make_shared<Entry>();
  entry->model = resolved.model;
  entry->packed = resolved.model->Pack(resolved.values);
  std::lock_guard<std::mutex> lock(mutex_);
  if (map_.find(key) == map_.end()) {
    order_.push_front(key);
    map_[key] = {entry, order_.begin()};
    if (map_.size() > capacity_) {
      map_.erase(order_.back());
      order_.pop_back();
    }
  }
  *out = entry;
  return "";
}

grpc::ServerUnaryReactor* LoomlightService::Reply(grpc::CallbackServerContext* context, const char* rpc,
                                                  batching::Clock::time_point received, grpc::Status status) {
  metrics_->Call(rpc, status.error_code(), SecondsSince(received));
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
  for (const auto& model : registry_->models()) {
    v1::ModelInfo* info = response->add_models();
    info->set_name(model->name());
    info->set_description(model->description());
    info->set_spatially_varying(model->spatially_varying());
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
  return Reply(context, "ListModels", received, grpc::Status::OK);
}

grpc::ServerUnaryReactor* LoomlightService::Evaluate(grpc::CallbackServerContext* context,
                                                     const v1::EvaluateRequest* request,
                                                     v1::EvaluateResponse* response) {
  const auto received = batching::Clock::now();
  std::shared_ptr<const MaterialCache::Entry> material;
  std::string error = materials_.Get(request->material(), *registry_, &material);
  if (!error.empty()) return Reply(context, "Evaluate", received, Invalid(error));
  if (!v1::Precision_IsValid(request->precision()))
    return Reply(context, "Evaluate", received, Invalid("precision: unknown value " + std::to_string(request->precision())));
  const bool fp64 = request->precision() == v1::PRECISION_FP64;
  if (fp64 && !has_fp64_)
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
  if (request->uv_size() > 0) {
    if (!material->model->spatially_varying())
      return Reply(context, "Evaluate", received, Invalid("uv: model '" + material->model->name() +
                                     "' is not spatially varying; send no uv"));
    error = ValidateTextureCoordinates(request->uv(), n, "uv");
    if (!error.empty()) return Reply(context, "Evaluate", received, Invalid(error));
  }

  auto job = std::make_shared<batching::Job>();
  job->model = material->model;
  job->fp64 = fp64;
  job->material = material->packed;
  job->wi = request->wi().data();
  job->wo = request->wo().data();
  job->uv = request->uv_size() > 0 ? request->uv().data() : nullptr;
  job->n = n;
  const auto deadline = context->deadline();
  if (deadline != std::chrono::system_clock::time_point::max())
    job->deadline = received + (deadline - std::chrono::system_clock::now());
  job->cancelled = [context] { return context->IsCancelled(); };
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  Metrics* metrics = metrics_;
  job->done = [reactor, response, received, metrics, n, model = material->model->name(), fp64](batching::JobResult r) {
    if (r.status == batching::JobStatus::kOk) {
      auto* f = response->mutable_f();
      f->Resize(static_cast<int>(r.f.size()), 0.0f);
      std::copy(r.f.begin(), r.f.end(), f->mutable_data());  // double to float: rounded once
      response->set_model(model);
      response->set_precision(fp64 ? v1::PRECISION_FP64 : v1::PRECISION_FP32);
      response->set_queue_seconds(r.queue_seconds);
      response->set_kernel_seconds(r.kernel_seconds);
      response->set_batch_queries(static_cast<uint32_t>(r.batch_queries));
      response->set_batch_requests(static_cast<uint32_t>(r.batch_requests));
      response->set_total_seconds(SecondsSince(received));
      metrics->Evaluated(model, fp64, n, r.batch_queries, r.batch_requests, r.queue_seconds, r.kernel_seconds);
    }
    const grpc::Status status = ToStatus(r);
    metrics->Call("Evaluate", status.error_code(), SecondsSince(received));
    reactor->Finish(status);
  };
  if (!batcher_->Submit(job)) {
    return Reply(context, "Evaluate", received,
                 {grpc::StatusCode::RESOURCE_EXHAUSTED, "evaluation queue is full; retry later"});
  }
  return reactor;
}

}  // namespace loomlight::api
