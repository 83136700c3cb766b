// The TextureSlice RPC: an image of a spatially varying material's BTF over a region of texture space for
// one wi and wo. Pixels become BTF queries that go through the batcher in chunks (so a slice interleaves
// with other clients' work); the host work (sample positions and per-pixel means, server/models/texture_slice.h;
// encoding) runs on a worker thread (the service's HostWorker), never on the batcher's.
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/metrics.h"
#include "server/api/service.h"
#include "server/batching/batcher.h"
#include "server/models/registry.h"
#include "server/models/texture_slice.h"

namespace loomlight::api {

// Documented limits (docs/api.md "TextureSlice").
constexpr uint32_t kMaxSliceSide = 2048;                   // width and height, pixels
constexpr uint32_t kMaxSamplesPerPixel = 256;
constexpr uint64_t kMaxSliceSamples = uint64_t{1} << 24;   // width x height x samples per pixel, per call
// Queries per batcher job: no larger than one Evaluate call, so that a big slice takes turns with other
// clients' launches instead of holding the device for seconds.
constexpr size_t kSliceChunkQueries = kMaxQueriesPerCall;

using TextureSliceDeps = ServiceDeps;

// Where each query samples (server/models/texture_slice.h); the tests name it through this header.
using models::PixelSampleOffset;

// The bytes a validated request's call holds (its admission).
size_t SliceBytes(const v1::TextureSliceRequest& request);
// Checks every field except the material and device support. Returns "" or "field: reason".
std::string ValidateTextureSliceRequest(const v1::TextureSliceRequest& request);

// Serves one call; the reactor is finished exactly once, with the image or an error status.
grpc::ServerUnaryReactor* HandleTextureSlice(const TextureSliceDeps& deps, grpc::CallbackServerContext* context,
                                             const v1::TextureSliceRequest* request,
                                             v1::TextureSliceResponse* response);

}  // namespace loomlight::api
