// `loomlight health`: the standard grpc.health.v1.Health/Check of a server, for operators and scripts.
// Prints the serving status (SERVING, NOT_SERVING, ...) and exits 0 only when it is SERVING (with --alive: when
// the server answered at all); a failed call (nobody listening, unknown service) is printed as
// `error: CODE: message` by main, exit status 1.
#include <iostream>
#include <string>

#include "client/commands.h"
#include "client/rpc.h"
#include "grpc/health/v1/health.grpc.pb.h"

namespace loomlight::client {
namespace {

namespace health = grpc::health::v1;

const char* serving_status_name(health::HealthCheckResponse::ServingStatus status) {
  switch (status) {
    case health::HealthCheckResponse::SERVING: return "SERVING";
    case health::HealthCheckResponse::NOT_SERVING: return "NOT_SERVING";
    case health::HealthCheckResponse::SERVICE_UNKNOWN: return "SERVICE_UNKNOWN";
    default: return "UNKNOWN";
  }
}

int run_health(const ParsedOptions& options) {
  Client client(options);  // --server and --timeout as every command takes them
  const health::HealthCheckResponse::ServingStatus status = client.health(options.last("service").value_or(""));
  std::cout << serving_status_name(status) << '\n';
  if (options.has("alive")) return 0;  // it answered: the process lives, whether or not it takes calls now
  return status == health::HealthCheckResponse::SERVING ? 0 : 1;
}

}  // namespace

const Command& health_command() {
  static const Command command = {
      "health",
      "[--service NAME] [--alive]",
      "check whether the server is serving (grpc.health.v1.Health/Check)",
      "Prints SERVING, NOT_SERVING (still building and warming its kernels, or shutting down) or the error,\n"
      "and exits 0 only when SERVING, so scripts can poll it. The server reports \"\" (the whole server) and\n"
      "loomlight.v1.Loomlight.\n"
      "With --alive it exits 0 whenever the server answers (a liveness probe: a server that is warming, busy\n"
      "past --stall-seconds or draining is alive, and restarting it would only cancel its calls).\n"
      "Example: until loomlight health --timeout 5; do sleep 2; done",
      {{"service", "NAME", "the service to check (default \"\": the whole server)"},
       {"alive", "", "exit 0 when the server answers at all, SERVING or not (liveness, not readiness)"}},
      run_health,
  };
  return command;
}

}  // namespace loomlight::client
