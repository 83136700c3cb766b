// The mesh RPCs (docs/products.md "Meshes"): UploadMesh receives a client's glTF or OBJ file (a header, then the
// file in chunks), checks it with ParseMesh on the asset loader and stores it by name (assets::MeshStore);
// ListMeshes and DeleteMesh. Names and sizes are checked on the gRPC thread before anything is buffered.
#pragma once

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"

namespace loomlight::api {

grpc::ServerReadReactor<v1::UploadMeshMessage>* HandleUploadMesh(const ServiceDeps& deps,
                                                                 grpc::CallbackServerContext* context,
                                                                 v1::MeshInfo* response,
                                                                 grpc::Status serving);  // not OK: refused with it
grpc::Status HandleListMeshes(const ServiceDeps& deps, v1::ListMeshesResponse* response);
// Deletes the caller's mesh (another client's: PERMISSION_DENIED, unless its token lists `admin`).
grpc::Status HandleDeleteMesh(const ServiceDeps& deps, const grpc::ServerContextBase& context,
                              const v1::DeleteMeshRequest& request);

}  // namespace loomlight::api
