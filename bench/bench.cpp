// loomlight_bench [--out FILE] [--quick] [--only SECTIONS]: measures every model's kernels, the accuracy knobs'
// speed against error and the gRPC service, then writes the markdown report (default bench/report.md in the source tree) and prints it.
#include "bench/bench.h"

#include <absl/synchronization/mutex.h>

#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <set>
#include <sstream>
#include <utility>

#include "bench/report.h"
#include "bench/stats.h"
#include "server/api/server.h"
#include "server/models/registry.h"
#include "server/runtime/allocator.h"

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
  s.cpu_calls = 200;
  s.cpu_seconds = 0.3;
  s.cpu_warmup_calls = 20;
  s.concurrent_seconds = 0.3;
  s.concurrent_rounds = 3;
  s.cpu_idle_seconds = 0.2;
  s.btf_texels = 16;
  s.btf_queries = 20000;
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
  bool calibration = false;  // print the CPU calibration loop's time alone (reports written by other tools)
  std::set<std::string> only;  // section names; empty: all
};

// Section names for --only, in report order.
const char* const kSectionNames[] = {"kernel", "sweep", "service", "service-cpu", "slice", "tabulate",
                                     "render", "noise", "fair-share", "btf", "tabulated", "product",
                                     "fabrics", "materials-out"};
// Sections merged into another, still accepted by their old names: "kernel" measures every model.
const std::pair<const char*, const char*> kSectionAliases[] = {{"woven", "kernel"}, {"transmission", "kernel"}};

// The section's own name (an alias resolved), or "" when there is none.
std::string SectionName(const std::string& name) {
  for (const auto& [alias, section] : kSectionAliases)
    if (name == alias) return section;
  for (const char* n : kSectionNames)
    if (name == n) return n;
  return "";
}

void Usage(const char* argv0, const Args& defaults) {
  std::fprintf(stderr,
               "usage: %s [--out FILE] [--quick] [--only SECTIONS] | --calibration\n  --out FILE  report path (default %s)\n"
               "  --quick     small sizes, a smoke run of a few seconds\n"
               "  --only SECTIONS  comma-separated, of: kernel (every model; aliases woven, transmission), sweep\n"
               "              (accuracy knobs), service, service-cpu, slice, tabulate, render, noise, fair-share, btf,\n"
               "              tabulated (tabulated BRDFs against the analytic model), product (a garment against\n"
               "              Blender Cycles), fabrics (a tartan draft's colours, a knit at fiber level), materials-out\n"
               "              (every preset fitted to glTF sheen and OpenPBR fuzz, fitted glTF in Cycles)\n"
               "              (a partial report: give it its own --out)\n"
               "  --calibration  print the milliseconds of the fixed CPU calibration loop every report starts with\n"
               "              (for reports other tools write, e.g. web/bench/studio-latency.mjs)\n",
               argv0, defaults.out.c_str());
}

bool ParseArgs(int argc, char** argv, Args* args) {
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--quick")) {
      args->quick = true;
    } else if (!std::strcmp(argv[i], "--out") && i + 1 < argc) {
      args->out = argv[++i];
    } else if (!std::strcmp(argv[i], "--only") && i + 1 < argc) {
      std::istringstream names(argv[++i]);
      for (std::string name; std::getline(names, name, ',');) {
        const std::string section = SectionName(name);
        if (section.empty()) {
          std::fprintf(stderr, "unknown section '%s'\n", name.c_str());
          return false;
        }
        args->only.insert(section);
      }
    } else if (!std::strcmp(argv[i], "--calibration")) {
      args->calibration = true;
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
  // As the server does (server/api/server.cpp): the benchmark's own gRPC clients skip Abseil's debug-only
  // lock-order graph too.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  // The in-process servers' allocator as loomlight-server sets it (server/main.cpp).
  loomlight::runtime::KeepFreedMemory(loomlight::api::ServerOptions().limits.memory_budget_bytes);
  Args args;
  const bool parsed = ParseArgs(argc, argv, &args);
  if (!parsed || args.help) {
    Usage(argv[0], Args());
    return parsed ? 0 : 2;
  }
  if (args.calibration) {
    std::printf("%.0f\n", CalibrationMilliseconds());
    return 0;
  }
  const Sizes sizes = args.quick ? Sizes::Quick() : Sizes::Full();
  const CpuSnapshot start = CpuSnapshot::Now();
  auto want = [&args](const char* name) { return args.only.empty() || args.only.count(name) > 0; };

  std::string machine, sections, btf, tabulated;
  {
    std::unique_ptr<loomlight::runtime::ClRuntime> rt = StartRuntime();
    if (!rt) return 1;
    machine = MachineDescription(rt->platform_name(), rt->device_name(), sizes.quick);
    if (want("kernel")) sections += KernelSection(*rt, sizes);
    if (want("sweep")) sections += KnobSweepSection(*rt, sizes);
    if (want("btf")) btf = BtfSection(*rt, sizes);  // last in the report with the tabulated, the newest sections
    if (want("tabulated")) tabulated = TabulatedSection(*rt, sizes);
  }
  if (want("service")) sections += ServiceSection(sizes);
  if (want("service-cpu")) sections += ServiceCpuSection(sizes);
  if (want("slice")) sections += SliceSection(sizes);
  if (want("tabulate")) sections += TabulateSection(sizes);
  if (want("render")) sections += RenderSection(sizes);
  if (want("noise")) sections += NoiseSection(sizes);
  if (want("fair-share")) sections += FairShareSection(sizes);
  sections += btf + tabulated;
  if (want("product")) sections += ProductSection(sizes);
  if (want("fabrics")) sections += FabricsSection(sizes);
  if (want("materials-out")) sections += MaterialsOutSection(sizes);
  const std::string quietness = Quietness(OtherProcesses(start, CpuSnapshot::Now()));
  Progress("done: %s\n", quietness.c_str());
  std::string only;
  for (const char* name : kSectionNames)
    if (args.only.count(name)) only += (only.empty() ? "" : ",") + std::string(name);
  const std::string report = "# Loomlight benchmark\n\n" + machine + "- Quietness: " + quietness +
                             "\n\nProduced by `build/bench/loomlight_bench" + (sizes.quick ? " --quick" : "") +
                             (only.empty() ? "" : " --only " + only) + "`" +
                             (only.empty() ? "" : " (a partial run: only these sections)") + ".\n\n" + sections;

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
