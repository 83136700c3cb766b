// The TextureSlice RPC: an image of a spatially varying material's BTF over a region of texture space for
// one wi and wo. Pixels become BTF queries that go through the batcher in chunks (so a slice interleaves
// with other clients' work); the host work (sample positions, accumulation, encoding) runs on a worker
// thread (the service's HostWorker), never on the batcher's.
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

namespace loomlight::api {

// Documented limits (README "Limits").
constexpr uint32_t kMaxSliceSide = 2048;                   // width and height, pixels
constexpr uint32_t kMaxSamplesPerPixel = 256;
constexpr uint64_t kMaxSliceSamples = uint64_t{1} << 24;   // width x height x samples per pixel, per call
// Queries per batcher job: no larger than one Evaluate call, so that a big slice takes turns with other
// clients' launches instead of holding the device for seconds.
constexpr size_t kSliceChunkQueries = kMaxQueriesPerCall;

using TextureSliceDeps = ServiceDeps;

// The position in [0, 1)^2 inside pixel `pixel` (index y * width + x) of its sample `sample` of `samples`:
// the centre for one sample; otherwise the R2 sequence (i + 1/2) (0.7548776662, 0.5698402910) mod 1, shifted
// mod 1 by a fixed hash of the pixel index (a Cranley-Patterson rotation), so the result is deterministic
// but neighbouring pixels do not share one point set.
std::array<double, 2> PixelSampleOffset(uint64_t pixel, uint32_t sample, uint32_t samples);

// The bytes a validated request's call holds (its admission).
size_t SliceBytes(const v1::TextureSliceRequest& request);
// Checks every field except the material and device support. Returns "" or "field: reason".
std::string ValidateTextureSliceRequest(const v1::TextureSliceRequest& request);

// Serves one call; the reactor is finished exactly once, with the image or an error status.
grpc::ServerUnaryReactor* HandleTextureSlice(const TextureSliceDeps& deps, grpc::CallbackServerContext* context,
                                             const v1::TextureSliceRequest* request,
                                             v1::TextureSliceResponse* response);

}  // namespace loomlight::api
