// `loomlight batch`: runs a CSV of render and tabulation jobs concurrently through one channel (one replica,
// a load balancer such as HAProxy, or several replicas balanced by the channel itself), retrying calls that
// failed for reasons that may pass. Every job is idempotent: its output appears whole or not at all (written to
// a temporary file in the same directory, then renamed over the target), and a job whose output exists is
// skipped, so running the same CSV again resumes where a stopped or partly failed batch left off.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>
#include <variant>
#include <vector>

#include "client/commands.h"
#include "client/job_requests.h"
#include "client/progress.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

namespace fs = std::filesystem;

// Below the server's per-client limit of long-running calls (8 at once by default), which a client running
// exactly at it meets now and then: the server frees a call's slot just after the client has seen the call end.
constexpr int kDefaultConcurrency = 6;
constexpr int kDefaultRetries = 4;
constexpr double kDefaultBackoffSeconds = 0.5;
constexpr double kMaxBackoffSeconds = 10.0;

struct Job {
  std::string id;
  std::string kind;  // "render" or "tab", as in the CSV
  std::string out;
  std::string where;  // "FILE:LINE", for messages
  std::variant<v1::RenderRequest, v1::TabulateRequest> request;
};

// ---- reading the CSV ----

}  // namespace

// cli.h; `loomlight yarn --curves` reads its CSV with it too.
std::vector<std::string> split_csv_record(std::string_view line, const std::string& where) {
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  std::vector<std::string> fields(1);
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c != '"') {
        fields.back() += c;
      } else if (i + 1 < line.size() && line[i + 1] == '"') {
        fields.back() += '"';
        ++i;
      } else {
        quoted = false;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      fields.emplace_back();
    } else {
      fields.back() += c;
    }
  }
  if (quoted) throw UsageError(where + ": unterminated quoted field");
  return fields;
}

namespace {

// The options column as arguments: split at whitespace; single quotes keep whitespace inside one argument
// (--env-file 'my sky.exr'), as a shell would.
std::vector<std::string> split_arguments(std::string_view text, const std::string& where) {
  std::vector<std::string> arguments;
  std::string current;
  bool in_argument = false, quoted = false;
  for (const char c : text) {
    if (c == '\'') {
      quoted = !quoted;
      in_argument = true;
    } else if (!quoted && std::isspace(static_cast<unsigned char>(c))) {
      if (in_argument) arguments.push_back(std::move(current));
      current.clear();
      in_argument = false;
    } else {
      current += c;
      in_argument = true;
    }
  }
  if (quoted) throw UsageError(where + ": unterminated ' in the options column");
  if (in_argument) arguments.push_back(std::move(current));
  return arguments;
}

// Which field holds each column, from the header record. Unknown columns are refused, so a misspelt one is
// not silently ignored.
struct Columns {
  std::size_t id, kind, out;
  std::optional<std::size_t> options;
};

Columns parse_header(const std::vector<std::string>& header, const std::string& where) {
  std::map<std::string, std::size_t> index;
  for (std::size_t i = 0; i < header.size(); ++i) {
    const std::string& name = header[i];
    if (name != "id" && name != "kind" && name != "out" && name != "options")
      throw UsageError(where + ": unknown column '" + name + "' (columns: id, kind, out, options)");
    if (!index.emplace(name, i).second) throw UsageError(where + ": column '" + name + "' appears twice");
  }
  for (const char* required : {"id", "kind", "out"})
    if (!index.contains(required)) throw UsageError(where + ": the header has no '" + required + "' column");
  Columns columns{index["id"], index["kind"], index["out"], std::nullopt};
  if (index.contains("options")) columns.options = index["options"];
  return columns;
}

// A row as a job, its request built by the render or tab command's own code: a row means what the command
// line `loomlight KIND OPTIONS --out OUT` would.
Job parse_job(const std::vector<std::string>& fields, const Columns& columns, const std::string& where) {
  const std::size_t needed = std::max({columns.id, columns.kind, columns.out, columns.options.value_or(0)}) + 1;
  if (fields.size() < needed)
    throw UsageError(where + ": " + std::to_string(fields.size()) + " fields, the header has " +
                     std::to_string(needed));
  Job job{fields[columns.id], fields[columns.kind], fields[columns.out], where, {}};
  if (job.id.empty()) throw UsageError(where + ": empty id");
  if (job.out.empty()) throw UsageError(where + ": job " + job.id + ": empty out");
  const Command* command = job.kind == "render" ? &render_command() : job.kind == "tab" ? &tab_command() : nullptr;
  if (command == nullptr) throw UsageError(where + ": job " + job.id + ": kind must be render or tab, got '" + job.kind + "'");
  const std::string options_text = columns.options ? fields[*columns.options] : "";
  try {
    const std::vector<std::string> arguments = split_arguments(options_text, where);
    const ParsedOptions options = parse_options(command->options, arguments);
    if (!options.positional.empty()) throw UsageError("unexpected argument '" + options.positional[0] + "'");
    if (options.has("out")) throw UsageError("the output goes in the out column, not --out");
    if (command == &render_command())
      job.request = render_request(options, job.out);
    else
      job.request = tabulate_request(options, job.out);
  } catch (const UsageError& e) {
    throw UsageError(where + ": job " + job.id + ": " + e.what());
  }
  return job;
}

// Every job of the file, checked before any call: a typo in row 180 should not surface after 179 renders.
std::vector<Job> read_jobs(const std::string& path) {
  std::ifstream file(path);
  if (!file) throw UsageError("cannot read --csv " + path);
  std::vector<Job> jobs;
  std::optional<Columns> columns;
  std::set<std::string> ids, outputs;
  std::string line;
  for (int number = 1; std::getline(file, line); ++number) {
    const std::string where = path + ":" + std::to_string(number);
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;  // blank lines and comments
    const std::vector<std::string> fields = split_csv_record(line, where);
    if (!columns) {
      columns = parse_header(fields, where);
      continue;
    }
    Job job = parse_job(fields, *columns, where);
    if (!ids.insert(job.id).second) throw UsageError(where + ": job id '" + job.id + "' appears twice");
    // Two jobs writing one file would race and make the skip-if-present rule ambiguous.
    if (!outputs.insert(fs::absolute(job.out).lexically_normal().string()).second)
      throw UsageError(where + ": job " + job.id + ": output " + job.out + " is another job's output too");
    jobs.push_back(std::move(job));
  }
  if (!columns) throw UsageError(path + ": no header (id,kind,out,options)");
  return jobs;
}

// ---- writing outputs ----

// An output that appears whole or not at all: bytes go to a temporary file beside the target (the same
// directory, hence the same file system, so rename() replaces the target atomically), which commit() flushes
// to disk and renames; a file never committed is removed.
class AtomicFile {
 public:
  AtomicFile(const std::string& target, mode_t mode) : target_(target), temporary_(target + ".XXXXXX.tmp") {
    fd_ = mkstemps(temporary_.data(), 4);
    if (fd_ < 0) fail("cannot create a temporary file for");
    // mkstemp makes it private (0600); the output gets the mode any new file of this user would.
    if (fchmod(fd_, mode) != 0) {
      const int error = errno;
      discard();  // no destructor runs after a constructor throws
      errno = error;
      fail("cannot set the mode of");
    }
  }
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  ~AtomicFile() {
    if (!committed_) discard();
  }

  void write(std::string_view bytes) {
    while (!bytes.empty()) {
      const ssize_t n = ::write(fd_, bytes.data(), bytes.size());
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) fail("cannot write");
      bytes.remove_prefix(static_cast<std::size_t>(n));
    }
  }

  void commit() {
    // Flushed before the rename, so after a crash the name never points at a file whose data were lost.
    if (fsync(fd_) != 0) fail("cannot flush");
    const int fd = fd_;
    fd_ = -1;
    if (close(fd) != 0) fail("cannot close");
    if (std::rename(temporary_.c_str(), target_.c_str()) != 0) fail("cannot rename the temporary file to");
    committed_ = true;
  }

 private:
  void discard() {
    if (fd_ >= 0) close(fd_);
    fd_ = -1;
    unlink(temporary_.c_str());
  }

  [[noreturn]] void fail(const char* what) const {
    throw std::runtime_error(std::string(what) + " " + target_ + ": " + std::strerror(errno));
  }

  std::string target_, temporary_;
  int fd_ = -1;
  bool committed_ = false;
};

// The mode a new file gets from open(..., 0666) under the process's umask (read once, before any thread:
// reading it means setting it).
mode_t new_file_mode() {
  const mode_t mask = umask(0);
  umask(mask);
  return 0666 & ~mask;
}

// ---- running jobs ----

// Whether a failed call may succeed when tried again: the server, or the way to it, was unavailable,
// overloaded, too slow or aborted the call, or the connection broke mid-call. gRPC reports a stream reset by
// a proxy or a dying server as INTERNAL, UNKNOWN or CANCELLED with the transport's words, and those alone are
// retried; answers about the request itself (INVALID_ARGUMENT, NOT_FOUND, ...) never are.
bool is_transient(const RpcError& error) {
  switch (error.code) {
    case grpc::StatusCode::UNAVAILABLE:
    case grpc::StatusCode::DEADLINE_EXCEEDED:
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
    case grpc::StatusCode::ABORTED:
      return true;
    case grpc::StatusCode::INTERNAL:
    case grpc::StatusCode::UNKNOWN:
    case grpc::StatusCode::CANCELLED: {
      const std::string_view message = error.what();
      for (const std::string_view transport_words : {"RST_STREAM", "Stream removed", "Socket closed", "GOAWAY",
                                                      "Connection reset", "Broken pipe", "failed to connect"})
        if (message.find(transport_words) != std::string_view::npos) return true;
      return false;
    }
    default:
      return false;
  }
}

// One attempt at a job: the call, its output written atomically. Throws what the call or the file threw.
void run_attempt(Client& client, const Job& job, mode_t mode) {
  AtomicFile file(job.out, mode);
  if (const auto* request = std::get_if<v1::RenderRequest>(&job.request)) {
    v1::RenderUpdate last;
    client.render(*request, [&](const v1::RenderUpdate& update) {
      if (!update.image().empty()) last = update;
    });
    if (last.image().empty()) throw std::runtime_error("the server finished without an image");
    if (last.width() != request->width() || last.height() != request->height())
      throw std::runtime_error("the server returned a " + std::to_string(last.width()) + "x" +
                               std::to_string(last.height()) + " image for a " + std::to_string(request->width()) +
                               "x" + std::to_string(request->height()) + " render");
    file.write(last.image());
  } else {
    uint64_t cells_done = 0, cells_total = 0;
    client.tabulate(std::get<v1::TabulateRequest>(job.request), [&](const v1::TabulateChunk& chunk) {
      file.write(chunk.data());
      cells_done = chunk.cells_done();
      cells_total = std::max(cells_total, chunk.cells_total());
    });
    if (cells_total == 0 || cells_done != cells_total)
      throw std::runtime_error("the table ended after " + std::to_string(cells_done) + " of " +
                               std::to_string(cells_total) + " cells");
  }
  file.commit();
}

enum class JobStatus { done, skipped, failed };

const char* status_name(JobStatus status) {
  switch (status) {
    case JobStatus::done: return "done";
    case JobStatus::skipped: return "skipped";
    default: return "failed";
  }
}

struct JobResult {
  JobStatus status = JobStatus::skipped;
  int attempts = 0;
  double seconds = 0.0;
  std::string error;  // the last attempt's, when failed
};

std::string csv_field(const std::string& text) {
  if (text.find_first_of(",\"\n\r") == std::string::npos) return text;
  std::string quoted = "\"";
  for (const char c : text) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
  return quoted + '"';
}

// What the workers share: counts, the progress bar, the log and stderr, all behind one mutex.
class Report {
 public:
  Report(std::size_t total, const std::optional<std::string>& log_path) : total_(total), progress_("jobs") {
    if (log_path) {
      log_.open(*log_path, std::ios::trunc);
      if (!log_) throw UsageError("cannot write --log " + *log_path);
      log_ << "id,kind,status,attempts,seconds,out,error\n" << std::flush;
    }
  }

  void finished(const Job& job, const JobResult& result) {
    const std::lock_guard lock(mutex_);
    ++counts_[static_cast<int>(result.status)];
    if (result.status == JobStatus::failed)
      failures_.push_back(job.where + ": job " + job.id + " failed after " + std::to_string(result.attempts) +
                          (result.attempts == 1 ? " attempt: " : " attempts: ") + result.error);
    if (log_.is_open()) {
      // One line per job as it ends, flushed, so the log of an interrupted batch is complete up to there.
      char seconds[32];
      std::snprintf(seconds, sizeof seconds, "%.3f", result.seconds);
      log_ << csv_field(job.id) << ',' << job.kind << ',' << status_name(result.status) << ',' << result.attempts
           << ',' << seconds << ',' << csv_field(job.out) << ',' << csv_field(result.error) << '\n'
           << std::flush;
    }
    progress_.update(counts_[0] + counts_[1] + counts_[2], total_);
  }

  void retrying(const Job& job, int attempt, const std::string& error, double delay) {
    const std::lock_guard lock(mutex_);
    ++retries_;
    progress_.end();  // a terminal's bar is redrawn below the message at the next update
    std::fprintf(stderr, "job %s attempt %d: %s; retrying in %.1f s\n", job.id.c_str(), attempt, error.c_str(),
                 delay);
  }

  // The summary on stdout, failures on stderr; whether every job is done or skipped.
  bool summarize(double seconds) {
    progress_.end();
    for (const std::string& failure : failures_) std::fprintf(stderr, "error: %s\n", failure.c_str());
    const int done = counts_[0], skipped = counts_[1], failed = counts_[2];
    std::printf("batch: %zu jobs in %.1f s: %d done, %d skipped, %d failed, %d retries (%.2f jobs/s)\n", total_,
                seconds, done, skipped, failed, retries_, seconds > 0 ? done / seconds : 0.0);
    return failed == 0;
  }

 private:
  std::mutex mutex_;
  std::size_t total_;
  ProgressBar progress_;
  std::ofstream log_;
  int counts_[3] = {0, 0, 0};  // by JobStatus
  int retries_ = 0;
  std::vector<std::string> failures_;
};

struct RetryPolicy {
  int retries;
  double first_backoff_seconds;

  // Exponential backoff with jitter (half to all of the nominal delay), so workers that failed together when
  // a replica died do not return together.
  double delay_seconds(int failed_attempts, std::mt19937& random) const {
    const double nominal = std::min(kMaxBackoffSeconds, first_backoff_seconds * std::pow(2.0, failed_attempts - 1));
    return std::uniform_real_distribution<double>(0.5 * nominal, nominal)(random);
  }
};

JobResult run_job(Client& client, const Job& job, const RetryPolicy& policy, mode_t mode, Report& report,
                  std::mt19937& random) {
  JobResult result;
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    ++result.attempts;
    try {
      run_attempt(client, job, mode);
      result.status = JobStatus::done;
      break;
    } catch (const RpcError& e) {
      result.error = e.what();
      if (!is_transient(e) || result.attempts > policy.retries) {
        result.status = JobStatus::failed;
        break;
      }
      const double delay = policy.delay_seconds(result.attempts, random);
      report.retrying(job, result.attempts, result.error, delay);
      std::this_thread::sleep_for(std::chrono::duration<double>(delay));
    } catch (const std::exception& e) {  // a bad answer or a local file error: trying again would not help
      result.error = e.what();
      result.status = JobStatus::failed;
      break;
    }
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

int run_batch(const ParsedOptions& options) {
  const auto csv = options.last("csv");
  if (!csv) throw UsageError("batch needs --csv FILE");
  const int concurrency =
      options.last("jobs") ? parse_int(*options.last("jobs"), "--jobs", 1, 1024) : kDefaultConcurrency;
  const RetryPolicy policy{
      options.last("retries") ? parse_int(*options.last("retries"), "--retries", 0, 100) : kDefaultRetries,
      options.last("backoff") ? parse_number(*options.last("backoff"), "--backoff") : kDefaultBackoffSeconds};
  if (!(policy.first_backoff_seconds >= 0.0 && policy.first_backoff_seconds <= kMaxBackoffSeconds))
    throw UsageError("--backoff must be between 0 and 10 seconds");

  const std::vector<Job> jobs = read_jobs(*csv);
  Client client(options);  // one channel for all workers: it spreads their calls when it has several targets
  Report report(jobs.size(), options.last("log"));
  const mode_t mode = new_file_mode();

  std::vector<const Job*> pending;
  for (const Job& job : jobs) {
    if (fs::exists(job.out)) {
      report.finished(job, JobResult{});  // made by an earlier run: skipped
      continue;
    }
    const fs::path directory = fs::path(job.out).parent_path();
    if (!directory.empty()) fs::create_directories(directory);
    pending.push_back(&job);
  }

  const auto start = std::chrono::steady_clock::now();
  std::atomic<std::size_t> next{0};
  std::vector<std::jthread> workers;
  const int worker_count = static_cast<int>(std::min<std::size_t>(concurrency, pending.size()));
  for (int w = 0; w < worker_count; ++w)
    workers.emplace_back([&, w] {
      std::mt19937 random(std::random_device{}() + static_cast<unsigned>(w));
      for (std::size_t i; (i = next.fetch_add(1)) < pending.size();)
        report.finished(*pending[i], run_job(client, *pending[i], policy, mode, report, random));
    });
  workers.clear();  // joins
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report.summarize(seconds) ? 0 : 1;
}

}  // namespace

const Command& batch_command() {
  static const Command command = {
      "batch",
      "--csv FILE [--jobs N] [--retries N] [--backoff SECONDS] [--log FILE]",
      "run a CSV of render and tab jobs concurrently, with retries; reruns resume",
      "The CSV has a header naming its columns, in any order: id (unique), kind (render or tab), out (the\n"
      "output file; its extension picks the format as for the command) and options (optional: the command's\n"
      "options as on its command line, without --out; quote the field when it holds commas, and use '...'\n"
      "for an argument with spaces). Blank lines and lines starting with # are skipped. Every row is checked\n"
      "before the first call. Jobs run --jobs at a time through one channel (several --server targets or a\n"
      "load balancer spread them over replicas). A call that fails with UNAVAILABLE, DEADLINE_EXCEEDED,\n"
      "RESOURCE_EXHAUSTED, ABORTED or a broken connection is tried again after an exponential backoff, up to\n"
      "--retries times; other errors fail the job at once. Each output is written to OUT.XXXXXX.tmp beside\n"
      "it and renamed into place when complete, and a job whose output exists is skipped, so running the\n"
      "same CSV again resumes (a batch killed mid-write may leave a .tmp file, never taken for an output).\n"
      "Prints a progress bar on stderr and a summary (done, skipped, failed, retries); exits 1 when a job\n"
      "failed. --log writes one CSV line per job as it ends: id,kind,status,attempts,seconds,out,error:\n"
      "status done, skipped or failed; error the last failed attempt's, also for a job done after retries.\n"
      "Example CSV:\n"
      "  id,kind,out,options\n"
      "  satin,render,thumbs/satin.png,--preset polyester_satin_charmeuse_front --scene cylinders --spp 16\n"
      "  silk,tab,tables/silk.binary,--preset silk_shot --grid merl\n"
      "  shot,tab,lobes/shot.csv,\"--preset silk_shot --param thread2.albedo=0.1,0.5,0.9 --incidence 0,30\"",
      {
          {"csv", "FILE", "the jobs (required)"},
          {"jobs", "N", "jobs run at a time (default 6)"},
          {"retries", "N", "further attempts of a call that failed transiently (default 4)"},
          {"backoff", "SECONDS", "delay before the first retry, doubled for each further one up to 10 s (default 0.5)"},
          {"log", "FILE", "write id,kind,status,attempts,seconds,out,error per job"},
      },
      run_batch,
  };
  return command;
}

}  // namespace loomlight::client
