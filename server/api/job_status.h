// Batcher jobs for the RPCs: building one for a call, and the gRPC status of its outcome.
#pragma once

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "server/api/access.h"
#include "server/api/admission.h"
#include "server/batching/batcher.h"
#include "server/models/material_cache.h"
#include "server/models/material_plan.h"

namespace loomlight::api {

// The call's gRPC deadline on the batcher's steady clock, measured from `received` (max when none).
inline batching::Clock::time_point CallDeadline(grpc::CallbackServerContext* context,
                                                batching::Clock::time_point received) {
  const auto deadline = context->deadline();
  if (deadline == std::chrono::system_clock::time_point::max()) return batching::Clock::time_point::max();
  return received + (deadline - std::chrono::system_clock::now());
}

inline double SecondsSince(batching::Clock::time_point t) {
  return std::chrono::duration<double>(batching::Clock::now() - t).count();
}

// Why a call's work should stop now, or OK: its deadline passed, or the client cancelled or went away
// (`stream_broken`: a write failed). A cancellation that arrives within batching::kDeadlineSlack of the
// deadline is the deadline (the client's own timer cancels first), so it is counted as DEADLINE_EXCEEDED.
inline grpc::Status StopStatus(grpc::CallbackServerContext* context, batching::Clock::time_point deadline,
                               bool stream_broken = false) {
  const auto now = batching::Clock::now();
  if (now >= deadline) return {grpc::StatusCode::DEADLINE_EXCEEDED, "deadline passed"};
  if (!stream_broken && !context->IsCancelled()) return grpc::Status::OK;
  if (now + batching::kDeadlineSlack >= deadline) return {grpc::StatusCode::DEADLINE_EXCEEDED, "deadline passed"};
  return {grpc::StatusCode::CANCELLED, "call cancelled"};
}

// A job evaluating n queries (uv nullptr: f(wi, wo)) of one packed material into `sink` for `client` (the call's
// FairShareKey), stopped before launch by the call's deadline or cancellation; the caller sets `done`. The
// material, the arrays and the sink's buffers must outlive the job.
inline std::shared_ptr<batching::Job> NewJob(const models::Model* model, const models::PackedMaterial& material,
                                             bool fp64, batching::Clock::time_point deadline,
                                             grpc::CallbackServerContext* context, const std::string& client,
                                             const float* wi, const float* wo, const float* uv, size_t n,
                                             const runtime::ResultSink& sink) {
  auto job = std::make_shared<batching::Job>();
  job->model = model;
  job->fp64 = fp64;
  job->material = &material;
  job->sink = sink;
  job->wi = wi;
  job->wo = wo;
  job->uv = uv;
  job->n = n;
  job->deadline = deadline;
  job->cancelled = [context] { return context->IsCancelled(); };
  job->client = client;
  return job;
}

// Every RPC's kernel work goes through here: one job per part of a material plan (a curtain's reflection and
// layer, or the material alone), part k writing its results straight into `sink`'s buffer (3 per plan query,
// through the plan's slots and scale). done(k, result) is called exactly once per part: when its job returns
// (on the batcher's thread, or on this one when the batcher launches it at once), at once with an OK result and
// no launch for an empty part, or at once with the refusal (kUnavailable while the batcher stops, else
// kResourceExhausted) for a part that could not be queued, and for every part after it.
inline void SubmitPlan(batching::Batcher* batcher, const models::EvaluationPlan& plan, const runtime::ResultSink& sink,
                       bool fp64, batching::Priority priority, batching::Clock::time_point deadline,
                       grpc::CallbackServerContext* context, const std::string& client,
                       const std::function<void(size_t part, batching::JobResult)>& done) {
  batching::JobResult refused;
  for (size_t k = 0; k < plan.parts(); ++k) {
    if (refused.status != batching::JobStatus::kOk) {
      done(k, refused);
      continue;
    }
    if (plan.size(k) == 0) {
      done(k, batching::JobResult{});
      continue;
    }
    runtime::ResultSink part_sink = sink;
    part_sink.slot = plan.slots(k);
    part_sink.scale = plan.scale(k);
    auto job = NewJob(&plan.model(k), plan.packed(k), fp64, deadline, context, client, plan.wi(k), plan.wo(k),
                      plan.uv(k), plan.size(k), part_sink);
    job->quantity = plan.quantity();
    job->priority = priority;
    job->done = [done, k](batching::JobResult r) { done(k, std::move(r)); };
    if (grpc::Status s = SubmitJob(batcher, std::move(job)); !s.ok()) {
      refused.status = s.error_code() == grpc::StatusCode::UNAVAILABLE ? batching::JobStatus::kUnavailable
                                                                      : batching::JobStatus::kResourceExhausted;
      refused.message = s.error_message();
      done(k, refused);
    }
  }
}

// The most bytes of an INVALID_ARGUMENT status message. Messages quote client input only truncated
// (models::Quote), so a longer one is a bug; this is the last guard: a status message travels in the HTTP/2
// trailers, and one over the client's header limit (about 8 KB) reaches it as RESOURCE_EXHAUSTED instead.
inline constexpr size_t kMaxStatusMessageBytes = 1024;

// An INVALID_ARGUMENT status; a message over kMaxStatusMessageBytes is cut on a UTF-8 character boundary and
// ends with " … (message cut from N bytes)", the whole at most kMaxStatusMessageBytes. Every RPC's
// INVALID_ARGUMENT is made here.
inline grpc::Status Invalid(const std::string& message) {
  if (message.size() <= kMaxStatusMessageBytes) return {grpc::StatusCode::INVALID_ARGUMENT, message};
  const std::string mark = " \u2026 (message cut from " + std::to_string(message.size()) + " bytes)";
  size_t n = kMaxStatusMessageBytes - mark.size();  // message[n] is the first byte left out
  for (int k = 0; k < 3 && n > 0 && (static_cast<uint8_t>(message[n]) & 0xC0) == 0x80; ++k) --n;
  return {grpc::StatusCode::INVALID_ARGUMENT, message.substr(0, n) + mark};
}

// A material's error from the material cache: RESOURCE_EXHAUSTED when the memory budget could not hold its
// text parse now (models::kParseBudgetError), else INVALID_ARGUMENT.
inline grpc::Status MaterialError(const std::string& message) {
  if (message.rfind(models::kParseBudgetError, 0) == 0) return {grpc::StatusCode::RESOURCE_EXHAUSTED, message};
  return Invalid(message);
}

inline grpc::Status ToStatus(const batching::JobResult& r) {
  switch (r.status) {
    case batching::JobStatus::kOk: return grpc::Status::OK;
    case batching::JobStatus::kDeadlineExceeded: return {grpc::StatusCode::DEADLINE_EXCEEDED, r.message};
    case batching::JobStatus::kCancelled: return {grpc::StatusCode::CANCELLED, r.message};
    case batching::JobStatus::kUnavailable: return {grpc::StatusCode::UNAVAILABLE, r.message};
    case batching::JobStatus::kInternal: return {grpc::StatusCode::INTERNAL, r.message};
    case batching::JobStatus::kResourceExhausted: return {grpc::StatusCode::RESOURCE_EXHAUSTED, r.message};
  }
  return {grpc::StatusCode::INTERNAL, "unknown job status"};
}

// The outcome of a plan's parts (one batcher job each) as they finish, from any thread: the first failure,
// the slowest part's timing, the largest launch.
class PlanOutcome {
 public:
  void Expect(size_t parts) { remaining_ = parts; }
  // Adds a part's result; true for the last one (then result() is complete).
  bool Add(const batching::JobResult& r) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (r.status != batching::JobStatus::kOk && result_.status == batching::JobStatus::kOk) {
      result_.status = r.status;
      result_.message = r.message;
    }
    result_.queue_seconds = std::max(result_.queue_seconds, r.queue_seconds);
    result_.kernel_seconds = std::max(result_.kernel_seconds, r.kernel_seconds);
    if (r.batch_queries > result_.batch_queries) {
      result_.batch_queries = r.batch_queries;
      result_.batch_requests = r.batch_requests;
    }
    return --remaining_ == 0;
  }
  const batching::JobResult& result() const { return result_; }

 private:
  std::mutex mutex_;
  size_t remaining_ = 0;
  batching::JobResult result_;
};

// The launch a unary call's parts rode in, into its response (EvaluateResponse, SampleResponse): the slowest
// part's queue and kernel time, the largest launch's queries and requests.
template <class Response>
void SetLaunchFields(const batching::JobResult& r, Response* response) {
  response->set_queue_seconds(r.queue_seconds);
  response->set_kernel_seconds(r.kernel_seconds);
  response->set_batch_queries(static_cast<uint32_t>(r.batch_queries));
  response->set_batch_requests(static_cast<uint32_t>(r.batch_requests));
}

}  // namespace loomlight::api
