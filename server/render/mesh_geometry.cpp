#include "server/render/mesh_geometry.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>
#include <utility>
#include <vector>

#include "server/render/scene.h"
#include "server/yarn/embree_build_monitor.h"
#include "server/yarn/embree_mxcsr.h"

namespace loomlight::render {
namespace {

using assets::TriangleMesh;

// Embree's primitive and vertex ids are 32-bit, and ~0u is its "invalid" marker.
constexpr uint64_t kMaxEmbreeIds = 0xFFFFFFFE;
constexpr size_t kStopInterval = size_t{1} << 16;  // elements checked between two questions to `stop`
// Embree intersects in float: a ray leaving a surface point can meet its own triangle a few float steps of the
// coordinates' magnitude away (a point on a mesh 200 units across, offset by the renderer's 1e-6, was shadowed by
// its own triangle on 4 rays in 10). Hits nearer than this many float steps of the largest coordinate (the ray's
// origin's or the mesh's) are not taken.
constexpr double kSelfHitSteps = 64;
static_assert(sizeof(std::array<float, 3>) == 12 && sizeof(std::array<uint32_t, 3>) == 12,
              "Embree reads the mesh's vectors as packed float3 and uint3");

// "" or "mesh: <name> K is not finite" for the first element of `values` with a NaN or infinite component.
template <size_t N>
std::string CheckFinite(const std::vector<std::array<float, N>>& values, const char* name) {
  for (size_t i = 0; i < values.size(); ++i)
    for (float c : values[i])
      if (!std::isfinite(c)) return std::string("mesh: ") + name + " " + std::to_string(i) + " is not finite";
  return "";
}

// What the intersection code relies on (ParseMesh guarantees it; a mesh built otherwise gets a reason): every
// per-vertex array empty or one entry per position, tangents exactly where there are UVs, one material per
// triangle (or none: all material 0), material and vertex indices in range, finite values, within Embree's
// 32-bit ids.
template <class ShouldStop>
std::string CheckMesh(const TriangleMesh& m, ShouldStop should_stop) {
  const size_t n = m.positions.size();
  if (m.triangles.empty()) return "mesh: has no triangles";
  if (n > kMaxEmbreeIds || m.triangles.size() > kMaxEmbreeIds) {
    return "mesh: " + std::to_string(n) + " vertices and " + std::to_string(m.triangles.size()) +
           " triangles, more than Embree's " + std::to_string(kMaxEmbreeIds);
  }
  const auto per_vertex = [n](size_t size, const char* name) {
    return size == 0 || size == n ? std::string()
                                  : std::string("mesh: has ") + std::to_string(size) + " " + name + " for " +
                                        std::to_string(n) + " vertices";
  };
  for (std::string err : {per_vertex(m.normals.size(), "normals"), per_vertex(m.uvs.size(), "uvs")})
    if (!err.empty()) return err;
  if (m.tangents.size() != m.uvs.size()) {
    return "mesh: has " + std::to_string(m.tangents.size()) + " tangents for " + std::to_string(m.uvs.size()) +
           " uvs (tangents come with uvs, one per vertex)";
  }
  if (!m.triangle_material.empty() && m.triangle_material.size() != m.triangles.size()) {
    return "mesh: has " + std::to_string(m.triangle_material.size()) + " triangle materials for " +
           std::to_string(m.triangles.size()) + " triangles";
  }
  for (std::string err : {CheckFinite(m.positions, "position"), CheckFinite(m.normals, "normal"),
                          CheckFinite(m.uvs, "uv"), CheckFinite(m.tangents, "tangent")})
    if (!err.empty()) return err;
  const size_t materials = std::max<size_t>(m.material_names.size(), 1);
  for (size_t i = 0; i < m.triangles.size(); ++i) {
    if (i % kStopInterval == 0 && should_stop()) return "stopped";
    if (!m.triangle_material.empty() && m.triangle_material[i] >= materials) {
      return "mesh: triangle " + std::to_string(i) + " has material " + std::to_string(m.triangle_material[i]) +
             ", the mesh names " + std::to_string(m.material_names.size());
    }
    for (uint32_t v : m.triangles[i])
      if (v >= n) {
        return "mesh: triangle " + std::to_string(i) + " has vertex index " + std::to_string(v) + ", the mesh has " +
               std::to_string(n) + " vertices";
      }
  }
  return "";
}

Vec3 ToVec(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }
Vec3 ToVec(const std::array<float, 4>& a) { return {a[0], a[1], a[2]}; }

// The barycentric interpolation of a per-vertex attribute over triangle `tri` (weights b, summing to 1).
template <class Value, class Get>
auto Interpolate(const std::array<uint32_t, 3>& tri, const std::array<double, 3>& b, const std::vector<Value>& values,
                 Get get) {
  return b[0] * get(values[tri[0]]) + b[1] * get(values[tri[1]]) + b[2] * get(values[tri[2]]);
}

bool ValidRay(Vec3 origin, Vec3 direction, double min_distance, double max_distance) {
  return IsFinite(origin) && IsFinite(direction) && Dot(direction, direction) > 0 && min_distance >= 0 &&
         min_distance <= max_distance;  // NaN fails both
}

double MaxAbs(Vec3 v) { return std::max({std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)}); }

}  // namespace

struct MeshGeometry::Impl {
  yarn::EmbreeBuildMonitor monitor;  // the device's callbacks point at it: released after the device
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  // Embree reads a vertex buffer's last element with a 16-byte load, 4 bytes past a float3's end. The mesh's own
  // positions serve when their allocation extends past the last element (capacity beyond size: those bytes are
  // the vector's, read and ignored); otherwise this copy with one spare element.
  std::vector<std::array<float, 3>> padded_positions;
  double max_abs_coordinate = 0;  // over the mesh's positions

  // The ray's nearest distance: min_distance, or the float precision of its coordinates (kSelfHitSteps).
  double NearestDistance(Vec3 origin, Vec3 direction, double min_distance) const {
    const double scale = std::max(MaxAbs(origin), max_abs_coordinate);
    const double self_hit = kSelfHitSteps * std::numeric_limits<float>::epsilon() * scale / Length(direction);
    return std::max(min_distance, self_hit);
  }

  ~Impl() {
    if (scene != nullptr) rtcReleaseScene(scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }

  // Embree's closest hit (primitive `prim` at ray parameter `tfar`, barycentrics u and v of vertices 1 and 2)
  // as Intersect's Hit.
  void Surface(const TriangleMesh& m, Vec3 origin, Vec3 direction, float tfar, uint32_t prim, float u, float v,
               double uv_length, Hit* hit) const;
};

void MeshGeometry::Impl::Surface(const TriangleMesh& m, Vec3 origin, Vec3 direction, float tfar, uint32_t prim,
                                 float u, float v, double uv_length, Hit* hit) const {
  *hit = Hit{};
  const std::array<uint32_t, 3>& tri = m.triangles[prim];
  const double b1 = std::clamp<double>(u, 0, 1), b2 = std::clamp<double>(v, 0, 1 - b1);
  const std::array<double, 3> b{1 - b1 - b2, b1, b2};
  hit->distance = tfar;
  hit->position = origin + double(tfar) * direction;
  hit->object = m.triangle_material.empty() ? 0 : static_cast<int>(m.triangle_material[prim]);

  const Vec3 p0 = ToVec(m.positions[tri[0]]);
  Vec3 geometric = Normalize(Cross(ToVec(m.positions[tri[1]]) - p0, ToVec(m.positions[tri[2]]) - p0));
  if (Length(geometric) == 0) geometric = Normalize(-direction);  // Embree hits no zero-area triangle; guarded
  const auto xyz = [](const auto& a) { return ToVec(a); };
  Vec3 normal = m.normals.empty() ? Vec3{} : Normalize(Interpolate(tri, b, m.normals, xyz));
  if (Length(normal) == 0) normal = geometric;

  if (m.uvs.empty()) {
    // No texture coordinates: any frame about the normal, on the side the triangle's winding faces.
    if (Dot(normal, geometric) < 0) normal = -normal;
    hit->normal = normal;
    hit->tangent_s = AnyPerpendicular(normal);
    hit->tangent_t = Cross(normal, hit->tangent_s);
    return;
  }
  const auto uv = [](const std::array<float, 2>& a) { return Vec3{a[0], a[1], 0}; };
  const Vec3 st = uv_length * Interpolate(tri, b, m.uvs, uv);
  hit->s = st.x;
  hit->t = st.y;
  // tangent_s: +u, made perpendicular to the normal (Gram-Schmidt). tangent_t: +v, which the vertices' handedness
  // w places at w (normal x tangent) (glTF's bitangent).
  const Vec3 along_u = Interpolate(tri, b, m.tangents, xyz);
  Vec3 tangent = Normalize(along_u - Dot(along_u, normal) * normal);
  if (Length(tangent) == 0) tangent = AnyPerpendicular(normal);
  const double w = Interpolate(tri, b, m.tangents, [](const auto& a) { return double(a[3]); });
  const double handedness = w < 0 ? -1.0 : 1.0;
  hit->tangent_s = tangent;
  hit->tangent_t = handedness * Cross(normal, tangent);
  // The frame's normal is tangent_s x tangent_t, so the frame is right-handed with x = +u and y = +v (SPEC.md
  // section 1): the vertex normal where the UVs keep their orientation on the surface, the opposite way on a
  // mirrored UV panel (w = -1), whose frame then faces the vertex normal's back. The renderer shades both sides
  // alike (ShadeHit mirrors directions seen from behind), so only a transmitting material's front and back
  // swap there. The winding's side is not imposed here: it would turn +v around on a file whose winding
  // disagrees with its normals, and break the frame's continuity where a smooth normal crosses a facet's plane.
  hit->normal = handedness * normal;
}

MeshGeometry::~MeshGeometry() = default;

std::string MeshGeometry::Build(std::shared_ptr<const assets::TriangleMesh> mesh, uint64_t max_bvh_bytes,
                                const std::function<bool()>& stop, std::shared_ptr<const MeshGeometry>* out) {
  if (out == nullptr) return "out: is null";
  if (mesh == nullptr) return "mesh: is null";

  std::shared_ptr<MeshGeometry> built(new MeshGeometry());
  built->mesh_ = mesh;
  built->impl_ = std::make_unique<Impl>();
  Impl& impl = *built->impl_;
  yarn::EmbreeBuildMonitor& m = impl.monitor;
  m.limit = static_cast<int64_t>(std::min<uint64_t>(max_bvh_bytes, std::numeric_limits<int64_t>::max()));
  m.limit_name = "max_bvh_bytes";
  m.cancelled_status = "stopped";
  m.cancel = &stop;
  m.building = true;
  if (std::string err = CheckMesh(*mesh, [&m] { return m.ShouldCancel(); }); !err.empty()) return err;
  for (const std::array<float, 3>& p : mesh->positions)
    impl.max_abs_coordinate = std::max(impl.max_abs_coordinate, MaxAbs(ToVec(p)));
  if (m.ShouldCancel()) return m.cancelled_status;

  // Workers made on first use, not pinned: the server shares its cores with other work. Embree's thread count is
  // process-wide (the largest any live device asked for), so a mesh's device asks for every core once.
  const unsigned threads = std::clamp(std::thread::hardware_concurrency(), 1u, 64u);
  const std::string config = "threads=" + std::to_string(threads) + ",set_affinity=0,start_threads=0,verbose=0";
  impl.device = rtcNewDevice(config.c_str());
  if (impl.device == nullptr) {
    return std::string("embree: cannot create a device: ") + yarn::EmbreeErrorName(rtcGetDeviceError(nullptr));
  }
  m.Attach(impl.device);
  const auto failed = [&] {
    std::string err = m.Status(impl.device);
    return err.empty() ? std::string("embree: build failed") : err;
  };

  impl.scene = rtcNewScene(impl.device);
  if (impl.scene == nullptr) return failed();
  rtcSetSceneBuildQuality(impl.scene, RTC_BUILD_QUALITY_MEDIUM);
  rtcSetSceneProgressMonitorFunction(impl.scene, &yarn::EmbreeBuildMonitor::OnProgress, &m);

  const std::vector<std::array<float, 3>>* positions = &mesh->positions;
  if (positions->capacity() == positions->size()) {
    impl.padded_positions.reserve(positions->size() + 1);  // the insert below keeps this capacity
    impl.padded_positions.insert(impl.padded_positions.end(), positions->begin(), positions->end());
    positions = &impl.padded_positions;
  }
  RTCGeometry geometry = rtcNewGeometry(impl.device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (geometry == nullptr) return failed();
  rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, positions->data(), 0,
                             sizeof(std::array<float, 3>), positions->size());
  rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, mesh->triangles.data(), 0,
                             sizeof(std::array<uint32_t, 3>), mesh->triangles.size());
  rtcCommitGeometry(geometry);
  rtcAttachGeometryByID(impl.scene, geometry, 0);
  rtcReleaseGeometry(geometry);  // the scene holds it now
  if (std::string err = m.Status(impl.device); !err.empty()) return err;
  if (m.ShouldCancel()) return m.cancelled_status;

  rtcCommitScene(impl.scene);
  if (std::string err = m.Status(impl.device); !err.empty()) return err;
  // Built: the caller's predicate may not outlive this call, and queries allocate nothing to limit.
  m.building = false;
  m.cancel = nullptr;
  built->bvh_bytes_ = static_cast<uint64_t>(std::max<int64_t>(m.current.load(), 0));
  *out = std::move(built);
  return "";
}

bool MeshGeometry::Intersect(Vec3 origin, Vec3 direction, double min_distance, double max_distance, double uv_length,
                             Hit* hit) const {
  if (!ValidRay(origin, direction, min_distance, max_distance)) return false;
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh;
  rh.ray.org_x = static_cast<float>(origin.x);
  rh.ray.org_y = static_cast<float>(origin.y);
  rh.ray.org_z = static_cast<float>(origin.z);
  rh.ray.tnear = static_cast<float>(impl_->NearestDistance(origin, direction, min_distance));
  rh.ray.dir_x = static_cast<float>(direction.x);
  rh.ray.dir_y = static_cast<float>(direction.y);
  rh.ray.dir_z = static_cast<float>(direction.z);
  rh.ray.time = 0;
  rh.ray.tfar = static_cast<float>(max_distance);
  rh.ray.mask = ~0u;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  {
    const yarn::FlushDenormalsScope flush;
    rtcIntersect1(impl_->scene, &context, &rh);
  }
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  impl_->Surface(*mesh_, origin, direction, rh.ray.tfar, rh.hit.primID, rh.hit.u, rh.hit.v, uv_length, hit);
  return true;
}

void MeshGeometry::IntersectFrom(Vec3 origin, std::span<const Vec3> directions, double uv_length, std::span<Hit> hits,
                                 std::span<uint8_t> found) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;  // one origin, neighbouring directions: a pixel's rays
  constexpr size_t kPacket = 16;
  for (size_t first = 0; first < directions.size(); first += kPacket) {
    const size_t n = std::min(kPacket, directions.size() - first);
    alignas(64) int valid[kPacket];
    alignas(64) RTCRayHit16 rh;
    for (size_t k = 0; k < kPacket; ++k) {
      const bool ok = k < n && ValidRay(origin, directions[first + k], 0, INFINITY);
      valid[k] = ok ? -1 : 0;
      const Vec3 d = ok ? directions[first + k] : Vec3{0, 0, 1};
      rh.ray.org_x[k] = static_cast<float>(origin.x);
      rh.ray.org_y[k] = static_cast<float>(origin.y);
      rh.ray.org_z[k] = static_cast<float>(origin.z);
      rh.ray.tnear[k] = static_cast<float>(impl_->NearestDistance(origin, d, 0));
      rh.ray.dir_x[k] = static_cast<float>(d.x);
      rh.ray.dir_y[k] = static_cast<float>(d.y);
      rh.ray.dir_z[k] = static_cast<float>(d.z);
      rh.ray.time[k] = 0;
      rh.ray.tfar[k] = INFINITY;
      rh.ray.mask[k] = ~0u;
      rh.ray.id[k] = 0;
      rh.ray.flags[k] = 0;
      rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
    }
    {
      const yarn::FlushDenormalsScope flush;
      rtcIntersect16(valid, impl_->scene, &context, &rh);
    }
    for (size_t k = 0; k < n; ++k) {
      const size_t i = first + k;
      found[i] = valid[k] != 0 && rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
      if (found[i]) {
        impl_->Surface(*mesh_, origin, directions[i], rh.ray.tfar[k], rh.hit.primID[k], rh.hit.u[k], rh.hit.v[k],
                       uv_length, &hits[i]);
      }
    }
  }
}

bool MeshGeometry::Occluded(Vec3 origin, Vec3 direction, double min_distance, double max_distance) const {
  if (!ValidRay(origin, direction, min_distance, max_distance)) return false;
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay ray;
  ray.org_x = static_cast<float>(origin.x);
  ray.org_y = static_cast<float>(origin.y);
  ray.org_z = static_cast<float>(origin.z);
  ray.tnear = static_cast<float>(impl_->NearestDistance(origin, direction, min_distance));
  ray.dir_x = static_cast<float>(direction.x);
  ray.dir_y = static_cast<float>(direction.y);
  ray.dir_z = static_cast<float>(direction.z);
  ray.time = 0;
  ray.tfar = static_cast<float>(max_distance);
  ray.mask = ~0u;
  ray.id = 0;
  ray.flags = 0;
  {
    const yarn::FlushDenormalsScope flush;
    rtcOccluded1(impl_->scene, &context, &ray);
  }
  return ray.tfar < 0;  // Embree marks an occluded ray by setting tfar to -inf
}

}  // namespace loomlight::render
