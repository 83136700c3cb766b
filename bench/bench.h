// The benchmark's sections and their sizes. Each section returns its part of the markdown report.
#pragma once

#include <cstddef>
#include <string>

#include "server/runtime/cl_runtime.h"

namespace loomlight::bench {

struct Sizes {
  bool quick = false;
  int timed_runs = 3;                // best of this many after one warm-up
  size_t kernel_queries = 1000000;   // direction pairs timed per preset and implementation
  size_t kernel_error_queries = 1000000;  // prefix of those compared with the double reference
  size_t reference_threads = 2;      // the double reference is split over this many threads
  size_t sweep_queries = 200000;     // direction pairs timed per accuracy knob setting
  size_t sweep_error_queries = 100000;  // subset compared with the exact setting's double reference
  double service_seconds = 2.5;      // per service configuration (clients stop starting calls after it)
  size_t service_max_calls = 20000;  // per client and configuration, whichever comes first
  size_t big_call_queries = size_t{1} << 20;
  // Server CPU per call (section 3b): per round, health Check and 1-query Evaluate make this many calls,
  // each stopping early after cpu_seconds; the median of cpu_rounds.
  size_t cpu_calls = 2000;
  double cpu_seconds = 3.0;
  int cpu_rounds = 5;
  size_t cpu_warmup_calls = 200;  // of each kind, before the first round
  // The pinned 64-client throughput: many short interleaved rounds, so that the machine's drift (rounds of one
  // transport varied by up to 1.7x within a run of 3 s rounds) falls on every transport alike.
  double concurrent_seconds = 1.0;
  int concurrent_rounds = 15;
  double cpu_idle_seconds = 1.0;  // the idle server's own CPU is measured over this long
  int btf_texels = 64;             // BTF asset tile, per side (81 x 81 images of it)
  size_t btf_queries = 2000000;    // random BTF reconstruction queries timed per variant and implementation

  static Sizes Full();
  static Sizes Quick();
};

// Logs progress to stderr (the report goes to stdout and the file at the end).
void Progress(const char* fmt, ...) __attribute__((format(printf, 1, 2)));

// Section 1: every registered model and preset (BRDF and, where spatially varying, BTF): OpenCL fp32 / fp64 and
// the native baseline, throughput and error.
std::string KernelSection(runtime::ClRuntime& rt, const Sizes& sizes);
// Section 2: every declared accuracy knob, each setting's throughput against its error.
std::string KnobSweepSection(runtime::ClRuntime& rt, const Sizes& sizes);
// Section 3: the gRPC service in process, concurrent clients, batching on and off, one maximal call.
std::string ServiceSection(const Sizes& sizes);
// Section 3b: server CPU per Evaluate call (1 and 64 queries) against a health Check, the real server binary
// in a child process, one client.
std::string ServiceCpuSection(const Sizes& sizes);
// Section 5: TextureSlice time against resolution and samples per pixel, and the slice mean against the BRDF.
std::string SliceSection(const Sizes& sizes);
// Tabulate: cells/s on the MERL grid and a 4D grid per model, fp32 and fp64, and their table difference.
std::string TabulateSection(const Sizes& sizes);
// Render: thumbnail time for the cylinder scene at full and chosen fidelity, error against a reference.
std::string RenderSection(const Sizes& sizes);
// Noise against time: thumbnails at 1 to 64 samples per pixel against a converged reference, the time to
// 30, 35 and 40 dB, and the cylinders in Blender Cycles side by side when `blender` is on PATH.
std::string NoiseSection(const Sizes& sizes);
// Section 10: an interactive client's latency beside another's bulk work (fair share), TLS against plaintext.
std::string FairShareSection(const Sizes& sizes);
// Section 11: a BTF asset (woven twill on the H1 grid) synthesised and compressed in process, its error against
// storage, and the btf model's reconstruction throughput and error, OpenCL fp32 / fp64 and native.
std::string BtfSection(runtime::ClRuntime& rt, const Sizes& sizes);
// Tabulated BRDFs (server/models/tabulated_brdf.h): each tabulated preset's kernel throughput against the analytic
// model's on the same pairs, OpenCL fp32, and the table's error against the double reference.
std::string TabulatedSection(runtime::ClRuntime& rt, const Sizes& sizes);
// Section 12: product shots (issue 46), a garment mesh on white under the studio preset at 1600 x 1600, Loomlight
// against Blender Cycles (bench/cycles/product.py, when `blender` is on PATH), each against its own converged image.
std::string ProductSection(const Sizes& sizes);
// Section 13: fabrics as they are designed (issue 47): a tartan WIF draft with its colours on the swatch and as a
// texture slice, the 40 x 40 stitch jersey at fiber level (generation, BVH bytes and build time at full detail and
// Eq. 4's LoD) and a knit close-up at full detail and LoD with the LoD's error.
std::string FabricsSection(const Sizes& sizes);
// Section 14: materials out (issue 48): every surface preset fitted to the glTF sheen and OpenPBR fuzz lobes (error,
// time, worst region, the baseline), and three presets on the sphere in Loomlight and, as the fitted glTF, in Cycles.
std::string MaterialsOutSection(const Sizes& sizes);

}  // namespace loomlight::bench
