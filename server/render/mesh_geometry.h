// A client's triangle mesh (server/assets/mesh_file.h) in an Embree BVH, for the renderer's ray casting: closest
// hits with the surface a shading frame needs (interpolated normal, texture coordinates and the UV tangent frame)
// and occlusion rays. Immutable once built; shared by every render of the same mesh.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>

#include "server/assets/mesh_file.h"
#include "server/render/vec.h"

namespace loomlight::render {

struct Hit;  // server/render/scene.h

class MeshGeometry {
 public:
  // Builds the BVH over `mesh` (Embree's triangles on a device of its own, reading the mesh's positions and
  // triangles in place; the mesh is kept alive with the geometry). "" with *out set, or why not: "mesh: ..." (a
  // per-vertex array neither empty nor one per vertex, tangents not exactly where uvs are, triangle_material not
  // one per triangle, a material or vertex index out of range, a value not finite, no triangles), "bvh_memory:
  // ..." (Embree would have held more than max_bvh_bytes at some moment of the build: its memory monitor refuses
  // the allocation), "stopped" (`stop` returned true: asked before and during the build, also from Embree's
  // threads at once, so it must be thread-safe; not kept after Build returns), or "embree: ..." (Embree's own).
  static std::string Build(std::shared_ptr<const assets::TriangleMesh> mesh, uint64_t max_bvh_bytes,
                           const std::function<bool()>& stop, std::shared_ptr<const MeshGeometry>* out);
  ~MeshGeometry();
  MeshGeometry(const MeshGeometry&) = delete;
  MeshGeometry& operator=(const MeshGeometry&) = delete;

  const assets::TriangleMesh& mesh() const { return *mesh_; }
  uint64_t bvh_bytes() const { return bvh_bytes_; }  // what Embree holds for the built BVH
  // How many material indices hits carry: one per material name, at least one (a mesh without them is all 0).
  size_t materials() const { return mesh_->material_names.empty() ? 1 : mesh_->material_names.size(); }

  // The closest hit with distance in (min_distance, max_distance) (in units of |direction|; float precision,
  // Embree's): hit->object is the hit triangle's material index (TriangleMesh::triangle_material, 0 when it is
  // empty; the caller offsets it to its scene object), position (on the ray), s and t the texture coordinates
  // times uv_length (scene units per UV unit), and the shading frame: tangent_s along +u (the interpolated
  // tangent made perpendicular to the normal), tangent_t along +v, orthonormal and right-handed (tangent_s x
  // tangent_t = normal) so that x = +u and y = +v (SPEC.md section 1). The normal is the interpolated vertex
  // normal, or its opposite on a mirrored UV panel (vertex handedness w = -1: the frame then faces the normal's
  // back; shading is two-sided). A mesh without UVs: s = t = 0, the normal turned to the side the triangle's
  // winding faces, and an arbitrary tangent frame. An invalid ray (not finite, zero direction, min > max) misses.
  // In float, as Embree intersects: a hit nearer than 64 float steps of the largest coordinate (the origin's or
  // the mesh's: 8e-6 on a mesh of unit size) is not taken, so that a ray leaving the surface misses its own
  // triangle at any scale (IntersectFrom and Occluded too).
  bool Intersect(Vec3 origin, Vec3 direction, double min_distance, double max_distance, double uv_length,
                 Hit* hit) const;
  // Closest hits of rays from one origin (Embree's coherent packets of up to 16): found[i] = 1 with hits[i]
  // filled as Intersect fills it, or 0. Spans of one length.
  void IntersectFrom(Vec3 origin, std::span<const Vec3> directions, double uv_length, std::span<Hit> hits,
                     std::span<uint8_t> found) const;
  bool Occluded(Vec3 origin, Vec3 direction, double min_distance, double max_distance) const;

 private:
  MeshGeometry() = default;
  struct Impl;
  std::shared_ptr<const assets::TriangleMesh> mesh_;
  std::unique_ptr<Impl> impl_;
  uint64_t bvh_bytes_ = 0;
};

}  // namespace loomlight::render
