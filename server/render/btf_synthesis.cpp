#include "server/render/btf_synthesis.h"

#include <algorithm>

namespace loomlight::render {

BtfSynthesis::BtfSynthesis(std::shared_ptr<const models::PreparedMaterial> material,
                           const models::btf::DirectionGrid& grid, int width, int height, QueryEvaluator* evaluator,
                           std::function<Status()> stop, std::function<void()> progress)
    : material_(std::move(material)), evaluator_(evaluator), stop_(std::move(stop)), progress_(std::move(progress)),
      grid_size_(grid.size()) {
  images_.grid = grid;
  images_.width = width;
  images_.height = height;
  images_.f.assign(grid_size_ * grid_size_ * images_.image_values(), 0.0f);
  queries_.emplace(grid, width, height);
}

BtfSynthesis::BtfSynthesis(std::shared_ptr<const models::PreparedMaterial> material,
                           std::unique_ptr<BtfCapture> capture, QueryEvaluator* evaluator,
                           std::function<Status()> stop, std::function<void()> progress)
    : material_(std::move(material)), capture_(std::move(capture)), evaluator_(evaluator), stop_(std::move(stop)),
      progress_(std::move(progress)), grid_size_(capture_->grid().size()) {
  const size_t n = grid_size_, texels = size_t(capture_->width()) * capture_->height();
  images_.grid = capture_->grid();
  images_.width = capture_->width();
  images_.height = capture_->height();
  images_.f.assign(n * n * images_.image_values(), 0.0f);
  fiber_evaluator_ = {material_.get(), false, false, true};
  // Texels per piece: as many as keep a piece's queries within kBtfPieceQueries at most.
  piece_texels_ =
      std::clamp<size_t>(kBtfPieceQueries * texels / std::max<size_t>(capture_->MaxQueriesPerView(), 1), 1, texels);
}

void BtfSynthesis::Trace(const std::function<bool()>& stop) {
  const size_t texels = images_.texels();
  piece_end_ = std::min(texels, piece_begin_ + piece_texels_);
  capture_->TraceView(next_view_, piece_begin_, piece_end_, int(kTraceThreads), stop, &bucket_);
  traced_ = true;
}

void BtfSynthesis::Submit() {
  if (status_.ok())
    if (Status s = stop_(); !s.ok()) status_ = std::move(s);
  if (!status_.ok() || in_flight_ || done() || NeedsTrace()) return;
  in_flight_ = true;
  const auto done = [this](const ShadingOutcome& outcome) { OnDone(outcome); };
  if (!capture_) {
    queries_->SetView(images_.grid, next_view_);
    plan_ = std::make_unique<models::EvaluationPlan>(*material_, queries_->wi.data(), queries_->wo.data(),
                                                     queries_->uv.data(), queries_->size());
    return evaluator_->Submit({{plan_.get(), runtime::ResultSink{.f32 = images_.image(next_view_, 0)}}}, done);
  }
  f_.assign(3 * bucket_.size(), 0.0f);
  if (bucket_.size() == 0) {  // nothing seen or lit in this piece: the evaluator answers at once
    plan_.reset();
    return evaluator_->Submit({}, done);
  }
  plan_ = PlanOf(fiber_evaluator_, bucket_);
  evaluator_->Submit({{plan_.get(), runtime::ResultSink{.f32 = f_.data()}}}, done);
}

void BtfSynthesis::OnDone(const ShadingOutcome& outcome) {
  in_flight_ = false;
  if (!outcome.status.ok()) {
    if (status_.ok()) status_ = outcome.status;
  } else if (!capture_) {
    ++next_view_;
    ++views_done_;
  } else {
    BtfCapture::Accumulate(bucket_, f_.data(), images_.image(next_view_, 0));
    traced_ = false;
    piece_begin_ = piece_end_;
    if (piece_begin_ == images_.texels()) {  // the view's last piece
      ++views_done_;
      ++next_view_;
      piece_begin_ = 0;
    }
  }
  progress_();
}

void BtfSynthesis::ReleaseQueries() {
  bucket_ = {};
  f_ = {};
  queries_.reset();
  plan_.reset();
}

}  // namespace loomlight::render
