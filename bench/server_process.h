// The real loomlight-server binary as a child process of the benchmark, so that its CPU time can be read
// apart from the client's (section 3b).
#pragma once

#include <grpcpp/security/credentials.h>
#include <sys/types.h>

#include <memory>
#include <string>
#include <vector>

namespace loomlight::bench {

class ChildServer {
 public:
  // Starts LOOMLIGHT_SERVER_BINARY --address 127.0.0.1:0 plus `extra_args` and waits until it prints its port
  // and its health Check, over `credentials` (null: plaintext), answers SERVING; exits the benchmark when it
  // cannot. `cpu` >= 0 pins the process (every thread it will start) to that CPU.
  explicit ChildServer(const std::vector<std::string>& extra_args = {},
                       std::shared_ptr<grpc::ChannelCredentials> credentials = nullptr, int cpu = -1);
  ~ChildServer();  // SIGTERM, then SIGKILL after 10 s; reaped, so its CPU shows in RUSAGE_CHILDREN
  ChildServer(const ChildServer&) = delete;
  ChildServer& operator=(const ChildServer&) = delete;

  int port() const { return port_; }
  pid_t pid() const { return pid_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

  // CPU time of the whole process (every thread, living or exited, user + system), in seconds: the kernel's
  // process CPU clock (ns resolution) when it can be read, else utime + stime from /proc/<pid>/stat (ticks).
  double CpuSeconds() const;
  // Which of the two CpuSeconds reads, for the report.
  std::string CpuClockName() const;

 private:
  pid_t pid_ = -1;
  int port_ = 0;
};

}  // namespace loomlight::bench
