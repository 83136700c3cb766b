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
    if (write_watch_) write_watch_->Pause();  // the client took it: waiting on the server's work again
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
    if (write_watch_) deps_.stalled_writes->Forget(write_watch_);  // also when FinishCall did not run
    Post([this] { delete this; });
  }

 protected:
  WorkerStreamCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, const char* rpc,
                   batching::Clock::time_point received, Admission admission)
      : deps_(deps), context_(context), rpc_(rpc), received_(received), client_deadline_(CallDeadline(context, received)),
        deadline_(deps.call_caps.Deadline(received, client_deadline_, batching::Priority::kBulk)),
        client_(FairShareKey(*context, *deps.trusted_proxies)), admission_(std::move(admission)),
        write_watch_(deps.stalled_writes ? deps.stalled_writes->Watch(context, false) : nullptr) {}

  // Every write of the call (the derived calls' StartWrite is this one): watched while in flight, so a client that
  // reads nothing, leaving it in flight, has the call cancelled after --stall-write-seconds (IdleStreams).
  void StartWrite(const Message* message, grpc::WriteOptions options = grpc::WriteOptions()) {
    if (write_watch_) write_watch_->Touch();
    grpc::ServerWriteReactor<Message>::StartWrite(message, options);
  }

  // Runs `task` on the host worker in the call's turn among clients; every task of the call goes through here
  // (the worker keeps order only within a client, and `delete this` must run last).
  void Post(std::function<void()> task) { deps_.worker->Post(std::move(task), client_); }

  // Advances the call; runs on the host worker only.
  virtual void Pump() = 0;

  // Records why the work should stop, if it should (StopStatus).
  void NoticeStop() {
    if (status_.ok()) status_ = StopStatus(context_, deadline_, stream_broken_);
  }

  void FinishCall(grpc::Status status) {
    finished_ = true;
    if (write_watch_) {
      deps_.stalled_writes->Forget(write_watch_);  // the context is not the watchdog's to cancel any more
      if (write_watch_->cut_off())  // the client sees the cancellation; metrics see why
        status = {grpc::StatusCode::DEADLINE_EXCEEDED,
                  "the client read nothing for " +
                      std::to_string(std::chrono::duration_cast<std::chrono::seconds>(
                                         deps_.stalled_writes->limit()).count()) +
                      " s (--stall-write-seconds): the stream was cancelled"};
    }
    status = deps_.call_caps.Explain(status, received_, client_deadline_, batching::Priority::kBulk);
    deps_.metrics->Call(rpc_, status.error_code(),
                        std::chrono::duration<double>(batching::Clock::now() - received_).count());
    admission_.EndSlots();
    this->Finish(status);
  }

  const ServiceDeps deps_;
  grpc::CallbackServerContext* const context_;
  const char* const rpc_;
  const batching::Clock::time_point received_;
  const batching::Clock::time_point client_deadline_;  // max when the client set none
  const batching::Clock::time_point deadline_;         // the client's, at most the bulk cap (CallCaps)
  const std::string client_;  // FairShareKey
  Admission admission_;  // the call's slots (given back as it finishes) and bytes (released with the call)
  grpc::Status status_;  // not OK once the call is to end with an error (after what is in flight returns)
  bool write_in_flight_ = false;
  bool stream_broken_ = false;  // a write failed
  bool finished_ = false;
  const std::shared_ptr<IdleStreams::Stream> write_watch_;  // null without deps_.stalled_writes
};

}  // namespace loomlight::api
