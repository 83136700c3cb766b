// Admission: what a call may hold while it runs, decided before it starts. Every call reserves the bytes
// its buffers will need from the service's memory budget; long-running calls (TextureSlice, Tabulate,
// Render) also take one of a fixed number of slots. What does not fit is answered RESOURCE_EXHAUSTED at
// once, instead of growing the process or queueing behind everyone else (README "Limits and admission").
#pragma once

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>

#include "server/batching/batcher.h"
#include "server/batching/budget.h"

namespace loomlight::api {

// What an admitted call holds; released when the call object holding it is destroyed.
struct Admission {
  batching::Budget::Reservation slot;   // long-running calls only
  batching::Budget::Reservation bytes;  // the call's buffers (may grow, e.g. by a decoded environment map)
};

// Reserves `bytes` (and a slot from `slots` when not null). Returns OK or RESOURCE_EXHAUSTED saying which
// limit was reached.
inline grpc::Status Admit(batching::Budget* memory, batching::Budget* slots, size_t bytes, Admission* out) {
  if (slots && !slots->TryReserve(1, &out->slot))
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, "the server is running its limit of " +
                                                      std::to_string(slots->limit()) +
                                                      " long-running calls (TextureSlice, Tabulate, Render, YarnGeometry); retry later"};
  if (!memory->TryReserve(bytes, &out->bytes)) {
    out->slot.Release();
    return {grpc::StatusCode::RESOURCE_EXHAUSTED,
            "the call needs " + std::to_string(bytes >> 20) + " MiB of buffers and the server's memory budget (" +
                std::to_string(memory->limit() >> 20) + " MiB) is in use; retry later"};
  }
  return grpc::Status::OK;
}

// Queues a job; OK, or the status its call ends with (the job is then not taken).
inline grpc::Status SubmitJob(batching::Batcher* batcher, std::shared_ptr<batching::Job> job) {
  switch (batcher->Submit(std::move(job))) {
    case batching::Batcher::Refusal::kNone: return grpc::Status::OK;
    case batching::Batcher::Refusal::kQueueFull:
      return {grpc::StatusCode::RESOURCE_EXHAUSTED, "evaluation queue is full; retry later"};
    case batching::Batcher::Refusal::kStopping: return {grpc::StatusCode::UNAVAILABLE, "server is shutting down"};
  }
  return {grpc::StatusCode::INTERNAL, "unknown batcher refusal"};
}

}  // namespace loomlight::api
