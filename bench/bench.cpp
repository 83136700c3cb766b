// loomlight_bench [--out FILE] [--quick]: measures the kernels, the tangent-sample trade-off and the gRPC
// service, then writes the markdown report (default bench/report.md in the source tree) and prints it.
#include "bench/bench.h"

#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>

#include "bench/report.h"
#include "bench/stats.h"
#include "server/models/registry.h"

namespace loomlight::bench {

Sizes Sizes::Full() { return {}; }

Sizes Sizes::Quick() {
  Sizes s;
  s.quick = true;
  s.timed_runs = 1;
  s.kernel_queries = s.kernel_error_queries = 20000;
  s.sweep_queries = s.sweep_error_queries = 5000;
  s.service_seconds = 0.2;
  s.service_max_calls = 200;
  s.big_call_queries = size_t{1} << 16;
  return s;
}

void Progress(const char* fmt, ...) {
  va_list args;
  va_start(args, fmt);
  std::vfprintf(stderr, fmt, args);
  va_end(args);
}

namespace {

struct Args {
  std::string out = std::string(LOOMLIGHT_SOURCE_DIR) + "/bench/report.md";
  bool quick = false;
  bool help = false;
};

void Usage(const char* argv0, const Args& defaults) {
  std::fprintf(stderr,
               "usage: %s [--out FILE] [--quick]\n  --out FILE  report path (default %s)\n"
               "  --quick     small sizes, a smoke run of a few seconds\n",
               argv0, defaults.out.c_str());
}

bool ParseArgs(int argc, char** argv, Args* args) {
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--quick")) {
      args->quick = true;
    } else if (!std::strcmp(argv[i], "--out") && i + 1 < argc) {
      args->out = argv[++i];
    } else if (!std::strcmp(argv[i], "--help") || !std::strcmp(argv[i], "-h")) {
      args->help = true;
    } else {
      return false;
    }
  }
  return true;
}

std::unique_ptr<runtime::ClRuntime> StartRuntime() {
  std::string error;
  auto rt = runtime::ClRuntime::Create({}, &error);
  if (!rt || !rt->BuildPrograms(models::Registry::Global(), &error) || !rt->Warm(models::Registry::Global(), &error)) {
    std::fprintf(stderr, "OpenCL runtime: %s\n", error.c_str());
    return nullptr;
  }
  return rt;
}

// How much the shared machine was disturbed: the numbers are only comparable between quiet runs.
std::string Quietness(const OtherLoad& o) {
  return "other processes used " + Fixed(o.cpu_seconds, 0) + " CPU-s (" + Fixed(100 * o.share, 0) +
         "% of the machine) during the " + Fixed(o.wall_seconds, 0) + " s run; " + std::to_string(RepeatedRuns()) +
         " timed kernel runs were repeated because of them";
}

}  // namespace
}  // namespace loomlight::bench

int main(int argc, char** argv) {
  using namespace loomlight::bench;
  Args args;
  const bool parsed = ParseArgs(argc, argv, &args);
  if (!parsed || args.help) {
    Usage(argv[0], Args());
    return parsed ? 0 : 2;
  }
  const Sizes sizes = args.quick ? Sizes::Quick() : Sizes::Full();
  const CpuSnapshot start = CpuSnapshot::Now();

  std::string machine, sections, woven, transmission;
  {
    std::unique_ptr<loomlight::runtime::ClRuntime> rt = StartRuntime();
    if (!rt) return 1;
    machine = MachineDescription(rt->platform_name(), rt->device_name(), sizes.quick);
    sections += KernelSection(*rt, sizes);
    sections += TangentSweepSection(*rt, sizes);
    woven = WovenSection(*rt, sizes);  // numbered after the service section, which was there first
    transmission = TransmissionSection(*rt, sizes);
  }
  sections += ServiceSection(sizes);
  sections += woven;
  sections += SliceSection(sizes);
  sections += transmission;
  sections += TabulateSection(sizes);
  sections += RenderSection(sizes);
  const std::string quietness = Quietness(OtherProcesses(start, CpuSnapshot::Now()));
  Progress("done: %s\n", quietness.c_str());
  const std::string report = "# Loomlight benchmark\n\n" + machine + "- Quietness: " + quietness +
                             "\n\nProduced by `build/bench/loomlight_bench" + (sizes.quick ? " --quick" : "") +
                             "`.\n\n" + sections;

  std::ofstream out(args.out);
  out << report;
  if (!out) {
    std::fprintf(stderr, "cannot write %s\n", args.out.c_str());
    return 1;
  }
  std::cout << report;
  std::fprintf(stderr, "report written to %s\n", args.out.c_str());
  return 0;
}
