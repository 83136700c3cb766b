// loomlight-server: serves the Loomlight API on PoCL's CPU device (or any OpenCL device).
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <algorithm>
#include <cstring>
#include <optional>
#include <string>
#include <thread>

#include "server/api/server.h"
#include "server/runtime/allocator.h"

namespace {

void Usage() {
  std::fprintf(stderr,
               "usage: loomlight-server [options]\n"
               "  --address HOST:PORT        listen address (default 127.0.0.1:50051)\n"
               "  --tls-cert FILE            serve TLS with this PEM certificate chain (and --tls-key)\n"
               "  --tls-key FILE             the certificate's PEM private key\n"
               "  --tls-client-ca FILE       mutual TLS: clients must present a certificate this CA signed\n"
               "  --tokens FILE              every call but health needs a bearer token listed in FILE\n"
               "                             (lines 'TOKEN CLIENT CALLS'; reloaded on SIGHUP; needs TLS)\n"
               "  --allow-plaintext-remote   allow plaintext on an address other than loopback\n"
               "  --trusted-proxy ADDR[/BITS] believe X-Forwarded-For from this proxy (repeatable): fair share and\n"
               "                             per-client limits then count the client it forwards, not the proxy\n"
               "  --platform NAME            OpenCL platform substring (env LOOMLIGHT_PLATFORM; default PoCL)\n"
               "  --device NAME              OpenCL device substring (env LOOMLIGHT_DEVICE; default first CPU)\n"
               "  --cache-dir DIR            PoCL kernel cache (POCL_CACHE_DIR; default ~/.cache/loomlight/pocl)\n"
               "  --vector-width N           queries per work-item in float kernels: 1, 2, 4, 8, 16 (default: device)\n"
               "  --small-launch-queries N   launches of at most N queries run on PoCL's single-threaded basic device,\n"
               "                             on the launching thread (default 256; 0: every launch on the main device)\n"
               "  --max-batch-queries N      queries per coalesced launch (default 1048576)\n"
               "  --max-queue-delay-us N     wait this long for a batch to fill (default 0; both priorities)\n"
               "  --max-queued-queries N     queued queries per priority before RESOURCE_EXHAUSTED (default 8388608\n"
               "                             interactive, 16777216 bulk)\n"
               "  --queue-policy PRIORITY:KEY=VALUE[,KEY=VALUE...]\n"
               "                             one priority's queue (interactive: Evaluate, Sample, TextureSlice;\n"
               "                             bulk: Tabulate, Render); keys: max_queue_delay_us, max_queued_queries,\n"
               "                             max_client_queued_queries (default 4194304, bulk 8388608), timeout_ms (default 0,\n"
               "                             none), timeout_action: reject (a job queued longer than timeout_ms\n"
               "                             fails RESOURCE_EXHAUSTED; the default) or delay (it goes behind every\n"
               "                             job of its priority that has not timed out)\n"
               "  --no-batching              one request per launch\n"
               "  --metrics-address HOST:PORT  serve Prometheus metrics at http://HOST:PORT/metrics (default: off)\n"
               "  --environment-dir DIR      environment maps clients may name (EXR/HDR files; default: none)\n"
               "  --data-dir DIR             BTF assets live under DIR/btf (default $XDG_STATE_HOME/loomlight,\n"
               "                             else ~/.local/state/loomlight)\n"
               "  --btf-store-mb N           all BTF assets together, in MiB (default 2048)\n"
               "  --btf-client-quota-mb N    one client's BTF assets, in MiB (default 1024; 0: the store's bound)\n"
               "  --btf-sync-seconds N       look for assets other replicas sharing --data-dir added, replaced or\n"
               "                             deleted every N s (default 5; 0: only at start and on SIGHUP)\n"
               "  --memory-budget-mb N       bytes all calls' buffers may hold, in MiB (default 2048)\n"
               "  --max-long-calls N         TextureSlice, Tabulate and Render calls at once (default 16)\n"
               "  --max-long-calls-per-client N  of them, one client's (its token's name, else the address a\n"
               "                             --trusted-proxy forwarded, else its address; default 8)\n"
               "  --max-memory-per-client-mb N  of the memory budget, one client's calls together, in MiB\n"
               "                             (default: half of --memory-budget-mb)\n"
               "  --max-streams-per-connection N  calls open at once on one connection (default 100)\n"
               "  --keepalive-seconds N      ping a connection after N s without traffic (default 60) and close it\n"
               "                             when the answer takes --keepalive-timeout-seconds (default 20)\n"
               "  --max-connection-age-seconds N  a connection is told to reconnect after N s (default 3600); its\n"
               "                             calls may finish within --max-connection-age-grace-seconds (default:\n"
               "                             the bulk --max-call-seconds)\n"
               "  --max-health-watches N     health Watch streams open at once (default 256)\n"
               "  --max-health-watches-per-client N  of them, one client's (default 8)\n"
               "  --material-cache-mb N      packed materials kept, in MiB (default 64)\n"
               "  --fold-cache-mb N          BTF environment folds kept across renders, in MiB (default 128)\n"
               "  --fiber-cache-mb N         fiber scenes (fibers' BVH, tubes, openness) kept across calls, in MiB\n"
               "                             (default 256)\n"
               "  --upload-idle-seconds N    an UploadBtf that sends nothing for N s is cancelled (default 60)\n"
               "  --max-upload-seconds N     an UploadBtf still sending N s after it started is cancelled\n"
               "                             (default 1800)\n"
               "  --environment-cache-mb N   decoded environment maps kept, in MiB (default 256)\n"
               "  --grpc-memory-mb N         gRPC's own buffers, in MiB (default 512)\n"
               "  --stall-seconds N          health NOT_SERVING while one task runs longer (default 20)\n"
               "  --max-call-seconds [PRIORITY:]N  a call's deadline is its client's, at most N s (both priorities,\n"
               "                             or interactive: Evaluate, Sample, TextureSlice; bulk: Tabulate, Render,\n"
               "                             YarnGeometry, CreateBtf; repeatable; default interactive 120, bulk 3600)\n"
               "  --stall-write-seconds N    a stream whose client reads nothing for N s is cancelled (default 60)\n"
               "  --shutdown-grace SECONDS   on SIGTERM, in-flight calls may finish this long (default 30)\n");
}

// "bulk:timeout_ms=60000,max_queued_queries=4194304" into the priority's policy; "" or what is wrong.
std::string ParseQueuePolicy(const std::string& text, loomlight::batching::BatcherOptions* options) {
  const size_t colon = text.find(':');
  const std::string priority = text.substr(0, colon);
  loomlight::batching::QueuePolicy* policy = priority == "interactive" ? &options->interactive
                                             : priority == "bulk"      ? &options->bulk
                                                                       : nullptr;
  if (!policy || colon == std::string::npos) return "expected interactive:KEY=VALUE,... or bulk:KEY=VALUE,...";
  size_t begin = colon + 1;
  while (begin <= text.size()) {
    const size_t comma = std::min(text.find(',', begin), text.size());
    const std::string item = text.substr(begin, comma - begin);
    const size_t equals = item.find('=');
    if (equals == std::string::npos || equals + 1 == item.size()) return "'" + item + "' is not KEY=VALUE";
    const std::string key = item.substr(0, equals), value = item.substr(equals + 1);
    begin = comma + 1;
    using Action = loomlight::batching::QueuePolicy::TimeoutAction;
    if (key == "timeout_action") {
      if (value != "reject" && value != "delay") return "timeout_action is reject or delay, not '" + value + "'";
      policy->timeout_action = value == "reject" ? Action::kReject : Action::kDelay;
      continue;
    }
    char* end = nullptr;
    const unsigned long long n = std::strtoull(value.c_str(), &end, 10);
    if (*end) return "'" + item + "' is not KEY=NUMBER";
    if (key == "max_queue_delay_us") policy->max_queue_delay = std::chrono::microseconds(n);
    else if (key == "max_queued_queries") policy->max_queued_queries = n;
    else if (key == "max_client_queued_queries") policy->max_client_queued_queries = n;
    else if (key == "timeout_ms") policy->timeout = std::chrono::milliseconds(n);
    else return "unknown key '" + key + "'";
  }
  return "";
}

volatile std::sig_atomic_t g_stop = 0;
volatile std::sig_atomic_t g_reload = 0;

}  // namespace

int main(int argc, char** argv) {
  loomlight::api::ServerOptions options;
  options.data_dir = loomlight::assets::BtfStore::DefaultDataDir();
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    // "--name=value" is "--name value" (the form manifests and service files often use).
    std::optional<std::string> attached;
    if (const size_t equals = arg.find('='); arg.rfind("--", 0) == 0 && equals != std::string::npos) {
      attached = arg.substr(equals + 1);
      arg.resize(equals);
    }
    bool attached_taken = false;
    auto value = [&]() -> std::string {
      if (attached) {
        attached_taken = true;
        return *attached;
      }
      if (i + 1 >= argc) {
        std::fprintf(stderr, "error: %s needs a value\n", arg.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    auto number = [&]() -> unsigned long long {
      const std::string v = value();
      char* end = nullptr;
      const unsigned long long n = std::strtoull(v.c_str(), &end, 10);
      if (v.empty() || *end) {
        std::fprintf(stderr, "error: %s takes a whole number, got '%s'\n", arg.c_str(), v.c_str());
        std::exit(2);
      }
      return n;
    };
    auto positive = [&]() -> unsigned long long {
      const unsigned long long n = number();
      if (n == 0) {
        std::fprintf(stderr, "error: %s must be at least 1\n", arg.c_str());
        std::exit(2);
      }
      return n;
    };
    auto mebibytes = [&]() -> size_t {
      const unsigned long long n = positive();
      if (n > (1ull << 24)) {
        std::fprintf(stderr, "error: %s takes 1..16777216 MiB\n", arg.c_str());
        std::exit(2);
      }
      return static_cast<size_t>(n) << 20;
    };
    if (arg == "--address") options.address = value();
    else if (arg == "--tls-cert") options.access.tls_cert = value();
    else if (arg == "--tls-key") options.access.tls_key = value();
    else if (arg == "--tls-client-ca") options.access.tls_client_ca = value();
    else if (arg == "--tokens") options.access.tokens_file = value();
    else if (arg == "--allow-plaintext-remote") options.access.allow_plaintext_remote = true;
    else if (arg == "--trusted-proxy") {
      if (const std::string error = options.access.trusted_proxies.Add(value()); !error.empty()) {
        std::fprintf(stderr, "error: %s\n", error.c_str());
        return 2;
      }
    }
    else if (arg == "--platform") options.runtime.platform = value();
    else if (arg == "--device") options.runtime.device = value();
    else if (arg == "--cache-dir") options.runtime.cache_dir = value();
    else if (arg == "--vector-width") options.runtime.vector_width = static_cast<int>(number());
    else if (arg == "--small-launch-queries") options.runtime.small_launch_queries = static_cast<size_t>(number());
    else if (arg == "--max-batch-queries") options.batcher.max_batch_queries = number();
    else if (arg == "--max-queue-delay-us")
      options.batcher.interactive.max_queue_delay = options.batcher.bulk.max_queue_delay =
          std::chrono::microseconds(number());
    else if (arg == "--max-queued-queries")
      options.batcher.interactive.max_queued_queries = options.batcher.bulk.max_queued_queries = number();
    else if (arg == "--queue-policy") {
      if (std::string error = ParseQueuePolicy(value(), &options.batcher); !error.empty()) {
        std::fprintf(stderr, "error: --queue-policy: %s\n", error.c_str());
        return 2;
      }
    }
    else if (arg == "--no-batching") options.batcher.coalesce = false;
    else if (arg == "--metrics-address") options.metrics_address = value();
    else if (arg == "--environment-dir") options.environment_dir = value();
    else if (arg == "--data-dir") options.data_dir = value();
    else if (arg == "--btf-store-mb") options.btf_store_bytes = mebibytes();
    else if (arg == "--btf-client-quota-mb") options.btf_client_quota_bytes = std::min(number(), 1ULL << 24) << 20;
    else if (arg == "--btf-sync-seconds") options.btf_sync_period = std::chrono::seconds(std::min(number(), 86400ULL));
    else if (arg == "--memory-budget-mb") options.limits.memory_budget_bytes = mebibytes();
    else if (arg == "--max-long-calls") options.limits.max_long_running_calls = positive();
    else if (arg == "--max-long-calls-per-client") options.limits.max_long_calls_per_client = positive();
    else if (arg == "--max-memory-per-client-mb") options.memory_per_client_bytes = mebibytes();
    else if (arg == "--max-streams-per-connection")
      options.max_streams_per_connection = static_cast<int>(std::min(positive(), 1ULL << 20));
    else if (arg == "--keepalive-seconds")
      options.keepalive_time = std::chrono::seconds(std::min(positive(), 86400ULL));
    else if (arg == "--keepalive-timeout-seconds")
      options.keepalive_timeout = std::chrono::seconds(std::min(positive(), 86400ULL));
    else if (arg == "--max-connection-age-seconds")
      options.max_connection_age = std::chrono::seconds(std::min(positive(), 31536000ULL));
    else if (arg == "--max-connection-age-grace-seconds")
      options.max_connection_age_grace = std::chrono::seconds(std::min(positive(), 31536000ULL));
    else if (arg == "--max-health-watches") options.max_health_watches = positive();
    else if (arg == "--max-health-watches-per-client") options.max_health_watches_per_client = positive();
    else if (arg == "--material-cache-mb") options.limits.material_cache_bytes = mebibytes();
    else if (arg == "--fold-cache-mb") options.limits.fold_cache_bytes = mebibytes();
    else if (arg == "--fiber-cache-mb") options.limits.fiber_cache_bytes = mebibytes();
    else if (arg == "--upload-idle-seconds") options.limits.upload_idle_timeout = std::chrono::seconds(positive());
    else if (arg == "--max-upload-seconds") options.limits.upload_max_duration = std::chrono::seconds(positive());
    else if (arg == "--environment-cache-mb") options.environment_cache_bytes = mebibytes();
    else if (arg == "--grpc-memory-mb") options.grpc_memory_bytes = mebibytes();
    else if (arg == "--stall-seconds") options.stall_limit = std::chrono::seconds(positive());
    else if (arg == "--max-call-seconds") {
      // "N" caps both priorities, "interactive:N" or "bulk:N" one.
      const std::string v = value();
      const size_t colon = v.find(':');
      const std::string priority = colon == std::string::npos ? "" : v.substr(0, colon);
      const std::string n = v.substr(colon == std::string::npos ? 0 : colon + 1);
      char* end = nullptr;
      const unsigned long long seconds = std::strtoull(n.c_str(), &end, 10);
      if ((colon != std::string::npos && priority != "interactive" && priority != "bulk") || n.empty() || *end ||
          seconds == 0) {
        std::fprintf(stderr, "error: --max-call-seconds takes N, interactive:N or bulk:N (N >= 1), got '%.80s'\n",
                     v.c_str());
        return 2;
      }
      const std::chrono::milliseconds cap = std::chrono::seconds(std::min(seconds, 31536000ULL));  // a year at most
      if (priority != "bulk") options.call_caps.interactive = cap;
      if (priority != "interactive") options.call_caps.bulk = cap;
    }
    else if (arg == "--stall-write-seconds") options.stall_write_timeout = std::chrono::seconds(positive());
    else if (arg == "--shutdown-grace") options.shutdown_grace = std::chrono::seconds(number());
    else if (arg == "--help" || arg == "-h") { Usage(); return 0; }
    else { std::fprintf(stderr, "error: unknown option '%s'\n", arg.c_str()); Usage(); return 2; }
    if (attached && !attached_taken) {
      std::fprintf(stderr, "error: %s takes no value\n", arg.c_str());
      return 2;
    }
  }
  // Freed call buffers stay with the process, up to the budget calls may hold (server/runtime/allocator.h).
  if (!loomlight::runtime::KeepFreedMemory(options.limits.memory_budget_bytes))
    std::fprintf(stderr, "loomlight-server: warning: the allocator refused its thresholds; calls may page-fault more\n");
  std::string error;
  auto server = loomlight::api::LoomlightServer::Start(options, &error);
  if (!server) {
    std::fprintf(stderr, "loomlight-server: %s\n", error.c_str());
    return 1;
  }
  // Tests and scripts wait for "serving on port N".
  std::fprintf(stderr, "loomlight-server: serving on port %d (%s; OpenCL: %s / %s, float vector width %d, fp64 %s)\n",
               server->port(),
               options.access.tls_cert.empty() ? "plaintext" : (options.access.tokens_file.empty() ? "TLS" : "TLS with tokens"), server->runtime().platform_name().c_str(), server->runtime().device_name().c_str(),
               server->runtime().vector_width(), server->runtime().has_fp64() ? "yes" : "no");
  if (server->metrics_port() > 0)
    std::fprintf(stderr, "loomlight-server: metrics on port %d (/metrics)\n", server->metrics_port());
  std::signal(SIGINT, [](int) { g_stop = 1; });
  std::signal(SIGTERM, [](int) { g_stop = 1; });
  std::signal(SIGHUP, [](int) { g_reload = 1; });
  while (!g_stop) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (g_reload) {
      g_reload = 0;
      if (!options.access.tokens_file.empty()) {
        // A file that fails to load fails closed (LoomlightServer::ReloadTokens).
        const std::string reload_error = server->ReloadTokens();
        std::fprintf(stderr, "loomlight-server: SIGHUP: %s\n",
                     reload_error.empty()
                         ? "tokens reloaded"
                         : ("NOT_SERVING, every token refused until the file loads: " + reload_error).c_str());
      }
      server->SyncBtfAssets();
    }
  }
  std::fprintf(stderr, "loomlight-server: shutting down (in-flight calls get %lld s)\n",
               static_cast<long long>(options.shutdown_grace.count() / 1000));
  server->Shutdown();
  return 0;
}
