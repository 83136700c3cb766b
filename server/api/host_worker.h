// One thread that runs the host side of streaming RPCs (filling query directions, averaging and encoding
// results) in submission order. Batcher done callbacks and gRPC reactions only post here: the batcher's
// single thread serves every client's next launch, and gRPC callback threads must not do heavy work. One
// thread per service bounds the CPU that host work takes from the kernels.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>

namespace loomlight::api {

class HostWorker {
 public:
  HostWorker() : thread_([this] { Run(); }) {}
  HostWorker(const HostWorker&) = delete;
  HostWorker& operator=(const HostWorker&) = delete;
  // Runs every task posted so far, then joins.
  ~HostWorker();
  void Post(std::function<void()> task);
  // When the task running now started; max when idle (the health watchdog reads it).
  std::chrono::steady_clock::time_point busy_since() const { return busy_since_.load(); }

 private:
  void Run();

  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> tasks_;
  bool stopping_ = false;
  std::atomic<std::chrono::steady_clock::time_point> busy_since_{std::chrono::steady_clock::time_point::max()};
  std::thread thread_;  // declared last: starts after the rest is constructed
};

}  // namespace loomlight::api
