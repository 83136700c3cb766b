#include "server/batching/batcher.h"

#include <algorithm>
#include <tuple>

namespace loomlight::batching {
namespace {

bool SameKernel(const Job& a, const Job& b) {
  return a.model == b.model && a.fp64 == b.fp64 && a.material->uniform == b.material->uniform &&
         (a.uv != nullptr) == (b.uv != nullptr) && a.quantity == b.quantity;
}

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

// Host bytes a queued query holds: wi and wo, uv, and its result in double.
size_t QueuedBytesPerQuery(const Job& job) { return 6 * sizeof(float) + (job.uv ? 2 * sizeof(float) : 0) + 3 * sizeof(double); }

JobResult Failed(JobStatus status, std::string message) {
  JobResult r;
  r.status = status;
  r.message = std::move(message);
  return r;
}

}  // namespace

Batcher::Batcher(runtime::ClRuntime* runtime, BatcherOptions options)
    : runtime_(runtime), options_(options), worker_([this] { Run(); }) {}

Batcher::~Batcher() { Stop(); }

const char* PriorityName(Priority priority) { return priority == Priority::kInteractive ? "interactive" : "bulk"; }

Clock::time_point Batcher::PriorityQueue::oldest() const {
  Clock::time_point t = Clock::time_point::max();
  for (const auto& [name, client] : clients) t = std::min(t, client.jobs.front()->enqueued);
  return t;
}

Batcher::Refusal Batcher::Submit(std::shared_ptr<Job> job) {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (stopping_) return Refusal::kStopping;
    const int p = static_cast<int>(job->priority);
    PriorityQueue& queue = queue_[p];
    const QueuePolicy& policy = options_.policy(job->priority);
    const bool interactive_now = options_.coalesce && job->priority == Priority::kInteractive &&
                                 policy.max_queue_delay.count() == 0 && queue.empty();
    // A small interactive job runs at once on the small-launch device, beside whatever the main device runs:
    // it would otherwise wait for a bulk slice.
    if (interactive_now && runtime_->RunsApart(job->n)) {
      job->enqueued = Clock::now();
      lock.unlock();
      Launch({std::move(job)});
      return Refusal::kNone;
    }
    if (interactive_now && !launching_ && Empty() && job->n <= kMaxInlineQueries) {
      launching_ = true;
      job->enqueued = Clock::now();
      lock.unlock();
      Launch({std::move(job)});
      lock.lock();
      launching_ = false;
      const bool more = !Empty();
      lock.unlock();
      if (more) wake_.notify_one();
      return Refusal::kNone;
    }
    // An empty queue always accepts, so one request up to the per-call limit can always run.
    if (!queue.empty() && queue.queries + job->n > policy.max_queued_queries) return Refusal::kQueueFull;
    auto [it, added] = queue.clients.try_emplace(job->client);
    ClientQueue& client = it->second;
    if (!client.jobs.empty() && client.queued_queries + job->n > policy.max_client_queued_queries)
      return Refusal::kClientQueueFull;
    if (added) client.served = queue.virtual_time;  // idleness earns no credit
    job->enqueued = Clock::now();
    client.queued_queries += job->n;
    queue.jobs += 1;
    queue.queries += job->n;
    queue.bytes += job->n * QueuedBytesPerQuery(*job);
    client.jobs.push_back(std::move(job));
  }
  wake_.notify_one();
  return Refusal::kNone;
}

QueueStats Batcher::Stats() const {
  QueueStats stats;
  std::lock_guard<std::mutex> lock(mutex_);
  for (int p = 0; p < 2; ++p) {
    stats.queued_jobs[p] = queue_[p].jobs;
    stats.queued_queries[p] = queue_[p].queries;
    stats.queued_bytes[p] = queue_[p].bytes;
    stats.clients[p] = queue_[p].clients.size();
    stats.launching_queries[p] = launching_queries_[p].load();
  }
  return stats;
}

void Batcher::Stop() {
  std::vector<std::shared_ptr<Job>> left;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
    for (PriorityQueue& queue : queue_) {
      for (auto& [name, client] : queue.clients) left.insert(left.end(), client.jobs.begin(), client.jobs.end());
      queue = PriorityQueue();
    }
  }
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
  for (auto& job : left) job->done(Failed(JobStatus::kUnavailable, "server is shutting down"));
}

void Batcher::Remove(PriorityQueue& queue, std::map<std::string, ClientQueue>::iterator client,
                     std::deque<std::shared_ptr<Job>>::iterator job) {
  const size_t n = (*job)->n;
  client->second.served += static_cast<double>(n);
  client->second.queued_queries -= n;
  queue.jobs -= 1;
  queue.queries -= n;
  queue.bytes -= n * QueuedBytesPerQuery(**job);
  client->second.jobs.erase(job);
}

std::vector<std::shared_ptr<Job>> Batcher::TakeBatch() {
  std::vector<std::shared_ptr<Job>> batch;
  PriorityQueue& queue = queue_[queue_[0].empty() ? 1 : 0];
  size_t queries = 0;
  const Clock::time_point now = Clock::now();
  const QueuePolicy& policy = options_.policy(&queue == &queue_[0] ? Priority::kInteractive : Priority::kBulk);
  // Under the kDelay timeout action a timed-out job goes behind every job that has not timed out.
  const auto delayed = [&](const Job& job) {
    return policy.timeout_action == QueuePolicy::TimeoutAction::kDelay && policy.TimedOut(job.enqueued, now);
  };
  // Job by job, each from the client served least so far (ties: the longest waiting) among those with a job
  // that fits: fair within a launch too, so coalescing never gives one client's many jobs a ride ahead of
  // another's. While another client has a job of the launch's kernel, a launch takes one job per client: a
  // client with few jobs in flight (a Tabulate call's two chunks) would otherwise see them all ride one launch,
  // have nothing queued when it ends, and miss the next, which the others then fill whole.
  std::vector<std::string> in_batch;
  bool sharing = false;  // another client had a job of the launch's kernel when it began
  while (true) {
    auto chosen = queue.clients.end();
    std::deque<std::shared_ptr<Job>>::iterator chosen_job;
    for (auto client = queue.clients.begin(); client != queue.clients.end(); ++client) {
      if (sharing && std::find(in_batch.begin(), in_batch.end(), client->first) != in_batch.end()) continue;
      auto& jobs = client->second.jobs;
      auto fits = jobs.begin();
      if (!batch.empty())
        fits = std::find_if(jobs.begin(), jobs.end(), [&](const std::shared_ptr<Job>& job) {
          return SameKernel(*batch.front(), *job) && queries + job->n <= options_.max_batch_queries;
        });
      if (fits == jobs.end()) continue;
      const auto rank = [&](decltype(client) c, const Job& job) {
        return std::make_tuple(delayed(job), c->second.served, job.enqueued);
      };
      const bool better = chosen == queue.clients.end() || rank(client, **fits) < rank(chosen, **chosen_job);
      if (better) {
        chosen = client;
        chosen_job = fits;
      }
    }
    if (chosen == queue.clients.end()) break;
    if (batch.empty()) {
      queue.virtual_time = chosen->second.served;
      const Job& first = **chosen_job;
      sharing = std::count_if(queue.clients.begin(), queue.clients.end(), [&](const auto& client) {
                  return std::any_of(client.second.jobs.begin(), client.second.jobs.end(),
                                     [&](const std::shared_ptr<Job>& job) { return SameKernel(first, *job); });
                }) > 1;
    }
    in_batch.push_back(chosen->first);
    queries += (*chosen_job)->n;
    batch.push_back(*chosen_job);
    Remove(queue, chosen, chosen_job);
    if (chosen->second.jobs.empty()) queue.clients.erase(chosen);
    if (!options_.coalesce) break;
  }
  return batch;
}

void Batcher::Run() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    wake_.wait(lock, [this] { return stopping_ || (!Empty() && !launching_); });
    if (stopping_) return;
    const Priority next = queue_[0].empty() ? Priority::kBulk : Priority::kInteractive;
    if (const auto delay = options_.policy(next).max_queue_delay; delay.count() > 0) {
      // Let more requests join until the oldest has waited max_queue_delay or a batch is full.
      const Clock::time_point until = queue_[static_cast<int>(next)].oldest() + delay;
      wake_.wait_until(lock, until, [this] {
        return stopping_ || queue_[0].queries + queue_[1].queries >= options_.max_batch_queries;
      });
      if (stopping_) return;
    }
    if (launching_ || Empty()) continue;  // an inline launch started meanwhile
    std::vector<std::shared_ptr<Job>> batch = TakeBatch();
    launching_ = true;
    lock.unlock();
    Launch(std::move(batch));
    lock.lock();
    launching_ = false;
  }
}

void Batcher::Launch(std::vector<std::shared_ptr<Job>> batch) {
  const Clock::time_point now = Clock::now();
  // Requests whose deadline passed, whose client went away or that queued past their queue's timeout are
  // dropped before launch.
  std::vector<std::shared_ptr<Job>> live;
  for (auto& job : batch) {
    const bool cancelled = job->cancelled && job->cancelled();
    const QueuePolicy& policy = options_.policy(job->priority);
    const auto timeout = policy.timeout;
    if (job->deadline <= now || (cancelled && job->deadline <= now + kDeadlineSlack))
      job->done(Failed(JobStatus::kDeadlineExceeded, "deadline passed while queued"));
    else if (policy.timeout_action == QueuePolicy::TimeoutAction::kReject && policy.TimedOut(job->enqueued, now))
      job->done(Failed(JobStatus::kResourceExhausted,
                       std::string("queued longer than the ") + PriorityName(job->priority) + " queue's timeout of " +
                           std::to_string(timeout.count()) + " ms: the server is overloaded; retry later"));
    else if (cancelled)
      job->done(Failed(JobStatus::kCancelled, "cancelled while queued"));
    else
      live.push_back(std::move(job));
  }
  if (live.empty()) return;

  const models::Model* model = live.front()->model;
  const bool spatial = live.front()->uv != nullptr;
  size_t n = 0;
  for (auto& job : live) n += job->n;

  // Each distinct material once (clients of one preset share its packed material).
  std::vector<const models::PackedMaterial*> materials;
  std::vector<int> index;
  index.reserve(n);
  std::vector<size_t> first;
  // One job reads straight from its request; several are concatenated.
  std::vector<float> wi_all, wo_all, uv_all;
  const float* wi = live.front()->wi;
  const float* wo = live.front()->wo;
  const float* uv = live.front()->uv;
  for (size_t j = 0; j < live.size(); ++j) {
    const Job& job = *live[j];
    const auto known = std::find(materials.begin(), materials.end(), job.material);
    const int m = static_cast<int>(known - materials.begin());
    if (known == materials.end()) materials.push_back(job.material);
    first.push_back(index.size());
    index.insert(index.end(), job.n, m);
    if (live.size() > 1) {
      wi_all.insert(wi_all.end(), job.wi, job.wi + 3 * job.n);
      wo_all.insert(wo_all.end(), job.wo, job.wo + 3 * job.n);
      if (spatial) uv_all.insert(uv_all.end(), job.uv, job.uv + 2 * job.n);
    }
  }
  if (live.size() > 1) {
    wi = wi_all.data();
    wo = wo_all.data();
    uv = spatial ? uv_all.data() : nullptr;
  }

  const runtime::LaunchArgs args{.model = model, .fp64 = live.front()->fp64, .uniform = live.front()->material->uniform,
                                 .materials = &materials, .material_index = &index, .wi = wi, .wo = wo, .uv = uv,
                                 .n = n, .quantity = live.front()->quantity};
  std::string error;
  const Clock::time_point start = Clock::now();
  double kernel_seconds = 0;
  std::atomic<size_t>& launching = launching_queries_[static_cast<int>(live.front()->priority)];
  launching += n;
  const bool ok = RunAndDeliver(args, live, first, &error, &kernel_seconds);
  launching -= n;

  for (auto& job : live) {
    JobResult r;
    if (!ok) {
      r.status = JobStatus::kInternal;
      r.message = "kernel launch failed: " + error;
    }
    r.queue_seconds = Seconds(start - job->enqueued);
    r.kernel_seconds = kernel_seconds;
    r.batch_queries = n;
    r.batch_requests = live.size();
    job->done(std::move(r));
  }
}

bool Batcher::RunKernel(const runtime::LaunchArgs& args, runtime::LaunchResults* results, std::string* error,
                        double* seconds) {
  const Clock::time_point start = Clock::now();
  // The watchdog watches the main device; launches beside it on the small device are short.
  const bool watched = !runtime_->RunsApart(args.n);
  if (watched) busy_since_ = start;
  const bool ok = runtime_->Run(args, results, error);
  if (watched) busy_since_ = Clock::time_point::max();
  *seconds += Seconds(Clock::now() - start);
  return ok;
}

bool Batcher::RunAndDeliver(const runtime::LaunchArgs& args, const std::vector<std::shared_ptr<Job>>& jobs,
                            const std::vector<size_t>& first, std::string* error, double* seconds) {
  // Writes launch queries [begin, begin + count), the results of one run, to the jobs they belong to.
  auto deliver = [&](const runtime::LaunchResults& results, size_t begin, size_t count) {
    for (size_t j = 0; j < jobs.size(); ++j) {
      const size_t lo = std::max(begin, first[j]), hi = std::min(begin + count, first[j] + jobs[j]->n);
      if (lo < hi) results.Write(lo - begin, hi - lo, jobs[j]->sink, lo - first[j]);
    }
  };
  runtime::LaunchResults results;
  if (jobs.front()->priority != Priority::kBulk) {
    if (!RunKernel(args, &results, error, seconds)) return false;
    deliver(results, 0, args.n);
    return true;
  }
  std::vector<int> index;
  size_t slice = kFirstBulkSlice;
  for (size_t begin = 0; begin < args.n;) {
    const size_t m = std::min(slice, args.n - begin);
    index.assign(args.material_index->begin() + begin, args.material_index->begin() + begin + m);
    runtime::LaunchArgs a = args;
    a.material_index = &index;
    a.wi = args.wi + 3 * begin;
    a.wo = args.wo + 3 * begin;
    a.uv = args.uv ? args.uv + 2 * begin : nullptr;
    a.n = m;
    double t = 0;
    if (!RunKernel(a, &results, error, &t)) return false;
    *seconds += t;
    deliver(results, begin, m);
    begin += m;
    // The next slice takes about bulk_slice at the rate just measured.
    const double rate = m / std::max(t, 1e-6);
    slice = std::clamp<size_t>(static_cast<size_t>(rate * Seconds(options_.bulk_slice)), kMinBulkSlice,
                               std::max(kMinBulkSlice, options_.max_batch_queries));
    if (begin < args.n) LaunchWaitingInteractive();
  }
  return true;
}

void Batcher::LaunchWaitingInteractive() {
  while (true) {
    std::vector<std::shared_ptr<Job>> batch;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stopping_ || queue_[static_cast<int>(Priority::kInteractive)].empty()) return;
      batch = TakeBatch();  // interactive: its queue is not empty
    }
    Launch(std::move(batch));
  }
}

}  // namespace loomlight::batching
