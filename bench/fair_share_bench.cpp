// Section: fair share and TLS. An in-process server with TLS and bearer tokens (the test-only certificates of
// tests/data/tls), so every caller is a named client: an editor's 64-query Evaluate calls while a batch client
// runs eight maximum-size tabulations, a second batch client's one tabulation beside them, and Evaluate
// throughput over TLS against plaintext.
#include <grpcpp/grpcpp.h>

#include <atomic>
#include <barrier>
#include <thread>

#include "bench/bench.h"
#include "bench/in_process.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/access.h"
#include "server/api/server.h"
#include "server/api/tabulate.h"

namespace loomlight::bench {
namespace {

using Stub = v1::Loomlight::Stub;

const std::string kTls = std::string(LOOMLIGHT_SOURCE_DIR) + "/tests/data/tls/";
const std::string kEditorToken = "editor-token-0123456789abcdef";

// Client names are the tokens' (the file is written next to the certificates' copy in a temporary dir).
struct Clients {
  std::string file;
  Clients() {
    file = "/tmp/loomlight-bench-tokens-" + std::to_string(getpid()) + ".txt";
    FILE* f = std::fopen(file.c_str(), "w");
    std::fprintf(f, "%s editor *\nbatch-one-token-0123456789 batch-one *\nbatch-two-token-0123456789 batch-two *\n",
                 kEditorToken.c_str());
    std::fclose(f);
  }
  ~Clients() { std::remove(file.c_str()); }
};

std::unique_ptr<api::LoomlightServer> StartTlsServer(const std::string& tokens_file, bool tls) {
  api::ServerOptions options;
  if (tls) {
    options.access.tls_cert = kTls + "server.pem";
    options.access.tls_key = kTls + "server.key";
    options.access.tokens_file = tokens_file;  // may be "": TLS alone
  }
  return StartServer(options);
}

// Its own TCP connection (as Connect in the service section), over TLS with `token` when given.
std::unique_ptr<Stub> ConnectAs(int port, const std::string& token, int connection, bool tls = true) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(api::kMaxMessageBytes);
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt("loomlight.bench.client", connection);
  if (!tls)
    return v1::Loomlight::NewStub(grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port),
                                                   grpc::InsecureChannelCredentials(), args));
  grpc::SslCredentialsOptions ssl;
  std::string error;
  api::ReadFile(kTls + "ca.pem", &ssl.pem_root_certs, &error);
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::SslCredentials(ssl);
  if (!token.empty())
    credentials = grpc::CompositeChannelCredentials(credentials, grpc::AccessTokenCredentials(token));
  return v1::Loomlight::NewStub(grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port), credentials, args));
}

// The largest tabulation a call may ask for: the microcylinder on the MERL grid at the phi_h samples that fit
// the per-call limit.
v1::TabulateRequest MaximalTabulation() {
  v1::TabulateRequest request;
  request.mutable_material()->set_preset(models::Registry::Global().FindModel("microcylinder")->presets().front().name);
  request.mutable_merl()->set_phi_h_samples(static_cast<uint32_t>(api::kMaxTabulateQueries / (90 * 90 * 180)));
  request.set_format(v1::TABLE_FORMAT_RAW);
  return request;
}

// Streams one tabulation to its end; its seconds, or a negative number when it failed.
double Tabulate(Stub& stub, const v1::TabulateRequest& request) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(10));
  const Clock::time_point start = Clock::now();
  auto reader = stub.Tabulate(&context, request);
  v1::TabulateChunk chunk;
  while (reader->Read(&chunk)) {
  }
  const grpc::Status status = reader->Finish();
  if (!status.ok()) std::fprintf(stderr, "tabulation failed: %s\n", status.error_message().c_str());
  return status.ok() ? SecondsSince(start) : -1;
}

struct Latencies {
  std::vector<double> seconds;
  size_t failures = 0;
};

// The editor: a 64-query Evaluate every 5 ms (an interactive preview), for `seconds`.
Latencies Editor(int port, double seconds) {
  const std::unique_ptr<Stub> stub = ConnectAs(port, kEditorToken, 1000);
  const v1::EvaluateRequest request = MakeEvaluateRequest(64, 0);
  Latencies out;
  const Clock::time_point start = Clock::now();
  for (bool warm = false; SecondsSince(start) < seconds; warm = true) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    v1::EvaluateResponse response;
    const Clock::time_point call = Clock::now();
    const bool ok = stub->Evaluate(&context, request, &response).ok();
    if (warm) out.seconds.push_back(SecondsSince(call));
    out.failures += ok ? 0 : 1;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return out;
}

std::vector<std::string> LatencyRow(const std::string& load, const Latencies& l) {
  return {load, Count(l.seconds.size()), Millis(Percentile(l.seconds, 0.5)), Millis(Percentile(l.seconds, 0.99)),
          Millis(Percentile(l.seconds, 1.0)), Count(l.failures)};
}

// 64 clients x 64 queries back to back for `seconds`: queries per second.
double EvaluateThroughput(int port, bool tls, const std::string& token, double seconds) {
  constexpr int kClients = 64;
  std::atomic<size_t> calls{0}, failures{0};
  Clock::time_point start;
  std::barrier ready(kClients, [&start]() noexcept { start = Clock::now(); });
  std::vector<std::thread> threads;
  for (int id = 0; id < kClients; ++id)
    threads.emplace_back([&, id] {
      const std::unique_ptr<Stub> stub = ConnectAs(port, token, id, tls);
      const v1::EvaluateRequest request = MakeEvaluateRequest(64, id);
      auto call = [&] {
        grpc::ClientContext context;
        context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
        v1::EvaluateResponse response;
        return stub->Evaluate(&context, request, &response).ok();
      };
      call();  // connection and TLS handshake before the clock
      ready.arrive_and_wait();
      while (SecondsSince(start) < seconds) (call() ? calls : failures)++;
    });
  for (auto& t : threads) t.join();
  if (failures) std::fprintf(stderr, "%zu Evaluate calls failed\n", failures.load());
  return static_cast<double>(calls.load() * 64) / SecondsSince(start);
}

}  // namespace

std::string FairShareSection(const Sizes& sizes) {
  const Clients clients;
  const double editor_seconds = sizes.quick ? 3 : 10;
  const v1::TabulateRequest big = MaximalTabulation();

  Table latency({"load", "editor calls", "p50 ms", "p99 ms", "max ms", "failed"}, 1);
  Table bulk({"tabulation of batch-two", "seconds", "vs alone"}, 1);
  {
    auto server = StartTlsServer(clients.file, true);
    const int port = server->port();
    Progress("fair share: editor alone\n");
    latency.Add(LatencyRow("none", Editor(port, editor_seconds)));

    Progress("fair share: batch-two's tabulation alone\n");
    const std::unique_ptr<Stub> two = ConnectAs(port, "batch-two-token-0123456789", 2000);
    const double alone = Tabulate(*two, big);

    Progress("fair share: batch-one's eight tabulations, the editor and batch-two beside them\n");
    std::atomic<bool> stop{false};
    std::atomic<int> batch_done{0};
    std::vector<std::thread> batch;
    for (int i = 0; i < 8; ++i)
      batch.emplace_back([&, i] {
        const std::unique_ptr<Stub> one = ConnectAs(port, "batch-one-token-0123456789", 3000 + i);
        while (!stop) batch_done += Tabulate(*one, big) > 0;
      });
    std::this_thread::sleep_for(std::chrono::seconds(2));  // the eight are streaming
    std::thread beside([&] {
      const double shared = Tabulate(*two, big);
      bulk.Add({"alone", Fixed(alone, 2), "1.00"});
      bulk.Add({"beside batch-one's eight", Fixed(shared, 2), Fixed(shared / alone, 2)});
    });
    latency.Add(LatencyRow("batch-one: 8 maximal tabulations", Editor(port, editor_seconds)));
    beside.join();
    stop = true;
    for (auto& t : batch) t.join();
    Progress("fair share: batch-one finished %d tabulations\n", batch_done.load());
  }

  Table tls({"transport", "queries/s", "vs plaintext"}, 1);
  {
    const double seconds = sizes.quick ? 1.5 : sizes.service_seconds * 2;
    Progress("fair share: Evaluate throughput, plaintext\n");
    auto plain_server = StartTlsServer(clients.file, false);
    const double plaintext = EvaluateThroughput(plain_server->port(), false, "", seconds);
    plain_server.reset();
    Progress("fair share: Evaluate throughput, TLS\n");
    auto tls_only = StartTlsServer("", true);
    const double encrypted = EvaluateThroughput(tls_only->port(), true, "", seconds);
    tls_only.reset();
    Progress("fair share: Evaluate throughput, TLS with a token\n");
    auto tls_server = StartTlsServer(clients.file, true);
    const double secure = EvaluateThroughput(tls_server->port(), true, kEditorToken, seconds);
    tls.Add({"plaintext", Rate(plaintext), "1.00"});
    tls.Add({"TLS 1.3", Rate(encrypted), Fixed(encrypted / plaintext, 2)});
    tls.Add({"TLS 1.3 + bearer token", Rate(secure), Fixed(secure / plaintext, 2)});
  }

  const std::string method =
      "An in-process server with TLS and bearer tokens: three clients by name. `editor` sends a 64-query "
      "Evaluate every 5 ms; `batch-one` keeps eight maximal tabulations streaming (microcylinder on the MERL grid "
      "at " + std::to_string(big.merl().phi_h_samples()) + " phi_h samples: 33.5M kernel queries each), restarting "
      "each as it ends; `batch-two` runs one such tabulation alone and then beside batch-one's eight. Throughput: 64 "
      "clients, each on its own connection, 64-query Evaluate calls back to back, plaintext and TLS (handshake "
      "before the clock).";
  return Section("10. Fair share and TLS", method,
                 TableBlock("The editor's Evaluate latency as its client sees it, alone and under batch-one's load.",
                            latency) +
                     TableBlock("batch-two's one tabulation: fair share gives it about half the device while "
                                "batch-one has eight queued (first come, first served would give it a ninth).",
                                bulk) +
                     TableBlock("Evaluate throughput, 64 clients x 64 queries.", tls));
}

}  // namespace loomlight::bench
