// The dynamic batcher against the real OpenCL runtime: coalescing by kernel, drops before launch,
// queue bounds.
#include <gtest/gtest.h>

#include <algorithm>

#include <future>
#include <mutex>
#include <string>

#include "server/batching/batcher.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using batching::Job;
using batching::JobResult;
using batching::JobStatus;
using batching::Batcher;

struct Submitted {
  std::shared_ptr<Job> job;
  std::future<JobResult> result;
  std::vector<float> wi, wo;
  models::PackedMaterial material;
  std::vector<double> f;  // the job's sink
};

// A job of n random queries of a preset with T tangent samples; its result arrives through the future.
std::unique_ptr<Submitted> MakeJob(const std::string& preset, size_t n, int T = 32) {
  auto s = std::make_unique<Submitted>();
  const models::PresetSpec* spec = nullptr;
  const models::Model* model = models::Registry::Global().FindPreset(preset, &spec);
  models::ParamValues v = model->PresetValues(*spec);
  v["tangent_samples"] = {double(T)};
  std::mt19937 rng(n);
  s->wi.resize(3 * n);
  s->wo.resize(3 * n);
  for (size_t q = 0; q < n; ++q) {
    accuracy::RandomHemisphere(rng, &s->wi[3 * q]);
    accuracy::RandomHemisphere(rng, &s->wo[3 * q]);
  }
  s->job = std::make_shared<Job>();
  s->job->model = model;
  s->material = model->Pack(v);
  s->job->material = &s->material;
  s->f.assign(3 * n, -1.0);
  s->job->sink.f64 = s->f.data();
  s->job->wi = s->wi.data();
  s->job->wo = s->wo.data();
  s->job->n = n;
  auto promise = std::make_shared<std::promise<JobResult>>();
  s->result = promise->get_future();
  s->job->done = [promise](JobResult r) { promise->set_value(std::move(r)); };
  return s;
}

// Holds the batcher's thread before a launch (in the poll of a bulk job's `cancelled`) until opened, so what
// queues meanwhile, and how long it waits, is set by the test, not by how fast the device is.
class Gate {
 public:
  explicit Gate(Batcher& batcher) : job_(MakeJob("velvet", 16)), released_(release_.get_future().share()) {
    job_->job->priority = batching::Priority::kBulk;
    job_->job->client = "gate";
    job_->job->cancelled = [this, released = released_] {
      entered_.set_value();
      released.wait();
      return false;
    };
    EXPECT_EQ(batcher.Submit(job_->job), Batcher::Refusal::kNone);
    entered_.get_future().wait();
  }
  ~Gate() { EXPECT_EQ(job_->result.get().status, JobStatus::kOk); }
  void Open() { release_.set_value(); }

 private:
  std::unique_ptr<Submitted> job_;
  std::promise<void> entered_, release_;
  std::shared_future<void> released_;
};


TEST(Batcher, CoalescesSameKernelAndKeepsOtherKernelsApart) {
  batching::Batcher batcher(&testing::SharedRuntime(), {});
  Gate gate(batcher);  // holds the launch while the rest queue
  // Larger than a small launch (which would run at once on the small-launch device, beside the held launch).
  auto a = MakeJob("linen_plain", 300), b = MakeJob("silk_shot", 400), c = MakeJob("velvet", 500);
  auto other = MakeJob("velvet", 350, 16);  // different tangent sample count: its own launch
  for (auto* s : {a.get(), b.get(), other.get(), c.get()}) ASSERT_EQ(batcher.Submit(s->job), Batcher::Refusal::kNone);
  gate.Open();
  for (auto* s : {a.get(), b.get(), c.get()}) {
    const JobResult r = s->result.get();
    ASSERT_EQ(r.status, JobStatus::kOk);
    EXPECT_EQ(r.batch_requests, 3u);
    EXPECT_EQ(r.batch_queries, 1200u);
    // Each job's slice of the launch is its own material's answer.
    const auto direct = testing::RunKernel(*s->job->model, s->material, false, s->wi, s->wo);
    EXPECT_EQ(s->f, direct);
  }
  const JobResult r = other->result.get();
  EXPECT_EQ(r.batch_requests, 1u);
  EXPECT_GE(*std::min_element(other->f.begin(), other->f.end()), 0.0);  // every value written (the sink held -1)
}

TEST(Batcher, DropsExpiredAndCancelledJobsBeforeLaunch) {
  batching::Batcher batcher(&testing::SharedRuntime(), {});
  auto expired = MakeJob("velvet", 1000);
  expired->job->deadline = batching::Clock::now() - std::chrono::milliseconds(1);
  auto cancelled = MakeJob("velvet", 1000);
  cancelled->job->cancelled = [] { return true; };
  auto fine = MakeJob("velvet", 1000);
  for (auto* s : {expired.get(), cancelled.get(), fine.get()}) ASSERT_EQ(batcher.Submit(s->job), Batcher::Refusal::kNone);
  const JobResult re = expired->result.get(), rc = cancelled->result.get(), rf = fine->result.get();
  EXPECT_EQ(re.status, JobStatus::kDeadlineExceeded);
  EXPECT_EQ(*std::max_element(expired->f.begin(), expired->f.end()), -1.0);  // nothing written
  EXPECT_EQ(rc.status, JobStatus::kCancelled);
  EXPECT_EQ(rf.status, JobStatus::kOk);
  EXPECT_EQ(rf.batch_requests, 1u);  // the dropped jobs never rode in the launch
}

TEST(Batcher, RefusesBeyondTheQueueBoundButAlwaysTakesOneRequest) {
  batching::BatcherOptions options;
  options.interactive.max_queued_queries = options.bulk.max_queued_queries = 500;
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  auto big = MakeJob("velvet", 1000), first = MakeJob("velvet", 400);
  EXPECT_EQ(batcher.Submit(big->job), Batcher::Refusal::kNone);  // larger than the bound, but the queue was empty
  EXPECT_EQ(batcher.Submit(first->job), Batcher::Refusal::kQueueFull);  // 1400 queued would exceed 500
  gate.Open();
  EXPECT_EQ(big->result.get().status, JobStatus::kOk);
  // Once the queue has drained, a job within the bound is taken again.
  EXPECT_EQ(batcher.Submit(first->job), Batcher::Refusal::kNone);
  EXPECT_EQ(first->result.get().status, JobStatus::kOk);
}

// The first job waits for company (up to the queue delay, here longer than any test) until the batch is full.
TEST(Batcher, QueueDelayLetsABatchFill) {
  batching::BatcherOptions options;
  options.interactive.max_queue_delay = std::chrono::seconds(600);
  options.max_batch_queries = 200;  // full with both jobs: launched then, not after the delay
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  auto a = MakeJob("velvet", 100);
  ASSERT_EQ(batcher.Submit(a->job), Batcher::Refusal::kNone);
  auto b = MakeJob("linen_plain", 100);
  ASSERT_EQ(batcher.Submit(b->job), Batcher::Refusal::kNone);
  EXPECT_EQ(a->result.get().batch_requests, 2u);
  EXPECT_EQ(b->result.get().batch_requests, 2u);
}

TEST(Batcher, StopFailsQueuedJobsAsUnavailable) {
  auto batcher = std::make_unique<batching::Batcher>(&testing::SharedRuntime(), batching::BatcherOptions{});
  auto gate = std::make_unique<Gate>(*batcher);
  auto queued = MakeJob("velvet", 1000);
  ASSERT_EQ(batcher->Submit(queued->job), Batcher::Refusal::kNone);
  // Stop waits for the held launch; the gate opens once Stop has begun (Submit says so), so the queued job
  // cannot launch first.
  std::thread stop([&] { batcher->Stop(); });
  std::vector<std::unique_ptr<Submitted>> probes;
  while (true) {
    probes.push_back(MakeJob("velvet", 10));
    if (batcher->Submit(probes.back()->job) == Batcher::Refusal::kStopping) break;
  }
  probes.pop_back();  // refused: never taken
  gate->Open();
  stop.join();
  gate.reset();  // the held launch itself completes
  EXPECT_EQ(queued->result.get().status, JobStatus::kUnavailable);
  for (auto& p : probes) EXPECT_EQ(p->result.get().status, JobStatus::kUnavailable);
}

}  // namespace
TEST(Batcher, InteractiveJobsLaunchBeforeQueuedBulkJobs) {
  batching::BatcherOptions options;
  options.max_batch_queries = 1000;  // one job per launch, so the finishing order is the launch order
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  // Queued while a launch is held: bulk first, then an interactive job of another kernel (larger than a small
  // launch, which would run at once beside the held one).
  std::mutex mutex;
  std::vector<std::string> finished;
  auto track = [&](Submitted& s, const std::string& label) {
    auto done = s.job->done;
    s.job->done = [&, label, done](JobResult r) {
      {
        std::lock_guard<std::mutex> lock(mutex);
        finished.push_back(label);
      }
      done(std::move(r));
    };
  };
  auto bulk = MakeJob("velvet", 1000);
  bulk->job->priority = batching::Priority::kBulk;
  auto interactive = MakeJob("linen_plain", 1000);
  track(*bulk, "bulk");
  track(*interactive, "interactive");
  ASSERT_EQ(batcher.Submit(bulk->job), Batcher::Refusal::kNone);
  ASSERT_EQ(batcher.Submit(interactive->job), Batcher::Refusal::kNone);
  gate.Open();
  ASSERT_EQ(interactive->result.get().status, JobStatus::kOk);
  ASSERT_EQ(bulk->result.get().status, JobStatus::kOk);
  // The interactive job launched first although it queued last.
  EXPECT_EQ(finished, (std::vector<std::string>{"interactive", "bulk"}));
}

TEST(Batcher, BulkWorkCannotFillTheInteractiveQueue) {
  batching::BatcherOptions options;
  options.interactive.max_queued_queries = options.bulk.max_queued_queries = 500;
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  auto bulk = MakeJob("velvet", 400), more_bulk = MakeJob("velvet", 400), interactive = MakeJob("velvet", 400);
  bulk->job->priority = more_bulk->job->priority = batching::Priority::kBulk;
  EXPECT_EQ(batcher.Submit(bulk->job), Batcher::Refusal::kNone);
  EXPECT_EQ(batcher.Submit(more_bulk->job), Batcher::Refusal::kQueueFull);
  EXPECT_EQ(batcher.Submit(interactive->job), Batcher::Refusal::kNone);  // its own queue has room
  gate.Open();
  EXPECT_EQ(interactive->result.get().status, JobStatus::kOk);
  EXPECT_EQ(bulk->result.get().status, JobStatus::kOk);
}

TEST(Batcher, SmallInteractiveJobsRunBesideALongLaunch) {
  if (!testing::SharedRuntime().RunsApart(64)) GTEST_SKIP() << "no small-launch device";
  batching::Batcher batcher(&testing::SharedRuntime(), {});
  Gate gate(batcher);
  auto small = MakeJob("linen_plain", 64);
  ASSERT_EQ(batcher.Submit(small->job), Batcher::Refusal::kNone);
  // Answered by Submit itself, while the main launch is still held.
  ASSERT_EQ(small->result.wait_for(std::chrono::milliseconds(0)), std::future_status::ready);
  const JobResult r = small->result.get();
  EXPECT_EQ(r.status, JobStatus::kOk);
  EXPECT_EQ(small->f, testing::RunKernel(*small->job->model, small->material, false, small->wi, small->wo));
  gate.Open();
}

// Bulk jobs of 2,000 queries from named clients, recording which client's job each finished launch served.
class LaunchOrder {
 public:
  std::unique_ptr<Submitted> Submit(Batcher& batcher, const std::string& client) {
    auto s = MakeJob("velvet", 2000);
    s->job->priority = batching::Priority::kBulk;
    s->job->client = client;
    auto done = s->job->done;
    s->job->done = [this, client, done](JobResult r) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        clients_.push_back(client);
      }
      done(std::move(r));
    };
    EXPECT_EQ(batcher.Submit(s->job), Batcher::Refusal::kNone);
    return s;
  }
  std::vector<std::string> clients() {
    std::lock_guard<std::mutex> lock(mutex_);
    return clients_;
  }

 private:
  std::mutex mutex_;
  std::vector<std::string> clients_;
};

TEST(Batcher, ClientsShareTheDeviceFairly) {
  batching::BatcherOptions options;
  options.max_batch_queries = 2000;  // one job per launch, so the launch order shows the schedule
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  LaunchOrder launches;
  auto submit = [&](const std::string& client) { return launches.Submit(batcher, client); };
  std::vector<std::unique_ptr<Submitted>> jobs;
  for (int i = 0; i < 6; ++i) jobs.push_back(submit("many"));
  jobs.push_back(submit("one"));  // queued last
  gate.Open();
  for (auto& j : jobs) EXPECT_EQ(j->result.get().status, JobStatus::kOk);
  // First come, first served would run it seventh; fair share, second (after the first of the six, which
  // queued first with the same service).
  const std::vector<std::string> order = launches.clients();
  ASSERT_EQ(order.size(), 7u);
  EXPECT_EQ(std::find(order.begin(), order.end(), "one") - order.begin(), 1);
}

TEST(Batcher, OneClientCannotTakeTheWholeQueue) {
  batching::BatcherOptions options;
  options.interactive.max_client_queued_queries = 1000;
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  auto first = MakeJob("velvet", 600), second = MakeJob("velvet", 600), other = MakeJob("velvet", 600);
  first->job->client = second->job->client = "greedy";
  other->job->client = "modest";
  EXPECT_EQ(batcher.Submit(first->job), Batcher::Refusal::kNone);
  EXPECT_EQ(batcher.Submit(second->job), Batcher::Refusal::kClientQueueFull);  // 1200 > its 1000
  EXPECT_EQ(batcher.Submit(other->job), Batcher::Refusal::kNone);
  gate.Open();
  EXPECT_EQ(first->result.get().status, JobStatus::kOk);
  EXPECT_EQ(other->result.get().status, JobStatus::kOk);
}

TEST(Batcher, JobsQueuedPastTheTimeoutAreRejected) {
  batching::BatcherOptions options;
  options.bulk.timeout = std::chrono::milliseconds(100);
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  auto bulk = MakeJob("velvet", 1000), interactive = MakeJob("velvet", 1000);
  bulk->job->priority = batching::Priority::kBulk;
  ASSERT_EQ(batcher.Submit(bulk->job), Batcher::Refusal::kNone);
  ASSERT_EQ(batcher.Submit(interactive->job), Batcher::Refusal::kNone);  // its queue has no timeout
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // at least 300 ms queued: past the 100 ms timeout
  gate.Open();
  const JobResult rb = bulk->result.get();
  EXPECT_EQ(rb.status, JobStatus::kResourceExhausted);
  EXPECT_NE(rb.message.find("bulk queue's timeout of 100 ms"), std::string::npos) << rb.message;
  EXPECT_EQ(interactive->result.get().status, JobStatus::kOk);
}

// A client with one job queued beside another's many shares each launch one job each: its jobs do not all ride
// one launch while the other's wait (a Tabulate call keeps two chunks in flight: with both in one launch it
// would have none queued for the next).
TEST(Batcher, WhileClientsShareAKernelALaunchTakesOneJobEach) {
  batching::BatcherOptions options;
  options.max_batch_queries = 10000;  // room for all five
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  std::vector<std::unique_ptr<Submitted>> many;
  for (int i = 0; i < 4; ++i) {
    many.push_back(MakeJob("velvet", 2000));
    many.back()->job->priority = batching::Priority::kBulk;
    many.back()->job->client = "many";
    ASSERT_EQ(batcher.Submit(many.back()->job), Batcher::Refusal::kNone);
  }
  auto few = MakeJob("velvet", 2000);
  few->job->priority = batching::Priority::kBulk;
  few->job->client = "few";
  ASSERT_EQ(batcher.Submit(few->job), Batcher::Refusal::kNone);
  gate.Open();
  const JobResult shared = few->result.get();
  EXPECT_EQ(shared.status, JobStatus::kOk);
  EXPECT_EQ(shared.batch_requests, 2u);  // its job and one of the other client's, not all five
  // Alone, the other client's jobs coalesce again: the remaining three in one launch.
  size_t most = 0;
  for (auto& m : many) {
    const JobResult r = m->result.get();
    EXPECT_EQ(r.status, JobStatus::kOk);
    most = std::max(most, r.batch_requests);
  }
  EXPECT_EQ(most, 3u);
}

// Triton's DELAY action: a job that queued past the timeout stays queued but goes behind a job that has not
// timed out, where fair share alone would launch it first (it queued first, with the same service).
TEST(Batcher, TimedOutJobsGoBehindUnderTheDelayAction) {
  batching::BatcherOptions options;
  options.max_batch_queries = 2000;  // one job per launch, so the launch order shows the schedule
  options.bulk.timeout = std::chrono::milliseconds(150);
  options.bulk.timeout_action = batching::QueuePolicy::TimeoutAction::kDelay;
  batching::Batcher batcher(&testing::SharedRuntime(), options);
  Gate gate(batcher);
  LaunchOrder launches;
  auto submit = [&](const std::string& client) { return launches.Submit(batcher, client); };
  auto late = submit("late");
  std::this_thread::sleep_for(std::chrono::milliseconds(400));  // past the timeout
  auto fresh = submit("fresh");
  gate.Open();
  EXPECT_EQ(late->result.get().status, JobStatus::kOk);  // delayed, not rejected
  EXPECT_EQ(fresh->result.get().status, JobStatus::kOk);
  const std::vector<std::string> order = launches.clients();
  ASSERT_EQ(order.size(), 2u);
  EXPECT_EQ(order[0], "fresh");
  EXPECT_EQ(order[1], "late");
}

TEST(Batcher, SubmitAfterStopSaysStopping) {
  batching::Batcher batcher(&testing::SharedRuntime(), {});
  batcher.Stop();
  auto job = MakeJob("velvet", 10);
  EXPECT_EQ(batcher.Submit(job->job), Batcher::Refusal::kStopping);
}

}  // namespace loomlight
