// The Loomlight gRPC service (callback API): validation, limits and status codes; the work goes to the
// batcher. Nothing reaches a kernel unvalidated.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <memory>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/access.h"
#include "server/api/admission.h"
#include "server/api/host_worker.h"
#include "server/api/idle_streams.h"
#include "server/api/metrics.h"
#include "server/assets/btf_store.h"
#include "server/assets/environment_maps.h"
#include "server/assets/mesh_store.h"
#include "server/batching/batcher.h"
#include "server/batching/budget.h"
#include "server/models/material_cache.h"
#include "server/models/registry.h"
#include "server/render/folded_environment.h"

namespace loomlight::yarn {
class FiberSceneCache;  // server/yarn/fiber_scene_cache.h
}

namespace loomlight::api {

// Documented limits (docs/api.md#input-rules-shared-by-evaluate-sample-tabulate-textureslice-and-render).
constexpr size_t kMaxQueriesPerCall = size_t{1} << 20;  // 1,048,576 direction pairs
constexpr double kUnitTolerance = 1e-4;                 // | |w| - 1 | accepted (then renormalised)
constexpr int kMaxMessageBytes = 64 << 20;              // gRPC send/receive limit
// |u|, |v| accepted, in pattern repeats: at 1024 a float still resolves 1/32 of a cell of a 256-thread repeat.
constexpr float kMaxTextureCoordinate = 1024.0f;
// Bytes an Evaluate call holds per query beyond its request: f in double (24), a curtain's transmittance,
// interaction and split copies (64), the kernel's result (24), the launch's concatenated copy (36) and the
// response (12), rounded up.
constexpr size_t kEvaluateBytesPerQuery = 192;
// Evaluate calls up to this many queries of a cached material are validated and planned on gRPC's thread
// (microseconds); larger ones, and every call that must pack a material, on the service's preparer worker.
constexpr size_t kInlineEvaluateQueries = 4096;

// Limits of one service (docs/operations.md "Limits and admission").
struct ServiceLimits {
  size_t memory_budget_bytes = size_t{2} << 30;  // every call's buffers, cached environment maps
  size_t max_long_running_calls = 16;            // TextureSlice, Tabulate and Render calls at once
  size_t max_long_calls_per_client = 8;          // of them, one client's (its name, else its address)
  // Packed materials with their sampling tables and tabulated BRDFs (each up to 64 MiB: a silk's is 56), so a
  // catalogue's materials keep their tables from render to render.
  size_t material_cache_bytes = size_t{256} << 20;
  size_t fold_cache_bytes = size_t{128} << 20;  // BTF environment folds kept across Render calls
  size_t fiber_cache_bytes = size_t{256} << 20;  // fiber scenes (BVH, tubes, openness) kept across calls
  // A client-streaming call (UploadBtf) that sends nothing for this long is cancelled (server/api/idle_streams.h).
  std::chrono::milliseconds upload_idle_timeout{60000};
  // And one still sending after this long from its start (a client trickling just under the idle limit).
  std::chrono::milliseconds upload_max_duration{1800000};
};

// What the streaming and long-running RPC handlers (TextureSlice, Tabulate, Render) need from the service;
// all owned by it and outliving every call.
struct ServiceDeps {
  const models::Registry* registry = nullptr;
  batching::Batcher* batcher = nullptr;
  bool has_fp64 = false;
  Metrics* metrics = nullptr;
  models::MaterialCache* materials = nullptr;
  render::FoldCache* folds = nullptr;  // BTF environment folds (render::FoldCache), kept across Render calls
  yarn::FiberSceneCache* fiber_scenes = nullptr;  // built fiber scenes, kept across calls
  HostWorker* worker = nullptr;  // host work (directions, accumulation, encoding) off the batcher's thread
  HostWorker* loader = nullptr;  // reading and decoding assets (environment maps), off the host worker
  HostWorker* geometry = nullptr;  // generating yarn geometry and fitting lobes (FitMaterial), off the host worker
  // Evaluate's and Sample's material packing, checks, planning and last steps of large calls (server/api/unary_call.h)
  HostWorker* preparer = nullptr;
  batching::Budget* memory = nullptr;      // bytes every call reserves (server/api/admission.h)
  batching::Budget* long_calls = nullptr;  // slots of long-running calls
  ClientSlots* client_long_calls = nullptr;  // and each client's share of them
  assets::EnvironmentMaps* environments = nullptr;
  assets::BtfStore* btf_store = nullptr;  // null: the server keeps no BTF assets
  assets::MeshStore* mesh_store = nullptr;  // null: the server keeps no meshes (RenderRequest.mesh carries them)
  IdleStreams* idle_uploads = nullptr;     // UploadBtf and UploadMesh calls, cut off when they stop sending
  std::chrono::milliseconds max_upload_duration{0};  // and when they are still sending after this (0: never)
  // Server-streaming calls, cut off when their client reads nothing (server/api/stream_call.h; null: never).
  IdleStreams* stalled_writes = nullptr;
  CallCaps call_caps;  // how long a call may run when its client set no shorter deadline
  const TrustedProxies* trusted_proxies = &kNoTrustedProxies;  // whose X-Forwarded-For names the client
};

// Packs a material its handler checked with MaterialCache::Peek; on a worker, never on a gRPC thread (packing
// a thin layer solves its adding-doubling tables). OK, or INVALID_ARGUMENT as Get says.
grpc::Status PrepareMaterial(const ServiceDeps& deps, const v1::Material& material,
                             std::shared_ptr<const models::PreparedMaterial>* out);

// Admits a long-running call (TextureSlice, Tabulate, Render, YarnGeometry): its client's slot, a server slot
// and its buffers' bytes; OK or RESOURCE_EXHAUSTED saying which limit was reached.
grpc::Status AdmitLongCall(const ServiceDeps& deps, const grpc::ServerContextBase& context, size_t bytes,
                           Admission* out);

// Finishes a streaming call that never started streaming (a rejected request), recording it as `rpc`'s.
template <class Message>
class RejectedStream final : public grpc::ServerWriteReactor<Message> {
 public:
  RejectedStream(Metrics* metrics, const char* rpc, batching::Clock::time_point received, grpc::Status status) {
    metrics->Call(rpc, status.error_code(), std::chrono::duration<double>(batching::Clock::now() - received).count());
    this->Finish(std::move(status));
  }
  void OnDone() override { delete this; }
};

class LoomlightService final : public v1::Loomlight::CallbackService {
 public:
  // `deps` names the registry, batcher, metrics, budgets and environment maps (owned by the caller, outliving
  // the service); the service adds its material cache and workers.
  LoomlightService(const ServiceDeps& deps, const ServiceLimits& limits);
  ~LoomlightService() override;

  // Until set, every RPC is answered UNAVAILABLE (health reports NOT_SERVING meanwhile too).
  void SetServing(bool serving) { serving_ = serving; }
  // The service's single-thread workers, named: the health watchdog reads their progress (tests post to them).
  struct NamedWorker {
    const char* name;
    HostWorker* worker;
  };
  std::array<NamedWorker, 4> workers() {
    return {{{"host worker", &worker_}, {"asset loader", &loader_}, {"preparer", &preparer_},
             {"geometry worker", &geometry_}}};
  }
  const models::MaterialCache& materials() const { return materials_; }
  // Cancels the uploads that stopped sending (the watchdog's round).
  void CancelIdleUploads() { idle_uploads_.CancelIdle(); }
  // Brings the BTF assets and the meshes up to date with the data directory (another server sharing it may have
  // written), on the asset loader; a BTF change empties the caches holding assets' tables. Does nothing without a
  // store, or while the last sync is still queued.
  void SyncBtfAssets();

  grpc::ServerUnaryReactor* ListModels(grpc::CallbackServerContext* context, const v1::ListModelsRequest* request,
                                       v1::ListModelsResponse* response) override;
  // The scene registry's scenes (server/render/scene_registry.h), each at its parameters' defaults.
  grpc::ServerUnaryReactor* ListScenes(grpc::CallbackServerContext* context, const v1::ListScenesRequest* request,
                                       v1::ListScenesResponse* response) override;
  grpc::ServerUnaryReactor* Evaluate(grpc::CallbackServerContext* context, const v1::EvaluateRequest* request,
                                     v1::EvaluateResponse* response) override;
  // Delegates to HandleTextureSlice (server/api/texture_slice.h).
  grpc::ServerUnaryReactor* TextureSlice(grpc::CallbackServerContext* context, const v1::TextureSliceRequest* request,
                                         v1::TextureSliceResponse* response) override;
  // Delegates to HandleTabulate (server/api/tabulate.h).
  grpc::ServerWriteReactor<v1::TabulateChunk>* Tabulate(grpc::CallbackServerContext* context,
                                                       const v1::TabulateRequest* request) override;
  // Delegates to HandleRender (server/api/render_rpc.h).
  grpc::ServerWriteReactor<v1::RenderUpdate>* Render(grpc::CallbackServerContext* context,
                                                    const v1::RenderRequest* request) override;
  // Delegates to HandleYarnGeometry (server/api/yarn_rpc.h).
  grpc::ServerWriteReactor<v1::YarnGeometryChunk>* YarnGeometry(grpc::CallbackServerContext* context,
                                                               const v1::YarnGeometryRequest* request) override;
  // Delegates to HandleSample (server/api/sample_rpc.h).
  grpc::ServerUnaryReactor* Sample(grpc::CallbackServerContext* context, const v1::SampleRequest* request,
                                   v1::SampleResponse* response) override;
  // Delegate to server/api/btf_rpc.h.
  grpc::ServerWriteReactor<v1::CreateBtfProgress>* CreateBtf(grpc::CallbackServerContext* context,
                                                            const v1::CreateBtfRequest* request) override;
  grpc::ServerReadReactor<v1::UploadBtfMessage>* UploadBtf(grpc::CallbackServerContext* context,
                                                          v1::BtfAssetInfo* response) override;
  grpc::ServerUnaryReactor* ListBtfs(grpc::CallbackServerContext* context, const v1::ListBtfsRequest* request,
                                     v1::ListBtfsResponse* response) override;
  grpc::ServerUnaryReactor* DeleteBtf(grpc::CallbackServerContext* context, const v1::DeleteBtfRequest* request,
                                      v1::DeleteBtfResponse* response) override;
  // Delegates to HandleFitMaterial (server/api/fit_rpc.h).
  grpc::ServerUnaryReactor* FitMaterial(grpc::CallbackServerContext* context, const v1::FitMaterialRequest* request,
                                        v1::FitMaterialResponse* response) override;
  // Delegate to server/api/mesh_rpc.h.
  grpc::ServerReadReactor<v1::UploadMeshMessage>* UploadMesh(grpc::CallbackServerContext* context,
                                                            v1::MeshInfo* response) override;
  grpc::ServerUnaryReactor* ListMeshes(grpc::CallbackServerContext* context, const v1::ListMeshesRequest* request,
                                       v1::ListMeshesResponse* response) override;
  grpc::ServerUnaryReactor* DeleteMesh(grpc::CallbackServerContext* context, const v1::DeleteMeshRequest* request,
                                       v1::DeleteMeshResponse* response) override;

 private:
  // UNAVAILABLE while the service is not serving (warming up or draining), else OK.
  grpc::Status Serving() const;

  ServiceDeps deps_;
  models::MaterialCache materials_;
  render::FoldCache folds_;
  std::unique_ptr<yarn::FiberSceneCache> fiber_scenes_;
  ClientSlots client_long_calls_;
  IdleStreams idle_uploads_;
  std::atomic<bool> serving_{false};
  std::atomic<bool> sync_queued_{false};
  // Declared last, so destroyed first (the preparer and the loader before the worker): their remaining tasks
  // may still use the members above.
  HostWorker worker_;
  HostWorker loader_;
  HostWorker preparer_;  // Evaluate's material packing and large requests' validation and planning; Sample's work
  HostWorker geometry_;  // yarn generation, lobe fits (FitMaterial)
};

// Checks packed direction triples: a multiple of 3, finite, unit within kUnitTolerance. Returns "" or
// "field[i]: reason".
std::string ValidateDirections(const google::protobuf::RepeatedField<float>& w, const std::string& field);
// Evaluate's and Sample's checks of a call's precision (known, and fp64 only where the device has it), and of its
// query count (at most kMaxQueriesPerCall, named as `count_field`) and error_target; OK or the status to reply.
grpc::Status CheckPrecision(int precision, bool has_fp64);
grpc::Status CheckQueriesAndTarget(size_t n, const std::string& count_field, double error_target);
// Evaluate's checks that need no material (on the gRPC thread, before admission): precision, quantity, the
// arrays' lengths, the query count and error_target. OK or the status to reply.
grpc::Status CheckEvaluateRequest(const v1::EvaluateRequest& request, bool has_fp64);
// Evaluate's checks once the material is known (its model, and whether it has a curtain layer): directions,
// uv, fiber axes and the quantity against what the model serves. "" or the INVALID_ARGUMENT message.
std::string CheckEvaluateQueries(const v1::EvaluateRequest& request, const models::Model& model, bool has_layer);
// Checks texture coordinates: 2 per query, finite, within kMaxTextureCoordinate. Returns "" or "field[i]: reason".
std::string ValidateTextureCoordinates(const google::protobuf::RepeatedField<float>& uv, size_t n,
                                       const std::string& field);

}  // namespace loomlight::api
