// The shared skeleton of the server-streaming calls (Tabulate, Render): their state lives on the service's
// host worker. Every gRPC reaction posts there and then calls Pump(), the derived call's one place for
// progress, writes and finishing, so the state needs no lock; `delete this` (posted by OnDone, the last
// reaction) runs after every task posted before it.
#pragma once

#include <grpcpp/grpcpp.h>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/service.h"

namespace loomlight::api {

template <class Message>
class WorkerStreamCall : public grpc::ServerWriteReactor<Message> {
 public:
  void OnWriteDone(bool ok) override {
    Post([this, ok] {
      write_in_flight_ = false;
      if (!ok) stream_broken_ = true;  // the client went away
      Pump();
    });
  }
  void OnCancel() override {
    Post([this] { Pump(); });
  }
  void OnDone() override {
    Post([this] { delete this; });
  }

 protected:
  WorkerStreamCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, const char* rpc,
                   batching::Clock::time_point received, Admission admission)
      : deps_(deps), context_(context), rpc_(rpc), received_(received), deadline_(CallDeadline(context, received)),
        client_(FairShareKey(*context, *deps.trusted_proxies)), admission_(std::move(admission)) {}

  // Runs `task` on the host worker in the call's turn among clients; every task of the call goes through here
  // (the worker keeps order only within a client, and `delete this` must run last).
  void Post(std::function<void()> task) { deps_.worker->Post(std::move(task), client_); }

  // Advances the call; runs on the host worker only.
  virtual void Pump() = 0;

  // Records why the work should stop, if it should (StopStatus).
  void NoticeStop() {
    if (status_.ok()) status_ = StopStatus(context_, deadline_, stream_broken_);
  }

  void FinishCall(const grpc::Status& status) {
    finished_ = true;
    deps_.metrics->Call(rpc_, status.error_code(),
                        std::chrono::duration<double>(batching::Clock::now() - received_).count());
    admission_.EndSlots();
    this->Finish(status);
  }

  const ServiceDeps deps_;
  grpc::CallbackServerContext* const context_;
  const char* const rpc_;
  const batching::Clock::time_point received_;
  const batching::Clock::time_point deadline_;
  const std::string client_;  // FairShareKey
  Admission admission_;  // the call's slots (given back as it finishes) and bytes (released with the call)
  grpc::Status status_;  // not OK once the call is to end with an error (after what is in flight returns)
  bool write_in_flight_ = false;
  bool stream_broken_ = false;  // a write failed
  bool finished_ = false;
};

}  // namespace loomlight::api
