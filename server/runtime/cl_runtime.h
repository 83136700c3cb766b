// OpenCL runtime: platform and device choice, one program build per model and precision at start-up
// (PoCL's on-disk cache in POCL_CACHE_DIR and the programs' binaries kept beside it keep restarts fast), and
// launches with a fixed local size.
#pragma once

#include <CL/cl.h>

#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::runtime {

// Kernel sources embedded at build time (cmake/EmbedKernels.cmake), keyed by path under kernels/.
const std::map<std::string, std::string>& EmbeddedKernelSources();

struct RuntimeOptions {
  std::string platform;   // substring of the platform name or vendor; "" = PoCL if present, else the first
  std::string device;     // substring of the device name; "" = the platform's first CPU device, else any
  std::string cache_dir;  // POCL_CACHE_DIR if not already set; "" = $HOME/.cache/loomlight/pocl
  size_t local_size = 64;  // queries per work-group
  int vector_width = 8;    // queries per work-item in float kernels (explicit vectors); fp64 kernels use 1
  // Launches of at most this many queries go to PoCL's single-threaded `basic` device, which runs them on the
  // launching thread, when the device is PoCL's multi-threaded CPU device (`pthread`): waking its worker
  // threads costs more than evaluating a few queries. Same compiler, same code: the same bits. 0: never.
  size_t small_launch_queries = 256;
};

// One launch: n queries of one model's kernel; each query's material is materials[material_index[q]], packed
// once per precision (the launch reads data32 or data, never converting). uv (pairs) selects the model's
// spatially varying kernel.
struct LaunchArgs {
  const models::Model* model = nullptr;
  bool fp64 = false;
  int uniform = 0;
  const std::vector<const models::PackedMaterial*>* materials = nullptr;
  const std::vector<int>* material_index = nullptr;  // nullptr: every query has materials[0]
  const float* wi = nullptr;
  const float* wo = nullptr;
  const float* uv = nullptr;  // nullptr: f(wi, wo)
  size_t n = 0;
  models::Quantity quantity = models::Quantity::kScattering;  // kAmbient: the model's ambient entry (uv nullptr)
};

// Where one caller's results go, written straight from the device's output in the caller's precision (a
// float response, a double accumulator): query i's RGB to out[3 * slot(i) + c], times scale[slot(i)].
struct ResultSink {
  float* f32 = nullptr;  // exactly one of f32 and f64
  double* f64 = nullptr;
  const size_t* slot = nullptr;   // i -> destination query; nullptr: i
  const double* scale = nullptr;  // per destination query; nullptr: 1
};

// A launch's results as the device left them: planar per lane, in the kernel's precision.
class LaunchResults {
 public:
  // Writes the launch's queries [first, first + count) to the sink's queries [sink_first, sink_first + count).
  void Write(size_t first, size_t count, const ResultSink& sink, size_t sink_first) const;
  // Wall time from the kernel's enqueue to its results being readable: the device's part of the launch,
  // without the host's lane layout and copies.
  double kernel_seconds() const { return kernel_seconds_; }

 private:
  friend class ClRuntime;
  std::vector<float> f32;
  std::vector<double> f64;
  std::vector<size_t> lane_of;  // query -> lane
  size_t lanes = 0;
  double kernel_seconds_ = 0;
};

class ClRuntime {
 public:
  // Picks the device (options, then LOOMLIGHT_PLATFORM / LOOMLIGHT_DEVICE from the environment).
  static std::unique_ptr<ClRuntime> Create(const RuntimeOptions& options, std::string* error);
  ~ClRuntime();

  // Builds every model's kernel in float and, where the device has cl_khr_fp64, double. On failure the
  // error carries the build log.
  bool BuildPrograms(const models::Registry& registry, std::string* error);
  // Launches every kernel once so the first request does not pay for PoCL's work-group compilation.
  bool Warm(const models::Registry& registry, std::string* error);

  // Runs one launch. Thread-safe: launches are serialised.
  bool Run(const LaunchArgs& args, LaunchResults* results, std::string* error);
  // One material for all n queries (uv nullptr: f(wi, wo)); kernel_seconds: LaunchResults::kernel_seconds.
  bool RunSingle(const models::Model& model, const models::PackedMaterial& m, bool fp64, const float* wi,
                 const float* wo, const float* uv, size_t n, std::vector<double>* f, std::string* error,
                 models::Quantity quantity = models::Quantity::kScattering, double* kernel_seconds = nullptr);

  bool has_fp64() const { return has_fp64_; }
  const std::string& device_name() const { return main_.device_name; }
  // Whether a launch of n queries runs on the small-launch device, apart from (and beside) the main one.
  bool RunsApart(size_t n) const { return small_.device != nullptr && n <= small_launch_queries_; }
  // The device small launches go to ("" when they go to the main device too).
  const std::string& small_device_name() const { return small_.device_name; }
  const std::string& platform_name() const { return platform_name_; }
  size_t local_size() const { return main_.local_size; }
  int vector_width() const { return vector_width_; }

 private:
  ClRuntime() = default;
  struct Program {
    cl_program program = nullptr;
    cl_kernel kernel = nullptr;
    cl_kernel uv_kernel = nullptr;  // spatially varying models only
    cl_kernel ambient_kernel = nullptr;  // models with an ambient entry only
    int width = 1;                  // queries per work-item
  };
  // Host memory and an OpenCL buffer over it (CL_MEM_USE_HOST_PTR), kept between launches and grown on demand:
  // small launches on a CPU device reuse them instead of creating six buffers per launch.
  struct Staging {
    std::vector<double> host;  // doubles: aligned for every element type
    cl_mem mem = nullptr;
    // A buffer of at least `bytes` over host memory; nullptr on failure.
    cl_mem Reserve(cl_context context, size_t bytes, cl_int* err);
    void Release();
  };
  // One device with its context, queue and programs (keyed by model name and fp64), built with `local_size`
  // queries per work-group.
  struct Target {
    cl_device_id device = nullptr;
    cl_context context = nullptr;
    cl_command_queue queue = nullptr;
    size_t local_size = 64;
    std::string device_name;
    std::map<std::pair<std::string, bool>, Program> programs;
    bool staged = false;  // launches use `staging` (materials, offsets, wi, wo, uv, f) instead of new buffers
    Staging staging[6];
    // One launch at a time per device (its kernels' arguments and staging are shared); the small device's
    // launches run beside the main device's.
    std::mutex launch_mutex;
    bool Open(cl_device_id d, std::string* error);
    void Close();
  };
  // From the program binary cache (binary_cache_dir_) when it holds this program, else from source (then stored).
  bool Build(Target& target, const models::KernelSpec& spec, bool fp64, Program* out, std::string* error);
  bool CreateKernels(const models::KernelSpec& spec, Program* out, std::string* error);

  cl_platform_id platform_ = nullptr;
  bool has_fp64_ = false;
  int vector_width_ = 8;
  std::string platform_name_;
  std::string binary_cache_dir_;  // "" when none (no cache directory)
  Target main_;
  Target small_;  // device null: none
  size_t small_launch_queries_ = 0;
};

}  // namespace loomlight::runtime
