// Environment lighting folded into `btf` materials (Sattler et al. 2003 Sec. 5.3, Eqs. 10 and 12; the model's side
// is server/models/btf/environment_fold.h): per scene object, a grid of vertices over its surface coordinates
// (s, t); at each, the map's light (with the scene's own occlusion toward each of its directions: the paper's
// visibility maps) folded once per render into G_j and gamma_kj for every view slot; at a hit, the 4 vertices
// around its (s, t) blended bilinearly and evaluated toward wo. A hit on such an object then needs no
// environment sample: no noise from the map, the fold's error instead (the map's discretisation into cells, the
// vertices' spacing, and shadow edges blurred between vertices).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "server/models/btf/environment_fold.h"
#include "server/render/shading.h"

namespace loomlight::render {

class FoldedEnvironment {
 public:
  // The map's quadrature (Environment::Cells): 64 x 32 cells of 5.6 degrees, a fifth to a third of a BTF grid's
  // spacing (Table 1: 15-17 degrees), and up to 4096 bright pixels (the sun) at the map's own resolution.
  static constexpr int kCellsAround = 64, kCellsDown = 32;
  static constexpr size_t kMaxBrightCells = 4096;
  // Vertices: spheres 64 around x 32 latitudes, cylinders 64 around x 16 along the axis (their frames vary
  // around only; the rows resolve shadows of other objects), quads 8 x 8 (shadows only); every grid halved
  // (down to 4 x 2) until all objects' tables fit kMaxTableBytes.
  static constexpr uint64_t kMaxTableBytes = uint64_t{64} << 20;

  // Per object: the packed `btf` material to fold its environment light into (tables null: not folded), the
  // components its kernel path uses, and whether its hits read the BTF (texels) or the BRDF (the tile mean).
  struct Material {
    std::shared_ptr<const models::PackedTables> tables;
    int components = 0;
    bool textured = true;
  };

  // Folds setup.environment for every object with a material, on `threads` threads. `admit` is asked for the
  // bytes the tables will hold before any work (false: the call fails with `refused` set); `stop` is polled.
  // Returns "" or why not.
  static std::string Build(const RenderSetup& setup, const std::vector<Material>& materials, int threads,
                           const std::function<bool()>& stop, const std::function<bool(uint64_t)>& admit,
                           bool* refused, std::shared_ptr<const FoldedEnvironment>* out);

  bool Covers(int object) const { return object >= 0 && size_t(object) < objects_.size() && objects_[object].folded(); }

  // One hit on a folded object: the ShadingPoint's fields.
  struct Query {
    int object = -1;
    bool back = false;
    double s = 0, t = 0;
    Vec3 wo;
    float u = 0, v = 0;
  };
  Query QueryOf(const ShadingPoint& point) const;
  // Reflected environment radiance of each query (a batch: one chunk's hits at a time).
  void Radiance(const std::vector<Query>& queries, std::vector<Rgb>* out) const;

  // For the fidelity report: the object's vertices, sides, cells and table bytes.
  std::string Describe(int object) const;
  uint64_t bytes() const;
  double seconds() const { return seconds_; }

 private:
  // The vertex grid over one object's surface coordinates: vertex (i, j) at the centre of cell (i, j) of an
  // ns x nt split of [s_lo, s_hi] x [t_lo, t_hi]; s wraps around on spheres and cylinders.
  struct Grid {
    int ns = 1, nt = 1;
    bool periodic_s = false;
    double s_lo = 0, s_hi = 1, t_lo = 0, t_hi = 1;
  };
  struct Object {
    Grid grid;
    bool textured = true;
    std::shared_ptr<const models::btf::EnvironmentFold> side[2];  // front, back (null: that side is never seen)
    bool folded() const { return side[0] || side[1]; }
  };
  std::vector<Object> objects_;
  size_t cells_ = 0;
  double seconds_ = 0;
};

}  // namespace loomlight::render
