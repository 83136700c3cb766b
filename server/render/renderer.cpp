#include "server/render/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>
#include <thread>

#include "server/models/tabulated_brdf.h"
#include "server/render/adaptive_sampling.h"
#include "server/render/tone_map.h"

namespace loomlight::render {

struct Renderer::Chunk {
  uint64_t first_pixel = 0, pixels = 0;     // pixels 0: nothing prepared
  // Per pixel of the chunk (and one past the last): its first slot, one slot per pixel sample.
  std::vector<uint32_t> slot_begin;
  std::vector<QueryBucket> buckets;  // per evaluator; tag = slot
  std::vector<Rgb> value;            // per slot: the radiance needing no query, then the sample's all
  std::vector<uint16_t> slot_queries;  // adaptive first pass: per slot, its queries (the sample's work)
  std::vector<uint8_t> slot_folded;    // adaptive first pass: per slot, 1 for a hit shaded by the fold
  std::vector<std::vector<double>> f;  // per evaluator: the kernel's results
  std::vector<std::unique_ptr<models::EvaluationPlan>> plans;  // per evaluator: its kernel parts
  uint64_t queries = 0;
  std::vector<uint8_t> slot_hit;  // product_only: per slot, 1 when the camera ray hit an object
  // Per object, per rung: the chunk's camera hits that took it (the trace threads' counts, added under the lock).
  std::vector<std::array<uint64_t, 2>> rung_hits;
  std::mutex rung_lock;
};

Renderer::Renderer(RenderInputs inputs, QueryEvaluator* evaluator, std::function<Status()> stop,
                   std::function<void()> progress)
    : in_(std::move(inputs)), setup_(in_.setup), evaluator_(evaluator), stop_(std::move(stop)),
      progress_(std::move(progress)), error_target_(in_.error_target), chunks_(new Chunk[2]) {
  if (in_.views.empty()) return;  // Plan says so
  const RenderView& first = in_.views.front();
  setup_.camera = PinholeCamera(first.camera, first.width, first.height);
  setup_.width = first.width;
  setup_.height = first.height;
}

Renderer::~Renderer() = default;

Status Renderer::Plan() {
  if (in_.views.empty()) return status_ = {batching::JobStatus::kInternal, "a render needs at least one view"};
  RenderSetup& s = setup_;
  const size_t objects = s.scene.objects.size();
  std::vector<ObjectMaterial> materials(objects);
  s.object_transmits.assign(objects, false);
  for (size_t o = 0; o < objects; ++o) {
    const bool own = o < in_.object_materials.size() && in_.object_materials[o].material;
    const models::PreparedMaterial& material = own ? *in_.object_materials[o].material : *in_.material;
    MaterialInfo& info = materials[o].info;
    info.model = material.model;
    info.values = material.values;
    info.layered = material.transmission != nullptr;
    materials[o].variants = own ? in_.object_materials[o].variants.get() : in_.variants.get();
    s.object_transmits[o] = Transmits(info);
  }
  if (std::string e = ChooseFidelity(s, materials, error_target_, in_.force_full_fidelity, &plan_, int(kTraceThreads));
      !e.empty())
    return status_ = {batching::JobStatus::kInternal, e};
  rung_hits_.assign(objects, {0, 0});
  if (plan_.fiber_full_detail) {  // AUTO's thinning was over the target: the render is at full detail
    s.scene.fibers = s.full_detail_fibers;
    s.scene.fiber_visibility = s.full_detail_visibility;
  }
  // The check's full-detail geometry is held only by s.scene from here (when chosen): otherwise the render
  // does not keep it alive, and the scene cache may let it go.
  s.full_detail_fibers.reset();
  s.full_detail_visibility.reset();
  s.fiber_shadows = plan_.fiber_shadows;
  s.fiber_occlusion = plan_.fiber_occlusion;
  ChooseBtfEnvironment();
  FindTableCandidates();
  return status_;
}

// The ladder's cheapest rung: objects whose BRDF path (no texture, no light through the cloth, no fibers) is
// the analytic model of a material whose model declares its lobe width may take the material's tabulated BRDF,
// in renders large enough to repay building it (kTabulateFromSamples) or when it is built already.
void Renderer::FindTableCandidates() {
  if (in_.force_full_fidelity) return;
  uint64_t samples = 0;
  for (const RenderView& view : in_.views) samples += uint64_t(view.width) * view.height * setup_.samples_per_pixel;
  for (size_t o = 0; o < plan_.objects.size(); ++o) {
    const int e = plan_.objects[o].evaluator;
    if (e < 0) continue;
    const Evaluator& far = plan_.evaluators[e];
    if (far.with_uv || far.transmission || far.fiber_axis || far.quantity != models::Quantity::kScattering) continue;
    if (far.material->TableBuilt() && far.material->Table()) {
      table_candidates_.push_back(o);
    } else if (samples >= kTabulateFromSamples) {
      if (std::string why = far.material->TableBuilt() ? far.material->TableRefusal() : far.material->Untabulable();
          why.empty())
        table_candidates_.push_back(o);
      else
        plan_.fidelity[o].choices.push_back({"brdf_table", "analytic", "analytic", 0, "not tabulated: " + why});
    }
  }
}

// After Build: each candidate takes its material's table where the table's measured error is within the target.
void Renderer::TakeTables() {
  for (size_t o : table_candidates_) {
    ObjectShading& shading = plan_.objects[o];
    const models::PreparedMaterial* material = plan_.evaluators[shading.evaluator].material;
    const models::TabulatedBrdf* table = material->Table();
    FidelityChoice choice{"brdf_table", "analytic", "analytic", 0, ""};
    if (!table) {
      choice.reason = "not tabulated: " + material->TableRefusal();
    } else if (table->measured_error() > error_target_) {
      choice.reason = Format("the table is %.2g from the analytic model (relative L1), over the target",
                             table->measured_error());
    } else {
      Evaluator tabulated = plan_.evaluators[shading.evaluator];
      tabulated.table = table;
      shading.evaluator = EvaluatorIndex(&plan_.evaluators, tabulated);
      choice.chosen = "tabulated";
      choice.estimated_error = table->measured_error();
      choice.reason = Format("the BRDF looked up in a %d x %d x %d x %d table (%.3g MB), %.2g from the analytic "
                             "model (relative L1)", table->grid().eta_x, table->grid().eta_y, table->grid().psi,
                             table->grid().chi, table->bytes() / 1e6, table->measured_error());
    }
    plan_.fidelity[o].choices.push_back(choice);
    plan_.fidelity[o].estimated_error += choice.estimated_error;
  }
}

// Whether the environment light of the `btf` objects may be folded (btf_environment FOLDED, or AUTO where the
// fold's estimated error is within the target: FoldEnvironment decides, once folded) or is sampled, in the
// fidelity report of every object whose material is a `btf` asset lit by an environment. FOLDED is validated
// by the caller: a `btf` material without a layer, environment lighting, not a fiber scene.
void Renderer::ChooseBtfEnvironment() {
  const models::PreparedMaterial& material = *in_.material;
  // Folding is for one material over every object (objects wearing several sample the map as ever), and one
  // environment (a turntable's turns with its views).
  if (!in_.object_materials.empty()) return;
  for (const RenderView& view : in_.views)
    if (view.environment) return;
  if (!setup_.environment || !material.model->folds_environment() || setup_.scene.fibers) return;
  const bool asked = in_.btf_environment != BtfEnvironmentChoice::kSampled;
  folding_ = asked && !in_.force_full_fidelity && !material.transmission;
  if (folding_) return;
  const std::string reason = in_.force_full_fidelity ? "force_full_fidelity"
                             : material.transmission
                                 ? "the material lets light through its layer: the fold is of reflected light only"
                                 : "requested";
  for (size_t o = 0; o < plan_.fidelity.size(); ++o)
    if (!setup_.scene.objects[o].fibers)
      plan_.fidelity[o].choices.push_back({"btf_environment", "sampled", "sampled", 0, reason});
}

// The material whose sampler object o's hits draw from (null: it samples lights only, as fibers do and as objects
// whose environment light is in `folded` do).
const models::PreparedMaterial* Renderer::SampledMaterial(size_t o, const FoldedEnvironment* folded) const {
  if (folded && folded->Covers(int(o))) return nullptr;
  const int e = plan_.objects[o].evaluator;
  return e >= 0 && !plan_.evaluators[e].fiber_axis ? plan_.evaluators[e].material : nullptr;
}

// Surfaces sample their material too (weighed against the environment's samples by MIS), unless their
// environment light is folded. A material's table is built on its first render (in Build, off the renderer's
// thread) and kept with it in the material cache; the fold, when requested or a candidate, is built and chosen
// there first.
bool Renderer::NeedsBuild() const {
  if (folding_) return true;
  for (size_t o : table_candidates_)
    if (!plan_.evaluators[plan_.objects[o].evaluator].material->TableBuilt()) return true;
  for (size_t o = 0; o < plan_.objects.size() && setup_.environment; ++o)
    if (const models::PreparedMaterial* m = SampledMaterial(o, nullptr); m && !m->SamplerBuilt()) return true;
  return false;
}

Status Renderer::Build(const std::function<bool()>& stop, const std::function<bool(uint64_t)>& admit) {
  if (folding_) {
    // Each object's `btf` material (as its kernel path reads it: the chosen components, BTF or BRDF) folded with
    // the environment.
    std::vector<FoldedEnvironment::Material> materials(plan_.objects.size());
    for (size_t o = 0; o < plan_.objects.size(); ++o) {
      const int e = plan_.objects[o].evaluator;
      if (e < 0) continue;
      const Evaluator& evaluator = plan_.evaluators[e];
      materials[o] = {evaluator.material->packed.tables, evaluator.material->packed.uniform, evaluator.with_uv};
    }
    bool refused = false;
    const std::string e = FoldEnvironment(setup_, materials, in_.folds, error_target_,
                                          in_.btf_environment == BtfEnvironmentChoice::kFolded, int(kTraceThreads),
                                          stop, admit, &refused, &folded_, &fold_choices_);
    if (!e.empty())
      return {refused ? batching::JobStatus::kResourceExhausted : batching::JobStatus::kInternal,
              "btf_environment: " + e};
  }
  for (size_t o = 0; o < plan_.objects.size() && setup_.environment; ++o)
    if (const models::PreparedMaterial* m = SampledMaterial(o, folded_.get()); m && !m->SamplerBuilt()) {
      m->Sampler();
      if (in_.materials) in_.materials->ChargeSampler(*m);
    }
  for (size_t o : table_candidates_) {
    if (stop()) return {batching::JobStatus::kCancelled, "stopped while tabulating a BRDF"};
    const models::PreparedMaterial* m = plan_.evaluators[plan_.objects[o].evaluator].material;
    if (m->TableBuilt()) continue;
    m->Table();
    if (in_.materials) in_.materials->ChargeTable(*m);
  }
  return {};
}

void Renderer::Start() {
  RenderSetup& s = setup_;
  TakeTables();
  s.folded_environment = folded_;
  for (size_t o = 0; o < fold_choices_.size() && o < plan_.fidelity.size(); ++o)
    if (!fold_choices_[o].aspect.empty()) {
      plan_.fidelity[o].choices.push_back(fold_choices_[o]);
      plan_.fidelity[o].estimated_error += fold_choices_[o].estimated_error;
    }
  s.object_samplers.assign(s.scene.objects.size(), nullptr);
  for (size_t o = 0; o < plan_.objects.size() && s.environment; ++o)
    if (const models::PreparedMaterial* m = SampledMaterial(o, s.folded_environment.get()))
      s.object_samplers[o] = &m->Sampler();
  chunk_slots_ = std::max<uint64_t>(1, kRenderChunkQueries / std::max<size_t>(1, MaxQueriesPerSample(s)));
  const uint32_t spp = s.samples_per_pixel;
  adaptive_ = in_.sampling == Sampling::kAdaptive || (in_.sampling == Sampling::kAuto && spp >= kAutoAdaptiveSamples);
  first_pass_ = adaptive_ ? FirstPassSamples(spp) : spp;
  for (const RenderView& view : in_.views) samples_total_ += uint64_t(view.width) * view.height * spp;
  StartView();
}

// The current view's camera and first pass; its first chunks go to the evaluator.
void Renderer::StartView() {
  RenderSetup& s = setup_;
  const RenderView& view = in_.views[view_];
  s.camera = PinholeCamera(view.camera, view.width, view.height);
  if (view.lights) s.lights = *view.lights;
  if (view.environment) s.environment = view.environment;
  s.width = view.width;
  s.height = view.height;
  total_pixels_ = uint64_t(s.width) * s.height;
  sums_.assign(total_pixels_, Rgb{});
  hits_.assign(in_.product_only ? total_pixels_ : 0, 0);
  pass_ = 0;
  next_pixel_ = 0;
  pass_pixels_done_ = 0;
  counts_.clear();
  if (adaptive_) {
    squares_.assign(total_pixels_, 0.0);
    pixel_queries_.assign(total_pixels_, 0.0f);
  }
  // The first chunk goes to the evaluator before the second is traced, so the two overlap from the start.
  Prepare(chunks_[next_chunk_]);
  MaybeSubmit();
  Prepare(chunks_[1 - next_chunk_]);
}

bool Renderer::InFlight() const { return in_flight_; }

void Renderer::NoticeStop() {
  if (!status_.ok()) return;
  if (Status s = stop_(); !s.ok()) status_ = std::move(s);
}

// The samples of `pixel` this pass traces: [begin, end).
std::pair<uint32_t, uint32_t> Renderer::PassSamples(uint64_t pixel) const {
  return pass_ == 0 ? std::pair{0u, first_pass_} : std::pair{first_pass_, counts_[pixel]};
}

// Traces the next pixels of the pass (at most chunk_slots_ samples, or one pixel) into a free chunk buffer (none
// left: pixels = 0).
void Renderer::Prepare(Chunk& chunk) {
  chunk.first_pixel = next_pixel_;
  chunk.slot_begin.assign(1, 0);
  uint64_t slots = 0;
  for (; next_pixel_ < total_pixels_; ++next_pixel_) {
    const auto [begin, end] = PassSamples(next_pixel_);
    if (chunk.slot_begin.size() > 1 && slots + (end - begin) > chunk_slots_) break;
    slots += end - begin;
    chunk.slot_begin.push_back(static_cast<uint32_t>(slots));
  }
  chunk.pixels = next_pixel_ - chunk.first_pixel;
  chunk.buckets.resize(plan_.evaluators.size());
  for (QueryBucket& b : chunk.buckets) b.Clear();
  chunk.value.assign(slots, Rgb{});
  chunk.slot_folded.assign(adaptive_ && pass_ == 0 ? slots : 0, 0);
  chunk.slot_hit.assign(in_.product_only ? slots : 0, 0);
  chunk.rung_hits.assign(plan_.objects.size(), {0, 0});
  chunk.queries = 0;
  // Chunks are traced on kTraceThreads threads (casting rays and sampling lights and materials is the host's
  // share of a render), each taking the next block of kTraceBlockPixels pixels into its own buckets, appended
  // in thread order. Blocks are handed out as threads come for them, not fixed per thread: beside the device's
  // threads the two trace threads do not get equal CPU, and with every other block fixed to each, one thread
  // waited 10-27 ms per chunk for the other (a fifth of the satin cylinders' render with a core idle). Which
  // thread traces a block changes only where its queries sit in the batch; each sample's queries stay
  // together and in order, every query is evaluated alone, and a sample's value goes to its own slot, so the
  // image does not depend on the threads' timing.
  const uint64_t threads = std::clamp<uint64_t>(chunk.pixels, 1, kTraceThreads);
  // The other threads' buckets are kept from chunk to chunk, and through a chunk of one pixel or none (a
  // pass's end): filled afresh each time, they page-faulted their memory in again, which made the second
  // thread 15-25% slower than the first.
  trace_parts_.resize(std::max<size_t>(trace_parts_.size(), threads - 1));
  for (std::vector<QueryBucket>& part : trace_parts_) {
    part.resize(plan_.evaluators.size());
    for (QueryBucket& b : part) b.Clear();
  }
  std::atomic<uint64_t> next_block{0};
  std::vector<std::thread> workers;
  for (uint64_t t = 1; t < threads; ++t)
    workers.emplace_back([this, &chunk, &next_block, t] { TraceBlocks(chunk, &next_block, &trace_parts_[t - 1]); });
  TraceBlocks(chunk, &next_block, &chunk.buckets);
  for (std::thread& w : workers) w.join();
  for (const std::vector<QueryBucket>& part : trace_parts_)
    for (size_t e = 0; e < part.size(); ++e) chunk.buckets[e].Append(part[e]);
  for (const QueryBucket& b : chunk.buckets) chunk.queries += b.size();
}

// Traces the chunk's pixel blocks (of kTraceBlockPixels) this thread takes from *next_block: their queries into
// `buckets`, what needs none into chunk.value. Hits on objects with a folded environment get its radiance too,
// evaluated on the host for all the thread's blocks at once.
void Renderer::TraceBlocks(Chunk& chunk, std::atomic<uint64_t>* next_block, std::vector<QueryBucket>* buckets) const {
  std::array<ShadingPoint, Scene::kMaxPacket> points;
  std::array<PixelSample, Scene::kMaxPacket> batch;
  std::array<uint32_t, Scene::kMaxPacket> batch_slot;
  size_t queued = 0;
  std::vector<FoldedEnvironment::Query> folded;
  std::vector<uint32_t> folded_slot;
  std::vector<std::array<uint64_t, 2>> rung_hits(plan_.objects.size(), {0, 0});
  // Samples are traced a packet at a time, in pixel order (a pixel's queries stay in sample order).
  const auto flush = [&] {
    TracePixelSamples(setup_, {batch.data(), queued}, points.data());
    for (size_t k = 0; k < queued; ++k) {
      const ShadingPoint& point = points[k];
      const uint32_t slot = batch_slot[k];
      if (point.object < 0) {
        chunk.value[slot] = in_.product_only ? Rgb{} : point.background;
        continue;
      }
      if (in_.product_only) chunk.slot_hit[slot] = 1;
      const ObjectShading& shading = plan_.objects[point.object];
      ++rung_hits[point.object][EvaluatorFor(point, shading) == shading.near_evaluator ? 1 : 0];
      chunk.value[slot] = AppendQueries(point, shading, plan_.evaluators, slot, buckets);
      if (point.environment_folded) {
        folded.push_back(setup_.folded_environment->QueryOf(point));
        folded_slot.push_back(slot);
        if (!chunk.slot_folded.empty()) chunk.slot_folded[slot] = 1;
      }
    }
    queued = 0;
  };
  for (uint64_t block = next_block->fetch_add(1, std::memory_order_relaxed); block * kTraceBlockPixels < chunk.pixels;
       block = next_block->fetch_add(1, std::memory_order_relaxed)) {
    const uint64_t end = std::min<uint64_t>((block + 1) * kTraceBlockPixels, chunk.pixels);
    for (uint64_t p = block * kTraceBlockPixels; p < end; ++p) {
      const uint64_t pixel = chunk.first_pixel + p;
      uint32_t slot = chunk.slot_begin[p];
      const auto [first_sample, last_sample] = PassSamples(pixel);
      for (uint32_t s = first_sample; s < last_sample; ++s, ++slot) {
        batch[queued] = {pixel, s};
        batch_slot[queued] = slot;
        if (++queued == batch.size()) flush();
      }
    }
    flush();  // a packet holds one block's samples, whichever thread traces it
  }
  {
    std::lock_guard lock(chunk.rung_lock);
    for (size_t o = 0; o < rung_hits.size(); ++o)
      for (int r = 0; r < 2; ++r) chunk.rung_hits[o][r] += rung_hits[o][r];
  }
  if (folded.empty()) return;
  std::vector<Rgb> radiance;
  setup_.folded_environment->Radiance(folded, &radiance);
  for (size_t q = 0; q < folded.size(); ++q) chunk.value[folded_slot[q]] = chunk.value[folded_slot[q]] + radiance[q];
}

// Sends the next chunk's queries to the evaluator when none is there (a chunk with none, e.g. only background,
// goes too: the evaluator answers it at once).
void Renderer::MaybeSubmit() {
  NoticeStop();
  Chunk& chunk = chunks_[next_chunk_];
  if (!status_.ok() || in_flight_ || chunk.pixels == 0 || submitted_[next_chunk_]) return;
  submitted_[next_chunk_] = true;
  in_flight_ = true;
  const int index = next_chunk_;
  chunk.f.assign(plan_.evaluators.size(), {});
  chunk.plans.clear();
  chunk.plans.resize(plan_.evaluators.size());
  std::vector<ShadingWork> work;
  for (size_t e = 0; e < plan_.evaluators.size(); ++e) {
    const QueryBucket& b = chunk.buckets[e];
    if (b.size() == 0) continue;
    chunk.f[e].resize(3 * b.size());
    chunk.plans[e] = PlanOf(plan_.evaluators[e], b);
    work.push_back({chunk.plans[e].get(), runtime::ResultSink{.f64 = chunk.f[e].data()}});
  }
  evaluator_->Submit(std::move(work), [this, index](const ShadingOutcome& outcome) { OnChunkDone(index, outcome); });
}

// The next chunk goes to the evaluator first; this one is then accumulated and its buffer refilled.
void Renderer::OnChunkDone(int index, const ShadingOutcome& outcome) {
  Chunk& chunk = chunks_[index];
  in_flight_ = false;
  submitted_[index] = false;
  next_chunk_ = 1 - index;
  if (!outcome.status.ok() && status_.ok()) status_ = outcome.status;
  queries_ += outcome.queries;
  kernel_seconds_ += outcome.kernel_seconds;
  NoticeStop();
  if (status_.ok()) {
    MaybeSubmit();
    Accumulate(chunk);
    if (pass_pixels_done_ == total_pixels_ && pass_ == 0 && adaptive_) {
      // Both buffers are free: the other holds nothing (the pass is done), and this one was just accumulated.
      AllocateSamples();
      Prepare(chunks_[next_chunk_]);
      MaybeSubmit();  // with the evaluator while this buffer is traced
      Prepare(chunk);
    } else {
      Prepare(chunk);
    }
    if (pass_pixels_done_ == total_pixels_) FinishView();
  }
  progress_();
}

// After an adaptive render's first pass: each pixel's samples (render::AllocateSamples), from the spread of its
// first samples and their work (queries, folded hits); then the second pass begins.
void Renderer::AllocateSamples() {
  PixelNoise noise;
  noise.variance.resize(total_pixels_);
  noise.cost.resize(total_pixels_);
  const double n = first_pass_;
  for (uint64_t p = 0; p < total_pixels_; ++p) {
    const Rgb& sum = sums_[p];
    // The unbiased sample variance, summed over the channels: (sum x^2 - (sum x)^2 / n) / (n - 1).
    noise.variance[p] = std::max(0.0, squares_[p] - (sum.x * sum.x + sum.y * sum.y + sum.z * sum.z) / n) / (n - 1);
    noise.cost[p] = kSampleCostWithoutQueries + pixel_queries_[p] / n;
  }
  counts_ = render::AllocateSamples(setup_.width, setup_.height, noise, first_pass_, setup_.samples_per_pixel,
                                    MostSamples());
  // The view's planned samples give way to its allocated ones.
  samples_total_ -= total_pixels_ * setup_.samples_per_pixel;
  for (uint32_t c : counts_) samples_total_ += c;
  squares_ = {};
  pixel_queries_ = {};
  pass_ = 1;
  next_pixel_ = 0;
  pass_pixels_done_ = 0;
}

// The most samples an adaptive render gives one pixel.
uint32_t Renderer::MostSamples() const {
  return static_cast<uint32_t>(std::min<uint64_t>(8 * uint64_t{setup_.samples_per_pixel}, chunk_slots_));
}

uint32_t Renderer::PixelSamples(uint64_t pixel) const {
  return pass_ == 1 ? counts_[pixel] : setup_.samples_per_pixel;
}

// Each sample's radiance (its queries' weight x f added to what needed none), then each pixel's sum; the first
// pass of an adaptive render also keeps each pixel's sum of squares and its queries.
void Renderer::Accumulate(Chunk& chunk) {
  const bool measure = adaptive_ && pass_ == 0;
  if (measure) chunk.slot_queries.assign(chunk.value.size(), 0);
  for (size_t e = 0; e < chunk.buckets.size(); ++e) {
    const QueryBucket& b = chunk.buckets[e];
    const std::vector<double>& f = chunk.f[e];
    for (size_t q = 0; q < b.size(); ++q) {
      Rgb& sample = chunk.value[b.tag[q]];
      for (int c = 0; c < 3; ++c) {
        const double value = double(b.weight[3 * q + c]) * f[3 * q + c];
        if (std::isfinite(value)) (c == 0 ? sample.x : c == 1 ? sample.y : sample.z) += value;
      }
      if (measure) ++chunk.slot_queries[b.tag[q]];
    }
  }
  for (uint64_t p = 0; p < chunk.pixels; ++p) {
    const uint64_t pixel = chunk.first_pixel + p;
    Rgb& sum = sums_[pixel];
    for (uint32_t slot = chunk.slot_begin[p]; slot < chunk.slot_begin[p + 1]; ++slot) {
      const Rgb& v = chunk.value[slot];
      sum = sum + v;
      if (in_.product_only) hits_[pixel] += chunk.slot_hit[slot];
      if (!measure) continue;
      squares_[pixel] += v.x * v.x + v.y * v.y + v.z * v.z;
      pixel_queries_[pixel] += chunk.slot_queries[slot] + (chunk.slot_folded[slot] ? kFoldedSampleCost : 0.0);
    }
  }
  samples_done_ += chunk.value.size();
  pass_pixels_done_ += chunk.pixels;
  for (size_t o = 0; o < chunk.rung_hits.size() && o < rung_hits_.size(); ++o)
    for (int r = 0; r < 2; ++r) rung_hits_[o][r] += chunk.rung_hits[o][r];
}

// The view's image from its sums; then the next view, or the render is done.
void Renderer::FinishView() {
  RenderedImage out;
  imaging::LinearRgbImage& image = out.image;
  image.width = setup_.width;
  image.height = setup_.height;
  image.rgb.resize(3 * total_pixels_);
  for (uint64_t p = 0; p < total_pixels_; ++p)
    for (int c = 0; c < 3; ++c) {
      double v = sums_[p][c] / PixelSamples(p);
      if (!std::isfinite(v) || v < 0) v = 0;  // never NaN or Inf in an image
      image.rgb[3 * p + c] = static_cast<float>(v);
      out.mean[c] += v / total_pixels_;
    }
  if (in_.product_only) {
    out.coverage.resize(total_pixels_);
    double covered = 0;
    for (uint64_t p = 0; p < total_pixels_; ++p) {
      out.coverage[p] = static_cast<float>(double(hits_[p]) / PixelSamples(p));
      covered += out.coverage[p];
    }
    out.fill = covered / double(total_pixels_);
    hits_ = {};
  }
  out.adaptive = adaptive_;
  out.min_samples_per_pixel = out.max_samples_per_pixel = setup_.samples_per_pixel;
  if (adaptive_) {
    const auto range = std::minmax_element(counts_.begin(), counts_.end());
    out.min_samples_per_pixel = *range.first;
    out.max_samples_per_pixel = *range.second;
  }
  images_.push_back(std::move(out));
  sums_ = {};
  if (++view_ < in_.views.size()) return StartView();
  done_ = true;
}

// The rung an evaluator is: fibers, the BTF (texture coordinates) or the BRDF.
static std::string RungName(const Evaluator& e) {
  return e.fiber_axis ? "fibers" : e.with_uv ? "BTF" : e.table ? "tabulated BRDF" : "BRDF";
}

std::vector<std::vector<Renderer::RungShare>> Renderer::RungShares() const {
  std::vector<std::vector<RungShare>> out(rung_hits_.size());
  for (size_t o = 0; o < rung_hits_.size() && o < plan_.objects.size(); ++o) {
    const uint64_t total = rung_hits_[o][0] + rung_hits_[o][1];
    if (total == 0) continue;
    const ObjectShading& shading = plan_.objects[o];
    for (int r = 0; r < 2; ++r) {
      const int e = r == 0 ? shading.evaluator : shading.near_evaluator;
      if (e < 0) continue;
      out[o].push_back({RungName(plan_.evaluators[e]), double(rung_hits_[o][r]) / double(total)});
    }
  }
  return out;
}

std::vector<Renderer::RungShare> Renderer::TotalRungShares() const {
  std::vector<std::pair<std::string, uint64_t>> hits;
  uint64_t total = 0;
  for (size_t o = 0; o < rung_hits_.size() && o < plan_.objects.size(); ++o)
    for (int r = 0; r < 2; ++r) {
      const int e = r == 0 ? plan_.objects[o].evaluator : plan_.objects[o].near_evaluator;
      if (e < 0) continue;
      const std::string name = RungName(plan_.evaluators[e]);
      auto it = std::find_if(hits.begin(), hits.end(), [&](const auto& h) { return h.first == name; });
      if (it == hits.end()) it = hits.insert(hits.end(), {name, 0});
      it->second += rung_hits_[o][r];
      total += rung_hits_[o][r];
    }
  std::vector<RungShare> out;
  for (const auto& [name, n] : hits)
    if (total > 0) out.push_back({name, double(n) / double(total)});
  return out;
}

std::string EncodeRendered(const imaging::LinearRgbImage& image, const std::vector<float>* coverage,
                           imaging::Background background, imaging::ImageFormat format, double exposure,
                           std::string* bytes, double* used_exposure) {
  *used_exposure = 1;
  if (std::string error = imaging::CheckBackground(format, background); !error.empty()) return error;
  const bool product_only = background != imaging::Background::kScene;
  if (product_only && (!coverage || coverage->size() != image.rgb.size() / 3))
    return "the coverage does not match the image";
  if (format == imaging::ImageFormat::kExr && !product_only)
    return imaging::EncodeImage(image, format, 1.0, bytes);
  // One copy of the image: the product's colour, then (8-bit formats) tone mapped in place.
  imaging::LinearRgbImage display = image;
  if (product_only) ProductColour(*coverage, &display);
  if (format != imaging::ImageFormat::kExr) {
    *used_exposure = exposure > 0 ? exposure : AutomaticExposure(display, product_only ? coverage : nullptr);
    ToneMap(*used_exposure, &display);
  }
  return imaging::EncodeImage(display, format, 1.0, bytes, background, product_only ? coverage : nullptr);
}

}  // namespace loomlight::render
