// One thread that runs the host side of streaming RPCs (filling query directions, averaging and encoding
// results) in submission order. Batcher done callbacks and gRPC reactions only post here: the batcher's
// single thread serves every client's next launch, and gRPC callback threads must not do heavy work. One
// thread per service bounds the CPU that host work takes from the kernels.
#pragma once

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

 private:
  void Run();

  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> tasks_;
  bool stopping_ = false;
  std::thread thread_;  // declared last: starts after the rest is constructed
};

}  // namespace loomlight::api
