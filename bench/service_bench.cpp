// Section 3: the gRPC service in process on a loopback port, driven by concurrent synchronous clients,
// each on its own channel (and TCP connection) and its own address (X-Forwarded-For from a trusted loopback: a
// host is one client), with the batcher coalescing and not.
#include <grpcpp/grpcpp.h>

#include <barrier>
#include <map>
#include <thread>

#include "bench/bench.h"
#include "bench/in_process.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"

namespace loomlight::bench {

using Stub = v1::Loomlight::Stub;

std::unique_ptr<api::LoomlightServer> StartServer(bool coalesce) {
  api::ServerOptions options;
  options.batcher.coalesce = coalesce;
  options.access.trusted_proxies.Add("127.0.0.1");  // the load's clients name their addresses (Call)
  return StartServer(options);
}

std::unique_ptr<api::LoomlightServer> StartServer(api::ServerOptions options) {
  options.address = "127.0.0.1:0";
  std::string error;
  auto server = api::LoomlightServer::Start(options, &error);
  if (!server) {
    std::fprintf(stderr, "cannot start the server: %s\n", error.c_str());
    std::exit(1);
  }
  return server;
}

std::unique_ptr<Stub> Connect(int port, int client_id) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(api::kMaxMessageBytes);
  args.SetMaxSendMessageSize(api::kMaxMessageBytes);
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt("loomlight.bench.client", client_id);
  return v1::Loomlight::NewStub(
      grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials(), args));
}

// n random pairs for one of the presets (clients rotate through them; all share the default T, so the
// batcher may coalesce them into one launch).
v1::EvaluateRequest MakeEvaluateRequest(size_t n, int client_id) {
  const auto& presets = models::Registry::Global().FindModel("microcylinder")->presets();
  v1::EvaluateRequest r;
  r.mutable_material()->set_preset(presets[static_cast<size_t>(client_id) % presets.size()].name);
  const Pairs p = RandomPairs(n, 1000 + static_cast<unsigned>(client_id));
  r.mutable_wi()->Add(p.wi.begin(), p.wi.end());
  r.mutable_wo()->Add(p.wo.begin(), p.wo.end());
  return r;
}

namespace {

struct CallResult {
  double seconds = 0;           // as the client sees it
  double kernel_seconds = 0;    // of the launch the call rode in (server side)
  uint32_t launch_queries = 0;  // queries in that launch
  bool ok = false;
};

// One Evaluate; from `address` (X-Forwarded-For) when not empty, as one of many client machines.
CallResult Call(Stub& stub, const v1::EvaluateRequest& request, const std::string& address = "") {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  if (!address.empty()) ctx.AddMetadata("x-forwarded-for", address);
  v1::EvaluateResponse response;
  const Clock::time_point start = Clock::now();
  const grpc::Status status = stub.Evaluate(&ctx, request, &response);
  CallResult r{SecondsSince(start), response.kernel_seconds(), response.batch_queries(), status.ok()};
  if (!status.ok()) std::fprintf(stderr, "call failed: %s\n", status.error_message().c_str());
  return r;
}

struct LoadConfig {
  int clients = 1;
  size_t queries_per_call = 1;
};

struct LoadResult {
  double queries_per_second = 0, p50 = 0, p99 = 0, mean_launch_queries = 0;
  size_t calls = 0, failures = 0;
};

LoadResult Summarise(const std::vector<std::vector<CallResult>>& per_client, size_t queries_per_call,
                     double wall_seconds) {
  LoadResult r;
  std::vector<double> latency;
  double launch_sum = 0;
  for (const auto& calls : per_client)
    for (const CallResult& c : calls) {
      latency.push_back(c.seconds);
      launch_sum += c.launch_queries;
      r.failures += c.ok ? 0 : 1;
    }
  r.calls = latency.size();
  r.queries_per_second = static_cast<double>((r.calls - r.failures) * queries_per_call) / wall_seconds;
  r.p50 = Percentile(latency, 0.5);
  r.p99 = Percentile(latency, 0.99);
  r.mean_launch_queries = r.calls ? launch_sum / static_cast<double>(r.calls) : 0;
  return r;
}

// Every client connects and makes one untimed call; then all start together and call back to back until
// the time or call budget is spent. Throughput counts the queries of every call over the wall time.
LoadResult RunLoad(int port, const LoadConfig& config, const Sizes& sizes) {
  std::vector<std::vector<CallResult>> results(static_cast<size_t>(config.clients));
  Clock::time_point start;
  std::barrier ready(config.clients, [&start]() noexcept { start = Clock::now(); });
  std::vector<std::thread> threads;
  for (int id = 0; id < config.clients; ++id)
    threads.emplace_back([&, id] {
      const std::unique_ptr<Stub> stub = Connect(port, id);
      const v1::EvaluateRequest request = MakeEvaluateRequest(config.queries_per_call, id);
      const std::string address = "10.77.0." + std::to_string(id + 1);
      Call(*stub, request, address);
      ready.arrive_and_wait();
      std::vector<CallResult>& mine = results[static_cast<size_t>(id)];
      while (mine.size() < sizes.service_max_calls && SecondsSince(start) < sizes.service_seconds)
        mine.push_back(Call(*stub, request, address));
    });
  for (auto& t : threads) t.join();
  return Summarise(results, config.queries_per_call, SecondsSince(start));
}

// One client, one maximal call: the fastest of the timed runs after a warm-up.
CallResult RunBigCall(int port, const Sizes& sizes) {
  const std::unique_ptr<Stub> stub = Connect(port, -1);
  const v1::EvaluateRequest request = MakeEvaluateRequest(sizes.big_call_queries, 0);
  Call(*stub, request);
  CallResult best{1e30};
  for (int r = 0; r < sizes.timed_runs; ++r) {
    const CallResult c = Call(*stub, request);
    if (c.ok && c.seconds < best.seconds) best = c;
  }
  return best;
}

const std::vector<int> kClients = {1, 8, 64};
const std::vector<size_t> kQueriesPerCall = {1, 64, 4096};

// Every load configuration against one server; keyed by (clients, queries per call).
std::map<std::pair<int, size_t>, LoadResult> RunAllLoads(int port, bool batching, const Sizes& sizes) {
  std::map<std::pair<int, size_t>, LoadResult> out;
  for (int clients : kClients)
    for (size_t n : kQueriesPerCall) {
      Progress("service: batching %s, %d clients x %zu queries\n", batching ? "on" : "off", clients, n);
      out[{clients, n}] = RunLoad(port, {clients, n}, sizes);
    }
  return out;
}

std::vector<std::string> LoadRow(int clients, size_t n, bool batching, const LoadResult& r) {
  return {std::to_string(clients), Count(n), batching ? "on" : "off", Count(r.calls), Rate(r.queries_per_second),
          Millis(r.p50), Millis(r.p99), Fixed(r.mean_launch_queries, 0), Count(r.failures)};
}

}  // namespace

std::string ServiceSection(const Sizes& sizes) {
  std::map<bool, std::map<std::pair<int, size_t>, LoadResult>> loads;
  CallResult big;
  for (bool batching : {true, false}) {
    const std::unique_ptr<api::LoomlightServer> server = StartServer(batching);
    loads[batching] = RunAllLoads(server->port(), batching, sizes);
    if (batching) {
      Progress("service: one call of %zu queries\n", sizes.big_call_queries);
      big = RunBigCall(server->port(), sizes);
    }
  }
  Table table({"clients", "queries/call", "batching", "calls", "queries/s", "p50 ms", "p99 ms",
               "mean queries/launch", "failed"},
              3);
  for (int clients : kClients)
    for (size_t n : kQueriesPerCall)
      for (bool batching : {true, false}) table.Add(LoadRow(clients, n, batching, loads[batching][{clients, n}]));

  const double big_rate = static_cast<double>(sizes.big_call_queries) / big.seconds;
  const double ratio = loads[true][{64, 64}].queries_per_second / big_rate;
  Table single({"call", "queries", "latency ms", "server kernel ms", "queries/s"});
  single.Add({"one client, one call", Count(sizes.big_call_queries), Millis(big.seconds), Millis(big.kernel_seconds),
              Rate(big_rate)});

  const std::string method =
      "An in-process `LoomlightServer` on 127.0.0.1 (port 0), one instance with batching and one without "
      "(`coalesce = false`), and synchronous gRPC clients in threads of the same process, each on its own channel "
      "and TCP connection; server, clients and kernel share the " +
      std::to_string(std::thread::hardware_concurrency()) +
      " hardware threads. Each client sends one request (its own preset, fp32, default T) once untimed, then back "
      "to back for " + Fixed(sizes.service_seconds, 1) + " s or " + Count(sizes.service_max_calls) +
      " calls, whichever comes first; queries/s = answered queries / wall time.";
  const std::string body =
      TableBlock("queries/s higher is better, latency per call as the client sees it; compare the batching on and "
                 "off rows of one load; mean queries/launch (the kernel launch a call rode in) above queries/call "
                 "is the batcher coalescing.",
                 table) +
      TableBlock("one maximal call (best of " + std::to_string(sizes.timed_runs) +
                     ") amortises every per-call cost: the service's ceiling on this machine.",
                 single) +
      "**64 clients x 64 queries with batching / single " + Count(sizes.big_call_queries) + "-query call: " +
      Fixed(ratio, 2) + "** (target >= 0.5)\n";
  return Section("3. gRPC service", method, body);
}

}  // namespace loomlight::bench
