// The Sample RPC: importance sampling of a material for client renderers. For each wo (and uv) of a batch, a
// direction wi drawn from the material's sampler (server/models/direction_sampler.h: a tabulated density that
// is exact, the same one the Render RPC samples), its pdf, f(wi, wo) evaluated through the batcher exactly as
// Evaluate does, and the weight f |cos| / pdf. Validation and limits are Evaluate's; the material, its sampling
// table (built on first use, tens to hundreds of milliseconds) and the drawing run on the service's preparer
// worker, never on a gRPC callback thread or the batcher's.
#pragma once

#include <cstddef>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/service.h"

namespace loomlight::api {

// Bytes a Sample call holds per query beyond its request: Evaluate's (kEvaluateBytesPerQuery: f, a curtain's
// split copies, the kernel's result and the launch's copy) plus the response's wi, pdf and weight (28),
// rounded up.
constexpr size_t kSampleBytesPerQuery = 256;
// Queries drawn per preparer task: a large call takes turns with other calls' preparation, and its deadline
// and cancellation are checked between chunks.
constexpr size_t kSampleDrawChunk = 65536;
// Calls up to this many queries compute their weights on the batcher's thread when f arrives (microseconds);
// larger ones on the preparer.
constexpr size_t kInlineSampleWeights = 4096;

// Checks SampleRequest.random for n queries: empty, or 3 n numbers, each finite in [0, 1). Returns "" or
// "random...: reason".
std::string ValidateSampleRandom(const google::protobuf::RepeatedField<float>& random, size_t n);

// Sample's checks that need no material (on the gRPC thread, before admission): precision, some wo, the query
// count and error_target. OK or the status to reply.
grpc::Status CheckSampleRequest(const v1::SampleRequest& request, bool has_fp64);
// Sample's checks once the material's model is known: wo, uv against what the model serves, and random. "" or the
// INVALID_ARGUMENT message.
std::string CheckSampleQueries(const v1::SampleRequest& request, const models::Model& model);

// Serves one call (the service has checked that it is serving); the reactor is finished exactly once, with the
// samples or an error status.
grpc::ServerUnaryReactor* HandleSample(const ServiceDeps& deps, grpc::CallbackServerContext* context,
                                       const v1::SampleRequest* request, v1::SampleResponse* response);

}  // namespace loomlight::api
