// The gRPC status of a batcher job's outcome, shared by every RPC that runs kernel jobs.
#pragma once

#include <grpcpp/grpcpp.h>

#include "server/batching/batcher.h"

namespace loomlight::api {

inline grpc::Status ToStatus(const batching::JobResult& r) {
  switch (r.status) {
    case batching::JobStatus::kOk: return grpc::Status::OK;
    case batching::JobStatus::kDeadlineExceeded: return {grpc::StatusCode::DEADLINE_EXCEEDED, r.message};
    case batching::JobStatus::kCancelled: return {grpc::StatusCode::CANCELLED, r.message};
    case batching::JobStatus::kUnavailable: return {grpc::StatusCode::UNAVAILABLE, r.message};
    case batching::JobStatus::kInternal: return {grpc::StatusCode::INTERNAL, r.message};
    case batching::JobStatus::kResourceExhausted: return {grpc::StatusCode::RESOURCE_EXHAUSTED, r.message};
  }
  return {grpc::StatusCode::INTERNAL, "unknown job status"};
}

}  // namespace loomlight::api
