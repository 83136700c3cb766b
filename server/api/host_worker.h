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

namespace loomlight::api {

class HostWorker {
 public:
  HostWorker() : thread_([this] { Run(); }) {}
  HostWorker(const HostWorker&) = delete;
  HostWorker& operator=(const HostWorker&) = delete;
  // Runs every task posted so far, then joins.
  ~HostWorker();
  // Queues a task for `client` (server/api/access.h FairShareKey). One call's tasks must all name the same
  // client: their order is kept only within a client.
  void Post(std::function<void()> task, const std::string& client = "");
  // When the task running now started; max when idle (the health watchdog reads it).
  std::chrono::steady_clock::time_point busy_since() const { return busy_since_.load(); }

 private:
  void Run();

  std::mutex mutex_;
  std::condition_variable wake_;
  std::map<std::string, std::deque<std::function<void()>>> tasks_;  // by client; none empty
  std::deque<std::string> turn_;  // the clients with tasks, next first
  bool stopping_ = false;
  std::atomic<std::chrono::steady_clock::time_point> busy_since_{std::chrono::steady_clock::time_point::max()};
  std::thread thread_;  // declared last: starts after the rest is constructed
};

}  // namespace loomlight::api
