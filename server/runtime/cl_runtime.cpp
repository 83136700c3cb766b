#include "server/runtime/cl_runtime.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <unistd.h>

namespace loomlight::runtime {
namespace {

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

bool Contains(const std::string& haystack, const std::string& needle) {
  return Lower(haystack).find(Lower(needle)) != std::string::npos;
}

// A string property of a platform or device (clGetPlatformInfo / clGetDeviceInfo have the same shape).
template <class Id, class What, class Getter>
std::string InfoString(Getter get, Id id, What what) {
  size_t size = 0;
  get(id, what, 0, nullptr, &size);
  std::string s(size, '\0');
  get(id, what, size, s.data(), nullptr);
  while (!s.empty() && s.back() == '\0') s.pop_back();
  return s;
}
std::string PlatformInfo(cl_platform_id p, cl_platform_info what) { return InfoString(clGetPlatformInfo, p, what); }
std::string DeviceInfo(cl_device_id d, cl_device_info what) { return InfoString(clGetDeviceInfo, d, what); }

// PoCL's CPU devices are named after their driver: "pthread-<cpu>" (multi-threaded) and "basic-<cpu>" (runs
// commands on the thread that waits for them).
bool IsPoclBasic(const std::string& device_name) { return device_name.rfind("basic-", 0) == 0; }
bool IsPoclPthread(const std::string& device_name) { return device_name.rfind("pthread-", 0) == 0; }

// n copies of a k-vector, one after another.
std::vector<float> Repeat(const float* v, size_t k, size_t n) {
  std::vector<float> out;
  for (size_t i = 0; i < n; ++i) out.insert(out.end(), v, v + k);
  return out;
}

std::string ClError(const char* what, cl_int err) { return std::string(what) + " failed (OpenCL error " + std::to_string(err) + ")"; }

// Materials from this size on are not copied into a launch's buffers (see Run).
constexpr size_t kLargeMaterialBytes = size_t{1} << 20;

// Releases OpenCL memory objects at scope exit.
struct Buffers {
  std::vector<cl_mem> mems;
  ~Buffers() {
    for (cl_mem m : mems)
      if (m) clReleaseMemObject(m);
  }
};

// Program binaries kept beside PoCL's cache. PoCL finds a cached program only after preprocessing its source with
// clang (about 90 ms a program; 20 programs were 2 of a server's 3 s to start); a program made from its binary
// builds in about 3 ms. A file is named by what it is for (source, options, device), so a changed source replaces
// its old file, and holds the full key it was built from (platform, driver, device, options, source text),
// compared whole before use: anything else is a miss and the source is built.
std::string ProgramBinaryKey(cl_platform_id platform, cl_device_id device, const std::string& options,
                             const std::string& source) {
  return PlatformInfo(platform, CL_PLATFORM_VERSION) + "\n" + DeviceInfo(device, CL_DRIVER_VERSION) + "\n" +
         DeviceInfo(device, CL_DEVICE_NAME) + "\n" + options + "\n" + source;
}

std::string ProgramBinaryPath(const std::string& dir, const std::string& source_name, const std::string& options,
                              const std::string& device_name) {
  std::string name = source_name + options + "-" + device_name;
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '.') c = '_';
  return dir + "/" + name.substr(0, 200) + ".bin";
}

constexpr char kProgramBinaryMagic[] = "loomlight program binary 1";

// The binary stored under `key` at `path`; false when absent or stored for another key.
bool ReadProgramBinary(const std::string& path, const std::string& key, std::string* binary) {
  std::ifstream in(path, std::ios::binary);
  std::string magic, size;
  if (!std::getline(in, magic) || magic != kProgramBinaryMagic || !std::getline(in, size)) return false;
  std::string stored(key.size(), '\0');
  if (size != std::to_string(key.size()) || !in.read(stored.data(), stored.size()) || stored != key) return false;
  std::ostringstream rest;
  rest << in.rdbuf();
  *binary = rest.str();
  return !binary->empty();
}

// Stores a built program's binary; best effort (a failure leaves the next start building from source). Written
// whole under a name of its own, then renamed over the old file: a reader in another process sees one or the other.
void WriteProgramBinary(const std::string& path, const std::string& key, cl_program program) {
  size_t size = 0;
  if (clGetProgramInfo(program, CL_PROGRAM_BINARY_SIZES, sizeof size, &size, nullptr) != CL_SUCCESS || size == 0) return;
  std::string binary(size, '\0');
  unsigned char* data = reinterpret_cast<unsigned char*>(binary.data());
  if (clGetProgramInfo(program, CL_PROGRAM_BINARIES, sizeof data, &data, nullptr) != CL_SUCCESS) return;
  static std::atomic<unsigned> written{0};
  const std::string temporary = path + ".tmp" + std::to_string(::getpid()) + "-" + std::to_string(written++);
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out << kProgramBinaryMagic << "\n" << key.size() << "\n" << key << binary;
    if (!out.flush()) {
      std::remove(temporary.c_str());
      return;
    }
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) std::filesystem::remove(temporary, ec);
}

}  // namespace

std::unique_ptr<ClRuntime> ClRuntime::Create(const RuntimeOptions& options, std::string* error) {
  // PoCL reads POCL_CACHE_DIR when the ICD loads it: set it before the first OpenCL call.
  std::string cache = options.cache_dir;
  if (cache.empty() && std::getenv("HOME")) cache = std::string(std::getenv("HOME")) + "/.cache/loomlight/pocl";
  if (!cache.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(cache, ec);
    setenv("POCL_CACHE_DIR", cache.c_str(), /*overwrite=*/options.cache_dir.empty() ? 0 : 1);
  }
  // PoCL offers its multi-threaded CPU device alone unless told otherwise; small launches want its
  // single-threaded one beside it (RuntimeOptions::small_launch_queries). An operator's own choice stands.
  if (options.small_launch_queries > 0) setenv("POCL_DEVICES", "pthread basic", /*overwrite=*/0);
  std::string want_platform = options.platform, want_device = options.device;
  if (want_platform.empty() && std::getenv("LOOMLIGHT_PLATFORM")) want_platform = std::getenv("LOOMLIGHT_PLATFORM");
  if (want_device.empty() && std::getenv("LOOMLIGHT_DEVICE")) want_device = std::getenv("LOOMLIGHT_DEVICE");

  cl_uint np = 0;
  if (clGetPlatformIDs(0, nullptr, &np) != CL_SUCCESS || np == 0) {
    *error = "no OpenCL platform found (is pocl-opencl-icd installed?)";
    return nullptr;
  }
  std::vector<cl_platform_id> platforms(np);
  clGetPlatformIDs(np, platforms.data(), nullptr);

  auto rt = std::unique_ptr<ClRuntime>(new ClRuntime);
  rt->main_.local_size = options.local_size;
  if (const char* pocl_cache = std::getenv("POCL_CACHE_DIR"); pocl_cache && *pocl_cache) {
    std::error_code ec;
    rt->binary_cache_dir_ = std::string(pocl_cache) + "/loomlight-programs";
    if (!std::filesystem::create_directories(rt->binary_cache_dir_, ec) && ec) rt->binary_cache_dir_.clear();
  }
  cl_device_id chosen = nullptr;
  std::string seen;
  // Two passes: the requested platform, or PoCL first and then anything when nothing was requested.
  for (int pass = 0; pass < 2 && !chosen; ++pass) {
    for (cl_platform_id p : platforms) {
      const std::string name = PlatformInfo(p, CL_PLATFORM_NAME), vendor = PlatformInfo(p, CL_PLATFORM_VENDOR);
      if (pass == 0) seen += " '" + name + "'";
      if (!want_platform.empty()) {
        if (!Contains(name, want_platform) && !Contains(vendor, want_platform)) continue;
      } else if (pass == 0 && !Contains(name, "portable computing language")) {
        continue;
      }
      cl_uint nd = 0;
      if (clGetDeviceIDs(p, CL_DEVICE_TYPE_ALL, 0, nullptr, &nd) != CL_SUCCESS || nd == 0) continue;
      std::vector<cl_device_id> devices(nd);
      clGetDeviceIDs(p, CL_DEVICE_TYPE_ALL, nd, devices.data(), nullptr);
      for (cl_device_id d : devices) {
        cl_device_type type = 0;
        clGetDeviceInfo(d, CL_DEVICE_TYPE, sizeof(type), &type, nullptr);
        const std::string dname = DeviceInfo(d, CL_DEVICE_NAME);
        // PoCL's single-threaded `basic` device is only ever the small-launch device, never the main one.
        const bool match = want_device.empty() ? ((type & CL_DEVICE_TYPE_CPU) || pass == 1) && !IsPoclBasic(dname)
                                               : Contains(dname, want_device);
        if (!match) continue;
        rt->platform_ = p;
        chosen = d;
        rt->platform_name_ = name;
        break;
      }
      if (chosen) break;
    }
    if (!want_platform.empty()) break;
  }
  if (!chosen) {
    *error = "no OpenCL device matches platform '" + want_platform + "' device '" + want_device +
             "'; platforms:" + seen;
    return nullptr;
  }
  rt->has_fp64_ = DeviceInfo(chosen, CL_DEVICE_EXTENSIONS).find("cl_khr_fp64") != std::string::npos;
  rt->vector_width_ = options.vector_width;
  if (rt->vector_width_ == 0) {
    cl_uint native = 1;
    clGetDeviceInfo(chosen, CL_DEVICE_NATIVE_VECTOR_WIDTH_FLOAT, sizeof(native), &native, nullptr);
    rt->vector_width_ = 1;
    while (rt->vector_width_ * 2 <= static_cast<int>(native) && rt->vector_width_ < 16) rt->vector_width_ *= 2;
  }
  if (rt->vector_width_ != 1 && rt->vector_width_ != 2 && rt->vector_width_ != 4 && rt->vector_width_ != 8 &&
      rt->vector_width_ != 16) {
    *error = "vector width must be 1, 2, 4, 8 or 16";
    return nullptr;
  }
  if (!rt->main_.Open(chosen, error)) return nullptr;
  // Small launches: PoCL's `basic` device beside its `pthread` one (POCL_DEVICES lists both, set above), one
  // work-item of explicit vectors per work-group (one lane group), so a 1-query launch computes one vector.
  if (options.small_launch_queries > 0 && IsPoclPthread(rt->main_.device_name)) {
    cl_uint nd = 0;
    clGetDeviceIDs(rt->platform_, CL_DEVICE_TYPE_ALL, 0, nullptr, &nd);
    std::vector<cl_device_id> devices(nd);
    if (nd > 0) clGetDeviceIDs(rt->platform_, CL_DEVICE_TYPE_ALL, nd, devices.data(), nullptr);
    for (cl_device_id d : devices) {
      if (!IsPoclBasic(DeviceInfo(d, CL_DEVICE_NAME))) continue;
      rt->small_.local_size = static_cast<size_t>(rt->vector_width_);
      rt->small_.staged = true;
      if (!rt->small_.Open(d, error)) return nullptr;
      rt->small_launch_queries_ = options.small_launch_queries;
      break;
    }
  }
  return rt;
}

bool ClRuntime::Target::Open(cl_device_id d, std::string* error) {
  device = d;
  device_name = DeviceInfo(d, CL_DEVICE_NAME);
  cl_int err = CL_SUCCESS;
  context = clCreateContext(nullptr, 1, &device, nullptr, nullptr, &err);
  if (err != CL_SUCCESS) {
    *error = ClError("clCreateContext", err);
    return false;
  }
  queue = clCreateCommandQueue(context, device, 0, &err);
  if (err != CL_SUCCESS) {
    *error = ClError("clCreateCommandQueue", err);
    return false;
  }
  return true;
}

cl_mem ClRuntime::Staging::Reserve(cl_context context, size_t bytes, cl_int* err) {
  bytes = std::max<size_t>(bytes, sizeof(double));
  if (mem && host.size() * sizeof(double) >= bytes) return mem;
  Release();
  host.assign(std::max(2 * host.size(), (bytes + sizeof(double) - 1) / sizeof(double)), 0.0);
  mem = clCreateBuffer(context, CL_MEM_READ_WRITE | CL_MEM_USE_HOST_PTR, host.size() * sizeof(double), host.data(), err);
  return *err == CL_SUCCESS ? mem : nullptr;
}

void ClRuntime::Staging::Release() {
  if (mem) clReleaseMemObject(mem);
  mem = nullptr;
}

void ClRuntime::Target::Close() {
  for (Staging& s : staging) s.Release();
  for (auto& [key, p] : programs) {
    if (p.kernel) clReleaseKernel(p.kernel);
    if (p.uv_kernel) clReleaseKernel(p.uv_kernel);
    if (p.ambient_kernel) clReleaseKernel(p.ambient_kernel);
    if (p.program) clReleaseProgram(p.program);
  }
  programs.clear();
  if (queue) clReleaseCommandQueue(queue);
  if (context) clReleaseContext(context);
  queue = nullptr;
  context = nullptr;
}

ClRuntime::~ClRuntime() {
  main_.Close();
  small_.Close();
}

bool ClRuntime::Build(Target& target, const models::KernelSpec& spec, bool fp64, Program* out, std::string* error) {
  const std::string& source = spec.source;
  const auto& sources = EmbeddedKernelSources();
  auto it = sources.find(source);
  if (it == sources.end()) {
    *error = "kernel source '" + source + "' is not embedded (add it to KERNEL_ENTRIES in CMakeLists.txt)";
    return false;
  }
  out->width = fp64 ? std::max(1, vector_width_ / 2) : vector_width_;  // doubles are twice as wide
  const size_t items = std::max<size_t>(1, target.local_size / out->width);
  const std::string options = "-cl-std=CL1.2 -DLL_LOCAL_SIZE=" + std::to_string(items) +
                              " -DLL_WIDTH=" + std::to_string(out->width) + (fp64 ? " -DLL_FP64" : "");
  cl_int err = CL_SUCCESS;
  std::string key, binary_path, binary;
  if (!binary_cache_dir_.empty()) {
    key = ProgramBinaryKey(platform_, target.device, options, it->second);
    binary_path = ProgramBinaryPath(binary_cache_dir_, source, options, target.device_name);
    if (ReadProgramBinary(binary_path, key, &binary)) {
      const unsigned char* data = reinterpret_cast<const unsigned char*>(binary.data());
      const size_t size = binary.size();
      cl_int status = CL_SUCCESS;
      out->program = clCreateProgramWithBinary(target.context, 1, &target.device, &size, &data, &status, &err);
      if (err == CL_SUCCESS && status == CL_SUCCESS &&
          clBuildProgram(out->program, 1, &target.device, options.c_str(), nullptr, nullptr) == CL_SUCCESS)
        return CreateKernels(spec, out, error);
      if (out->program) clReleaseProgram(out->program);  // not usable here: built from source below
      out->program = nullptr;
    }
  }
  const char* text = it->second.c_str();
  out->program = clCreateProgramWithSource(target.context, 1, &text, nullptr, &err);
  if (err != CL_SUCCESS) {
    *error = ClError("clCreateProgramWithSource", err);
    return false;
  }
  err = clBuildProgram(out->program, 1, &target.device, options.c_str(), nullptr, nullptr);
  if (err != CL_SUCCESS) {
    size_t size = 0;
    clGetProgramBuildInfo(out->program, target.device, CL_PROGRAM_BUILD_LOG, 0, nullptr, &size);
    std::string log(size, '\0');
    clGetProgramBuildInfo(out->program, target.device, CL_PROGRAM_BUILD_LOG, size, log.data(), nullptr);
    *error = "building " + source + (fp64 ? " (fp64)" : " (fp32)") + " for " + target.device_name + " failed (OpenCL error " +
             std::to_string(err) + "):\n" + log;
    return false;
  }
  if (!binary_path.empty()) WriteProgramBinary(binary_path, key, out->program);
  return CreateKernels(spec, out, error);
}

bool ClRuntime::CreateKernels(const models::KernelSpec& spec, Program* out, std::string* error) {
  for (auto [function, kernel] : {std::pair{&spec.function, &out->kernel}, std::pair{&spec.uv_function, &out->uv_kernel},
                                  std::pair{&spec.ambient_function, &out->ambient_kernel}}) {
    if (function->empty()) continue;
    cl_int err = CL_SUCCESS;
    *kernel = clCreateKernel(out->program, function->c_str(), &err);
    if (err != CL_SUCCESS) {
      *error = ClError(("clCreateKernel " + *function).c_str(), err);
      return false;
    }
  }
  return true;
}

bool ClRuntime::BuildPrograms(const models::Registry& registry, std::string* error) {
  for (Target* target : {&main_, &small_}) {
    if (!target->device) continue;
    for (const auto& model : registry.models()) {
      for (bool fp64 : {false, true}) {
        if (fp64 && !has_fp64_) continue;
        Program& p = target->programs[{model->name(), fp64}];  // owned by the map at once: released on failure
        if (!Build(*target, model->kernel(), fp64, &p, error)) return false;
      }
    }
  }
  return true;
}

bool ClRuntime::Warm(const models::Registry& registry, std::string* error) {
  for (const auto& model : registry.models()) {
    const models::PackedMaterial m = model->Pack(model->DefaultValues());
    const float up[3] = {0, 0, 1}, uv[2] = {0.5f, 0.5f};
    for (bool fp64 : {false, true}) {
      if (fp64 && !has_fp64_) continue;
      for (bool spatial : {false, true}) {
        if (spatial && !model->spatially_varying()) continue;
        // One query (the small-launch device, when there is one) and one launch too large for it.
        for (size_t n : {size_t{1}, small_launch_queries_ + 1}) {
          const std::vector<float> wi = Repeat(up, 3, n), uvs = Repeat(uv, 2, n);
          std::vector<double> f;
          if (!RunSingle(*model, m, fp64, wi.data(), wi.data(), spatial ? uvs.data() : nullptr, n, &f, error))
            return false;
          if (!spatial && model->has_ambient() &&
              !RunSingle(*model, m, fp64, wi.data(), wi.data(), nullptr, n, &f, error, models::Quantity::kAmbient))
            return false;
        }
      }
    }
  }
  return true;
}

bool ClRuntime::RunSingle(const models::Model& model, const models::PackedMaterial& m, bool fp64, const float* wi,
                          const float* wo, const float* uv, size_t n, std::vector<double>* f, std::string* error,
                          models::Quantity quantity, double* kernel_seconds) {
  const std::vector<const models::PackedMaterial*> materials = {&m};
  const LaunchArgs args{.model = &model, .fp64 = fp64, .uniform = m.uniform, .materials = &materials,
                        .material_index = nullptr, .wi = wi, .wo = wo, .uv = uv, .n = n, .quantity = quantity};
  LaunchResults results;
  if (!Run(args, &results, error)) return false;
  if (kernel_seconds) *kernel_seconds = results.kernel_seconds();
  f->resize(3 * n);  // Write sets every value
  results.Write(0, n, ResultSink{.f64 = f->data()}, 0);
  return true;
}

void LaunchResults::Write(size_t first, size_t count, const ResultSink& sink, size_t sink_first) const {
  auto write = [&](const auto* planar, auto* out) {
    for (size_t i = 0; i < count; ++i) {
      const size_t lane = lane_of[first + i];
      const size_t slot = sink.slot ? sink.slot[sink_first + i] : sink_first + i;
      const double scale = sink.scale ? sink.scale[slot] : 1.0;
      for (size_t c = 0; c < 3; ++c) {
        const auto value = planar[c * lanes + lane];
        out[3 * slot + c] = sink.scale ? scale * value : value;  // unscaled: one rounding at most
      }
    }
  };
  if (!f64.empty())
    sink.f32 ? write(f64.data(), sink.f32) : write(f64.data(), sink.f64);
  else
    sink.f32 ? write(f32.data(), sink.f32) : write(f32.data(), sink.f64);
}

bool ClRuntime::Run(const LaunchArgs& a, LaunchResults* results, std::string* error) {
  Target& target = small_.device && a.n <= small_launch_queries_ ? small_ : main_;
  auto it = target.programs.find({a.model->name(), a.fp64});
  if (it == target.programs.end()) {
    *error = "no " + std::string(a.fp64 ? "fp64" : "fp32") + " kernel for model '" + a.model->name() + "'";
    return false;
  }
  const Program& program = it->second;
  const bool ambient = a.quantity == models::Quantity::kAmbient;
  cl_kernel k = ambient ? program.ambient_kernel : a.uv ? program.uv_kernel : program.kernel;
  if (!k) {
    *error = "model '" + a.model->name() + (ambient ? "' has no ambient entry" : "' is not spatially varying");
    return false;
  }
  // Each distinct material once, in the kernel's precision; material m starts at offset[m].
  std::vector<size_t> offset;
  size_t values = 0;
  for (const models::PackedMaterial* m : *a.materials) {
    offset.push_back(values);
    values += m->size();
  }
  if (values > size_t(INT32_MAX)) {
    *error = "materials of one launch exceed 2^31 values";
    return false;
  }
  results->lane_of.clear();
  results->lanes = 0;
  results->f32.clear();
  results->f64.clear();
  if (a.n == 0) return true;
  const size_t width = program.width;
  const size_t items_per_group = std::max<size_t>(1, target.local_size / width);

  // Lanes: each work-item evaluates `width` consecutive lanes of one material, so a run of queries of one
  // material starts at a multiple of the width; the lane count is padded to whole work-groups. Padding
  // lanes look straight up at uv (0, 0), so every lane computes finite values.
  std::vector<size_t>& lane_of = results->lane_of;
  lane_of.resize(a.n);
  std::vector<int> group_offset;  // where each work-item's material starts
  int group_m = -1;
  size_t lanes = 0;
  for (size_t q = 0; q < a.n; ++q) {
    const int m = a.material_index ? (*a.material_index)[q] : 0;
    if (lanes % width != 0 && m != group_m) lanes += width - lanes % width;
    if (lanes % width == 0) {
      group_offset.push_back(static_cast<int>(offset[m]));
      group_m = m;
    }
    lane_of[q] = lanes++;
  }
  // One material: its queries may take the lanes in any order, and the model may choose one that reads its
  // tables with more locality (Model::LocalityOrder); the copies in and out follow lane_of either way.
  const bool reordered = a.materials->size() == 1 && !ambient && a.model->LocalityOrder(a.wo, a.uv, a.n, lane_of.data());
  const size_t lanes_per_group = width * items_per_group;
  lanes = (lanes + lanes_per_group - 1) / lanes_per_group * lanes_per_group;
  group_offset.resize(lanes / width, 0);
  std::vector<float> wi(3 * lanes, 0.0f), wo(3 * lanes, 0.0f);  // planar: x, y, z blocks
  std::fill(wi.begin() + 2 * lanes, wi.end(), 1.0f);
  std::fill(wo.begin() + 2 * lanes, wo.end(), 1.0f);
  std::vector<float> uv(a.uv ? 2 * lanes : 1, 0.0f);  // planar u, v; one dummy value for f(wi, wo)
  // Reordered lanes are filled in lane order (reading each query's few bytes where they lie), not scattered
  // over the eight planes, which would touch eight lines per query.
  std::vector<size_t> query_of_lane;
  if (reordered) {
    query_of_lane.resize(a.n);
    for (size_t q = 0; q < a.n; ++q) query_of_lane[lane_of[q]] = q;
  }
  for (size_t i = 0; i < a.n; ++i) {
    const size_t q = reordered ? query_of_lane[i] : i, lane = reordered ? i : lane_of[q];
    for (size_t c = 0; c < 3; ++c) {
      wi[c * lanes + lane] = a.wi[3 * q + c];
      wo[c * lanes + lane] = a.wo[3 * q + c];
    }
    if (a.uv)
      for (size_t c = 0; c < 2; ++c) uv[c * lanes + lane] = a.uv[2 * q + c];
  }
  const size_t real_size = a.fp64 ? sizeof(double) : sizeof(float);
  // One material is read where it lies; several are concatenated once.
  std::vector<char> concatenated;
  const void* materials_ptr = a.fp64 ? static_cast<const void*>(a.materials->front()->values64())
                                     : static_cast<const void*>(a.materials->front()->values32());
  if (a.materials->size() > 1) {
    concatenated.resize(values * real_size);
    for (size_t m = 0; m < a.materials->size(); ++m) {
      const models::PackedMaterial& p = *(*a.materials)[m];
      const void* from = a.fp64 ? static_cast<const void*>(p.values64()) : static_cast<const void*>(p.values32());
      std::memcpy(concatenated.data() + offset[m] * real_size, from, p.size() * real_size);
    }
    materials_ptr = concatenated.data();
  }

  std::lock_guard<std::mutex> lock(target.launch_mutex);
  cl_int err = CL_SUCCESS;
  Buffers b;
  // The six arguments' buffers: new ones holding copies (large launches), or the target's staging, filled here.
  size_t next = 0;
  auto make = [&](size_t bytes, const void* host, cl_mem_flags flags) -> cl_mem {
    if (target.staged) {
      Staging& s = target.staging[next++];
      cl_mem m = s.Reserve(target.context, bytes, &err);
      if (m && host) std::memcpy(s.host.data(), host, bytes);
      return m;
    }
    cl_mem m = clCreateBuffer(target.context, flags | (host ? CL_MEM_COPY_HOST_PTR : 0), bytes, const_cast<void*>(host), &err);
    b.mems.push_back(m);
    return m;
  };
  // A large material (a BTF asset, tens of MB) is read where it lies (on a CPU device, without a copy; the
  // launch ends before Run returns): copying it per launch would cost more than a small launch's kernel.
  const size_t material_bytes = std::max<size_t>(1, values) * real_size;
  cl_mem mat = nullptr;
  if (material_bytes >= kLargeMaterialBytes && a.materials->size() == 1) {
    mat = clCreateBuffer(target.context, CL_MEM_READ_ONLY | CL_MEM_USE_HOST_PTR, material_bytes,
                         const_cast<void*>(materials_ptr), &err);
    b.mems.push_back(mat);
    ++next;  // its staging slot stays unused
    if (err != CL_SUCCESS) {
      *error = ClError("clCreateBuffer", err);
      return false;
    }
  } else {
    mat = make(material_bytes, values ? materials_ptr : nullptr, CL_MEM_READ_ONLY);
  }
  cl_mem idx = make(group_offset.size() * sizeof(int), group_offset.data(), CL_MEM_READ_ONLY);
  cl_mem bwi = make(wi.size() * sizeof(float), wi.data(), CL_MEM_READ_ONLY);
  cl_mem bwo = make(wo.size() * sizeof(float), wo.data(), CL_MEM_READ_ONLY);
  cl_mem buv = make(uv.size() * sizeof(float), uv.data(), CL_MEM_READ_ONLY);
  cl_mem out = make(3 * lanes * real_size, nullptr, CL_MEM_WRITE_ONLY);
  if (err != CL_SUCCESS) {
    *error = ClError("clCreateBuffer", err);
    return false;
  }
  const cl_int uniform = a.uniform, nlanes = static_cast<cl_int>(lanes);
  clSetKernelArg(k, 0, sizeof(cl_mem), &mat);
  clSetKernelArg(k, 1, sizeof(cl_int), &uniform);
  clSetKernelArg(k, 2, sizeof(cl_mem), &idx);
  clSetKernelArg(k, 3, sizeof(cl_mem), &bwi);
  clSetKernelArg(k, 4, sizeof(cl_mem), &bwo);
  clSetKernelArg(k, 5, sizeof(cl_mem), &buv);
  clSetKernelArg(k, 6, sizeof(cl_mem), &out);
  clSetKernelArg(k, 7, sizeof(cl_int), &nlanes);
  const size_t global = lanes / width;
  const auto enqueued = std::chrono::steady_clock::now();
  err = clEnqueueNDRangeKernel(target.queue, k, 1, nullptr, &global, &items_per_group, 0, nullptr, nullptr);
  if (err != CL_SUCCESS) {
    *error = ClError("clEnqueueNDRangeKernel", err);
    return false;
  }
  results->lanes = lanes;
  err = clFinish(target.queue);
  results->kernel_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - enqueued).count();
  if (err != CL_SUCCESS) {
    *error = ClError("clFinish", err);
    return false;
  }
  if (target.staged) {  // the kernel wrote into the staging's host memory (the device is this CPU)
    const char* host = reinterpret_cast<const char*>(target.staging[5].host.data());
    if (a.fp64) {
      results->f64.resize(3 * lanes);
      std::memcpy(results->f64.data(), host, 3 * lanes * sizeof(double));
    } else {
      results->f32.resize(3 * lanes);
      std::memcpy(results->f32.data(), host, 3 * lanes * sizeof(float));
    }
  } else if (a.fp64) {
    results->f64.resize(3 * lanes);
    err = clEnqueueReadBuffer(target.queue, out, CL_TRUE, 0, 3 * lanes * sizeof(double), results->f64.data(), 0, nullptr,
                              nullptr);
  } else {
    results->f32.resize(3 * lanes);
    err = clEnqueueReadBuffer(target.queue, out, CL_TRUE, 0, 3 * lanes * sizeof(float), results->f32.data(), 0, nullptr,
                              nullptr);
  }
  if (err != CL_SUCCESS) {
    *error = ClError("clEnqueueReadBuffer", err);
    return false;
  }
  return true;
}

}  // namespace loomlight::runtime
