// The FitMaterial RPC (docs/materials-out.md): fits each fabric of a request with a standard lobe other tools
// render (server/models/fit/lobe_fit.h: glTF sheen or OpenPBR fuzz) and writes the fits as a glTF (on the request's
// mesh or a preview sphere, with a KHR_materials_variants variant per colourway) or a MaterialX document. The
// request is checked on the gRPC thread and admitted as a long call; the mesh, each distinct fabric's fit (about a
// second each) and the export run as separate tasks on the geometry worker, so other clients' work interleaves
// between them, each stopping when the call's deadline passes or its client cancels.
#pragma once

#include <cstddef>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"

namespace loomlight::api {

constexpr int kMaxColourways = 16;         // FitMaterialRequest.colourways
constexpr size_t kMaxFitNameBytes = 128;    // FitMaterialRequest.name, Colourway.name
constexpr size_t kMaxFitsPerCall = 64;      // distinct fabrics fitted by one call

// FitMaterial's checks that need no packing (the gRPC thread): target, format and their pairing, names,
// colourways, bindings, the mesh's source, and every material (its model must be a surface model). OK or
// INVALID_ARGUMENT naming the field.
grpc::Status CheckFitMaterialRequest(models::MaterialCache* cache, const models::Registry& registry,
                                     const v1::FitMaterialRequest& request);

// Serves one call (the service has checked that it is serving); the reactor is finished exactly once.
grpc::ServerUnaryReactor* HandleFitMaterial(const ServiceDeps& deps, grpc::CallbackServerContext* context,
                                            const v1::FitMaterialRequest* request,
                                            v1::FitMaterialResponse* response);

}  // namespace loomlight::api
