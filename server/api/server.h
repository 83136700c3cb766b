// Assembles the service: OpenCL runtime (built and warmed), batcher, gRPC server with health and reflection.
#pragma once

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>

#include "server/api/service.h"
#include "server/batching/batcher.h"
#include "server/runtime/cl_runtime.h"

namespace loomlight::api {

struct ServerOptions {
  std::string address = "127.0.0.1:50051";  // port 0 picks a free port (see LoomlightServer::port)
  runtime::RuntimeOptions runtime;
  batching::BatcherOptions batcher;
  std::string metrics_address;  // "host:port" for Prometheus' /metrics ("" = none; port 0 picks one)
};

class LoomlightServer {
 public:
  // Listens (health NOT_SERVING), builds and warms the kernels, then reports SERVING.
  // Returns nullptr with *error set on failure (e.g. a kernel build log).
  static std::unique_ptr<LoomlightServer> Start(const ServerOptions& options, std::string* error);
  ~LoomlightServer();
  void Wait() { server_->Wait(); }
  void Shutdown();
  int port() const { return port_; }
  int metrics_port() const { return metrics_->port(); }
  const Metrics& metrics() const { return *metrics_; }
  const runtime::ClRuntime& runtime() const { return *runtime_; }

 private:
  LoomlightServer() = default;
  std::unique_ptr<runtime::ClRuntime> runtime_;
  std::unique_ptr<batching::Batcher> batcher_;
  std::unique_ptr<Metrics> metrics_;
  std::unique_ptr<LoomlightService> service_;
  std::unique_ptr<grpc::Server> server_;
  int port_ = 0;
  bool shut_down_ = false;
};

}  // namespace loomlight::api
