#include "server/api/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/resource_quota.h>
#include <absl/synchronization/mutex.h>

#include <algorithm>
#include <cstdio>
#include <limits>
#include <map>
#include <set>
#include <unordered_map>

#include "grpc/health/v1/health.grpc.pb.h"

namespace loomlight::api {
namespace {
const char* kServiceName = "loomlight.v1.Loomlight";
namespace health = grpc::health::v1;

// A Watch refused before it started.
class RefusedWatch final : public grpc::ServerWriteReactor<health::HealthCheckResponse> {
 public:
  explicit RefusedWatch(grpc::Status status) { Finish(std::move(status)); }
  void OnDone() override { delete this; }
};
}  // namespace

// grpc.health.v1.Health, served here rather than by gRPC's default service, which bounds nothing: Watch needs no
// token (probes and load balancers carry none) and its stream stays open as long as its client likes, so open
// Watch streams are bounded overall and per client (FairShareKey), and the extras are RESOURCE_EXHAUSTED.
class HealthService final : public health::Health::CallbackService {
 public:
  HealthService(size_t max_watches, size_t max_per_client, const TrustedProxies* proxies)
      : max_watches_(max_watches), max_per_client_(max_per_client), proxies_(proxies) {}

  // Sets a service's status ("" is the server's) and tells its watchers.
  void Set(const std::string& service, bool serving) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (shut_down_) return;
    serving_[service] = serving;
    for (Watcher* watcher : watchers_)
      if (watcher->service == service) watcher->Send(Status(service));
  }
  // Every service NOT_SERVING from now on; each Watch is told so, then ends (it would hold the drain otherwise).
  void Shutdown() {
    std::lock_guard<std::mutex> lock(mutex_);
    shut_down_ = true;
    for (auto& [name, serving] : serving_) serving = false;
    for (Watcher* watcher : std::set<Watcher*>(watchers_)) {
      watcher->Send(Status(watcher->service));
      End(watcher, {grpc::StatusCode::UNAVAILABLE, "the server is shutting down"});
    }
  }
  size_t watches() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return watchers_.size();
  }
  size_t peak_watches() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return peak_;
  }

  grpc::ServerUnaryReactor* Check(grpc::CallbackServerContext* context, const health::HealthCheckRequest* request,
                                  health::HealthCheckResponse* response) override {
    grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
    std::lock_guard<std::mutex> lock(mutex_);
    if (serving_.count(request->service()) == 0) {
      reactor->Finish({grpc::StatusCode::NOT_FOUND, "unknown service"});
    } else {
      response->set_status(Status(request->service()));
      reactor->Finish(grpc::Status::OK);
    }
    return reactor;
  }

  grpc::ServerWriteReactor<health::HealthCheckResponse>* Watch(grpc::CallbackServerContext* context,
                                                               const health::HealthCheckRequest* request) override {
    const std::string client = FairShareKey(*context, *proxies_);
    std::lock_guard<std::mutex> lock(mutex_);
    if (shut_down_) return new RefusedWatch({grpc::StatusCode::UNAVAILABLE, "the server is shutting down"});
    if (watchers_.size() >= max_watches_)
      return new RefusedWatch({grpc::StatusCode::RESOURCE_EXHAUSTED,
                               "the server has its limit of " + std::to_string(max_watches_) +
                                   " health Watch streams open (--max-health-watches); use Check, or retry later"});
    size_t& own = per_client_[client];
    if (own >= max_per_client_)
      return new RefusedWatch({grpc::StatusCode::RESOURCE_EXHAUSTED,
                               "this client (" + client.substr(0, 80) + ") has its limit of " +
                                   std::to_string(max_per_client_) +
                                   " health Watch streams open (--max-health-watches-per-client); end one first"});
    ++own;
    auto* watcher = new Watcher(this, client, request->service().substr(0, 256));
    watchers_.insert(watcher);
    peak_ = std::max(peak_, watchers_.size());
    watcher->Send(Status(watcher->service));
    return watcher;
  }

 private:
  // One Watch stream: at most one write in flight; a change meanwhile is sent when it completes (the latest
  // status only, so a client that reads nothing holds one small message).
  class Watcher final : public grpc::ServerWriteReactor<health::HealthCheckResponse> {
   public:
    Watcher(HealthService* owner, std::string client, std::string service)
        : client(std::move(client)), service(std::move(service)), owner_(owner) {}
    // Under the owner's lock, as is every member below.
    void Send(health::HealthCheckResponse::ServingStatus status) {
      latest_ = status;
      if (writing_ || ending_ || (sent_any_ && status == response_.status())) return;
      writing_ = sent_any_ = true;
      response_.set_status(status);
      StartWrite(&response_);
    }
    void OnWriteDone(bool ok) override {
      std::lock_guard<std::mutex> lock(owner_->mutex_);
      writing_ = false;
      if (ending_) Finish(end_status_);
      else if (!ok) owner_->End(this, {grpc::StatusCode::CANCELLED, "the health Watch was cancelled"});
      else Send(latest_);
    }
    void OnCancel() override {
      std::lock_guard<std::mutex> lock(owner_->mutex_);
      owner_->End(this, {grpc::StatusCode::CANCELLED, "the health Watch was cancelled"});
    }
    void OnDone() override { delete this; }

    const std::string client, service;

   private:
    friend class HealthService;
    HealthService* const owner_;
    health::HealthCheckResponse response_;
    health::HealthCheckResponse::ServingStatus latest_ = health::HealthCheckResponse::UNKNOWN;
    bool writing_ = false, sent_any_ = false, ending_ = false;
    grpc::Status end_status_;
  };

  health::HealthCheckResponse::ServingStatus Status(const std::string& service) const {
    const auto it = serving_.find(service);
    if (it == serving_.end()) return health::HealthCheckResponse::SERVICE_UNKNOWN;
    return it->second ? health::HealthCheckResponse::SERVING : health::HealthCheckResponse::NOT_SERVING;
  }
  // Ends a watcher's stream (once its write in flight is done) and stops counting it. Under the lock.
  void End(Watcher* watcher, grpc::Status status) {
    if (watcher->ending_) return;
    watcher->ending_ = true;
    watchers_.erase(watcher);
    if (auto it = per_client_.find(watcher->client); it != per_client_.end() && --it->second == 0)
      per_client_.erase(it);
    if (watcher->writing_) watcher->end_status_ = std::move(status);
    else watcher->Finish(std::move(status));
  }

  const size_t max_watches_, max_per_client_;
  const TrustedProxies* const proxies_;
  mutable std::mutex mutex_;
  std::map<std::string, bool> serving_;  // by service name
  std::set<Watcher*> watchers_;          // open, not ending
  std::unordered_map<std::string, size_t> per_client_;
  size_t peak_ = 0;
  bool shut_down_ = false;
};

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
  s->memory_ = std::make_unique<batching::Budget>(
      options.limits.memory_budget_bytes,
      options.memory_per_client_bytes ? options.memory_per_client_bytes : options.limits.memory_budget_bytes / 2);
  s->long_calls_ = std::make_unique<batching::Budget>(options.limits.max_long_running_calls);
  s->environments_ = assets::EnvironmentMaps::Open(options.environment_dir, options.environment_cache_bytes,
                                                   s->memory_.get(), error);
  if (!s->environments_) return nullptr;
  if (!options.data_dir.empty()) {
    s->btf_store_ = assets::BtfStore::Open(options.data_dir, options.btf_store_bytes, error);
    if (!s->btf_store_) return nullptr;
    s->btf_store_->set_client_quota(options.btf_client_quota_bytes);
    s->mesh_store_ = assets::MeshStore::Open(options.data_dir, options.mesh_store_bytes, options.mesh_cache_bytes,
                                             assets::MeshLimits{}, error);
    if (!s->mesh_store_) return nullptr;
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
  deps.mesh_store = s->mesh_store_.get();
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
  grpc::EnableDefaultHealthCheckService(false);  // ours (HealthService) bounds its Watch streams
  s->health_ = std::make_unique<HealthService>(options.max_health_watches, options.max_health_watches_per_client,
                                               &s->options_.access.trusted_proxies);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.address, credentials, &s->port_);
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
  interceptors.push_back(s->metrics_->ClientCallCounter());
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  builder.RegisterService(s->service_.get());
  builder.RegisterService(s->health_.get());
  builder.SetMaxReceiveMessageSize(kMaxMessageBytes);
  builder.SetMaxSendMessageSize(kMaxMessageBytes);
  // Per connection: a bound on its streams (one connection cannot open thousands of calls), keepalive pings
  // even while no call is open (without data too: gRPC stops after two otherwise), so a peer that vanished
  // without closing is found and its connection's buffers freed, and a maximum age.
  const auto ms = [](std::chrono::milliseconds d) {
    return static_cast<int>(std::min<int64_t>(d.count(), std::numeric_limits<int>::max()));
  };
  builder.AddChannelArgument(GRPC_ARG_MAX_CONCURRENT_STREAMS, options.max_streams_per_connection);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, ms(options.keepalive_time));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, ms(options.keepalive_timeout));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PINGS_WITHOUT_DATA, 0);
  builder.AddChannelArgument(GRPC_ARG_MAX_CONNECTION_AGE_MS, ms(options.max_connection_age));
  const std::chrono::milliseconds grace =
      options.max_connection_age_grace.count() > 0
          ? options.max_connection_age_grace
          : std::max(options.call_caps.bulk, options.call_caps.interactive);
  builder.AddChannelArgument(GRPC_ARG_MAX_CONNECTION_AGE_GRACE_MS, ms(grace));
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
  health_->Set("", serving);
  health_->Set(kServiceName, serving);
}

size_t LoomlightServer::health_watches() const { return health_->watches(); }
size_t LoomlightServer::health_watches_peak() const { return health_->peak_watches(); }

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
    health_->Shutdown();
    // No new calls from here; in-flight ones may finish within the grace, then gRPC cancels them.
    server_->Shutdown(std::chrono::system_clock::now() + options_.shutdown_grace);
  }
  if (batcher_) batcher_->Stop();
}

LoomlightServer::~LoomlightServer() { Shutdown(); }

}  // namespace loomlight::api
