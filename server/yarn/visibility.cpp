#include "server/yarn/visibility.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <deque>
#include <limits>
#include <mutex>
#include <numbers>
#include <utility>

#include "server/yarn/embree_mxcsr.h"

namespace loomlight::yarn {
namespace {

constexpr double kTwoPi = 2 * std::numbers::pi;
constexpr size_t kSharedCrossSections = 4;  // ~4.7 MB each at the default 192 x 192 x 32

// The parameters a cross-section depends on; the others set to cotton1's so equal densities share one.
YarnParams DensityParams(const YarnParams& p) {
  YarnParams key;
  key.plies = p.plies;
  key.fibers_per_ply = p.fibers_per_ply;
  key.yarn_radius = p.yarn_radius;
  key.ellipse_n = p.ellipse_n;
  key.ellipse_b = p.ellipse_b;
  key.eps = p.eps;
  key.beta = p.beta;
  key.fiber_width = p.fiber_width;
  return key;
}


}  // namespace

const char* ToString(ShadowMethod m) { return m == ShadowMethod::kTraced ? "traced" : "slices"; }
const char* ToString(OcclusionMethod m) {
  switch (m) {
    case OcclusionMethod::kTraced:
      return "traced";
    case OcclusionMethod::kTexture:
      return "texture";
    case OcclusionMethod::kDistance:
      return "distance";
  }
  return "traced";
}

// Other yarns as opaque tubes: a prism of kTubeSides sides along each yarn's centre polyline, a triangle mesh
// per yarn in an Embree scene of its own (triangles are Embree's cheapest primitive: a ray through a few tubes
// costs a fraction of the same tubes as round curves). A tube blocks a ray where the ray enters it, so a fiber
// inside another yarn's tube (yarns touch at crossings) is not shadowed by it, and its own yarn is skipped.
class TubeMesh {
 public:
  static std::string Make(const std::vector<std::shared_ptr<const YarnCurve>>& centres, double radius,
                          const std::function<bool()>& stop, TubeMesh* out);
  TubeMesh() = default;
  TubeMesh(const TubeMesh&) = delete;
  TubeMesh& operator=(const TubeMesh&) = delete;
  ~TubeMesh();
  bool Blocks(int yarn, Vec3 p, Vec3 w, double max_distance) const;

 private:
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  size_t yarns_ = 0;
};

namespace {

constexpr int kTubeSides = 8;

struct TubeContext {
  RTCIntersectContext base;  // first, so a pointer to it is one to the whole
  int skip_yarn = -1;
};

// Rejects hits on the skipped yarn and where the ray leaves a tube. The mesh winds counterclockwise seen from
// outside, so Embree's Ng points outward (tests/yarn_visibility_test.cpp checks both ways): a ray enters where
// it runs against Ng.
void OnlyEnteringOtherTubes(const RTCFilterFunctionNArguments* args) {
  const int skip = reinterpret_cast<const TubeContext*>(args->context)->skip_yarn;
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    const float along = RTCHitN_Ng_x(args->hit, args->N, i) * RTCRayN_dir_x(args->ray, args->N, i) +
                        RTCHitN_Ng_y(args->hit, args->N, i) * RTCRayN_dir_y(args->ray, args->N, i) +
                        RTCHitN_Ng_z(args->hit, args->N, i) * RTCRayN_dir_z(args->ray, args->N, i);
    if (along > 0 || (skip >= 0 && RTCHitN_instID(args->hit, args->N, i, 0) == unsigned(skip))) args->valid[i] = 0;
  }
}

Vec3 Unit(Vec3 v) { return (1 / Norm(v)) * v; }

}  // namespace

std::string TubeMesh::Make(const std::vector<std::shared_ptr<const YarnCurve>>& centres, double radius,
                           const std::function<bool()>& stop, TubeMesh* out) {
  out->device_ = rtcNewDevice("threads=1");
  if (!out->device_) return "embree: cannot create a device";
  out->scene_ = rtcNewScene(out->device_);
  // Watertight: a ray through a prism's edge (straight down onto a crest, say) hits one of its two triangles
// (measured: 15% slower than without).
  rtcSetSceneFlags(out->scene_, RTC_SCENE_FLAG_ROBUST);
  out->yarns_ = centres.size();
  // The prism's cross-section has the round tube's area.
  const double ring = radius * std::sqrt(2 * std::numbers::pi / (kTubeSides * std::sin(2 * std::numbers::pi / kTubeSides)));
  for (size_t y = 0; y < centres.size(); ++y) {
    if (stop && stop()) return "cancelled";
    // Vertices at least a radius apart (fewer, longer prisms); the chords cut into a crimped yarn's crest by
    // under a tenth of its radius at a layout's 16 points per crossing.
    const std::vector<Vec3> polyline = centres[y]->CentrePolyline();
    std::vector<Vec3> points;
    for (size_t k = 0; k < polyline.size(); ++k)
      if (k == 0 || k + 1 == polyline.size() || Norm(polyline[k] - points.back()) >= radius) points.push_back(polyline[k]);
    if (points.size() < 2 || !(Norm(points.back() - points.front()) > 0)) continue;
    RTCGeometry geom = rtcNewGeometry(out->device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    const size_t n = points.size();
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), n * kTubeSides));
    auto* t = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                             3 * sizeof(unsigned), 2 * (n - 1) * kTubeSides));
    if (!v || !t) {
      rtcReleaseGeometry(geom);
      return "embree: cannot allocate the tubes";
    }
    // Rings in a frame carried along the polyline (each normal the last one made perpendicular to the new tangent).
    Vec3 normal;
    for (size_t k = 0; k < n; ++k) {
      const Vec3 tangent = Unit(points[std::min(k + 1, n - 1)] - points[k > 0 ? k - 1 : 0]);
      if (k == 0) normal = Cross(tangent, std::abs(tangent.x) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0});
      normal = normal - Dot(normal, tangent) * tangent;
      normal = Norm(normal) > 1e-9 ? Unit(normal) : Unit(Cross(tangent, Vec3{0, 0, 1}));
      const Vec3 binormal = Cross(tangent, normal);
      for (int j = 0; j < kTubeSides; ++j) {
        const double a = 2 * std::numbers::pi * j / kTubeSides;
        const Vec3 q = points[k] + (ring * std::cos(a)) * normal + (ring * std::sin(a)) * binormal;
        float* dst = v + 3 * (k * kTubeSides + j);
        dst[0] = float(q.x), dst[1] = float(q.y), dst[2] = float(q.z);
      }
    }
    for (size_t k = 0; k + 1 < n; ++k)
      for (int j = 0; j < kTubeSides; ++j) {
        const unsigned a = unsigned(k * kTubeSides + j), b = unsigned(k * kTubeSides + (j + 1) % kTubeSides);
        const unsigned c = a + kTubeSides, d = b + kTubeSides;
        unsigned* tri = t + 6 * (k * kTubeSides + j);
        tri[0] = a, tri[1] = b, tri[2] = d;  // counterclockwise from outside: around the tangent, then along it
        tri[3] = a, tri[4] = d, tri[5] = c;
      }
    rtcSetGeometryOccludedFilterFunction(geom, OnlyEnteringOtherTubes);
    rtcCommitGeometry(geom);
    // Each tube its own scene, instanced (identity) as instance y: a ray skips its own yarn's instance by its
    // mask bit before traversing any of it (it starts inside that tube, so its triangles are all around it;
    // measured on a cotton1 plain weave: toward the light 79 ns a ray instead of 145, random directions 190
    // instead of 291), where no other yarn shares the bit; beyond 32 yarns the filter skips it.
    RTCScene tube = rtcNewScene(out->device_);
    rtcSetSceneFlags(tube, RTC_SCENE_FLAG_ROBUST);
    rtcAttachGeometry(tube, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(tube);
    RTCGeometry instance = rtcNewGeometry(out->device_, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(instance, tube);
    rtcReleaseScene(tube);  // the instance holds it
    const float identity[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};
    rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, identity);
    rtcSetGeometryMask(instance, 1u << (y % 32));
    rtcCommitGeometry(instance);
    rtcAttachGeometryByID(out->scene_, instance, unsigned(y));
    rtcReleaseGeometry(instance);
  }
  rtcCommitScene(out->scene_);
  if (rtcGetDeviceError(out->device_) != RTC_ERROR_NONE) return "embree: building the tubes failed";
  return "";
}

TubeMesh::~TubeMesh() {
  if (scene_) rtcReleaseScene(scene_);
  if (device_) rtcReleaseDevice(device_);
}

bool TubeMesh::Blocks(int yarn, Vec3 p, Vec3 w, double max_distance) const {
  if (!scene_) return false;
  TubeContext context;
  rtcInitIntersectContext(&context.base);
  context.skip_yarn = yarn;
  RTCRay ray;
  ray.org_x = float(p.x), ray.org_y = float(p.y), ray.org_z = float(p.z);
  ray.dir_x = float(w.x), ray.dir_y = float(w.y), ray.dir_z = float(w.z);
  if (!std::isfinite(ray.org_x + ray.org_y + ray.org_z + ray.dir_x + ray.dir_y + ray.dir_z)) return false;
  ray.tnear = 0;
  ray.tfar = std::isfinite(max_distance) ? float(max_distance) : std::numeric_limits<float>::infinity();
  ray.time = 0;
  ray.mask = yarn >= 0 && yarn < 32 && yarns_ <= 32 ? ~(1u << yarn) : ~0u;
  ray.id = 0;
  ray.flags = 0;
  {
    const FlushDenormalsScope flush;
    rtcOccluded1(scene_, &context.base, &ray);
  }
  return ray.tfar < 0;  // Embree marks an occluded ray by setting tfar to -inf
}

std::string SharedCrossSection(const YarnParams& params, const CrossSectionOptions& options,
                               std::shared_ptr<const YarnCrossSection>* out) {
  struct Entry {
    YarnParams key;
    CrossSectionOptions options;
    std::shared_ptr<const YarnCrossSection> value;
  };
  static std::mutex mutex;
  static std::deque<Entry> entries;  // most recent first
  const YarnParams key = DensityParams(params);
  {
    std::lock_guard lock(mutex);
    for (auto it = entries.begin(); it != entries.end(); ++it) {
      if (it->key == key && it->options == options) {
        Entry hit = *it;
        entries.erase(it);
        entries.push_front(hit);
        *out = hit.value;
        return "";
      }
    }
  }
  // Built outside the lock (a quarter second): two calls may build the same one; both results are equal.
  auto built = std::make_shared<YarnCrossSection>();
  if (std::string e = YarnCrossSection::Make(params, options, built.get()); !e.empty()) return e;
  std::lock_guard lock(mutex);
  entries.push_front({key, options, built});
  if (entries.size() > kSharedCrossSections) entries.pop_back();
  *out = std::move(built);
  return "";
}

// The openness nodes of each yarn: one set per arc step along the centre, kOpennessAngles about it (a
// "diamond" angle: the quadrant plus |b| / (|n| + |b|) within it, monotone in the angle without a
// trigonometric call) and kOpennessRadii distances from it, up to kOpennessReach tube radii (fibers lie within
// about 1.2; farther points, hairs, take the outermost node).
constexpr double kOpennessArcStep = 0.5;  // tube radii: ~9 nodes per crossing interval at the default spacing
constexpr int kOpennessAngles = 8;
constexpr int kOpennessRadii = 3;
constexpr double kOpennessReach = 1.2;
constexpr int kOpennessZ = 8;  // the directions' strata: 8 in z (equal areas of the sphere) x 8 in azimuth

struct YarnVisibility::OpennessTable {
  struct Yarn {
    double step = 1;  // arc length between nodes
    int arcs = 0;
    size_t first = 0;  // its first node
  };
  std::vector<Yarn> yarns;
  double radius = 1;  // the tubes'
  // Per node: its openness, or -1 until traced. Relaxed atomics: a node raced to by two threads gets the same
  // value from both.
  std::unique_ptr<std::atomic<float>[]> nodes;
  size_t count = 0;
};

namespace {

// The point (n, b) of a diamond angle d in [0, 4) on the unit circle.
void DiamondToUnit(double d, double* n, double* b) {
  const int quadrant = static_cast<int>(d) & 3;
  const double f = d - std::floor(d);
  double x = 1 - f, y = f;
  const double length = std::sqrt(x * x + y * y);
  x /= length, y /= length;
  for (int q = 0; q < quadrant; ++q) std::swap(x, y), x = -x;  // a quarter turn each
  *n = x, *b = y;
}

// The diamond angle of (n, b), in [0, 4); 0 at the origin.
double UnitToDiamond(double n, double b) {
  const double sum = std::fabs(n) + std::fabs(b);
  if (!(sum > 0)) return 0;
  if (b >= 0) return n >= 0 ? b / sum : 1 + (-n) / sum;
  return n < 0 ? 2 + (-b) / sum : 3 + n / sum;
}

// A node's own azimuth offset for its strata, from its index (Weyl sequence): neighbouring nodes do not share
// their directions' aliasing.
double NodeJitter(size_t node) { return std::fmod(0.5 + 0.6180339887498949 * double(node), 1.0); }

}  // namespace

std::string YarnVisibility::Make(const YarnParams& params, std::vector<std::shared_ptr<const YarnCurve>> centres,
                                 double tube_radius, const CrossSectionOptions& options, std::function<bool()> stop,
                                 YarnVisibility* out) {
  if (centres.empty()) return "centres: no yarn";
  for (const auto& c : centres)
    if (!c) return "centres: a null curve";
  if (!std::isfinite(tube_radius) || tube_radius < kMinLength || tube_radius > kMaxLength)
    return "tube_radius: must be finite in the yarn lengths' range";
  YarnVisibility v;
  if (std::string e = SharedCrossSection(params, options, &v.cross_section_); !e.empty()) return e;
  v.alpha_yarn_ = params.alpha_yarn;
  if (centres.size() > 1) {
    auto tubes = std::make_shared<TubeMesh>();
    if (std::string e = TubeMesh::Make(centres, tube_radius, stop, tubes.get()); !e.empty()) return "tubes: " + e;
    v.tubes_ = std::move(tubes);
    auto table = std::make_shared<OpennessTable>();
    table->radius = tube_radius;
    // The arc step grows when the yarns are long enough to take the table over its byte cap.
    double length = 0;
    for (const auto& c : centres) length += c->Length();
    const size_t per_arc = size_t{kOpennessAngles} * kOpennessRadii;
    const double max_arcs = double(kMaxOpennessBytes / sizeof(float) / per_arc) - 2.0 * double(centres.size());
    if (!(max_arcs >= 2.0 * double(centres.size()))) return "centres: too many yarns for the openness table";
    const double step = std::max(kOpennessArcStep * tube_radius, length / max_arcs);
    for (const auto& c : centres) {
      OpennessTable::Yarn y;
      y.arcs = std::max(2, static_cast<int>(std::ceil(c->Length() / step)) + 1);
      y.step = c->Length() / (y.arcs - 1);
      y.first = table->count;
      table->count += size_t(y.arcs) * per_arc;
      table->yarns.push_back(y);
    }
    table->nodes = std::make_unique<std::atomic<float>[]>(table->count);
    for (size_t i = 0; i < table->count; ++i) table->nodes[i].store(-1.0f, std::memory_order_relaxed);
    v.openness_ = std::move(table);
  }
  v.centres_ = std::move(centres);
  *out = std::move(v);
  return "";
}

CrossSectionPoint YarnVisibility::Locate(int yarn, Vec3 p) const {
  CrossSectionPoint out;
  if (yarn < 0 || yarn >= yarns()) return out;
  const YarnCurve& curve = *centres_[size_t(yarn)];
  double arc = 0;
  const CurveFrame f = curve.ClosestFrame(p, &arc);
  out.yarn = yarn;
  out.normal = f.normal;
  out.binormal = Cross(f.tangent, f.normal);
  const double phase = kTwoPi * arc / alpha_yarn_;
  out.cos_phase = std::cos(phase);
  out.sin_phase = std::sin(phase);
  const Vec3 d = p - f.position;
  const double n = Dot(d, out.normal), b = Dot(d, out.binormal);
  out.arc = arc;
  out.n = n;
  out.b = b;
  // Turned back by the phase: ply j's centre is then at angle 2 pi j / K, as in the cross-section.
  out.x = out.cos_phase * n + out.sin_phase * b;
  out.y = -out.sin_phase * n + out.cos_phase * b;
  return out;
}

double YarnVisibility::SelfShadow(const CrossSectionPoint& x, Vec3 w, double own_radius) const {
  if (x.yarn < 0) return 1;
  // The light's direction in the cross-section, turned back likewise (its component along the yarn does not
  // change the depth).
  const double n = Dot(w, x.normal), b = Dot(w, x.binormal);
  return cross_section_->ShadowToward(x.x, x.y, x.cos_phase * n + x.sin_phase * b, -x.sin_phase * n + x.cos_phase * b,
                                      own_radius);
}

bool YarnVisibility::OtherYarnsBlock(int yarn, Vec3 p, Vec3 w, double max_distance) const {
  return tubes_ && tubes_->Blocks(yarn, p, w, max_distance);
}

double YarnVisibility::Occlusion(const CrossSectionPoint& x, OcclusionMethod method) const {
  if (method == OcclusionMethod::kTraced || x.yarn < 0) return 1;
  return method == OcclusionMethod::kTexture ? cross_section_->Occlusion(x.x, x.y)
                                             : cross_section_->DistanceOcclusion(std::sqrt(x.x * x.x + x.y * x.y));
}

size_t YarnVisibility::openness_bytes() const { return openness_ ? openness_->count * sizeof(float) : 0; }

double YarnVisibility::OtherYarnsOpenness(const CrossSectionPoint& x) const {
  if (!openness_ || x.yarn < 0 || x.yarn >= yarns()) return 1;
  if (!std::isfinite(x.arc + x.n + x.b)) return 1;  // not a place in the table (the indices below need finite input)
  const OpennessTable& table = *openness_;
  const OpennessTable::Yarn& y = table.yarns[size_t(x.yarn)];
  const YarnCurve& curve = *centres_[size_t(x.yarn)];
  // Trilinear in (arc, angle, distance); the angle wraps.
  const double fa = std::clamp(x.arc / y.step, 0.0, double(y.arcs - 1));
  const double fd = UnitToDiamond(x.n, x.b) * (kOpennessAngles / 4.0);
  const double fr = std::min(std::sqrt(x.n * x.n + x.b * x.b) / (kOpennessReach * table.radius), 1.0) * (kOpennessRadii - 1);
  const int a0 = std::min(static_cast<int>(fa), y.arcs - 2), d0 = static_cast<int>(fd) % kOpennessAngles,
            r0 = std::min(static_cast<int>(fr), kOpennessRadii - 2);
  const double ta = fa - a0, td = fd - std::floor(fd), tr = fr - r0;
  const auto node = [&](int a, int d, int r) -> double {
    const size_t index = y.first + (size_t(a) * kOpennessAngles + size_t(d % kOpennessAngles)) * kOpennessRadii + size_t(r);
    const float known = table.nodes[index].load(std::memory_order_relaxed);
    if (known >= 0) return known;
    // Trace it: the node's point, rays in kOpennessDirections directions, one per equal-area stratum.
    const CurveFrame f = curve.At(a * y.step);
    double un = 0, ub = 0;
    DiamondToUnit(4.0 * (d % kOpennessAngles) / kOpennessAngles, &un, &ub);
    const double distance = kOpennessReach * table.radius * r / (kOpennessRadii - 1);
    const Vec3 p = f.position + (distance * un) * f.normal + (distance * ub) * Cross(f.tangent, f.normal);
    const double jitter = NodeJitter(index);
    constexpr int kAzimuths = kOpennessDirections / kOpennessZ;
    int open = 0;
    for (int i = 0; i < kOpennessZ; ++i) {
      const double z = 1 - 2 * (i + 0.5) / kOpennessZ, s = std::sqrt(std::max(0.0, 1 - z * z));
      for (int j = 0; j < kAzimuths; ++j) {
        const double phi = kTwoPi * (j + jitter) / kAzimuths;
        if (!tubes_->Blocks(x.yarn, p, {s * std::cos(phi), s * std::sin(phi), z}, INFINITY)) ++open;
      }
    }
    const float value = float(open) / float(kOpennessDirections);
    table.nodes[index].store(value, std::memory_order_relaxed);
    return value;
  };
  double sum = 0;
  for (int da = 0; da < 2; ++da)
    for (int dd = 0; dd < 2; ++dd)
      for (int dr = 0; dr < 2; ++dr) {
        const double w = (da ? ta : 1 - ta) * (dd ? td : 1 - td) * (dr ? tr : 1 - tr);
        if (w > 0) sum += w * node(a0 + da, d0 + dd, r0 + dr);
      }
  return sum;
}

}  // namespace loomlight::yarn
