// A virtual BTF gonioreflectometer (SPEC.md section 7's "rendered procedural yarn" source; Sattler et al.
// Sec. 3 measure real cloth the same way): a periodic patch of fibers, one tile of which is the BTF's tile,
// seen by parallel rays from each view direction of a grid and lit by a directional light from each light
// direction.
//
// Readings (ours):
// - The tile is [x0, x0 + period_x] x [y0, y0 + period_y] of the plane z = 0 (the cloth's mid-plane; normal +z,
//   thread 1 = texture u along +x as SPEC.md section 1), repeated without end (Scene::tiling). Texel (iu, iv)
//   covers u in [iu, iu + 1) / width, v likewise; its rays pass through jittered points of that cell of the
//   plane along -wo, and meet the first fiber above or below it: parallax and self-occlusion are in the images,
//   as in a measured BTF.
// - A hit is shaded exactly as a Render's fiber hit (render/shading.h: the fiber model's f about the fiber's
//   axis, cos theta_i about the axis, shadow rays traced through the fibers; no ambient light). The light has
//   unit irradiance on a plane facing it, so L = sum over hits of f * cos_axis * V, and the BTF value is
//   f_btf = L / cos theta_i with theta_i the light's angle to the cloth normal: radiance per unit irradiance on
//   the reference plane, the quantity a woven BTF gives (SPEC.md section 4's f). A ray that meets no fiber sees
//   black (a dark backing behind an open weave).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "server/models/btf/btf_asset.h"
#include "server/render/shading.h"

namespace loomlight::render {

class BtfCapture {
 public:
  // The capture of `fibers` (which must hold the 3 x 3 tiles around `tile`, the BTF's tile and its periods) on
  // `grid` at width x height texels, `samples` rays per texel. Every view's queries are then (light, texel) pairs
  // of one fiber evaluator.
  BtfCapture(std::shared_ptr<const yarn::FiberScene> fibers, const Scene::Tiling& tile,
             const models::btf::DirectionGrid& grid, int width, int height, int samples, uint64_t seed);

  // The most queries one view can give (every sample of every texel sees every light).
  size_t MaxQueriesPerView() const;
  const models::btf::DirectionGrid& grid() const { return grid_; }
  int width() const { return width_; }
  int height() const { return height_; }

  // The queries of texels [begin, end) of view `view` for the fiber model (wi, wo, axis; weight: the light's
  // weight over samples x cos theta_i; tag: light * texels + texel, so f x weight adds to
  // BtfImages::image(view, 0)[3 tag ..]), traced on `threads` threads, each a run of texels, appended in texel
  // order (the result does not depend on the thread count). `stop` is asked between texels; true leaves the
  // bucket incomplete.
  void TraceView(size_t view, size_t begin, size_t end, int threads, const std::function<bool()>& stop,
                 QueryBucket* bucket) const;

  // Adds the view's evaluated queries (f: 3 per query) into its images (BtfImages::image(view, 0)).
  static void Accumulate(const QueryBucket& bucket, const float* f, float* view_images);

 private:
  void TraceTexels(size_t view, size_t begin, size_t end, const std::function<bool()>& stop, QueryBucket* bucket) const;

  RenderSetup setup_;
  Scene::Tiling tile_;
  models::btf::DirectionGrid grid_;
  int width_, height_, samples_;
  std::vector<double> inverse_cosine_;  // per light: 1 / cos theta_i
  double ray_start_z_ = 0;              // rays start above every fiber
};

}  // namespace loomlight::render
