#include "server/api/btf_rpc.h"

#include <algorithm>
#include <thread>

#include "server/api/job_status.h"
#include "server/api/stream_call.h"
#include "server/assets/btf_store.h"
#include "server/models/material_plan.h"
#include "server/models/quote.h"

namespace loomlight::api {
namespace {
using batching::Clock;
constexpr const char* kRpc = "CreateBtf";

grpc::Status NoStore() {
  return {grpc::StatusCode::FAILED_PRECONDITION, "this server keeps no BTF assets (started without a data directory)"};
}

// A request's asset: its name, grid, tile and compression.
struct BtfJob {
  std::string name;
  models::btf::DirectionGrid grid;
  int texels = 0;
  models::btf::CompressionOptions compression;
  bool replace = false;
};

std::string CheckAssetRequest(const std::string& name, const v1::BtfGrid& grid, uint32_t texels,
                              const v1::BtfCompression& compression, bool replace, BtfJob* job) {
  if (std::string e = assets::ValidateAssetName(name); !e.empty()) return "name: " + e;
  job->name = name;
  job->replace = replace;
  if (std::string e = assets::GridOf(grid, "grid", &job->grid); !e.empty()) return e;
  if (texels > kMaxBtfTexels)
    return "resolution: at most " + std::to_string(kMaxBtfTexels) + " texels per side, got " + std::to_string(texels);
  job->texels = int(texels == 0 ? kDefaultBtfTexels : texels);
  return CompressionOf(compression, &job->compression);
}

// Bytes a call building this asset holds at most: the images, every view's PCA and the packed tables.
size_t BuildBytes(const BtfJob& job) {
  const size_t n = job.grid.size(), d = 3 * size_t(job.texels) * job.texels,
               k = size_t(std::min<int>(job.compression.max_components, int(n)));
  return n * n * d * sizeof(float) + n * (d * k + n * k + d) * sizeof(double) +
         2 * n * d * sizeof(double) + n * d * (1 + k) * sizeof(float);
}

// One CreateBtf call: the material prepared on the geometry worker; one view's images in flight on the batcher
// at a time (every light and texel of the view: a bulk job); then compression and storing on the geometry
// worker; progress written from the host worker, one write in flight.
class CreateBtfCall final : public WorkerStreamCall<v1::CreateBtfProgress> {
 public:
  CreateBtfCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, BtfJob job, v1::Material material,
                Admission admission, Clock::time_point received)
      : WorkerStreamCall(deps, context, kRpc, received, std::move(admission)), job_(std::move(job)),
        material_(std::move(material)) {
    deps_.geometry->Post([this] { Prepare(); });
  }

 private:
  enum class Stage { kPreparing, kSynthesis, kCompression, kDone };

  // On the geometry worker: the material packed, and the directions every view shares.
  void Prepare() {
    std::shared_ptr<const models::PreparedMaterial> prepared;
    grpc::Status s = PrepareMaterial(deps_, material_, &prepared);
    if (s.ok() && !prepared->model->spatially_varying())
      s = Invalid("material: model " + models::Quote(prepared->model->name()) +
                  " does not vary over the surface (a BTF needs one that does, e.g. woven)");
    if (s.ok() && prepared->transmission) s = Invalid("material.transmission: a BTF asset is a reflection model");
    if (s.ok()) {
      const size_t n = job_.grid.size(), texels = size_t(job_.texels) * job_.texels;
      images_.grid = job_.grid;
      images_.width = images_.height = job_.texels;
      images_.f.assign(n * n * images_.image_values(), 0.0f);
      // Query (light l, texel t) of a view: wi the light's direction, uv the texel's centre.
      wi_.resize(3 * n * texels);
      uv_.resize(2 * n * texels);
      wo_.resize(3 * n * texels);
      for (size_t l = 0; l < n; ++l) {
        double w[3];
        job_.grid.Direction(l, w);
        for (size_t t = 0; t < texels; ++t) {
          const size_t q = l * texels + t;
          for (int c = 0; c < 3; ++c) wi_[3 * q + c] = float(w[c]);
          uv_[2 * q] = float((double(t % job_.texels) + 0.5) / job_.texels);
          uv_[2 * q + 1] = float((double(t / job_.texels) + 0.5) / job_.texels);
        }
      }
    }
    Post([this, s, prepared] {
      prepared_ = prepared;
      if (!s.ok() && status_.ok()) status_ = s;
      stage_ = Stage::kSynthesis;
      Pump();
    });
  }

  void Pump() override {
    if (finished_ || stage_ == Stage::kPreparing) return;  // OnCancel's pump waits for the worker's step
    NoticeStop();
    if (status_.ok()) MaybeSubmitView();
    if (!status_.ok()) {
      if (!job_in_flight_ && !compressing_ && !write_in_flight_) FinishCall(status_);
      return;
    }
    if (write_in_flight_) return;
    if (stage_ == Stage::kDone && final_sent_) return FinishCall(grpc::Status::OK);
    if (reported_ != Progress()) WriteProgress();
  }

  std::tuple<Stage, size_t> Progress() const {
    return {stage_, stage_ == Stage::kSynthesis ? views_done_ : stage_ == Stage::kCompression ? compressed_ : 0};
  }

  void WriteProgress() {
    reported_ = Progress();
    message_.Clear();
    const size_t n = job_.grid.size();
    message_.set_views(uint32_t(n));
    switch (stage_) {
      case Stage::kSynthesis:
        message_.set_stage("synthesis");
        message_.set_views_done(uint32_t(views_done_));
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

  // The next view's images to the batcher when none is in flight; after the last, compression.
  void MaybeSubmitView() {
    if (stage_ != Stage::kSynthesis || job_in_flight_ || compressing_) return;
    const size_t n = job_.grid.size(), texels = size_t(job_.texels) * job_.texels;
    if (next_view_ == n) return StartCompression();
    const size_t v = next_view_++;
    double w[3];
    job_.grid.Direction(v, w);
    for (size_t q = 0; q < n * texels; ++q)
      for (int c = 0; c < 3; ++c) wo_[3 * q + c] = float(w[c]);
    plan_ = std::make_unique<models::EvaluationPlan>(*prepared_, wi_.data(), wo_.data(), uv_.data(), n * texels);
    job_in_flight_ = plan_->parts();
    SubmitPlan(deps_.batcher, *plan_, runtime::ResultSink{.f32 = images_.image(v, 0)}, false,
               batching::Priority::kBulk, deadline_, context_, [this](size_t k, batching::JobResult result) {
                 Post([this, k, result = std::move(result)] { OnViewDone(k, result); });
               });
  }

  void OnViewDone(size_t part, const batching::JobResult& result) {
    --job_in_flight_;
    if (result.status != batching::JobStatus::kOk) {
      if (status_.ok()) status_ = ToStatus(result);
    } else if (result.batch_queries > 0) {
      deps_.metrics->Evaluated(plan_->model(part).name(), false, plan_->size(part), result.batch_queries,
                               result.batch_requests, result.queue_seconds, result.kernel_seconds);
      synthesis_kernel_seconds_ += result.kernel_seconds;
    }
    if (job_in_flight_ == 0 && status_.ok()) ++views_done_;
    Pump();
  }

  // On the geometry worker: the PCA of every view, then the asset written to the store.
  void StartCompression() {
    compressing_ = true;
    stage_ = Stage::kCompression;
    synthesis_seconds_ = SecondsSince(received_);
    deps_.geometry->Post([this] {
      const auto stop = [this] { return !StopStatus(context_, deadline_).ok(); };
      const int threads = int(std::max(1u, std::min(4u, std::thread::hardware_concurrency())));
      std::shared_ptr<models::btf::BtfAsset> asset = models::btf::Compress(
          images_, job_.compression, [this](size_t done) { Post([this, done] { compressed_ = done; Pump(); }); }, stop,
          threads);
      grpc::Status s;
      if (!asset) {
        s = StopStatus(context_, deadline_);
        if (s.ok()) s = {grpc::StatusCode::INTERNAL, "compression failed"};
      } else {
        asset->name = job_.name;
        asset->source = Describe();
        asset->synthesis_seconds = synthesis_seconds_;
        std::string error;
        switch (deps_.btf_store->Put(asset, job_.replace, &error)) {
          case assets::BtfStore::Outcome::kOk: deps_.materials->Clear(); break;
          case assets::BtfStore::Outcome::kExists: s = {grpc::StatusCode::ALREADY_EXISTS, "name: " + error}; break;
          case assets::BtfStore::Outcome::kFull: s = {grpc::StatusCode::RESOURCE_EXHAUSTED, error}; break;
          case assets::BtfStore::Outcome::kFailed: s = {grpc::StatusCode::INTERNAL, error}; break;
        }
      }
      images_.f = {};  // the call's biggest buffer, not needed to answer
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
    });
  }

  std::string Describe() const {
    const models::Model& m = *prepared_->model;
    std::string s = material_.preset().empty() ? "model " + m.name() : m.name() + " preset " + material_.preset();
    if (material_.params_size() > 0) s += " with " + std::to_string(material_.params_size()) + " parameters set";
    return s + ", synthesised at texel centres";
  }

  BtfJob job_;
  const v1::Material material_;
  Stage stage_ = Stage::kPreparing;
  std::shared_ptr<const models::PreparedMaterial> prepared_;
  models::btf::BtfImages images_;
  std::vector<float> wi_, wo_, uv_;
  std::unique_ptr<models::EvaluationPlan> plan_;
  size_t next_view_ = 0, views_done_ = 0, compressed_ = 0, job_in_flight_ = 0;
  bool compressing_ = false, final_sent_ = false;
  double synthesis_seconds_ = 0, synthesis_kernel_seconds_ = 0;
  std::shared_ptr<models::btf::BtfAsset> asset_;
  std::tuple<Stage, size_t> reported_{Stage::kPreparing, 0};
  v1::CreateBtfProgress message_;
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

grpc::ServerWriteReactor<v1::CreateBtfProgress>* HandleCreateBtf(const ServiceDeps& deps,
                                                                 grpc::CallbackServerContext* context,
                                                                 const v1::CreateBtfRequest* request) {
  const auto received = Clock::now();
  const auto reject = [&](grpc::Status status) {
    deps.metrics->Call(kRpc, status.error_code(), SecondsSince(received));
    return new RejectedStream<v1::CreateBtfProgress>(std::move(status));
  };
  if (!deps.btf_store) return reject(NoStore());
  BtfJob job;
  if (std::string e = CheckAssetRequest(request->name(), request->grid(), request->resolution(),
                                        request->compression(), request->replace(), &job);
      !e.empty())
    return reject(Invalid(e));
  if (!job.replace && deps.btf_store->Exists(job.name))
    return reject({grpc::StatusCode::ALREADY_EXISTS, "name: an asset named " + models::Quote(job.name) +
                                                          " exists (set replace, or delete it first)"});
  const models::Model* model = nullptr;
  std::shared_ptr<const models::PreparedMaterial> cached;
  if (std::string e = deps.materials->Peek(request->material(), *deps.registry, &model, &cached); !e.empty())
    return reject(Invalid(e));
  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, BuildBytes(job), &admission); !s.ok()) return reject(s);
  return new CreateBtfCall(deps, context, std::move(job), request->material(), std::move(admission), received);
}

grpc::Status HandleListBtfs(const ServiceDeps& deps, v1::ListBtfsResponse* response) {
  if (!deps.btf_store) return NoStore();
  for (const auto& asset : deps.btf_store->List()) assets::DescribeAsset(*asset, response->add_assets());
  response->set_max_bytes(deps.btf_store->max_bytes());
  return grpc::Status::OK;
}

grpc::Status HandleDeleteBtf(const ServiceDeps& deps, const v1::DeleteBtfRequest& request) {
  if (!deps.btf_store) return NoStore();
  if (std::string e = assets::ValidateAssetName(request.name()); !e.empty()) return Invalid("name: " + e);
  if (!deps.btf_store->Delete(request.name()))
    return {grpc::StatusCode::NOT_FOUND, "name: no BTF asset named " + models::Quote(request.name())};
  deps.materials->Clear();
  return grpc::Status::OK;
}

}  // namespace loomlight::api
