#include "server/batching/batcher.h"

#include <algorithm>

namespace loomlight::batching {
namespace {

bool SameKernel(const Job& a, const Job& b) {
  return a.model == b.model && a.fp64 == b.fp64 && a.material->uniform == b.material->uniform &&
         (a.uv != nullptr) == (b.uv != nullptr) && a.quantity == b.quantity;
}

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

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

Batcher::Refusal Batcher::Submit(std::shared_ptr<Job> job) {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (stopping_) return Refusal::kStopping;
    if (options_.coalesce && options_.max_queue_delay.count() == 0 && !launching_ && Empty() &&
        job->priority == Priority::kInteractive &&
        job->n <= kMaxInlineQueries) {
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
    const int p = static_cast<int>(job->priority);
    // An empty queue always accepts, so one request up to the per-call limit can always run.
    if (!queue_[p].empty() && queued_queries_[p] + job->n > options_.max_queued_queries) return Refusal::kQueueFull;
    job->enqueued = Clock::now();
    queued_queries_[p] += job->n;
    queue_[p].push_back(std::move(job));
  }
  wake_.notify_one();
  return Refusal::kNone;
}

void Batcher::Stop() {
  std::deque<std::shared_ptr<Job>> left;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
    for (int p = 0; p < 2; ++p) {
      left.insert(left.end(), queue_[p].begin(), queue_[p].end());
      queue_[p].clear();
      queued_queries_[p] = 0;
    }
  }
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
  for (auto& job : left) job->done(Failed(JobStatus::kUnavailable, "server is shutting down"));
}

std::vector<std::shared_ptr<Job>> Batcher::TakeBatch() {
  std::vector<std::shared_ptr<Job>> batch;
  size_t queries = 0;
  const int p = queue_[0].empty() ? 1 : 0;
  std::deque<std::shared_ptr<Job>>& queue = queue_[p];
  for (auto it = queue.begin(); it != queue.end();) {
    const bool first = batch.empty();
    if (!first && (!options_.coalesce || !SameKernel(*batch.front(), **it) ||
                   queries + (*it)->n > options_.max_batch_queries)) {
      ++it;
      continue;
    }
    queries += (*it)->n;
    queued_queries_[p] -= (*it)->n;
    batch.push_back(std::move(*it));
    it = queue.erase(it);
    if (!options_.coalesce) break;
  }
  return batch;
}

void Batcher::Run() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    wake_.wait(lock, [this] { return stopping_ || (!Empty() && !launching_); });
    if (stopping_) return;
    if (options_.max_queue_delay.count() > 0) {
      // Let more requests join until the oldest has waited max_queue_delay or a batch is full.
      const std::deque<std::shared_ptr<Job>>& first = queue_[0].empty() ? queue_[1] : queue_[0];
      const Clock::time_point until = first.front()->enqueued + options_.max_queue_delay;
      wake_.wait_until(lock, until, [this] {
        return stopping_ || queued_queries_[0] + queued_queries_[1] >= options_.max_batch_queries;
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
  // Requests whose deadline passed or whose client went away are dropped before launch.
  std::vector<std::shared_ptr<Job>> live;
  for (auto& job : batch) {
    const bool cancelled = job->cancelled && job->cancelled();
    if (job->deadline <= now || (cancelled && job->deadline <= now + kDeadlineSlack))
      job->done(Failed(JobStatus::kDeadlineExceeded, "deadline passed while queued"));
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
  const bool ok = RunAndDeliver(args, live, first, &error, &kernel_seconds);

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
  busy_since_ = start;
  const bool ok = runtime_->Run(args, results, error);
  busy_since_ = Clock::time_point::max();
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
