#include "server/api/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>

namespace loomlight::api {
namespace {
const char* kServiceName = "loomlight.v1.Loomlight";

void SetServing(grpc::Server* server, bool serving) {
  grpc::HealthCheckServiceInterface* health = server->GetHealthCheckService();
  health->SetServingStatus("", serving);
  health->SetServingStatus(kServiceName, serving);
}
}  // namespace

std::unique_ptr<LoomlightServer> LoomlightServer::Start(const ServerOptions& options, std::string* error) {
  auto s = std::unique_ptr<LoomlightServer>(new LoomlightServer);
  s->runtime_ = runtime::ClRuntime::Create(options.runtime, error);
  if (!s->runtime_) return nullptr;
  const models::Registry& registry = models::Registry::Global();
  if (!s->runtime_->BuildPrograms(registry, error)) return nullptr;

  s->metrics_ = std::make_unique<Metrics>();
  if (!options.metrics_address.empty()) {
    *error = s->metrics_->Serve(options.metrics_address);
    if (!error->empty()) return nullptr;
  }
  s->batcher_ = std::make_unique<batching::Batcher>(s->runtime_.get(), options.batcher);
  s->service_ = std::make_unique<LoomlightService>(&registry, s->batcher_.get(), s->runtime_->has_fp64(),
                                                   s->metrics_.get());
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.address, grpc::InsecureServerCredentials(), &s->port_);
  builder.RegisterService(s->service_.get());
  builder.SetMaxReceiveMessageSize(kMaxMessageBytes);
  builder.SetMaxSendMessageSize(kMaxMessageBytes);
  s->server_ = builder.BuildAndStart();
  if (!s->server_ || s->port_ == 0) {
    *error = "cannot listen on " + options.address;
    return nullptr;
  }
  SetServing(s->server_.get(), false);
  // Warm before SERVING: PoCL compiles each kernel for the work-group size on first launch.
  if (!s->runtime_->Warm(registry, error)) {
    s->Shutdown();
    return nullptr;
  }
  SetServing(s->server_.get(), true);
  return s;
}

void LoomlightServer::Shutdown() {
  if (shut_down_) return;
  shut_down_ = true;
  if (server_) {
    SetServing(server_.get(), false);
    // Let in-flight calls finish for up to a second, then cancel them.
    server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(1));
  }
  if (batcher_) batcher_->Stop();
}

LoomlightServer::~LoomlightServer() { Shutdown(); }

}  // namespace loomlight::api
