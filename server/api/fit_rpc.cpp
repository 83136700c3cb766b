#include "server/api/fit_rpc.h"

#include <algorithm>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "server/api/access.h"
#include "server/api/admission.h"
#include "server/api/host_worker.h"
#include "server/api/job_status.h"
#include "server/api/mesh_rpc.h"
#include "server/api/unary_call.h"
#include "server/export/gltf_export.h"
#include "server/export/mtlx_export.h"
#include "server/models/fit/lobe_fit.h"
#include "server/models/material_cache.h"
#include "server/models/quote.h"

namespace loomlight::api {
namespace {
using batching::Clock;
constexpr const char* kRpc = "FitMaterial";
// What a call holds beside its mesh: the fit's direction pairs and f (4096 pairs, a few arrays of doubles), the
// Jacobian of one fit, the response.
constexpr size_t kFitCallBytes = size_t{4} << 20;
// What an export holds per triangle of its mesh (positions, normals, uvs, tangents of its corners and the index,
// in the model and in the file's buffer, then the file in the response) and beside them.
constexpr size_t kExportBytesPerTriangle = 3 * 2 * (12 + 12 + 8 + 16) + 2 * 12;
constexpr size_t kExportBaseBytes = size_t{1} << 20;

const char* TargetModel(v1::FitTarget target) {
  return target == v1::FIT_TARGET_OPENPBR ? "openpbr" : "gltf_sheen";
}

std::string CheckName(const std::string& name, const std::string& field, bool required) {
  if (required && name.empty()) return field + ": empty";
  if (name.size() > kMaxFitNameBytes)
    return field + ": " + std::to_string(name.size()) + " bytes, over the limit of " +
           std::to_string(kMaxFitNameBytes);
  return "";
}

std::string CheckMaterial(models::MaterialCache* cache, const models::Registry& registry, const v1::Material& material,
                          const std::string& field) {
  const models::Model* model = nullptr;
  std::shared_ptr<const models::PreparedMaterial> cached;
  if (std::string e = cache->Peek(material, registry, &model, &cached); !e.empty()) return field + ": " + e;
  if (!model->fiber_axis_param().empty())
    return field + ": model " + models::Quote(model->name()) +
           " shades about a fibre's axis, not a surface; fit the surface it makes (a woven material, or a BTF made "
           "from its fibers with CreateBtf)";
  return "";
}

// Who wears which fabric: (colourway, mesh material) -> an index into the call's distinct fabrics.
struct Wearer {
  int colourway = -1;  // -1: no colourways
  int slot = 0;        // the mesh's material index (0: the preview or the MaterialX document)
  int fabric = 0;
};

class FitCall : public std::enable_shared_from_this<FitCall> {
 public:
  FitCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, const v1::FitMaterialRequest* request,
          v1::FitMaterialResponse* response, Admission admission, Clock::time_point received)
      : deps_(deps), context_(context), request_(*request), response_(response),
        reactor_(context->DefaultReactor()), admission_(std::move(admission)), received_(received),
        client_deadline_(CallDeadline(context, received)),
        deadline_(deps.call_caps.Deadline(received, client_deadline_, batching::Priority::kBulk)),
        client_(FairShareKey(*context, *deps.trusted_proxies)),
        target_(deps.registry->FindModel(TargetModel(request->target()))) {}

  grpc::ServerUnaryReactor* reactor() const { return reactor_; }

  void Start() {
    auto self = shared_from_this();
    deps_.geometry->Post([self] { self->Step(self->Assign()); }, client_);
  }

 private:
  grpc::Status Stopped() const { return StopStatus(context_, deadline_); }

  // The next task: the status so far, else the next fabric's fit, else the export.
  void Step(grpc::Status status) {
    if (status.ok()) status = Stopped();
    if (!status.ok()) return Finish(status);
    auto self = shared_from_this();
    if (fits_.size() < fabrics_.size())
      return deps_.geometry->Post([self] { self->Step(self->FitNext()); }, client_);
    Finish(Export());
  }

  // The mesh (if any) and who wears which fabric, distinct fabrics fitted once.
  grpc::Status Assign() {
    if (!target_) return {grpc::StatusCode::INTERNAL, "the server has no model " + std::string(TargetModel(request_.target()))};
    slots_ = {""};  // the preview sphere's, or the MaterialX document's one
    if (request_.has_mesh()) {
      const auto stop = ReportingProgress([this] { return !Stopped().ok(); });
      if (grpc::Status s = LoadMeshSource(deps_, request_.mesh(), stop, &admission_, &mesh_); !s.ok()) {
        grpc::Status stopped = Stopped();
        return stopped.ok() ? s : stopped;
      }
      slots_ = mesh_->material_names;
      if (!admission_.bytes.Grow(kExportBaseBytes + kExportBytesPerTriangle * mesh_->triangles.size()))
        return {grpc::StatusCode::RESOURCE_EXHAUSTED,
                "mesh: its export needs more than this client's share of the server's memory budget now"};
    }
    std::map<std::string, int> fabric_of_bytes;
    // A slot wears its binding's fabric, else the fallback (`material`, or the colourway's).
    const auto assign = [&](int colourway, const v1::Material* fallback,
                            const google::protobuf::RepeatedPtrField<v1::MaterialBinding>& bindings,
                            const std::string& field) -> grpc::Status {
      for (int b = 0; b < bindings.size(); ++b)
        if (std::find(slots_.begin(), slots_.end(), bindings[b].mesh_material()) == slots_.end())
          return Invalid(field + "bindings[" + std::to_string(b) + "].mesh_material: the mesh has no material " +
                         models::Quote(bindings[b].mesh_material()) + " (MeshInfo.materials)");
      for (int slot = 0; slot < int(slots_.size()); ++slot) {
        const v1::Material* fabric = fallback;
        for (const v1::MaterialBinding& b : bindings)
          if (b.mesh_material() == slots_[slot]) fabric = &b.material();
        if (!fabric)
          return Invalid(field + "material: unset, and the mesh material " + models::Quote(slots_[slot]) +
                         " has no binding");
        auto [at, added] = fabric_of_bytes.emplace(fabric->SerializeAsString(), int(fabrics_.size()));
        if (added) {
          if (fabrics_.size() == kMaxFitsPerCall)
            return Invalid(field + "bindings: more than " + std::to_string(kMaxFitsPerCall) +
                           " distinct fabrics in one call");
          fabrics_.push_back(*fabric);
        }
        wearers_.push_back({colourway, slot, at->second});
      }
      return grpc::Status::OK;
    };
    if (request_.colourways_size() == 0)
      return assign(-1, request_.has_material() ? &request_.material() : nullptr, request_.bindings(), "");
    for (int c = 0; c < request_.colourways_size(); ++c) {
      const v1::Colourway& way = request_.colourways(c);
      if (grpc::Status s = assign(c, way.has_material() ? &way.material() : nullptr, way.bindings(),
                                  "colourways[" + std::to_string(c) + "].");
          !s.ok())
        return s;
    }
    return grpc::Status::OK;
  }

  // The next distinct fabric: packed, f on the fit's directions (a curtain's reflection), fitted.
  grpc::Status FitNext() {
    const size_t k = fits_.size();
    std::shared_ptr<const models::PreparedMaterial> prepared;
    if (grpc::Status s = PrepareMaterial(deps_, fabrics_[k], &prepared); !s.ok()) return s;
    const auto stop = ReportingProgress([this] { return !Stopped().ok(); });
    const std::vector<double> f = models::fit::ReferenceOnFitDirections(*prepared->model, prepared->packed);
    fits_.push_back(models::fit::FitLobe(*target_, f, stop));
    return grpc::Status::OK;
  }

  // A readable name of what fabric k is worn by (its first wearer).
  std::string FabricName(int k) const {
    std::string name = request_.name().empty() ? std::string(fabrics_[k].preset().empty() ? "fabric"
                                                                                           : fabrics_[k].preset())
                                               : request_.name();
    for (const Wearer& w : wearers_) {
      if (w.fabric != k) continue;
      if (w.colourway >= 0) name += " " + request_.colourways(w.colourway).name();
      if (!slots_[w.slot].empty()) name += " " + slots_[w.slot];
      break;
    }
    return name;
  }

  grpc::Status Export() {
    for (const Wearer& w : wearers_) {
      v1::MaterialFit* out = response_->add_fits();
      if (w.colourway >= 0) out->set_colourway(request_.colourways(w.colourway).name());
      out->set_mesh_material(slots_[w.slot]);
      const models::fit::FitResult& fit = fits_[w.fabric];
      out->mutable_fitted()->set_model(target_->name());
      for (const auto& [name, values] : fit.params) {
        v1::Param* p = out->mutable_fitted()->add_params();
        p->set_name(name);
        for (double v : values) p->add_values(v);
      }
      out->set_error(fit.error);
      for (const models::fit::RegionError& r : fit.regions) {
        v1::FitRegionError* region = out->add_regions();
        region->set_region(r.region);
        region->set_error(r.error);
        region->set_share(r.share);
      }
      out->set_seconds(fit.seconds);
      out->set_iterations(uint32_t(fit.iterations));
      out->set_poor_fit(fit.poor_fit);
    }
    std::string error;
    switch (request_.format()) {
      case v1::EXPORT_FORMAT_NONE: return grpc::Status::OK;
      case v1::EXPORT_FORMAT_GLB:
      case v1::EXPORT_FORMAT_GLTF: {
        exporting::GltfScene scene;
        scene.name = request_.name().empty() ? "fabric" : request_.name();
        scene.mesh = mesh_.get();
        for (size_t k = 0; k < fabrics_.size(); ++k) scene.materials.push_back({FabricName(int(k)), fits_[k].params});
        scene.slot_material.assign(slots_.size(), 0);
        for (const Wearer& w : wearers_)
          if (w.colourway <= 0) scene.slot_material[w.slot] = w.fabric;  // the first colourway shows by default
        for (int c = 0; c < request_.colourways_size(); ++c) {
          exporting::GltfVariant variant{request_.colourways(c).name(), std::vector<int>(slots_.size(), 0)};
          for (const Wearer& w : wearers_)
            if (w.colourway == c) variant.material_of_slot[w.slot] = w.fabric;
          scene.variants.push_back(std::move(variant));
        }
        const bool binary = request_.format() == v1::EXPORT_FORMAT_GLB;
        error = exporting::WriteGltf(scene, binary, response_->mutable_file());
        response_->set_file_extension(binary ? ".glb" : ".gltf");
        break;
      }
      case v1::EXPORT_FORMAT_MTLX: {
        std::vector<exporting::MtlxMaterial> materials;
        for (size_t k = 0; k < fabrics_.size(); ++k) materials.push_back({FabricName(int(k)), fits_[k].params});
        error = exporting::WriteMtlx(materials, response_->mutable_file());
        response_->set_file_extension(".mtlx");
        break;
      }
      default: return Invalid("format: unknown value " + std::to_string(request_.format()));
    }
    if (!error.empty()) return {grpc::StatusCode::INTERNAL, "export: " + error};
    return grpc::Status::OK;
  }

  void Finish(grpc::Status status) {
    status = deps_.call_caps.Explain(status, received_, client_deadline_, batching::Priority::kBulk);
    if (!status.ok()) response_->Clear();
    admission_.EndSlots();
    FinishUnary(deps_.metrics, reactor_, kRpc, received_, status);
  }

  const ServiceDeps& deps_;
  grpc::CallbackServerContext* context_;
  const v1::FitMaterialRequest& request_;
  v1::FitMaterialResponse* response_;
  grpc::ServerUnaryReactor* reactor_;
  Admission admission_;
  const Clock::time_point received_, client_deadline_, deadline_;
  const std::string client_;
  const models::Model* target_;
  std::shared_ptr<const assets::TriangleMesh> mesh_;
  std::vector<std::string> slots_;
  std::vector<v1::Material> fabrics_;
  std::vector<Wearer> wearers_;
  std::vector<models::fit::FitResult> fits_;
};

}  // namespace

grpc::Status CheckFitMaterialRequest(models::MaterialCache* cache, const models::Registry& registry,
                                     const v1::FitMaterialRequest& r) {
  if (!v1::FitTarget_IsValid(r.target()) || r.target() == v1::FIT_TARGET_UNSPECIFIED)
    return Invalid("target: give FIT_TARGET_GLTF_SHEEN or FIT_TARGET_OPENPBR");
  if (!v1::ExportFormat_IsValid(r.format())) return Invalid("format: unknown value " + std::to_string(r.format()));
  const bool gltf = r.format() == v1::EXPORT_FORMAT_GLB || r.format() == v1::EXPORT_FORMAT_GLTF;
  if (gltf && r.target() != v1::FIT_TARGET_GLTF_SHEEN)
    return Invalid("format: a glTF carries the glTF sheen fit; ask for target FIT_TARGET_GLTF_SHEEN");
  if (r.format() == v1::EXPORT_FORMAT_MTLX && r.target() != v1::FIT_TARGET_OPENPBR)
    return Invalid("format: a MaterialX document carries the OpenPBR fit; ask for target FIT_TARGET_OPENPBR");
  if (r.has_mesh() && !gltf)
    return Invalid("mesh: only a glTF export carries geometry; ask for format EXPORT_FORMAT_GLB or _GLTF");
  if (r.has_mesh())
    if (std::string e = ValidateMeshSource(r.mesh(), "mesh"); !e.empty()) return Invalid(e);
  if (std::string e = CheckName(r.name(), "name", false); !e.empty()) return Invalid(e);
  const auto check_fabrics = [&](const v1::Material& material, bool has_material,
                                 const google::protobuf::RepeatedPtrField<v1::MaterialBinding>& bindings,
                                 const std::string& field) -> std::string {
    if (!bindings.empty() && !r.has_mesh()) return field + "bindings: bindings name mesh materials; give a mesh";
    if (std::string e = ValidateMaterialBindings(bindings, field + "bindings"); !e.empty()) return e;
    if (!has_material && bindings.empty()) return field + "material: unset";
    if (has_material)
      if (std::string e = CheckMaterial(cache, registry, material, field + "material"); !e.empty()) return e;
    for (int b = 0; b < bindings.size(); ++b)
      if (std::string e = CheckMaterial(cache, registry, bindings[b].material(),
                                        field + "bindings[" + std::to_string(b) + "].material");
          !e.empty())
        return e;
    return "";
  };
  if (r.colourways_size() == 0) {
    std::string e = check_fabrics(r.material(), r.has_material(), r.bindings(), "");
    return e.empty() ? grpc::Status::OK : Invalid(e);
  }
  if (r.has_material() || r.bindings_size() > 0)
    return Invalid("colourways: each colourway gives its fabrics; leave material and bindings unset");
  if (r.colourways_size() > kMaxColourways)
    return Invalid("colourways: " + std::to_string(r.colourways_size()) + " exceed the limit of " +
                   std::to_string(kMaxColourways));
  for (int c = 0; c < r.colourways_size(); ++c) {
    const v1::Colourway& way = r.colourways(c);
    const std::string field = "colourways[" + std::to_string(c) + "].";
    if (std::string e = CheckName(way.name(), field + "name", true); !e.empty()) return Invalid(e);
    for (int d = 0; d < c; ++d)
      if (r.colourways(d).name() == way.name())
        return Invalid(field + "name: " + models::Quote(way.name()) + " names two colourways");
    if (std::string e = check_fabrics(way.material(), way.has_material(), way.bindings(), field); !e.empty())
      return Invalid(e);
  }
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* HandleFitMaterial(const ServiceDeps& deps, grpc::CallbackServerContext* context,
                                            const v1::FitMaterialRequest* request,
                                            v1::FitMaterialResponse* response) {
  const auto received = Clock::now();
  if (grpc::Status s = CheckFitMaterialRequest(deps.materials, *deps.registry, *request); !s.ok())
    return AnswerNow(deps.metrics, context, kRpc, received, s);
  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, kFitCallBytes, &admission); !s.ok())
    return AnswerNow(deps.metrics, context, kRpc, received, s);
  auto call = std::make_shared<FitCall>(deps, context, request, response, std::move(admission), received);
  call->Start();
  return call->reactor();
}

}  // namespace loomlight::api
