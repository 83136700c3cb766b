// The Loomlight gRPC service (callback API): validation, limits and status codes; the work goes to the
// batcher. Nothing reaches a kernel unvalidated.
#pragma once

#include <atomic>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/batching/batcher.h"
#include "server/models/registry.h"

namespace loomlight::api {

// Documented limits (README "Limits").
constexpr size_t kMaxQueriesPerCall = size_t{1} << 20;  // 1,048,576 direction pairs
constexpr double kUnitTolerance = 1e-4;                 // | |w| - 1 | accepted (then renormalised)
constexpr int kMaxMessageBytes = 64 << 20;              // gRPC send/receive limit

class LoomlightService final : public v1::Loomlight::CallbackService {
 public:
  LoomlightService(const models::Registry* registry, batching::Batcher* batcher, bool has_fp64)
      : registry_(registry), batcher_(batcher), has_fp64_(has_fp64) {}

  grpc::ServerUnaryReactor* ListModels(grpc::CallbackServerContext* context, const v1::ListModelsRequest* request,
                                       v1::ListModelsResponse* response) override;
  grpc::ServerUnaryReactor* Evaluate(grpc::CallbackServerContext* context, const v1::EvaluateRequest* request,
                                     v1::EvaluateResponse* response) override;

 private:
  const models::Registry* registry_;
  batching::Batcher* batcher_;
  bool has_fp64_;
};

// Checks packed direction triples: a multiple of 3, finite, unit within kUnitTolerance. Returns "" or
// "field[i]: reason".
std::string ValidateDirections(const google::protobuf::RepeatedField<float>& w, const std::string& field);

}  // namespace loomlight::api
