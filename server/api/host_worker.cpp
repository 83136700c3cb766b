#include "server/api/host_worker.h"

namespace loomlight::api {
namespace {
thread_local HostWorker* current = nullptr;
}  // namespace

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
    ++queued_;
  }
  wake_.notify_one();
}

void HostWorker::Progress() {
  // Never from idle to busy: a helper thread's late report after its task ended must not look like a task.
  TimePoint seen = last_progress_.load();
  while (seen != TimePoint::max() && !last_progress_.compare_exchange_weak(seen, std::chrono::steady_clock::now())) {
  }
}

HostWorker* HostWorker::Current() { return current; }

size_t HostWorker::queued() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return queued_;
}

void HostWorker::Run() {
  current = this;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    wake_.wait(lock, [this] { return stopping_ || !tasks_.empty(); });
    if (tasks_.empty()) return;  // stopping, and everything queued has run
    // A client whose queue emptied left the turn; posting again while its task ran put it back before a client
    // that came after. It has just had its turn: the others go first.
    if (turn_.size() > 1 && turn_.front() == last_served_) {
      turn_.push_back(std::move(turn_.front()));
      turn_.pop_front();
    }
    const auto client = tasks_.find(turn_.front());
    turn_.pop_front();
    last_served_ = client->first;
    std::function<void()> task = std::move(client->second.front());
    client->second.pop_front();
    --queued_;
    if (client->second.empty())
      tasks_.erase(client);
    else
      turn_.push_back(client->first);
    lock.unlock();
    const TimePoint start = std::chrono::steady_clock::now();
    busy_since_ = start;
    last_progress_ = start;
    task();
    last_progress_ = TimePoint::max();
    busy_since_ = TimePoint::max();
    lock.lock();
  }
}

}  // namespace loomlight::api
