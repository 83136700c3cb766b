#include "tests/testing.h"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <thread>
#include <cmath>
#include <cstdio>
#include <sstream>

namespace loomlight::testing {

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

ServerProcess::~ServerProcess() {
  if (pid_ > 0) {
    kill(pid_, SIGTERM);
    int status = 0;
    waitpid(pid_, &status, 0);
  }
}

}  // namespace loomlight::testing
