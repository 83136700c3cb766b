// A yarn job's fibers as a ray-traceable scene (Render's fiber scenes, CreateBtf's fiber source): generated,
// admitted, built into an Embree BVH with the yarns' cheap visibility, and kept across calls. No protobuf and no
// gRPC: server/api/yarn_rpc.h turns the outcome into the call's status.
#pragma once

#include <cstddef>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <string>

#include "server/yarn/fiber_scene.h"
#include "server/yarn/visibility.h"
#include "server/yarn/yarn_job.h"

namespace loomlight::yarn {

// Fiber scenes kept across calls: generating a woven patch's fibers and building their BVH takes about a tenth
// of a second, and an editor renders the same patch again under another light or from another side (the same
// detail); the openness nodes one render traced serve the next. Least recently used first out, bounded in bytes
// (the BVH's estimate and the openness table); an entry matches a job with the same yarn, layout, pattern,
// detail and limits (SameFibers).
class FiberSceneCache {
 public:
  explicit FiberSceneCache(size_t capacity_bytes) : capacity_bytes_(capacity_bytes) {}
  struct Scene {
    std::shared_ptr<const FiberScene> fibers;
    std::shared_ptr<const YarnVisibility> visibility;  // null where it was built without
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

// How BuildFiberScene ended: kOk, or why not with a message (kLimits: the yarn limits' error from generation;
// kNoMemory: `grow` refused or the BVH outgrew its estimate; kInternal: anything else). kStopped whenever
// `stopped` said so when a step failed.
struct FiberSceneOutcome {
  enum class Kind { kOk, kStopped, kLimits, kNoMemory, kInternal };
  Kind kind = Kind::kOk;
  std::string message;
};

// Generates the job's fibers, admits the BVH's estimated bytes through `grow` before building it bounded by them,
// and with `visibility` not null also builds the yarns' cheap visibility (cross-section slices and occlusion,
// other yarns as tubes) and admits its openness table. `stopped` is asked between fibers and during the build.
// With a `cache`, a scene it holds for the same fibers is used as it is (nothing generated, built or admitted),
// and a scene built here is kept there.
FiberSceneOutcome BuildFiberScene(YarnJob* job, const std::function<bool()>& stopped,
                                  const std::function<bool(size_t)>& grow, std::shared_ptr<const FiberScene>* scene,
                                  std::shared_ptr<const YarnVisibility>* visibility, FiberSceneCache* cache);

}  // namespace loomlight::yarn
