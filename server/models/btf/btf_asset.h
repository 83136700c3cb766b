// BTF assets in memory (Sattler, Sarlette and Klein 2003; SPEC.md section 7): a grid of view and light
// directions, the images of f over one texture tile at every (view, light) pair, their per-view PCA (Eq. 1)
// and the compressed form the kernels read (kernels/models/btf.h). The `btf` model (plugins/btf.cpp) finds
// assets here by id; server/assets/btf_store.h keeps them on disk by name.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::models::btf {

// Rings of constant polar angle; ring r holds `count` directions at phi = 360 j / count degrees. Directions
// are numbered ring by ring.
struct Ring {
  double theta_deg = 0;
  int count = 1;
};

constexpr size_t kMaxGridDirections = 256;
constexpr int kMaxComponents = 64;  // BT_MAX_COMPONENTS
constexpr int kMaxTexels = 256;     // per side of the tile

struct DirectionGrid {
  std::vector<Ring> rings;

  // Table 1's samplings: H1 (theta 0, 17, .. 85) and H2 (0, 15, .. 75), 1, 6, 12, 18, 20, 24 azimuths each.
  static DirectionGrid Preset(const std::string& name, bool* found);
  // "" or the reason ("rings[2].theta: ..."): theta ascending in [0, 89], counts >= 1, a ring at theta 0 of
  // count 1 only, at most kMaxGridDirections directions.
  std::string Validate() const;
  size_t size() const;
  // Direction i (unit xyz, z > 0).
  void Direction(size_t i, double xyz[3]) const;
  // The grid direction within tolerance_deg of w (unit), or -1.
  int Find(const double w[3], double tolerance_deg) const;
};

// BTF images: f (1/sr) for every (view, light) pair of the grid over a width x height tile, stored view-major:
// value(view, light, texel, channel) at ((view * N + light) * texels + texel) * 3 + channel, texel =
// iv * width + iu with iv = 0 at v = 0 (texel centres at ((iu + 0.5) / width, (iv + 0.5) / height)).
struct BtfImages {
  DirectionGrid grid;
  int width = 0, height = 0;
  std::vector<float> f;
  size_t texels() const { return size_t(width) * height; }
  size_t image_values() const { return 3 * texels(); }
  float* image(size_t view, size_t light) { return f.data() + (view * grid.size() + light) * image_values(); }
  const float* image(size_t view, size_t light) const {
    return f.data() + (view * grid.size() + light) * image_values();
  }
};

// The queries whose results, in order, are one view's images (BtfImages::image(view, 0) onward): query (light l,
// texel t) at q = l * texels + t, wi the light's direction, uv the texel's centre, wo the view's (SetView).
struct ViewQueries {
  std::vector<float> wi, wo, uv;
  ViewQueries(const DirectionGrid& grid, int width, int height);
  size_t size() const { return uv.size() / 2; }
  void SetView(const DirectionGrid& grid, size_t view);
};

struct CompressionOptions {
  int max_components = 16;
  double target_psnr_db = 0;  // > 0: the fewest components (up to max_components) reaching it
};

// Reconstructing the images with `components` components: RMSE, PSNR (peak / RMSE) and the asset's bytes.
struct ErrorRow {
  int components = 0;
  double rmse = 0, psnr_db = 0;
  uint64_t bytes = 0;
};

// A compressed BTF: immutable once made; shared by the store, the materials naming it and launches.
struct BtfAsset {
  std::string name, source;
  std::string owner;  // the client that stored it (server/api/access.h FairShareKey); "" before owners
  DirectionGrid grid;
  int width = 0, height = 0;
  int components = 0;  // kept per view slot (K)
  double peak = 0, rms = 0;
  std::vector<ErrorRow> errors;  // components 0 .. K
  double synthesis_seconds = 0, compression_seconds = 0;
  double threads_per_tile = 1;  // how fine the tile's structure is (Model::ThreadsPerRepeat)
  std::shared_ptr<const PackedTables> tables;  // kernels/models/btf.h's layout, float32
  uint64_t id = 0;                             // set by Assets::Add: the `btf` model's asset_id

  uint64_t bytes() const { return tables ? tables->size() * sizeof(float) : 0; }
  uint64_t images_float16_bytes() const { return uint64_t(grid.size()) * grid.size() * width * height * 3 * 2; }
  // The asset's bytes in float32 with c of its components (what a smaller asset would need).
  uint64_t BytesAt(int c) const;
};

// Compresses images (Eq. 1): per view slot, a mean-centred PCA over that view's light images, from the
// eigenvectors of the lights' Gram matrix (Eigen; N x N for N lights, much smaller than the pixels). Keeps
// options.max_components (or the fewest reaching target_psnr_db) and records the error at every count from
// the discarded eigenvalues (exact for the float64 PCA; the float32 tables add ~1e-7 relative). `progress`
// (may be empty) gets views done; `cancelled` (may be empty) stops it (then nullptr). Views run on `threads`.
std::shared_ptr<BtfAsset> Compress(const BtfImages& images, const CompressionOptions& options,
                                   const std::function<void(size_t)>& progress,
                                   const std::function<bool()>& cancelled, int threads = 2);

// Builds an asset from its parts (its tables as stored, e.g. read back from disk); "" or why they disagree.
std::string AssembleAsset(std::vector<float> tables, BtfAsset* asset);

// The assets the `btf` model can name, by id (ids are never reused, so a material packed for an asset that was
// deleted or replaced cannot find its successor). Id 0 is a built-in demonstration asset (15 directions, 4 x 4
// texels): the model's default and preset, so the model can be packed and tested without an asset.
class Assets {
 public:
  static Assets& Global();
  // Registers the asset under a new id (set in *asset) and returns it.
  uint64_t Add(const std::shared_ptr<BtfAsset>& asset);
  void Remove(uint64_t id);
  std::shared_ptr<const BtfAsset> Find(uint64_t id) const;
  // The asset of that name, in any case ("Twill" finds "twill": names differing only in case are one name).
  std::shared_ptr<const BtfAsset> FindName(const std::string& name) const;
  std::vector<std::shared_ptr<const BtfAsset>> List() const;

 private:
  Assets();
  mutable std::mutex mutex_;
  std::map<uint64_t, std::shared_ptr<const BtfAsset>> by_id_;
  uint64_t next_id_ = 1;
};

}  // namespace loomlight::models::btf
