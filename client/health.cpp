// `loomlight health`: the standard grpc.health.v1.Health/Check of a server, for operators and scripts.
// Prints the serving status (SERVING, NOT_SERVING, ...) and exits 0 only when it is SERVING; a failed call
// (nobody listening, unknown service) is printed as `error: CODE: message` by main, exit status 1.
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <string>

#include <grpcpp/grpcpp.h>

#include "client/commands.h"
#include "client/rpc.h"
#include "grpc/health/v1/health.grpc.pb.h"

namespace loomlight::client {
namespace {

namespace health = grpc::health::v1;

// The same target and deadline rules as every other command (Client in rpc.cpp): --server, else
// $LOOMLIGHT_SERVER, else 127.0.0.1:50051; --timeout seconds, default 60, 0 = none.
std::string health_target(const ParsedOptions& options) {
  if (auto server = options.last("server")) return *server;
  if (const char* env = std::getenv("LOOMLIGHT_SERVER"); env != nullptr && *env != '\0') return env;
  return "127.0.0.1:50051";
}

std::chrono::milliseconds health_timeout(const ParsedOptions& options) {
  const auto text = options.last("timeout");
  const double seconds = text ? parse_number(*text, "--timeout") : 60.0;
  if (!(seconds >= 0.0) || !std::isfinite(seconds)) throw UsageError("--timeout must be a number of seconds >= 0");
  return std::chrono::milliseconds(static_cast<long long>(std::llround(seconds * 1000.0)));
}

const char* serving_status_name(health::HealthCheckResponse::ServingStatus status) {
  switch (status) {
    case health::HealthCheckResponse::SERVING: return "SERVING";
    case health::HealthCheckResponse::NOT_SERVING: return "NOT_SERVING";
    case health::HealthCheckResponse::SERVICE_UNKNOWN: return "SERVICE_UNKNOWN";
    default: return "UNKNOWN";
  }
}

int run_health(const ParsedOptions& options) {
  const auto timeout = health_timeout(options);
  auto stub = health::Health::NewStub(grpc::CreateChannel(health_target(options), grpc::InsecureChannelCredentials()));
  grpc::ClientContext context;
  if (timeout.count() > 0) context.set_deadline(std::chrono::system_clock::now() + timeout);
  health::HealthCheckRequest request;
  request.set_service(options.last("service").value_or(""));
  health::HealthCheckResponse response;
  const grpc::Status status = stub->Check(&context, request, &response);
  if (!status.ok()) throw RpcError(status);
  std::cout << serving_status_name(response.status()) << '\n';
  return response.status() == health::HealthCheckResponse::SERVING ? 0 : 1;
}

}  // namespace

const Command& health_command() {
  static const Command command = {
      "health",
      "[--service NAME]",
      "check whether the server is serving (grpc.health.v1.Health/Check)",
      "Prints SERVING, NOT_SERVING (still building and warming its kernels, or shutting down) or the error,\n"
      "and exits 0 only when SERVING, so scripts can poll it. The server reports \"\" (the whole server) and\n"
      "loomlight.v1.Loomlight.\n"
      "Example: until loomlight health --timeout 5; do sleep 2; done",
      {{"service", "NAME", "the service to check (default \"\": the whole server)"}},
      run_health,
  };
  return command;
}

}  // namespace loomlight::client
