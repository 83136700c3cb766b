// The service's single-thread workers serve clients in turn, and health tells stuck from long: HostWorker's
// round robin with one client's tasks blocked, YarnGeometry calls of two clients on the geometry worker end to
// end, and a long task that reports progress (SERVING) against one that does not (NOT_SERVING). Every assertion
// is about order, counts or states; the only times are limits on waiting for a state, for a failure to show.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/server.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using Clock = std::chrono::steady_clock;

// Opened once by the test; tasks wait on it.
class Gate {
 public:
  void Open() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      open_ = true;
    }
    opened_.notify_all();
  }
  void Wait() {
    std::unique_lock<std::mutex> lock(mutex_);
    opened_.wait(lock, [this] { return open_; });
  }

 private:
  std::mutex mutex_;
  std::condition_variable opened_;
  bool open_ = false;
};

// Opens its gates when the test ends however it ends (an ASSERT included), so no worker is left waiting; the
// tasks hold the gates, which outlive them.
struct GatesOpenAtExit {
  std::shared_ptr<Gate> Make() { return gates.emplace_back(std::make_shared<Gate>()); }
  ~GatesOpenAtExit() {
    for (const auto& gate : gates) gate->Open();
  }
  std::vector<std::shared_ptr<Gate>> gates;
};

// Polls until `condition` holds; false if it does not within a minute (only a broken mechanism takes that long).
bool Eventually(const std::function<bool()>& condition) {
  const auto give_up = Clock::now() + std::chrono::seconds(60);
  while (!condition()) {
    if (Clock::now() > give_up) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return true;
}

api::HostWorker& Worker(api::LoomlightServer& server, const std::string& name) {
  for (const auto& [what, worker] : server.service().workers())
    if (what == name) return *worker;
  ADD_FAILURE() << "no worker " << name;
  std::abort();
}

// ---- HostWorker ----

// Client A's first task blocks while A queues nine more and B one: B's runs right after A's first, not after all
// ten (it ran last when every task was one queue).
TEST(HostWorker, AnotherClientsTaskRunsAfterAtMostOneOfABusyClients) {
  constexpr int kB = -1;  // B's task; A's are 0 to 9
  std::vector<int> order;  // written by the worker's thread only, read after it joined
  Gate gate;
  {
    api::HostWorker worker;
    worker.Post(
        [&] {
          gate.Wait();
          order.push_back(0);
        },
        "A");
    EXPECT_TRUE(Eventually([&] { return worker.busy_since() != Clock::time_point::max(); }));
    for (int i = 1; i < 10; ++i) worker.Post([&order, i] { order.push_back(i); }, "A");
    worker.Post([&] { order.push_back(kB); }, "B");
    EXPECT_EQ(worker.queued(), 10u);
    gate.Open();
  }  // the destructor runs every task, then joins
  EXPECT_EQ(order, (std::vector<int>{0, kB, 1, 2, 3, 4, 5, 6, 7, 8, 9}));  // and A's own order kept
}

// Progress moves the running task's last progress on, from the task's helper threads too (ReportingProgress);
// while idle there is none, and a report after the task ended does not make the worker look busy.
TEST(HostWorker, ProgressIsTheRunningTasksOnly) {
  api::HostWorker worker;
  EXPECT_EQ(api::HostWorker::Current(), nullptr);
  worker.Progress();
  EXPECT_EQ(worker.last_progress(), Clock::time_point::max());
  std::promise<std::function<bool()>> late;  // a poll kept past its task's end
  std::promise<void> checked;
  worker.Post([&] {
    EXPECT_EQ(api::HostWorker::Current(), &worker);
    const Clock::time_point start = worker.last_progress();
    EXPECT_EQ(start, worker.busy_since());
    std::function<bool()> poll = api::ReportingProgress([] { return false; });
    std::this_thread::sleep_for(std::chrono::milliseconds(2));  // now() moves on
    std::thread helper([&] { EXPECT_FALSE(poll()); });
    helper.join();
    EXPECT_GT(worker.last_progress(), start);
    EXPECT_EQ(worker.busy_since(), start);
    late.set_value(poll);
    checked.set_value();
  });
  checked.get_future().wait();
  std::function<bool()> poll = late.get_future().get();
  ASSERT_TRUE(Eventually([&] { return worker.busy_since() == Clock::time_point::max(); }));
  poll();
  EXPECT_EQ(worker.last_progress(), Clock::time_point::max());
}

// ---- End to end: YarnGeometry on the geometry worker ----

struct YarnOutcome {
  grpc::Status status;
  uint64_t fibers = 0;
};

YarnOutcome FetchYarn(v1::Loomlight::Stub& stub, const std::string& forwarded_for) {
  v1::YarnGeometryRequest request;
  request.mutable_yarn()->set_preset("cotton1");
  request.mutable_straight()->set_length(0.2);
  request.set_max_control_points(1'000'000);  // what the call reserves: 7 calls well within one client's share
  request.set_max_fibers(10'000);
  grpc::ClientContext context;
  context.AddMetadata("x-forwarded-for", forwarded_for);
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(5));
  auto reader = stub.YarnGeometry(&context, request);
  YarnOutcome out;
  v1::YarnGeometryChunk chunk;
  while (reader->Read(&chunk))
    if (chunk.has_summary()) out.fibers = chunk.summary().fibers();
  out.status = reader->Finish();
  return out;
}

// Six calls of client A queued on the geometry worker, then one of B: B's generation runs after A's first, so
// B's call completes while A's last four still wait (held there by a task in B's turn after B's call). With the
// geometry worker first-come-first-served, B's call waited behind all six (that task ran with six queued).
TEST(WorkerFairness, OneClientsQueuedYarnCallsDoNotHoldAnothersBehindThemAll) {
  api::ServerOptions options;
  ASSERT_EQ(options.access.trusted_proxies.Add("127.0.0.0/8"), "");  // clients named by X-Forwarded-For
  options.limits.max_long_calls_per_client = 8;
  options.limits.max_long_running_calls = 16;
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  api::HostWorker& geometry = Worker(*server, "geometry worker");
  const std::string a = "198.51.100.7", b = "203.0.113.9";
  const std::string b_key = "forwarded:::ffff:" + b;  // FairShareKey of B's calls

  std::vector<std::future<YarnOutcome>> a_calls;  // before the gates: their destructors wait for the calls
  std::future<YarnOutcome> b_call;
  GatesOpenAtExit gates;
  const std::shared_ptr<Gate> first = gates.Make(), second = gates.Make();
  geometry.Post([first] { first->Wait(); }, "test");
  ASSERT_TRUE(Eventually([&] { return geometry.busy_since() != Clock::time_point::max(); }));
  for (int i = 0; i < 6; ++i) a_calls.push_back(std::async(std::launch::async, [&] { return FetchYarn(*stub, a); }));
  ASSERT_TRUE(Eventually([&] { return geometry.queued() == 6; }));
  b_call = std::async(std::launch::async, [&] { return FetchYarn(*stub, b); });
  ASSERT_TRUE(Eventually([&] { return geometry.queued() == 7; }));
  // In B's turn after B's generation: when it runs, the tasks before it have all been taken.
  std::atomic<size_t> queued_behind_second{0};
  std::atomic<bool> second_running{false};
  geometry.Post(
      [&, second] {
        queued_behind_second = geometry.queued();
        second_running = true;
        second->Wait();
      },
      b_key);
  first->Open();

  ASSERT_TRUE(Eventually([&] { return second_running.load(); }));
  EXPECT_EQ(queued_behind_second.load(), 4u);  // A's last four: A's first two generations ran, B's between them
  // B's generation ran before the task holding the worker: its call completes meanwhile.
  const bool b_done = b_call.wait_for(std::chrono::seconds(120)) == std::future_status::ready;
  EXPECT_TRUE(b_done) << "B's call waited behind A's";
  second->Open();
  if (b_done) {
    const YarnOutcome outcome = b_call.get();
    EXPECT_TRUE(outcome.status.ok()) << outcome.status.error_message();
    EXPECT_GT(outcome.fibers, 0u);
  }
  for (auto& call : a_calls) {
    const YarnOutcome outcome = call.get();
    EXPECT_TRUE(outcome.status.ok()) << outcome.status.error_message();
  }
}

// ---- Health: stuck is no progress, not long ----

grpc::health::v1::HealthCheckResponse::ServingStatus Health(int port) {
  auto stub = grpc::health::v1::Health::NewStub(
      grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials()));
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::health::v1::HealthCheckResponse response;
  if (!stub->Check(&context, grpc::health::v1::HealthCheckRequest(), &response).ok())
    return grpc::health::v1::HealthCheckResponse::UNKNOWN;
  return response.status();
}

// With --stall-seconds 1: a task on the geometry worker that reports progress (from a helper thread, as yarn
// generation's threads do) for four limits keeps the server SERVING throughout; a task that stops reporting
// turns it NOT_SERVING (Loomlight RPCs UNAVAILABLE), and SERVING again once it ends.
TEST(WorkerHealth, ALongTaskMakingProgressIsNotStuckASilentOneIs) {
  using grpc::health::v1::HealthCheckResponse;
  api::ServerOptions options;
  options.stall_limit = std::chrono::seconds(1);
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  const int port = server->port();
  api::HostWorker& geometry = Worker(*server, "geometry worker");
  ASSERT_TRUE(Eventually([&] { return Health(port) == HealthCheckResponse::SERVING; }));

  std::atomic<bool> ended{false};
  std::atomic<double> ran_seconds{0};
  geometry.Post([&] {
    const auto start = Clock::now();
    const std::function<bool()> poll = api::ReportingProgress([] { return false; });
    std::thread helper([&] {
      while (Clock::now() - start < 4 * options.stall_limit) {
        poll();
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
    });
    helper.join();
    ran_seconds = std::chrono::duration<double>(Clock::now() - start).count();
    ended = true;
  });
  bool left_serving = false;
  int checks = 0;
  while (!ended) {
    if (Health(port) != HealthCheckResponse::SERVING) left_serving = true;
    ++checks;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_GE(ran_seconds.load(), 4.0);  // longer than the limit, four times over
  EXPECT_GT(checks, 0);
  EXPECT_FALSE(left_serving);

  GatesOpenAtExit gates;
  const std::shared_ptr<Gate> gate = gates.Make();
  geometry.Post([gate] { gate->Wait(); });  // no progress at all
  EXPECT_TRUE(Eventually([&] { return Health(port) == HealthCheckResponse::NOT_SERVING; }));
  {
    auto stub = testing::Connect(port);
    grpc::ClientContext context;
    v1::ListModelsResponse models;
    EXPECT_EQ(stub->ListModels(&context, v1::ListModelsRequest(), &models).error_code(),
              grpc::StatusCode::UNAVAILABLE);
  }
  gate->Open();
  EXPECT_TRUE(Eventually([&] { return Health(port) == HealthCheckResponse::SERVING; }));
}

}  // namespace
}  // namespace loomlight
