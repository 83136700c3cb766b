#include "bench/server_process.h"

#include <grpcpp/grpcpp.h>
#include <sched.h>
#include <signal.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <sstream>
#include <thread>

#include "bench/bench.h"
#include "grpc/health/v1/health.grpc.pb.h"

namespace loomlight::bench {

namespace {

// The environment for the child: ours, with POCL_CACHE_DIR set to the server's default cache when unset (so
// the child never compiles its kernels into a temporary directory).
std::vector<std::string> ChildEnvironment() {
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) env.emplace_back(*e);
  if (!std::getenv("POCL_CACHE_DIR")) {
    const char* home = std::getenv("HOME");
    env.push_back(std::string("POCL_CACHE_DIR=") + (home ? home : "/tmp") + "/.cache/loomlight/pocl");
  }
  return env;
}

bool HealthServing(const std::string& address, const std::shared_ptr<grpc::ChannelCredentials>& credentials) {
  auto stub = grpc::health::v1::Health::NewStub(grpc::CreateChannel(address, credentials));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
  grpc::health::v1::HealthCheckRequest request;
  grpc::health::v1::HealthCheckResponse response;
  return stub->Check(&ctx, request, &response).ok() &&
         response.status() == grpc::health::v1::HealthCheckResponse::SERVING;
}

}  // namespace

ChildServer::ChildServer(const std::vector<std::string>& extra_args,
                         std::shared_ptr<grpc::ChannelCredentials> credentials, int cpu) {
  if (!credentials) credentials = grpc::InsecureChannelCredentials();
  std::vector<std::string> args = {LOOMLIGHT_SERVER_BINARY, "--address", "127.0.0.1:0"};
  args.insert(args.end(), extra_args.begin(), extra_args.end());
  std::vector<std::string> env = ChildEnvironment();
  // Everything the child needs is prepared before fork: between fork and exec only async-signal-safe calls.
  std::vector<char*> argv, envp;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  for (auto& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  cpu_set_t cpus;
  CPU_ZERO(&cpus);
  if (cpu >= 0) CPU_SET(cpu, &cpus);

  int fds[2];
  if (pipe(fds) != 0) {
    std::perror("pipe");
    std::exit(1);
  }
  pid_ = fork();
  if (pid_ < 0) {
    std::perror("fork");
    std::exit(1);
  }
  if (pid_ == 0) {
    // stdout too: the benchmark's own stdout carries the report.
    dup2(fds[1], STDOUT_FILENO);
    dup2(fds[1], STDERR_FILENO);
    close(fds[0]);
    close(fds[1]);
    if (cpu >= 0 && sched_setaffinity(0, sizeof cpus, &cpus) != 0) _exit(126);  // inherited across exec
    execve(argv[0], argv.data(), envp.data());
    _exit(127);
  }
  close(fds[1]);
  // The server prints "serving on port N" once its kernels are built and warm; everything before goes to our
  // stderr (errors included), everything after is drained so the server never blocks on a full pipe.
  FILE* out = fdopen(fds[0], "r");
  char line[4096];
  while (out && std::fgets(line, sizeof line, out)) {
    if (const char* p = std::strstr(line, "serving on port ")) {
      port_ = std::atoi(p + std::strlen("serving on port "));
      break;
    }
    std::fputs(line, stderr);
  }
  if (out)
    std::thread([out] {
      char buf[4096];
      while (std::fgets(buf, sizeof buf, out)) {}
      std::fclose(out);
    }).detach();
  if (port_ <= 0) {
    std::fprintf(stderr, "%s did not start\n", LOOMLIGHT_SERVER_BINARY);
    std::exit(1);
  }
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (!HealthServing(address(), credentials)) {
    if (std::chrono::steady_clock::now() > until) {
      std::fprintf(stderr, "%s: health never SERVING on %s\n", LOOMLIGHT_SERVER_BINARY, address().c_str());
      std::exit(1);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

ChildServer::~ChildServer() {
  if (pid_ <= 0) return;
  kill(pid_, SIGTERM);
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  int status = 0;
  while (waitpid(pid_, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > until) {
      kill(pid_, SIGKILL);
      waitpid(pid_, &status, 0);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

double ChildServer::CpuSeconds() const {
  clockid_t clock;
  timespec ts{};
  if (clock_getcpuclockid(pid_, &clock) == 0 && clock_gettime(clock, &ts) == 0)
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
  // /proc/<pid>/stat: "pid (comm) state ..." with utime and stime the 14th and 15th fields; comm may hold spaces.
  std::ifstream in("/proc/" + std::to_string(pid_) + "/stat");
  std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t paren = stat.rfind(')');
  if (paren == std::string::npos) return 0;
  std::istringstream fields(stat.substr(paren + 2));
  std::string skip;
  for (int i = 3; i < 14; ++i) fields >> skip;
  double utime = 0, stime = 0;
  fields >> utime >> stime;
  return (utime + stime) / static_cast<double>(sysconf(_SC_CLK_TCK));
}

std::string ChildServer::CpuClockName() const {
  clockid_t clock;
  timespec ts{};
  return clock_getcpuclockid(pid_, &clock) == 0 && clock_gettime(clock, &ts) == 0
             ? "the kernel's CPU clock of the server process (`clock_getcpuclockid`, ns, all threads)"
             : "utime + stime of `/proc/<pid>/stat` (clock ticks of " +
                   std::to_string(1000 / sysconf(_SC_CLK_TCK)) + " ms, all threads)";
}

}  // namespace loomlight::bench
