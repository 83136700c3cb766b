#include "client/rpc.h"

#include <cmath>
#include <cstdlib>
#include <ostream>

namespace loomlight::client {
namespace {

constexpr const char* kDefaultServer = "127.0.0.1:50051";
constexpr double kDefaultTimeoutSeconds = 60.0;
// Large batches (a full plot, a CSV of directions) exceed gRPC's 4 MiB default.
constexpr int kMaxMessageBytes = 64 << 20;

std::string server_target(const ParsedOptions& options) {
  if (auto server = options.last("server")) return *server;
  if (const char* env = std::getenv("LOOMLIGHT_SERVER"); env != nullptr && *env != '\0') return env;
  return kDefaultServer;
}

std::chrono::milliseconds call_timeout(const ParsedOptions& options) {
  const auto text = options.last("timeout");
  const double seconds = text ? parse_number(*text, "--timeout") : kDefaultTimeoutSeconds;
  if (!(seconds >= 0.0) || !std::isfinite(seconds)) throw UsageError("--timeout must be a number of seconds >= 0");
  return std::chrono::milliseconds(static_cast<long long>(std::llround(seconds * 1000.0)));
}

std::shared_ptr<grpc::Channel> make_channel(const std::string& target) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(kMaxMessageBytes);
  args.SetMaxSendMessageSize(kMaxMessageBytes);
  return grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args);
}

void check(const grpc::Status& status) {
  if (!status.ok()) throw RpcError(status);
}

}  // namespace

const char* precision_name(v1::Precision precision) {
  return precision == v1::PRECISION_FP64 ? "fp64" : "fp32";
}

RpcError::RpcError(const grpc::Status& status)
    : std::runtime_error(std::string(status_code_name(status.error_code())) + ": " + status.error_message()),
      code(status.error_code()) {}

const char* status_code_name(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK: return "OK";
    case grpc::StatusCode::CANCELLED: return "CANCELLED";
    case grpc::StatusCode::UNKNOWN: return "UNKNOWN";
    case grpc::StatusCode::INVALID_ARGUMENT: return "INVALID_ARGUMENT";
    case grpc::StatusCode::DEADLINE_EXCEEDED: return "DEADLINE_EXCEEDED";
    case grpc::StatusCode::NOT_FOUND: return "NOT_FOUND";
    case grpc::StatusCode::ALREADY_EXISTS: return "ALREADY_EXISTS";
    case grpc::StatusCode::PERMISSION_DENIED: return "PERMISSION_DENIED";
    case grpc::StatusCode::RESOURCE_EXHAUSTED: return "RESOURCE_EXHAUSTED";
    case grpc::StatusCode::FAILED_PRECONDITION: return "FAILED_PRECONDITION";
    case grpc::StatusCode::ABORTED: return "ABORTED";
    case grpc::StatusCode::OUT_OF_RANGE: return "OUT_OF_RANGE";
    case grpc::StatusCode::UNIMPLEMENTED: return "UNIMPLEMENTED";
    case grpc::StatusCode::INTERNAL: return "INTERNAL";
    case grpc::StatusCode::UNAVAILABLE: return "UNAVAILABLE";
    case grpc::StatusCode::DATA_LOSS: return "DATA_LOSS";
    case grpc::StatusCode::UNAUTHENTICATED: return "UNAUTHENTICATED";
    default: return "UNKNOWN_STATUS";
  }
}

const OptionList& connection_options() {
  static const OptionList options = {
      {"server", "HOST:PORT", "server address (default $LOOMLIGHT_SERVER, else 127.0.0.1:50051)"},
      {"timeout", "SECONDS", "deadline of each call (default 60; 0 = none)"},
  };
  return options;
}

Client::Client(const ParsedOptions& options)
    : channel_(make_channel(server_target(options))), stub_(v1::Loomlight::NewStub(channel_)),
      timeout_(call_timeout(options)) {}

void Client::prepare(grpc::ClientContext& context) const {
  if (timeout_.count() > 0) context.set_deadline(std::chrono::system_clock::now() + timeout_);
}

grpc::health::v1::HealthCheckResponse::ServingStatus Client::health(const std::string& service) {
  grpc::ClientContext context;
  prepare(context);
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  grpc::health::v1::HealthCheckResponse response;
  check(grpc::health::v1::Health::NewStub(channel_)->Check(&context, request, &response));
  return response.status();
}

v1::ListModelsResponse Client::list_models() {
  grpc::ClientContext context;
  prepare(context);
  v1::ListModelsResponse response;
  check(stub_->ListModels(&context, v1::ListModelsRequest(), &response));
  return response;
}

v1::EvaluateResponse Client::evaluate(const v1::EvaluateRequest& request) {
  grpc::ClientContext context;
  prepare(context);
  v1::EvaluateResponse response;
  check(stub_->Evaluate(&context, request, &response));
  // A short answer would silently misalign rows with their directions.
  const int queries = request.wi_size() / 3;
  if (response.f_size() != 3 * queries)
    throw std::runtime_error("server returned " + std::to_string(response.f_size()) + " values for " +
                             std::to_string(queries) + " queries (expected " + std::to_string(3 * queries) + ")");
  if (response.transmittance_size() != 0 && response.transmittance_size() != queries)
    throw std::runtime_error("server returned " + std::to_string(response.transmittance_size()) +
                             " transmittances for " + std::to_string(queries) + " queries");
  return response;
}

v1::SampleResponse Client::sample(const v1::SampleRequest& request) {
  grpc::ClientContext context;
  prepare(context);
  v1::SampleResponse response;
  check(stub_->Sample(&context, request, &response));
  const int queries = request.wo_size() / 3;
  if (response.wi_size() != 3 * queries || response.pdf_size() != queries || response.weight_size() != 3 * queries ||
      response.f_size() != 3 * queries)
    throw std::runtime_error("server returned " + std::to_string(response.pdf_size()) + " samples for " +
                             std::to_string(queries) + " queries");
  return response;
}

v1::TextureSliceResponse Client::texture_slice(const v1::TextureSliceRequest& request) {
  grpc::ClientContext context;
  prepare(context);
  v1::TextureSliceResponse response;
  check(stub_->TextureSlice(&context, request, &response));
  if (response.image().empty() || response.width() != request.width() || response.height() != request.height())
    throw std::runtime_error("server returned a " + std::to_string(response.width()) + "x" +
                             std::to_string(response.height()) + " image of " + std::to_string(response.image().size()) +
                             " bytes for a " + std::to_string(request.width()) + "x" +
                             std::to_string(request.height()) + " slice");
  return response;
}

namespace {

// Reads a server stream to its end, handing every message to `on_message`; throws RpcError when the call
// ends with an error, also after some messages arrived.
template <class Message>
void read_stream(grpc::ClientContext& context, grpc::ClientReader<Message>& reader,
                 const std::function<void(const Message&)>& on_message) {
  Message message;
  try {
    while (reader.Read(&message)) on_message(message);
  } catch (...) {
    // A stream must be finished before its context goes: cancel it, so the server stops too.
    context.TryCancel();
    while (reader.Read(&message)) {}
    reader.Finish();
    throw;
  }
  check(reader.Finish());
}

}  // namespace

void Client::tabulate(const v1::TabulateRequest& request,
                      const std::function<void(const v1::TabulateChunk&)>& on_chunk) {
  grpc::ClientContext context;
  prepare(context);
  read_stream(context, *stub_->Tabulate(&context, request), on_chunk);
}

void Client::render(const v1::RenderRequest& request, const std::function<void(const v1::RenderUpdate&)>& on_update) {
  grpc::ClientContext context;
  prepare(context);
  read_stream(context, *stub_->Render(&context, request), on_update);
}

void Client::yarn_geometry(const v1::YarnGeometryRequest& request,
                           const std::function<void(const v1::YarnGeometryChunk&)>& on_chunk) {
  grpc::ClientContext context;
  prepare(context);
  read_stream(context, *stub_->YarnGeometry(&context, request), on_chunk);
}

void print_timing(std::ostream& out, const v1::EvaluateResponse& response, int queries) {
  out << "model=" << response.model() << " precision=" << precision_name(response.precision())
      << " queries=" << queries << " queue_seconds=" << response.queue_seconds()
      << " kernel_seconds=" << response.kernel_seconds() << " total_seconds=" << response.total_seconds()
      << " batch_queries=" << response.batch_queries() << " batch_requests=" << response.batch_requests() << '\n';
}

}  // namespace loomlight::client
