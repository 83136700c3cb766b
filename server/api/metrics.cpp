#include "server/api/metrics.h"

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <thread>

namespace loomlight::api {
namespace {

const char* CodeName(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK: return "OK";
    case grpc::StatusCode::CANCELLED: return "CANCELLED";
    case grpc::StatusCode::INVALID_ARGUMENT: return "INVALID_ARGUMENT";
    case grpc::StatusCode::DEADLINE_EXCEEDED: return "DEADLINE_EXCEEDED";
    case grpc::StatusCode::RESOURCE_EXHAUSTED: return "RESOURCE_EXHAUSTED";
    case grpc::StatusCode::FAILED_PRECONDITION: return "FAILED_PRECONDITION";
    case grpc::StatusCode::UNAVAILABLE: return "UNAVAILABLE";
    case grpc::StatusCode::INTERNAL: return "INTERNAL";
    default: return "OTHER";
  }
}

// Powers of `step` from `first`, `count` of them: histogram buckets spanning several decades.
prometheus::Histogram::BucketBoundaries Geometric(double first, double step, int count) {
  prometheus::Histogram::BucketBoundaries b;
  for (int i = 0; i < count; ++i) b.push_back(first * std::pow(step, i));
  return b;
}

}  // namespace

Metrics::Metrics()
    : registry_(std::make_shared<prometheus::Registry>()),
      calls_(prometheus::BuildCounter()
                 .Name("loomlight_calls_total")
                 .Help("Finished RPCs by method and status code")
                 .Register(*registry_)),
      call_seconds_(prometheus::BuildHistogram()
                        .Name("loomlight_call_seconds")
                        .Help("Time in the server per RPC")
                        .Register(*registry_)),
      queries_(prometheus::BuildCounter()
                   .Name("loomlight_queries_total")
                   .Help("Direction pairs evaluated, by model and precision")
                   .Register(*registry_)),
      tabulated_cells_(prometheus::BuildCounter()
                           .Name("loomlight_tabulated_cells_total")
                           .Help("Table cells evaluated by Tabulate calls, by model and precision")
                           .Register(*registry_)),
      rendered_queries_(prometheus::BuildCounter()
                            .Name("loomlight_rendered_queries_total")
                            .Help("Shading queries evaluated by Render calls")
                            .Register(*registry_)),
      launch_queries_(prometheus::BuildHistogram()
                          .Name("loomlight_launch_queries")
                          .Help("Queries in the kernel launch each request rode in")
                          .Register(*registry_)
                          .Add({}, Geometric(1, 4, 11))),
      launch_requests_(prometheus::BuildHistogram()
                           .Name("loomlight_launch_requests")
                           .Help("Requests coalesced into the launch each request rode in")
                           .Register(*registry_)
                           .Add({}, Geometric(1, 2, 9))),
      queue_seconds_(prometheus::BuildHistogram()
                         .Name("loomlight_queue_seconds")
                         .Help("Time a request waited for its launch")
                         .Register(*registry_)
                         .Add({}, Geometric(1e-5, 4, 10))),
      kernel_seconds_(prometheus::BuildHistogram()
                          .Name("loomlight_kernel_seconds")
                          .Help("Duration of the launch each request rode in")
                          .Register(*registry_)
                          .Add({}, Geometric(1e-5, 4, 10))),
      resources_(prometheus::BuildGauge()
                     .Name("loomlight_resource")
                     .Help("Admission resources, sampled every half second: memory budget bytes and long-running "
                           "call slots (in use and limit), material cache bytes, serving (1) or not (0)")
                     .Register(*registry_)),
      client_calls_(prometheus::BuildCounter()
                        .Name("loomlight_client_calls_total")
                        .Help("Finished calls by client (token's client, certificate name or anonymous), call "
                              "and status code")
                        .Register(*registry_)),
      queues_(prometheus::BuildGauge()
                  .Name("loomlight_queue")
                  .Help("The batcher's queues by priority (interactive, bulk), sampled every half second: queued "
                        "jobs, queries, bytes and clients, and queries in a kernel launch now")
                  .Register(*registry_)) {}

namespace {

// One call seen by the interceptor: its client and method are known at the start, its status at the end.
class ClientCallInterceptor : public grpc::experimental::Interceptor {
 public:
  ClientCallInterceptor(Metrics* metrics, grpc::experimental::ServerRpcInfo* info) : metrics_(metrics), info_(info) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(grpc::experimental::InterceptionHookPoints::PRE_SEND_STATUS))
      metrics_->ClientCall(ClientName(*info_->server_context()), CallName(info_->method()),
                           methods->GetSendStatus().error_code());
    methods->Proceed();
  }

 private:
  Metrics* metrics_;
  grpc::experimental::ServerRpcInfo* info_;
};

class ClientCallInterceptorFactory : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit ClientCallInterceptorFactory(Metrics* metrics) : metrics_(metrics) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override {
    return new ClientCallInterceptor(metrics_, info);
  }

 private:
  Metrics* metrics_;
};

}  // namespace

std::string Metrics::Serve(const std::string& address, const AccessOptions& access,
                           std::shared_ptr<TokenAuthProcessor> tokens) {
  // Plaintext HTTP always: bookworm's civetweb 1.15 crashes serving HTTPS with OpenSSL 3 (it looks up
  // SSL_get_peer_certificate, a macro since 3.0, and calls the null pointer). So /metrics is kept to loopback
  // (a local scraper or agent) unless the operator allows otherwise, and with tokens needs one.
  if (!access.allow_plaintext_remote && !IsLoopbackAddress(address))
    return "refusing plaintext metrics on " + address +
           ", which is not a loopback address (metrics are served over plaintext HTTP only): use a loopback "
           "address, or --allow-plaintext-remote";
  try {
    exposer_ = std::make_unique<prometheus::Exposer>(address, 1);
  } catch (const std::exception& e) {
    return "cannot serve metrics on " + address + ": " + e.what();
  }
  exposer_->RegisterCollectable(registry_);
  metrics_tokens_ = std::move(tokens);
  if (metrics_tokens_)
    exposer_->RegisterAuth(
        [this](const std::string& user, const std::string& password) {
          const TokenTable::Entry* entry = metrics_tokens_->table()->Find(password);
          // Allows("metrics") holds only for a token that lists `metrics`: `*` is every RPC, not scraping.
          return entry != nullptr && entry->client == user && entry->Allows("metrics");
        },
        "loomlight metrics");
  return "";
}

// civetweb (under prometheus::Exposer) polls its listening socket in 2 s quanta and sees a stop only between them,
// so destroying the exposer took up to 2 s: every test server's end. A connection (closed at once: the worker that
// takes it reads end of file) wakes the poll; one every few ms until the exposer is gone.
Metrics::~Metrics() {
  if (!exposer_) return;
  const int port = this->port();
  std::atomic<bool> stopped{false};
  std::thread waker([port, &stopped] {
    while (!stopped) {
      const int fd = socket(AF_INET, SOCK_STREAM, 0);
      sockaddr_in addr{};
      addr.sin_family = AF_INET;
      addr.sin_port = htons(static_cast<uint16_t>(port));
      addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);  // an exposer on another address stops as before
      connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
      close(fd);
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  });
  exposer_.reset();
  stopped = true;
  waker.join();
}

std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> Metrics::ClientCallCounter() {
  return std::make_unique<ClientCallInterceptorFactory>(this);
}

void Metrics::ClientCall(const std::string& client, const std::string& call, grpc::StatusCode code) {
  prometheus::Counter* counter;
  {
    std::lock_guard<std::mutex> lock(children_mutex_);
    const std::string code_name = CodeName(code);
    prometheus::Counter*& c = client_call_counters_[client + '\0' + call + '\0' + code_name];
    if (!c) c = &client_calls_.Add({{"client", client}, {"call", call}, {"code", code_name}});
    counter = c;
  }
  counter->Increment();
}

int Metrics::port() const {
  if (!exposer_) return 0;
  const auto ports = exposer_->GetListeningPorts();
  return ports.empty() ? 0 : ports.front();
}

void Metrics::Call(const std::string& rpc, grpc::StatusCode code, double seconds) {
  prometheus::Counter* counter;
  prometheus::Histogram* histogram;
  {
    std::lock_guard<std::mutex> lock(children_mutex_);
    const std::string code_name = CodeName(code);
    prometheus::Counter*& c = call_counters_[rpc + '\0' + code_name];
    if (!c) c = &calls_.Add({{"rpc", rpc}, {"code", code_name}});
    prometheus::Histogram*& h = call_histograms_[rpc];
    if (!h) h = &call_seconds_.Add({{"rpc", rpc}}, Geometric(1e-5, 4, 10));
    counter = c;
    histogram = h;
  }
  counter->Increment();
  histogram->Observe(seconds);
}

void Metrics::Evaluated(const std::string& model, bool fp64, size_t queries, size_t launch_queries,
                        size_t launch_requests, double queue_seconds, double kernel_seconds) {
  const char* precision = fp64 ? "fp64" : "fp32";
  prometheus::Counter* counter;
  {
    std::lock_guard<std::mutex> lock(children_mutex_);
    prometheus::Counter*& c = query_counters_[model + '\0' + precision];
    if (!c) c = &queries_.Add({{"model", model}, {"precision", precision}});
    counter = c;
  }
  counter->Increment(static_cast<double>(queries));
  launch_queries_.Observe(static_cast<double>(launch_queries));
  launch_requests_.Observe(static_cast<double>(launch_requests));
  queue_seconds_.Observe(queue_seconds);
  kernel_seconds_.Observe(kernel_seconds);
}

void Metrics::Tabulated(const std::string& model, bool fp64, uint64_t cells) {
  tabulated_cells_.Add({{"model", model}, {"precision", fp64 ? "fp64" : "fp32"}}).Increment(static_cast<double>(cells));
  tabulated_cells_total_ += cells;
}

void Metrics::Resources(const ResourceSample& r) {
  const std::pair<const char*, double> values[] = {
      {"memory_bytes_in_use", double(r.memory_in_use)}, {"memory_bytes_limit", double(r.memory_limit)},
      {"long_calls_in_use", double(r.long_calls_in_use)}, {"long_calls_limit", double(r.long_calls_limit)},
      {"material_cache_bytes", double(r.material_cache_bytes)}, {"serving", r.serving ? 1.0 : 0.0}};
  for (const auto& [name, value] : values) resources_.Add({{"name", name}}).Set(value);
}

void Metrics::Queues(const batching::QueueStats& q) {
  for (int p = 0; p < 2; ++p) {
    const std::string priority = batching::PriorityName(static_cast<batching::Priority>(p));
    const std::pair<const char*, size_t> values[] = {{"queued_jobs", q.queued_jobs[p]},
                                                     {"queued_queries", q.queued_queries[p]},
                                                     {"queued_bytes", q.queued_bytes[p]},
                                                     {"queued_clients", q.clients[p]},
                                                     {"launching_queries", q.launching_queries[p]}};
    for (const auto& [name, value] : values)
      queues_.Add({{"priority", priority}, {"name", name}}).Set(static_cast<double>(value));
  }
}

void Metrics::Rendered(uint64_t queries) {
  rendered_queries_.Add({}).Increment(static_cast<double>(queries));
  rendered_queries_total_ += queries;
}

}  // namespace loomlight::api
