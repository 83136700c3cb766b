// The bounds a client-streaming upload (UploadBtf, UploadMesh) is held to while it receives: a client that sends
// nothing for --upload-idle-seconds is cut off (IdleStreams, the watchdog's round), and so is one still sending
// --max-upload-seconds after the call began (an alarm), however steadily it trickles.
#pragma once

#include <grpcpp/alarm.h>
#include <grpcpp/grpcpp.h>

#include <chrono>
#include <memory>
#include <mutex>
#include <string>

#include "server/api/idle_streams.h"
#include "server/api/service.h"

namespace loomlight::api {

class UploadBounds {
 public:
  UploadBounds(const ServiceDeps& deps, grpc::CallbackServerContext* context)
      : idle_streams_(deps.idle_uploads), idle_(deps.idle_uploads->Watch(context)),
        max_duration_(deps.max_upload_duration), bound_(std::make_shared<DurationBound>()) {
    bound_->context = context;
    if (max_duration_.count() > 0) {
      // The alarm holds the shared state only: it may fire after this call is gone, and then does nothing.
      alarm_.Set(std::chrono::system_clock::now() + max_duration_, [bound = bound_](bool fired) {
        std::lock_guard<std::mutex> lock(bound->mutex);
        if (!fired || !bound->context) return;
        bound->expired = true;
        bound->context->TryCancel();  // the pending read ends; the call finishes from there
      });
      alarm_set_ = true;
    }
  }
  ~UploadBounds() { Stop(); }
  UploadBounds(const UploadBounds&) = delete;
  UploadBounds& operator=(const UploadBounds&) = delete;

  // A message arrived (or the server's own work on one ended: a wait on the server is not the client's silence).
  void Touch() { idle_->Touch(); }

  // Nothing more is received (the stream ended, or the call fails): neither bound applies from now on, and the
  // context is not touched again. DEADLINE_EXCEEDED saying which bound cut the upload off, else OK.
  grpc::Status Stop() {
    idle_streams_->Forget(idle_);
    bool expired;
    {
      std::lock_guard<std::mutex> lock(bound_->mutex);
      bound_->context = nullptr;
      expired = bound_->expired;
    }
    if (alarm_set_) alarm_.Cancel();
    alarm_set_ = false;
    const auto seconds = [](auto d) {
      return std::to_string(std::chrono::duration_cast<std::chrono::seconds>(d).count());
    };
    if (expired)
      return {grpc::StatusCode::DEADLINE_EXCEEDED,
              "the upload was still sending after " + seconds(max_duration_) + " s (--max-upload-seconds): cancelled"};
    if (idle_->cut_off())
      return {grpc::StatusCode::DEADLINE_EXCEEDED,
              "the client sent nothing for " + seconds(idle_streams_->limit()) + " s: the upload was cancelled"};
    return grpc::Status::OK;
  }

 private:
  // The whole-duration bound's state, shared with its alarm.
  struct DurationBound {
    std::mutex mutex;
    grpc::CallbackServerContext* context = nullptr;  // null once the call stops receiving
    bool expired = false;
  };

  IdleStreams* const idle_streams_;
  const std::shared_ptr<IdleStreams::Stream> idle_;
  const std::chrono::milliseconds max_duration_;
  const std::shared_ptr<DurationBound> bound_;
  grpc::Alarm alarm_;
  bool alarm_set_ = false;
};

}  // namespace loomlight::api
