// CreateBtf's synthesis (docs/btf-assets.md): every (view, light) image of a BTF on a direction grid, evaluated
// through the renderer's QueryEvaluator (render/renderer.h; the API's is the batcher), one evaluation in flight:
// - from a spatially varying material: its own f at texel centres, a whole view (every light and texel) at a time;
// - from fibers (render/btf_capture.h): a piece of a view (a run of its texels, at most kBtfPieceQueries queries)
//   traced through the patch off the caller's thread (Trace), then its queries evaluated and added into the
//   view's images.
// Like the renderer, every method but Trace runs on one thread (the API's host worker), where the evaluator
// answers; each answer is reported to the progress sink.
#pragma once

#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "server/models/btf/btf_asset.h"
#include "server/models/material_plan.h"
#include "server/render/btf_capture.h"
#include "server/render/renderer.h"

namespace loomlight::render {

// A fiber capture's queries traced and evaluated at a time (a piece of a view: a run of its texels); each costs
// its wi, wo, axis, weight and tag, the kernel's result and, while the tracing threads' parts are joined, a
// second copy (kBtfBytesPerPieceQuery).
constexpr size_t kBtfPieceQueries = size_t{1} << 18;
constexpr size_t kBtfBytesPerPieceQuery = 2 * 52 + 12;

class BtfSynthesis {
 public:
  // From `material`'s own f (a spatially varying model) at the texel centres of a width x height tile.
  BtfSynthesis(std::shared_ptr<const models::PreparedMaterial> material, const models::btf::DirectionGrid& grid,
               int width, int height, QueryEvaluator* evaluator, std::function<Status()> stop,
               std::function<void()> progress);
  // From `capture`'s rays, shaded by the fiber model `material`.
  BtfSynthesis(std::shared_ptr<const models::PreparedMaterial> material, std::unique_ptr<BtfCapture> capture,
               QueryEvaluator* evaluator, std::function<Status()> stop, std::function<void()> progress);

  // Whether the next piece must be traced (Trace, off this thread) before Submit.
  bool NeedsTrace() const { return capture_ && !traced_; }
  // Off the renderer's thread: the next piece's rays; `stop` true leaves it incomplete (Submit then stops too).
  void Trace(const std::function<bool()>& stop);
  // Sends the next view (or traced piece) to the evaluator, unless the token says stop.
  void Submit();

  bool InFlight() const { return in_flight_; }
  bool done() const { return views_done_ == grid_size_; }
  size_t views_done() const { return views_done_; }
  const Status& status() const { return status_; }
  // Every view's images once done (BtfImages::image(view, light)).
  models::btf::BtfImages& images() { return images_; }
  // Frees the queries and their results (the images stay).
  void ReleaseQueries();

 private:
  void OnDone(const ShadingOutcome& outcome);

  const std::shared_ptr<const models::PreparedMaterial> material_;
  const std::unique_ptr<BtfCapture> capture_;  // null: from the material's f
  QueryEvaluator* const evaluator_;
  const std::function<Status()> stop_;
  const std::function<void()> progress_;
  const size_t grid_size_;
  Status status_;
  models::btf::BtfImages images_;
  bool in_flight_ = false;
  size_t next_view_ = 0, views_done_ = 0;
  std::unique_ptr<models::EvaluationPlan> plan_;
  std::optional<models::btf::ViewQueries> queries_;  // from the material
  // From fibers: the piece traced ([piece_begin_, piece_end_) of the view's texels), its queries and results.
  Evaluator fiber_evaluator_;
  QueryBucket bucket_;
  std::vector<float> f_;
  size_t piece_begin_ = 0, piece_end_ = 0, piece_texels_ = 1;
  bool traced_ = false;
};

}  // namespace loomlight::render
