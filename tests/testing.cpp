#include "tests/testing.h"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/socket.h>
#include <netinet/in.h>
#include <arpa/inet.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <thread>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "server/api/service.h"
// OpenImageIO after protobuf/gRPC: its headers define a bswap macro that breaks theirs.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace loomlight::testing {
namespace {

// Each test process writes under a temporary directory of its own, removed when it exits: gtest's TempDir() reads
// TEST_TMPDIR, so a test's "lobe.png" or "environment_test.exr" cannot meet the same name written by a test beside
// it (`ctest -j`) or by another checkout's run; and the servers it starts keep their default data directory
// (XDG_STATE_HOME/loomlight) there, not in the user's home. Before main, so before any test asks.
// (loomlight_testing is an object library: this is linked into every test, whether or not it calls anything else.)
class PrivateTempDir {
 public:
  PrivateTempDir() {
    const char* base = std::getenv("TEST_TMPDIR");
    std::string path = std::string(base && *base ? base : "/tmp") + "/loomlight-test-XXXXXX";
    if (!mkdtemp(path.data())) return;  // then TempDir() stays the shared one
    path_ = path;
    setenv("TEST_TMPDIR", path_.c_str(), 1);
    setenv("XDG_STATE_HOME", (path_ + "/state").c_str(), 1);
  }
  ~PrivateTempDir() {
    std::error_code ec;
    if (!path_.empty() && getpid() == owner_) std::filesystem::remove_all(path_, ec);  // not in a forked child
  }

 private:
  std::string path_;
  const pid_t owner_ = getpid();
};
const PrivateTempDir private_temp_dir;

}  // namespace

runtime::ClRuntime& SharedRuntime() {
  static std::unique_ptr<runtime::ClRuntime> rt = [] {
    std::string error;
    auto r = runtime::ClRuntime::Create({}, &error);
    if (!r || !r->BuildPrograms(models::Registry::Global(), &error) ||
        !r->Warm(models::Registry::Global(), &error)) {
      std::fprintf(stderr, "OpenCL runtime: %s\n", error.c_str());
      std::abort();
    }
    return r;
  }();
  return *rt;
}

std::vector<double> RunLaunch(const runtime::LaunchArgs& args) {
  runtime::LaunchResults results;
  std::string error;
  std::vector<double> f(3 * args.n, 0.0);
  EXPECT_TRUE(SharedRuntime().Run(args, &results, &error)) << error;
  if (error.empty()) results.Write(0, args.n, runtime::ResultSink{.f64 = f.data()}, 0);
  return f;
}

std::vector<double> RunKernel(const models::Model& model, const models::PackedMaterial& m, bool fp64,
                              const std::vector<float>& wi, const std::vector<float>& wo,
                              const std::vector<float>& uv) {
  std::vector<double> f;
  std::string error;
  EXPECT_TRUE(SharedRuntime().RunSingle(model, m, fp64, wi.data(), wo.data(), uv.empty() ? nullptr : uv.data(),
                                        wi.size() / 3, &f, &error))
      << error;
  return f;
}

// The API's message size limits, both ways.
static grpc::ChannelArguments MessageLimits() {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(api::kMaxMessageBytes);
  args.SetMaxSendMessageSize(api::kMaxMessageBytes);
  return args;
}

std::unique_ptr<v1::Loomlight::Stub> Connect(const std::string& address) {
  return v1::Loomlight::NewStub(grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), MessageLimits()));
}

std::unique_ptr<v1::Loomlight::Stub> Connect(int port) { return Connect("127.0.0.1:" + std::to_string(port)); }

std::shared_ptr<grpc::Channel> OwnChannel(const std::string& address) {
  grpc::ChannelArguments args = MessageLimits();
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  return grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
}

int RunClient(const std::string& address, const std::string& args, std::string* output) {
  const std::string command = std::string(LOOMLIGHT_CLIENT_BINARY) + " --server " + address + " " + args + " 2>&1";
  FILE* pipe = popen(command.c_str(), "r");
  output->clear();
  char buffer[4096];
  while (pipe && std::fgets(buffer, sizeof buffer, pipe)) *output += buffer;
  const int status = pipe ? pclose(pipe) : -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

int RunClient(int port, const std::string& args, std::string* output) {
  return RunClient("127.0.0.1:" + std::to_string(port), args, output);
}

int ClosedLoopbackPort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) {
    ADD_FAILURE() << "socket: " << std::strerror(errno);
    return 0;
  }
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t length = sizeof addr;
  const bool bound = bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 &&
                     getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &length) == 0;
  if (!bound) ADD_FAILURE() << "bind: " << std::strerror(errno);
  close(fd);
  return bound ? ntohs(addr.sin_port) : 0;
}

DecodedImage DecodeImage(const std::string& bytes, const char* name) {
  DecodedImage d;
  OIIO::Filesystem::IOMemReader reader(bytes.data(), bytes.size());
  auto in = OIIO::ImageInput::open(name, nullptr, &reader);
  EXPECT_TRUE(in) << OIIO::geterror();
  if (!in) return d;
  d.width = in->spec().width;
  d.height = in->spec().height;
  d.channels = in->spec().nchannels;
  d.pixels.resize(size_t(d.width) * d.height * d.channels);
  EXPECT_TRUE(in->read_image(0, 0, 0, d.channels, OIIO::TypeDesc::FLOAT, d.pixels.data())) << in->geterror();
  return d;
}

// GET http://127.0.0.1:port/path; the body, or "" on failure.
std::string HttpGet(int port, const std::string& path, const std::string& headers) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  std::string response;
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0) {
    const std::string request = "GET " + path + " HTTP/1.0\r\nHost: 127.0.0.1\r\n" + headers + "\r\n";
    if (write(fd, request.data(), request.size()) == static_cast<ssize_t>(request.size())) {
      char buf[4096];
      for (ssize_t got; (got = read(fd, buf, sizeof buf)) > 0;) response.append(buf, static_cast<size_t>(got));
    }
  }
  close(fd);
  const size_t body = response.find("\r\n\r\n");
  return body == std::string::npos ? "" : response.substr(body + 4);
}

double MetricValue(const std::string& text, const std::string& name) {
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? NAN : std::stod(text.substr(at + name.size() + 2));
}

double CallsEnded(int metrics_port, const std::string& rpc, const std::string& code) {
  const double n = MetricValue(HttpGet(metrics_port, "/metrics"),
                               "loomlight_calls_total{code=\"" + code + "\",rpc=\"" + rpc + "\"}");
  return std::isnan(n) ? 0 : n;
}

bool WaitForCallsEnded(int metrics_port, const std::string& rpc, const std::string& code, double count) {
  const auto guard = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (CallsEnded(metrics_port, rpc, code) < count) {
    if (std::chrono::steady_clock::now() > guard) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

std::string HdrBomb(int width, int height) {
  return "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y " + std::to_string(height) + " +X " + std::to_string(width) + "\n";
}

v1::TabulateRequest BigTable() {
  v1::TabulateRequest r;
  r.mutable_material()->set_preset("velvet");
  v1::AnisotropicGrid* g = r.mutable_anisotropic();
  g->set_theta_i_count(64);
  g->set_phi_i_count(64);
  g->set_theta_o_count(64);
  g->set_phi_o_count(128);
  r.set_format(v1::TABLE_FORMAT_RAW);
  return r;
}

std::unique_ptr<api::LoomlightServer> StartInProcessServer(api::ServerOptions options) {
  options.address = "127.0.0.1:0";
  std::string error;
  auto server = api::LoomlightServer::Start(options, &error);
  EXPECT_NE(server, nullptr) << error;
  return server;
}

ServerProcess::ServerProcess(std::vector<std::string> extra_args) {
  int fds[2];
  if (pipe(fds) != 0) return;
  pid_ = fork();
  if (pid_ == 0) {
    dup2(fds[1], STDERR_FILENO);
    close(fds[0]);
    close(fds[1]);
    std::vector<std::string> args = {LOOMLIGHT_SERVER_BINARY, "--address", "127.0.0.1:0"};
    args.insert(args.end(), extra_args.begin(), extra_args.end());
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(fds[1]);
  // The server prints "serving on port N" once its kernels are built and warm and health is SERVING.
  FILE* err = fdopen(fds[0], "r");
  char line[4096];
  while (err && std::fgets(line, sizeof line, err)) {
    if (const char* p = std::strstr(line, "serving on port ")) {
      port_ = std::atoi(p + std::strlen("serving on port "));
      break;
    }
    std::fputs(line, stderr);
  }
  // Keep draining the pipe so the server never blocks on a full stderr.
  if (err) std::thread([err] {
      char buf[4096];
      while (std::fgets(buf, sizeof buf, err)) {}
      std::fclose(err);
    }).detach();
}

bool ServerProcess::running() const {
  if (pid_ <= 0) return false;
  int status = 0;
  return waitpid(pid_, &status, WNOHANG) == 0;
}

size_t ServerProcess::RssBytes() const {
  std::ifstream status("/proc/" + std::to_string(pid_) + "/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stoull(line.substr(6)) * 1024;  // "VmRSS:  1234 kB"
  return 0;
}

int ServerProcess::Terminate(std::chrono::milliseconds timeout) {
  if (pid_ <= 0) return -1;
  kill(pid_, SIGTERM);
  const auto until = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < until) {
    int status = 0;
    if (waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return -1;
}

ServerProcess::~ServerProcess() {
  if (pid_ > 0) {
    kill(pid_, SIGTERM);
    int status = 0;
    waitpid(pid_, &status, 0);
  }
}

}  // namespace loomlight::testing
