// Who may call: TLS, mutual TLS, bearer tokens with per-call permissions (reflection and metrics included),
// token reload, the plaintext-on-loopback rule, per-client call counts, and the client's TLS options.
// Certificates and tokens: tests/data/tls (test-only material, see its README).
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/access.h"
#include "server/api/server.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

const std::string kTls = std::string(LOOMLIGHT_SOURCE_DIR) + "/tests/data/tls/";
const std::string kEditorToken = "editor-token-0123456789abcdef";      // alice-editor: every call
const std::string kPipelineToken = "pipeline-token-0123456789abcdef";  // thumbs-pipeline: Render, ListModels, metrics

std::string Read(const std::string& name) {
  std::string text, error;
  EXPECT_TRUE(api::ReadFile(kTls + name, &text, &error)) << error;
  return text;
}

api::ServerOptions TlsOptions() {
  api::ServerOptions options;
  options.access.tls_cert = kTls + "server.pem";
  options.access.tls_key = kTls + "server.key";
  return options;
}

// A TLS channel to 127.0.0.1:port trusting the test CA, with a bearer token and a client certificate if given.
std::shared_ptr<grpc::Channel> TlsChannel(int port, const std::string& token = "", const std::string& cert = "") {
  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs = Read("ca.pem");
  if (!cert.empty()) {
    ssl.pem_cert_chain = Read(cert + ".pem");
    ssl.pem_private_key = Read(cert + ".key");
  }
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::SslCredentials(ssl);
  if (!token.empty())
    credentials = grpc::CompositeChannelCredentials(credentials, grpc::AccessTokenCredentials(token));
  return grpc::CreateChannel("127.0.0.1:" + std::to_string(port), credentials);
}

grpc::Status ListModels(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  v1::ListModelsResponse response;
  return v1::Loomlight::NewStub(channel)->ListModels(&context, v1::ListModelsRequest(), &response);
}

grpc::Status Evaluate(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  v1::EvaluateRequest request;
  request.mutable_material()->set_preset("linen_plain");
  for (float v : {0.f, 0.f, 1.f}) request.add_wi(v), request.add_wo(v);
  v1::EvaluateResponse response;
  return v1::Loomlight::NewStub(channel)->Evaluate(&context, request, &response);
}

grpc::StatusCode Health(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::health::v1::HealthCheckResponse response;
  return grpc::health::v1::Health::NewStub(channel)
      ->Check(&context, grpc::health::v1::HealthCheckRequest(), &response)
      .error_code();
}

// One message on reflection's stream (list the services), through the generic stub: its status code.
grpc::StatusCode Reflection(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::CompletionQueue queue;
  auto call = stub.PrepareCall(&context, "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo", &queue);
  void* tag = nullptr;
  bool ok = false;
  call->StartCall(reinterpret_cast<void*>(1));
  queue.Next(&tag, &ok);
  const char list_services[] = {0x3a, 0x01, 0x2a};  // ServerReflectionRequest{list_services: "*"}
  grpc::Slice slice(list_services, sizeof list_services);
  grpc::ByteBuffer message(&slice, 1);
  call->WriteLast(message, grpc::WriteOptions(), reinterpret_cast<void*>(2));
  queue.Next(&tag, &ok);
  grpc::ByteBuffer reply;
  call->Read(&reply, reinterpret_cast<void*>(3));
  queue.Next(&tag, &ok);
  grpc::Status status;
  call->Finish(&status, reinterpret_cast<void*>(4));
  while (queue.Next(&tag, &ok) && tag != reinterpret_cast<void*>(4)) {
  }
  return status.error_code();
}

std::string Base64(const std::string& in) {
  static const char* digits = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (size_t i = 0; i < in.size(); i += 3) {
    const unsigned n = (static_cast<unsigned char>(in[i]) << 16) |
                       (i + 1 < in.size() ? static_cast<unsigned char>(in[i + 1]) << 8 : 0) |
                       (i + 2 < in.size() ? static_cast<unsigned char>(in[i + 2]) : 0);
    out += digits[(n >> 18) & 63];
    out += digits[(n >> 12) & 63];
    out += i + 1 < in.size() ? digits[(n >> 6) & 63] : '=';
    out += i + 2 < in.size() ? digits[n & 63] : '=';
  }
  return out;
}

std::string Metrics(int port, const std::string& user, const std::string& token) {
  return testing::HttpGet(port, "/metrics",
                          user.empty() ? "" : "Authorization: Basic " + Base64(user + ":" + token) + "\r\n");
}

TEST(Access, TokensDecideWhoMayCallWhat) {
  api::ServerOptions options = TlsOptions();
  options.access.tokens_file = kTls + "tokens.txt";
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const int port = server->port();

  // Plaintext does not even reach the service.
  auto plaintext = grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials());
  EXPECT_EQ(ListModels(plaintext).error_code(), grpc::StatusCode::UNAVAILABLE);

  // Health needs no token (probes and load balancers carry none); everything else does.
  EXPECT_EQ(Health(TlsChannel(port)), grpc::StatusCode::OK);
  EXPECT_EQ(ListModels(TlsChannel(port)).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(ListModels(TlsChannel(port, "not-a-listed-token-0123456789")).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(Reflection(TlsChannel(port)), grpc::StatusCode::UNAUTHENTICATED);

  // The editor may call anything; the pipeline only what its line lists.
  auto editor = TlsChannel(port, kEditorToken), pipeline = TlsChannel(port, kPipelineToken);
  EXPECT_TRUE(ListModels(editor).ok());
  EXPECT_TRUE(Evaluate(editor).ok());
  EXPECT_EQ(Reflection(editor), grpc::StatusCode::OK);
  EXPECT_TRUE(ListModels(pipeline).ok());
  const grpc::Status denied = Evaluate(pipeline);
  EXPECT_EQ(denied.error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_NE(denied.error_message().find("Evaluate"), std::string::npos) << denied.error_message();
  EXPECT_EQ(Reflection(pipeline), grpc::StatusCode::PERMISSION_DENIED);

  // One connection is one client: a second client's token on it is refused, the first's still works.
  auto shared = TlsChannel(port);
  auto call_as = [&](const std::string& token) {
    grpc::ClientContext context;
    context.set_credentials(grpc::AccessTokenCredentials(token));
    v1::ListModelsResponse response;
    return v1::Loomlight::NewStub(shared)->ListModels(&context, v1::ListModelsRequest(), &response);
  };
  EXPECT_TRUE(call_as(kEditorToken).ok());
  EXPECT_EQ(call_as(kPipelineToken).error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_TRUE(call_as(kEditorToken).ok());

  // Metrics: basic auth with a client's token that allows `metrics`; calls counted by client name.
  const int metrics = server->metrics_port();
  EXPECT_EQ(Metrics(metrics, "", "").find("loomlight_"), std::string::npos);
  EXPECT_EQ(Metrics(metrics, "thumbs-pipeline", kEditorToken).find("loomlight_"), std::string::npos);
  const std::string text = Metrics(metrics, "thumbs-pipeline", kPipelineToken);
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="ListModels",client="thumbs-pipeline",code="OK"} 1)"),
            std::string::npos)
      << text.substr(0, 2000);
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="Evaluate",client="alice-editor",code="OK"} 1)"),
            std::string::npos);
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="ListModels",client="alice-editor",code="OK"} 3)"),
            std::string::npos);
}

TEST(Access, TokensReloadWholeOrNotAtAll) {
  const std::string file = ::testing::TempDir() + "/loomlight-tokens-" + std::to_string(getpid()) + ".txt";
  auto write = [&](const std::string& text) { std::ofstream(file) << text; };
  write("first-token-0123456789abcdef first *\n");
  api::ServerOptions options = TlsOptions();
  options.access.tokens_file = file;
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const int port = server->port();
  EXPECT_TRUE(ListModels(TlsChannel(port, "first-token-0123456789abcdef")).ok());

  write("second-token-0123456789abcdef second ListModels\n");
  EXPECT_EQ(server->ReloadTokens(), "");
  EXPECT_EQ(ListModels(TlsChannel(port, "first-token-0123456789abcdef")).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(ListModels(TlsChannel(port, "second-token-0123456789abcdef")).ok());

  // A broken file keeps the tokens in use: nobody is locked out by a typo.
  write("second-token-0123456789abcdef second ListModels\nshort x *\n");
  const std::string error = server->ReloadTokens();
  EXPECT_NE(error.find(":2:"), std::string::npos) << error;
  EXPECT_TRUE(ListModels(TlsChannel(port, "second-token-0123456789abcdef")).ok());
  std::remove(file.c_str());
}

TEST(Access, MutualTlsNamesTheClientByItsCertificate) {
  api::ServerOptions options = TlsOptions();
  options.access.tls_client_ca = kTls + "ca.pem";
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const int port = server->port();
  EXPECT_NE(ListModels(TlsChannel(port)).error_code(), grpc::StatusCode::OK);  // no certificate
  EXPECT_NE(ListModels(TlsChannel(port, "", "stranger")).error_code(), grpc::StatusCode::OK);  // untrusted CA
  EXPECT_TRUE(ListModels(TlsChannel(port, "", "client")).ok());
  const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="ListModels",client="alice-editor",code="OK"} 1)"),
            std::string::npos)
      << text.substr(0, 2000);
}

TEST(Access, PlaintextOnlyOnLoopbackAndTokensOnlyOverTls) {
  std::shared_ptr<grpc::ServerCredentials> credentials;
  std::shared_ptr<api::TokenAuthProcessor> processor;
  api::AccessOptions plaintext;
  EXPECT_EQ(api::MakeServerCredentials(plaintext, "127.0.0.1:50051", &credentials, &processor), "");
  EXPECT_EQ(api::MakeServerCredentials(plaintext, "[::1]:50051", &credentials, &processor), "");
  EXPECT_EQ(api::MakeServerCredentials(plaintext, "localhost:50051", &credentials, &processor), "");
  for (const char* remote : {"0.0.0.0:50051", "[::]:50051", "10.1.2.3:50051", "example.org:50051"}) {
    const std::string error = api::MakeServerCredentials(plaintext, remote, &credentials, &processor);
    EXPECT_NE(error.find("not a loopback address"), std::string::npos) << remote << ": " << error;
  }
  plaintext.allow_plaintext_remote = true;
  EXPECT_EQ(api::MakeServerCredentials(plaintext, "0.0.0.0:50051", &credentials, &processor), "");

  api::AccessOptions tokens_in_clear;
  tokens_in_clear.tokens_file = kTls + "tokens.txt";
  EXPECT_NE(api::MakeServerCredentials(tokens_in_clear, "127.0.0.1:0", &credentials, &processor).find("needs TLS"),
            std::string::npos);

  api::ServerOptions remote;
  remote.address = "0.0.0.0:0";
  std::string error;
  EXPECT_EQ(api::LoomlightServer::Start(remote, &error), nullptr);
  EXPECT_NE(error.find("--allow-plaintext-remote"), std::string::npos) << error;

  api::ServerOptions metrics_remote;
  metrics_remote.address = "127.0.0.1:0";
  metrics_remote.metrics_address = "0.0.0.0:0";
  EXPECT_EQ(api::LoomlightServer::Start(metrics_remote, &error), nullptr);
  EXPECT_NE(error.find("metrics"), std::string::npos) << error;
}

TEST(Access, TokenFilesAreCheckedLineByLine) {
  const std::string file = ::testing::TempDir() + "/loomlight-bad-tokens-" + std::to_string(getpid()) + ".txt";
  const std::pair<const char*, const char*> cases[] = {
      {"short-token a *\n", "shorter than 16"},
      {"# comment\nlong-enough-token-0123 onlytwo\n", ":2: expected"},
      {"long-enough-token-0123 a *\nlong-enough-token-0123 b *\n", "listed twice"},
      {"long-enough-token-0123 a , \n", "no calls listed"},
      {"long-enough-token-0123 a * extra\n", "expected"},
  };
  for (const auto& [text, expected] : cases) {
    std::ofstream(file) << text;
    std::string error;
    EXPECT_EQ(api::TokenTable::Load(file, &error), nullptr) << text;
    EXPECT_NE(error.find(expected), std::string::npos) << text << " -> " << error;
  }
  std::ofstream(file) << "# a comment line\n\nlong-enough-token-0123 a Evaluate,Render   # trailing\n";
  std::string error;
  auto table = api::TokenTable::Load(file, &error);
  ASSERT_TRUE(table) << error;
  const api::TokenTable::Entry* entry = table->Find("long-enough-token-0123");
  ASSERT_NE(entry, nullptr);
  EXPECT_TRUE(entry->Allows("Render"));
  EXPECT_FALSE(entry->Allows("Tabulate"));
  EXPECT_EQ(table->Find("long-enough-token-012"), nullptr);  // a prefix is not the token
  std::remove(file.c_str());
  EXPECT_EQ(api::CallName("/loomlight.v1.Loomlight/Evaluate"), "Evaluate");
  EXPECT_EQ(api::CallName("/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo"), "reflection");
}

TEST(Access, ClientConnectsWithCaAndToken) {
  api::ServerOptions options = TlsOptions();
  options.access.tokens_file = kTls + "tokens.txt";
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const std::string target = "127.0.0.1:" + std::to_string(server->port());
  const std::string token_file = ::testing::TempDir() + "/loomlight-token-" + std::to_string(getpid());
  std::ofstream(token_file) << kEditorToken << "\n";
  std::string output;
  EXPECT_EQ(testing::RunClient(target, "--tls-ca " + kTls + "ca.pem --token-file " + token_file +
                                           " eval --preset linen_plain --wi 0,0,1 --wo 0,0,1",
                               &output),
            0)
      << output;
  EXPECT_EQ(testing::RunClient(target, "--tls-ca " + kTls + "ca.pem models", &output), 1);
  EXPECT_NE(output.find("UNAUTHENTICATED"), std::string::npos) << output;
  // The client refuses to send a token in plaintext.
  EXPECT_EQ(testing::RunClient(target, "--token-file " + token_file + " models", &output), 2);
  EXPECT_NE(output.find("only over TLS"), std::string::npos) << output;
  std::remove(token_file.c_str());
}

}  // namespace
}  // namespace loomlight
