#include "client/rpc.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <ostream>
#include <sstream>
#include <vector>

namespace loomlight::client {
namespace {

constexpr const char* kDefaultServer = "127.0.0.1:50051";
constexpr double kDefaultTimeoutSeconds = 60.0;
// Large batches (a full plot, a CSV of directions) exceed gRPC's 4 MiB default.
constexpr int kMaxMessageBytes = 64 << 20;

std::string server_target(const ParsedOptions& options) {
  return options.last("server").value_or(kDefaultServer);  // --server's CLI11 envname gives $LOOMLIGHT_SERVER
}

std::chrono::milliseconds call_timeout(const ParsedOptions& options) {
  const auto text = options.last("timeout");
  const double seconds = text ? parse_number(*text, "--timeout") : kDefaultTimeoutSeconds;
  if (!(seconds >= 0.0) || !std::isfinite(seconds)) throw UsageError("--timeout must be a number of seconds >= 0");
  return std::chrono::milliseconds(static_cast<long long>(std::llround(seconds * 1000.0)));
}

std::string read_text_file(const std::string& path, std::string_view what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw UsageError(std::string(what) + ": cannot read '" + path + "'");
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// "h1:p1,h2:p2" splits into its targets; one target stays one.
std::vector<std::string> split_targets(const std::string& target) {
  std::vector<std::string> parts;
  size_t begin = 0;
  while (true) {
    const size_t comma = target.find(',', begin);
    std::string part = target.substr(begin, comma == std::string::npos ? std::string::npos : comma - begin);
    if (part.empty()) throw UsageError("--server: empty target in '" + target + "'");
    parts.push_back(std::move(part));
    if (comma == std::string::npos) return parts;
    begin = comma + 1;
  }
}

// Several "HOST:PORT" targets become one gRPC "ipv4:"/"ipv6:" address list (gRPC's own resolvers), each host
// name resolved here once: a replica that goes away is then skipped by round_robin without a new resolution.
std::string address_list_target(const std::vector<std::string>& targets) {
  std::vector<std::string> v4, v6;
  for (const std::string& target : targets) {
    const size_t colon = target.rfind(':');
    if (colon == std::string::npos || colon == 0 || colon + 1 == target.size())
      throw UsageError("--server: '" + target + "' in a list must be HOST:PORT");
    std::string host = target.substr(0, colon);
    const std::string port = target.substr(colon + 1);
    if (host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
    addrinfo hints{};
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* found = nullptr;
    if (getaddrinfo(host.c_str(), port.c_str(), &hints, &found) != 0 || found == nullptr)
      throw UsageError("--server: cannot resolve '" + target + "'");
    for (const addrinfo* a = found; a != nullptr; a = a->ai_next) {
      char text[INET6_ADDRSTRLEN] = {};
      if (a->ai_family == AF_INET) {
        inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(a->ai_addr)->sin_addr, text, sizeof text);
        v4.push_back(std::string(text) + ":" + port);
      } else if (a->ai_family == AF_INET6) {
        inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6*>(a->ai_addr)->sin6_addr, text, sizeof text);
        v6.push_back("[" + std::string(text) + "]:" + port);
      }
    }
    freeaddrinfo(found);
  }
  // gRPC's address-list schemes take one family; IPv4 is what loopback replicas and most clusters use.
  const std::vector<std::string>& chosen = v4.empty() ? v6 : v4;
  std::string joined = v4.empty() ? "ipv6:" : "ipv4:";
  for (size_t i = 0; i < chosen.size(); ++i) joined += (i ? "," : "") + chosen[i];
  return joined;
}

// The channel's credentials: plaintext by default; TLS when a CA (or "system") is given, with the client's own
// certificate for mutual TLS and a bearer token, which gRPC sends only over TLS.
std::shared_ptr<grpc::ChannelCredentials> channel_credentials(const ParsedOptions& options) {
  std::string token;
  if (auto file = options.last("token-file")) {
    token = read_text_file(*file, "--token-file");
    while (!token.empty() && std::isspace(static_cast<unsigned char>(token.back()))) token.pop_back();
  } else if (const char* env = std::getenv("LOOMLIGHT_TOKEN"); env != nullptr && *env != '\0') {
    token = env;
  }
  const auto ca = options.last("tls-ca");
  if (!ca) {
    if (!token.empty()) throw UsageError("a token is sent only over TLS: give --tls-ca (a CA file, or 'system')");
    if (options.has("tls-cert") || options.has("tls-key")) throw UsageError("--tls-cert and --tls-key need --tls-ca");
    return grpc::InsecureChannelCredentials();
  }
  grpc::SslCredentialsOptions ssl;
  if (*ca != "system") ssl.pem_root_certs = read_text_file(*ca, "--tls-ca");
  if (options.has("tls-cert") != options.has("tls-key")) throw UsageError("--tls-cert and --tls-key go together");
  if (auto cert = options.last("tls-cert")) {
    ssl.pem_cert_chain = read_text_file(*cert, "--tls-cert");
    ssl.pem_private_key = read_text_file(*options.last("tls-key"), "--tls-key");
  }
  auto credentials = grpc::SslCredentials(ssl);
  if (token.empty()) return credentials;
  return grpc::CompositeChannelCredentials(credentials, grpc::AccessTokenCredentials(token));
}

std::shared_ptr<grpc::Channel> make_channel(const ParsedOptions& options) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(kMaxMessageBytes);
  args.SetMaxSendMessageSize(kMaxMessageBytes);
  std::string target = server_target(options);
  const std::vector<std::string> targets = split_targets(target);
  // Several replicas (a list, or a DNS name with several addresses): gRPC's round_robin spreads calls over every
  // ready one and skips those that fail.
  if (targets.size() > 1) target = address_list_target(targets);
  if (targets.size() > 1 || target.rfind("dns:", 0) == 0) args.SetLoadBalancingPolicyName("round_robin");
  if (auto name = options.last("tls-server-name")) {
    args.SetSslTargetNameOverride(*name);
  } else if (targets.size() > 1 && options.has("tls-ca")) {
    // An address list has no host name to check the certificate against: the first target's stands for all.
    args.SetSslTargetNameOverride(targets.front().substr(0, targets.front().rfind(':')));
  }
  return grpc::CreateCustomChannel(target, channel_credentials(options), args);
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
      {"server", "TARGET", "HOST:PORT, several as H1:P1,H2:P2, or dns:///NAME:PORT; several replicas are used round-robin (default $LOOMLIGHT_SERVER, else 127.0.0.1:50051)",
       "LOOMLIGHT_SERVER"},
      {"tls-ca", "FILE", "connect with TLS, trusting the CA certificates in FILE ('system': the system's)"},
      {"tls-cert", "FILE", "the client's certificate chain, for servers that require one (mutual TLS)"},
      {"tls-key", "FILE", "the private key of --tls-cert"},
      {"tls-server-name", "NAME", "the name the server's certificate must carry (default: the target's host)"},
      {"token-file", "FILE", "send the bearer token in FILE (default $LOOMLIGHT_TOKEN); needs TLS"},
      {"timeout", "SECONDS", "deadline of each call (default 60; 0 = none)"},
  };
  return options;
}

Client::Client(const ParsedOptions& options)
    : channel_(make_channel(options)), stub_(v1::Loomlight::NewStub(channel_)),
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

v1::ListScenesResponse Client::list_scenes() {
  grpc::ClientContext context;
  prepare(context);
  v1::ListScenesResponse response;
  check(stub_->ListScenes(&context, v1::ListScenesRequest(), &response));
  return response;
}

v1::EvaluateResponse Client::evaluate(const v1::EvaluateRequest& request) {
  grpc::ClientContext context;
  prepare(context);
  v1::EvaluateResponse response;
  check(stub_->Evaluate(&context, request, &response));
  // A short answer would silently misalign rows with their directions. AMBIENT queries have no wi: one per wo.
  const int queries = (request.quantity() == v1::QUANTITY_AMBIENT ? request.wo_size() : request.wi_size()) / 3;
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

void Client::create_btf(const v1::CreateBtfRequest& request,
                        const std::function<void(const v1::CreateBtfProgress&)>& on_progress) {
  grpc::ClientContext context;
  prepare(context);
  read_stream(context, *stub_->CreateBtf(&context, request), on_progress);
}

namespace {
// A client-streaming upload: `message` (holding the header) first, then each message `fill` fills (after its
// clear_part) until it returns false.
template <class Message>
void stream_upload(grpc::ClientContext& context, grpc::ClientWriter<Message>& writer, Message& message,
                   const std::function<bool(Message&)>& fill) {
  // Write fails once the server has ended the call (a bad header, a bad part): Finish then says why.
  bool open = writer.Write(message);
  try {
    for (message.clear_part(); open && fill(message); message.clear_part()) open = writer.Write(message);
  } catch (...) {
    context.TryCancel();  // the server must not store a partial upload
    writer.Finish();
    throw;
  }
  if (open) writer.WritesDone();
}
}  // namespace

v1::BtfAssetInfo Client::upload_btf(const v1::UploadBtfHeader& header,
                                    const std::function<bool(v1::BtfImage&)>& next_image) {
  grpc::ClientContext context;
  prepare(context);
  v1::BtfAssetInfo asset;
  const auto writer = stub_->UploadBtf(&context, &asset);
  v1::UploadBtfMessage message;
  *message.mutable_header() = header;
  stream_upload<v1::UploadBtfMessage>(context, *writer, message,
                                      [&](v1::UploadBtfMessage& m) { return next_image(*m.mutable_image()); });
  check(writer->Finish());
  return asset;
}

v1::MeshInfo Client::upload_mesh(const v1::UploadMeshHeader& header,
                                 const std::function<bool(std::string&)>& next_chunk) {
  grpc::ClientContext context;
  prepare(context);
  v1::MeshInfo mesh;
  const auto writer = stub_->UploadMesh(&context, &mesh);
  v1::UploadMeshMessage message;
  *message.mutable_header() = header;
  stream_upload<v1::UploadMeshMessage>(context, *writer, message,
                                       [&](v1::UploadMeshMessage& m) { return next_chunk(*m.mutable_chunk()); });
  check(writer->Finish());
  return mesh;
}

v1::ListMeshesResponse Client::list_meshes() {
  grpc::ClientContext context;
  prepare(context);
  v1::ListMeshesResponse response;
  check(stub_->ListMeshes(&context, v1::ListMeshesRequest(), &response));
  return response;
}

void Client::delete_mesh(const std::string& name) {
  grpc::ClientContext context;
  prepare(context);
  v1::DeleteMeshRequest request;
  request.set_name(name);
  v1::DeleteMeshResponse response;
  check(stub_->DeleteMesh(&context, request, &response));
}

v1::FitMaterialResponse Client::fit_material(const v1::FitMaterialRequest& request) {
  grpc::ClientContext context;
  prepare(context);
  v1::FitMaterialResponse response;
  check(stub_->FitMaterial(&context, request, &response));
  if (request.format() != v1::EXPORT_FORMAT_NONE && response.file().empty())
    throw std::runtime_error("server returned no file for the export asked for");
  return response;
}

v1::ListBtfsResponse Client::list_btfs() {
  grpc::ClientContext context;
  prepare(context);
  v1::ListBtfsResponse response;
  check(stub_->ListBtfs(&context, v1::ListBtfsRequest(), &response));
  return response;
}

void Client::delete_btf(const std::string& name) {
  grpc::ClientContext context;
  prepare(context);
  v1::DeleteBtfRequest request;
  request.set_name(name);
  v1::DeleteBtfResponse response;
  check(stub_->DeleteBtf(&context, request, &response));
}

void print_timing(std::ostream& out, const v1::EvaluateResponse& response, int queries) {
  out << "model=" << response.model() << " precision=" << precision_name(response.precision())
      << " queries=" << queries << " queue_seconds=" << response.queue_seconds()
      << " kernel_seconds=" << response.kernel_seconds() << " total_seconds=" << response.total_seconds()
      << " batch_queries=" << response.batch_queries() << " batch_requests=" << response.batch_requests() << '\n';
}

}  // namespace loomlight::client
