#include "server/yarn/fiber_scene.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <utility>

#include "server/models/quote.h"
#include "server/yarn/embree_build_monitor.h"
#include "server/yarn/embree_mxcsr.h"

namespace loomlight::yarn {
namespace {

// Occluded's rule: a fiber blocks a ray where the ray enters it. A ray that starts inside a tube (the shading
// fiber's neighbours overlap it: a ply's fibers together cover about its whole cross-section, so they
// overlap) and leaves it is not blocked by that tube; Intersect still reports such exits (FiberHit.entering).
// For round curves Ng is the outward normal, so entering is dot(Ng, direction) <= 0.
void OnlyEnteringBlocks(const RTCFilterFunctionNArguments* args) {
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    const float along = RTCHitN_Ng_x(args->hit, args->N, i) * RTCRayN_dir_x(args->ray, args->N, i) +
                        RTCHitN_Ng_y(args->hit, args->N, i) * RTCRayN_dir_y(args->ray, args->N, i) +
                        RTCHitN_Ng_z(args->hit, args->N, i) * RTCRayN_dir_z(args->ray, args->N, i);
    if (along > 0) args->valid[i] = 0;
  }
}


constexpr int kMaxThreads = 64;
constexpr int64_t kMaxBytesLimit = int64_t{1} << 50;
// Embree's primitive and vertex ids are 32-bit, and ~0u is its "invalid" marker.
constexpr int64_t kMaxPerGeometry = int64_t{0xFFFFFFFE};
constexpr int64_t kVertexBytes = 16;  // float4
constexpr int64_t kIndexBytes = 4;
constexpr int64_t kFlagBytes = 1;
constexpr int64_t kBufferPaddingBytes = 64;  // per buffer: Embree pads buffers for its vector loads

using models::Number;

RTCBuildQuality ToEmbree(BvhQuality q) {
  switch (q) {
    case BvhQuality::kLow:
      return RTC_BUILD_QUALITY_LOW;
    case BvhQuality::kMedium:
      return RTC_BUILD_QUALITY_MEDIUM;
    case BvhQuality::kHigh:
      return RTC_BUILD_QUALITY_HIGH;
  }
  return RTC_BUILD_QUALITY_MEDIUM;
}

struct FloatPoint {
  float x, y, z;
  bool operator==(const FloatPoint&) const = default;
};

FloatPoint ToFloat(const Vec3& p) {
  return {static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)};
}

bool Finite(FloatPoint p) { return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z); }

// Points of `c` after the float conversion, consecutive equal ones merged (a zero-length segment has no
// tangent). Calls emit(point) for each kept point; returns how many, or -1 when a point is not finite.
template <typename Emit>
int64_t MergedPoints(const FiberCurve& c, Emit&& emit) {
  int64_t kept = 0;
  FloatPoint last{};
  for (const Vec3& p : c.points) {
    const FloatPoint f = ToFloat(p);
    if (!Finite(f)) return -1;
    if (kept > 0 && f == last) continue;
    emit(f);
    last = f;
    ++kept;
  }
  return kept;
}

bool ValidRay(const FiberRay& r) {
  const Float3& o = r.origin;
  const Float3& d = r.direction;
  if (!(std::isfinite(o.x) && std::isfinite(o.y) && std::isfinite(o.z))) return false;
  const float dd = d.x * d.x + d.y * d.y + d.z * d.z;  // NaN or inf components make this fail too
  if (!(dd > 0 && dd <= std::numeric_limits<float>::max())) return false;
  return r.tnear >= 0 && r.tnear <= r.tfar;  // NaN fails both
}

Float3 Normalized(float x, float y, float z) {
  const float n = std::sqrt(x * x + y * y + z * z);
  if (!(n > 0) || !std::isfinite(n)) return {0, 0, 0};
  return {x / n, y / n, z / n};
}

}  // namespace

// What the device's callbacks share with Build (embree_build_monitor.h). Heap-allocated so it stays put when the
// scene moves.
struct FiberScene::Monitor : EmbreeBuildMonitor {};

std::string ValidateFiberSceneOptions(const FiberSceneOptions& o) {
  if (o.quality != BvhQuality::kLow && o.quality != BvhQuality::kMedium && o.quality != BvhQuality::kHigh) {
    return "options.quality: is " + std::to_string(static_cast<int>(o.quality)) + ", must be low, medium or high";
  }
  if (o.threads < 1 || o.threads > kMaxThreads) {
    return "options.threads: is " + std::to_string(o.threads) + ", must be in 1.." + std::to_string(kMaxThreads);
  }
  if (o.max_bytes < 1 || o.max_bytes > kMaxBytesLimit) {
    return "options.max_bytes: is " + std::to_string(o.max_bytes) + ", must be in 1.." + std::to_string(kMaxBytesLimit);
  }
  return "";
}

FiberSceneEstimate EstimateFiberScene(std::span<const YarnGeometry* const> yarns) {
  FiberSceneEstimate e;
  int64_t geometries = 0;
  for (const YarnGeometry* y : yarns) {
    if (y == nullptr) continue;
    int64_t segments = 0;
    for (const FiberCurve& c : y->fibers) {
      const int64_t n = static_cast<int64_t>(c.points.size());
      if (n < 2) continue;
      ++e.curves;
      e.vertices += n;
      segments += n - 1;
    }
    e.segments += segments;
    if (segments > 0) ++geometries;
  }
  e.buffer_bytes = e.vertices * kVertexBytes + e.segments * (kIndexBytes + kFlagBytes) +
                   geometries * 3 * kBufferPaddingBytes;
  e.bvh_bytes = e.segments * kBvhBytesPerSegment + kBvhBytesFixed;
  e.total_bytes = e.buffer_bytes + e.bvh_bytes;
  return e;
}

FiberScene::FiberScene() = default;

FiberScene::FiberScene(FiberScene&& other) noexcept { *this = std::move(other); }

FiberScene& FiberScene::operator=(FiberScene&& other) noexcept {
  if (this == &other) return *this;
  Release();
  device_ = std::exchange(other.device_, nullptr);
  scene_ = std::exchange(other.scene_, nullptr);
  monitor_ = std::move(other.monitor_);
  tables_ = std::move(other.tables_);
  stats_ = std::exchange(other.stats_, {});
  lower_ = std::exchange(other.lower_, Float3{1, 1, 1});
  upper_ = std::exchange(other.upper_, Float3{0, 0, 0});
  return *this;
}

FiberScene::~FiberScene() { Release(); }

void FiberScene::Release() {
  // The scene before the device, and the device before the monitor its callbacks point at.
  if (scene_ != nullptr) rtcReleaseScene(scene_);
  if (device_ != nullptr) rtcReleaseDevice(device_);
  scene_ = nullptr;
  device_ = nullptr;
  monitor_.reset();
  tables_.clear();
  stats_ = {};
  lower_ = {1, 1, 1};
  upper_ = {0, 0, 0};
}

std::string FiberScene::Build(std::span<const YarnGeometry* const> yarns, const FiberSceneOptions& options,
                              FiberScene* out, FiberSceneStats* stats) {
  FiberSceneStats local;
  FiberSceneStats& st = stats != nullptr ? *stats : local;
  st = {};
  if (out == nullptr) return "out: is null";
  out->Release();
  if (std::string err = ValidateFiberSceneOptions(options); !err.empty()) return err;
  if (yarns.size() > static_cast<size_t>(kMaxPerGeometry)) return "yarns: too many";

  // Pass 1: validate and count, so the buffers can be allocated at their size (Embree's buffers do not grow).
  std::vector<int64_t> yarn_vertices(yarns.size(), 0);
  std::vector<int64_t> yarn_segments(yarns.size(), 0);
  for (size_t y = 0; y < yarns.size(); ++y) {
    if (yarns[y] == nullptr) continue;
    const std::vector<FiberCurve>& curves = yarns[y]->fibers;
    if (curves.size() > static_cast<size_t>(kMaxPerGeometry)) {
      return "yarns: yarn " + std::to_string(y) + " has too many curves";
    }
    for (size_t c = 0; c < curves.size(); ++c) {
      const float radius = static_cast<float>(curves[c].width / 2);
      if (!(radius > 0) || !std::isfinite(radius)) {
        return "yarns: yarn " + std::to_string(y) + " curve " + std::to_string(c) + " has width " +
               Number(curves[c].width) + ", must be positive and finite in float";
      }
      const int64_t n = MergedPoints(curves[c], [](FloatPoint) {});
      if (n < 0) {
        return "yarns: yarn " + std::to_string(y) + " curve " + std::to_string(c) +
               " has a point that is not finite in float";
      }
      if (n < 2) {
        ++st.skipped_curves;
        continue;
      }
      ++st.curves;
      yarn_vertices[y] += n;
      yarn_segments[y] += n - 1;
    }
    if (yarn_vertices[y] > kMaxPerGeometry) {
      return "yarns: yarn " + std::to_string(y) + " has " + std::to_string(yarn_vertices[y]) +
             " points, more than Embree's " + std::to_string(kMaxPerGeometry);
    }
    st.vertices += yarn_vertices[y];
    st.segments += yarn_segments[y];
  }

  const auto start = std::chrono::steady_clock::now();
  FiberScene scene;
  scene.monitor_ = std::make_unique<Monitor>();
  Monitor* m = scene.monitor_.get();
  m->limit = options.max_bytes;
  m->limit_name = "options.max_bytes";
  m->cancel = &options.cancel;
  m->building = true;
  if (m->ShouldCancel()) return "cancelled";

  // Workers made on first use, not pinned: the server shares its cores with other work.
  const std::string config = "threads=" + std::to_string(options.threads) + ",set_affinity=0,start_threads=0,verbose=0";
  scene.device_ = rtcNewDevice(config.c_str());
  if (scene.device_ == nullptr) {
    return std::string("embree: cannot create a device: ") + EmbreeErrorName(rtcGetDeviceError(nullptr));
  }
  m->Attach(scene.device_);

  // Every failure path goes through here: release what Embree holds and say what the monitor still counts.
  auto fail = [&](std::string err) {
    if (err.empty()) err = "embree: build failed";
    if (scene.scene_ != nullptr) rtcReleaseScene(scene.scene_);
    scene.scene_ = nullptr;
    st.bytes_after_release = m->current.load();
    st.peak_bytes = m->peak.load();
    st.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    scene.Release();
    return err;
  };

  scene.scene_ = rtcNewScene(scene.device_);
  if (scene.scene_ == nullptr) return fail(m->Status(scene.device_));
  RTCSceneFlags flags = RTC_SCENE_FLAG_NONE;
  if (options.compact) flags = flags | RTC_SCENE_FLAG_COMPACT;
  if (options.robust) flags = flags | RTC_SCENE_FLAG_ROBUST;
  rtcSetSceneFlags(scene.scene_, flags);
  rtcSetSceneBuildQuality(scene.scene_, ToEmbree(options.quality));
  rtcSetSceneProgressMonitorFunction(scene.scene_, &Monitor::OnProgress, m);

  scene.tables_.resize(yarns.size());
  for (size_t y = 0; y < yarns.size(); ++y) {
    if (m->ShouldCancel()) return fail("cancelled");
    YarnTable& table = scene.tables_[y];
    if (yarns[y] == nullptr) continue;
    const std::vector<FiberCurve>& curves = yarns[y]->fibers;
    table.curves.resize(curves.size());
    const std::vector<PlyDetail>& plies = yarns[y]->plies;
    for (size_t c = 0; c < curves.size(); ++c) {
      table.curves[c] = {curves[c].type, curves[c].ply, curves[c].fiber, static_cast<float>(curves[c].width)};
      if (curves[c].type == FiberType::kCore && curves[c].ply >= 0 && size_t(curves[c].ply) < plies.size()) {
        const PlyDetail& ply = plies[size_t(curves[c].ply)];
        table.curves[c].core_free_path = static_cast<float>(ply.core_free_path);
        table.curves[c].core_fiber_width = static_cast<float>(ply.core_fiber_width);
      }
    }
    table.core_turn_rate = static_cast<float>(yarns[y]->core_turn_rate);
    table.curve_first.assign(curves.size(), 0);
    if (yarn_segments[y] == 0) continue;  // Embree refuses empty buffers; hits never name this yarn

    RTCGeometry geom = rtcNewGeometry(scene.device_, RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE);
    if (geom == nullptr) return fail(m->Status(scene.device_));
    const size_t nv = static_cast<size_t>(yarn_vertices[y]);
    const size_t ns = static_cast<size_t>(yarn_segments[y]);
    auto* vertices = static_cast<float*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), nv));
    auto* indices = vertices == nullptr ? nullptr
                                        : static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
                                              geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT, sizeof(uint32_t), ns));
    auto* segment_flags = indices == nullptr ? nullptr
                                             : static_cast<uint8_t*>(rtcSetNewGeometryBuffer(
                                                   geom, RTC_BUFFER_TYPE_FLAGS, 0, RTC_FORMAT_UCHAR, 1, ns));
    if (segment_flags == nullptr) {
      rtcReleaseGeometry(geom);
      return fail(m->Status(scene.device_));
    }
    table.segment_curve.resize(ns);
    uint32_t v = 0;
    uint32_t s = 0;
    for (size_t c = 0; c < curves.size(); ++c) {
      table.curve_first[c] = s;
      const float radius = static_cast<float>(curves[c].width / 2);
      if (MergedPoints(curves[c], [](FloatPoint) {}) < 2) continue;  // skipped (counted in pass 1)
      const uint32_t first = v;
      float* dst = vertices + size_t{4} * v;
      const int64_t n = MergedPoints(curves[c], [&](FloatPoint p) {
        *dst++ = p.x;
        *dst++ = p.y;
        *dst++ = p.z;
        *dst++ = radius;
      });
      v += static_cast<uint32_t>(n);
      for (uint32_t k = first; k + 1 < v; ++k, ++s) {
        indices[s] = k;
        table.segment_curve[s] = static_cast<uint32_t>(c);
        // Neighbours only within the fiber: its joints are clipped, its two ends stay round caps.
        segment_flags[s] = static_cast<uint8_t>((k > first ? RTC_CURVE_FLAG_NEIGHBOR_LEFT : 0) |
                                                (k + 2 < v ? RTC_CURVE_FLAG_NEIGHBOR_RIGHT : 0));
      }
    }
    table.vertices = vertices;
    table.indices = indices;
    rtcSetGeometryBuildQuality(geom, ToEmbree(options.quality));
    rtcSetGeometryOccludedFilterFunction(geom, OnlyEnteringBlocks);
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(scene.scene_, geom, static_cast<unsigned>(y));
    rtcReleaseGeometry(geom);  // the scene holds it now
    if (std::string err = m->Status(scene.device_); !err.empty()) return fail(err);
  }
  if (m->ShouldCancel()) return fail("cancelled");

  rtcCommitScene(scene.scene_);
  if (std::string err = m->Status(scene.device_); !err.empty()) return fail(err);

  // Built: the caller's predicate may not outlive this call, and queries allocate nothing to limit.
  m->building = false;
  m->cancel = nullptr;
  RTCBounds b;
  rtcGetSceneBounds(scene.scene_, &b);
  if (st.segments > 0) {
    scene.lower_ = {b.lower_x, b.lower_y, b.lower_z};
    scene.upper_ = {b.upper_x, b.upper_y, b.upper_z};
  }
  st.peak_bytes = m->peak.load();
  st.embree_bytes = m->current.load();
  for (const YarnTable& t : scene.tables_) {
    st.host_bytes += static_cast<int64_t>(t.segment_curve.capacity() * sizeof(uint32_t) +
                                          t.curve_first.capacity() * sizeof(uint32_t) +
                                          t.curves.capacity() * sizeof(CurveInfo));
  }
  st.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  scene.stats_ = st;
  *out = std::move(scene);
  return "";
}

// The tangent a hit is shaded with: at each joint the mean of the two segments' directions, linear along the
// segment between its two joints (a round end keeps the segment's own), so a narrow lobe's highlight slides
// along a polyline fiber instead of lighting whole segments (the curve's true tangent turns smoothly).
Float3 FiberScene::ShadingTangent(const YarnTable& table, uint32_t seg, const float* v0, Float3 tangent, float u) {
  const uint32_t c = table.segment_curve[seg];
  const uint32_t first = table.curve_first[c];
  const uint32_t end = c + 1 < table.curve_first.size() ? table.curve_first[c + 1]
                                                        : static_cast<uint32_t>(table.segment_curve.size());
  const auto direction = [](const float* a, const float* b) { return Normalized(b[0] - a[0], b[1] - a[1], b[2] - a[2]); };
  const auto mean = [](Float3 a, Float3 b) { return Normalized(a.x + b.x, a.y + b.y, a.z + b.z); };
  const Float3 left = seg > first ? mean(direction(v0 - 4, v0), tangent) : tangent;
  const Float3 right = seg + 1 < end ? mean(tangent, direction(v0 + 4, v0 + 8)) : tangent;
  const float w = std::clamp(u, 0.0f, 1.0f);
  const Float3 t = Normalized((1 - w) * left.x + w * right.x, (1 - w) * left.y + w * right.y, (1 - w) * left.z + w * right.z);
  return t == Float3{} ? tangent : t;
}

// Embree's answer for one ray (its tfar, hit and Ng) made a FiberHit.
void FiberScene::Finish(const FiberRay& r, float tfar, uint32_t geom, uint32_t prim, float u, Float3 ng,
                        FiberHit* out) const {
  FiberHit& h = *out;
  if (geom == RTC_INVALID_GEOMETRY_ID || geom >= tables_.size()) return;
  const YarnTable& table = tables_[geom];
  const uint32_t seg = prim;
  if (seg >= table.segment_curve.size()) return;
  const float* v0 = table.vertices + size_t{4} * table.indices[seg];
  const float* v1 = v0 + 4;
  const Float3 tangent = Normalized(v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]);
  const Float3& d = r.direction;
  const float t = tfar;
  const Float3 p{r.origin.x + t * d.x, r.origin.y + t * d.y, r.origin.z + t * d.z};
  // For round curves Ng is the outward surface normal, unnormalised (its length is about the radius).
  Float3 n = Normalized(ng.x, ng.y, ng.z);
  if (n == Float3{}) {
    // Not seen from Embree; from the geometry if it ever happens: away from the segment's axis.
    const float a = (p.x - v0[0]) * tangent.x + (p.y - v0[1]) * tangent.y + (p.z - v0[2]) * tangent.z;
    n = Normalized(p.x - v0[0] - a * tangent.x, p.y - v0[1] - a * tangent.y, p.z - v0[2] - a * tangent.z);
    if (n == Float3{}) n = Normalized(-d.x, -d.y, -d.z);
  }
  const uint32_t c = table.segment_curve[seg];
  const CurveInfo& info = table.curves[c];
  Float3 shading = ShadingTangent(table, seg, v0, tangent, u);
  if (info.type == FiberType::kCore && table.core_turn_rate != 0) {
    // The core's fibers at its surface (n outward here) run along t + rate r (t x n).
    const float k = table.core_turn_rate * 0.5f * info.width;
    const Float3 side{shading.y * n.z - shading.z * n.y, shading.z * n.x - shading.x * n.z, shading.x * n.y - shading.y * n.x};
    const Float3 turned = Normalized(shading.x + k * side.x, shading.y + k * side.y, shading.z + k * side.z);
    if (!(turned == Float3{})) shading = turned;
  }
  const bool entering = n.x * d.x + n.y * d.y + n.z * d.z <= 0;
  if (!entering) n = {-n.x, -n.y, -n.z};
  h.hit = true;
  h.entering = entering;
  h.t = t;
  h.position = p;
  h.tangent = tangent;
  h.shading_tangent = shading;
  h.normal = n;
  h.u = std::clamp(u, 0.0f, 1.0f);
  h.type = info.type;
  h.ply = info.ply;
  h.fiber = info.fiber;
  h.yarn = static_cast<int>(geom);
  h.curve = static_cast<int>(c);
  h.segment = static_cast<int>(seg - table.curve_first[c]);
  h.width = info.width;
  h.core_free_path = info.core_free_path;
  h.core_fiber_width = info.core_fiber_width;
}

std::string FiberScene::Intersect(std::span<const FiberRay> rays, std::span<FiberHit> hits) const {
  if (hits.size() != rays.size()) {
    return "hits: has " + std::to_string(hits.size()) + " entries for " + std::to_string(rays.size()) + " rays";
  }
  for (FiberHit& h : hits) h = FiberHit{};
  if (scene_ == nullptr) return "";
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  if (rays.size() == 1) {
    const FiberRay& r = rays[0];
    if (!ValidRay(r)) return "";
    RTCRayHit rh;
    rh.ray.org_x = r.origin.x;
    rh.ray.org_y = r.origin.y;
    rh.ray.org_z = r.origin.z;
    rh.ray.tnear = r.tnear;
    rh.ray.dir_x = r.direction.x;
    rh.ray.dir_y = r.direction.y;
    rh.ray.dir_z = r.direction.z;
    rh.ray.time = 0;
    rh.ray.tfar = r.tfar;
    rh.ray.mask = ~0u;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    // A lone ray: on random rays at a cotton1 yarn (one thread, AVX2) rtcIntersect1 ran 1.9 Mrays/s,
    // rtcIntersect1M 1.6-2.0 and rtcIntersect8 packets 1.9-2.0.
    {
      const FlushDenormalsScope flush;
      rtcIntersect1(scene_, &context, &rh);
    }
    Finish(r, rh.ray.tfar, rh.hit.geomID, rh.hit.primID, rh.hit.u, {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z}, &hits[0]);
    return "";
  }
  // Several rays: packets of 16, which pay for coherent rays (one pixel's camera rays).
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  for (size_t first = 0; first < rays.size(); first += 16) {
    const size_t n = std::min<size_t>(16, rays.size() - first);
    alignas(64) int valid[16];
    alignas(64) RTCRayHit16 rh;
    for (size_t k = 0; k < 16; ++k) {
      const bool ok = k < n && ValidRay(rays[first + k]);
      valid[k] = ok ? -1 : 0;
      const FiberRay r = ok ? rays[first + k] : FiberRay{{0, 0, 0}, {0, 0, 1}, 0, 0};
      rh.ray.org_x[k] = r.origin.x;
      rh.ray.org_y[k] = r.origin.y;
      rh.ray.org_z[k] = r.origin.z;
      rh.ray.tnear[k] = r.tnear;
      rh.ray.dir_x[k] = r.direction.x;
      rh.ray.dir_y[k] = r.direction.y;
      rh.ray.dir_z[k] = r.direction.z;
      rh.ray.time[k] = 0;
      rh.ray.tfar[k] = r.tfar;
      rh.ray.mask[k] = ~0u;
      rh.ray.id[k] = 0;
      rh.ray.flags[k] = 0;
      rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
    }
    {
      const FlushDenormalsScope flush;
      rtcIntersect16(valid, scene_, &context, &rh);
    }
    for (size_t k = 0; k < n; ++k) {
      if (!valid[k]) continue;
      Finish(rays[first + k], rh.ray.tfar[k], rh.hit.geomID[k], rh.hit.primID[k], rh.hit.u[k],
             {rh.hit.Ng_x[k], rh.hit.Ng_y[k], rh.hit.Ng_z[k]}, &hits[first + k]);
    }
  }
  return "";
}

std::string FiberScene::Occluded(std::span<const FiberRay> rays, std::span<uint8_t> occluded) const {
  if (occluded.size() != rays.size()) {
    return "occluded: has " + std::to_string(occluded.size()) + " entries for " + std::to_string(rays.size()) +
           " rays";
  }
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  const FlushDenormalsScope flush;  // once for the whole loop: it does no arithmetic of its own
  for (size_t i = 0; i < rays.size(); ++i) {
    const FiberRay& r = rays[i];
    occluded[i] = 0;
    if (scene_ == nullptr || !ValidRay(r)) continue;
    RTCRay ray;
    ray.org_x = r.origin.x;
    ray.org_y = r.origin.y;
    ray.org_z = r.origin.z;
    ray.tnear = r.tnear;
    ray.dir_x = r.direction.x;
    ray.dir_y = r.direction.y;
    ray.dir_z = r.direction.z;
    ray.time = 0;
    ray.tfar = r.tfar;
    ray.mask = ~0u;
    ray.id = 0;
    ray.flags = 0;
    rtcOccluded1(scene_, &context, &ray);
    // Embree marks an occluded ray by setting tfar to -inf.
    occluded[i] = ray.tfar < 0 ? 1 : 0;
  }
  return "";
}

}  // namespace loomlight::yarn
