// The YarnGeometry RPC: the fiber curves of a procedural yarn (server/yarn/), straight or laid out as the warp
// and weft of a weave, streamed to the client. The request is checked on the gRPC thread (cheap: parameters,
// layout, limits); the curves are generated on the service's geometry worker (deadline and cancellation stop
// it between fibers; server/yarn/yarn_job.h), then converted to float in batches of whole curves
// (server/yarn/geometry_stream.h) and written in ~1 MiB chunks from the host worker, one write in flight
// (server/api/stream_call.h).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "server/models/registry.h"
#include "server/yarn/fiber_scene.h"
#include "server/yarn/fiber_scene_cache.h"
#include "server/yarn/layout.h"
#include "server/yarn/visibility.h"
#include "server/yarn/yarn.h"
#include "server/yarn/yarn_job.h"

namespace loomlight::api {

// Documented limits (docs/fibers.md "Yarn geometry"): a call's curves are bounded by these, or by the request's own
// lower max_fibers and max_control_points. The geometry is held in double until it is sent: about 24 bytes
// per control point and 64 per curve, charged to the memory budget at the call's limits.
constexpr uint64_t kMaxYarnFibers = 200'000;
constexpr uint64_t kMaxYarnControlPoints = 8'000'000;
constexpr size_t kYarnBytesPerPoint = 24;
constexpr size_t kYarnBytesPerFiber = 64;
// A woven layout's centre polylines, per vertex (server/yarn/layout.h), charged too.
constexpr size_t kLayoutBytesPerVertex = 130;
// Curve data per streamed chunk (each control point 12 bytes as float, each curve 24 bytes of attributes).
constexpr size_t kYarnChunkBytes = size_t{1} << 20;

// Yarn parameters of a request: the preset (default cotton1) with its overrides and seed. Returns "" or
// "yarn.field: reason".
std::string YarnParamsOf(const v1::Yarn& yarn, yarn::YarnParams* out);

// What a validated yarn request asks for, and its generation (server/yarn/yarn_job.h); Render and CreateBtf
// name them through this header.
using yarn::GenerateYarnJob;
using yarn::LaidYarn;
using yarn::SameFibers;
using yarn::YarnJob;

// A request's layout: at most one of these set (none: one straight yarn of straight_length, 0 = 1).
struct YarnLayoutRequest {
  const v1::WovenYarnLayout* woven = nullptr;
  const v1::CurveYarnLayout* curves = nullptr;
  const v1::KnitYarnLayout* knit = nullptr;
  double straight_length = 0;
};

// The yarn of a request and its layout: a woven patch (fields under "woven."), the client's curves
// ("curves.yarns[k].field"; each curve's yarn is its own or the request's with the seed
// yarn::LayoutYarnSeed(seed, k), scaled to its radius by ScaleYarn), a knit ("knit.") or one straight yarn
// ("straight.length"). Everything is checked that needs no geometry built (a curve's points are checked when its
// centre is built: "yarns[k].points: ..." from generation, which CurveError names). job->layout_bytes: the
// centres' estimated bytes, for admission. Detail and limits are the caller's. Returns "" or "field: reason".
std::string YarnJobOf(const models::Registry& registry, const v1::Yarn& yarn, const YarnLayoutRequest& layout,
                      YarnJob* job);
// The same for a woven patch (`woven` not null) or a straight yarn.
std::string YarnJobOf(const models::Registry& registry, const v1::Yarn& yarn, const v1::WovenYarnLayout* woven,
                      double straight_length, YarnJob* job);

// A geometrically similar yarn of yarn radius `radius`: every length scaled by radius / yarn_radius (yarn_radius,
// ellipse_n, ellipse_b, fiber_width, alpha, alpha_yarn) and the densities per unit length divided by it.
void ScaleYarn(double radius, yarn::YarnParams* p);

// A generation error of a curve layout's yarn ("yarns[k].field: reason") as the request's field
// ("curves.yarns[k].field: reason"), or "" for any other error.
std::string CurveError(const std::string& error);

// A job's fibers in an Embree BVH, for ray tracing them (Render's fiber scenes, CreateBtf's fiber source):
// generates them, admits the BVH's estimated bytes through `grow` (RESOURCE_EXHAUSTED when it refuses) before
// building it bounded by them, and with `visibility` not null also builds the yarns' cheap visibility
// (cross-section slices and occlusion, other yarns as tubes): yarn::BuildFiberScene with `stop` saying why to
// stop (deadline, cancellation; OK to go on). OK, INVALID_ARGUMENT for the yarn's limits ("<yarn_field>: ..."),
// RESOURCE_EXHAUSTED where memory is short, or why it stopped. With a `cache`, a scene it holds for the same
// fibers is used as it is (nothing generated, built or admitted), and a scene built here is kept there.
grpc::Status BuildFiberScene(YarnJob* job, const std::function<grpc::Status()>& stop,
                             const std::function<bool(size_t)>& grow, std::shared_ptr<const yarn::FiberScene>* scene,
                             std::shared_ptr<const yarn::YarnVisibility>* visibility, yarn::FiberSceneCache* cache,
                             const std::string& yarn_field = "yarn");

// The schema and presets ListModels reports under `yarn`.
void DescribeYarnModel(v1::YarnModelInfo* out);

// Serves one call: validation errors finish at once; otherwise the reactor streams the summary and curves.
grpc::ServerWriteReactor<v1::YarnGeometryChunk>* HandleYarnGeometry(const ServiceDeps& deps,
                                                                   grpc::CallbackServerContext* context,
                                                                   const v1::YarnGeometryRequest* request);

}  // namespace loomlight::api
