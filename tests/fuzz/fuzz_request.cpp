// Fuzz target: request validation and planning, the server's code between a request's bytes and a plan or a
// gRPC error, without an OpenCL device. Input: byte 0 picks the RPC (bits 0-1: Evaluate, Sample, Tabulate,
// Render; bit 3 set: CreateBtf instead; bit 4 set: FitMaterial instead) and the device (bit 2 set: a device without
// fp64); the rest is that RPC's request, protobuf-encoded.
//
// Each RPC runs its handler's checks in the handler's order: the material (MaterialCache::Peek, which resolves it
// as Get does, without packing), then the request's Check* functions (server/api/). A rejection must be
// INVALID_ARGUMENT (FAILED_PRECONDITION only for fp64 on a device without it) with a bounded, one-line message
// that names the field. An accepted request is planned as the server would: Evaluate's material packed and its
// EvaluationPlan built and evaluated on the host (every query in exactly one part, transmittances in [0, 1], f
// finite and not negative); Tabulate's grid walked at its ends (unit directions); Render's fiber job present
// exactly for fiber scenes. Under ASan and UBSan (scripts/fuzz.sh) any memory error or undefined behaviour on the
// way is a crash.
//
// A structure-aware mutator (LLVMFuzzerCustomMutator below) edits parsed requests through protobuf reflection,
// with the registry's names as a dictionary, so mutations keep a valid encoding and reach past the parser.
#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <google/protobuf/stubs/logging.h>

#include "loomlight/v1/loomlight.pb.h"
#include "server/api/btf_rpc.h"
#include "server/api/fit_rpc.h"
#include "server/api/render_rpc.h"
#include "server/api/sample_rpc.h"
#include "server/api/service.h"
#include "server/api/tabulate.h"
#include "server/api/yarn_rpc.h"
#include "server/models/material_cache.h"
#include "server/models/material_plan.h"
#include "server/render/scene_registry.h"
#include "tests/fuzz/fuzz_check.h"

extern "C" size_t LLVMFuzzerMutate(uint8_t* data, size_t size, size_t max_size);

namespace loomlight::fuzz {
namespace {

using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

enum class Rpc { kEvaluate, kSample, kTabulate, kRender, kCreateBtf, kFitMaterial };
constexpr uint8_t kRpcMask = 3;
constexpr uint8_t kNoFp64Bit = 4;
constexpr uint8_t kCreateBtfBit = 8;
constexpr uint8_t kFitMaterialBit = 16;

Rpc RpcOf(uint8_t first) {
  if (first & kFitMaterialBit) return Rpc::kFitMaterial;
  return first & kCreateBtfBit ? Rpc::kCreateBtf : static_cast<Rpc>(first & kRpcMask);
}
// Queries evaluated on the host per accepted Evaluate: enough to reach every part of a plan, few enough to keep
// the fuzzer fast.
constexpr size_t kMaxEvaluatedQueries = 64;

std::unique_ptr<Message> NewRequest(Rpc rpc) {
  switch (rpc) {
    case Rpc::kEvaluate: return std::make_unique<v1::EvaluateRequest>();
    case Rpc::kSample: return std::make_unique<v1::SampleRequest>();
    case Rpc::kTabulate: return std::make_unique<v1::TabulateRequest>();
    case Rpc::kRender: return std::make_unique<v1::RenderRequest>();
    case Rpc::kCreateBtf: return std::make_unique<v1::CreateBtfRequest>();
    case Rpc::kFitMaterial: return std::make_unique<v1::FitMaterialRequest>();
  }
  return nullptr;
}

// The server's material cache, kept across inputs as the server keeps it across calls.
models::MaterialCache& Cache() {
  static models::MaterialCache cache(api::ServiceLimits{}.material_cache_bytes);
  return cache;
}
const models::Registry& Registry() { return models::Registry::Global(); }

// "field: reason", the field spelled as in the request ("material.params[2].values[0]", "lights[1].rgb", "grid").
bool NamesAField(const std::string& message) {
  const size_t colon = message.find(": ");
  if (colon == std::string::npos || colon == 0) return false;
  return std::all_of(message.begin(), message.begin() + colon, [](char c) {
    return std::islower(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) || c == '_' ||
           c == '.' || c == '[' || c == ']';
  });
}

void CheckRejection(const grpc::Status& status, bool has_fp64) {
  const grpc::StatusCode code = status.error_code();
  FUZZ_CHECK(code == grpc::StatusCode::INVALID_ARGUMENT || (code == grpc::StatusCode::FAILED_PRECONDITION && !has_fp64),
             "code " + std::to_string(code) + ": " + status.error_message());
  FUZZ_CHECK(MessageDefect(status.error_message()).empty(),
             MessageDefect(status.error_message()) + ": " + status.error_message());
  FUZZ_CHECK(NamesAField(status.error_message()), status.error_message());
}
void CheckRejection(const std::string& invalid_argument) {
  CheckRejection(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, invalid_argument), true);
}

// The handlers' first step: the material resolved (MaterialCache::Peek). *model is null when it was rejected.
void ResolveMaterial(const v1::Material& material, const models::Model** model) {
  std::shared_ptr<const models::PreparedMaterial> cached;
  *model = nullptr;
  if (std::string error = Cache().Peek(material, Registry(), model, &cached); !error.empty()) {
    *model = nullptr;
    CheckRejection(error);
  }
}

bool Finite(double v) { return std::isfinite(v); }

// An accepted Evaluate: packed (MaterialCache::Get, as EvaluateCall::Start), planned and evaluated on the host.
void PlanEvaluate(const v1::EvaluateRequest& request) {
  std::shared_ptr<const models::PreparedMaterial> material;
  const std::string error = Cache().Get(request.material(), Registry(), &material);
  FUZZ_CHECK(error.empty(), "Peek accepted the material, Get refused it: " + error);
  const size_t n = request.wo_size() / 3;
  const bool ambient = request.quantity() == v1::QUANTITY_AMBIENT;
  const models::EvaluationPlan plan(*material, request.wi().data(), request.wo().data(),
                                    request.uv_size() > 0 ? request.uv().data() : nullptr, n,
                                    request.fiber_axis_size() > 0 ? request.fiber_axis().data() : nullptr,
                                    ambient ? models::Quantity::kAmbient : models::Quantity::kScattering);
  std::vector<int> covered(n, 0);
  for (size_t k = 0; k < plan.parts(); ++k)
    for (size_t i = 0; i < plan.size(k); ++i) {
      const size_t q = plan.slots(k) ? plan.slots(k)[i] : i;
      FUZZ_CHECK(q < n, "part " + std::to_string(k) + " names query " + std::to_string(q) + " of " + std::to_string(n));
      ++covered[q];
    }
  FUZZ_CHECK(std::all_of(covered.begin(), covered.end(), [](int c) { return c == 1; }),
             "a query is in no part or in two");
  for (double t : plan.transmittance()) FUZZ_CHECK(t >= 0 && t <= 1, "transmittance " + std::to_string(t));
  if (n > kMaxEvaluatedQueries) return;
  std::vector<double> f(3 * n);
  models::EvaluateNative(plan, f.data());
  for (size_t i = 0; i < f.size(); ++i)  // f is a density of scattered light: finite and never negative
    FUZZ_CHECK(Finite(f[i]) && f[i] >= 0, material->model->name() + " f[" + std::to_string(i) + "] = " + std::to_string(f[i]));
}

void FuzzEvaluate(const v1::EvaluateRequest& request, bool has_fp64) {
  if (grpc::Status s = api::CheckEvaluateRequest(request, has_fp64); !s.ok()) return CheckRejection(s, has_fp64);
  const models::Model* model = nullptr;
  ResolveMaterial(request.material(), &model);
  if (!model) return;
  if (std::string error = api::CheckEvaluateQueries(request, *model, request.material().has_transmission());
      !error.empty())
    return CheckRejection(error);
  PlanEvaluate(request);
}

void FuzzSample(const v1::SampleRequest& request, bool has_fp64) {
  if (grpc::Status s = api::CheckSampleRequest(request, has_fp64); !s.ok()) return CheckRejection(s, has_fp64);
  const models::Model* model = nullptr;
  ResolveMaterial(request.material(), &model);
  if (!model) return;
  if (std::string error = api::CheckSampleQueries(request, *model); !error.empty()) return CheckRejection(error);
}

void CheckUnit(const float* w, const std::string& what) {
  const double length = std::sqrt(double(w[0]) * w[0] + double(w[1]) * w[1] + double(w[2]) * w[2]);
  FUZZ_CHECK(std::fabs(length - 1) < 1e-5, what + " has length " + std::to_string(length));
}

void FuzzTabulate(const v1::TabulateRequest& request, bool has_fp64) {
  const models::Model* model = nullptr;
  ResolveMaterial(request.material(), &model);
  if (!model) return;
  api::TabulationGrid grid;
  if (grpc::Status s = api::CheckTabulateRequest(request, *model, has_fp64, &grid); !s.ok())
    return CheckRejection(s, has_fp64);
  uint64_t cells = 1;
  for (uint32_t d : grid.dims()) cells *= d;
  FUZZ_CHECK(cells == grid.cells() && cells >= 1, "cells " + std::to_string(grid.cells()));
  FUZZ_CHECK(grid.queries() <= api::kMaxTabulateQueries, "queries " + std::to_string(grid.queries()));
  FUZZ_CHECK(grid.row_cells() >= 1 && grid.cells() % grid.row_cells() == 0, "row cells " + std::to_string(grid.row_cells()));
  for (const uint64_t q : {uint64_t{0}, grid.queries() / 2, grid.queries() - 1}) {
    float wi[3], wo[3];
    grid.Directions(q, wi, wo);
    CheckUnit(wi, "wi of query " + std::to_string(q));
    CheckUnit(wo, "wo of query " + std::to_string(q));
    const std::vector<double> angles = grid.CellAngles(q / grid.queries_per_cell());
    FUZZ_CHECK(angles.size() == grid.angle_names().size() && std::all_of(angles.begin(), angles.end(), Finite),
               "cell angles of query " + std::to_string(q));
  }
  FUZZ_CHECK(api::TabulateBytes(request, grid) > 0, "no bytes admitted");
  std::string header;
  api::MakeTableEncoder(request.format(), grid, request.precision() == v1::PRECISION_FP64)->Begin(&header);
}

void FuzzRender(const v1::RenderRequest& request, bool has_fp64) {
  const models::Model* model = nullptr;
  ResolveMaterial(request.material(), &model);
  if (!model) return;
  api::FiberJobs fiber_jobs;
  render::RenderSetup::FiberDetail detail;
  if (grpc::Status s = api::CheckRenderRequest(Registry(), request, *model, has_fp64, &fiber_jobs, &detail); !s.ok())
    return CheckRejection(s, has_fp64);
  const std::unique_ptr<api::YarnJob>& fiber_job = fiber_jobs.chosen;
  FUZZ_CHECK(!fiber_jobs.full || (fiber_job && fiber_jobs.full->detail.footprint == 0),
             "a full-detail job to check against without a chosen one, or not at full detail");
  // A fiber scene (one the request names by its scene_name or its scene value) and only one has fibers to generate.
  render::ResolvedScene scene;
  FUZZ_CHECK(render::ResolveScene(request, render::SceneRegistry::Global(), &scene).empty(), "an accepted scene");
  const bool fiber_scene = scene.spec->needs.fibers;
  FUZZ_CHECK(bool(fiber_job) == fiber_scene, "fiber job " + std::to_string(bool(fiber_job)) + " for scene " +
                                                 scene.spec->name);
  FUZZ_CHECK(!fiber_scene || !detail.chosen.empty(), "a fiber scene without a level of detail");
  const uint64_t pixels = uint64_t{request.width()} * request.height();
  FUZZ_CHECK(pixels >= 1 && request.width() <= api::kMaxRenderSide && request.height() <= api::kMaxRenderSide,
             std::to_string(request.width()) + " x " + std::to_string(request.height()));
  FUZZ_CHECK(api::RenderBytes(request) >= pixels, "admits less than a byte a pixel");
}

void FuzzCreateBtf(const v1::CreateBtfRequest& request) {
  api::BtfJob job;
  std::unique_ptr<api::FiberSource> fibers;
  size_t bytes = 0;
  if (grpc::Status s = api::CheckCreateBtfRequest(Registry(), request, &job, &fibers, &bytes); !s.ok())
    return CheckRejection(s, true);
  const models::Model* model = nullptr;
  ResolveMaterial(request.material(), &model);
  const size_t n = job.grid.size();
  FUZZ_CHECK(n >= 1 && n <= models::btf::kMaxGridDirections, std::to_string(n) + " directions");
  FUZZ_CHECK(job.width >= 1 && job.width <= int(api::kMaxBtfTexels) && job.height == job.width,
             std::to_string(job.width) + " x " + std::to_string(job.height) + " texels");
  FUZZ_CHECK(job.compression.max_components >= 1 && job.compression.max_components <= models::btf::kMaxComponents,
             std::to_string(job.compression.max_components) + " components");
  // Admitted: at least the images in float.
  FUZZ_CHECK(bytes >= n * n * 3 * size_t(job.width) * job.height * sizeof(float), "admits less than its images");
  FUZZ_CHECK(bool(fibers) == request.has_fibers(), "fiber source " + std::to_string(bool(fibers)));
  if (!fibers) return;
  FUZZ_CHECK(fibers->samples >= 1 && fibers->samples <= 64, std::to_string(fibers->samples) + " rays per texel");
  // The patch holds the 3 x 3 repeats around the tile: a weave's, or a knit's stitches with a course to spare.
  const yarn::YarnJob& patch = fibers->yarn;
  if (request.fibers().has_knit())
    FUZZ_CHECK(patch.kind == yarn::YarnLayoutKind::kKnit && patch.knit.wales == api::kKnitPatchWales &&
                   patch.knit.courses == api::kKnitPatchCourses,
               "the knit patch is not " + std::to_string(api::kKnitPatchWales) + " x " +
                   std::to_string(api::kKnitPatchCourses) + " stitches");
  else
    FUZZ_CHECK(patch.kind == yarn::YarnLayoutKind::kWoven && patch.layout.repeats_u == 3 && patch.layout.repeats_v == 3,
               "the fiber patch is not 3 x 3 repeats");
  for (size_t v = 0; v < n; ++v) {
    double w[3];
    job.grid.Direction(v, w);
    CheckUnit(std::array<float, 3>{float(w[0]), float(w[1]), float(w[2])}.data(), "grid direction " + std::to_string(v));
    FUZZ_CHECK(w[2] > 0, "grid direction " + std::to_string(v) + " below the surface");
  }
}

// ---- The structure-aware mutator ----

// Names the registry and the yarn model know (presets, models, parameters), and a few texts worth trying in a
// string field: a WIF draft for text parameters, environment names that must be refused.
const std::vector<std::string>& Dictionary() {
  static const std::vector<std::string> words = [] {
    std::vector<std::string> w;
    for (const auto& model : Registry().models()) {
      w.push_back(model->name());
      for (const models::PresetSpec& p : model->presets()) w.push_back(p.name);
      for (const models::ParamSpec& p : model->params()) w.push_back(p.name);
    }
    v1::YarnModelInfo yarn;
    api::DescribeYarnModel(&yarn);
    for (const v1::Preset& p : yarn.presets()) w.push_back(p.name());
    for (const v1::ParamSchema& p : yarn.params()) w.push_back(p.name());
    w.push_back(
        "[WIF]\nVersion=1.1\n[CONTENTS]\nWEAVING=yes\nTHREADING=yes\nLIFTPLAN=yes\n[WEAVING]\nShafts=2\n"
        "[THREADING]\n1=1\n2=2\n[LIFTPLAN]\n1=1\n2=2\n");
    for (const char* s : {"studio", "../studio", "/etc/passwd", "studio.hdr", "", "\xff\xfe"}) w.push_back(s);
    return w;
  }();
  return words;
}

class Mutator {
 public:
  explicit Mutator(unsigned seed) : rng_(seed) {}

  // Changes one field somewhere in `message`; false when it has none.
  bool Mutate(Message* message) {
    std::vector<std::pair<Message*, const FieldDescriptor*>> fields;
    Collect(message, 0, &fields);
    if (fields.empty()) return false;
    const auto& [owner, field] = fields[Below(fields.size())];
    if (field->is_repeated())
      MutateRepeated(owner, field);
    else
      MutateSingular(owner, field);
    return true;
  }

 private:
  size_t Below(size_t n) { return std::uniform_int_distribution<size_t>(0, n - 1)(rng_); }

  // Every field of the message and of the messages set in it (a few levels deep: Material.transmission nests).
  void Collect(Message* m, int depth, std::vector<std::pair<Message*, const FieldDescriptor*>>* out) {
    const Reflection* r = m->GetReflection();
    for (int i = 0; i < m->GetDescriptor()->field_count(); ++i) {
      const FieldDescriptor* f = m->GetDescriptor()->field(i);
      out->push_back({m, f});
      if (f->cpp_type() != FieldDescriptor::CPPTYPE_MESSAGE || depth >= 4) continue;
      if (f->is_repeated()) {
        for (int k = 0; k < r->FieldSize(*m, f); ++k) Collect(r->MutableRepeatedMessage(m, f, k), depth + 1, out);
      } else if (r->HasField(*m, f)) {
        Collect(r->MutableMessage(m, f), depth + 1, out);
      }
    }
  }

  int64_t Integer(int64_t current) {
    static constexpr int64_t kEdges[] = {0, 1, 2, 3, 4, 8, 16, 90, 180, 255, 256, 257, 1024, 2048, 2049,
                                         1 << 20, (1 << 20) + 1, std::numeric_limits<int32_t>::max(), -1};
    switch (Below(3)) {
      case 0: return kEdges[Below(std::size(kEdges))];
      case 1: return current + (Below(2) ? 1 : -1);
      default: return static_cast<int64_t>(Below(1000));
    }
  }

  double Real(double current) {
    static constexpr double kEdges[] = {0, -0.0, 1, -1, 0.5, 1e-4, 1e-310, 90, 180, 360, 361, 1024, 1e5, 1e9, 1e300,
                                        std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::infinity(),
                                        -std::numeric_limits<double>::infinity()};
    switch (Below(3)) {
      case 0: return kEdges[Below(std::size(kEdges))];
      case 1: return current * (1 + std::uniform_real_distribution<double>(-1e-4, 1e-4)(rng_));
      default: return std::uniform_real_distribution<double>(-2, 2)(rng_);
    }
  }

  std::string Text(const std::string& current) {
    if (Below(2)) return Dictionary()[Below(Dictionary().size())];
    std::string bytes = current.empty() ? std::string(1, 'a') : current;  // libFuzzer mutates at least a byte
    const size_t size = bytes.size(), max_size = std::max<size_t>(2 * size, 64);
    bytes.resize(max_size);
    bytes.resize(LLVMFuzzerMutate(reinterpret_cast<uint8_t*>(bytes.data()), size, max_size));
    return bytes;
  }

  void MutateSingular(Message* m, const FieldDescriptor* f) {
    const Reflection* r = m->GetReflection();
    switch (f->cpp_type()) {
      case FieldDescriptor::CPPTYPE_INT32: return r->SetInt32(m, f, static_cast<int32_t>(Integer(r->GetInt32(*m, f))));
      case FieldDescriptor::CPPTYPE_INT64: return r->SetInt64(m, f, Integer(r->GetInt64(*m, f)));
      case FieldDescriptor::CPPTYPE_UINT32:
        return r->SetUInt32(m, f, static_cast<uint32_t>(Integer(r->GetUInt32(*m, f))));
      case FieldDescriptor::CPPTYPE_UINT64:
        return r->SetUInt64(m, f, static_cast<uint64_t>(Integer(static_cast<int64_t>(r->GetUInt64(*m, f)))));
      case FieldDescriptor::CPPTYPE_DOUBLE: return r->SetDouble(m, f, Real(r->GetDouble(*m, f)));
      case FieldDescriptor::CPPTYPE_FLOAT: return r->SetFloat(m, f, static_cast<float>(Real(r->GetFloat(*m, f))));
      case FieldDescriptor::CPPTYPE_BOOL: return r->SetBool(m, f, !r->GetBool(*m, f));
      case FieldDescriptor::CPPTYPE_ENUM:  // open enums: unknown numbers too
        return r->SetEnumValue(m, f, static_cast<int>(Below(f->enum_type()->value_count() + 2)) - 1);
      case FieldDescriptor::CPPTYPE_STRING: return r->SetString(m, f, Text(r->GetString(*m, f)));
      case FieldDescriptor::CPPTYPE_MESSAGE:
        if (r->HasField(*m, f) && Below(2)) return r->ClearField(m, f);
        r->MutableMessage(m, f);  // set (in a oneof: switches the case)
        return;
    }
  }

  // Adds, drops or changes an element; a float list (packed directions, uv, random numbers) may also get a
  // whole unit direction, so that it stays a valid list of triples.
  void MutateRepeated(Message* m, const FieldDescriptor* f) {
    const Reflection* r = m->GetReflection();
    const int size = r->FieldSize(*m, f);
    const size_t action = Below(4);
    if (action == 0 && size > 0) return r->RemoveLast(m, f);
    if (action == 1 && f->cpp_type() == FieldDescriptor::CPPTYPE_FLOAT) {
      std::normal_distribution<double> normal;
      const double x = normal(rng_), y = normal(rng_), z = normal(rng_), length = std::hypot(x, y, z);
      for (double c : {x, y, z}) r->AddFloat(m, f, static_cast<float>(length > 0 ? c / length : 1));
      return;
    }
    if (action == 2 && size > 0) {
      const int i = static_cast<int>(Below(size));
      switch (f->cpp_type()) {
        case FieldDescriptor::CPPTYPE_UINT32:
          return r->SetRepeatedUInt32(m, f, i, static_cast<uint32_t>(Integer(r->GetRepeatedUInt32(*m, f, i))));
        case FieldDescriptor::CPPTYPE_DOUBLE: return r->SetRepeatedDouble(m, f, i, Real(r->GetRepeatedDouble(*m, f, i)));
        case FieldDescriptor::CPPTYPE_FLOAT:
          return r->SetRepeatedFloat(m, f, i, static_cast<float>(Real(r->GetRepeatedFloat(*m, f, i))));
        case FieldDescriptor::CPPTYPE_STRING: return r->SetRepeatedString(m, f, i, Text(r->GetRepeatedString(*m, f, i)));
        default: break;  // messages are mutated through their own fields
      }
    }
    switch (f->cpp_type()) {
      case FieldDescriptor::CPPTYPE_INT32: return r->AddInt32(m, f, static_cast<int32_t>(Integer(0)));
      case FieldDescriptor::CPPTYPE_UINT32: return r->AddUInt32(m, f, static_cast<uint32_t>(Integer(0)));
      case FieldDescriptor::CPPTYPE_INT64: return r->AddInt64(m, f, Integer(0));
      case FieldDescriptor::CPPTYPE_UINT64: return r->AddUInt64(m, f, static_cast<uint64_t>(Integer(0)));
      case FieldDescriptor::CPPTYPE_DOUBLE: return r->AddDouble(m, f, Real(0));
      case FieldDescriptor::CPPTYPE_FLOAT: return r->AddFloat(m, f, static_cast<float>(Real(0)));
      case FieldDescriptor::CPPTYPE_BOOL: return r->AddBool(m, f, Below(2));
      case FieldDescriptor::CPPTYPE_ENUM: return r->AddEnumValue(m, f, static_cast<int>(Below(4)));
      case FieldDescriptor::CPPTYPE_STRING: return r->AddString(m, f, Text(""));
      case FieldDescriptor::CPPTYPE_MESSAGE: r->AddMessage(m, f); return;
    }
  }

  std::mt19937_64 rng_;
};

// FitMaterial's checks (api::CheckFitMaterialRequest, which resolves every material as Peek does). Accepted: a
// target and a format that go together, at most kMaxColourways named once each and within their bytes, a mesh
// only with a glTF, and every fabric's material resolving to a surface model.
void FuzzFitMaterial(const v1::FitMaterialRequest& request) {
  if (grpc::Status s = api::CheckFitMaterialRequest(&Cache(), Registry(), request); !s.ok())
    return CheckRejection(s, true);
  const bool gltf = request.format() == v1::EXPORT_FORMAT_GLB || request.format() == v1::EXPORT_FORMAT_GLTF;
  FUZZ_CHECK(request.target() == v1::FIT_TARGET_GLTF_SHEEN || request.target() == v1::FIT_TARGET_OPENPBR,
             "target " + std::to_string(request.target()));
  FUZZ_CHECK(!gltf || request.target() == v1::FIT_TARGET_GLTF_SHEEN, "a glTF of an OpenPBR fit");
  FUZZ_CHECK(request.format() != v1::EXPORT_FORMAT_MTLX || request.target() == v1::FIT_TARGET_OPENPBR,
             "MaterialX of a glTF fit");
  FUZZ_CHECK(!request.has_mesh() || gltf, "a mesh without a glTF");
  FUZZ_CHECK(request.colourways_size() <= api::kMaxColourways, std::to_string(request.colourways_size()));
  FUZZ_CHECK(request.name().size() <= api::kMaxFitNameBytes, std::to_string(request.name().size()) + " bytes");
  std::vector<const v1::Material*> fabrics;
  const auto wear = [&](const v1::Material& m, bool has, const auto& bindings) {
    if (has) fabrics.push_back(&m);
    for (const v1::MaterialBinding& b : bindings) fabrics.push_back(&b.material());
  };
  wear(request.material(), request.has_material(), request.bindings());
  for (const v1::Colourway& way : request.colourways()) {
    FUZZ_CHECK(!way.name().empty() && way.name().size() <= api::kMaxFitNameBytes, "colourway name");
    wear(way.material(), way.has_material(), way.bindings());
  }
  FUZZ_CHECK(!fabrics.empty(), "accepted without a fabric");
  for (const v1::Material* m : fabrics) {
    const models::Model* model = nullptr;
    std::shared_ptr<const models::PreparedMaterial> cached;
    FUZZ_CHECK(Cache().Peek(*m, Registry(), &model, &cached).empty(), "an accepted fabric does not resolve");
    FUZZ_CHECK(model && model->fiber_axis_param().empty(), "a fiber model accepted");
  }
}

}  // namespace
}  // namespace loomlight::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace loomlight::fuzz;
  // Strings that are not UTF-8 fail to parse, as gRPC would refuse them; protobuf's log line for each is noise.
  static const google::protobuf::LogSilencer quiet_protobuf;
  if (size == 0) return 0;
  const Rpc rpc = RpcOf(data[0]);
  const bool has_fp64 = (data[0] & kNoFp64Bit) == 0;
  std::unique_ptr<Message> request = NewRequest(rpc);
  if (!request->ParseFromArray(data + 1, static_cast<int>(size - 1))) return 0;  // gRPC would refuse it earlier
  using namespace loomlight;
  switch (rpc) {
    case Rpc::kEvaluate: FuzzEvaluate(static_cast<v1::EvaluateRequest&>(*request), has_fp64); break;
    case Rpc::kSample: FuzzSample(static_cast<v1::SampleRequest&>(*request), has_fp64); break;
    case Rpc::kTabulate: FuzzTabulate(static_cast<v1::TabulateRequest&>(*request), has_fp64); break;
    case Rpc::kRender: FuzzRender(static_cast<v1::RenderRequest&>(*request), has_fp64); break;
    case Rpc::kCreateBtf: FuzzCreateBtf(static_cast<v1::CreateBtfRequest&>(*request)); break;
    case Rpc::kFitMaterial: FuzzFitMaterial(static_cast<v1::FitMaterialRequest&>(*request)); break;
  }
  return 0;
}

// Half the time, and whenever the input does not parse, libFuzzer's byte mutations (they also find what a
// parsed mutation cannot: broken encodings); otherwise one field changed through reflection.
extern "C" size_t LLVMFuzzerCustomMutator(uint8_t* data, size_t size, size_t max_size, unsigned seed) {
  using namespace loomlight::fuzz;
  Mutator mutator(seed);
  std::unique_ptr<Message> request;
  if (size > 0 && seed % 2 == 0) {
    request = NewRequest(RpcOf(data[0]));
    if (!request->ParseFromArray(data + 1, static_cast<int>(size - 1)) || !mutator.Mutate(request.get()))
      request.reset();
  }
  if (!request) return LLVMFuzzerMutate(data, size, max_size);
  std::string bytes(1, static_cast<char>(data[0]));
  request->AppendToString(&bytes);
  if (bytes.size() > max_size) return LLVMFuzzerMutate(data, size, max_size);
  std::memcpy(data, bytes.data(), bytes.size());
  return bytes.size();
}
