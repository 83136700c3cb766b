// The Loomlight gRPC service (callback API): validation, limits and status codes; the work goes to the
// batcher. Nothing reaches a kernel unvalidated.
#pragma once

#include <list>
#include <memory>
#include <mutex>
#include <unordered_map>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/metrics.h"
#include "server/batching/batcher.h"
#include "server/models/registry.h"

namespace loomlight::api {

// Documented limits (README "Limits").
constexpr size_t kMaxQueriesPerCall = size_t{1} << 20;  // 1,048,576 direction pairs
constexpr double kUnitTolerance = 1e-4;                 // | |w| - 1 | accepted (then renormalised)
constexpr int kMaxMessageBytes = 64 << 20;              // gRPC send/receive limit
// |u|, |v| accepted, in pattern repeats: at 1024 a float still resolves 1/32 of a cell of a 256-thread repeat.
constexpr float kMaxTextureCoordinate = 1024.0f;

// Resolved and packed materials by their serialized request form, least recently used first out: clients
// send the same few materials over and over, and resolving a preset (maps of parameter values) and packing
// it (the tangent curve sampled with cos/sin) costs as much as evaluating a small request.
class MaterialCache {
 public:
  struct Entry {
    const models::Model* model = nullptr;
    models::PackedMaterial packed;
    std::shared_ptr<const Entry> transmission;  // the curtain's layer (Material.transmission), or null
  };
  explicit MaterialCache(size_t capacity) : capacity_(capacity) {}
  // The cached entry, or one resolved now ("" on success, else the INVALID_ARGUMENT message).
  std::string Get(const v1::Material& material, const models::Registry& registry,
                  std::shared_ptr<const Entry>* out);

 private:
  // Resolves and packs one material (and its layer), naming fields under `field`.
  static std::string Resolve(const v1::Material& material, const models::Registry& registry,
                             const std::string& field, Entry* out);
  size_t capacity_;
  std::mutex mutex_;
  std::list<std::string> order_;  // most recently used first
  std::unordered_map<std::string, std::pair<std::shared_ptr<const Entry>, std::list<std::string>::iterator>> map_;
};

// What the streaming and long-running RPC handlers (TextureSlice, Tabulate, Render) need from the service;
// all owned by it and outliving every call.
struct ServiceDeps {
  const models::Registry* registry = nullptr;
  batching::Batcher* batcher = nullptr;
  bool has_fp64 = false;
  Metrics* metrics = nullptr;
  MaterialCache* materials = nullptr;
  HostWorker* worker = nullptr;  // host work (directions, accumulation, encoding) off the batcher's thread
};

// Finishes a streaming call that never started streaming (a rejected request).
template <class Message>
class RejectedStream final : public grpc::ServerWriteReactor<Message> {
 public:
  explicit RejectedStream(grpc::Status status) { this->Finish(std::move(status)); }
  void OnDone() override { delete this; }
};

class LoomlightService final : public v1::Loomlight::CallbackService {
 public:
  LoomlightService(const models::Registry* registry, batching::Batcher* batcher, bool has_fp64, Metrics* metrics)
      : registry_(registry), batcher_(batcher), has_fp64_(has_fp64), metrics_(metrics) {}

  grpc::ServerUnaryReactor* ListModels(grpc::CallbackServerContext* context, const v1::ListModelsRequest* request,
                                       v1::ListModelsResponse* response) override;
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

 private:
  ServiceDeps deps() { return {registry_, batcher_, has_fp64_, metrics_, &materials_, &worker_}; }
  // Finishes a call on the default reactor and records it.
  grpc::ServerUnaryReactor* Reply(grpc::CallbackServerContext* context, const char* rpc,
                                  batching::Clock::time_point received, grpc::Status status);

  const models::Registry* registry_;
  batching::Batcher* batcher_;
  bool has_fp64_;
  Metrics* metrics_;
  MaterialCache materials_{1024};
  // Declared last, so destroyed first: its remaining tasks may still use the members above.
  HostWorker worker_;
};

// Checks packed direction triples: a multiple of 3, finite, unit within kUnitTolerance. Returns "" or
// "field[i]: reason".
std::string ValidateDirections(const google::protobuf::RepeatedField<float>& w, const std::string& field);
// Checks texture coordinates: 2 per query, finite, within kMaxTextureCoordinate. Returns "" or "field[i]: reason".
std::string ValidateTextureCoordinates(const google::protobuf::RepeatedField<float>& uv, size_t n,
                                       const std::string& field);

}  // namespace loomlight::api
