// Section 3b: the server's CPU per call. The real loomlight-server binary runs as a child process, so its CPU
// clock holds nothing of the client's; one client thread calls it back to back on one channel, health Check
// (the standard empty call) and Evaluate of 1 and 64 queries in interleaved rounds.
#include <grpcpp/grpcpp.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <thread>

#include "bench/bench.h"
#include "bench/in_process.h"
#include "bench/report.h"
#include "bench/server_process.h"
#include "bench/stats.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/access.h"
#include "server/api/server.h"

namespace loomlight::bench {

namespace {

using grpc::health::v1::Health;
using grpc::health::v1::HealthCheckRequest;
using grpc::health::v1::HealthCheckResponse;

struct Kind {
  std::string name;
  size_t queries = 0;  // 0: health Check
};

const std::vector<Kind> kKinds = {{"health Check", 0}, {"Evaluate", 1}, {"Evaluate", 64}};

// One channel (one TCP connection of its own) for both services, with the message limits of section 3's clients.
class Client {
 public:
  Client(int port, const std::shared_ptr<grpc::ChannelCredentials>& credentials, int connection = 0) {
    grpc::ChannelArguments args;
    args.SetMaxReceiveMessageSize(api::kMaxMessageBytes);
    args.SetMaxSendMessageSize(api::kMaxMessageBytes);
    // The local subchannel pool and a distinct argument: gRPC would otherwise share one connection.
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    args.SetInt("loomlight.bench.connection", connection);
    channel_ = grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port), credentials, args);
    health_ = Health::NewStub(channel_);
    loomlight_ = v1::Loomlight::NewStub(channel_);
    for (const Kind& k : kKinds)
      requests_.push_back(k.queries ? MakeEvaluateRequest(k.queries, 0) : v1::EvaluateRequest());
  }

  // One call of kinds()[kind], with section 3's 120 s deadline (a deadline costs the server a timer: both
  // kinds carry it alike); whether it succeeded.
  bool Call(size_t kind) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    grpc::Status status;
    if (kKinds[kind].queries == 0) {
      HealthCheckResponse response;
      status = health_->Check(&ctx, HealthCheckRequest(), &response);
      if (status.ok() && response.status() != HealthCheckResponse::SERVING)
        status = grpc::Status(grpc::StatusCode::UNAVAILABLE, "health not SERVING");
    } else {
      v1::EvaluateResponse response;
      status = loomlight_->Evaluate(&ctx, requests_[kind], &response);
    }
    if (!status.ok()) std::fprintf(stderr, "service cpu: call failed: %s\n", status.error_message().c_str());
    return status.ok();
  }

  // The same Evaluate call through gRPC's callback API: `done(ok)` runs on one of gRPC's threads when it ends,
  // so many calls in flight need no thread each (a blocking thread per call costs the client a context switch
  // and a completion queue per call).
  void CallAsync(size_t kind, std::function<void(bool)> done) {
    auto call = std::make_shared<AsyncCall>();
    call->ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    loomlight_->async()->Evaluate(&call->ctx, &requests_[kind], &call->response,
                                  [call, done = std::move(done)](grpc::Status status) {
                                    if (!status.ok())
                                      std::fprintf(stderr, "service cpu: call failed: %s\n",
                                                   status.error_message().c_str());
                                    done(status.ok());
                                  });
  }

 private:
  struct AsyncCall {
    grpc::ClientContext ctx;
    v1::EvaluateResponse response;
  };
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<Health::Stub> health_;
  std::unique_ptr<v1::Loomlight::Stub> loomlight_;
  std::vector<v1::EvaluateRequest> requests_;
};

// CPU of this (the client's) process, all threads: gRPC's own threads do part of the client's work.
double SelfCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Round {
  size_t calls = 0, failures = 0;
  double server_cpu = 0, client_cpu = 0, wall = 0;  // seconds, over all the round's calls
  std::vector<double> latency;                      // seconds, per call
};

Round RunRound(const ChildServer& server, Client& client, size_t kind, size_t max_calls, double seconds) {
  Round r;
  r.latency.reserve(max_calls);
  const double server0 = server.CpuSeconds(), client0 = SelfCpuSeconds();
  const Clock::time_point start = Clock::now();
  while (r.calls < max_calls && SecondsSince(start) < seconds) {
    const Clock::time_point call = Clock::now();
    r.failures += client.Call(kind) ? 0 : 1;
    r.latency.push_back(SecondsSince(call));
    ++r.calls;
  }
  r.wall = SecondsSince(start);
  r.server_cpu = server.CpuSeconds() - server0;
  r.client_cpu = SelfCpuSeconds() - client0;
  return r;
}

double Median(std::vector<double> v) { return Percentile(v, 0.5); }

// "Threads:" of /proc/<pid>/status, or 0.
int Threads(pid_t pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("Threads:", 0) == 0) return std::atoi(line.c_str() + 8);
  return 0;
}

struct KindResult {
  size_t calls = 0, failures = 0;
  double server_us = 0, server_min_us = 0, server_max_us = 0;  // per call: median, fastest and slowest round
  double client_us = 0, idle_us = 0, p50_us = 0;
};

KindResult Summarise(const std::vector<Round>& rounds, double idle_rate) {
  KindResult k;
  std::vector<double> server, client, idle, latency;
  for (const Round& r : rounds) {
    if (r.calls == 0) continue;
    const double n = static_cast<double>(r.calls);
    k.calls += r.calls;
    k.failures += r.failures;
    server.push_back(1e6 * r.server_cpu / n);
    client.push_back(1e6 * r.client_cpu / n);
    idle.push_back(1e6 * idle_rate * r.wall / n);
    latency.insert(latency.end(), r.latency.begin(), r.latency.end());
  }
  if (server.empty()) return k;
  k.server_us = Median(server);
  k.server_min_us = *std::min_element(server.begin(), server.end());
  k.server_max_us = *std::max_element(server.begin(), server.end());
  k.client_us = Median(client);
  k.idle_us = Median(idle);
  k.p50_us = 1e6 * Percentile(latency, 0.5);
  return k;
}

// The test-only TLS material (tests/data/tls: a certificate for 127.0.0.1 and a token file).
const std::string kTlsDir = std::string(LOOMLIGHT_SOURCE_DIR) + "/tests/data/tls/";
const char kTlsToken[] = "editor-token-0123456789abcdef";

struct Transport {
  std::string name;
  std::vector<std::string> server_args;
  std::shared_ptr<grpc::ChannelCredentials> credentials;  // the client's, token included
};

std::vector<Transport> Transports() {
  grpc::SslCredentialsOptions ssl;
  std::string error;
  api::ReadFile(kTlsDir + "ca.pem", &ssl.pem_root_certs, &error);
  return {{"plaintext", {}, grpc::InsecureChannelCredentials()},
          {"TLS + token",
           {"--tls-cert", kTlsDir + "server.pem", "--tls-key", kTlsDir + "server.key", "--tokens",
            kTlsDir + "tokens.txt"},
           grpc::CompositeChannelCredentials(grpc::SslCredentials(ssl), grpc::AccessTokenCredentials(kTlsToken))},
          // TLS alone (no tokens file, no token sent): what the bearer-token check adds on top of TLS.
          {"TLS", {"--tls-cert", kTlsDir + "server.pem", "--tls-key", kTlsDir + "server.key"},
           grpc::SslCredentials(ssl)}};
}

struct TransportResult {
  std::vector<KindResult> kinds;
  double idle_rate = 0;  // the idle server's CPU seconds per second
  int threads = 0;
  std::string clock_name;
};

// Warm-up, the idle server's own CPU, then interleaved rounds of every kind, on a fresh child server.
TransportResult Measure(const Transport& transport, const Sizes& sizes) {
  TransportResult out;
  std::vector<std::string> args = {"--shutdown-grace", "2"};
  args.insert(args.end(), transport.server_args.begin(), transport.server_args.end());
  const ChildServer server(args, transport.credentials);
  out.clock_name = server.CpuClockName();
  Client client(server.port(), transport.credentials);
  Progress("service cpu, %s: %zu warm-up calls of each kind\n", transport.name.c_str(), sizes.cpu_warmup_calls);
  for (size_t kind = 0; kind < kKinds.size(); ++kind)
    for (size_t i = 0; i < sizes.cpu_warmup_calls; ++i) client.Call(kind);
  // What the server burns doing nothing (gRPC timers, the batcher, the stall watchdog, PoCL's workers).
  const double idle0 = server.CpuSeconds();
  const Clock::time_point idle_start = Clock::now();
  std::this_thread::sleep_for(std::chrono::duration<double>(sizes.cpu_idle_seconds));
  out.idle_rate = (server.CpuSeconds() - idle0) / SecondsSince(idle_start);

  std::vector<std::vector<Round>> rounds(kKinds.size());
  for (int round = 0; round < sizes.cpu_rounds; ++round)
    for (size_t kind = 0; kind < kKinds.size(); ++kind) {
      Progress("service cpu, %s: round %d, %s of %zu queries\n", transport.name.c_str(), round + 1,
               kKinds[kind].name.c_str(), kKinds[kind].queries);
      rounds[kind].push_back(
          RunRound(server, client, kind, sizes.cpu_calls, sizes.cpu_seconds));
    }
  out.threads = Threads(server.pid());
  for (const auto& r : rounds) out.kinds.push_back(Summarise(r, out.idle_rate));
  return out;
}

// Every thread of this process pinned to one CPU while it lives (threads started meanwhile inherit their
// creator's CPU); then back to the mask the constructing thread had.
class PinnedProcess {
 public:
  explicit PinnedProcess(int cpu) {
    sched_getaffinity(0, sizeof before_, &before_);
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(cpu, &one);
    SetEveryThread(one);
  }
  ~PinnedProcess() { SetEveryThread(before_); }

 private:
  static void SetEveryThread(const cpu_set_t& cpus) {
    std::error_code error;
    for (const auto& task : std::filesystem::directory_iterator("/proc/self/task", error))
      sched_setaffinity(std::atoi(task.path().filename().c_str()), sizeof cpus, &cpus);
  }
  cpu_set_t before_;
};

constexpr int kConcurrentClients = 64;
constexpr size_t kConcurrentKind = 2;  // Evaluate of 64 queries

struct RoundRate {
  double queries_per_second = 0;
  double server_busy = 0;  // the server's CPU seconds per second of the round (its one CPU: 1 = saturated)
  double client_busy = 0;  // the same for this process (the clients' CPU)
};

// Queries per second of the clients, each on its own connection with one Evaluate call of 64 queries in flight,
// the next started as the last ends, for `seconds`; with how busy the server's and the clients' CPUs were. The
// calls go through gRPC's callback API so that the clients' side costs as little CPU as it can: with remote
// clients none of it would be on the server's machine.
RoundRate ConcurrentRound(std::vector<std::unique_ptr<Client>>& clients, const ChildServer& server, double seconds,
                          size_t* failures) {
  std::atomic<size_t> calls{0}, failed{0};
  std::mutex mutex;
  std::condition_variable all_done;
  size_t running = clients.size();
  const double server_cpu = server.CpuSeconds(), client_cpu = SelfCpuSeconds();
  const Clock::time_point start = Clock::now();
  // One closed loop per client: each completion starts that client's next call until the time is up.
  std::function<void(Client*)> next = [&](Client* client) {
    client->CallAsync(kConcurrentKind, [&, client](bool ok) {
      (ok ? calls : failed)++;
      if (SecondsSince(start) < seconds) {
        next(client);
        return;
      }
      std::lock_guard<std::mutex> lock(mutex);
      if (--running == 0) all_done.notify_one();
    });
  };
  for (auto& client : clients) next(client.get());
  {
    std::unique_lock<std::mutex> lock(mutex);
    all_done.wait(lock, [&] { return running == 0; });
  }
  const double wall = SecondsSince(start);
  *failures += failed.load();
  RoundRate out;
  out.queries_per_second = static_cast<double>(calls.load() * kKinds[kConcurrentKind].queries) / wall;
  out.server_busy = (server.CpuSeconds() - server_cpu) / wall;
  out.client_busy = (SelfCpuSeconds() - client_cpu) / wall;
  return out;
}

struct ConcurrentResult {
  bool ran = false;
  std::string why_not;
  std::vector<std::vector<RoundRate>> rate;  // [transport][round]
  size_t failures = 0;
};

// The throughput figure with remote clients' CPU kept off the server's: each transport's server a child
// process pinned to CPU 0, the benchmark's 64 clients (and every thread of this process) pinned to CPU 1, so the
// server's one CPU is the bottleneck as on a machine of its own; interleaved rounds of every transport.
ConcurrentResult MeasureConcurrent(const std::vector<Transport>& transports, const Sizes& sizes) {
  ConcurrentResult out;
  cpu_set_t allowed;
  sched_getaffinity(0, sizeof allowed, &allowed);
  if (!CPU_ISSET(0, &allowed) || !CPU_ISSET(1, &allowed)) {
    out.why_not = "needs CPUs 0 and 1";
    return out;
  }
  std::vector<std::unique_ptr<ChildServer>> servers;
  for (const Transport& t : transports) {
    std::vector<std::string> args = {"--shutdown-grace", "2"};
    args.insert(args.end(), t.server_args.begin(), t.server_args.end());
    servers.push_back(std::make_unique<ChildServer>(args, t.credentials, 0));
  }
  const PinnedProcess pinned(1);
  std::vector<std::vector<std::unique_ptr<Client>>> clients(transports.size());
  for (size_t t = 0; t < transports.size(); ++t)
    for (int c = 0; c < kConcurrentClients; ++c) {
      clients[t].push_back(std::make_unique<Client>(servers[t]->port(), transports[t].credentials, c));
      for (size_t i = 0; i < 20; ++i) clients[t].back()->Call(kConcurrentKind);  // connection, handshake, warm-up
    }
  out.rate.resize(transports.size());
  for (int round = 0; round < sizes.concurrent_rounds; ++round)
    for (size_t t = 0; t < transports.size(); ++t) {
      Progress("service cpu, %d clients, %s: round %d\n", kConcurrentClients, transports[t].name.c_str(), round + 1);
      out.rate[t].push_back(ConcurrentRound(clients[t], *servers[t], sizes.concurrent_seconds, &out.failures));
    }
  out.ran = true;
  return out;
}

}  // namespace

std::string ServiceCpuSection(const Sizes& sizes) {
  Progress("service cpu: starting %s\n", LOOMLIGHT_SERVER_BINARY);
  const std::vector<Transport> transports = Transports();
  std::vector<TransportResult> results;
  for (const Transport& t : transports) results.push_back(Measure(t, sizes));
  const ConcurrentResult concurrent = MeasureConcurrent(transports, sizes);

  const std::vector<KindResult>& plain = results[0].kinds;
  const double health_us = plain[0].server_us;
  auto ratio = [](double us, double base_us) { return base_us > 0 ? us / base_us : 0.0; };
  Table table({"transport", "call", "queries", "calls", "server CPU us/call", "rounds min-max", "of it idle us",
               "client CPU us/call", "p50 latency us", "server CPU / plaintext health", "failed"});
  for (size_t t = 0; t < transports.size(); ++t)
    for (size_t kind = 0; kind < kKinds.size(); ++kind) {
      const KindResult& r = results[t].kinds[kind];
      table.Add({transports[t].name, kKinds[kind].name, kKinds[kind].queries ? Count(kKinds[kind].queries) : "-",
                 Count(r.calls), Fixed(r.server_us, 1),
                 Fixed(r.server_min_us, 1) + "-" + Fixed(r.server_max_us, 1), Fixed(r.idle_us, 1),
                 Fixed(r.client_us, 1), Fixed(r.p50_us, 0), Fixed(ratio(r.server_us, health_us), 2),
                 Count(r.failures)});
    }
  // A server whose CPU is the bottleneck serves calls in inverse proportion to its CPU per call.
  const double tls_capacity = ratio(plain[2].server_us, results[1].kinds[2].server_us);

  const std::string method =
      "The real `loomlight-server` binary as a child process of the benchmark (`--address 127.0.0.1:0`, default "
      "options: batching on), so that its CPU time holds nothing of the client's; in plaintext, with TLS and "
      "bearer tokens (`--tls-cert`, `--tls-key`, `--tokens`: the test-only certificate and token file of "
      "tests/data/tls; the client sends its token on every call but health, which needs none), and with TLS "
      "alone (no tokens: what the token check adds). One "
      "client thread in the benchmark, on one channel (one TCP connection, its TLS handshake in the warm-up), "
      "calls it back to back: the standard `grpc.health.v1` Health/Check (service \"\", the empty call) and "
      "Evaluate with section 3's request (a microcylinder preset, fp32, default T) of 1 and of 64 random pairs, "
      "every call with a 120 s deadline. After " +
      Count(sizes.cpu_warmup_calls) + " warm-up calls of each kind, " +
      std::to_string(sizes.cpu_rounds) + " interleaved rounds of health, Evaluate 1, Evaluate 64, each " +
      Count(sizes.cpu_calls) + " calls or " +
      Fixed(sizes.cpu_seconds, 1) + " s, whichever comes first. Server CPU per call is the difference of " +
      results[0].clock_name + " over a round, divided by its calls; the table gives the median round. The idle "
      "server used " + Fixed(1e6 * results[0].idle_rate, 0) + " us of CPU per second in plaintext, " +
      Fixed(1e6 * results[1].idle_rate, 0) + " with TLS and tokens (measured over " + Fixed(sizes.cpu_idle_seconds, 1) +
      " s before the rounds; included in the per-call figures, shown as \"of it idle\"); it ran " +
      std::to_string(results[0].threads) + " threads at the end. Client CPU is the whole benchmark process's.";
  const std::string body =
      TableBlock("server CPU us/call lower is better; the ratio column divides by the plaintext health Check's, "
                 "the cost of gRPC's own call path on this server; rounds min-max shows how steady the machine "
                 "was.",
                 table) +
      "**server CPU, 1-query Evaluate / health Check: " + Fixed(ratio(plain[1].server_us, health_us), 2) +
      "** (target <= 1.4)\n\n**server capacity for 64-query Evaluate calls with TLS and tokens, as a share of "
      "plaintext's (plaintext server CPU per call / TLS's): " + Fixed(tls_capacity, 2) +
      "** (target >= 0.85: within 15%)\n";
  std::string concurrent_block;
  if (!concurrent.ran) {
    concurrent_block = "\nThe pinned throughput run was skipped: " + concurrent.why_not + ".\n";
  } else {
    Table rates({"transport", "queries/s (median round)", "rounds min-max", "server CPU busy", "clients' CPU busy",
                 "vs plaintext (median of rounds)"},
                1);
    std::vector<double> round_ratio;
    for (size_t t = 0; t < transports.size(); ++t) {
      std::vector<double> r, server_busy, client_busy, ratios;
      for (size_t i = 0; i < concurrent.rate[t].size(); ++i) {
        const RoundRate& round = concurrent.rate[t][i];
        r.push_back(round.queries_per_second);
        server_busy.push_back(round.server_busy);
        client_busy.push_back(round.client_busy);
        ratios.push_back(round.queries_per_second / concurrent.rate[0][i].queries_per_second);
      }
      if (t == 1) round_ratio = ratios;
      rates.Add({transports[t].name, Rate(Median(r)),
                 Rate(*std::min_element(r.begin(), r.end())) + "-" + Rate(*std::max_element(r.begin(), r.end())),
                 Fixed(100 * Median(server_busy), 0) + "%", Fixed(100 * Median(client_busy), 0) + "%",
                 Fixed(Median(ratios), 2)});
    }
    std::string each;
    for (double x : round_ratio) each += (each.empty() ? "" : ", ") + Fixed(x, 2);
    concurrent_block =
        "\n**" + std::to_string(kConcurrentClients) + " clients x 64 queries, the server on a CPU of its own.** "
        "The same servers, started again with every thread pinned to CPU 0; the benchmark's " +
        std::to_string(kConcurrentClients) + " clients, each on its own connection (its TLS handshake before the "
        "clock), and every thread of the benchmark pinned to CPU 1, so that the clients' own TLS work is not "
        "taken from the server's CPU (as with clients on other machines) and the server's one CPU is the "
        "bottleneck. Each client keeps one Evaluate call of 64 random pairs in flight, starting the next as the "
        "last ends, through gRPC's callback API (a blocking thread per client spent the clients' CPU on context "
        "switches, and the clients' CPU, not the server's, was then the limit); " +
        std::to_string(sizes.concurrent_rounds) + " interleaved rounds of " + Fixed(sizes.concurrent_seconds, 1) +
        " s per transport, " + Count(concurrent.failures) + " calls failed.\n\n" +
        TableBlock("queries/s higher is better; the ratio is TLS's queries over plaintext's in the same round; "
                   "CPU busy is CPU seconds per second of the round (median round): the server's one CPU at 100% is "
                   "the bottleneck the figure means, less says the calls waited on something else.",
                   rates) +
        "**Evaluate throughput with TLS and tokens, 64 clients x 64 queries, as a share of plaintext's (median "
        "of the rounds' ratios " + each + "): " + Fixed(Median(round_ratio), 2) +
        "** (target >= 0.85: within 15%)\n";
  }
  return Section("3b. Server CPU per call", method, body + concurrent_block);
}

}  // namespace loomlight::bench
