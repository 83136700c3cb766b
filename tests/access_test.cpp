// Who may call: TLS, mutual TLS, bearer tokens with per-call permissions (reflection and metrics included),
// tokens of several clients on one connection (a proxy's), token reload failing closed, the plaintext-on-loopback
// rule, per-client call counts bounded in labels, and the client's TLS options.
// Certificates and tokens: tests/data/tls (test-only material, see its README).
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>
#include <vector>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/access.h"
#include "server/api/server.h"
#include "server/api/tabulate.h"
#include "server/models/registry.h"
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

bool Serving(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::health::v1::HealthCheckResponse response;
  const grpc::Status status = grpc::health::v1::Health::NewStub(channel)->Check(
      &context, grpc::health::v1::HealthCheckRequest(), &response);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return response.status() == grpc::health::v1::HealthCheckResponse::SERVING;
}

// A unary call of any method path with an empty request (the generic stub): its status.
grpc::Status CallPath(const std::shared_ptr<grpc::Channel>& channel, const std::string& path) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::CompletionQueue queue;
  grpc::Slice empty("", 0);
  grpc::ByteBuffer request(&empty, 1), reply;
  auto call = stub.PrepareUnaryCall(&context, path, request, &queue);
  call->StartCall();
  grpc::Status status;
  call->Finish(&reply, &status, reinterpret_cast<void*>(1));
  void* tag = nullptr;
  bool ok = false;
  EXPECT_TRUE(queue.Next(&tag, &ok));
  return status;
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

  // Metrics: basic auth with a client's token that lists `metrics` itself (the editor's `*` is every RPC, not
  // scraping); calls counted by client name.
  const int metrics = server->metrics_port();
  EXPECT_EQ(Metrics(metrics, "", "").find("loomlight_"), std::string::npos);
  EXPECT_EQ(Metrics(metrics, "thumbs-pipeline", kEditorToken).find("loomlight_"), std::string::npos);
  EXPECT_EQ(Metrics(metrics, "alice-editor", kEditorToken).find("loomlight_"), std::string::npos);
  const std::string text = Metrics(metrics, "thumbs-pipeline", kPipelineToken);
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="ListModels",client="thumbs-pipeline",code="OK"} 1)"),
            std::string::npos)
      << text.substr(0, 2000);
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="Evaluate",client="alice-editor",code="OK"} 1)"),
            std::string::npos);
  EXPECT_NE(text.find(R"(loomlight_client_calls_total{call="ListModels",client="alice-editor",code="OK"} 1)"),
            std::string::npos);
}

// A proxy (HAProxy) sends many clients' calls over one connection: each call is the client its own token names,
// concurrent calls of two clients on one channel included, and a refusal never names the other client.
// tests/proxy_tokens_test.sh does the same through HAProxy with TLS on both sides.
TEST(Access, OneConnectionCarriesSeveralClientsCalls) {
  api::ServerOptions options = TlsOptions();
  options.access.tokens_file = kTls + "tokens.txt";
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto shared = TlsChannel(server->port());
  auto call_as = [&](const std::string& token) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
    context.set_credentials(grpc::AccessTokenCredentials(token));
    v1::ListModelsResponse response;
    return v1::Loomlight::NewStub(shared)->ListModels(&context, v1::ListModelsRequest(), &response);
  };
  EXPECT_TRUE(call_as(kEditorToken).ok());
  const grpc::Status second = call_as(kPipelineToken);
  EXPECT_TRUE(second.ok()) << second.error_message();
  constexpr int kCallsEach = 40;
  std::vector<std::thread> threads;
  std::atomic<int> failed{0};
  for (const std::string& token : {kEditorToken, kPipelineToken, kEditorToken, kPipelineToken})
    threads.emplace_back([&, token] {
      for (int i = 0; i < kCallsEach / 2; ++i)
        if (!call_as(token).ok()) ++failed;
    });
  for (std::thread& thread : threads) thread.join();
  EXPECT_EQ(failed.load(), 0);

  grpc::ClientContext context;
  context.set_credentials(grpc::AccessTokenCredentials(kPipelineToken));
  v1::EvaluateResponse response;
  const grpc::Status denied = v1::Loomlight::NewStub(shared)->Evaluate(&context, v1::EvaluateRequest(), &response);
  EXPECT_EQ(denied.error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_NE(denied.error_message().find("thumbs-pipeline"), std::string::npos) << denied.error_message();
  EXPECT_EQ(denied.error_message().find("alice-editor"), std::string::npos) << denied.error_message();

  const std::string text = Metrics(server->metrics_port(), "thumbs-pipeline", kPipelineToken);
  for (const char* client : {"alice-editor", "thumbs-pipeline"})
    EXPECT_NE(text.find(std::string(R"(loomlight_client_calls_total{call="ListModels",client=")") + client +
                        R"(",code="OK"} )" + std::to_string(kCallsEach + 1) + "\n"),
              std::string::npos)
        << client << "\n" << text.substr(text.find("loomlight_client_calls_total{"), 1500);
}

// A method name is client input: calling made-up methods adds one series ("unknown") to the metrics, not one per
// name, and a refusal echoes the name quoted and cut short.
TEST(Access, UnknownMethodsAreOneMetricsLabelAndEchoedShort) {
  api::ServerOptions options;
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(server->port()), grpc::InsecureChannelCredentials());
  auto series = [&] {
    const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
    size_t count = 0;
    for (size_t at = text.find("\nloomlight_client_calls_total{"); at != std::string::npos;
         at = text.find("\nloomlight_client_calls_total{", at + 1))
      ++count;
    return std::make_pair(count, text);
  };
  EXPECT_TRUE(ListModels(channel).ok());
  constexpr int kNames = 50;
  for (int i = 0; i < kNames; ++i) {
    EXPECT_EQ(CallPath(channel, "/loomlight.v1.Loomlight/Foo" + std::to_string(i)).error_code(),
              grpc::StatusCode::UNIMPLEMENTED);
    EXPECT_EQ(CallPath(channel, "/random" + std::to_string(i) + ".Service/Method").error_code(),
              grpc::StatusCode::UNIMPLEMENTED);
  }
  const auto [first_count, first] = series();
  EXPECT_EQ(first.find("Foo"), std::string::npos) << first_count << " series";
  EXPECT_EQ(first.find("random"), std::string::npos);
  EXPECT_NE(first.find(R"(loomlight_client_calls_total{call="unknown",client="anonymous",code="OTHER"} )" +
                       std::to_string(2 * kNames) + "\n"),
            std::string::npos)
      << first.substr(first.find("loomlight_client_calls_total{"), 1500);
  for (int i = 0; i < kNames; ++i) CallPath(channel, "/loomlight.v1.Loomlight/Bar" + std::to_string(i));
  EXPECT_EQ(series().first, first_count);

  // With tokens, a method the pipeline's token does not list is refused, the name quoted and cut short.
  api::ServerOptions tls = TlsOptions();
  tls.access.tokens_file = kTls + "tokens.txt";
  auto secured = testing::StartInProcessServer(tls);
  ASSERT_TRUE(secured);
  const std::string path = "/loomlight.v1.Loomlight/" + std::string(4000, 'A');
  const grpc::Status denied = CallPath(TlsChannel(secured->port(), kPipelineToken), path);
  EXPECT_EQ(denied.error_code(), grpc::StatusCode::PERMISSION_DENIED) << denied.error_message().substr(0, 300);
  EXPECT_LT(denied.error_message().size(), 400u) << denied.error_message().substr(0, 300);
  EXPECT_NE(denied.error_message().find("(4024 bytes)"), std::string::npos) << denied.error_message().substr(0, 300);
}

// A reload swaps the whole file; a file that fails to load fails closed (a token the operator removed must not
// stay valid because of a typo): every token is refused, the replica is NOT_SERVING, until a reload succeeds.
TEST(Access, TokensReloadWholeOrFailClosed) {
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

  EXPECT_TRUE(Serving(TlsChannel(port)));

  // The operator removes the second token, but the file has an error on line 2: no token is valid.
  write("third-token-0123456789abcdef third ListModels\nshort x *\n");
  const std::string error = server->ReloadTokens();
  EXPECT_NE(error.find(":2:"), std::string::npos) << error;
  const grpc::Status refused = ListModels(TlsChannel(port, "second-token-0123456789abcdef"));
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_NE(refused.error_message().find("failed to reload"), std::string::npos) << refused.error_message();
  EXPECT_EQ(ListModels(TlsChannel(port, "third-token-0123456789abcdef")).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_FALSE(Serving(TlsChannel(port)));

  write("third-token-0123456789abcdef third ListModels\n");
  EXPECT_EQ(server->ReloadTokens(), "");
  EXPECT_TRUE(ListModels(TlsChannel(port, "third-token-0123456789abcdef")).ok());
  EXPECT_EQ(ListModels(TlsChannel(port, "second-token-0123456789abcdef")).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(Serving(TlsChannel(port)));
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
  EXPECT_EQ(api::MakeServerCredentials(plaintext, "127.0.0.2:50051", &credentials, &processor), "");
  EXPECT_EQ(api::MakeServerCredentials(plaintext, "[::ffff:127.0.0.1]:50051", &credentials, &processor), "");
  // Names are resolved, every address checked: a name that starts "127." is not an address.
  for (const char* remote : {"0.0.0.0:50051", "[::]:50051", "10.1.2.3:50051", "example.org:50051",
                             "127.evil.example:50051", "128.0.0.1:50051", "[::2]:50051", ":50051"}) {
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
      // '#' inside a field is an error, not a comment that silently cuts the token (to 17 characters here).
      {"long-enough-token#0123 a *\n", ":1: '#' inside a field"},
      {"long-enough-token-0123 a Evaluate#,Render\n", "'#' inside a field"},
  };
  for (const auto& [text, expected] : cases) {
    std::ofstream(file) << text;
    std::string error;
    EXPECT_EQ(api::TokenTable::Load(file, &error), nullptr) << text;
    EXPECT_NE(error.find(expected), std::string::npos) << text << " -> " << error;
  }
  std::ofstream(file) << "# a comment line\n\nlong-enough-token-0123 a Evaluate,Render   # trailing\n"
                          "other-long-token-0123 b *,metrics\t# after a tab\n";
  std::string error;
  auto table = api::TokenTable::Load(file, &error);
  ASSERT_TRUE(table) << error;
  const api::TokenTable::Entry* entry = table->Find("long-enough-token-0123");
  ASSERT_NE(entry, nullptr);
  EXPECT_TRUE(entry->Allows("Render"));
  EXPECT_FALSE(entry->Allows("Tabulate"));
  EXPECT_FALSE(entry->Allows("metrics"));
  EXPECT_EQ(table->Find("long-enough-token-012"), nullptr);   // a prefix is not the token
  EXPECT_EQ(table->Find("long-enough-token-0123x"), nullptr);  // nor is a longer one
  EXPECT_EQ(table->Find("long-enough-token-0124"), nullptr);
  // `*` is every RPC but not scraping; "*,metrics" is both.
  const api::TokenTable::Entry* all = table->Find("other-long-token-0123");
  ASSERT_NE(all, nullptr);
  EXPECT_EQ(all->client, "b");
  EXPECT_TRUE(all->Allows("Tabulate"));
  EXPECT_TRUE(all->Allows("metrics"));
  std::ofstream(file) << "long-enough-token-0123 a *\n";
  table = api::TokenTable::Load(file, &error);
  ASSERT_TRUE(table) << error;
  EXPECT_TRUE(table->Find("long-enough-token-0123")->Allows("reflection"));
  EXPECT_FALSE(table->Find("long-enough-token-0123")->Allows("metrics"));
  std::remove(file.c_str());
  EXPECT_EQ(api::CallName("/loomlight.v1.Loomlight/Evaluate"), "Evaluate");
  EXPECT_EQ(api::CallName("/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo"), "reflection");
  EXPECT_EQ(api::CallName("/grpc.health.v1.Health/Check"), "health");
  for (const char* made_up : {"/loomlight.v1.Loomlight/Foo123", "/loomlight.v1.Loomlight/", "/x.Y/Evaluate",
                              "Evaluate", "", "/loomlight.v1.Loomlight/Evaluate/x"})
    EXPECT_EQ(api::CallName(made_up), "unknown") << made_up;
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

// A long-running call that holds its slot while the test runs: a large tabulation whose stream the client reads
// only up to its first message (it is admitted), forwarded for `forwarded_for` when not empty. The call is
// cancelled when the object goes.
struct HeldTabulation {
  static v1::TabulateRequest Request() {
    v1::TabulateRequest request;
    request.mutable_material()->set_preset("velvet");
    v1::AnisotropicGrid* grid = request.mutable_anisotropic();
    grid->set_theta_i_count(64);
    grid->set_phi_i_count(64);
    grid->set_theta_o_count(64);
    grid->set_phi_o_count(64);  // 16.8 M cells: far more than the transport's windows hold unread
    request.set_format(v1::TABLE_FORMAT_RAW);
    return request;
  }
  HeldTabulation(v1::Loomlight::Stub& stub, const std::string& forwarded_for) {
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    if (!forwarded_for.empty()) context.AddMetadata("x-forwarded-for", forwarded_for);
    reader = stub.Tabulate(&context, Request());
    v1::TabulateChunk first;
    admitted = reader->Read(&first);
    if (!admitted) status = reader->Finish();
  }
  ~HeldTabulation() {
    if (!admitted) return;
    context.TryCancel();
    v1::TabulateChunk rest;
    while (reader->Read(&rest)) {
    }
    reader->Finish();
  }
  grpc::ClientContext context;
  std::unique_ptr<grpc::ClientReader<v1::TabulateChunk>> reader;
  bool admitted = false;
  grpc::Status status;  // why not, when refused
};

// Behind a load balancer every call comes from the proxy. A proxy the operator trusts (--trusted-proxy) names
// the client in X-Forwarded-For, whose last entry (the one the proxy appended) is the client for fair share and
// per-client limits; from anyone else the header is ignored, so a client cannot escape its limit by sending one.
TEST(Access, TrustedProxiesNameTheClientsTheyForward) {
  api::ServerOptions options;
  options.limits.max_long_calls_per_client = 1;
  ASSERT_EQ(options.access.trusted_proxies.Add("127.0.0.0/8"), "");
  {
    auto server = testing::StartInProcessServer(options);
    ASSERT_TRUE(server);
    auto stub = testing::Connect(server->port());  // one connection: the proxy's
    HeldTabulation first(*stub, "198.51.100.7");
    ASSERT_TRUE(first.admitted) << first.status.error_message();
    // Another client behind the proxy (the client's own entry first, the proxy's last) has its own slot.
    HeldTabulation other(*stub, "198.51.100.7, 203.0.113.9");
    EXPECT_TRUE(other.admitted) << other.status.error_message();
    // The first client again, whatever it claimed before the proxy's entry: its one slot is taken.
    HeldTabulation again(*stub, "203.0.113.9,198.51.100.7");
    EXPECT_FALSE(again.admitted);
    EXPECT_EQ(again.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(again.status.error_message().find("forwarded:::ffff:198.51.100.7"), std::string::npos)
        << again.status.error_message();
  }
  // Not a trusted proxy: the header changes nothing, the connection is the client.
  options.access.trusted_proxies = api::TrustedProxies();
  ASSERT_EQ(options.access.trusted_proxies.Add("10.0.0.0/8"), "");
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  HeldTabulation first(*stub, "198.51.100.7");
  ASSERT_TRUE(first.admitted) << first.status.error_message();
  HeldTabulation forged(*stub, "203.0.113.9");
  EXPECT_FALSE(forged.admitted);
  EXPECT_EQ(forged.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(forged.status.error_message().find("peer:"), std::string::npos) << forged.status.error_message();
}

TEST(Access, TrustedProxyBlocksAreParsed) {
  api::TrustedProxies proxies;
  EXPECT_EQ(proxies.Add("10.1.0.0/16"), "");
  EXPECT_EQ(proxies.Add("2001:db8::/32"), "");
  EXPECT_EQ(proxies.Add("192.0.2.1"), "");
  EXPECT_TRUE(proxies.Contains("ipv4:10.1.255.3:5000"));
  EXPECT_FALSE(proxies.Contains("ipv4:10.2.0.1:5000"));
  EXPECT_TRUE(proxies.Contains("ipv6:[2001:db8:1::5]:443"));
  EXPECT_FALSE(proxies.Contains("ipv6:[2001:db9::5]:443"));
  EXPECT_TRUE(proxies.Contains("ipv4:192.0.2.1:1"));
  EXPECT_FALSE(proxies.Contains("ipv4:192.0.2.2:1"));
  EXPECT_TRUE(proxies.Contains("ipv6:[::ffff:10.1.0.9]:7"));  // IPv4 by way of an IPv6 socket
  EXPECT_FALSE(proxies.Contains("unix:/run/loomlight.sock"));
  for (const char* bad : {"", "10.1.0.0/33", "2001:db8::/129", "10.1.0.0/", "10.1.0.0/x", "proxy.example:80",
                          "10.1.0.0/-1"})
    EXPECT_NE(proxies.Add(bad), "") << bad;
}

// The long-call slot is given back before the client sees its call end, so a client whose limit is one can
// start its next call the moment the last one ended.
TEST(Access, ALongCallsSlotIsFreeWhenTheClientSeesItsEnd) {
  api::ServerOptions options;
  options.limits.max_long_calls_per_client = 1;
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::TabulateRequest request;
  request.mutable_material()->set_preset("velvet");
  v1::AnisotropicGrid* grid = request.mutable_anisotropic();
  grid->set_theta_i_count(2);
  grid->set_phi_i_count(2);
  grid->set_theta_o_count(2);
  grid->set_phi_o_count(2);
  int refused = 0;
  for (int i = 0; i < 200; ++i) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
    auto reader = stub->Tabulate(&context, request);
    v1::TabulateChunk message;
    while (reader->Read(&message)) {
    }
    const grpc::Status status = reader->Finish();
    if (status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED) ++refused;
    else EXPECT_TRUE(status.ok()) << status.error_message();
  }
  EXPECT_EQ(refused, 0);
}

// Its own TCP connection to 127.0.0.1:port (a local subchannel pool and a distinct argument, or gRPC would
// share one): a second, third... connection from the same host.
std::shared_ptr<grpc::Channel> OwnConnection(int port, int connection) {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt("loomlight.test.connection", connection);
  return grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials(), args);
}

// Without a token or certificate a client is its address, not its connection: four connections from 127.0.0.1
// share one client's long-call limit (each was a client of its own, and had the limit to itself).
TEST(OneClient, ConnectionsFromOneHostShareItsLongCallLimit) {
  api::ServerOptions options;
  options.limits.max_long_calls_per_client = 2;
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  std::vector<std::unique_ptr<v1::Loomlight::Stub>> stubs;
  std::vector<std::unique_ptr<HeldTabulation>> held;
  int admitted = 0;
  for (int c = 0; c < 4; ++c) {
    stubs.push_back(v1::Loomlight::NewStub(OwnConnection(server->port(), c)));
    held.push_back(std::make_unique<HeldTabulation>(*stubs.back(), ""));
    if (held.back()->admitted) {
      ++admitted;
      continue;
    }
    EXPECT_EQ(held.back()->status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(held.back()->status.error_message().find("peer:::ffff:127.0.0.1)"), std::string::npos)
        << held.back()->status.error_message();
  }
  EXPECT_EQ(admitted, 2);  // was 4
  EXPECT_EQ(server->long_calls_in_use(), 2u);
}

// Each client has a share of the memory budget: a client holding one large call is refused a second that would
// pass its share, though the budget has room, and another client's call still gets in.
TEST(OneClient, AClientsShareOfTheMemoryBudgetLeavesRoomForOthers) {
  const models::PresetSpec* preset = nullptr;
  const models::Model* model = models::Registry::Global().FindPreset("velvet", &preset);
  ASSERT_TRUE(model);
  api::TabulationGrid grid;
  ASSERT_EQ(api::ResolveTabulationGrid(HeldTabulation::Request(), *model, &grid), "");
  const size_t call = api::TabulateBytes(HeldTabulation::Request(), grid);
  api::ServerOptions options;
  options.limits.memory_budget_bytes = 4 * call;
  options.memory_per_client_bytes = call + call / 2;  // one such call, not two
  ASSERT_EQ(options.access.trusted_proxies.Add("127.0.0.0/8"), "");  // two clients behind a "proxy"
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  HeldTabulation first(*stub, "198.51.100.7");
  ASSERT_TRUE(first.admitted) << first.status.error_message();
  HeldTabulation second(*stub, "198.51.100.7");
  EXPECT_FALSE(second.admitted);  // admitted before: the budget had room for three more
  EXPECT_EQ(second.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(second.status.error_message().find("this client (forwarded:::ffff:198.51.100.7) holds its share"),
            std::string::npos)
      << second.status.error_message();
  HeldTabulation other(*stub, "203.0.113.9");
  EXPECT_TRUE(other.admitted) << other.status.error_message();
}

// The share in the budget itself: a client's reservations (and their growth) stop at its share, another client's
// do not, and what one client gives back is its own again; more than a share is a permanent refusal.
TEST(OneClient, TheBudgetHoldsEachClientToItsShare) {
  batching::Budget memory(100, 40);
  api::Admission a1, a2, b1, too_big;
  ASSERT_TRUE(api::Admit(&memory, nullptr, 30, &a1, "a").ok());
  const grpc::Status refused = api::Admit(&memory, nullptr, 20, &a2, "a");
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << refused.error_message();
  EXPECT_NE(refused.error_message().find("its share of the memory budget (0 MiB"), std::string::npos)
      << refused.error_message();
  EXPECT_FALSE(a1.bytes.Grow(11));  // growing past the share mid-call
  EXPECT_TRUE(a1.bytes.Grow(10));
  ASSERT_TRUE(api::Admit(&memory, nullptr, 40, &b1, "b").ok());
  EXPECT_EQ(memory.in_use(), 80u);
  EXPECT_EQ(memory.client_in_use("a"), 40u);
  a1.bytes.Release();
  EXPECT_EQ(memory.client_in_use("a"), 0u);
  EXPECT_TRUE(api::Admit(&memory, nullptr, 20, &a2, "a").ok());
  const grpc::Status never = api::Admit(&memory, nullptr, 41, &too_big, "c");
  EXPECT_EQ(never.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << never.error_message();
  EXPECT_NE(never.error_message().find("more than one client's share"), std::string::npos) << never.error_message();
  // The server's own reservations (caches) are bounded by the whole budget only.
  batching::Budget::Reservation cache;
  EXPECT_TRUE(memory.TryReserve(40, &cache));
  EXPECT_EQ(memory.in_use(), 100u);
}

// A health Watch stream on `channel`, forwarded for `forwarded_for` when not empty: admitted when its first
// message (the current status) came; else why not. Cancelled when the object goes.
struct HeldWatch {
  HeldWatch(const std::shared_ptr<grpc::Channel>& channel, const std::string& forwarded_for) {
    if (!forwarded_for.empty()) context.AddMetadata("x-forwarded-for", forwarded_for);
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    reader = grpc::health::v1::Health::NewStub(channel)->Watch(&context, grpc::health::v1::HealthCheckRequest());
    admitted = reader->Read(&first);
    if (!admitted) status = reader->Finish();
  }
  ~HeldWatch() {
    if (!admitted) return;
    context.TryCancel();
    while (reader->Read(&first)) {
    }
    reader->Finish();
  }
  grpc::ClientContext context;
  std::unique_ptr<grpc::ClientReader<grpc::health::v1::HealthCheckResponse>> reader;
  grpc::health::v1::HealthCheckResponse first;
  bool admitted = false;
  grpc::Status status;
};

// Polls `done` for up to 30 s (waiting for an event, not timing it).
bool Eventually(const std::function<bool()>& done) {
  for (int i = 0; i < 3000; ++i) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return done();
}

// One connection holds at most --max-streams-per-connection calls open at once: its client's transport keeps
// the others waiting (HTTP/2 SETTINGS_MAX_CONCURRENT_STREAMS), so the server never sees more of them; another
// connection has its own.
TEST(OneClient, AConnectionOpensAtMostItsBoundOfStreams) {
  api::ServerOptions options;
  options.max_streams_per_connection = 2;
  options.max_health_watches_per_client = 100;
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const std::shared_ptr<grpc::Channel> a = OwnConnection(server->port(), 1), b = OwnConnection(server->port(), 2);
  ASSERT_EQ(Health(a), grpc::StatusCode::OK);  // connected: the server's SETTINGS are known to the client
  ASSERT_EQ(Health(b), grpc::StatusCode::OK);
  std::atomic<int> started{0};
  std::vector<std::unique_ptr<HeldWatch>> watches(6);
  std::vector<std::thread> threads;
  // Four Watch streams on connection a, then two on b.
  for (int i = 0; i < 6; ++i) {
    if (i == 4) {
      EXPECT_TRUE(Eventually([&] { return started == 2; })) << started;
    }
    threads.emplace_back([&, i] {
      watches[static_cast<size_t>(i)] = std::make_unique<HeldWatch>(i < 4 ? a : b, "");
      if (watches[static_cast<size_t>(i)]->admitted) ++started;
    });
  }
  EXPECT_TRUE(Eventually([&] { return started == 4; })) << started;
  // a's other two wait in its transport, and so does a call made on a now: its deadline passes unanswered.
  {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
    grpc::health::v1::HealthCheckResponse response;
    EXPECT_EQ(grpc::health::v1::Health::NewStub(a)
                  ->Check(&context, grpc::health::v1::HealthCheckRequest(), &response)
                  .error_code(),
              grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  EXPECT_EQ(server->health_watches(), 4u);
  EXPECT_EQ(server->health_watches_peak(), 4u);  // two per connection; six without the bound
  // Ending everything: the waiting streams end too (cancelled before or after they start).
  server->Shutdown();
  for (auto& t : threads) t.join();
}

// Health needs no token, and a Watch stream stays open as long as its client likes: open Watch streams are
// bounded per client and overall, and the extras refused RESOURCE_EXHAUSTED; an ended one makes room.
TEST(OneClient, HealthWatchStreamsBeyondTheBoundAreRefused) {
  api::ServerOptions options;
  options.max_health_watches = 3;
  options.max_health_watches_per_client = 2;
  ASSERT_EQ(options.access.trusted_proxies.Add("127.0.0.0/8"), "");  // clients behind a "proxy"
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const std::shared_ptr<grpc::Channel> channel = OwnConnection(server->port(), 1);
  auto first = std::make_unique<HeldWatch>(channel, "198.51.100.7");
  ASSERT_TRUE(first->admitted) << first->status.error_message();
  EXPECT_EQ(first->first.status(), grpc::health::v1::HealthCheckResponse::SERVING);
  HeldWatch second(channel, "198.51.100.7");
  ASSERT_TRUE(second.admitted) << second.status.error_message();
  HeldWatch third(channel, "198.51.100.7");  // the client's third
  EXPECT_FALSE(third.admitted);
  EXPECT_EQ(third.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(third.status.error_message().find("--max-health-watches-per-client"), std::string::npos)
      << third.status.error_message();
  HeldWatch other(channel, "203.0.113.9");
  ASSERT_TRUE(other.admitted) << other.status.error_message();
  HeldWatch fourth(channel, "192.0.2.1");  // a client with none, but the server has its three open
  EXPECT_FALSE(fourth.admitted);
  EXPECT_EQ(fourth.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(fourth.status.error_message().find("--max-health-watches)"), std::string::npos)
      << fourth.status.error_message();
  EXPECT_EQ(server->health_watches(), 3u);
  // Check is not a Watch: still answered.
  EXPECT_EQ(Health(channel), grpc::StatusCode::OK);
  first.reset();  // cancelled: its place is free once the server sees it end
  ASSERT_TRUE(Eventually([&] { return server->health_watches() == 2; }));
  HeldWatch again(channel, "192.0.2.1");
  EXPECT_TRUE(again.admitted) << again.status.error_message();
  // Shutting down, the open ones are told NOT_SERVING, then end.
  server->Shutdown();
  grpc::health::v1::HealthCheckResponse update;
  EXPECT_TRUE(again.reader->Read(&update));
  EXPECT_EQ(update.status(), grpc::health::v1::HealthCheckResponse::NOT_SERVING);
}

}  // namespace
}  // namespace loomlight
