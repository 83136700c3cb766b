// The YarnGeometry RPC: the fiber curves of a procedural yarn (server/yarn/), straight or laid out as the warp
// and weft of a weave, streamed to the client. The request is checked on the gRPC thread (cheap: parameters,
// layout, limits); the curves are generated on the service's geometry worker (deadline and cancellation stop
// it between fibers), then converted to float and written in ~1 MiB chunks from the host worker, one write in
// flight (server/api/stream_call.h).
#pragma once

#include <cstdint>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "server/yarn/yarn.h"

namespace loomlight::api {

// Documented limits (README "Yarn geometry"): a call's curves are bounded by these, or by the request's own
// lower max_fibers and max_control_points. The geometry is held in double until it is sent: about 24 bytes
// per control point and 64 per curve, charged to the memory budget at the call's limits.
constexpr uint64_t kMaxYarnFibers = 200'000;
constexpr uint64_t kMaxYarnControlPoints = 8'000'000;
constexpr size_t kYarnBytesPerPoint = 24;
constexpr size_t kYarnBytesPerFiber = 64;
// A woven layout's centre polylines, per vertex (server/yarn/layout.h), charged too.
constexpr size_t kLayoutBytesPerVertex = 130;
// Curve data per streamed chunk (each control point 12 bytes as float, each curve 24 bytes of attributes).
constexpr size_t kYarnChunkBytes = size_t{1} << 20;

// Yarn parameters of a request: the preset (default cotton1) with its overrides and seed. Returns "" or
// "yarn.field: reason".
std::string YarnParamsOf(const v1::Yarn& yarn, yarn::YarnParams* out);

// The schema and presets ListModels reports under `yarn`.
void DescribeYarnModel(v1::YarnModelInfo* out);

// Serves one call: validation errors finish at once; otherwise the reactor streams the summary and curves.
grpc::ServerWriteReactor<v1::YarnGeometryChunk>* HandleYarnGeometry(const ServiceDeps& deps,
                                                                   grpc::CallbackServerContext* context,
                                                                   const v1::YarnGeometryRequest* request);

}  // namespace loomlight::api
