// Dynamic batcher: concurrent Evaluate calls for the same kernel (model, precision, launch-uniform value,
// with or without uv)
// are coalesced into one launch, each query carrying its material's index. One launch is in flight at a
// time (the CPU device already uses every core for one launch); whatever queues meanwhile forms the next.
// Two priorities: interactive work (Evaluate, Sample, TextureSlice) always launches before bulk work
// (Tabulate, Render chunks), and a bulk launch runs in slices of about `bulk_slice` with waiting interactive
// work launched between them, so an interactive call waits for one slice, not for a whole bulk launch; a small
// interactive job does not even wait for that, as it runs on PoCL's small-launch device beside the main one.
// Each priority has its own queue policy (limits, timeout, queueing delay, in the spirit of Triton's), so
// bulk work can never fill the queue interactive calls need. Within a priority, clients share the device
// fairly: start-time fair queuing by queries, so a client's next job goes ahead of another's that has been
// served more, and one client's many jobs cannot make another's wait behind all of them; while several clients
// have jobs of one kernel queued, a launch takes one job of each.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "server/models/registry.h"
#include "server/runtime/cl_runtime.h"

namespace loomlight::batching {

using Clock = std::chrono::steady_clock;
// A client whose deadline passes cancels the call from its side a little before the server's copy of the
// deadline passes (the grpc-timeout header is relative, measured when it was sent): a cancellation within
// this much of the deadline is the deadline.
constexpr Clock::duration kDeadlineSlack = std::chrono::milliseconds(100);

// kResourceExhausted: a job that queued past its queue's timeout, or (set by callers) one Submit refused.
enum class JobStatus { kOk, kDeadlineExceeded, kCancelled, kInternal, kUnavailable, kResourceExhausted };

// A job's outcome; its f went to the job's sink (when the status is kOk).
struct JobResult {
  JobStatus status = JobStatus::kOk;
  std::string message;
  double queue_seconds = 0, kernel_seconds = 0;
  size_t batch_queries = 0, batch_requests = 0;
};

enum class Priority { kInteractive = 0, kBulk = 1 };
const char* PriorityName(Priority priority);

// One request's work. The material, wi, wo (and uv) and the sink's buffers are the caller's, which must outlive
// the completion callback; results are written into the sink before it.
struct Job {
  Priority priority = Priority::kInteractive;
  std::string client;  // who shares the device fairly with others: the caller's name, or its connection
  const models::Model* model = nullptr;
  bool fp64 = false;
  const models::PackedMaterial* material = nullptr;  // shared and immutable: jobs of one material share it
  runtime::ResultSink sink;
  const float* wi = nullptr;
  const float* wo = nullptr;
  const float* uv = nullptr;  // texture coordinates (spatially varying models): the BTF kernel
  size_t n = 0;
  models::Quantity quantity = models::Quantity::kScattering;  // kAmbient: the model's ambient entry
  Clock::time_point deadline = Clock::time_point::max();
  std::function<bool()> cancelled;        // polled before launch; may be empty
  std::function<void(JobResult)> done;    // called exactly once, on the batcher's thread
  Clock::time_point enqueued;
};

// One priority's queue (docs/operations.md "Limits and admission": queue policy).
struct QueuePolicy {
  std::chrono::microseconds max_queue_delay{0};  // 0: batch whatever queued while the last launch ran
  size_t max_queued_queries = size_t{1} << 23;   // beyond this Submit refuses (RESOURCE_EXHAUSTED)
  size_t max_client_queued_queries = size_t{1} << 22;  // one client's share of them
  // What happens to a job queued longer than `timeout` (0: nothing; it waits until its call's deadline).
  std::chrono::milliseconds timeout{0};
  // Triton's timeout actions: kReject fails it RESOURCE_EXHAUSTED (the server is overloaded: retry); kDelay
  // keeps it queued but behind every job of its priority that has not timed out.
  enum class TimeoutAction { kReject, kDelay };
  TimeoutAction timeout_action = TimeoutAction::kReject;
  // Whether a job enqueued at `enqueued` has timed out at `now`.
  bool TimedOut(Clock::time_point enqueued, Clock::time_point now) const {
    return timeout.count() > 0 && now - enqueued > timeout;
  }
};

struct BatcherOptions {
  size_t max_batch_queries = size_t{1} << 20;     // a larger single request still runs, alone
  bool coalesce = true;                           // false: one request per launch (for comparison)
  std::chrono::milliseconds bulk_slice{20};       // a bulk launch's slices take about this long each
  QueuePolicy interactive;
  // Bulk work queues twice as deep: a Tabulate call keeps two chunks in flight (server/api/tabulate.h), so a
  // client's eight long calls (a curtain's two parts each) fit its share, and sixteen calls the queue.
  QueuePolicy bulk{.max_queued_queries = size_t{1} << 24, .max_client_queued_queries = size_t{1} << 23};
  const QueuePolicy& policy(Priority p) const { return p == Priority::kInteractive ? interactive : bulk; }
};

// What is queued and launching now, per priority (exported as metrics).
struct QueueStats {
  size_t queued_jobs[2] = {0, 0}, queued_queries[2] = {0, 0}, queued_bytes[2] = {0, 0}, clients[2] = {0, 0};
  size_t launching_queries[2] = {0, 0};  // in the kernel now, on the main device and on the small one
};

class Batcher {
 public:
  Batcher(runtime::ClRuntime* runtime, BatcherOptions options);
  ~Batcher();
  enum class Refusal { kNone, kQueueFull, kClientQueueFull, kStopping };
  // Queues the job; otherwise says why not (the job is not taken and done is not called). A small interactive
  // job that finds the batcher idle (nothing queued, nothing launching) is launched at once on the calling
  // thread instead, done called there: waking the batcher's thread would cost more than the launch, and there
  // is nothing to coalesce it with.
  Refusal Submit(std::shared_ptr<Job> job);
  // When the kernel running now started; max when none runs (the health watchdog reads it).
  Clock::time_point busy_since() const { return busy_since_.load(); }
  // Stops after failing every queued job with kUnavailable.
  void Stop();
  const BatcherOptions& options() const { return options_; }
  QueueStats Stats() const;

 private:
  // One client's queued jobs of one priority, with the queries it has been served (its start tag).
  struct ClientQueue {
    std::deque<std::shared_ptr<Job>> jobs;
    size_t queued_queries = 0;
    double served = 0;
  };
  // One priority: its clients with queued jobs, and the virtual time (the served count of the client chosen
  // last), from which a client that starts queueing again begins, so idleness earns no credit.
  struct PriorityQueue {
    std::map<std::string, ClientQueue> clients;
    size_t jobs = 0, queries = 0, bytes = 0;
    double virtual_time = 0;
    bool empty() const { return jobs == 0; }
    Clock::time_point oldest() const;
  };

  void Run();
  bool Empty() const { return queue_[0].empty() && queue_[1].empty(); }
  // Takes the next batch (lock held) from the highest priority waiting: the oldest job of its client served
  // least, and every queued job of that priority with its key (each client charged its own queries).
  std::vector<std::shared_ptr<Job>> TakeBatch();
  void Remove(PriorityQueue& queue, std::map<std::string, ClientQueue>::iterator client,
              std::deque<std::shared_ptr<Job>>::iterator job);
  void Launch(std::vector<std::shared_ptr<Job>> batch);
  // One kernel run, marked busy for the watchdog; adds its time to *seconds.
  bool RunKernel(const runtime::LaunchArgs& args, runtime::LaunchResults* results, std::string* error,
                 double* seconds);
  // Runs the launch (a bulk one in slices, waiting interactive batches launched between them) and writes each
  // job's results into its sink; jobs[j]'s queries start at first[j] in the launch.
  bool RunAndDeliver(const runtime::LaunchArgs& args, const std::vector<std::shared_ptr<Job>>& jobs,
                     const std::vector<size_t>& first, std::string* error, double* seconds);
  void LaunchWaitingInteractive();

  static constexpr size_t kFirstBulkSlice = size_t{1} << 14;  // then sized from the measured rate
  static constexpr size_t kMaxInlineQueries = 4096;              // an idle batcher launches these on the caller
  static constexpr size_t kMinBulkSlice = size_t{1} << 12;

  runtime::ClRuntime* runtime_;
  BatcherOptions options_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  PriorityQueue queue_[2];  // by Priority
  std::atomic<size_t> launching_queries_[2] = {0, 0};
  std::atomic<Clock::time_point> busy_since_{Clock::time_point::max()};
  bool stopping_ = false;
  bool launching_ = false;  // a launch runs (on the batcher's thread or inline on a caller's)
  std::thread worker_;
};

}  // namespace loomlight::batching
