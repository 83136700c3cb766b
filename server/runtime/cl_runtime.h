// OpenCL runtime: platform and device choice, one program build per model and precision at start-up
// (PoCL's on-disk cache in POCL_CACHE_DIR keeps restarts fast), and launches with a fixed local size.
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
};

// One launch: n queries of one model's kernel; each query's material is materials[material_index[q]], packed
// once per precision (the launch reads data32 or data, never converting). uv (pairs) selects the model's
// spatially varying kernel.
struct LaunchArgs {
  const models::Model* model = nullptr;
  bool fp64 = false;
  int uniform = 0;
  const std::vector<const models::PackedMaterial*>* materials = nullptr;
  const std::vector<int>* material_index = nullptr;
  const float* wi = nullptr;
  const float* wo = nullptr;
  const float* uv = nullptr;  // nullptr: f(wi, wo)
  size_t n = 0;
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

 private:
  friend class ClRuntime;
  std::vector<float> f32;
  std::vector<double> f64;
  std::vector<size_t> lane_of;  // query -> lane
  size_t lanes = 0;
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
  // One material for all n queries (uv nullptr: f(wi, wo)).
  bool RunSingle(const models::Model& model, const models::PackedMaterial& m, bool fp64, const float* wi,
                 const float* wo, const float* uv, size_t n, std::vector<double>* f, std::string* error);

  bool has_fp64() const { return has_fp64_; }
  const std::string& device_name() const { return device_name_; }
  const std::string& platform_name() const { return platform_name_; }
  size_t local_size() const { return local_size_; }
  int vector_width() const { return vector_width_; }

 private:
  ClRuntime() = default;
  struct Program {
    cl_program program = nullptr;
    cl_kernel kernel = nullptr;
    cl_kernel uv_kernel = nullptr;  // spatially varying models only
    int width = 1;                  // queries per work-item
  };
  bool Build(const models::KernelSpec& spec, bool fp64, Program* out, std::string* error);

  cl_platform_id platform_ = nullptr;
  cl_device_id device_ = nullptr;
  cl_context context_ = nullptr;
  cl_command_queue queue_ = nullptr;
  bool has_fp64_ = false;
  size_t local_size_ = 64;
  int vector_width_ = 8;
  std::string device_name_, platform_name_;
  std::map<std::pair<std::string, bool>, Program> programs_;  // (model, fp64)
  std::mutex launch_mutex_;
};

}  // namespace loomlight::runtime
