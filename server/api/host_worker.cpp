#include "server/api/host_worker.h"

namespace loomlight::api {

HostWorker::~HostWorker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_one();
  thread_.join();
}

void HostWorker::Post(std::function<void()> task, const std::string& client) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto& queue = tasks_[client];
    if (queue.empty()) turn_.push_back(client);
    queue.push_back(std::move(task));
  }
  wake_.notify_one();
}

void HostWorker::Run() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    wake_.wait(lock, [this] { return stopping_ || !tasks_.empty(); });
    if (tasks_.empty()) return;  // stopping, and everything queued has run
    const auto client = tasks_.find(turn_.front());
    turn_.pop_front();
    std::function<void()> task = std::move(client->second.front());
    client->second.pop_front();
    if (client->second.empty())
      tasks_.erase(client);
    else
      turn_.push_back(client->first);
    lock.unlock();
    busy_since_ = std::chrono::steady_clock::now();
    task();
    busy_since_ = std::chrono::steady_clock::time_point::max();
    lock.lock();
  }
}

}  // namespace loomlight::api
