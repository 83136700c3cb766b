// Client-streaming calls (UploadBtf) must keep sending: the server's watchdog cancels one that has sent nothing
// for the service's limit, so a client that stalls gives back its long-call slot and the bytes it was charged
// instead of holding them until its deadline (README "Limits and admission").
#pragma once

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <unordered_set>

#include "server/batching/batcher.h"

namespace loomlight::api {

class IdleStreams {
 public:
  using Clock = batching::Clock;

  // One watched stream; the call touches it on every message it receives.
  class Stream {
   public:
    explicit Stream(grpc::CallbackServerContext* context) : context_(context) { Touch(); }
    void Touch() { last_message_ = Clock::now().time_since_epoch().count(); }
    // The watchdog cancelled the call: it sent nothing for the limit.
    bool cut_off() const { return cut_off_; }

   private:
    friend class IdleStreams;
    grpc::CallbackServerContext* const context_;
    std::atomic<Clock::rep> last_message_{0};
    std::atomic<bool> cut_off_{false};
  };

  explicit IdleStreams(Clock::duration limit) : limit_(limit) {}
  Clock::duration limit() const { return limit_; }

  // Watches the call of `context` until Forget.
  std::shared_ptr<Stream> Watch(grpc::CallbackServerContext* context) {
    auto stream = std::make_shared<Stream>(context);
    std::lock_guard<std::mutex> lock(mutex_);
    streams_.insert(stream);
    return stream;
  }

  // Stops watching a stream: when its client has sent everything, and before its call finishes (the context is
  // never touched after this returns). Null or forgotten already: nothing.
  void Forget(const std::shared_ptr<Stream>& stream) {
    std::lock_guard<std::mutex> lock(mutex_);
    streams_.erase(stream);
  }

  // Cancels every watched call idle for longer than the limit (the watchdog's round).
  void CancelIdle() {
    const Clock::rep now = Clock::now().time_since_epoch().count();
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& stream : streams_)
      if (!stream->cut_off_ && now - stream->last_message_ > limit_.count()) {
        stream->cut_off_ = true;
        stream->context_->TryCancel();  // the pending read ends; the call finishes from there
      }
  }

 private:
  const Clock::duration limit_;
  std::mutex mutex_;
  std::unordered_set<std::shared_ptr<Stream>> streams_;
};

}  // namespace loomlight::api
