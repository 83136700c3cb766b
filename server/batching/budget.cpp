#include "server/batching/budget.h"

namespace loomlight::batching {

Budget::Reservation& Budget::Reservation::operator=(Reservation&& other) noexcept {
  if (this != &other) {
    Release();
    budget_ = other.budget_;
    bytes_ = other.bytes_;
    other.bytes_ = 0;
  }
  return *this;
}

bool Budget::Reservation::Grow(size_t bytes) {
  if (bytes == 0) return true;
  if (!budget_ || !budget_->Take(bytes)) return false;
  bytes_ += bytes;
  return true;
}

void Budget::Reservation::Release() {
  if (budget_ && bytes_ > 0) budget_->Give(bytes_);
  bytes_ = 0;
}

bool Budget::TryReserve(size_t bytes, Reservation* out) {
  if (out->budget_ && out->budget_ != this) return false;
  out->budget_ = this;
  return out->Grow(bytes);
}

bool Budget::Take(size_t bytes) {
  size_t used = in_use_.load(std::memory_order_relaxed);
  do {
    if (bytes > limit_ || used > limit_ - bytes) return false;
  } while (!in_use_.compare_exchange_weak(used, used + bytes, std::memory_order_relaxed));
  return true;
}

}  // namespace loomlight::batching
