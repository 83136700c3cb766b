// One byte budget for everything requests make the server hold: queued and in-flight queries, unsent
// stream bytes, decoded environment maps, render and table buffers. Work reserves its bytes before it
// starts and gives them back when done; a reservation that does not fit is refused (the caller answers
// RESOURCE_EXHAUSTED), so load never grows the process past the budget.
#pragma once

#include <atomic>
#include <cstddef>

namespace loomlight::batching {

class Budget {
 public:
  explicit Budget(size_t limit_bytes) : limit_(limit_bytes) {}
  Budget(const Budget&) = delete;
  Budget& operator=(const Budget&) = delete;

  // Bytes held from the budget until destroyed (or Release); move-only. An empty one holds nothing.
  class Reservation {
   public:
    Reservation() = default;
    Reservation(Reservation&& other) noexcept : budget_(other.budget_), bytes_(other.bytes_) { other.bytes_ = 0; }
    Reservation& operator=(Reservation&& other) noexcept;
    ~Reservation() { Release(); }
    // Holds `bytes` more; false (nothing changes) when the budget cannot take them.
    bool Grow(size_t bytes);
    void Release();
    size_t bytes() const { return bytes_; }

   private:
    friend class Budget;
    Reservation(Budget* budget, size_t bytes) : budget_(budget), bytes_(bytes) {}
    Budget* budget_ = nullptr;
    size_t bytes_ = 0;
  };

  // Reserves `bytes` into *out (which must be empty or of this budget); false when they do not fit.
  bool TryReserve(size_t bytes, Reservation* out);
  size_t in_use() const { return in_use_.load(std::memory_order_relaxed); }
  size_t limit() const { return limit_; }

 private:
  bool Take(size_t bytes);
  void Give(size_t bytes) { in_use_.fetch_sub(bytes, std::memory_order_relaxed); }

  const size_t limit_;
  std::atomic<size_t> in_use_{0};
};

}  // namespace loomlight::batching
