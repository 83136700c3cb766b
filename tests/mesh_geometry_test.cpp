// A triangle mesh in Embree (server/render/mesh_geometry.h) and in a render::Scene, against closed forms computed
// here: a tessellated unit sphere against the analytic one within the tessellation's own bound, the UV tangent frame
// on quads whose UVs are rotated or mirrored, packets against single rays, occlusion against the closest hit, the
// BVH byte limit and the stop predicate, a mesh beside an analytic shape in one scene, and a sphere mesh rendered
// like the analytic sphere within the renders' own noise.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <numbers>
#include <random>
#include <stdexcept>
#include <vector>

#include "server/assets/mesh_file.h"
#include "server/models/material_cache.h"
#include "server/models/registry.h"
#include "server/render/environment.h"
#include "server/render/mesh_geometry.h"
#include "server/render/renderer.h"
#include "server/render/scene.h"
#include "server/render/shading.h"
#include "tests/renderer_testing.h"

namespace loomlight {
namespace {

using assets::TriangleMesh;
using render::Hit;
using render::MeshGeometry;
using render::Vec3;

constexpr double kPi = std::numbers::pi;

std::array<float, 3> F3(Vec3 v) { return {float(v.x), float(v.y), float(v.z)}; }
Vec3 V3(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

// A sphere of `radius` at the origin tessellated along longitude and latitude: (columns + 1) x (rows + 1) vertices
// (the seam's column twice, at u = 0 and u = 1; each pole a row of coincident vertices), u = longitude / 2 pi and
// v = latitude / 2 pi (one scale on both axes), longitude measured from +z toward +x (the analytic sphere's s).
// Per vertex: the exact normal, the tangent east (d position / d longitude) with w = +1 (normal x east = north,
// the way v grows). Two triangles per cell, wound counter-clockwise seen from outside; none of zero area at the
// poles.
std::shared_ptr<TriangleMesh> LatLongSphere(int columns, int rows, double radius = 1) {
  auto mesh = std::make_shared<TriangleMesh>();
  for (int i = 0; i <= rows; ++i)
    for (int j = 0; j <= columns; ++j) {
      const double lat = -kPi / 2 + kPi * i / rows, lon = 2 * kPi * j / columns;
      const Vec3 n{std::cos(lat) * std::sin(lon), std::sin(lat), std::cos(lat) * std::cos(lon)};
      mesh->positions.push_back(F3(radius * n));
      mesh->normals.push_back(F3(n));
      mesh->uvs.push_back({float(lon / (2 * kPi)), float(lat / (2 * kPi))});
      mesh->tangents.push_back({float(std::cos(lon)), 0.0f, float(-std::sin(lon)), 1.0f});
    }
  const auto at = [columns](int i, int j) { return uint32_t(i * (columns + 1) + j); };
  for (int i = 0; i < rows; ++i)
    for (int j = 0; j < columns; ++j) {
      const uint32_t a = at(i, j), b = at(i, j + 1), c = at(i + 1, j), d = at(i + 1, j + 1);
      if (i > 0) mesh->triangles.push_back({a, b, d});
      if (i + 1 < rows) mesh->triangles.push_back({a, d, c});
    }
  mesh->triangle_material.assign(mesh->triangles.size(), 0);
  mesh->material_names = {"sphere"};
  return mesh;
}

std::shared_ptr<const MeshGeometry> MustBuild(std::shared_ptr<const TriangleMesh> mesh) {
  std::shared_ptr<const MeshGeometry> built;
  const std::string err = MeshGeometry::Build(std::move(mesh), uint64_t{1} << 30, [] { return false; }, &built);
  EXPECT_EQ(err, "");
  EXPECT_NE(built, nullptr);
  return built;
}

// The smallest distance from the centre to a triangle's plane, over the mesh's triangles: every triangle's vertices
// are on the unit sphere, so its plane cuts the sphere in the triangle's circumcircle (radius R = abc / (4 area)),
// at sqrt(1 - R^2) from the centre, and the whole mesh lies between that radius and 1.
double InnerRadius(const TriangleMesh& mesh) {
  double inner = 1;
  for (const auto& tri : mesh.triangles) {
    const Vec3 p0 = V3(mesh.positions[tri[0]]), p1 = V3(mesh.positions[tri[1]]), p2 = V3(mesh.positions[tri[2]]);
    const double a = render::Length(p1 - p0), b = render::Length(p2 - p1), c = render::Length(p0 - p2);
    const double area = 0.5 * render::Length(render::Cross(p1 - p0, p2 - p0));
    const double circumradius = a * b * c / (4 * area);
    inner = std::min(inner, std::sqrt(std::max(0.0, 1 - circumradius * circumradius)));
  }
  return inner;
}

double Angle(Vec3 a, Vec3 b) {
  return std::atan2(render::Length(render::Cross(a, b)), render::Dot(a, b));
}

void ExpectNear(Vec3 actual, Vec3 expected, double tolerance, const char* what) {
  EXPECT_LE(render::Length(actual - expected), tolerance)
      << what << ": (" << actual.x << ", " << actual.y << ", " << actual.z << ") expected (" << expected.x << ", "
      << expected.y << ", " << expected.z << ")";
}

// The frame's promises whatever the mesh: unit, orthogonal, right-handed.
void ExpectRightHandedFrame(const Hit& h) {
  EXPECT_NEAR(render::Length(h.normal), 1, 1e-9);
  EXPECT_NEAR(render::Length(h.tangent_s), 1, 1e-9);
  EXPECT_NEAR(render::Length(h.tangent_t), 1, 1e-9);
  EXPECT_NEAR(render::Dot(h.normal, h.tangent_s), 0, 1e-9);
  EXPECT_NEAR(render::Dot(h.normal, h.tangent_t), 0, 1e-9);
  ExpectNear(render::Cross(h.tangent_s, h.tangent_t), h.normal, 1e-9, "tangent_s x tangent_t");
}

TEST(MeshGeometry, SphereMeshHitsAgreeWithTheAnalyticSphere) {
  constexpr int kColumns = 96, kRows = 48;
  const auto mesh = LatLongSphere(kColumns, kRows);
  const auto geometry = MustBuild(mesh);
  const double inner = InnerRadius(*mesh);
  ASSERT_GT(inner, 0.99);
  const double cell_lon = 2 * kPi / kColumns, cell_lat = kPi / kRows;

  render::Scene sphere;
  sphere.objects.push_back({"sphere", render::SphereShape({0, 0, 0}, 1)});
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uniform(0, 1);
  int compared = 0;
  for (int k = 0; k < 2000; ++k) {
    // A ray from a random point 4 away toward a random point of the disc of radius 0.8 facing it: impact
    // parameter p <= 0.8 < inner, so it meets both surfaces at an angle no flatter than asin(0.8) to the normal.
    const double z = 2 * uniform(rng) - 1, phi = 2 * kPi * uniform(rng);
    const Vec3 toward{std::sqrt(1 - z * z) * std::cos(phi), z, std::sqrt(1 - z * z) * std::sin(phi)};
    const Vec3 side = render::AnyPerpendicular(toward), up = render::Cross(toward, side);
    const double r = 0.8 * std::sqrt(uniform(rng)), a = 2 * kPi * uniform(rng);
    const Vec3 origin = 4 * toward, target = r * std::cos(a) * side + r * std::sin(a) * up;
    const Vec3 d = render::Normalize(target - origin);
    Hit analytic, meshed;
    ASSERT_TRUE(sphere.Intersect(origin, d, 0, INFINITY, &analytic));
    ASSERT_TRUE(geometry->Intersect(origin, d, 0, INFINITY, 2 * kPi, &meshed));
    EXPECT_EQ(meshed.object, 0);
    EXPECT_FALSE(meshed.fiber);
    ExpectRightHandedFrame(meshed);
    ExpectNear(meshed.position, origin + meshed.distance * d, 1e-9, "position on the ray");

    // Distance: the mesh lies in the shell between `inner` and 1, so the ray meets it no earlier than the sphere
    // and no later than where it reaches radius `inner` (float positions and Embree's float arithmetic: 1e-5).
    const double p = render::Length(origin - render::Dot(origin, d) * d);
    const double shell = std::sqrt(1 - p * p) - std::sqrt(inner * inner - p * p);
    EXPECT_GE(meshed.distance, analytic.distance - 1e-5);
    EXPECT_LE(meshed.distance, analytic.distance + shell + 1e-5);
    // Normal: the vertex normals are the vertices' positions, so the interpolated normal is the direction of the
    // mesh's hit point; it and the analytic hit are on one ray at least `inner` from the centre, apart by at most
    // `shell`: their directions differ by at most shell / inner radians.
    const double turned = shell / inner + 1e-5;
    EXPECT_LE(Angle(meshed.normal, analytic.normal), turned);

    // The frame and the coordinates away from the poles (where longitude, and the analytic frame, turn fast):
    // within a cell of the analytic hit's, plus the longitude the two points' small separation spans there.
    const double lat = std::asin(std::clamp(analytic.normal.y, -1.0, 1.0));
    if (std::fabs(lat) > kPi / 3) continue;
    ++compared;
    const double lon_slack = turned / std::cos(lat);
    // tangent_s east (+u), tangent_t north (+v): the analytic sphere's tangents.
    EXPECT_LE(Angle(meshed.tangent_s, analytic.tangent_s), cell_lon + lon_slack + turned);
    EXPECT_LE(Angle(meshed.tangent_t, analytic.tangent_t), cell_lon + lon_slack + turned);
    // s = u 2 pi is the longitude in [0, 2 pi] (the analytic one in (-pi, pi]); t = v 2 pi the latitude.
    const double ds = std::remainder(meshed.s - analytic.s, 2 * kPi);
    EXPECT_LE(std::fabs(ds), cell_lon + lon_slack) << meshed.s << " vs " << analytic.s;
    EXPECT_LE(std::fabs(meshed.t - analytic.t), cell_lat + turned) << meshed.t << " vs " << analytic.t;
  }
  EXPECT_GT(compared, 1000);
}

// A 2 x 2 quad in the xy plane (normal +z, wound counter-clockwise seen from +z) with the given per-corner UVs and
// one tangent for all four corners (xyz and the handedness w).
std::shared_ptr<TriangleMesh> Quad(const std::array<std::array<float, 2>, 4>& uvs, std::array<float, 4> tangent) {
  auto mesh = std::make_shared<TriangleMesh>();
  mesh->positions = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};
  mesh->normals.assign(4, {0, 0, 1});
  mesh->uvs.assign(uvs.begin(), uvs.end());
  mesh->tangents.assign(4, tangent);
  mesh->triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh->triangle_material = {0, 0};
  mesh->material_names = {"cloth"};
  return mesh;
}

// The quad's hit at (0.3, -0.2, 0), seen from +z (front) or -z (back).
Hit QuadHit(const MeshGeometry& quad, double uv_length, bool from_back = false) {
  const Vec3 origin{0.3, -0.2, from_back ? -5.0 : 5.0}, d{0, 0, from_back ? 1.0 : -1.0};
  Hit h;
  EXPECT_TRUE(quad.Intersect(origin, d, 0, INFINITY, uv_length, &h));
  EXPECT_NEAR(h.distance, 5, 1e-6);
  ExpectNear(h.position, {0.3, -0.2, 0}, 1e-6, "position");
  ExpectRightHandedFrame(h);
  return h;
}

TEST(MeshGeometry, TangentFrameFollowsTheUvs) {
  constexpr double kUvLength = 3;
  // u = (x + 1) / 2, v = (y + 1) / 2: +u is +x, +v is +y (w = +1: z x x = y). The tangent is given tilted out of
  // the surface: Gram-Schmidt against the normal leaves +x.
  const auto plain = MustBuild(Quad({{{0, 0}, {1, 0}, {1, 1}, {0, 1}}}, {2, 0, 1, 1}));
  for (bool back : {false, true}) {
    const Hit h = QuadHit(*plain, kUvLength, back);
    ExpectNear(h.tangent_s, {1, 0, 0}, 1e-6, "tangent_s");
    ExpectNear(h.tangent_t, {0, 1, 0}, 1e-6, "tangent_t");
    ExpectNear(h.normal, {0, 0, 1}, 1e-6, "normal");  // the surface's frame, whichever side the ray comes from
    EXPECT_NEAR(h.s, 0.65 * kUvLength, 1e-6);
    EXPECT_NEAR(h.t, 0.4 * kUvLength, 1e-6);
  }
  // The UVs turned 90 degrees: u = (y + 1) / 2, v = (1 - x) / 2, so +u is +y and +v is -x (w = +1: z x y = -x).
  // The warp (v) runs along the other world axis.
  const auto turned = MustBuild(Quad({{{0, 1}, {0, 0}, {1, 0}, {1, 1}}}, {0, 1, 0, 1}));
  const Hit h = QuadHit(*turned, kUvLength);
  ExpectNear(h.tangent_s, {0, 1, 0}, 1e-6, "tangent_s");
  ExpectNear(h.tangent_t, {-1, 0, 0}, 1e-6, "tangent_t");
  ExpectNear(h.normal, {0, 0, 1}, 1e-6, "normal");
  EXPECT_NEAR(h.s, 0.4 * kUvLength, 1e-6);
  EXPECT_NEAR(h.t, 0.35 * kUvLength, 1e-6);
}

TEST(MeshGeometry, MirroredUvsKeepTheFrameRightHandedFacingTheBack) {
  // u = (1 - x) / 2, v = (y + 1) / 2: +u is -x and +v is +y, a mirror image of the plain layout (w = -1: the
  // bitangent -(z x -x) = +y). x = +u and y = +v hold; the right-handed frame's normal is then -z, the back of
  // the vertex normal.
  constexpr double kUvLength = 2;
  const auto mirrored = MustBuild(Quad({{{1, 0}, {0, 0}, {0, 1}, {1, 1}}}, {-1, 0, 0, -1}));
  for (bool back : {false, true}) {
    const Hit h = QuadHit(*mirrored, kUvLength, back);
    ExpectNear(h.tangent_s, {-1, 0, 0}, 1e-6, "tangent_s");
    ExpectNear(h.tangent_t, {0, 1, 0}, 1e-6, "tangent_t");
    ExpectNear(h.normal, {0, 0, -1}, 1e-6, "normal");
    EXPECT_NEAR(h.s, 0.35 * kUvLength, 1e-6);
    EXPECT_NEAR(h.t, 0.4 * kUvLength, 1e-6);
  }
}

TEST(MeshGeometry, WithoutUvsTheNormalFacesTheWindingsSide) {
  // Vertex normals pointing against the winding (-z for a quad wound counter-clockwise seen from +z): the frame's
  // normal is turned to +z; s and t are 0.
  auto mesh = Quad({{{0, 0}, {1, 0}, {1, 1}, {0, 1}}}, {1, 0, 0, 1});
  mesh->uvs.clear();
  mesh->tangents.clear();
  mesh->normals.assign(4, {0, 0, -1});
  const auto geometry = MustBuild(mesh);
  for (bool back : {false, true}) {
    const Hit h = QuadHit(*geometry, 1, back);
    ExpectNear(h.normal, {0, 0, 1}, 1e-9, "normal");
    EXPECT_EQ(h.s, 0);
    EXPECT_EQ(h.t, 0);
  }
  // Without normals too: the winding's normal.
  mesh->normals.clear();
  const Hit h = QuadHit(*MustBuild(mesh), 1);
  ExpectNear(h.normal, {0, 0, 1}, 1e-9, "normal");
}

void ExpectSameHit(const Hit& a, const Hit& b) {
  EXPECT_NEAR(a.distance, b.distance, 1e-6 * b.distance);
  EXPECT_EQ(a.object, b.object);
  ExpectNear(a.position, b.position, 1e-6, "position");
  ExpectNear(a.normal, b.normal, 1e-6, "normal");
  ExpectNear(a.tangent_s, b.tangent_s, 1e-6, "tangent_s");
  ExpectNear(a.tangent_t, b.tangent_t, 1e-6, "tangent_t");
  EXPECT_NEAR(a.s, b.s, 1e-6);
  EXPECT_NEAR(a.t, b.t, 1e-6);
}

// Directions from `origin` spread around the way to the origin: some meet the unit sphere, some pass it; one is
// zero (an invalid ray: a miss both ways).
std::vector<Vec3> SpreadDirections(Vec3 origin, int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0, 0.2);
  std::vector<Vec3> directions;
  for (int i = 0; i < n; ++i)
    directions.push_back(render::Normalize(-1.0 / render::Length(origin) * origin +
                                           Vec3{normal(rng), normal(rng), normal(rng)}));
  directions[n / 2] = {0, 0, 0};
  return directions;
}

TEST(MeshGeometry, IntersectFromEqualsIntersectRayByRay) {
  const auto geometry = MustBuild(LatLongSphere(48, 24));
  const Vec3 origin{0.5, 0.3, 4};
  const std::vector<Vec3> directions = SpreadDirections(origin, 37, 11);  // two packets and a part
  std::vector<Hit> hits(directions.size());
  std::vector<uint8_t> found(directions.size(), 2);
  geometry->IntersectFrom(origin, directions, 1.5, hits, found);
  int hit = 0;
  for (size_t i = 0; i < directions.size(); ++i) {
    Hit one;
    const bool single = geometry->Intersect(origin, directions[i], 0, INFINITY, 1.5, &one);
    ASSERT_EQ(found[i], single ? 1 : 0) << i;
    if (!single) continue;
    ++hit;
    ExpectSameHit(hits[i], one);
  }
  EXPECT_GT(hit, 5);
  EXPECT_LT(hit, int(directions.size()) - 5);
}

TEST(MeshGeometry, OccludedAgreesWithIntersect) {
  const auto geometry = MustBuild(LatLongSphere(48, 24));
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> box(-2, 2), length(0, 4);
  std::normal_distribution<double> normal;
  int blocked = 0, clear = 0;
  for (int k = 0; k < 3000; ++k) {
    const Vec3 origin{box(rng), box(rng), box(rng)};  // some inside the sphere
    const Vec3 d = render::Normalize({normal(rng), normal(rng), normal(rng)});
    const double lo = k % 2 ? 0.0 : 0.5 * length(rng), hi = lo + length(rng);
    Hit h;
    const bool found = geometry->Intersect(origin, d, lo, INFINITY, 1, &h);
    if (found && (std::fabs(h.distance - hi) < 1e-4 || std::fabs(h.distance - lo) < 1e-4)) continue;  // float
    const bool expected = found && h.distance < hi;
    EXPECT_EQ(geometry->Occluded(origin, d, lo, hi), expected) << k;
    ++(expected ? blocked : clear);
  }
  EXPECT_GT(blocked, 300);
  EXPECT_GT(clear, 300);
}

TEST(MeshGeometry, ShadowRaysLeaveTheirOwnTriangleAtAnyScale) {
  // A square of half-side `scale` at z = 0 seen from above; from each hit, a shadow ray toward a light 20 degrees
  // from the normal, started as the renderer starts it (kRayOffset along the normal). Embree's float arithmetic
  // must not find the square itself; a second square 1e-4 scale above it (in a mesh of both) must block the ray.
  const Vec3 toward_light = render::Normalize({0.3, 0.2, 1});
  for (double scale : {1.0, 100.0, 1e4}) {
    auto base = Quad({{{0, 0}, {1, 0}, {1, 1}, {0, 1}}}, {1, 0, 0, 1});
    for (auto& p : base->positions) p = F3(scale * V3(p));
    auto covered = std::make_shared<TriangleMesh>(*base);
    for (const auto& p : base->positions) covered->positions.push_back(F3(2 * V3(p) + Vec3{0, 0, 1e-4 * scale}));
    covered->normals.assign(8, {0, 0, 1});
    covered->uvs.insert(covered->uvs.end(), base->uvs.begin(), base->uvs.end());
    covered->tangents.assign(8, base->tangents[0]);
    covered->triangles.push_back({4, 5, 6});
    covered->triangles.push_back({4, 6, 7});
    covered->triangle_material.assign(4, 0);
    const auto alone = MustBuild(base), under_cover = MustBuild(covered);
    std::mt19937_64 rng(9);
    std::uniform_real_distribution<double> across(-0.5 * scale, 0.5 * scale);
    int self_shadowed = 0, uncovered = 0;
    for (int k = 0; k < 1000; ++k) {
      const Vec3 origin{0.3 * scale, 0.2 * scale, 3 * scale};
      const Vec3 d = render::Normalize(Vec3{across(rng), across(rng), 0} - origin);
      Hit h;
      ASSERT_TRUE(alone->Intersect(origin, d, 0, INFINITY, 1, &h));
      const Vec3 from = h.position + render::kRayOffset * h.normal;
      self_shadowed += alone->Occluded(from, toward_light, 0, INFINITY);
      uncovered += !under_cover->Occluded(from, toward_light, 0, INFINITY);
    }
    EXPECT_EQ(self_shadowed, 0) << "scale " << scale;
    EXPECT_EQ(uncovered, 0) << "scale " << scale;
  }
}

TEST(MeshGeometry, PositionsSharedOrCopiedHitAlike) {
  // Embree reads 4 bytes past the last float3 vertex: the mesh's own vector serves when it has room beyond its
  // size, a padded copy when it has none. Both give the same hits.
  auto roomy = LatLongSphere(24, 12);
  roomy->positions.reserve(roomy->positions.size() + 8);
  auto exact = std::make_shared<TriangleMesh>(*roomy);
  exact->positions = std::vector<std::array<float, 3>>(roomy->positions.begin(), roomy->positions.end());
  ASSERT_GT(roomy->positions.capacity(), roomy->positions.size());
  ASSERT_EQ(exact->positions.capacity(), exact->positions.size());
  const auto a = MustBuild(roomy), b = MustBuild(exact);
  const Vec3 origin{0.2, -0.4, 3};
  int hit = 0;
  for (const Vec3& d : SpreadDirections(origin, 64, 3)) {
    Hit ha, hb;
    const bool found = a->Intersect(origin, d, 0, INFINITY, 1, &ha);
    ASSERT_EQ(b->Intersect(origin, d, 0, INFINITY, 1, &hb), found);
    if (!found) continue;
    ++hit;
    ExpectSameHit(ha, hb);
  }
  EXPECT_GT(hit, 10);
}

TEST(MeshGeometry, BvhByteLimitStopsTheBuild) {
  const auto mesh = LatLongSphere(128, 64);
  const auto built = MustBuild(mesh);
  const uint64_t bytes = built->bvh_bytes();
  ASSERT_GT(bytes, 0u);
  std::printf("BVH of %zu triangles: %llu bytes\n", mesh->triangles.size(), static_cast<unsigned long long>(bytes));
  // The monitor refuses any allocation that would take Embree past the limit, so a build that held `bytes` at
  // its end cannot finish under half of them (more than any thread's allocation blocks vary from run to run).
  for (uint64_t limit : {uint64_t{1000}, bytes / 2}) {
    std::shared_ptr<const MeshGeometry> out;
    const std::string err = MeshGeometry::Build(mesh, limit, {}, &out);
    EXPECT_EQ(err.rfind("bvh_memory: ", 0), 0u) << err;
    EXPECT_NE(err.find("over the limit of " + std::to_string(limit) + " bytes (max_bvh_bytes)"), std::string::npos)
        << err;
    EXPECT_EQ(out, nullptr);
  }
  // A limit the build fits in: what it holds is within it.
  std::shared_ptr<const MeshGeometry> out;
  ASSERT_EQ(MeshGeometry::Build(mesh, 4 * bytes, {}, &out), "");
  EXPECT_LE(out->bvh_bytes(), 4 * bytes);
}

TEST(MeshGeometry, StopStopsTheBuild) {
  const auto mesh = LatLongSphere(256, 128);
  {
    std::shared_ptr<const MeshGeometry> out;
    EXPECT_EQ(MeshGeometry::Build(mesh, uint64_t{1} << 30, [] { return true; }, &out), "stopped");
    EXPECT_EQ(out, nullptr);
  }
  // Count how often a whole build asks, then say stop at later questions: the build stops wherever it is.
  std::atomic<int> asked{0};
  std::shared_ptr<const MeshGeometry> whole;
  ASSERT_EQ(MeshGeometry::Build(mesh, uint64_t{1} << 30, [&] { return ++asked, false; }, &whole), "");
  const int total = asked.load();
  std::printf("a build of %zu triangles asked %d times\n", mesh->triangles.size(), total);
  ASSERT_GT(total, 3);  // more than Build's own questions before the BVH: Embree asked during the build
  for (int stop_at : {2, 3, 4, std::max(4, total / 4)}) {
    std::atomic<int> n{0};
    std::shared_ptr<const MeshGeometry> out;
    EXPECT_EQ(MeshGeometry::Build(mesh, uint64_t{1} << 30, [&] { return ++n >= stop_at; }, &out), "stopped")
        << stop_at << " of " << total;
    EXPECT_EQ(out, nullptr);
  }
  // A predicate that throws counts as "stop" rather than unwinding through Embree.
  std::shared_ptr<const MeshGeometry> out;
  EXPECT_EQ(MeshGeometry::Build(mesh, uint64_t{1} << 30, []() -> bool { throw std::runtime_error("boom"); }, &out),
            "stopped");
}

TEST(MeshGeometry, RejectsMeshesItCannotIntersect) {
  const auto good = Quad({{{0, 0}, {1, 0}, {1, 1}, {0, 1}}}, {1, 0, 0, 1});
  struct Case {
    const char* name;
    std::function<void(TriangleMesh*)> spoil;
    const char* error;
  };
  const std::vector<Case> cases = {
      {"no triangles", [](TriangleMesh* m) { m->triangles.clear(); m->triangle_material.clear(); },
       "mesh: has no triangles"},
      {"index out of range", [](TriangleMesh* m) { m->triangles[1][2] = 4; },
       "mesh: triangle 1 has vertex index 4, the mesh has 4 vertices"},
      {"normals short", [](TriangleMesh* m) { m->normals.pop_back(); }, "mesh: has 3 normals for 4 vertices"},
      {"uvs without tangents", [](TriangleMesh* m) { m->tangents.clear(); }, "mesh: has 0 tangents for 4 uvs"},
      {"materials short", [](TriangleMesh* m) { m->triangle_material.pop_back(); },
       "mesh: has 1 triangle materials for 2 triangles"},
      {"material out of range", [](TriangleMesh* m) { m->triangle_material[0] = 1; },
       "mesh: triangle 0 has material 1, the mesh names 1"},
      {"position not finite", [](TriangleMesh* m) { m->positions[2][1] = NAN; }, "mesh: position 2 is not finite"},
      {"uv not finite", [](TriangleMesh* m) { m->uvs[3][0] = INFINITY; }, "mesh: uv 3 is not finite"},
  };
  for (const Case& c : cases) {
    auto mesh = std::make_shared<TriangleMesh>(*good);
    c.spoil(mesh.get());
    std::shared_ptr<const MeshGeometry> out;
    const std::string err = MeshGeometry::Build(mesh, uint64_t{1} << 30, {}, &out);
    EXPECT_EQ(err.rfind(c.error, 0), 0u) << c.name << ": " << err;
    EXPECT_EQ(out, nullptr) << c.name;
  }
  std::shared_ptr<const MeshGeometry> out;
  EXPECT_EQ(MeshGeometry::Build(nullptr, 1 << 20, {}, &out), "mesh: is null");
}

TEST(MeshScene, TheCloserOfMeshAndShapeWins) {
  // The quad mesh at z = 0 (its two triangles materials 0 and 1) and an analytic sphere of radius 0.5 at z = 2:
  // from +z the sphere is closer, from -z the quad. The mesh's materials are objects 1 and 2; their objects' own
  // shapes (a default sphere at the origin) are not intersected.
  auto mesh = Quad({{{0, 0}, {1, 0}, {1, 1}, {0, 1}}}, {1, 0, 0, 1});
  mesh->triangle_material = {0, 1};
  mesh->material_names = {"front", "back"};
  render::Scene scene;
  scene.objects.push_back({"ball", render::SphereShape({0, 0, 2}, 0.5)});
  scene.objects.push_back({"mesh front", render::Shape{}});
  scene.objects.push_back({"mesh back", render::Shape{}});
  scene.mesh = MustBuild(mesh);
  scene.mesh_first_object = 1;
  scene.mesh_uv_length = 4;

  Hit h;
  ASSERT_TRUE(scene.Intersect({0.1, 0.05, 5}, {0, 0, -1}, 0, INFINITY, &h));
  EXPECT_EQ(h.object, 0);
  EXPECT_NEAR(h.distance, 3 - std::sqrt(0.25 - 0.1 * 0.1 - 0.05 * 0.05), 1e-9);  // the ball's top
  EXPECT_FALSE(scene.Intersect({0.1, 0.05, -5}, {0, 0, -1}, 0, INFINITY, &h));
  // From below, (0.1, 0.05) is on triangle 0 (corners 0, 1, 2: below the diagonal y = x), material 0.
  ASSERT_TRUE(scene.Intersect({0.1, 0.05, -5}, {0, 0, 1}, 0, INFINITY, &h));
  EXPECT_EQ(h.object, 1);
  EXPECT_NEAR(h.distance, 5, 1e-6);
  EXPECT_NEAR(h.s, 0.55 * 4, 1e-6);  // u = (x + 1) / 2 times mesh_uv_length
  ASSERT_TRUE(scene.Intersect({-0.1, 0.5, -5}, {0, 0, 1}, 0, INFINITY, &h));
  EXPECT_EQ(h.object, 2);
  // Beside the ball (off its disc) from +z: the quad.
  ASSERT_TRUE(scene.Intersect({0.8, 0.6, 5}, {0, 0, -1}, 0, INFINITY, &h));
  EXPECT_EQ(h.object, 1);
  EXPECT_NEAR(h.distance, 5, 1e-6);
  // The mesh objects' own shapes are not there: a ray through their default unit sphere, above the quad, misses.
  EXPECT_FALSE(scene.Intersect({1.5, 0, 0}, {-1, 0, 0.001}, 0, 1.2, &h));
  // The quad blocks a shadow ray that the ball does not, and the ball one that the quad does not.
  EXPECT_TRUE(scene.Occluded({0.8, 0.6, -1}, {0, 0, 1}, 2));
  EXPECT_FALSE(scene.Occluded({0.8, 0.6, -1}, {0, 0, 1}, 0.9));
  EXPECT_TRUE(scene.Occluded({0, 0, 1}, {0, 0, 1}, 3, 0.01));
  EXPECT_FALSE(scene.Occluded({0.5, -3, 0.5}, {0, 1, 0}, 10));  // through the mesh objects' default sphere

  // The packet path agrees with single rays: rays from above, some on the ball, some on the quad, some past both.
  const Vec3 origin{0.2, 0.1, 6};
  std::vector<Vec3> directions;
  for (int i = 0; i < 21; ++i)
    for (int j = 0; j < 3; ++j)
      directions.push_back(render::Normalize({-0.019 * (i - 10), 0.05 * (j - 1) - 0.3 * (i % 2), -1}));
  std::vector<Hit> hits(directions.size());
  std::vector<uint8_t> found(directions.size());
  scene.IntersectFrom(origin, directions, hits, found);
  int ball = 0, quad = 0;
  for (size_t i = 0; i < directions.size(); ++i) {
    Hit one;
    ASSERT_EQ(found[i], scene.Intersect(origin, directions[i], 0, INFINITY, &one) ? 1 : 0) << i;
    if (!found[i]) continue;
    ExpectSameHit(hits[i], one);
    ++(one.object == 0 ? ball : quad);
  }
  EXPECT_GT(ball, 5);
  EXPECT_GT(quad, 5);
}

// ---- Rendered: a sphere mesh against the analytic sphere ----

constexpr int kSide = 48;
constexpr uint32_t kSamplesPerPixel = 32;

models::MaterialCache& Cache() {
  static models::MaterialCache cache(size_t{256} << 20);
  return cache;
}

// The built-in sphere scene under the built-in sky and one directional light, sampled uniformly, every query
// answered as a Lambertian's; with `mesh`, the sphere object is that mesh (the scene's object 0 its material).
render::RenderInputs SphereRender(std::shared_ptr<const MeshGeometry> mesh, uint64_t seed) {
  render::RenderInputs in;
  render::RenderSetup& s = in.setup;
  s.scene = render::MakeScene(render::SceneKind::kSphere);
  if (mesh) {
    s.scene.mesh = std::move(mesh);
    s.scene.mesh_first_object = 0;
    s.scene.mesh_uv_length = 2 * kPi;  // s and t as on the analytic unit sphere
  }
  render::Light light;
  light.direction = render::Normalize({1.0, 0.4, 0.1});
  light.rgb = {2, 2, 2};
  s.lights = {light};
  s.environment = std::make_shared<render::Environment>(render::Environment::Builtin());
  s.samples_per_pixel = kSamplesPerPixel;
  s.seed = seed;
  s.texture_scale = s.scene.default_texture_scale;
  render::RenderView view;
  view.camera = s.scene.default_camera;
  view.width = view.height = kSide;
  in.views.push_back(view);
  v1::Material material;
  material.set_preset("velvet");
  std::shared_ptr<const models::PreparedMaterial> prepared;
  EXPECT_EQ(Cache().Get(material, models::Registry::Global(), &prepared), "");
  in.material = prepared;
  in.variants = std::make_unique<render::CachedVariants>(material, models::Registry::Global(), Cache());
  in.materials = &Cache();
  in.sampling = render::Sampling::kUniform;
  return in;
}

std::vector<float> Render(std::shared_ptr<const MeshGeometry> mesh, uint64_t seed) {
  testing::LambertianEvaluator evaluator(0.6);
  const testing::Rendered run = testing::RenderWith(SphereRender(std::move(mesh), seed), &evaluator);
  EXPECT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_TRUE(run.done);
  if (run.images.size() != 1) return {};
  return run.images[0].image.rgb;
}

TEST(MeshRender, SphereMeshRendersLikeTheAnalyticSphereWithinNoise) {
  const render::Scene scene = render::MakeScene(render::SceneKind::kSphere);
  ASSERT_EQ(scene.objects.size(), 1u);
  ASSERT_EQ(scene.objects[0].shape.kind, render::Shape::Kind::kSphere);
  ASSERT_EQ(scene.objects[0].shape.radius, 1);
  ASSERT_EQ(render::Length(scene.objects[0].shape.centre), 0);
  const auto mesh = MustBuild(LatLongSphere(256, 128));

  // The analytic sphere at two seeds and the mesh at the second: same-seed renders share every sample point, so
  // their difference is the geometry's alone; different seeds differ by the sampling's noise.
  const std::vector<float> analytic3 = Render(nullptr, 3), analytic4 = Render(nullptr, 4), meshed4 = Render(mesh, 4);
  const size_t values = size_t{3} * kSide * kSide;
  ASSERT_EQ(analytic3.size(), values);
  ASSERT_EQ(analytic4.size(), values);
  ASSERT_EQ(meshed4.size(), values);

  // Each pixel wholly on the sphere or wholly off it (a 9 x 9 grid of its points, corners included, by the
  // ray-sphere test here); the rest are on the silhouette, where the inscribed mesh covers a sliver less.
  const render::PinholeCamera camera(scene.default_camera, kSide, kSide);
  const auto on_sphere = [&](double px, double py) {
    const Vec3 o = camera.position(), d = camera.Direction(px, py);
    const double b = render::Dot(o, d), c = render::Dot(o, o) - 1;
    return b * b - c >= 0 && -b > 0;
  };
  double noise2 = 0, shifted2 = 0, geometry2 = 0, geometry_sum = 0;
  int inside = 0, outside = 0;
  for (int y = 0; y < kSide; ++y)
    for (int x = 0; x < kSide; ++x) {
      int on = 0;
      for (int j = 0; j <= 8; ++j)
        for (int i = 0; i <= 8; ++i) on += on_sphere(x + i / 8.0, y + j / 8.0);
      for (int c = 0; c < 3; ++c) {
        const size_t k = 3 * (size_t(y) * kSide + x) + c;
        if (on == 0) {
          EXPECT_EQ(meshed4[k], analytic4[k]) << "pixel " << x << ", " << y << " sees the same sky";
        } else if (on == 81) {
          noise2 += std::pow(analytic4[k] - analytic3[k], 2);
          shifted2 += std::pow(meshed4[k] - analytic3[k], 2);
          geometry2 += std::pow(meshed4[k] - analytic4[k], 2);
          geometry_sum += meshed4[k] - analytic4[k];
        }
      }
      outside += on == 0;
      inside += on == 81;
    }
  ASSERT_GT(inside, 500);
  ASSERT_GT(outside, 500);
  const double n = 3.0 * inside;
  noise2 /= n;  // twice a pixel's variance: the mean square difference of two independent renders
  shifted2 /= n;
  geometry2 /= n;
  std::printf("on the sphere (%d pixels): rms difference between seeds %.5f; mesh vs analytic at another seed "
              "%.5f, at the same seed %.5f (mean %.2e)\n",
              inside, std::sqrt(noise2), std::sqrt(shifted2), std::sqrt(geometry2), geometry_sum / n);
  ASSERT_GT(noise2, 0);
  // Mesh against analytic at different seeds: noise alone, as between two analytic renders (the ratio of two mean
  // squares over these pixels has a standard deviation near 0.05 when nothing else differs).
  EXPECT_LT(shifted2 / noise2, 1.25);
  EXPECT_GT(shifted2 / noise2, 0.8);
  // At the same sample points the geometry's own difference is far below the noise, and without a bias of its
  // own: its mean within the standard error the sampling gives a mean over these pixels.
  EXPECT_LT(geometry2, 0.01 * noise2);
  EXPECT_LT(std::fabs(geometry_sum / n), std::sqrt(noise2 / 2 / n));
}

}  // namespace
}  // namespace loomlight
