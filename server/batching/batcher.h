// Dynamic batcher: concurrent Evaluate calls for the same kernel (model, precision, launch-uniform value,
// with or without uv)
// are coalesced into one launch, each query carrying its material's index. One launch is in flight at a
// time (the CPU device already uses every core for one launch); whatever queues meanwhile forms the next.
#pragma once

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "server/models/registry.h"
#include "server/runtime/cl_runtime.h"

namespace loomlight::batching {

using Clock = std::chrono::steady_clock;

// kResourceExhausted: never set by the batcher; callers use it for a job Submit refused.
enum class JobStatus { kOk, kDeadlineExceeded, kCancelled, kInternal, kUnavailable, kResourceExhausted };

struct JobResult {
  JobStatus status = JobStatus::kOk;
  std::string message;
  std::vector<double> f;  // 3 per query
  double queue_seconds = 0, kernel_seconds = 0;
  size_t batch_queries = 0, batch_requests = 0;
};

// One request's work. wi, wo (and uv) point at the caller's data, which must outlive the completion callback.
struct Job {
  const models::Model* model = nullptr;
  bool fp64 = false;
  models::PackedMaterial material;
  const float* wi = nullptr;
  const float* wo = nullptr;
  const float* uv = nullptr;  // texture coordinates (spatially varying models): the BTF kernel
  size_t n = 0;
  Clock::time_point deadline = Clock::time_point::max();
  std::function<bool()> cancelled;        // polled before launch; may be empty
  std::function<void(JobResult)> done;    // called exactly once, on the batcher's thread
  Clock::time_point enqueued;
};

struct BatcherOptions {
  size_t max_batch_queries = size_t{1} << 20;     // a larger single request still runs, alone
  std::chrono::microseconds max_queue_delay{0};   // 0: batch whatever queued while the last launch ran
  size_t max_queued_queries = size_t{1} << 23;    // beyond this Submit refuses (RESOURCE_EXHAUSTED)
  bool coalesce = true;                           // false: one request per launch (for comparison)
};

class Batcher {
 public:
  Batcher(runtime::ClRuntime* runtime, BatcherOptions options);
  ~Batcher();
  // Queues the job; false when the queue is full (the job is not taken and done is not called).
  bool Submit(std::shared_ptr<Job> job);
  // Stops after failing every queued job with kUnavailable.
  void Stop();
  const BatcherOptions& options() const { return options_; }

 private:
  void Run();
  // Takes the next batch from the queue (lock held): the oldest job and every queued job with its key.
  std::vector<std::shared_ptr<Job>> TakeBatch();
  void Launch(std::vector<std::shared_ptr<Job>> batch);

  runtime::ClRuntime* runtime_;
  BatcherOptions options_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::shared_ptr<Job>> queue_;
  size_t queued_queries_ = 0;
  bool stopping_ = false;
  std::thread worker_;
};

}  // namespace loomlight::batching
