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
  // Builds the BVH over `mesh`. "" with *out set, or why not: the BVH would take more than max_bvh_bytes (Embree's
  // memory monitor stops the build), `stop` returned true (asked during the build), or Embree failed.
  static std::string Build(std::shared_ptr<const assets::TriangleMesh> mesh, uint64_t max_bvh_bytes,
                           const std::function<bool()>& stop, std::shared_ptr<const MeshGeometry>* out);
  ~MeshGeometry();
  MeshGeometry(const MeshGeometry&) = delete;
  MeshGeometry& operator=(const MeshGeometry&) = delete;

  const assets::TriangleMesh& mesh() const { return *mesh_; }
  uint64_t bvh_bytes() const { return bvh_bytes_; }

  // The closest hit with distance in (min_distance, max_distance): hit->object is the hit triangle's material
  // index (TriangleMesh::triangle_material; the caller offsets it to its scene object), position, the
  // interpolated shading normal (made to face the geometric normal's side), tangent_s along +u and tangent_t
  // along +v (orthonormal with the normal, right-handed: tangent_s x tangent_t = normal), s and t the texture
  // coordinates times uv_length (scene units per UV unit). A mesh without UVs: s = t = 0 and an arbitrary
  // tangent frame.
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
