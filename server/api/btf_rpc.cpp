#include "server/api/btf_rpc.h"

#include <grpcpp/alarm.h>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <thread>

#include "server/api/access.h"
#include "server/api/job_status.h"
#include "server/api/render_rpc.h"
#include "server/api/stream_call.h"
#include "server/api/upload_bounds.h"
#include "server/api/yarn_rpc.h"
#include "server/assets/btf_store.h"
#include "server/imaging/image_encode.h"
#include "server/models/btf/uploaded_images.h"
#include "server/models/material_plan.h"
#include "server/models/quote.h"
#include "server/render/btf_synthesis.h"

namespace loomlight::api {
namespace {
using batching::Clock;
constexpr const char* kRpc = "CreateBtf";

constexpr const char* kUploadRpc = "UploadBtf";

// Ends an upload that cannot start (no store; the service not serving), recording it.
class RejectedUpload final : public grpc::ServerReadReactor<v1::UploadBtfMessage> {
 public:
  RejectedUpload(Metrics* metrics, grpc::Status status) {
    metrics->Call(kUploadRpc, status.error_code(), 0);
    Finish(std::move(status));
  }
  void OnDone() override { delete this; }
};

grpc::Status NoStore() {
  return {grpc::StatusCode::FAILED_PRECONDITION, "this server keeps no BTF assets (started without a data directory)"};
}

// The checks CreateBtf and UploadBtf share (fields named under `prefix`); the tile's size is the caller's.
std::string CheckAssetRequest(const std::string& prefix, const std::string& name, const v1::BtfGrid& grid,
                              const v1::BtfCompression& compression, bool replace, BtfJob* job) {
  if (std::string e = assets::ValidateAssetName(name); !e.empty()) return prefix + "name: " + e;
  job->name = name;
  job->replace = replace;
  if (std::string e = assets::GridOf(grid, prefix + "grid", &job->grid); !e.empty()) return e;
  if (std::string e = CompressionOf(compression, &job->compression); !e.empty()) return prefix + e;
  return "";
}

// The caller's part of a job: who it is (its FairShareKey: its client's name, else the address a trusted proxy
// forwarded, else its host, not its connection, so a client that reconnects still owns its assets) and whether
// its token lists `admin`.
void SetCaller(const ServiceDeps& deps, const grpc::ServerContextBase& context, BtfJob* job) {
  job->owner = FairShareKey(context, *deps.trusted_proxies);
  job->admin = TokenListsRight(context, "admin");
}

grpc::Status NotOwner(const std::string& prefix, const std::string& name) {
  return {grpc::StatusCode::PERMISSION_DENIED, prefix + "name: the asset " + models::Quote(name) +
                                                   " belongs to another client (its owner, or a token with the "
                                                   "admin right, may replace or delete it)"};
}

// Early, before any work: ALREADY_EXISTS when the name is taken (in any case) and the job does not replace it;
// PERMISSION_DENIED when it replaces another client's asset. The store checks again when it writes: another
// call may take the name meanwhile.
grpc::Status CheckNameFree(const ServiceDeps& deps, const BtfJob& job, const std::string& prefix) {
  if (job.replace) {
    const auto old = models::btf::Assets::Global().FindName(job.name);
    if (old && !old->owner.empty() && old->owner != job.owner && !job.admin) return NotOwner(prefix, job.name);
    return grpc::Status::OK;
  }
  if (!deps.btf_store->Exists(job.name)) return grpc::Status::OK;
  return {grpc::StatusCode::ALREADY_EXISTS,
          prefix + "name: an asset named " + models::Quote(job.name) + " exists (set replace, or delete it first)"};
}

std::string CheckTexels(const std::string& field, uint32_t texels, int* out) {
  if (texels > kMaxBtfTexels)
    return field + ": at most " + std::to_string(kMaxBtfTexels) + " texels per side, got " + std::to_string(texels);
  *out = int(texels == 0 ? kDefaultBtfTexels : texels);
  return "";
}

// What an asset was made from, recorded with it.
struct AssetOrigin {
  std::string source;
  double synthesis_seconds = 0;
  double threads_per_tile = 1;
};

// Compresses the images and stores the asset under the job's name, replacing or not; on the geometry worker.
// OK with *out the stored asset, or why not (the stop's status when `stop` ended it).
grpc::Status CompressAndStore(const ServiceDeps& deps, const models::btf::BtfImages& images, const BtfJob& job,
                              const AssetOrigin& origin, const std::function<void(size_t)>& progress,
                              const std::function<grpc::Status()>& stop,
                              std::shared_ptr<models::btf::BtfAsset>* out) {
  const int threads = int(std::max(1u, std::min(4u, std::thread::hardware_concurrency())));
  std::shared_ptr<models::btf::BtfAsset> asset = models::btf::Compress(
      images, job.compression, progress, [&stop] { return !stop().ok(); }, threads);
  if (!asset) {
    grpc::Status s = stop();
    return s.ok() ? grpc::Status(grpc::StatusCode::INTERNAL, "compression failed") : s;
  }
  asset->name = job.name;
  asset->source = origin.source;
  asset->synthesis_seconds = origin.synthesis_seconds;
  asset->threads_per_tile = origin.threads_per_tile;
  asset->owner = job.owner;
  std::string error;
  switch (deps.btf_store->Put(asset, job.replace, &error, job.admin)) {
    case assets::BtfStore::Outcome::kOk:
      deps.materials->Clear();  // a material naming this name must not find a replaced asset's packing
      if (deps.folds) deps.folds->Clear();  // nor its folds (they keep the old tables alive)
      *out = asset;
      return grpc::Status::OK;
    case assets::BtfStore::Outcome::kExists: return {grpc::StatusCode::ALREADY_EXISTS, "name: " + error};
    case assets::BtfStore::Outcome::kFull: return {grpc::StatusCode::RESOURCE_EXHAUSTED, error};
    case assets::BtfStore::Outcome::kDenied: return NotOwner("", job.name);
    case assets::BtfStore::Outcome::kFailed: break;
  }
  return {grpc::StatusCode::INTERNAL, error};
}

// Bytes a call building this asset holds at most: the images, every view's PCA and the packed tables.
size_t BuildBytes(const BtfJob& job) {
  const size_t n = job.grid.size(), d = 3 * size_t(job.width) * job.height,
               k = size_t(std::min<int>(job.compression.max_components, int(n)));
  return n * n * d * sizeof(float) + n * (d * k + n * k + d) * sizeof(double) +
         2 * n * d * sizeof(double) + n * d * (1 + k) * sizeof(float);
}

// ---- The fiber source (render/btf_capture.h) ----

// Rays per texel by default and at most.
constexpr uint32_t kDefaultFiberSamples = 4;
constexpr uint32_t kMaxFiberSamples = 64;
// The patch traced: this many weave repeats per side, the tile the central one (Scene::tiling needs 3).
constexpr int kFiberTileRepeats = 3;
// The request's fiber source: its yarn on its weave (cotton_twill by default) laid out 3 x 3 repeats, or in its
// knit laid out kKnitPatchWales x kKnitPatchCourses, at full detail within Render's fiber limits. "" or
// "fibers.field: reason".
std::string FiberSourceOf(const models::Registry& registry, const v1::FiberBtfSource& f, FiberSource* out) {
  if (f.samples_per_texel() > kMaxFiberSamples)
    return "fibers.samples_per_texel: at most " + std::to_string(kMaxFiberSamples) + ", got " +
           std::to_string(f.samples_per_texel());
  out->samples = int(f.samples_per_texel() == 0 ? kDefaultFiberSamples : f.samples_per_texel());
  YarnJob& job = out->yarn;
  job.limits.max_fibers = static_cast<int64_t>(kMaxRenderFibers);
  job.limits.max_control_points = static_cast<int64_t>(kMaxRenderFiberPoints);
  job.detail.threads = 2;
  job.detail.footprint = 0;  // every fiber: the texels are finer than a ply
  if (f.has_knit()) {
    if (f.has_woven()) return "fibers.knit: give a knit or a woven layout, not both";
    v1::KnitYarnLayout knit = f.knit();
    for (const auto& [field, stitches] : {std::pair{"wales", knit.wales()}, {"courses", knit.courses()}})
      if (stitches != 0)
        return std::string("fibers.knit.") + field +
               ": the tile is one repeat of the stitch and the server lays out the patch around it; leave it 0";
    knit.set_wales(kKnitPatchWales);
    knit.set_courses(kKnitPatchCourses);
    if (std::string e = YarnJobOf(registry, f.yarn(), {.knit = &knit}, &job); !e.empty()) return "fibers." + e;
    return "";
  }
  v1::WovenYarnLayout woven = f.woven();
  for (const auto& [field, repeats] : {std::pair{"repeats_u", woven.repeats_u()}, {"repeats_v", woven.repeats_v()}})
    if (repeats != 0)
      return std::string("fibers.woven.") + field +
             ": the tile is one repeat and the server lays out the patch around it; leave it 0";
  if (!woven.has_weave()) woven.mutable_weave()->set_preset("cotton_twill");
  woven.set_repeats_u(kFiberTileRepeats);
  woven.set_repeats_v(kFiberTileRepeats);
  if (std::string e = YarnJobOf(registry, f.yarn(), &woven, 0, &job); !e.empty()) return "fibers." + e;
  return "";
}

// The fiber source's bytes on top of BuildBytes: the generated curves while the BVH is built (the BVH itself is
// admitted once estimated), the layout's polylines and one piece's queries.
size_t FiberSourceBytes(const FiberSource& f) {
  return kMaxRenderFiberPoints * kYarnBytesPerPoint + kMaxRenderFibers * kYarnBytesPerFiber + f.yarn.layout_bytes +
         render::kBtfPieceQueries * render::kBtfBytesPerPieceQuery;
}

// One CreateBtf call: the material prepared on the geometry worker; its images synthesised view by view
// (render::BtfSynthesis: every light and texel of a view as bulk batcher jobs; from fibers, a piece of a view's
// texels traced on the geometry worker, then its queries), one evaluation in flight; then compression and
// storing on the geometry worker; progress written from the host worker, one write in flight.
class CreateBtfCall final : public WorkerStreamCall<v1::CreateBtfProgress> {
 public:
  CreateBtfCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, BtfJob job, v1::Material material,
                std::unique_ptr<FiberSource> fibers, Admission admission, Clock::time_point received)
      : WorkerStreamCall(deps, context, kRpc, received, std::move(admission)), job_(std::move(job)),
        material_(std::move(material)), fibers_(std::move(fibers)),
        evaluator_({deps_.batcher, deps_.metrics, false, deadline_, context_, client_,
                    [this](std::function<void()> task) { Post(std::move(task)); }, [this] { Pump(); }, false}) {
    deps_.geometry->Post([this] { Prepare(); }, client_);
  }

 private:
  enum class Stage { kPreparing, kSynthesis, kCompression, kDone };

  // On the geometry worker: the material packed, the fibers built when the source is fibers, and the synthesis
  // set up (its images allocated, the directions every view shares).
  void Prepare() {
    std::shared_ptr<const models::PreparedMaterial> prepared;
    std::unique_ptr<render::BtfCapture> capture;
    grpc::Status s = PrepareMaterial(deps_, material_, &prepared);
    if (s.ok() && fibers_) s = PrepareFibers(*prepared, &capture);
    else if (s.ok() && !prepared->model->spatially_varying())
      s = Invalid("material: model " + models::Quote(prepared->model->name()) +
                  " does not vary over the surface (a BTF needs one that does, e.g. woven)");
    if (s.ok() && prepared->transmission) s = Invalid("material.transmission: a BTF asset is a reflection model");
    std::unique_ptr<render::BtfSynthesis> synthesis;
    if (s.ok()) {
      const auto stop = [this] { return FromGrpc(StopStatus(context_, deadline_)); };
      const auto progress = [this] { Pump(); };
      synthesis = capture ? std::make_unique<render::BtfSynthesis>(prepared, std::move(capture), &evaluator_, stop, progress)
                          : std::make_unique<render::BtfSynthesis>(prepared, job_.grid, job_.width, job_.height,
                                                                   &evaluator_, stop, progress);
    }
    Post([this, s, prepared, synthesis = std::shared_ptr<render::BtfSynthesis>(std::move(synthesis))] {
      prepared_ = prepared;
      synthesis_ = synthesis;
      if (!s.ok() && status_.ok()) status_ = s;
      stage_ = Stage::kSynthesis;
      Pump();
    });
  }

  void Pump() override {
    if (finished_ || stage_ == Stage::kPreparing) return;  // OnCancel's pump waits for the worker's step
    NoticeStop();
    if (status_.ok() && synthesis_ && !synthesis_->status().ok()) status_ = ToGrpc(synthesis_->status());
    if (status_.ok()) MaybeSubmitView();
    if (!status_.ok()) {
      const bool in_flight = synthesis_ && synthesis_->InFlight();
      if (!in_flight && !compressing_ && !tracing_ && !write_in_flight_) FinishCall(status_);
      return;
    }
    if (write_in_flight_) return;
    if (stage_ == Stage::kDone && final_sent_) return FinishCall(grpc::Status::OK);
    if (reported_ != Progress()) WriteProgress();
  }

  std::tuple<Stage, size_t> Progress() const {
    return {stage_, stage_ == Stage::kSynthesis ? synthesis_->views_done() : stage_ == Stage::kCompression ? compressed_ : 0};
  }

  void WriteProgress() {
    reported_ = Progress();
    message_.Clear();
    const size_t n = job_.grid.size();
    message_.set_views(uint32_t(n));
    switch (stage_) {
      case Stage::kSynthesis:
        message_.set_stage("synthesis");
        message_.set_views_done(uint32_t(synthesis_->views_done()));
        break;
      case Stage::kCompression:
        message_.set_stage("compression");
        message_.set_views_done(uint32_t(compressed_));
        break;
      default:
        message_.set_stage("done");
        message_.set_views_done(uint32_t(n));
        assets::DescribeAsset(*asset_, message_.mutable_asset());
        final_sent_ = true;
    }
    write_in_flight_ = true;
    StartWrite(&message_);
  }

  // On the geometry worker: the fiber model checked, the patch's fibers generated and built, the capture set up.
  grpc::Status PrepareFibers(const models::PreparedMaterial& prepared, std::unique_ptr<render::BtfCapture>* capture) {
    if (prepared.model->fiber_axis_param().empty() || prepared.transmission)
      return Invalid("material: a fiber source shades each fiber with a fiber model (e.g. preset cotton), not " +
                     models::Quote(prepared.model->name()) + (prepared.transmission ? " with a layer" : ""));
    std::shared_ptr<const yarn::FiberScene> scene;
    grpc::Status s = BuildFiberScene(
        &fibers_->yarn, [this] { return StopStatus(context_, deadline_); },
        [this](size_t bytes) { return admission_.bytes.Grow(bytes); }, &scene, nullptr, deps_.fiber_scenes,
        "fibers.yarn");
    if (!s.ok()) return s;
    const YarnJob& y = fibers_->yarn;
    const double spacing = y.layout.spacing;
    render::Scene::Tiling tile{y.pattern.warps * spacing, y.pattern.picks * spacing, y.pattern.warps * spacing,
                               y.pattern.picks * spacing};
    if (y.kind == yarn::YarnLayoutKind::kKnit) {
      // The stitch repeat at the middle of the patch, on its grid (courses from y = 0, wales from x = 0).
      yarn::KnitLayout knit;
      if (std::string e = yarn::BuildKnit(y.knit, &knit); !e.empty()) return {grpc::StatusCode::INTERNAL, e};
      const auto middle = [](double size, double period) { return std::floor(0.5 * size / period) * period; };
      tile = {middle(y.knit.wales * knit.wale_spacing, knit.period_x),
              middle(y.knit.courses * knit.course_spacing, knit.period_y), knit.period_x, knit.period_y};
    }
    *capture = std::make_unique<render::BtfCapture>(scene, tile, job_.grid, job_.width, job_.height, fibers_->samples,
                                                    fibers_->yarn.params.seed);
    return grpc::Status::OK;
  }

  // The next view (or piece of one) to the batcher when none is in flight; after the last, compression.
  void MaybeSubmitView() {
    if (stage_ != Stage::kSynthesis || synthesis_->InFlight() || compressing_ || tracing_) return;
    if (synthesis_->done()) return StartCompression();
    if (synthesis_->NeedsTrace()) return TracePiece();
    synthesis_->Submit();
  }

  // The fiber source: the next piece of the current view traced on the geometry worker (two threads), then its
  // queries to the batcher.
  void TracePiece() {
    tracing_ = true;
    deps_.geometry->Post([this] {
      synthesis_->Trace(ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); }));
      Post([this] {
        tracing_ = false;
        if (status_.ok()) synthesis_->Submit();  // does nothing once the call is to stop
        Pump();
      });
    }, client_);
  }

  // On the geometry worker: the PCA of every view, then the asset written to the store.
  void StartCompression() {
    compressing_ = true;
    stage_ = Stage::kCompression;
    synthesis_->ReleaseQueries();  // the synthesis' queries and results, not needed any more
    synthesis_seconds_ = SecondsSince(received_);
    deps_.geometry->Post([this] {
      std::shared_ptr<models::btf::BtfAsset> asset;
      models::btf::BtfImages& images = synthesis_->images();
      grpc::Status s = CompressAndStore(
          deps_, images, job_, {Describe(), synthesis_seconds_, ThreadsPerTile()},
          [this](size_t done) { Post([this, done] { compressed_ = done; Pump(); }); },
          ReportingProgress([this] { return StopStatus(context_, deadline_); }), &asset);
      images.f = {};  // the call's biggest buffer, not needed to answer
      Post([this, s, asset] {
        compressing_ = false;
        if (!s.ok()) {
          if (status_.ok()) status_ = s;
        } else {
          asset_ = asset;
          stage_ = Stage::kDone;
        }
        Pump();
      });
    }, client_);
  }

  std::string Describe() const {
    const models::Model& m = *prepared_->model;
    std::string s = material_.preset().empty() ? "model " + m.name() : m.name() + " preset " + material_.preset();
    if (material_.params_size() > 0) s += " with " + std::to_string(material_.params_size()) + " parameters set";
    if (!fibers_) return s + ", synthesised at texel centres";
    const YarnJob& y = fibers_->yarn;
    char text[200];
    const yarn::KnitParams& k = y.knit;
    if (y.kind == yarn::YarnLayoutKind::kKnit)
      std::snprintf(text, sizeof text, "fibers: %s knit, wale spacing %.4g, course spacing %.4g, yarn seed %llu, shaded by ",
                    k.stitch == yarn::KnitStitch::kRib1x1 ? "1 x 1 rib" : "jersey",
                    k.wale_spacing > 0 ? k.wale_spacing : yarn::DefaultWaleSpacing(k.stitch, k.yarn_radius),
                    k.course_spacing > 0 ? k.course_spacing : yarn::DefaultCourseSpacing(k.stitch, k.yarn_radius),
                    static_cast<unsigned long long>(y.params.seed));
    else
      std::snprintf(text, sizeof text, "fibers: %d x %d weave, spacing %.4g, crimp %.3g, yarn seed %llu, shaded by ",
                    y.pattern.warps, y.pattern.picks, y.layout.spacing, y.layout.crimp,
                    static_cast<unsigned long long>(y.params.seed));
    return std::string(text) + s + ", " + std::to_string(fibers_->samples) + " rays per texel";
  }

  double ThreadsPerTile() const {
    // A knit's tile: its wales (a rib's repeat has two), each a loop of two legs across.
    if (fibers_ && fibers_->yarn.kind == yarn::YarnLayoutKind::kKnit)
      return fibers_->yarn.knit.stitch == yarn::KnitStitch::kRib1x1 ? 2 : 1;
    if (fibers_) return std::max(fibers_->yarn.pattern.warps, fibers_->yarn.pattern.picks);
    return prepared_->model->ThreadsPerRepeat(prepared_->values);
  }

  BtfJob job_;
  const v1::Material material_;
  const std::unique_ptr<FiberSource> fibers_;  // the fiber source (null: the material's own f at texel centres)
  BatcherEvaluator evaluator_;
  std::shared_ptr<render::BtfSynthesis> synthesis_;  // set once prepared
  bool tracing_ = false;  // the geometry worker traces a piece of a view
  Stage stage_ = Stage::kPreparing;
  std::shared_ptr<const models::PreparedMaterial> prepared_;
  size_t compressed_ = 0;
  bool compressing_ = false, final_sent_ = false;
  double synthesis_seconds_ = 0;
  std::shared_ptr<models::btf::BtfAsset> asset_;
  std::tuple<Stage, size_t> reported_{Stage::kPreparing, 0};
  v1::CreateBtfProgress message_;
};

// One UploadBtf call: the header takes a long-call slot (on gRPC's thread: a few checks). Each image is checked
// and decoded on the asset loader (the client's turn among clients; one read at a time): its header is read
// first, refused beyond 4 channels or another size than the upload's, and the bytes its decoding holds are
// charged to the memory budget before they are allocated; the decoded image's bytes stay charged, so a client
// that stalls holds only what it sent, never what its header promised. When the client closes the stream with
// every pair sent, the call is charged for the compression (BuildBytes), the images are gathered into one buffer,
// compressed and stored on the geometry worker, and the call answers the stored asset. An error ends the call at
// once. The upload's bounds (server/api/upload_bounds.h): a client that sends nothing for --upload-idle-seconds
// is cut off, and so is one still sending --max-upload-seconds after the call began.
class UploadBtfCall final : public grpc::ServerReadReactor<v1::UploadBtfMessage> {
 public:
  UploadBtfCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, v1::BtfAssetInfo* response)
      : deps_(deps), context_(context), response_(response), received_(Clock::now()),
        deadline_(CallDeadline(context, received_)), bounds_(deps, context),
        client_(FairShareKey(*context, *deps.trusted_proxies)) {
    StartRead(&message_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) return EndOfStream();
    bounds_.Touch();
    if (images_seen_ < 0) return Next(Header());
    deps_.loader->Post(
        [this] {
          const grpc::Status s = Image();
          bounds_.Touch();  // a wait for the loader is not the client's silence
          Next(s);
        },
        client_);
  }
  void OnDone() override { delete this; }

 private:
  // The next read, or the end of the call with an error.
  void Next(const grpc::Status& s) {
    if (!s.ok()) return Finish(s);
    message_.Clear();
    StartRead(&message_);
  }

  grpc::Status Header() {
    if (!message_.has_header()) return Invalid("the first message must be a header");
    const v1::UploadBtfHeader& h = message_.header();
    std::string e = CheckAssetRequest("header.", h.name(), h.grid(), h.compression(), h.replace(), &job_);
    if (e.empty() && (h.width() == 0 || h.height() == 0)) e = "header.width, header.height: give the images' size";
    if (e.empty()) e = CheckTexels("header.width", h.width(), &job_.width);
    if (e.empty()) e = CheckTexels("header.height", h.height(), &job_.height);
    if (e.empty() && (!std::isfinite(h.value_scale()) || h.value_scale() < 0))
      e = "header.value_scale: must be finite and >= 0";
    if (!e.empty()) return Invalid(e);
    scale_ = h.value_scale() == 0 ? 1.0 : h.value_scale();
    if (!(h.threads_per_tile() == 0 || (h.threads_per_tile() >= 1 && h.threads_per_tile() <= 1024)))
      return Invalid("header.threads_per_tile: must be in [1, 1024] (0 = 1)");
    threads_per_tile_ = h.threads_per_tile() == 0 ? 1.0 : h.threads_per_tile();
    SetCaller(deps_, *context_, &job_);
    if (grpc::Status s = CheckNameFree(deps_, job_, "header."); !s.ok()) return s;
    if (grpc::Status s = AdmitLongCall(deps_, *context_, 0, &admission_); !s.ok()) return s;
    const size_t n = job_.grid.size();
    images_.grid = job_.grid;
    images_.width = job_.width;
    images_.height = job_.height;
    pairs_.assign(n * n, {});
    images_seen_ = 0;
    return grpc::Status::OK;
  }

  grpc::Status Image() {
    const std::string field = "images[" + std::to_string(images_seen_++) + "]";
    if (!message_.has_image()) return Invalid(field + ": after the header, only images");
    const v1::BtfImage& image = message_.image();
    const size_t n = job_.grid.size();
    if (size_t(images_seen_) > n * n)
      return Invalid(field + ": more images than the grid's " + std::to_string(n * n) + " (view, light) pairs");
    int slot[2];
    const char* names[2] = {"view", "light"};
    const google::protobuf::RepeatedField<float>* dirs[2] = {&image.view(), &image.light()};
    for (int k = 0; k < 2; ++k) {
      const auto& w = *dirs[k];
      const std::string f = field + "." + names[k];
      if (w.size() != 3) return Invalid(f + ": an xyz direction, 3 values, got " + std::to_string(w.size()));
      const double x = w[0], y = w[1], z = w[2], norm = std::sqrt(x * x + y * y + z * z);
      if (!std::isfinite(norm) || std::abs(norm - 1) > kUnitTolerance) return Invalid(f + ": not a unit vector");
      const double unit[3] = {x / norm, y / norm, z / norm};
      slot[k] = job_.grid.Find(unit, 0.5);
      if (slot[k] < 0) return Invalid(f + ": not within 0.5 degrees of a direction of the grid");
    }
    const size_t pair = size_t(slot[0]) * n + size_t(slot[1]);
    if (!pairs_[pair].empty())
      return Invalid(field + ": view " + std::to_string(slot[0]) + " and light " + std::to_string(slot[1]) +
                     " were sent before");
    // From the image's header, before its pixels are decoded: its size, and the bytes decoding it takes charged
    // (released with `decoded`, declared after it) along with the bytes the call keeps of it.
    batching::Budget::Reservation decoding;
    bool over_budget = false;
    const auto admit = [&](int width, int height, int channels) -> std::string {
      if (width != job_.width || height != job_.height)
        return std::to_string(width) + " x " + std::to_string(height) + " pixels, the header says " +
               std::to_string(job_.width) + " x " + std::to_string(job_.height);
      if (deps_.memory->TryReserve(imaging::DecodeBytes(width, height, channels), &decoding) &&
          admission_.bytes.Grow(images_.image_values() * sizeof(float)))
        return "";
      over_budget = true;
      return "the server's memory budget holds no more images now; retry later";
    };
    imaging::LinearRgbImage decoded;
    if (std::string e = imaging::DecodeImage(image.data(), size_t(kMaxBtfTexels) * kMaxBtfTexels, &decoded, admit);
        !e.empty())
      return {over_budget ? grpc::StatusCode::RESOURCE_EXHAUSTED : grpc::StatusCode::INVALID_ARGUMENT,
              field + ".data: " + e};
    if (!models::btf::StoreUploadedImage(decoded.rgb.data(), job_.width, job_.height, scale_, &pairs_[pair]))
      return Invalid(field + ".data: a value that is negative or not finite (f is >= 0)");
    ++filled_count_;
    return grpc::Status::OK;
  }

  // The client closed its side (or went away): everything arrived, or the call fails saying what is missing.
  void EndOfStream() {
    // Nothing more to receive (compressing is not idling), or a bound cut the upload off.
    if (grpc::Status s = bounds_.Stop(); !s.ok()) return Finish(s);
    if (grpc::Status s = StopStatus(context_, deadline_); !s.ok()) return Finish(s);
    if (images_seen_ < 0) return Finish(Invalid("no header: the stream was empty"));
    const size_t n = job_.grid.size();
    if (filled_count_ < n * n) {
      size_t missing = 0;
      while (!pairs_[missing].empty()) ++missing;
      return Finish(Invalid("images: " + std::to_string(n * n - filled_count_) + " of " + std::to_string(n * n) +
                            " (view, light) pairs missing, the first view " + std::to_string(missing / n) +
                            ", light " + std::to_string(missing % n)));
    }
    if (!admission_.bytes.Grow(BuildBytes(job_)))
      return Finish(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                                 "the server's memory budget cannot hold the compression of " +
                                     std::to_string(n * n) + " images now; retry later"));
    deps_.geometry->Post([this] {
      models::btf::GatherPairs(&pairs_, &images_);  // one buffer, view-major, as Compress reads it
      std::shared_ptr<models::btf::BtfAsset> asset;
      grpc::Status s = CompressAndStore(deps_, images_, job_, {"upload", 0, threads_per_tile_}, nullptr,
                                        ReportingProgress([this] { return StopStatus(context_, deadline_); }), &asset);
      images_.f = {};
      if (s.ok()) assets::DescribeAsset(*asset, response_);
      Finish(s);
    }, client_);
  }

  void Finish(const grpc::Status& s) {
    bounds_.Stop();  // an error before the end of the stream
    deps_.metrics->Call(kUploadRpc, s.error_code(), SecondsSince(received_));
    admission_.EndSlots();
    grpc::ServerReadReactor<v1::UploadBtfMessage>::Finish(s);
  }

  const ServiceDeps deps_;
  grpc::CallbackServerContext* const context_;
  v1::BtfAssetInfo* const response_;
  const Clock::time_point received_, deadline_;
  UploadBounds bounds_;
  const std::string client_;  // FairShareKey: its images take their turn on the loader
  Admission admission_;
  BtfJob job_;
  double scale_ = 1, threads_per_tile_ = 1;
  int images_seen_ = -1;  // -1: the header has not come
  models::btf::BtfImages images_;          // grid and size from the header; the values once all have come
  std::vector<std::vector<float>> pairs_;  // the images as they arrive, by view * N + light
  size_t filled_count_ = 0;
  v1::UploadBtfMessage message_;
};
}  // namespace

std::string CompressionOf(const v1::BtfCompression& c, models::btf::CompressionOptions* out) {
  if (c.max_components() > uint32_t(models::btf::kMaxComponents))
    return "compression.max_components: at most " + std::to_string(models::btf::kMaxComponents);
  out->max_components = int(c.max_components() == 0 ? kDefaultBtfComponents : c.max_components());
  if (!std::isfinite(c.target_psnr_db()) || c.target_psnr_db() < 0 || c.target_psnr_db() > 200)
    return "compression.target_psnr_db: must be in [0, 200] dB";
  out->target_psnr_db = c.target_psnr_db();
  return "";
}

grpc::Status CheckCreateBtfRequest(const models::Registry& registry, const v1::CreateBtfRequest& request, BtfJob* job,
                                   std::unique_ptr<FiberSource>* fibers, size_t* bytes) {
  std::string e = CheckAssetRequest("", request.name(), request.grid(), request.compression(), request.replace(), job);
  if (e.empty()) e = CheckTexels("resolution", request.resolution(), &job->width);
  if (!e.empty()) return Invalid(e);
  job->height = job->width;
  fibers->reset();
  if (request.has_fibers()) {
    *fibers = std::make_unique<FiberSource>();
    if (std::string f = FiberSourceOf(registry, request.fibers(), fibers->get()); !f.empty()) return Invalid(f);
  }
  *bytes = BuildBytes(*job) + (*fibers ? FiberSourceBytes(**fibers) : 0);
  return grpc::Status::OK;
}

grpc::ServerWriteReactor<v1::CreateBtfProgress>* HandleCreateBtf(const ServiceDeps& deps,
                                                                 grpc::CallbackServerContext* context,
                                                                 const v1::CreateBtfRequest* request) {
  const auto received = Clock::now();
  const auto reject = [&](grpc::Status status) {
    return new RejectedStream<v1::CreateBtfProgress>(deps.metrics, kRpc, received, std::move(status));
  };
  if (!deps.btf_store) return reject(NoStore());
  BtfJob job;
  std::unique_ptr<FiberSource> fibers;
  size_t bytes = 0;
  if (grpc::Status s = CheckCreateBtfRequest(*deps.registry, *request, &job, &fibers, &bytes); !s.ok()) return reject(s);
  SetCaller(deps, *context, &job);
  if (grpc::Status s = CheckNameFree(deps, job, ""); !s.ok()) return reject(s);
  const models::Model* model = nullptr;
  std::shared_ptr<const models::PreparedMaterial> cached;
  if (std::string e = deps.materials->Peek(request->material(), *deps.registry, &model, &cached); !e.empty())
    return reject(MaterialError(e));
  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, bytes, &admission); !s.ok()) return reject(s);
  return new CreateBtfCall(deps, context, std::move(job), request->material(), std::move(fibers), std::move(admission),
                           received);
}

grpc::ServerReadReactor<v1::UploadBtfMessage>* HandleUploadBtf(const ServiceDeps& deps,
                                                               grpc::CallbackServerContext* context,
                                                               v1::BtfAssetInfo* response, grpc::Status serving) {
  if (!serving.ok()) return new RejectedUpload(deps.metrics, std::move(serving));
  if (!deps.btf_store) return new RejectedUpload(deps.metrics, NoStore());
  return new UploadBtfCall(deps, context, response);
}

grpc::Status HandleListBtfs(const ServiceDeps& deps, v1::ListBtfsResponse* response) {
  if (!deps.btf_store) return NoStore();
  for (const auto& asset : deps.btf_store->List()) assets::DescribeAsset(*asset, response->add_assets());
  response->set_max_bytes(deps.btf_store->max_bytes());
  return grpc::Status::OK;
}

grpc::Status HandleDeleteBtf(const ServiceDeps& deps, const grpc::ServerContextBase& context,
                             const v1::DeleteBtfRequest& request) {
  if (!deps.btf_store) return NoStore();
  if (std::string e = assets::ValidateAssetName(request.name()); !e.empty()) return Invalid("name: " + e);
  switch (deps.btf_store->Delete(request.name(), FairShareKey(context, *deps.trusted_proxies),
                                 TokenListsRight(context, "admin"))) {
    case assets::BtfStore::Removal::kNotFound:
      return {grpc::StatusCode::NOT_FOUND, "name: no BTF asset named " + models::Quote(request.name())};
    case assets::BtfStore::Removal::kDenied: return NotOwner("", request.name());
    case assets::BtfStore::Removal::kRemoved: break;
  }
  deps.materials->Clear();
  if (deps.folds) deps.folds->Clear();
  return grpc::Status::OK;
}

}  // namespace loomlight::api
