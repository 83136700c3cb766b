// Test helpers shared by the Loomlight tests: random directions, error statistics, the OpenCL runtime and
// a real server process on a loopback port.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/models/accuracy.h"
#include "server/models/registry.h"
#include "server/runtime/cl_runtime.h"

namespace loomlight::testing {

// One runtime (device chosen, programs built, warmed) per test process.
runtime::ClRuntime& SharedRuntime();

// Runs a packed material through a kernel in one launch.
// uv (pairs) empty: f(wi, wo); else the model's spatially varying kernel.
std::vector<double> RunKernel(const models::Model& model, const models::PackedMaterial& m, bool fp64,
                              const std::vector<float>& wi, const std::vector<float>& wo,
                              const std::vector<float>& uv = {});
// One launch on the shared runtime (materials mixed as the batcher mixes them); f in double, 3 per query.
std::vector<double> RunLaunch(const runtime::LaunchArgs& args);

// A stub for a Loomlight server, with the API's message size limits both ways (large requests and replies).
std::unique_ptr<v1::Loomlight::Stub> Connect(const std::string& address);
std::unique_ptr<v1::Loomlight::Stub> Connect(int port);  // 127.0.0.1:port
// A channel to `address` with those limits and a connection of its own (a local subchannel pool), as a
// separate client process would have.
std::shared_ptr<grpc::Channel> OwnChannel(const std::string& address);

// Runs the `loomlight` client binary against `address` with `args`; returns its exit code, with its stdout
// and stderr in *output.
int RunClient(const std::string& address, const std::string& args, std::string* output);
int RunClient(int port, const std::string& args, std::string* output);  // 127.0.0.1:port
// A loopback port nobody listens on: bound, noted and closed (nothing else binds ephemeral loopback ports here);
// 0 (with a test failure) when none could be bound.
int ClosedLoopbackPort();

// GET http://127.0.0.1:port/path (e.g. the metrics endpoint) with extra header lines ("Name: value\r\n" each);
// the body, or "" on failure.
std::string HttpGet(int port, const std::string& path, const std::string& headers = "");

// A metric's value in Prometheus' text format, `name` with its labels as printed ("x_total{code=\"OK\"}"); NAN
// when absent.
double MetricValue(const std::string& text, const std::string& name);

// Waits until the server whose metrics listen on `metrics_port` has ended `count` calls of `rpc` with `code`
// (loomlight_calls_total, counted once a call's work is all back): what a test waits for before it reads what the
// call did, instead of sleeping a time a slow machine may overrun. The wait's 60 s guard is against a hang, not a
// bound; false when it passes.
bool WaitForCallsEnded(int metrics_port, const std::string& rpc, const std::string& code, double count);
double CallsEnded(int metrics_port, const std::string& rpc, const std::string& code);  // 0 when none yet

// An image decoded with OpenImageIO: channels as float, whatever the file's type (8-bit PNG: 0..1).
struct DecodedImage {
  int width = 0, height = 0, channels = 0;
  std::vector<float> pixels;
};
// Decodes PNG, JPEG or EXR bytes in memory; `name` (e.g. "x.png") picks the reader. Failures are test failures.
DecodedImage DecodeImage(const std::string& bytes, const char* name);

// A Radiance HDR header declaring `width` x `height` pixels and no pixel data: a few dozen bytes that would decode
// to width x height x 12 bytes.
std::string HdrBomb(int width, int height);

// A velvet table of 33.5 M cells (400 MB of RAW output): seconds of work, for streams held unread or cut short.
v1::TabulateRequest BigTable();

// A server in this process on 127.0.0.1 with a free port (options.address is replaced); a test failure and
// nullptr when it cannot start.
std::unique_ptr<api::LoomlightServer> StartInProcessServer(api::ServerOptions options = {});

// The loomlight-server binary started on 127.0.0.1 with a free port; killed on destruction.
class ServerProcess {
 public:
  explicit ServerProcess(std::vector<std::string> extra_args = {});
  ~ServerProcess();
  int port() const { return port_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  bool running() const;
  pid_t pid() const { return pid_; }
  // The server's resident memory now (VmRSS), in bytes; 0 when it cannot be read.
  size_t RssBytes() const;
  // Sends SIGTERM, then waits up to `timeout` for the process to exit: its exit code, or -1 (still running,
  // or killed by a signal).
  int Terminate(std::chrono::milliseconds timeout);

 private:
  pid_t pid_ = -1;
  int port_ = 0;
};

}  // namespace loomlight::testing
