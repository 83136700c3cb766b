#include "server/api/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/resource_quota.h>
#include <absl/synchronization/mutex.h>

#include <cstdio>

namespace loomlight::api {
namespace {
const char* kServiceName = "loomlight.v1.Loomlight";
}  // namespace

std::unique_ptr<LoomlightServer> LoomlightServer::Start(const ServerOptions& options, std::string* error) {
  auto s = std::unique_ptr<LoomlightServer>(new LoomlightServer);
  s->options_ = options;
  // Credentials first: a missing certificate or a refused plaintext address fails before the kernels build.
  std::shared_ptr<grpc::ServerCredentials> credentials;
  *error = MakeServerCredentials(options.access, options.address, &credentials, &s->tokens_);
  if (!error->empty()) return nullptr;
  s->runtime_ = runtime::ClRuntime::Create(options.runtime, error);
  if (!s->runtime_) return nullptr;
  const models::Registry& registry = models::Registry::Global();
  if (!s->runtime_->BuildPrograms(registry, error)) return nullptr;

  s->metrics_ = std::make_unique<Metrics>();
  s->memory_ = std::make_unique<batching::Budget>(options.limits.memory_budget_bytes);
  s->long_calls_ = std::make_unique<batching::Budget>(options.limits.max_long_running_calls);
  s->environments_ = assets::EnvironmentMaps::Open(options.environment_dir, options.environment_cache_bytes,
                                                   s->memory_.get(), error);
  if (!s->environments_) return nullptr;
  if (!options.data_dir.empty()) {
    s->btf_store_ = assets::BtfStore::Open(options.data_dir, options.btf_store_bytes, error);
    if (!s->btf_store_) return nullptr;
    s->btf_store_->set_client_quota(options.btf_client_quota_bytes);
  }
  s->batcher_ = std::make_unique<batching::Batcher>(s->runtime_.get(), options.batcher);
  ServiceDeps deps;
  deps.registry = &registry;
  deps.batcher = s->batcher_.get();
  deps.has_fp64 = s->runtime_->has_fp64();
  deps.metrics = s->metrics_.get();
  deps.memory = s->memory_.get();
  deps.long_calls = s->long_calls_.get();
  deps.environments = s->environments_.get();
  deps.btf_store = s->btf_store_.get();
  deps.trusted_proxies = &s->options_.access.trusted_proxies;
  s->stalled_writes_ = std::make_unique<IdleStreams>(options.stall_write_timeout);
  deps.stalled_writes = s->stalled_writes_.get();
  deps.call_caps = options.call_caps;
  s->service_ = std::make_unique<LoomlightService>(deps, options.limits);
  if (!options.metrics_address.empty()) {
    *error = s->metrics_->Serve(options.metrics_address, options.access, s->tokens_);
    if (!error->empty()) return nullptr;
  }
  // Debian builds Abseil without NDEBUG, which leaves its lock-order graph (a deadlock detector for debugging)
  // running on every gRPC mutex acquisition: measured at ~4% of the server's CPU on small calls.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.address, credentials, &s->port_);
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
  interceptors.push_back(s->metrics_->ClientCallCounter());
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  builder.RegisterService(s->service_.get());
  builder.SetMaxReceiveMessageSize(kMaxMessageBytes);
  builder.SetMaxSendMessageSize(kMaxMessageBytes);
  // gRPC's own buffers (requests being received, replies being sent) are bounded too.
  grpc::ResourceQuota quota("loomlight");
  quota.Resize(options.grpc_memory_bytes);
  builder.SetResourceQuota(quota);
  s->server_ = builder.BuildAndStart();
  if (!s->server_ || s->port_ == 0) {
    *error = "cannot listen on " + options.address;
    return nullptr;
  }
  s->UpdateServing();  // NOT_SERVING: every RPC is answered UNAVAILABLE until warm
  // Warm before SERVING: PoCL compiles each kernel for the work-group size on first launch.
  if (!s->runtime_->Warm(registry, error)) {
    s->Shutdown();
    return nullptr;
  }
  {
    std::lock_guard<std::mutex> lock(s->mutex_);
    s->warm_ = true;
  }
  s->UpdateServing();
  s->watchdog_ = std::thread([server = s.get()] { server->Watch(); });
  return s;
}

std::string LoomlightServer::ReloadTokens() {
  if (!tokens_) return "no tokens file is in use (--tokens)";
  std::string error;
  auto table = TokenTable::Load(options_.access.tokens_file, &error);
  // Fail closed: a file that does not load leaves no token valid (TokenAuthProcessor::Fail), rather than
  // keeping one the operator just removed; the replica reports NOT_SERVING until a reload succeeds.
  if (table) tokens_->Replace(std::move(table));
  else tokens_->Fail(error);
  UpdateServing();
  return error;
}

void LoomlightServer::SyncBtfAssets() { service_->SyncBtfAssets(); }

void LoomlightServer::UpdateServing() {
  std::lock_guard<std::mutex> lock(mutex_);  // held throughout, so concurrent updates cannot end stale
  const bool serving = warm_ && !draining_ && !stuck_ && (!tokens_ || tokens_->failure().empty());
  service_->SetServing(serving);
  grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService();
  health->SetServingStatus("", serving);
  health->SetServingStatus(kServiceName, serving);
}

void LoomlightServer::Watch() {
  const auto period = std::min<std::chrono::milliseconds>(std::chrono::milliseconds(500), options_.stall_limit / 4);
  std::unique_lock<std::mutex> lock(mutex_);
  auto next_sync = batching::Clock::now() + options_.btf_sync_period;
  while (!draining_) {
    wake_.wait_for(lock, period, [this] { return draining_; });
    if (draining_) return;
    if (options_.btf_sync_period.count() > 0 && batching::Clock::now() >= next_sync) {
      service_->SyncBtfAssets();  // queued on the asset loader: the watchdog does no disk work itself
      next_sync = batching::Clock::now() + options_.btf_sync_period;
    }
    metrics_->Resources({memory_->in_use(), memory_->limit(), long_calls_->in_use(), long_calls_->limit(),
                         service_->materials().bytes(), warm_ && !stuck_});
    metrics_->Queues(batcher_->Stats());
    service_->CancelIdleUploads();
    stalled_writes_->CancelIdle();
    const auto now = batching::Clock::now();
    std::string reason;
    const auto seconds = [&](batching::Clock::time_point since) {
      return std::to_string(std::chrono::duration_cast<std::chrono::seconds>(now - since).count()) + " s";
    };
    // Stuck is no progress, not long: a worker's task reports progress as it ends each bounded step (yarn
    // generation between fibers, a map's read and decode), so only a task silent for the limit counts. One
    // kernel launch cannot report; it counts from its start.
    for (const auto& [what, worker] : service_->workers()) {
      const batching::Clock::time_point progress = worker->last_progress(), since = worker->busy_since();
      if (progress != batching::Clock::time_point::max() && since != batching::Clock::time_point::max() &&
          now - progress > options_.stall_limit)
        reason = std::string(what) + " busy with one task for " + seconds(since) + ", no progress for " +
                 seconds(progress);
    }
    if (const batching::Clock::time_point since = batcher_->busy_since();
        since != batching::Clock::time_point::max() && now - since > options_.stall_limit)
      reason = "kernel launch busy with one task for " + seconds(since);
    if (reason.empty() == !stuck_) continue;
    stuck_ = !reason.empty();
    std::fprintf(stderr, "loomlight-server: %s\n",
                 stuck_ ? ("NOT_SERVING: " + reason).c_str() : "SERVING again: nothing is stuck");
    lock.unlock();
    UpdateServing();
    lock.lock();
  }
}

void LoomlightServer::Shutdown() {
  if (shut_down_) return;
  shut_down_ = true;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    draining_ = true;
  }
  wake_.notify_all();
  if (watchdog_.joinable()) watchdog_.join();
  if (server_) {
    UpdateServing();
    // No new calls from here; in-flight ones may finish within the grace, then gRPC cancels them.
    server_->Shutdown(std::chrono::system_clock::now() + options_.shutdown_grace);
  }
  if (batcher_) batcher_->Stop();
}

LoomlightServer::~LoomlightServer() { Shutdown(); }

}  // namespace loomlight::api
