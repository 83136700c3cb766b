// loomlight-server: serves the Loomlight API on PoCL's CPU device (or any OpenCL device).
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <algorithm>
#include <cctype>
#include <cstring>
#include <functional>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "client/cli11_rules.h"
#include "server/api/server.h"
#include "server/runtime/allocator.h"

namespace {

constexpr std::size_t kHelpColumnWidth = 36;
constexpr unsigned long long kMaxMebibytes = 1ULL << 24;
constexpr unsigned long long kDaySeconds = 86400, kYearSeconds = 31536000;

// The checks of a number option, in the words the server always used (CLI11 prefixes the option's name). Digits
// only: strtoull took "-1" as 2^64 - 1.
const CLI::Validator kWholeNumber(
    [](std::string& text) {
      const bool digits = !text.empty() && text.size() <= 19 &&
                          std::all_of(text.begin(), text.end(), [](unsigned char c) { return std::isdigit(c); });
      return digits ? std::string() : "takes a whole number, got '" + text.substr(0, 80) + "'";
    },
    "");
const CLI::Validator kAtLeastOne([](std::string& text) { return std::stoull(text) == 0 ? "must be at least 1" : ""; },
                                 "");
const CLI::Validator kMebibytes(
    [](std::string& text) { return std::stoull(text) > kMaxMebibytes ? "takes 1..16777216 MiB" : ""; }, "");

using Number = unsigned long long;

// A whole-number option ("--name N"); `set` takes the number once every check passed.
CLI::Option* AddNumber(CLI::App& app, const std::string& name, const std::string& help,
                       std::function<void(Number)> set) {
  return app.add_option_function<Number>(name, std::move(set), help)->type_name("N")->check(kWholeNumber);
}
// At least 1.
CLI::Option* AddPositive(CLI::App& app, const std::string& name, const std::string& help,
                         std::function<void(Number)> set) {
  return AddNumber(app, name, help, std::move(set))->check(kAtLeastOne);
}
// 1..16777216 MiB into bytes.
CLI::Option* AddMebibytes(CLI::App& app, const std::string& name, const std::string& help, size_t* bytes) {
  return AddPositive(app, name, help, [bytes](Number n) { *bytes = static_cast<size_t>(n) << 20; })->check(kMebibytes);
}
// At least 1 s, at most `max_seconds` (a larger number is that bound).
template <typename Duration>
CLI::Option* AddSeconds(CLI::App& app, const std::string& name, const std::string& help, Duration* duration,
                        Number max_seconds) {
  return AddPositive(app, name, help,
                     [duration, max_seconds](Number n) { *duration = std::chrono::seconds(std::min(n, max_seconds)); });
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

// "N" caps both priorities' calls, "interactive:N" or "bulk:N" one; "" or what is wrong.
std::string ParseCallCap(const std::string& text, loomlight::api::ServerOptions* options) {
  const size_t colon = text.find(':');
  const std::string priority = colon == std::string::npos ? "" : text.substr(0, colon);
  const std::string n = text.substr(colon == std::string::npos ? 0 : colon + 1);
  char* end = nullptr;
  const unsigned long long seconds = std::strtoull(n.c_str(), &end, 10);
  if ((colon != std::string::npos && priority != "interactive" && priority != "bulk") || n.empty() || *end ||
      !std::isdigit(static_cast<unsigned char>(n[0])) || seconds == 0)
    return "--max-call-seconds takes N, interactive:N or bulk:N (N >= 1), got '" + text.substr(0, 80) + "'";
  const std::chrono::milliseconds cap = std::chrono::seconds(std::min(seconds, kYearSeconds));
  if (priority != "bulk") options->call_caps.interactive = cap;
  if (priority != "interactive") options->call_caps.bulk = cap;
  return "";
}

// Each value of a repeatable option, in command-line order, through `apply` ("" or what is wrong).
CLI::Option* AddRepeatable(CLI::App& app, const std::string& name, const std::string& value_name,
                           const std::string& help, std::function<std::string(const std::string&)> apply) {
  return app
      .add_option_function<std::vector<std::string>>(
          name,
          [apply = std::move(apply)](const std::vector<std::string>& values) {
            for (const std::string& value : values)
              if (const std::string error = apply(value); !error.empty()) throw CLI::ValidationError(error);
          },
          help)
      ->type_name(value_name)
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
}

volatile std::sig_atomic_t g_stop = 0;
volatile std::sig_atomic_t g_reload = 0;

// Declares every option of `options` on `app`: each sets its field once CLI11 has checked it.
void AddOptions(CLI::App& app, loomlight::api::ServerOptions& options) {
  using std::chrono::seconds;
  auto& access = options.access;
  auto& limits = options.limits;
  auto& batcher = options.batcher;
  app.add_option("--address", options.address, "listen address (default 127.0.0.1:50051)")->type_name("HOST:PORT");
  app.add_option("--tls-cert", access.tls_cert, "serve TLS with this PEM certificate chain (and --tls-key)")
      ->type_name("FILE");
  app.add_option("--tls-key", access.tls_key, "the certificate's PEM private key")->type_name("FILE");
  app.add_option("--tls-client-ca", access.tls_client_ca,
                 "mutual TLS: clients must present a certificate this CA signed")
      ->type_name("FILE");
  app.add_option("--tokens", access.tokens_file,
                 "every call but health needs a bearer token listed in FILE\n"
                 "(lines 'TOKEN CLIENT CALLS'; reloaded on SIGHUP; needs TLS)")
      ->type_name("FILE");
  app.add_flag("--allow-plaintext-remote", access.allow_plaintext_remote,
               "allow plaintext on an address other than loopback")
      ->check(loomlight::cli::NoValue());
  AddRepeatable(app, "--trusted-proxy", "ADDR[/BITS]",
                "believe X-Forwarded-For from this proxy (repeatable): fair share and\n"
                "per-client limits then count the client it forwards, not the proxy",
                [&access](const std::string& block) { return access.trusted_proxies.Add(block); });
  app.add_option("--platform", options.runtime.platform,
                 "OpenCL platform substring (env LOOMLIGHT_PLATFORM; default PoCL)")
      ->type_name("NAME");
  app.add_option("--device", options.runtime.device,
                 "OpenCL device substring (env LOOMLIGHT_DEVICE; default first CPU)")
      ->type_name("NAME");
  app.add_option("--cache-dir", options.runtime.cache_dir,
                 "PoCL kernel cache (POCL_CACHE_DIR; default ~/.cache/loomlight/pocl)")
      ->type_name("DIR");
  AddNumber(app, "--vector-width", "queries per work-item in float kernels: 1, 2, 4, 8, 16 (default: device)",
            [&options](Number n) { options.runtime.vector_width = static_cast<int>(std::min<Number>(n, 1024)); });
  AddNumber(app, "--small-launch-queries",
            "launches of at most N queries run on PoCL's single-threaded basic device,\n"
            "on the launching thread (default 256; 0: every launch on the main device)",
            [&options](Number n) { options.runtime.small_launch_queries = static_cast<size_t>(n); });
  AddNumber(app, "--max-batch-queries", "queries per coalesced launch (default 1048576)",
            [&batcher](Number n) { batcher.max_batch_queries = n; });
  // Declared before --queue-policy: CLI11 applies options in this order, so one priority's policy overrides these.
  AddNumber(app, "--max-queue-delay-us", "wait this long for a batch to fill (default 0; both priorities)",
            [&batcher](Number n) {
              batcher.interactive.max_queue_delay = batcher.bulk.max_queue_delay = std::chrono::microseconds(n);
            });
  AddNumber(app, "--max-queued-queries",
            "queued queries per priority before RESOURCE_EXHAUSTED (default 8388608\n"
            "interactive, 16777216 bulk)",
            [&batcher](Number n) { batcher.interactive.max_queued_queries = batcher.bulk.max_queued_queries = n; });
  AddRepeatable(app, "--queue-policy", "PRIORITY:KEY=VALUE[,KEY=VALUE...]",
                "one priority's queue (interactive: Evaluate, Sample, TextureSlice;\n"
                "bulk: Tabulate, Render); keys: max_queue_delay_us, max_queued_queries,\n"
                "max_client_queued_queries (default 4194304, bulk 8388608), timeout_ms (default 0,\n"
                "none), timeout_action: reject (a job queued longer than timeout_ms\n"
                "fails RESOURCE_EXHAUSTED; the default) or delay (it goes behind every\n"
                "job of its priority that has not timed out); repeatable, one priority each",
                [&batcher](const std::string& text) {
                  const std::string error = ParseQueuePolicy(text, &batcher);
                  return error.empty() ? error : "--queue-policy: " + error;
                });
  app.add_flag_callback("--no-batching", [&batcher] { batcher.coalesce = false; }, "one request per launch")
      ->check(loomlight::cli::NoValue());
  app.add_option("--metrics-address", options.metrics_address,
                 "serve Prometheus metrics at http://HOST:PORT/metrics (default: off)")
      ->type_name("HOST:PORT");
  app.add_option("--environment-dir", options.environment_dir,
                 "environment maps clients may name (EXR/HDR files; default: none)")
      ->type_name("DIR");
  app.add_option("--data-dir", options.data_dir,
                 "BTF assets live under DIR/btf, meshes under DIR/meshes (default\n"
                 "$XDG_STATE_HOME/loomlight, "
                 "else ~/.local/state/loomlight)")
      ->type_name("DIR");
  AddMebibytes(app, "--btf-store-mb", "all BTF assets together, in MiB (default 2048)", &options.btf_store_bytes);
  AddMebibytes(app, "--mesh-store-mb", "all uploaded meshes' files together, in MiB (default 2048)",
               &options.mesh_store_bytes);
  AddMebibytes(app, "--mesh-cache-mb", "parsed meshes kept for renders, in MiB (default 512)",
               &options.mesh_cache_bytes);
  AddNumber(app, "--btf-client-quota-mb", "one client's BTF assets, in MiB (default 1024; 0: the store's bound)",
            [&options](Number n) { options.btf_client_quota_bytes = std::min(n, kMaxMebibytes) << 20; });
  AddNumber(app, "--btf-sync-seconds",
            "look for assets and meshes other replicas sharing --data-dir added, replaced or\n"
            "deleted every N s (default 5; 0: only at start and on SIGHUP)",
            [&options](Number n) { options.btf_sync_period = seconds(std::min(n, kDaySeconds)); });
  AddMebibytes(app, "--memory-budget-mb", "bytes all calls' buffers may hold, in MiB (default 2048)",
               &limits.memory_budget_bytes);
  AddPositive(app, "--max-long-calls", "TextureSlice, Tabulate and Render calls at once (default 16)",
              [&limits](Number n) { limits.max_long_running_calls = n; });
  AddPositive(app, "--max-long-calls-per-client",
              "of them, one client's (its token's name, else the address a\n"
              "--trusted-proxy forwarded, else its address; default 8)",
              [&limits](Number n) { limits.max_long_calls_per_client = n; });
  AddMebibytes(app, "--max-memory-per-client-mb",
               "of the memory budget, one client's calls together, in MiB\n"
               "(default: half of --memory-budget-mb)",
               &options.memory_per_client_bytes);
  AddPositive(app, "--max-streams-per-connection", "calls open at once on one connection (default 100)",
              [&options](Number n) { options.max_streams_per_connection = static_cast<int>(std::min(n, 1ULL << 20)); });
  AddSeconds(app, "--keepalive-seconds", "ping a connection after N s without traffic (default 60)",
             &options.keepalive_time, kDaySeconds);
  AddSeconds(app, "--keepalive-timeout-seconds", "close a pinged connection whose answer takes N s (default 20)",
             &options.keepalive_timeout, kDaySeconds);
  AddSeconds(app, "--max-connection-age-seconds", "a connection is told to reconnect after N s (default 3600)",
             &options.max_connection_age, kYearSeconds);
  AddSeconds(app, "--max-connection-age-grace-seconds",
             "an aged connection's calls may finish within N s (default: the bulk\n"
             "--max-call-seconds)",
             &options.max_connection_age_grace, kYearSeconds);
  AddPositive(app, "--max-health-watches", "health Watch streams open at once (default 256)",
              [&options](Number n) { options.max_health_watches = n; });
  AddPositive(app, "--max-health-watches-per-client", "of them, one client's (default 8)",
              [&options](Number n) { options.max_health_watches_per_client = n; });
  AddMebibytes(app, "--material-cache-mb", "packed materials kept, with their sampling tables and tabulated BRDFs, in MiB (default 256)", &limits.material_cache_bytes);
  AddMebibytes(app, "--fold-cache-mb", "BTF environment folds kept across renders, in MiB (default 128)",
               &limits.fold_cache_bytes);
  AddMebibytes(app, "--fiber-cache-mb",
               "fiber scenes (fibers' BVH, tubes, openness) kept across calls, in MiB\n"
               "(default 256)",
               &limits.fiber_cache_bytes);
  AddPositive(app, "--upload-idle-seconds", "an upload (UploadBtf, UploadMesh) that sends nothing for N s is\n"
              "cancelled (default 60)",
              [&limits](Number n) { limits.upload_idle_timeout = seconds(n); });
  AddPositive(app, "--max-upload-seconds",
              "an upload still sending N s after it started is cancelled\n"
              "(default 1800)",
              [&limits](Number n) { limits.upload_max_duration = seconds(n); });
  AddMebibytes(app, "--environment-cache-mb", "decoded environment maps kept, in MiB (default 256)",
               &options.environment_cache_bytes);
  AddMebibytes(app, "--grpc-memory-mb", "gRPC's own buffers, in MiB (default 512)", &options.grpc_memory_bytes);
  AddPositive(app, "--stall-seconds", "health NOT_SERVING while one task runs longer (default 20)",
              [&options](Number n) { options.stall_limit = seconds(n); });
  AddRepeatable(app, "--max-call-seconds", "[PRIORITY:]N",
                "a call's deadline is its client's, at most N s (both priorities,\n"
                "or interactive: Evaluate, Sample, TextureSlice; bulk: Tabulate, Render,\n"
                "YarnGeometry, CreateBtf; repeatable; default interactive 120, bulk 3600)",
                [&options](const std::string& text) { return ParseCallCap(text, &options); });
  AddPositive(app, "--stall-write-seconds", "a stream whose client reads nothing for N s is cancelled (default 60)",
              [&options](Number n) { options.stall_write_timeout = seconds(n); });
  AddNumber(app, "--shutdown-grace", "on SIGTERM, in-flight calls may finish this long (default 30)",
            [&options](Number n) { options.shutdown_grace = seconds(std::min(n, kYearSeconds)); })
      ->type_name("SECONDS");
}

}  // namespace

int main(int argc, char** argv) {
  loomlight::api::ServerOptions options;
  options.data_dir = loomlight::assets::BtfStore::DefaultDataDir();
  CLI::App app("Serves the Loomlight API on PoCL's CPU device (or any OpenCL device).", "loomlight-server");
  loomlight::cli::Configure(app, kHelpColumnWidth);
  AddOptions(app, options);
  loomlight::cli::AddHelpFlag(app, "Options");
  // "--name=value" is "--name value" (the form manifests and service files often use); an unknown option or a bad
  // value is refused before --help is looked at, so `loomlight-server ARGS --help` checks ARGS.
  std::string usage_error;
  try {
    app.parse(argc, argv);
    const std::vector<std::string> extras = app.remaining();
    if (const auto unknown = loomlight::cli::UnknownOption(extras)) usage_error = *unknown;
    else if (!extras.empty()) usage_error = "unexpected argument '" + extras.front().substr(0, 80) + "'";
  } catch (const CLI::ParseError& e) {
    usage_error = e.what();
  }
  if (!usage_error.empty()) {
    std::fprintf(stderr, "error: %s\nRun 'loomlight-server --help' for the options.\n", usage_error.c_str());
    return 2;
  }
  if (app.get_option("--help")->count() > 0) {
    std::cout << app.help();
    return 0;
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
