// One thread that runs the host side of streaming RPCs (filling query directions, averaging and encoding
// results): each client's tasks in submission order, clients in turn (round robin), so one client's many
// calls cannot make another's next step wait behind all of theirs. Batcher done callbacks and gRPC reactions only post here: the batcher's
// single thread serves every client's next launch, and gRPC callback threads must not do heavy work. One
// thread per service bounds the CPU that host work takes from the kernels.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <utility>

namespace loomlight::api {

class HostWorker {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;

  HostWorker() : thread_([this] { Run(); }) {}
  HostWorker(const HostWorker&) = delete;
  HostWorker& operator=(const HostWorker&) = delete;
  // Runs every task posted so far, then joins.
  ~HostWorker();
  // Queues a task for `client` (server/api/access.h FairShareKey). One call's tasks must all name the same
  // client: their order is kept only within a client.
  void Post(std::function<void()> task, const std::string& client = "");
  // The running task reached the end of one bounded step: the health watchdog counts a task as stuck only after
  // --stall-seconds without progress, however long a task making progress runs. Any thread may call it (a task's
  // helper threads too); while the worker is idle it does nothing.
  void Progress();
  // The worker whose task is running on this thread; null on any other thread.
  static HostWorker* Current();
  // When the task running now started; max when idle.
  TimePoint busy_since() const { return busy_since_.load(); }
  // When the task running now last made progress (its start if it has not reported any); max when idle.
  TimePoint last_progress() const { return last_progress_.load(); }
  // Tasks waiting to run (not the running one), every client's together.
  size_t queued() const;

 private:
  void Run();

  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::map<std::string, std::deque<std::function<void()>>> tasks_;  // by client; none empty
  std::deque<std::string> turn_;  // the clients with tasks, next first
  std::string last_served_;       // the client whose task ran last
  size_t queued_ = 0;
  bool stopping_ = false;
  std::atomic<TimePoint> busy_since_{TimePoint::max()};
  std::atomic<TimePoint> last_progress_{TimePoint::max()};
  std::thread thread_;  // declared last: starts after the rest is constructed
};

// `stop` (a long task's poll of whether to end early, made between bounded steps) that also reports progress to
// the worker running the task: make it on the worker's thread; the task's helper threads may call it.
template <class Stop>
auto ReportingProgress(Stop stop) {
  return [worker = HostWorker::Current(), stop = std::move(stop)] {
    if (worker) worker->Progress();
    return stop();
  };
}

}  // namespace loomlight::api
