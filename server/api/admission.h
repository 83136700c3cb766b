// Admission: what a call may hold while it runs, decided before it starts. Every call reserves the bytes
// its buffers will need from the service's memory budget; long-running calls (TextureSlice, Tabulate,
// Render) also take one of a fixed number of slots. What does not fit is answered RESOURCE_EXHAUSTED at
// once, instead of growing the process or queueing behind everyone else; a call that could never fit is
// FAILED_PRECONDITION, and no call holds what it was admitted with past its priority's cap (CallCaps)
// (docs/operations.md "Limits and admission").
#pragma once

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

#include "server/batching/batcher.h"
#include "server/batching/budget.h"

namespace loomlight::api {

// Long-running calls per client: one client's streams cannot take every slot of the server's limit.
class ClientSlots {
 public:
  explicit ClientSlots(size_t per_client) : per_client_(per_client) {}
  // A client's slot until destroyed; move-only.
  class Hold {
   public:
    Hold() = default;
    Hold(Hold&& other) noexcept : owner_(other.owner_), client_(std::move(other.client_)) { other.owner_ = nullptr; }
    Hold& operator=(Hold&& other) noexcept {
      if (this != &other) {
        Release();
        owner_ = other.owner_;
        client_ = std::move(other.client_);
        other.owner_ = nullptr;
      }
      return *this;
    }
    ~Hold() { Release(); }
    void Release() {
      if (owner_) owner_->Give(client_);
      owner_ = nullptr;
    }

   private:
    friend class ClientSlots;
    ClientSlots* owner_ = nullptr;
    std::string client_;
  };
  bool TryTake(const std::string& client, Hold* out) {
    std::lock_guard<std::mutex> lock(mutex_);
    size_t& held = held_[client];
    if (held >= per_client_) return false;
    ++held;
    out->owner_ = this;
    out->client_ = client;
    return true;
  }
  size_t per_client() const { return per_client_; }

 private:
  void Give(const std::string& client) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (auto it = held_.find(client); it != held_.end() && --it->second == 0) held_.erase(it);
  }
  const size_t per_client_;
  std::mutex mutex_;
  std::unordered_map<std::string, size_t> held_;
};

// What an admitted call holds; released when the call object holding it is destroyed, the slots earlier by
// EndSlots.
struct Admission {
  ClientSlots::Hold client_slot;        // long-running calls only
  batching::Budget::Reservation slot;   // long-running calls only
  batching::Budget::Reservation bytes;  // the call's buffers (may grow, e.g. by a decoded environment map)
  // Gives back the slots as the call finishes (its work is over; its buffers go with the call object, later, on
  // a worker): a client that starts its next call the moment it sees this one end must find its slot free.
  void EndSlots() {
    client_slot.Release();
    slot.Release();
  }
};

// How long a call may hold what it was admitted with. gRPC calls have no deadline unless the client sets one,
// and such a call would hold its slot and bytes for as long as its work (or its client) lasts: a call's deadline
// is its client's, at most the server's cap for its priority (--max-call-seconds).
struct CallCaps {
  std::chrono::milliseconds interactive{120000};  // Evaluate, Sample, TextureSlice
  std::chrono::milliseconds bulk{3600000};        // Tabulate, Render, YarnGeometry, CreateBtf

  std::chrono::milliseconds of(batching::Priority priority) const {
    return priority == batching::Priority::kInteractive ? interactive : bulk;
  }
  // The deadline of a call of `priority` received at `received` whose client set `client_deadline` (max: none).
  batching::Clock::time_point Deadline(batching::Clock::time_point received, batching::Clock::time_point client_deadline,
                                       batching::Priority priority) const {
    return std::min(client_deadline, received + of(priority));
  }
  // The status a call ends with: a DEADLINE_EXCEEDED that was the cap (it came before the client's deadline)
  // says so, since the client set no such deadline itself.
  grpc::Status Explain(const grpc::Status& status, batching::Clock::time_point received,
                       batching::Clock::time_point client_deadline, batching::Priority priority) const {
    if (status.error_code() != grpc::StatusCode::DEADLINE_EXCEEDED || client_deadline <= received + of(priority))
      return status;
    return {grpc::StatusCode::DEADLINE_EXCEEDED,
            "the call ran for the server's limit on " + std::string(batching::PriorityName(priority)) + " calls, " +
                std::to_string(std::chrono::duration_cast<std::chrono::seconds>(of(priority)).count()) +
                " s (--max-call-seconds): ask for less work per call"};
  }
};

// Why `memory` does not hold `bytes` more for a call of `client` ("" for none) that already holds `held`:
// FAILED_PRECONDITION when they are more than the whole budget, or than one client's share of it, so no retry
// can succeed until the request shrinks or the operator raises --memory-budget-mb (gRPC's guide: do not retry
// until the system's state is fixed; this server answers a missing fp64 device the same way), else
// RESOURCE_EXHAUSTED, "retry later": the client's share, or the budget, is in use now.
inline grpc::Status MemoryRefusal(const batching::Budget& memory, size_t held, size_t bytes, const std::string& what,
                                  const std::string& client = "") {
  const size_t mib = (held + bytes + (size_t{1} << 20) - 1) >> 20;
  const std::string needs = what + " needs " + std::to_string(mib) + " MiB of buffers";
  const std::string budget = std::to_string(memory.limit() >> 20) + " MiB";
  const std::string share = std::to_string(memory.client_limit() >> 20) + " MiB, --max-memory-per-client-mb";
  if (bytes > memory.limit() || held > memory.limit() - bytes)
    return {grpc::StatusCode::FAILED_PRECONDITION,
            needs + ", more than the server's whole memory budget (" + budget +
                "): ask for less (fewer queries, a smaller image or table)"};
  if (!client.empty() && (bytes > memory.client_limit() || held > memory.client_limit() - bytes))
    return {grpc::StatusCode::FAILED_PRECONDITION,
            needs + ", more than one client's share of the server's memory budget (" + share +
                "): ask for less (fewer queries, a smaller image or table)"};
  if (!client.empty() && memory.client_in_use(client) + bytes > memory.client_limit())
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, needs + " and this client (" + client.substr(0, 80) +
                                                      ") holds its share of the memory budget (" + share +
                                                      ") in its other calls; retry when one ends"};
  return {grpc::StatusCode::RESOURCE_EXHAUSTED,
          needs + " and the server's memory budget (" + budget + ") is in use; retry later"};
}

// Reserves `bytes` for `client` (FairShareKey; "" for none), and a slot from `slots` when not null. Returns OK,
// RESOURCE_EXHAUSTED saying which limit was reached, or FAILED_PRECONDITION when the call needs more than the
// whole memory budget or one client's share of it (MemoryRefusal).
inline grpc::Status Admit(batching::Budget* memory, batching::Budget* slots, size_t bytes, Admission* out,
                          const std::string& client) {
  // A call no budget could hold is refused before it takes a slot (and whatever is in use).
  if (bytes > memory->limit() || (!client.empty() && bytes > memory->client_limit())) {
    out->client_slot.Release();
    return MemoryRefusal(*memory, 0, bytes, "the call", client);
  }
  if (slots && !slots->TryReserve(1, &out->slot)) {
    out->client_slot.Release();
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, "the server is running its limit of " +
                                                      std::to_string(slots->limit()) +
                                                      " long-running calls (TextureSlice, Tabulate, Render, YarnGeometry); retry later"};
  }
  if (!memory->TryReserveFor(client, bytes, &out->bytes)) {
    out->slot.Release();
    out->client_slot.Release();
    return MemoryRefusal(*memory, 0, bytes, "the call", client);
  }
  return grpc::Status::OK;
}

// Queues a job; OK, or the status its call ends with (the job is then not taken).
inline grpc::Status SubmitJob(batching::Batcher* batcher, std::shared_ptr<batching::Job> job) {
  switch (batcher->Submit(std::move(job))) {
    case batching::Batcher::Refusal::kNone: return grpc::Status::OK;
    case batching::Batcher::Refusal::kQueueFull:
      return {grpc::StatusCode::RESOURCE_EXHAUSTED, "evaluation queue is full; retry later"};
    case batching::Batcher::Refusal::kClientQueueFull:
      return {grpc::StatusCode::RESOURCE_EXHAUSTED,
              "this client's share of the evaluation queue is full; retry when its queued calls finish"};
    case batching::Batcher::Refusal::kStopping: return {grpc::StatusCode::UNAVAILABLE, "server is shutting down"};
  }
  return {grpc::StatusCode::INTERNAL, "unknown batcher refusal"};
}

}  // namespace loomlight::api
