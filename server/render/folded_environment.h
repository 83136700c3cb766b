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
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
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
  // EstimateError's reference: the map in cells half as wide each way, at up to this many pilot points per object.
  static constexpr int kReferenceCellsAround = 2 * kCellsAround, kReferenceCellsDown = 2 * kCellsDown;
  static constexpr size_t kMaxErrorPoints = 64;

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

  // The fold's error per object (-1: no pilot point on it, or not folded), estimated at `points` (the fidelity
  // pilot's hits): sum |folded - reference| / sum reference of the points' reflected environment radiance
  // (R + G + B), the reference folded at each point's own frame and shadow rays (no vertices to interpolate
  // between, so no shadow edge blurred) from a map quadrature twice as fine each way. That is what sampled
  // lighting converges to, up to the finer quadrature's own error. Empty when stopped.
  std::vector<double> EstimateError(const RenderSetup& setup, const std::vector<Material>& materials,
                                    const std::vector<ShadingPoint>& points, int threads,
                                    const std::function<bool()>& stop) const;
  // A copy that folds only the objects with keep[o]; the others sample the environment.
  std::shared_ptr<const FoldedEnvironment> Keeping(const std::vector<bool>& keep) const;

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

// Folds kept across Render calls: a fold takes 0.1-0.5 s and a catalogue renders one asset under one sky again
// and again. Least recently used first out, bounded in bytes. Keyed on everything a fold depends on: the map
// and its transform, every object's shape (they shadow each other), the threads' angles and scale, the camera
// (which sides are seen) and each object's asset tables, components and path. An entry keeps its map and its
// asset's tables alive, so no other map or asset can take their addresses while it is cached.
class FoldCache {
 public:
  explicit FoldCache(uint64_t capacity_bytes) : capacity_bytes_(capacity_bytes) {}
  static std::string Key(const RenderSetup& setup, const std::vector<FoldedEnvironment::Material>& materials);
  std::shared_ptr<const FoldedEnvironment> Find(const std::string& key);
  // Keeps `fold` (made for setup's environment) unless it alone is over the bound.
  void Insert(const std::string& key, std::shared_ptr<const FoldedEnvironment> fold, const RenderSetup& setup);
  // The fold's error estimates (FoldedEnvironment::EstimateError) kept with it, by what they depend on
  // beyond the key (the pilot's image size): found, or kept for the next call.
  bool FindErrors(const std::string& key, const std::string& pilot, std::vector<double>* errors);
  void KeepErrors(const std::string& key, const std::string& pilot, const std::vector<double>& errors);
  void Clear();  // an asset was replaced or deleted
  uint64_t bytes() const;

 private:
  struct Entry {
    std::shared_ptr<const FoldedEnvironment> fold;
    std::shared_ptr<const Environment> environment;  // keeps the map (its identity) alive
    std::list<std::string>::iterator order;
    std::vector<std::pair<std::string, std::vector<double>>> errors;  // by pilot; a few per fold
  };
  static constexpr size_t kMaxErrorsPerFold = 16;
  const uint64_t capacity_bytes_;
  mutable std::mutex mutex_;
  std::list<std::string> order_;  // most recently used first
  std::unordered_map<std::string, Entry> map_;
  uint64_t bytes_ = 0;
};

}  // namespace loomlight::render
