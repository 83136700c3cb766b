#include "server/api/mesh_rpc.h"

#include <algorithm>
#include <memory>
#include <string>

#include "server/api/access.h"
#include "server/api/job_status.h"
#include "server/api/render_rpc.h"
#include "server/api/unary_call.h"
#include "server/api/upload_bounds.h"
#include "server/assets/mesh_file.h"
#include "server/assets/mesh_store.h"
#include "server/models/quote.h"

namespace loomlight::api {
namespace {
using batching::Clock;
constexpr const char* kUploadRpc = "UploadMesh";

// What the parse holds beside the file, charged before it starts: as for a mesh sent with a render
// (render_rpc.h kMeshParseBytesPerFileByte, at most kMaxMeshParseBytes).
uint64_t ParseBytes(uint64_t file_bytes) {
  return std::min(kMeshParseBytesPerFileByte * file_bytes, kMaxMeshParseBytes);
}

grpc::Status NoStore() {
  return {grpc::StatusCode::FAILED_PRECONDITION, "this server keeps no meshes (started without a data directory)"};
}

grpc::Status NotOwner(const std::string& name) {
  return {grpc::StatusCode::PERMISSION_DENIED, "name: the mesh " + models::Quote(name) +
                                                   " belongs to another client (its owner, or a token with the "
                                                   "admin right, may delete it)"};
}

// Ends an upload that cannot start (no store; the service not serving), recording it.
class RejectedUpload final : public grpc::ServerReadReactor<v1::UploadMeshMessage> {
 public:
  RejectedUpload(Metrics* metrics, grpc::Status status) {
    metrics->Call(kUploadRpc, status.error_code(), 0);
    Finish(std::move(status));
  }
  void OnDone() override { delete this; }
};

// One UploadMesh call: the header checked and the call admitted on the gRPC thread, the chunks appended there
// (charged as they come, never past the header's size), then the parse charged and the file parsed and stored on
// the asset loader.
class UploadMeshCall final : public grpc::ServerReadReactor<v1::UploadMeshMessage> {
 public:
  UploadMeshCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, v1::MeshInfo* response)
      : deps_(deps), context_(context), response_(response), received_(Clock::now()),
        deadline_(CallDeadline(context, received_)), bounds_(deps, context),
        client_(FairShareKey(*context, *deps.trusted_proxies)) {
    StartRead(&message_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) return EndOfStream();
    bounds_.Touch();
    const grpc::Status s = header_seen_ ? Chunk() : Header();
    if (!s.ok()) return Finish(s);
    message_.Clear();
    StartRead(&message_);
  }
  void OnDone() override { delete this; }

 private:
  grpc::Status Header() {
    if (!message_.has_header()) return Invalid("the first message must be a header");
    const v1::UploadMeshHeader& h = message_.header();
    if (std::string e = assets::ValidateAssetName(h.name()); !e.empty()) return Invalid("header.name: " + e);
    if (!v1::MeshFormat_IsValid(h.format()))
      return Invalid("header.format: unknown value " + std::to_string(h.format()));
    const uint64_t max = deps_.mesh_store->limits().max_bytes;
    if (h.size() == 0) return Invalid("header.size: the file's bytes, at least 1");
    if (h.size() > max)
      return Invalid("header.size: " + std::to_string(h.size()) + " bytes, over the limit of " + std::to_string(max) +
                     " bytes per mesh file");
    if (deps_.mesh_store->Exists(h.name()))  // early; the store checks again when it writes
      return {grpc::StatusCode::ALREADY_EXISTS,
              "header.name: a mesh named " + models::Quote(h.name()) + " exists (delete it first)"};
    if (deps_.mesh_store->bytes() + h.size() > deps_.mesh_store->max_bytes())
      return {grpc::StatusCode::RESOURCE_EXHAUSTED,
              "the mesh store holds " + std::to_string(deps_.mesh_store->bytes() >> 20) + " MiB of its bound of " +
                  std::to_string(deps_.mesh_store->max_bytes() >> 20) +
                  " MiB (--mesh-store-mb): no room for this file; delete meshes first"};
    // Its bytes are charged as they arrive: a client that stalls holds what it sent, not what it declared.
    if (grpc::Status s = AdmitLongCall(deps_, *context_, 0, &admission_); !s.ok()) return s;
    name_ = h.name();
    format_ = h.format();
    size_ = h.size();
    header_seen_ = true;
    return grpc::Status::OK;
  }

  grpc::Status Chunk() {
    if (!message_.has_chunk()) return Invalid("chunk: after the header, only chunks");
    const std::string& chunk = message_.chunk();
    if (chunk.size() > size_ - data_.size())  // refused before it is kept: nothing past the declared size
      return Invalid("chunk: the chunks hold more than the header's size of " + std::to_string(size_) + " bytes");
    if (const size_t needed = data_.size() + chunk.size(); needed > charged_) {
      // Room grown by doubling (appends stay linear), never past the declared size, charged before it is taken.
      const size_t room = size_t(std::min<uint64_t>(size_, std::max(needed, 2 * charged_)));
      if (!admission_.bytes.Grow(room - charged_))
        return {grpc::StatusCode::RESOURCE_EXHAUSTED,
                "the server's memory budget holds no more of this upload now; retry later"};
      data_.reserve(room);
      charged_ = room;
    }
    data_.append(chunk);
    return grpc::Status::OK;
  }

  // The client closed its side (or went away, or a bound cut it off).
  void EndOfStream() {
    if (grpc::Status s = bounds_.Stop(); !s.ok()) return Finish(s);
    if (grpc::Status s = StopStatus(context_, deadline_); !s.ok()) return Finish(s);
    if (!header_seen_) return Finish(Invalid("no header: the stream was empty"));
    if (data_.size() != size_)
      return Finish(Invalid("chunk: the chunks hold " + std::to_string(data_.size()) + " bytes, the header's size is " +
                            std::to_string(size_)));
    if (!admission_.bytes.Grow(ParseBytes(size_)))
      return Finish({grpc::StatusCode::RESOURCE_EXHAUSTED,
                     "the server's memory budget cannot hold the parse of " + std::to_string(size_) +
                         " bytes of mesh now; retry later"});
    deps_.loader->Post([this] { Finish(ParseAndStore()); }, client_);
  }

  // On the asset loader: the file checked by the parser, then stored with its description.
  grpc::Status ParseAndStore() {
    const auto stop = ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); });
    const v1::MeshFormat format = assets::DetectMeshFormat(data_, format_);
    auto mesh = std::make_shared<assets::TriangleMesh>();
    if (std::string e = assets::ParseMesh(data_, format, deps_.mesh_store->limits(), mesh.get(), nullptr, stop);
        !e.empty()) {
      if (grpc::Status s = StopStatus(context_, deadline_); !s.ok()) return s;
      return Invalid(e);
    }
    v1::MeshInfo info;
    assets::DescribeMesh(*mesh, &info);
    info.set_name(name_);
    info.set_format(format);
    info.set_bytes(data_.size());
    std::string error;
    switch (deps_.mesh_store->Put(info, data_, client_, std::move(mesh), &error)) {
      case assets::MeshStore::Outcome::kOk: *response_ = info; return grpc::Status::OK;
      case assets::MeshStore::Outcome::kExists: return {grpc::StatusCode::ALREADY_EXISTS, "header.name: " + error};
      case assets::MeshStore::Outcome::kFull: return {grpc::StatusCode::RESOURCE_EXHAUSTED, error};
      case assets::MeshStore::Outcome::kFailed: break;
    }
    return {grpc::StatusCode::INTERNAL, error};
  }

  void Finish(const grpc::Status& s) {
    bounds_.Stop();  // an error before the end of the stream
    deps_.metrics->Call(kUploadRpc, s.error_code(), SecondsSince(received_));
    admission_.EndSlots();
    grpc::ServerReadReactor<v1::UploadMeshMessage>::Finish(s);
  }

  const ServiceDeps deps_;
  grpc::CallbackServerContext* const context_;
  v1::MeshInfo* const response_;
  const Clock::time_point received_, deadline_;
  UploadBounds bounds_;
  const std::string client_;  // FairShareKey: the mesh's owner; its parse takes its turn on the loader
  Admission admission_;
  bool header_seen_ = false;
  std::string name_;
  v1::MeshFormat format_ = v1::MESH_FORMAT_AUTO;
  uint64_t size_ = 0;
  std::string data_;  // the file as it arrives, at most size_ bytes
  size_t charged_ = 0;  // data_'s room, charged to the memory budget
  v1::UploadMeshMessage message_;
};
}  // namespace

grpc::ServerReadReactor<v1::UploadMeshMessage>* HandleUploadMesh(const ServiceDeps& deps,
                                                                 grpc::CallbackServerContext* context,
                                                                 v1::MeshInfo* response, grpc::Status serving) {
  if (!serving.ok()) return new RejectedUpload(deps.metrics, std::move(serving));
  if (!deps.mesh_store) return new RejectedUpload(deps.metrics, NoStore());
  return new UploadMeshCall(deps, context, response);
}

grpc::Status HandleListMeshes(const ServiceDeps& deps, v1::ListMeshesResponse* response) {
  if (!deps.mesh_store) return NoStore();
  for (v1::MeshInfo& info : deps.mesh_store->List()) *response->add_meshes() = std::move(info);
  response->set_max_bytes(deps.mesh_store->max_bytes());
  return grpc::Status::OK;
}

grpc::Status HandleDeleteMesh(const ServiceDeps& deps, const grpc::ServerContextBase& context,
                              const v1::DeleteMeshRequest& request) {
  if (!deps.mesh_store) return NoStore();
  if (std::string e = assets::ValidateAssetName(request.name()); !e.empty()) return Invalid("name: " + e);
  switch (deps.mesh_store->Delete(request.name(), FairShareKey(context, *deps.trusted_proxies),
                                  TokenListsRight(context, "admin"))) {
    case assets::MeshStore::Removal::kNotFound:
      return {grpc::StatusCode::NOT_FOUND, "name: no mesh named " + models::Quote(request.name())};
    case assets::MeshStore::Removal::kDenied: return NotOwner(request.name());
    case assets::MeshStore::Removal::kRemoved: break;
  }
  return grpc::Status::OK;
}

std::string ValidateMeshSource(const v1::MeshSource& mesh, const std::string& field) {
  if (mesh.has_data()) {
    if (!v1::MeshFormat_IsValid(mesh.data().format()))
      return field + ".data.format: unknown value " + std::to_string(mesh.data().format());
    if (mesh.data().data().empty()) return field + ".data.data: empty";
    if (mesh.data().data().size() > assets::MeshLimits{}.max_bytes)
      return field + ".data.data: " + std::to_string(mesh.data().data().size()) + " bytes exceed the limit of " +
             std::to_string(assets::MeshLimits{}.max_bytes);
  } else if (mesh.source_case() == v1::MeshSource::kName) {
    if (std::string e = assets::ValidateAssetName(mesh.name()); !e.empty()) return field + ".name: " + e;
  } else {
    return field + ": give a stored mesh's name or the file's data";
  }
  return "";
}

std::string ValidateMaterialBindings(const google::protobuf::RepeatedPtrField<v1::MaterialBinding>& bindings,
                                     const std::string& field) {
  const auto indexed = [&field](int i) { return field + "[" + std::to_string(i) + "]"; };
  if (bindings.size() > int(assets::MeshLimits{}.max_materials))
    return field + ": " + std::to_string(bindings.size()) + " bindings exceed the limit of " +
           std::to_string(assets::MeshLimits{}.max_materials) + " materials per mesh";
  for (int i = 0; i < bindings.size(); ++i) {
    const v1::MaterialBinding& b = bindings[i];
    if (b.mesh_material().size() > kMaxMeshMaterialName)
      return indexed(i) + ".mesh_material: longer than " + std::to_string(kMaxMeshMaterialName) + " bytes";
    if (!b.has_material()) return indexed(i) + ".material: unset";
    for (int j = 0; j < i; ++j)
      if (bindings[j].mesh_material() == b.mesh_material())
        return indexed(i) + ".mesh_material: " + models::Quote(b.mesh_material()) + " is bound twice";
  }
  return "";
}

grpc::Status LoadMeshSource(const ServiceDeps& deps, const v1::MeshSource& source, const std::function<bool()>& stop,
                            Admission* admission, std::shared_ptr<const assets::TriangleMesh>* out) {
  if (source.has_data()) {
    const uint64_t parse_bytes = ParseBytes(source.data().data().size());
    if (!admission->bytes.Grow(size_t(parse_bytes)))
      return {grpc::StatusCode::RESOURCE_EXHAUSTED, "mesh.data: parsing it needs " + std::to_string(parse_bytes) +
                                                        " bytes, over this client's share of the memory budget"};
    auto parsed = std::make_shared<assets::TriangleMesh>();
    if (std::string e = assets::ParseMesh(source.data().data(), source.data().format(), assets::MeshLimits{},
                                          parsed.get(), nullptr, stop);
        !e.empty())
      return Invalid("mesh.data: " + e);
    *out = std::move(parsed);
    return grpc::Status::OK;
  }
  if (!deps.mesh_store)
    return {grpc::StatusCode::FAILED_PRECONDITION, "mesh.name: this server keeps no meshes (no data directory)"};
  v1::MeshInfo info;
  std::string error;
  std::shared_ptr<const assets::TriangleMesh> mesh;
  switch (deps.mesh_store->Load(source.name(), stop, &mesh, &info, &error)) {
    case assets::MeshStore::Found::kOk: break;
    case assets::MeshStore::Found::kNotFound:
      return {grpc::StatusCode::NOT_FOUND, "mesh.name: no mesh " + models::Quote(source.name()) + " (ListMeshes)"};
    case assets::MeshStore::Found::kFailed:
      return {grpc::StatusCode::INTERNAL, "mesh.name: cannot load " + models::Quote(source.name()) + ": " + error};
  }
  if (!admission->bytes.Grow(size_t(mesh->memory_bytes())))
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, "mesh.name: the mesh's " + std::to_string(mesh->memory_bytes()) +
                                                      " bytes are over this client's share of the memory budget"};
  *out = std::move(mesh);
  return grpc::Status::OK;
}

}  // namespace loomlight::api
