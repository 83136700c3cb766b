// The YarnGeometry RPC: the fiber curves of a procedural yarn (server/yarn/), straight or laid out as the warp
// and weft of a weave, streamed to the client. The request is checked on the gRPC thread (cheap: parameters,
// layout, limits); the curves are generated on the service's geometry worker (deadline and cancellation stop
// it between fibers), then converted to float and written in ~1 MiB chunks from the host worker, one write in
// flight (server/api/stream_call.h).
#pragma once

#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <string>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "server/models/registry.h"
#include "server/yarn/fiber_scene.h"
#include "server/yarn/layout.h"
#include "server/yarn/visibility.h"
#include "server/yarn/yarn.h"

namespace loomlight::api {

// Documented limits (README "Yarn geometry"): a call's curves are bounded by these, or by the request's own
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

// What a validated yarn request asks for (YarnGeometry, Render's yarn scenes): everything GenerateYarn or
// GenerateLayout needs.
struct YarnJob {
  yarn::YarnParams params;
  yarn::DetailOptions detail;
  yarn::YarnLimits limits;
  double straight_length = 1;
  bool woven = false;  // else one straight yarn
  models::weave::WeavePattern pattern;
  yarn::LayoutParams layout;
  size_t layout_bytes = 0;  // the centre polylines' estimated size
};

// The yarn of a request and its layout: a woven patch (`woven` not null; fields under "woven.") or one
// straight yarn of `straight_length` (0 = 1; "straight.length"). Detail and limits are the caller's. Returns ""
// or "field: reason".
std::string YarnJobOf(const models::Registry& registry, const v1::Yarn& yarn, const v1::WovenYarnLayout* woven,
                      double straight_length, YarnJob* job);

// One generated yarn of a job: a layout's warp or weft, or the straight yarn.
struct LaidYarn {
  bool warp = false;
  int thread = 0;
  double length = 0;
  std::shared_ptr<const yarn::YarnCurve> centre;  // the centre curve its fibers were generated along
};
// Generates a job's fibers (GenerateLayout or GenerateStraightYarn): one YarnGeometry per yarn. Returns "" or
// their error ("cancelled", "max_fibers: ...", ...), leaving both outputs empty.
std::string GenerateYarnJob(YarnJob* job, std::vector<yarn::YarnGeometry>* yarns, std::vector<LaidYarn>* laid);

// Fiber scenes kept across calls (Render's fiber scenes, CreateBtf's fiber source): generating a woven patch's
// fibers and building their BVH takes about a tenth of a second, and an editor renders the same patch again
// under another light or from another side (the same detail); the openness nodes one render traced serve the
// next. Least recently used first out, bounded in bytes (the BVH's estimate and the openness table); an entry
// matches a job with the same yarn, layout, pattern, detail and limits (SameFibers).
class FiberSceneCache {
 public:
  explicit FiberSceneCache(size_t capacity_bytes) : capacity_bytes_(capacity_bytes) {}
  struct Scene {
    std::shared_ptr<const yarn::FiberScene> fibers;
    std::shared_ptr<const yarn::YarnVisibility> visibility;  // null where it was built without
  };
  // The scene built for a job with the same fibers (with its visibility when `need_visibility`); false if none.
  bool Find(const YarnJob& job, bool need_visibility, Scene* out);
  // Keeps `scene` for `job` (replacing an entry for the same fibers) unless it alone is over the bound.
  void Keep(const YarnJob& job, Scene scene, size_t bytes);
  size_t bytes() const;
  size_t entries() const;

 private:
  struct Entry {
    YarnJob job;  // its stop predicate cleared
    Scene scene;
    size_t bytes = 0;
  };
  const size_t capacity_bytes_;
  mutable std::mutex mutex_;
  std::list<Entry> entries_;  // most recently used first
  size_t bytes_ = 0;
};

// Whether two jobs generate the same fibers along the same centres.
bool SameFibers(const YarnJob& a, const YarnJob& b);

// A job's fibers in an Embree BVH, for ray tracing them (Render's fiber scenes, CreateBtf's fiber source):
// generates them, admits the BVH's estimated bytes through `grow` (RESOURCE_EXHAUSTED when it refuses) before
// building it bounded by them, and with `visibility` not null also builds the yarns' cheap visibility
// (cross-section slices and occlusion, other yarns as tubes). `stop` says why to stop (deadline, cancellation;
// OK to go on) and is asked between fibers and during the build. OK, INVALID_ARGUMENT for the yarn's limits
// ("<yarn_field>: ..."), or why it stopped. With a `cache`, a scene it holds for the same fibers is used as it
// is (nothing generated, built or admitted), and a scene built here is kept there.
grpc::Status BuildFiberScene(YarnJob* job, const std::function<grpc::Status()>& stop,
                             const std::function<bool(size_t)>& grow, std::shared_ptr<const yarn::FiberScene>* scene,
                             std::shared_ptr<const yarn::YarnVisibility>* visibility, FiberSceneCache* cache,
                             const std::string& yarn_field = "yarn");

// The schema and presets ListModels reports under `yarn`.
void DescribeYarnModel(v1::YarnModelInfo* out);

// Serves one call: validation errors finish at once; otherwise the reactor streams the summary and curves.
grpc::ServerWriteReactor<v1::YarnGeometryChunk>* HandleYarnGeometry(const ServiceDeps& deps,
                                                                   grpc::CallbackServerContext* context,
                                                                   const v1::YarnGeometryRequest* request);

}  // namespace loomlight::api
