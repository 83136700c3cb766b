// The Render RPC: a thumbnail of a material on a preset scene. This layer validates the request, admits it,
// translates it into the renderer's inputs (server/render/renderer.h: scene, camera, lights, material, fidelity
// options), sends the renderer's chunks of shading queries through the batcher as Evaluate-style jobs and
// streams progress and the encoded image. The renderer and encoding run on the service's HostWorker, never on
// the batcher's thread or a gRPC callback thread.
#pragma once

#include <cstdint>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/metrics.h"
#include "server/api/service.h"
#include "server/api/yarn_rpc.h"
#include "server/batching/batcher.h"
#include "server/models/registry.h"
#include "server/render/renderer.h"
#include "server/render/shading.h"

namespace loomlight::api {

// Documented limits (docs/thumbnails.md "Limits").
constexpr uint32_t kMaxRenderSide = 4096;                      // width and height, pixels
constexpr uint32_t kMaxRenderViews = 72;                       // a turntable's images (RenderRequest.views)
// The final message's images together (a turntable's first view twice), under one message's limit.
constexpr size_t kMaxRenderReplyBytes = size_t(kMaxMessageBytes) - (size_t{1} << 20);
constexpr size_t kMaxMeshMaterialName = 256;                   // RenderRequest.materials[].mesh_material, bytes
// Meshes sent with a request: bytes a parse may take per byte of the file (an OBJ's "f 1 2 3" line of 8 bytes
// becomes a triangle of 12 and up to three vertices of 48), and at most (the limits' triangles and vertices).
constexpr uint64_t kMeshParseBytesPerFileByte = 24;
constexpr uint64_t kMaxMeshParseBytes = uint64_t{512} << 20;
// An Embree BVH of triangles takes about 60-120 bytes per triangle (measured: docs/products.md); admitted at this
// bound, which also bounds the build.
constexpr uint64_t kMeshBvhBytesPerTriangle = 160;
constexpr uint32_t kMaxRenderSamplesPerPixel = 1024;
constexpr uint32_t kDefaultRenderSamplesPerPixel = 16;          // samples_per_pixel 0
constexpr uint64_t kMaxRenderSamples = uint64_t{1} << 26;      // width x height x samples per pixel
constexpr int kMaxRenderLights = 16;
constexpr double kMaxSceneCoordinate = 1e4;                    // |x|, |y|, |z| of cameras and point lights
constexpr double kMaxLightValue = 1e9;                         // per RGB channel
constexpr double kMaxTextureScale = 1e5;                       // pattern repeats per unit
constexpr double kMinFovDeg = 1, kMaxFovDeg = 150;
// Fiber scenes: the most fiber curves and control points one render generates (about 16 times a 2 x 2 repeat
// twill patch of cotton1 at full detail); their BVH is bounded by the memory budget as it is built.
constexpr uint64_t kMaxRenderFibers = 100'000;
constexpr uint64_t kMaxRenderFiberPoints = 2'000'000;

using RenderDeps = ServiceDeps;

// The renderer's status as the call's, and the call's stop (deadline, cancellation) as the renderer's token.
grpc::Status ToGrpc(const render::Status& status);
render::Status FromGrpc(const grpc::Status& status);

// The renderer's (and CreateBtf's synthesis') QueryEvaluator over the batcher, for one call: each plan of a
// chunk as bulk jobs, one per part, stopped by the call's deadline or cancellation; each part's launch in the
// metrics (and its queries as rendered, `count_rendered`); the chunk's outcome posted to the call's turn on the
// host worker once every part has returned, `pump` after each part before then.
class BatcherEvaluator final : public render::QueryEvaluator {
 public:
  struct Call {
    batching::Batcher* batcher = nullptr;
    Metrics* metrics = nullptr;
    bool fp64 = false;
    batching::Clock::time_point deadline;
    grpc::CallbackServerContext* context = nullptr;
    std::string client;  // FairShareKey
    std::function<void(std::function<void()>)> post;  // runs a task in the call's turn on the host worker
    std::function<void()> pump;
    bool count_rendered = false;
  };
  explicit BatcherEvaluator(Call call) : call_(std::move(call)) {}
  void Submit(std::vector<render::ShadingWork> work, std::function<void(const render::ShadingOutcome&)> done) override;

 private:
  struct ChunkJobs;
  void OnJobDone(ChunkJobs& chunk, const models::EvaluationPlan& plan, size_t part, const batching::JobResult& result);
  const Call call_;
};

// Checks every field except the material, whether a named environment map exists and device support.
// Returns "" or "field: reason".
std::string ValidateRenderRequest(const v1::RenderRequest& request);
// A fiber scene's yarn at the detail chosen and, when that is AUTO's thinning, at full detail to check it by.
struct FiberJobs {
  std::unique_ptr<YarnJob> chosen, full;
};
// Every check of a request once its material's model is known (no packing, no map read, no fiber generated):
// its fields (ValidateRenderRequest), fp64 where the device has it, and for a fiber scene its yarn and a fiber
// model, whose jobs and level of detail go to *fiber_jobs and *detail. OK or the status to reply.
grpc::Status CheckRenderRequest(const models::Registry& registry, const v1::RenderRequest& request,
                                const models::Model& model, bool has_fp64, FiberJobs* fiber_jobs,
                                render::RenderSetup::FiberDetail* detail);
// The bytes a validated request's call holds (its admission), before any environment map is decoded.
size_t RenderBytes(const v1::RenderRequest& request);

// Serves one call: validation errors finish at once; otherwise the reactor streams progress and the image.
grpc::ServerWriteReactor<v1::RenderUpdate>* HandleRender(const RenderDeps& deps, grpc::CallbackServerContext* context,
                                                         const v1::RenderRequest* request);

}  // namespace loomlight::api
