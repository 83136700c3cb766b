// The renderer (DESIGN.md "The renderer is a client of the evaluator"): a built scene, its views, lights and
// material in; linear RGB images and the fidelity report out. Pixel samples are traced on the host into shading
// queries, which go to a QueryEvaluator (the API layer's is the batcher) a chunk at a time, at most
// kRenderChunkQueries per chunk and one chunk with the evaluator at a time, so that other clients' work
// interleaves with a render.
//
// Threads: every method but Build runs on one thread, the renderer's (the API's host worker); the evaluator
// calls back there too. Build runs elsewhere (the API's asset loader) while the renderer's thread leaves the
// renderer alone. Nothing here blocks on the evaluator: the render advances as chunks come back, and reports each
// step to its progress sink.
//
// Chunks: two buffers alternate; while one chunk is with the evaluator, the renderer accumulates the previous
// one and traces the next. Every pixel sample's sum is taken in a fixed order (evaluators in order, then queries
// in order), and a pixel's in sample order, so the image does not depend on timing or on how launches were
// batched. Sampling uniformly is one pass of samples_per_pixel; adaptively (adaptive_sampling.h), a first pass
// of a few samples per pixel measures each pixel's noise, and a second gives each pixel its share of the rest.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "server/batching/batcher.h"
#include "server/imaging/image_encode.h"
#include "server/models/material_cache.h"
#include "server/models/material_plan.h"
#include "server/render/fidelity.h"
#include "server/render/folded_environment.h"
#include "server/render/shading.h"

namespace loomlight::render {

// Queries per chunk (whole pixels): a quarter of one Evaluate call's limit (api::kMaxQueriesPerCall), so that a
// render takes turns with other clients' launches often and its host work (ray casting, accumulation) overlaps
// the kernels.
constexpr size_t kRenderChunkQueries = size_t{1} << 18;
// Threads a chunk is traced on (ray casting, light and material sampling: the host's share of a render; a BTF
// capture's pieces too).
constexpr uint64_t kTraceThreads = 2;
// Renders of at least this many pixel samples (every view's) tabulate a BRDF path's material when its model can be
// (server/models/tabulated_brdf.h; seconds, once per material, kept with it in the material cache) and take the
// table where its measured error is within the target; smaller ones take a table only when it is built already.
constexpr uint64_t kTabulateFromSamples = uint64_t{1} << 24;
// Pixels per block the trace threads take turns over: small enough that sky and cloth fall to both, large
// enough that neighbouring samples make coherent ray packets.
constexpr uint64_t kTraceBlockPixels = 16;

// Why a render (or a capture) ended: OK, or the evaluator's failure, the cancellation token's reason, or an
// error of its own (kInternal, kResourceExhausted). The codes are the batcher's, which the API maps to gRPC's.
struct Status {
  batching::JobStatus code = batching::JobStatus::kOk;
  std::string message;
  bool ok() const { return code == batching::JobStatus::kOk; }
};

// One evaluator's queries of a chunk and where their results go (3 per query, through the plan's slots).
struct ShadingWork {
  const models::EvaluationPlan* plan = nullptr;
  runtime::ResultSink sink;
};

// What a chunk's evaluation came to.
struct ShadingOutcome {
  Status status;               // the first failure among the chunk's jobs
  uint64_t queries = 0;        // queries evaluated
  double kernel_seconds = 0;   // summed over the jobs
};

// Evaluates shading queries for the renderer; the API layer implements it over the batcher, tests with a
// closed-form f.
class QueryEvaluator {
 public:
  virtual ~QueryEvaluator() = default;
  // Evaluates every part of every plan of one chunk (none: nothing) into its sink, then calls `done` exactly
  // once, later, on the renderer's thread (never from within Submit). The plans and sinks outlive the call.
  virtual void Submit(std::vector<ShadingWork> work, std::function<void(const ShadingOutcome&)> done) = 0;
};

// One camera's image: a render has one or more, rendered in order, each with its own samples. A turntable's
// views turn the lights and the environment with the camera (the product turns under fixed studio lights).
struct RenderView {
  CameraSpec camera;
  int width = 1, height = 1;
  std::optional<std::vector<Light>> lights;         // unset: the setup's
  std::shared_ptr<const Environment> environment;  // null: the setup's (which may be none)
};

enum class Sampling { kAuto, kUniform, kAdaptive };              // kAuto: adaptive from kAutoAdaptiveSamples
enum class BtfEnvironmentChoice { kAuto, kFolded, kSampled };    // a `btf` asset's environment light

struct RenderInputs {
  // The built scene (its fibers generated and built), lights, environment, texture placement, samples per pixel,
  // seed and the fiber methods asked for; its camera, width and height are each view's in turn.
  RenderSetup setup;
  std::vector<RenderView> views;  // at least one. The fidelity plan is chosen once, at the first view.
  // The material, packed, and its variants for the fidelity chooser (which keeps the ones the render uses).
  std::shared_ptr<const models::PreparedMaterial> material;
  std::unique_ptr<MaterialVariants> variants;
  // Per object, when objects differ (a mesh's materials): what each wears instead of `material` (an empty
  // list, or a slot whose material is null: `material`).
  struct ObjectMaterial {
    std::shared_ptr<const models::PreparedMaterial> material;
    std::unique_ptr<MaterialVariants> variants;
  };
  std::vector<ObjectMaterial> object_materials;
  // The product alone (a white or transparent background): a camera ray that misses every object adds nothing,
  // and each view's image comes with its coverage (RenderedImage::coverage).
  bool product_only = false;
  double error_target = kDefaultErrorTarget;  // relative, > 0
  bool force_full_fidelity = false;
  Sampling sampling = Sampling::kAuto;
  BtfEnvironmentChoice btf_environment = BtfEnvironmentChoice::kAuto;
  models::MaterialCache* materials = nullptr;  // charged for the material samplers the render builds (may be null)
  FoldCache* folds = nullptr;                  // folds kept across renders (may be null)
};

// One view's image and what its sampling came to.
struct RenderedImage {
  imaging::LinearRgbImage image;  // linear RGB radiance, every value finite and >= 0
  // product_only: per pixel, the share of its samples whose camera ray hit an object (the image then holds the
  // product's radiance averaged over all the pixel's samples, misses adding 0: premultiplied by coverage), and
  // its mean over the pixels (the share of the frame the product fills). Empty and 1 otherwise.
  std::vector<float> coverage;
  double fill = 1;
  double mean[3] = {0, 0, 0};     // per channel, over the pixels
  bool adaptive = false;
  uint32_t min_samples_per_pixel = 0, max_samples_per_pixel = 0;
};

class Renderer {
 public:
  // `stop` is the cancellation token (asked between chunks: not OK ends the render with its status); `progress`
  // is called on the renderer's thread after each step that changed what the renderer reports.
  Renderer(RenderInputs inputs, QueryEvaluator* evaluator, std::function<Status()> stop,
           std::function<void()> progress);
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  // 1. The fidelity plan (its pilots run here). Not OK: the render cannot be made.
  Status Plan();
  // 2. Whether Build has work: the environment folded into `btf` materials, or material samplers not yet built.
  bool NeedsBuild() const;
  // Off the renderer's thread, within `stop` and the memory `admit` grants (a new fold's bytes).
  Status Build(const std::function<bool()>& stop, const std::function<bool(uint64_t)>& admit);
  // 3. Renders (after a successful Build, if it had work): the first chunks go to the evaluator.
  void Start();

  const Status& status() const { return status_; }
  bool InFlight() const;                   // a chunk is with the evaluator (the renderer must outlive it)
  bool done() const { return done_; }      // every view rendered: images() is complete
  uint64_t samples_done() const { return samples_done_; }
  uint64_t samples_total() const { return samples_total_; }  // of every view (an adaptive view's once allocated)
  double error_target() const { return error_target_; }
  const std::vector<ObjectFidelity>& fidelity() const { return plan_.fidelity; }  // set by Plan and Build
  // Per object: the rungs of the fidelity ladder its hits took, as (rung name, share of its hits); empty for
  // an object no camera ray hit. Complete once done().
  struct RungShare {
    std::string rung;
    double share = 0;
  };
  std::vector<std::vector<RungShare>> RungShares() const;
  // Every object's hits together.
  std::vector<RungShare> TotalRungShares() const;
  const std::vector<RenderedImage>& images() const { return images_; }
  const std::vector<RenderView>& views() const { return in_.views; }
  uint64_t queries() const { return queries_; }
  double kernel_seconds() const { return kernel_seconds_; }

 private:
  struct Chunk;
  void ChooseBtfEnvironment();
  void FindTableCandidates();
  void TakeTables();
  const models::PreparedMaterial* SampledMaterial(size_t object, const FoldedEnvironment* folded) const;
  void StartView();
  void NoticeStop();
  std::pair<uint32_t, uint32_t> PassSamples(uint64_t pixel) const;
  void Prepare(Chunk& chunk);
  void TraceBlocks(Chunk& chunk, std::atomic<uint64_t>* next_block, std::vector<QueryBucket>* buckets) const;
  void MaybeSubmit();
  void OnChunkDone(int index, const ShadingOutcome& outcome);
  void AllocateSamples();
  uint32_t MostSamples() const;
  uint32_t PixelSamples(uint64_t pixel) const;
  void Accumulate(Chunk& chunk);
  void FinishView();

  RenderInputs in_;
  RenderSetup& setup_;  // in_.setup, its camera the current view's
  QueryEvaluator* const evaluator_;
  const std::function<Status()> stop_;
  const std::function<void()> progress_;
  Status status_;
  FidelityPlan plan_;
  double error_target_;
  bool folding_ = false;  // the `btf` objects' environment light is folded or a candidate (ChooseBtfEnvironment)
  // Build's results, taken by Start.
  std::shared_ptr<const FoldedEnvironment> folded_;
  std::vector<FidelityChoice> fold_choices_;
  // Objects whose BRDF path's material may be tabulated (its table built in Build when it is not yet).
  std::vector<size_t> table_candidates_;

  std::unique_ptr<Chunk[]> chunks_;  // two
  bool submitted_[2] = {false, false};
  bool in_flight_ = false;
  int next_chunk_ = 0;  // the chunk to submit next (chunks alternate)
  size_t view_ = 0;
  uint64_t total_pixels_ = 0, chunk_slots_ = 1, next_pixel_ = 0, pass_pixels_done_ = 0;
  uint64_t samples_done_ = 0, samples_total_ = 0;
  std::vector<Rgb> sums_;  // per pixel: the sum over its samples
  std::vector<uint32_t> hits_;  // product_only, per pixel: its samples whose camera ray hit an object
  // Per object, per rung (0: its evaluator, 1: its near evaluator): the camera hits that took it.
  std::vector<std::array<uint64_t, 2>> rung_hits_;
  // Prepare: the queries of trace threads 1.. (per evaluator), before they join the chunk's buckets.
  std::vector<std::vector<QueryBucket>> trace_parts_;
  // Sampling: pass 0 gives every pixel first_pass_ samples (all of samples_per_pixel when uniform); an adaptive
  // render's pass 1 then gives pixel p its samples up to counts_[p].
  bool adaptive_ = false;
  uint32_t first_pass_ = 0;
  int pass_ = 0;
  std::vector<uint32_t> counts_;
  std::vector<double> squares_;       // adaptive, pass 0: per pixel, its samples' squared radiance summed over channels
  std::vector<float> pixel_queries_;  // adaptive, pass 0: per pixel, its samples' queries
  uint64_t queries_ = 0;
  double kernel_seconds_ = 0;
  bool done_ = false;
  std::vector<RenderedImage> images_;
};

// A rendered view encoded for the client.
//  - image: with background kScene, each pixel's mean radiance over its samples, what the background shows
//    included. With kWhite and kTransparent, each pixel's mean over ALL its samples of the radiance of those that
//    hit the product, a miss adding 0 (radiance premultiplied by coverage: the product's colour is image /
//    coverage).
//  - coverage: with kWhite and kTransparent (required), width x height values in [0, 1], the share of each
//    pixel's samples that hit the product; kScene ignores it (may be null).
// EXR: linear and unscaled (*used_exposure 1): kScene the image; kTransparent RGBA, premultiplied (the image,
// then the coverage); kWhite the image + (1 - coverage). PNG, JPEG, WebP: the product's colour x exposure (0:
// automatic, AutomaticExposure over the product's pixels weighted by coverage, or the whole image with kScene;
// the one used in *used_exposure) through the ACES curve to sRGB, then the background as imaging::EncodeImage
// puts it (white blended in display space; alpha unassociated). "" or why not (JPEG with kTransparent:
// imaging::CheckBackground's reason, which a request should have been refused with).
std::string EncodeRendered(const imaging::LinearRgbImage& image, const std::vector<float>* coverage,
                           imaging::Background background, imaging::ImageFormat format, double exposure,
                           std::string* bytes, double* used_exposure);

}  // namespace loomlight::render
