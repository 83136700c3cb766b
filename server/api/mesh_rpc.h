// The mesh RPCs (docs/products.md "Meshes"): UploadMesh receives a client's glTF or OBJ file (a header, then the
// file in chunks), checks it with ParseMesh on the asset loader and stores it by name (assets::MeshStore);
// ListMeshes and DeleteMesh. Names and sizes are checked on the gRPC thread before anything is buffered.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/admission.h"
#include "server/api/service.h"
#include "server/assets/mesh_file.h"

namespace loomlight::api {

grpc::ServerReadReactor<v1::UploadMeshMessage>* HandleUploadMesh(const ServiceDeps& deps,
                                                                 grpc::CallbackServerContext* context,
                                                                 v1::MeshInfo* response,
                                                                 grpc::Status serving);  // not OK: refused with it
grpc::Status HandleListMeshes(const ServiceDeps& deps, v1::ListMeshesResponse* response);
// Deletes the caller's mesh (another client's: PERMISSION_DENIED, unless its token lists `admin`).
grpc::Status HandleDeleteMesh(const ServiceDeps& deps, const grpc::ServerContextBase& context,
                              const v1::DeleteMeshRequest& request);

// A request's mesh (Render's, FitMaterial's), shared by the RPCs that take one.
// Its fields as sent: a stored mesh's name, or the file's data within MeshLimits. "" or "<field>...: reason".
std::string ValidateMeshSource(const v1::MeshSource& mesh, const std::string& field);
// Bindings of mesh materials to materials: each names a mesh material once (at most kMaxMeshMaterialName bytes)
// and gives a material; at most MeshLimits::max_materials. "" or "<field>[i]...: reason".
std::string ValidateMaterialBindings(const google::protobuf::RepeatedPtrField<v1::MaterialBinding>& bindings,
                                     const std::string& field);
// On a worker: the mesh parsed (sent with the request: its parse admitted first, at kMeshParseBytesPerFileByte)
// or loaded from the store by name (its bytes admitted once loaded), into *out; `stop` as ParseMesh asks it.
// OK, or the status naming mesh.data / mesh.name (the caller prefers its own stop status to a stopped parse's).
grpc::Status LoadMeshSource(const ServiceDeps& deps, const v1::MeshSource& source, const std::function<bool()>& stop,
                            Admission* admission, std::shared_ptr<const assets::TriangleMesh>* out);

}  // namespace loomlight::api
