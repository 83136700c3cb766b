// Assembles the service: OpenCL runtime (built and warmed), batcher, gRPC server with health and reflection.
#pragma once

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "server/api/access.h"
#include "server/api/service.h"
#include "server/assets/btf_store.h"
#include "server/batching/batcher.h"
#include "server/runtime/cl_runtime.h"

namespace loomlight::api {

struct ServerOptions {
  std::string address = "127.0.0.1:50051";  // port 0 picks a free port (see LoomlightServer::port)
  AccessOptions access;                     // TLS and tokens; plaintext only on loopback unless allowed
  runtime::RuntimeOptions runtime;
  batching::BatcherOptions batcher;
  std::string metrics_address;  // "host:port" for Prometheus' /metrics ("" = none; port 0 picks one)
  ServiceLimits limits;
  std::string environment_dir;                 // maps clients may name ("" = none)
  std::string data_dir;  // BTF assets under DATA_DIR/btf, meshes under DATA_DIR/meshes ("" = none: no asset RPCs)
  uint64_t btf_store_bytes = uint64_t{2} << 30;  // all BTF assets together (float32 tables)
  uint64_t btf_client_quota_bytes = uint64_t{1} << 30;  // one client's BTF assets (0: only the store's bound)
  uint64_t mesh_store_bytes = uint64_t{2} << 30;  // all meshes' files together (under DATA_DIR/meshes)
  uint64_t mesh_cache_bytes = uint64_t{512} << 20;  // parsed meshes kept for renders (TriangleMesh::memory_bytes)
  // How often the assets and meshes are brought up to date with the data directory (another replica sharing it
  // may have written or deleted one); 0 = only at start and on SyncBtfAssets (SIGHUP).
  std::chrono::seconds btf_sync_period{5};
  size_t environment_cache_bytes = size_t{256} << 20;  // decoded maps kept (within the memory budget)
  size_t grpc_memory_bytes = size_t{512} << 20;        // gRPC's own buffers (its resource quota)
  // Health reports NOT_SERVING while the host worker, the asset loader or a kernel launch has been busy
  // with one task for longer than this (stuck), and SERVING again when it recovers.
  std::chrono::milliseconds stall_limit{20000};
  std::chrono::milliseconds shutdown_grace{30000};  // in-flight calls may finish for this long on Shutdown
  CallCaps call_caps;  // a call's deadline is its client's, at most its priority's cap (--max-call-seconds)
  // A server-streaming call whose write waits this long on a client that reads nothing is cancelled.
  std::chrono::milliseconds stall_write_timeout{60000};
  // One client's share of the memory budget (limits.memory_budget_bytes), its calls together; 0: half.
  size_t memory_per_client_bytes = 0;
  // Per connection (HTTP/2): streams open at once (more wait in the client's transport); a keepalive ping after
  // this long without traffic, the connection closed when its answer takes longer than the timeout (a peer that
  // vanished is found even while idle); a maximum age, after which the client is told to reconnect (GOAWAY) and
  // its calls have the grace to finish (0: the bulk call cap, so the age never cuts a call the caps allow).
  int max_streams_per_connection = 100;
  std::chrono::milliseconds keepalive_time{60000}, keepalive_timeout{20000};
  std::chrono::milliseconds max_connection_age{3600000}, max_connection_age_grace{0};
  // Health Watch streams (unauthenticated, held as long as the client likes) open at once, overall and per
  // client (FairShareKey); more are RESOURCE_EXHAUSTED.
  size_t max_health_watches = 256, max_health_watches_per_client = 8;
};

class HealthService;  // grpc.health.v1.Health (server.cpp)

class LoomlightServer {
 public:
  // Listens (health NOT_SERVING), builds and warms the kernels, then reports SERVING.
  // Returns nullptr with *error set on failure (e.g. a kernel build log).
  static std::unique_ptr<LoomlightServer> Start(const ServerOptions& options, std::string* error);
  ~LoomlightServer();
  void Wait() { server_->Wait(); }
  // Health NOT_SERVING, no new calls; in-flight calls get the shutdown grace to finish, then are cancelled.
  void Shutdown();
  // Reads the tokens file again (SIGHUP); "" on success, else why the old tokens stay.
  std::string ReloadTokens();
  // Brings the BTF assets up to date with the data directory now (SIGHUP; the watchdog does it every
  // btf_sync_period), on the asset loader.
  void SyncBtfAssets();
  int port() const { return port_; }
  int metrics_port() const { return metrics_->port(); }
  const Metrics& metrics() const { return *metrics_; }
  const runtime::ClRuntime& runtime() const { return *runtime_; }
  // What calls hold now: bytes of the memory budget, and long-running call slots.
  size_t memory_in_use() const { return memory_->in_use(); }
  size_t long_calls_in_use() const { return long_calls_->in_use(); }
  // Health Watch streams open now, and the most ever open at once.
  size_t health_watches() const;
  size_t health_watches_peak() const;
  LoomlightService& service() { return *service_; }  // for tests: its workers
  assets::MeshStore* mesh_store() { return mesh_store_.get(); }  // for tests: what a render loads (null: none)

 private:
  LoomlightServer() = default;
  // Health and the service's gate together: SERVING only when warm, not draining and nothing is stuck.
  void UpdateServing();
  void Watch();  // the watchdog thread

  ServerOptions options_;
  std::unique_ptr<runtime::ClRuntime> runtime_;
  std::unique_ptr<batching::Batcher> batcher_;
  std::unique_ptr<Metrics> metrics_;
  std::unique_ptr<batching::Budget> memory_, long_calls_;
  std::unique_ptr<assets::EnvironmentMaps> environments_;
  std::unique_ptr<assets::BtfStore> btf_store_;
  std::unique_ptr<assets::MeshStore> mesh_store_;
  std::unique_ptr<IdleStreams> stalled_writes_;  // outlives the service and the gRPC server
  std::unique_ptr<LoomlightService> service_;
  std::unique_ptr<HealthService> health_;
  std::unique_ptr<grpc::Server> server_;
  std::shared_ptr<TokenAuthProcessor> tokens_;  // null when tokens are off
  int port_ = 0;
  std::mutex mutex_;  // guards the serving state below and the watchdog's wake-up
  std::condition_variable wake_;
  bool warm_ = false, draining_ = false, stuck_ = false;
  std::thread watchdog_;
  bool shut_down_ = false;
};

}  // namespace loomlight::api
