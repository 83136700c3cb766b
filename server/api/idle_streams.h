// Streams must keep moving: the server's watchdog cancels a client-streaming call (UploadBtf) that has sent
// nothing for the service's limit, and a server-streaming one (Tabulate, Render, ...) whose write has waited on a
// client that reads nothing for --stall-write-seconds, so a client that stalls gives back its long-call slot and
// the bytes it was charged instead of holding them until its deadline
// (docs/operations.md "Limits and admission").
#pragma once

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <chrono>
#include <limits>
#include <memory>
#include <mutex>
#include <unordered_set>

#include "server/batching/batcher.h"

namespace loomlight::api {

class IdleStreams {
 public:
  using Clock = batching::Clock;

  // One watched stream: it waits on its client from its last Touch (an upload: on every message it receives; a
  // server stream: as it starts a write) until Pause (a server stream: its write completed; the server's own
  // work is not the client's stall).
  class Stream {
   public:
    Stream(grpc::CallbackServerContext* context, bool waiting) : context_(context) {
      if (waiting) Touch();
      else Pause();
    }
    void Touch() { last_message_ = Clock::now().time_since_epoch().count(); }
    void Pause() { last_message_ = kNotWaiting; }
    // The watchdog cancelled the call: it waited on its client for longer than the limit.
    bool cut_off() const { return cut_off_; }

   private:
    friend class IdleStreams;
    static constexpr Clock::rep kNotWaiting = std::numeric_limits<Clock::rep>::max();
    grpc::CallbackServerContext* const context_;
    std::atomic<Clock::rep> last_message_{0};
    std::atomic<bool> cut_off_{false};
  };

  explicit IdleStreams(Clock::duration limit) : limit_(limit) {}
  Clock::duration limit() const { return limit_; }

  // Watches the call of `context` until Forget, waiting on its client from now or (not `waiting`) from its
  // first Touch.
  std::shared_ptr<Stream> Watch(grpc::CallbackServerContext* context, bool waiting = true) {
    auto stream = std::make_shared<Stream>(context, waiting);
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
      if (const Clock::rep since = stream->last_message_;
          !stream->cut_off_ && since != Stream::kNotWaiting && now - since > limit_.count()) {
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
