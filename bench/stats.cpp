#include "bench/stats.h"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <fstream>
#include <limits>
#include <string>
#include <thread>

namespace loomlight::bench {

double Time(const std::function<void()>& fn) {
  const Clock::time_point start = Clock::now();
  fn();
  return SecondsSince(start);
}

CpuSnapshot CpuSnapshot::Now() {
  CpuSnapshot s;
  std::ifstream stat("/proc/stat");
  std::string cpu;
  double user = 0, nice = 0, system = 0, idle = 0, iowait = 0, irq = 0, softirq = 0, steal = 0;
  stat >> cpu >> user >> nice >> system >> idle >> iowait >> irq >> softirq >> steal;
  s.machine_busy_seconds = (user + nice + system + irq + softirq + steal) / static_cast<double>(sysconf(_SC_CLK_TCK));
  // The benchmark's own children count as itself once reaped (section 3b's server process).
  for (int who : {RUSAGE_SELF, RUSAGE_CHILDREN}) {
    rusage u{};
    getrusage(who, &u);
    s.self_seconds += static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
                      1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
  }
  s.time = Clock::now();
  return s;
}

OtherLoad OtherProcesses(const CpuSnapshot& start, const CpuSnapshot& end) {
  OtherLoad o;
  o.wall_seconds = std::chrono::duration<double>(end.time - start.time).count();
  o.cpu_seconds = std::max(0.0, (end.machine_busy_seconds - start.machine_busy_seconds) -
                                    (end.self_seconds - start.self_seconds));
  o.share = o.cpu_seconds / std::max(1e-9, o.wall_seconds * std::thread::hardware_concurrency());
  return o;
}

namespace {
std::atomic<size_t> repeated_runs{0};

// Other processes took more than a tenth of the machine (beyond the clock-tick granularity of /proc/stat).
bool Disturbed(const OtherLoad& o) {
  return o.cpu_seconds > 0.1 * o.wall_seconds * std::thread::hardware_concurrency() + 0.05;
}
}  // namespace

std::vector<double> BestOfEach(int runs, const std::vector<std::function<void()>>& fns) {
  for (const auto& fn : fns) fn();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> best_clean(fns.size(), inf), best_any(fns.size(), inf);
  std::vector<int> clean(fns.size(), 0), attempts(fns.size(), 0);
  for (bool pending = true; pending;) {
    pending = false;
    for (size_t i = 0; i < fns.size(); ++i) {
      if (clean[i] >= runs || attempts[i] >= 3 * runs) continue;
      ++attempts[i];
      const CpuSnapshot before = CpuSnapshot::Now();
      const double seconds = Time(fns[i]);
      best_any[i] = std::min(best_any[i], seconds);
      if (Disturbed(OtherProcesses(before, CpuSnapshot::Now()))) {
        ++repeated_runs;
      } else {
        best_clean[i] = std::min(best_clean[i], seconds);
        ++clean[i];
      }
      pending = true;
    }
  }
  std::vector<double> best(fns.size());
  for (size_t i = 0; i < fns.size(); ++i) best[i] = clean[i] > 0 ? best_clean[i] : best_any[i];
  return best;
}

size_t RepeatedRuns() { return repeated_runs; }

}  // namespace loomlight::bench
