// Fiber curves in an Embree BVH, for ray-traced close-ups of yarn (Wu and Yuksel Sec. 4 shade fibers one by
// one; at close range the fibers themselves are the visible geometry).
//
// Design:
// - Geometry: every fiber polyline (yarn.h's FiberCurve) becomes a run of RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE
//   segments, vertices float4 (x, y, z, radius = width / 2). A round linear segment is a cone swept between
//   two spheres, so a polyline is a tube with round joints and round ends, as thick as the fiber everywhere:
//   a straight fiber is an exact capsule (a cylinder of the fiber's width), with no tessellation error and
//   no flat ribbon facing the camera (the flat curve types), which a close-up would show. Within one fiber,
//   the segments carry RTC_CURVE_FLAG_NEIGHBOR_LEFT/RIGHT (flags buffer, set explicitly rather than inferred
//   from the index buffer) so Embree clips a segment's joint sphere where the neighbouring segment covers it:
//   a ray through a joint hits the union of the two tubes once, with no gap and no hit inside the tube.
//   One Embree geometry per input YarnGeometry, with geomID = its index, primID = segment index; per segment
//   we keep the curve index so a hit maps back to the FiberCurve (type, ply, fiber, width).
// - Control points equal in float (after the conversion) are merged, so no segment has zero length and every
//   hit has a tangent; curves left with fewer than two distinct points are skipped (counted in the stats).
// - Memory and cancellation: the build runs on its own Embree device whose memory monitor
//   (rtcSetDeviceMemoryMonitorFunction) sees every allocation Embree makes for this scene: the vertex, index
//   and flags buffers (rtcSetNewGeometryBuffer, so Embree owns them) and the BVH builder's memory. The monitor
//   refuses an allocation that would take the running total over FiberSceneOptions::max_bytes (the build then
//   fails with "bvh_memory: ...", which a caller maps to RESOURCE_EXHAUSTED) and any allocation once the
//   caller's cancel predicate says so; the scene's progress monitor (rtcSetSceneProgressMonitorFunction) asks
//   the predicate too, so a build that allocates nothing more still stops ("cancelled"). EstimateFiberScene
//   gives an upper bound of the same bytes before anything is built, so a server can refuse early.
// - Errors: Embree reports through an error callback and rtcGetDeviceError; nothing throws past this API and
//   nothing aborts. Functions return "" or "field: reason".
// - Threads: the device is created with "threads=N,set_affinity=0,start_threads=0": TBB workers are made
//   lazily on the first build, not pinned, and TBB parks them when a build ends. Embree's thread count is
//   process-wide (a tbb::global_control at the largest count any live device asked for), so scenes built
//   with different counts share the largest.
// - Queries are const and thread-safe (Embree's rtcIntersect1 / rtcOccluded1 on a committed scene; our tables
//   are read-only after Build).
//
// Known limit of Embree 3.13's round linear curves (measured): a ray exactly parallel to a segment (e.g.
// direction (0, 0, 1) on a straight fiber along z) misses the segment, its round ends included; a direction
// off by 1e-3 rad hits. Random and camera rays are almost never exactly parallel.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "server/yarn/yarn.h"

// Embree's opaque handles, so that this header does not pull in Embree's.
struct RTCDeviceTy;
struct RTCSceneTy;

namespace loomlight::yarn {

struct Float3 {
  float x = 0;
  float y = 0;
  float z = 0;

  bool operator==(const Float3&) const = default;
};

// Embree's build quality. For curves Embree 3.13.5 showed the same memory and build time at every level
// (measured); kept so the scene follows Embree if that changes.
enum class BvhQuality : uint8_t {
  kLow,
  kMedium,
  kHigh,
};

struct FiberSceneOptions {
  BvhQuality quality = BvhQuality::kMedium;
  int threads = 2;  // Embree build threads, [1, 64]; queries run on the caller's threads
  // Bytes Embree may hold for the scene at any moment of the build: buffers plus BVH plus the builder's
  // temporaries. [1, 2^50].
  int64_t max_bytes = int64_t{1} << 30;
  bool compact = false;  // RTC_SCENE_FLAG_COMPACT: Embree trades query speed for memory (5% less on cotton1)
  bool robust = false;   // RTC_SCENE_FLAG_ROBUST: Embree's more conservative traversal
  // Asked during the build, from Embree's threads concurrently (must be thread-safe and cheap); when it
  // returns true the build stops with "cancelled". Not kept after Build returns.
  std::function<bool()> cancel;
};

// "" or "field: reason".
std::string ValidateFiberSceneOptions(const FiberSceneOptions& o);

// An upper bound on what Build asks of the memory monitor, from the inputs' sizes alone (no float
// conversion, so merged points are still counted). bvh_bytes is kBvhBytesPerSegment per segment plus
// kBvhBytesFixed. Measured with Embree 3.13.5 (AVX2, 1 and 2 threads): the BVH and the builder's
// temporaries peak at 61-91 bytes per segment on straight cotton1, polyester1, rayon2 and silk1 yarns (1 and
// 10 long, 16 and 64 points per twist) and at 67-74 on random, coincident and single long curves, the same at
// every quality, so whole-build peaks are 0.45-0.75 of total_bytes on real yarns. Not measured above 2
// threads: Embree's per-thread allocation blocks may add to the fixed part there.
inline constexpr int64_t kBvhBytesPerSegment = 128;
inline constexpr int64_t kBvhBytesFixed = int64_t{256} << 10;
struct FiberSceneEstimate {
  int64_t curves = 0;
  int64_t segments = 0;
  int64_t vertices = 0;
  int64_t buffer_bytes = 0;  // vertex (16 B), index (4 B) and flags (1 B) buffers
  int64_t bvh_bytes = 0;     // BVH and builder temporaries
  int64_t total_bytes = 0;   // buffer_bytes + bvh_bytes
};
FiberSceneEstimate EstimateFiberScene(std::span<const YarnGeometry* const> yarns);

struct FiberSceneStats {
  int64_t curves = 0;          // curves in the scene
  int64_t skipped_curves = 0;  // curves with fewer than two distinct (float) points
  int64_t segments = 0;
  int64_t vertices = 0;
  int64_t peak_bytes = 0;      // most bytes the memory monitor saw held during the build
  int64_t embree_bytes = 0;    // bytes Embree holds for the built scene (buffers + BVH)
  int64_t host_bytes = 0;      // our per-segment and per-curve tables
  double build_seconds = 0;
  // After a failed build: what the monitor still counted once the scene was released (0 = Embree freed all
  // it had allocated for this build).
  int64_t bytes_after_release = 0;
};

// A ray: points origin + t direction for t in [tnear, tfar]. Caller contract: origin finite, |direction|^2 a
// finite positive float (so no zero, NaN or inf component; it need not be unit, t is in its units), 0 <=
// tnear <= tfar (tfar may be +inf). Rays that break it are not traced: Intersect reports a miss, Occluded
// "not occluded" (checked per ray, cheaply).
struct FiberRay {
  Float3 origin;
  Float3 direction;
  float tnear = 0;
  float tfar = std::numeric_limits<float>::infinity();
};

struct FiberHit {
  bool hit = false;
  bool entering = false;  // the ray enters the fiber here (false: it leaves it, having started inside)
  float t = std::numeric_limits<float>::infinity();
  Float3 position;  // origin + t direction
  Float3 tangent;   // unit, along the fiber's segment, in the curve's point order
  // Unit, for shading: the joints' mean directions interpolated along the segment; on a core, turned to the
  // direction of the fibers it stands for at the hit (YarnGeometry::core_turn_rate).
  Float3 shading_tangent;
  Float3 normal;    // unit surface normal (Embree's Ng for round curves), facing the ray (dot(normal, dir) <= 0)
  float u = 0;      // position along the segment, [0, 1]
  FiberType type = FiberType::kMigration;
  int ply = 0;
  int fiber = -1;
  int yarn = -1;     // index of the input YarnGeometry
  int curve = -1;    // index into that geometry's fibers
  int segment = -1;  // segment within the curve (between its merged points segment and segment + 1)
  float width = 0;   // the fiber's diameter
  // Cores: the mean free path across the fibers it stands for, and their width (PlyDetail).
  float core_free_path = 0;
  float core_fiber_width = 0;
};

class FiberScene {
 public:
  FiberScene();  // empty: misses every ray
  FiberScene(FiberScene&& other) noexcept;
  FiberScene& operator=(FiberScene&& other) noexcept;
  FiberScene(const FiberScene&) = delete;
  FiberScene& operator=(const FiberScene&) = delete;
  ~FiberScene();

  // Builds the scene of all fibers of `yarns` (hit yarn index = position in the span; null entries are
  // empty yarns). Returns "" and replaces *out, or an error leaving *out empty: "options.<field>: ...",
  // "yarns: ..." (non-finite point or width, more than 2^32 - 2 segments or vertices in one yarn),
  // "bvh_memory: ..." (over max_bytes), "cancelled", or "embree: ..." (Embree's own message). *stats, if
  // given, is filled in either case.
  static std::string Build(std::span<const YarnGeometry* const> yarns, const FiberSceneOptions& options,
                           FiberScene* out, FiberSceneStats* stats = nullptr);

  // No scene: default-constructed, moved from, or after a failed Build.
  bool empty() const { return scene_ == nullptr; }
  const FiberSceneStats& stats() const { return stats_; }
  // The scene's axis-aligned bounds (fiber radii included); lower > upper when empty.
  Float3 lower() const { return lower_; }
  Float3 upper() const { return upper_; }

  // hits.size() must equal rays.size() (else "hits: ..."); an empty scene misses everything. Closest hit.
  std::string Intersect(std::span<const FiberRay> rays, std::span<FiberHit> hits) const;
  // Any fiber the ray enters in [tnear, tfar]: occluded[i] = 1 or 0 (a tube the ray starts inside and leaves
  // does not block it: a shadow ray from inside overlapping fibers). occluded.size() must equal rays.size().
  std::string Occluded(std::span<const FiberRay> rays, std::span<uint8_t> occluded) const;

 private:
  struct Monitor;
  struct CurveInfo {
    FiberType type = FiberType::kMigration;
    int ply = 0;
    int fiber = -1;
    float width = 0;
    float core_free_path = 0;  // cores: PlyDetail::core_free_path and core_fiber_width
    float core_fiber_width = 0;
  };
  struct YarnTable {
    const float* vertices = nullptr;  // Embree's buffer (x, y, z, r per vertex), alive while the scene is
    const uint32_t* indices = nullptr;
    std::vector<uint32_t> segment_curve;  // curve index per segment (primID)
    std::vector<uint32_t> curve_first;    // first segment of each curve (skipped curves: that of the next)
    std::vector<CurveInfo> curves;        // per input curve
    float core_turn_rate = 0;             // YarnGeometry::core_turn_rate
  };
  void Release();
  static Float3 ShadingTangent(const YarnTable& table, uint32_t seg, const float* v0, Float3 tangent, float u);
  void Finish(const FiberRay& r, float tfar, uint32_t geom, uint32_t prim, float u, Float3 ng, FiberHit* out) const;

  RTCDeviceTy* device_ = nullptr;
  RTCSceneTy* scene_ = nullptr;
  std::unique_ptr<Monitor> monitor_;  // the device's callbacks point at it; released after the device
  std::vector<YarnTable> tables_;
  FiberSceneStats stats_;
  Float3 lower_{1, 1, 1};
  Float3 upper_{0, 0, 0};
};

}  // namespace loomlight::yarn
