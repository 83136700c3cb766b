// One byte budget for everything requests make the server hold: queued and in-flight queries, unsent
// stream bytes, decoded environment maps, render and table buffers. Work reserves its bytes before it
// starts and gives them back when done; a reservation that does not fit is refused (the caller answers
// RESOURCE_EXHAUSTED), so load never grows the process past the budget. A call's reservation is also its
// client's: one client's reservations together hold at most the client limit, so one client cannot take the
// whole budget from the others.
#pragma once

#include <atomic>
#include <cstddef>
#include <mutex>
#include <string>
#include <unordered_map>

namespace loomlight::batching {

class Budget {
 public:
  // `client_limit_bytes`: what one client's reservations may hold together (0 or more than the limit: the limit).
  explicit Budget(size_t limit_bytes, size_t client_limit_bytes = 0)
      : limit_(limit_bytes),
        client_limit_(client_limit_bytes == 0 || client_limit_bytes > limit_bytes ? limit_bytes : client_limit_bytes) {}
  Budget(const Budget&) = delete;
  Budget& operator=(const Budget&) = delete;

  // Bytes held from the budget until destroyed (or Release); move-only. An empty one holds nothing.
  class Reservation {
   public:
    Reservation() = default;
    Reservation(Reservation&& other) noexcept
        : budget_(other.budget_), bytes_(other.bytes_), client_(std::move(other.client_)) {
      other.bytes_ = 0;
    }
    Reservation& operator=(Reservation&& other) noexcept;
    ~Reservation() { Release(); }
    // Holds `bytes` more; false (nothing changes) when the budget, or its client's limit, cannot take them.
    bool Grow(size_t bytes);
    void Release();
    size_t bytes() const { return bytes_; }
    const std::string& client() const { return client_; }  // "" when the server's own

   private:
    friend class Budget;
    Budget* budget_ = nullptr;
    size_t bytes_ = 0;
    std::string client_;
  };

  // Reserves `bytes` into *out (which must be empty or of this budget, and of the same client); false when they
  // do not fit. `client` "" is the server's own (a cache): only the whole budget bounds it.
  bool TryReserve(size_t bytes, Reservation* out) { return TryReserveFor("", bytes, out); }
  bool TryReserveFor(const std::string& client, size_t bytes, Reservation* out);
  size_t in_use() const { return in_use_.load(std::memory_order_relaxed); }
  size_t limit() const { return limit_; }
  size_t client_limit() const { return client_limit_; }
  size_t client_in_use(const std::string& client) const;

 private:
  bool Take(const std::string& client, size_t bytes);
  bool TakeFromWhole(size_t bytes);
  void Give(const std::string& client, size_t bytes);

  const size_t limit_, client_limit_;
  std::atomic<size_t> in_use_{0};
  mutable std::mutex clients_mutex_;
  std::unordered_map<std::string, size_t> clients_;  // bytes held, by client; none at 0
};

}  // namespace loomlight::batching
