// Prometheus metrics of the service (prometheus-cpp), served over HTTP at /metrics when an address is set.
#pragma once

#include <prometheus/counter.h>
#include <prometheus/exposer.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>

#include <grpcpp/grpcpp.h>
#include <grpcpp/support/server_interceptor.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

#include "server/api/access.h"
#include "server/batching/batcher.h"

namespace loomlight::api {

// Admission resources at one moment (server/api/admission.h).
struct ResourceSample {
  size_t memory_in_use = 0, memory_limit = 0, long_calls_in_use = 0, long_calls_limit = 0;
  size_t material_cache_bytes = 0;
  bool serving = false;
};

class Metrics {
 public:
  Metrics();
  ~Metrics();  // stops the HTTP endpoint at once (metrics.cpp)
  // Starts the HTTP endpoint ("host:port", port 0 picks one); "" on success, else the reason. Only on loopback
  // unless plaintext on other addresses is allowed; with tokens a scraper authenticates by HTTP basic auth
  // (user: a client, password: its token, which must list `metrics` itself: `*` does not include it).
  std::string Serve(const std::string& address, const AccessOptions& access,
                    std::shared_ptr<TokenAuthProcessor> tokens);
  int port() const;

  // One finished call of an RPC, with its status and time in the server.
  void Call(const std::string& rpc, grpc::StatusCode code, double seconds);
  // Queries evaluated for a model and precision, and the launch the request rode in.
  void Evaluated(const std::string& model, bool fp64, size_t queries, size_t launch_queries,
                 size_t launch_requests, double queue_seconds, double kernel_seconds);
  // Table cells a Tabulate call finished evaluating (after averaging its queries per cell).
  void Tabulated(const std::string& model, bool fp64, uint64_t cells);
  // Every tabulated cell since start, all models: the work tabulations did (tests compare it).
  uint64_t tabulated_cells() const { return tabulated_cells_total_.load(); }
  // The admission resources now (the server's watchdog samples them).
  void Resources(const ResourceSample& sample);
  // The batcher's queues now, per priority (sampled with the resources).
  void Queues(const batching::QueueStats& stats);
  // Counts every finished call by client name, method and status (loomlight_client_calls_total), whichever
  // service it went to (reflection, health): installed on the gRPC server as an interceptor. A method the server
  // does not have is "unknown" (CallName), so made-up method names add one series, not one each.
  std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> ClientCallCounter();
  void ClientCall(const std::string& client, const std::string& call, grpc::StatusCode code);
  // Kernel queries a Render call finished evaluating.
  void Rendered(uint64_t queries);
  // Every rendered query since start: the work renders did (tests compare it).
  uint64_t rendered_queries() const { return rendered_queries_total_.load(); }

 private:
  std::shared_ptr<prometheus::Registry> registry_;
  prometheus::Family<prometheus::Counter>& calls_;
  prometheus::Family<prometheus::Histogram>& call_seconds_;
  prometheus::Family<prometheus::Counter>& queries_;
  prometheus::Family<prometheus::Counter>& tabulated_cells_;
  std::atomic<uint64_t> tabulated_cells_total_{0};
  prometheus::Family<prometheus::Counter>& rendered_queries_;
  std::atomic<uint64_t> rendered_queries_total_{0};
  prometheus::Histogram& launch_queries_;
  prometheus::Histogram& launch_requests_;
  prometheus::Histogram& queue_seconds_;
  prometheus::Histogram& kernel_seconds_;
  prometheus::Family<prometheus::Gauge>& resources_;
  prometheus::Family<prometheus::Counter>& client_calls_;
  prometheus::Family<prometheus::Gauge>& queues_;
  std::shared_ptr<TokenAuthProcessor> metrics_tokens_;  // basic auth of /metrics (null: none)
  std::unique_ptr<prometheus::Exposer> exposer_;
  // The per-call metrics' children by their label values, found once (Family::Add builds and hashes a label
  // map on every call): "rpc\0code" -> calls_, rpc -> call_seconds_, "model\0precision" -> queries_,
  // "client\0call\0code" -> client_calls_.
  std::mutex children_mutex_;
  std::unordered_map<std::string, prometheus::Counter*> call_counters_, query_counters_, client_call_counters_;
  std::unordered_map<std::string, prometheus::Histogram*> call_histograms_;
};

}  // namespace loomlight::api
