#include "server/batching/budget.h"

namespace loomlight::batching {

Budget::Reservation& Budget::Reservation::operator=(Reservation&& other) noexcept {
  if (this != &other) {
    Release();
    budget_ = other.budget_;
    bytes_ = other.bytes_;
    client_ = std::move(other.client_);
    other.bytes_ = 0;
  }
  return *this;
}

bool Budget::Reservation::Grow(size_t bytes) {
  if (bytes == 0) return true;
  if (!budget_ || !budget_->Take(client_, bytes)) return false;
  bytes_ += bytes;
  return true;
}

void Budget::Reservation::Release() {
  if (budget_ && bytes_ > 0) budget_->Give(client_, bytes_);
  bytes_ = 0;
}

bool Budget::TryReserveFor(const std::string& client, size_t bytes, Reservation* out) {
  if (out->budget_ && (out->budget_ != this || out->client_ != client)) return false;
  out->budget_ = this;
  out->client_ = client;
  return out->Grow(bytes);
}

size_t Budget::client_in_use(const std::string& client) const {
  std::lock_guard<std::mutex> lock(clients_mutex_);
  const auto it = clients_.find(client);
  return it == clients_.end() ? 0 : it->second;
}

bool Budget::Take(const std::string& client, size_t bytes) {
  if (client.empty()) return TakeFromWhole(bytes);
  // The client's share and the whole budget change together, under the lock, so two calls of one client cannot
  // both pass its limit.
  std::lock_guard<std::mutex> lock(clients_mutex_);
  const auto it = clients_.find(client);
  const size_t held = it == clients_.end() ? 0 : it->second;
  if (bytes > client_limit_ || held > client_limit_ - bytes || !TakeFromWhole(bytes)) return false;
  if (it == clients_.end()) clients_.emplace(client, bytes);
  else it->second += bytes;
  return true;
}

void Budget::Give(const std::string& client, size_t bytes) {
  in_use_.fetch_sub(bytes, std::memory_order_relaxed);
  if (client.empty()) return;
  std::lock_guard<std::mutex> lock(clients_mutex_);
  if (auto it = clients_.find(client); it != clients_.end() && (it->second -= bytes) == 0) clients_.erase(it);
}

bool Budget::TakeFromWhole(size_t bytes) {
  size_t used = in_use_.load(std::memory_order_relaxed);
  do {
    if (bytes > limit_ || used > limit_ - bytes) return false;
  } while (!in_use_.compare_exchange_weak(used, used + bytes, std::memory_order_relaxed));
  return true;
}

}  // namespace loomlight::batching
