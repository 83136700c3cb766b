// The renderer (server/render/renderer.h) driven on the test's own thread, with no server: an evaluator that
// answers every query in closed form (a Lambertian reflector), so that images can be checked against radiance
// computed by the test.
#pragma once

#include <gtest/gtest.h>

#include <deque>
#include <functional>
#include <numbers>
#include <utility>
#include <vector>

#include "server/render/renderer.h"

namespace loomlight::testing {

// Evaluates every query as a Lambertian reflector, f = albedo / pi with both directions above the cloth (0 else),
// and answers on the test's own "renderer thread": a queue the test runs until it is empty.
class LambertianEvaluator final : public render::QueryEvaluator {
 public:
  explicit LambertianEvaluator(double albedo) : albedo_(albedo) {}

  void Submit(std::vector<render::ShadingWork> work, std::function<void(const render::ShadingOutcome&)> done) override {
    ++chunks_;
    if (on_submit) on_submit(chunks_);
    render::ShadingOutcome outcome;
    if (chunks_ == fail_chunk) {
      outcome.status = {batching::JobStatus::kInternal, "the device fell over"};
    } else {
      for (const render::ShadingWork& w : work)
        for (size_t k = 0; k < w.plan->parts(); ++k) {
          const float* wi = w.plan->wi(k);
          const float* wo = w.plan->wo(k);
          const size_t* slot = w.plan->slots(k);
          const double* scale = w.plan->scale(k);
          for (size_t i = 0; i < w.plan->size(k); ++i) {
            const size_t q = slot ? slot[i] : i;
            const double f = wi[3 * i + 2] > 0 && wo[3 * i + 2] > 0 ? albedo_ / std::numbers::pi : 0.0;
            for (int c = 0; c < 3; ++c) w.sink.f64[3 * q + c] = f * (scale ? scale[q] : 1.0);
          }
          outcome.queries += w.plan->size(k);
        }
    }
    queue_.push_back([done, outcome] { done(outcome); });
  }

  void RunUntilIdle() {
    while (!queue_.empty()) {
      auto task = std::move(queue_.front());
      queue_.pop_front();
      task();
    }
  }
  int chunks() const { return chunks_; }

  std::function<void(int chunk)> on_submit;  // called as chunk `chunk` (from 1) is submitted
  int fail_chunk = 0;                         // this chunk's evaluation fails (0: none does)

 private:
  double albedo_;
  int chunks_ = 0;
  std::deque<std::function<void()>> queue_;
};

struct Rendered {
  render::Status status;
  bool done = false;
  std::vector<render::RenderedImage> images;
  int progress = 0;
};

// Plans, builds and renders on this thread, the token `stop`.
inline Rendered RenderWith(render::RenderInputs in, LambertianEvaluator* evaluator,
                           std::function<render::Status()> stop = [] { return render::Status{}; }) {
  Rendered run;
  render::Renderer renderer(std::move(in), evaluator, std::move(stop), [&run] { ++run.progress; });
  EXPECT_TRUE(renderer.Plan().ok());
  if (renderer.NeedsBuild()) {
    EXPECT_TRUE(renderer.Build([] { return false; }, [](uint64_t) { return true; }).ok());
  }
  renderer.Start();
  evaluator->RunUntilIdle();
  EXPECT_FALSE(renderer.InFlight());
  run.status = renderer.status();
  run.done = renderer.done();
  run.images = renderer.images();
  return run;
}

}  // namespace loomlight::testing
