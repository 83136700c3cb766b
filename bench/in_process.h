// An in-process Loomlight server and client stubs for the service benchmarks (sections 3 and 5).
#pragma once

#include <memory>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"

namespace loomlight::bench {

// A server on 127.0.0.1 (port 0), batching on or off; exits the benchmark when it cannot start.
std::unique_ptr<api::LoomlightServer> StartServer(bool coalesce);
// A server with these options on 127.0.0.1 (port 0; the address is replaced); exits when it cannot start.
std::unique_ptr<api::LoomlightServer> StartServer(api::ServerOptions options);

// A stub on its own channel: the local subchannel pool and a distinct argument keep gRPC from sharing
// one TCP connection between clients.
std::unique_ptr<v1::Loomlight::Stub> Connect(int port, int client_id);

// The service sections' Evaluate request: n random direction pairs (seeded by client_id) for one of the
// microcylinder presets (client_id picks it, in turn), fp32, the default tangent samples.
v1::EvaluateRequest MakeEvaluateRequest(size_t n, int client_id);

}  // namespace loomlight::bench
