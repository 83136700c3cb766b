// The BTF asset RPCs (docs/btf-assets.md): UploadBtf takes a client's images; CreateBtf synthesises a BTF from a
// spatially varying material on a direction grid (view by view, as bulk batcher jobs), compresses it
// (models::btf::Compress, on the geometry worker) and stores it (assets::BtfStore), streaming progress; ListBtfs
// and DeleteBtf. Requests are checked on the gRPC thread; asset names are checked before anything touches the
// store.
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "server/api/yarn_rpc.h"

namespace loomlight::api {

// Documented limits (docs/btf-assets.md "Limits").
constexpr uint32_t kDefaultBtfTexels = 64;
constexpr uint32_t kMaxBtfTexels = 128;  // per side: 81 x 81 images of 128 x 128 are 1.3 GB in float
// A knit fiber source's patch: at least 5 stitch repeats each way (a rib's repeat is 2 wales), the tile the central
// one. A loop reaches into the courses beside its own, so the 3 x 3 repeats around the tile need one more all round
// to be whole.
constexpr int kKnitPatchWales = 10;
constexpr int kKnitPatchCourses = 5;
constexpr uint32_t kDefaultBtfComponents = 16;

// A request's asset: its name, grid, tile and compression.
struct BtfJob {
  std::string name;
  models::btf::DirectionGrid grid;
  int width = 0, height = 0;  // texels of the tile
  models::btf::CompressionOptions compression;
  bool replace = false;
  std::string owner;   // the client storing it (FairShareKey)
  bool admin = false;  // its token lists `admin`: it may replace another client's asset
};

// A CreateBtf fiber source (docs/btf-assets.md "From fibers"): the patch's yarn and layout, rays per texel.
struct FiberSource {
  YarnJob yarn;
  int samples = 1;
};

// CreateBtf's checks of its own fields (name, grid, resolution, compression, the fiber source), before the store
// and the material are looked at: OK with *job filled in and *fibers set when the request has a fiber source, or
// INVALID_ARGUMENT naming the field. *bytes: what the call is charged when admitted.
grpc::Status CheckCreateBtfRequest(const models::Registry& registry, const v1::CreateBtfRequest& request, BtfJob* job,
                                   std::unique_ptr<FiberSource>* fibers, size_t* bytes);

grpc::ServerWriteReactor<v1::CreateBtfProgress>* HandleCreateBtf(const ServiceDeps& deps,
                                                                 grpc::CallbackServerContext* context,
                                                                 const v1::CreateBtfRequest* request);
grpc::ServerReadReactor<v1::UploadBtfMessage>* HandleUploadBtf(const ServiceDeps& deps,
                                                               grpc::CallbackServerContext* context,
                                                               v1::BtfAssetInfo* response,
                                                               grpc::Status serving);  // not OK: refused with it
grpc::Status HandleListBtfs(const ServiceDeps& deps, v1::ListBtfsResponse* response);
// Deletes the caller's asset (another client's: PERMISSION_DENIED, unless its token lists `admin`).
grpc::Status HandleDeleteBtf(const ServiceDeps& deps, const grpc::ServerContextBase& context,
                             const v1::DeleteBtfRequest& request);

// The compression options of a request; "" or "compression.field: reason".
std::string CompressionOf(const v1::BtfCompression& c, models::btf::CompressionOptions* out);

}  // namespace loomlight::api
