// Timing and statistics shared by every benchmark section: wall-clock timing, best-of-N runs, percentiles,
// random direction pairs and the error measures against a reference.
#pragma once

#include <chrono>
#include <cstddef>
#include <functional>
#include <random>
#include <vector>

#include "server/models/accuracy.h"

namespace loomlight::bench {

using Clock = std::chrono::steady_clock;

inline double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// CPU time of the whole machine and of this process (with its reaped children: the server of section 3b), to
// tell how much other processes ran in between.
struct CpuSnapshot {
  double machine_busy_seconds = 0, self_seconds = 0;
  Clock::time_point time;
  static CpuSnapshot Now();
};
struct OtherLoad {
  double cpu_seconds = 0, wall_seconds = 0;
  double share = 0;  // of the machine's capacity (all hardware threads) over the interval
};
OtherLoad OtherProcesses(const CpuSnapshot& start, const CpuSnapshot& end);

// Wall-clock seconds of one call of fn.
double Time(const std::function<void()>& fn);
// One untimed warm-up call of each function, then `runs` rounds timing each in turn (so they all see the
// same conditions of the shared machine); the fastest seconds of each. A timed call during which other
// processes were busy is repeated, up to 3 x runs calls per function.
std::vector<double> BestOfEach(int runs, const std::vector<std::function<void()>>& fns);
inline double BestOf(int runs, const std::function<void()>& fn) { return BestOfEach(runs, {fn})[0]; }
// Timed calls BestOf repeated so far because other processes were busy.
size_t RepeatedRuns();

// Direction pairs, percentiles and errors against the reference are shared with the tests.
using accuracy::Accuracy;
using accuracy::Compare;
using accuracy::Pairs;
using accuracy::Percentile;
using accuracy::RandomPairs;

// Relative-error floor: values of f at or below it are not resolved by any display or table.
constexpr double kErrorFloor = 1e-4;

}  // namespace loomlight::bench
