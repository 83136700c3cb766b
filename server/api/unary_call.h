// The shared skeleton of the unary RPCs, as WorkerStreamCall (server/api/stream_call.h) is the streaming ones':
// FinishUnary is the one place a unary call is recorded and finished (AnswerNow for one answered without work,
// e.g. refused), and PlanCall is the state and the steps of the calls whose work is a material plan on the
// batcher (Evaluate, Sample).
#pragma once

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>

#include "server/api/admission.h"
#include "server/api/host_worker.h"
#include "server/api/job_status.h"
#include "server/api/metrics.h"
#include "server/api/service.h"
#include "server/models/material_plan.h"

namespace loomlight::api {

// Records a unary call's outcome as `rpc`'s and finishes its reactor.
inline void FinishUnary(Metrics* metrics, grpc::ServerUnaryReactor* reactor, const char* rpc,
                        batching::Clock::time_point received, const grpc::Status& status) {
  metrics->Call(rpc, status.error_code(), SecondsSince(received));
  reactor->Finish(status);
}

// Finishes a unary call at once (a refusal, or an answer that needed no work) on its default reactor.
inline grpc::ServerUnaryReactor* AnswerNow(Metrics* metrics, grpc::CallbackServerContext* context, const char* rpc,
                                           batching::Clock::time_point received, const grpc::Status& status) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  FinishUnary(metrics, reactor, rpc, received, status);
  return reactor;
}

// One unary call whose kernel work is a material plan (Evaluate, Sample), held by shared_ptr from its steps. Its
// handler makes it on the gRPC thread after the checks that need no material and the admission of its bytes; the
// call's own steps (the material, the checks that need it, the plan) run on the preparer, or inline for a small
// call of a cached material. SubmitParts sends the plan's parts to the batcher, the kernels writing f straight
// into the response; the call's last step runs once every part has returned: on the batcher's thread for a small
// call (microseconds of work left), else back on the preparer (never megabytes of work on the batcher's thread:
// the response is serialized where the call finishes). Finish fills what every such response has (model,
// approximation, precision, the launch's fields, the time) or clears it, records the call and finishes it.
template <class Request, class Response>
struct PlanCall {
  PlanCall(const ServiceDeps& deps, const char* rpc, grpc::CallbackServerContext* context, const Request* request,
           Response* response, batching::Clock::time_point received, bool fp64)
      : deps(&deps), rpc(rpc), context(context), request(request), response(response),
        reactor(context->DefaultReactor()), received(received), client_deadline(CallDeadline(context, received)),
        deadline(deps.call_caps.Deadline(received, client_deadline, batching::Priority::kInteractive)),
        client(FairShareKey(*context, *deps.trusted_proxies)), fp64(fp64) {}

  // Sends the plan's parts (f, 3 per query, into `f`); when all have returned, the first failure finishes the
  // call, else `last_step` runs (inline on the batcher's thread when `small`, else on the preparer).
  template <class Call>
  static void SubmitParts(const std::shared_ptr<Call>& call, float* f, bool small, void (Call::*last_step)()) {
    call->outcome.Expect(call->plan->parts());
    SubmitPlan(call->deps->batcher, *call->plan, runtime::ResultSink{.f32 = f}, call->fp64,
               batching::Priority::kInteractive, call->deadline, call->context, call->client,
               [call, small, last_step](size_t k, batching::JobResult r) {
                 const models::EvaluationPlan& plan = *call->plan;
                 if (r.status == batching::JobStatus::kOk && r.batch_queries > 0)
                   call->deps->metrics->Evaluated(plan.model(k).name(), call->fp64, plan.size(k), r.batch_queries,
                                                  r.batch_requests, r.queue_seconds, r.kernel_seconds);
                 if (!call->outcome.Add(r)) return;
                 if (call->outcome.result().status != batching::JobStatus::kOk)
                   return call->Finish(ToStatus(call->outcome.result()));
                 if (small) return ((*call).*last_step)();
                 call->deps->preparer->Post([call, last_step] { ((*call).*last_step)(); }, call->client);
               });
  }

  void Finish(grpc::Status status) {
    status = deps->call_caps.Explain(status, received, client_deadline, batching::Priority::kInteractive);
    if (status.ok()) {
      response->set_model(material->model->name());
      response->set_approximation(approximation);
      response->set_precision(fp64 ? v1::PRECISION_FP64 : v1::PRECISION_FP32);
      SetLaunchFields(outcome.result(), response);
      response->set_total_seconds(SecondsSince(received));
    } else {
      response->Clear();
    }
    FinishUnary(deps->metrics, reactor, rpc, received, status);
  }

  const ServiceDeps* const deps;
  const char* const rpc;
  grpc::CallbackServerContext* const context;
  const Request* const request;
  Response* const response;
  grpc::ServerUnaryReactor* const reactor;
  const batching::Clock::time_point received;
  const batching::Clock::time_point client_deadline;  // max when the client set none
  const batching::Clock::time_point deadline;         // the client's, at most the interactive cap (CallCaps)
  const std::string client;  // FairShareKey
  const bool fp64;
  Admission admission;  // the call's bytes, held until the call object goes
  std::shared_ptr<const models::PreparedMaterial> material;
  std::unique_ptr<models::EvaluationPlan> plan;  // refers to the request's and the response's arrays
  std::string approximation;                      // the knob settings used (the response's `approximation`)
  PlanOutcome outcome;
};

}  // namespace loomlight::api
