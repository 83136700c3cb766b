#include "server/api/texture_slice.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/unary_call.h"
#include "server/imaging/image_encode.h"
#include "server/models/texture_slice.h"

namespace loomlight::api {
namespace {

constexpr const char* kRpc = "TextureSlice";
using Clock = batching::Clock;


imaging::ImageFormat ToImaging(v1::ImageFormat format) {
  switch (format) {
    case v1::IMAGE_FORMAT_EXR: return imaging::ImageFormat::kExr;
    case v1::IMAGE_FORMAT_RAW: return imaging::ImageFormat::kRaw;
    default: return imaging::ImageFormat::kPng;
  }
}

std::string ValidateOneDirection(const google::protobuf::RepeatedField<float>& w, const std::string& field) {
  if (w.size() != 3)
    return field + ": needs exactly one xyz direction (3 values), got " + std::to_string(w.size()) + " values";
  return ValidateDirections(w, field);
}

std::string ValidateRegion(const v1::TextureRegion& region) {
  const std::pair<const char*, double> coords[] = {{"region.u_min", region.u_min()}, {"region.v_min", region.v_min()},
                                                   {"region.u_max", region.u_max()}, {"region.v_max", region.v_max()}};
  for (const auto& [field, value] : coords)
    if (!std::isfinite(value) || std::fabs(value) > kMaxTextureCoordinate)
      return std::string(field) + ": " + std::to_string(value) + " is not finite within +-" +
             std::to_string(static_cast<int>(kMaxTextureCoordinate)) + " pattern repeats";
  if (!(region.u_max() > region.u_min()))
    return "region.u_max: " + std::to_string(region.u_max()) + " must exceed region.u_min " +
           std::to_string(region.u_min());
  if (!(region.v_max() > region.v_min()))
    return "region.v_max: " + std::to_string(region.v_max()) + " must exceed region.v_min " +
           std::to_string(region.v_min());
  return "";
}

std::string ValidateSide(uint32_t pixels, const char* field) {
  if (pixels < 1 || pixels > kMaxSliceSide)
    return std::string(field) + ": " + std::to_string(pixels) + " pixels is outside 1.." + std::to_string(kMaxSliceSide);
  return "";
}

// The region to render: the request's, or one pattern repeat when unset.
v1::TextureRegion RegionOf(const v1::TextureSliceRequest& request) {
  if (request.has_region()) return request.region();
  v1::TextureRegion unit;
  unit.set_u_max(1.0);
  unit.set_v_max(1.0);
  return unit;
}

uint32_t SamplesPerPixel(const v1::TextureSliceRequest& request) {
  return std::max<uint32_t>(request.samples_per_pixel(), 1);
}

models::SliceSampling SamplingOf(const v1::TextureSliceRequest& request) {
  const v1::TextureRegion region = RegionOf(request);
  return {region.u_min(), region.v_min(), region.u_max(), region.v_max(), request.width(), request.height(),
          SamplesPerPixel(request)};
}

// One TextureSlice call in flight: its inputs, two chunk buffers and the image accumulated so far.
// While one chunk is on the device the worker accumulates the previous one and fills the next, so the
// device does not wait for host work. Shared by the batcher job in flight and the worker tasks; the
// reactor is finished exactly once, never while a chunk is in flight (the batcher polls the context until
// its done callback), and nothing here is touched after that.
class SliceCall : public std::enable_shared_from_this<SliceCall> {
 public:
  SliceCall(const TextureSliceDeps& deps, grpc::CallbackServerContext* context,
            const v1::TextureSliceRequest& request, v1::TextureSliceResponse* response,
            std::shared_ptr<const models::PreparedMaterial> material, Admission admission, Clock::time_point received)
      : deps_(deps),
        admission_(std::move(admission)),
        context_(context),
        client_(FairShareKey(*context, *deps.trusted_proxies)),
        reactor_(context->DefaultReactor()),
        response_(response),
        material_(std::move(material)),
        material_request_(request.material()),
        received_(received),
        fp64_(request.precision() == v1::PRECISION_FP64),
        width_(request.width()),
        height_(request.height()),
        samples_(SamplesPerPixel(request)),
        sampling_(SamplingOf(request)),
        format_(request.format()),
        exposure_(request.exposure()),
        total_queries_(uint64_t{width_} * height_ * samples_),
        // Whole pixels per chunk, so each pixel's mean comes from one chunk.
        chunk_queries_(std::min<uint64_t>(kSliceChunkQueries / samples_ * samples_, total_queries_)) {
    deadline_ = deps.call_caps.Deadline(received, CallDeadline(context, received), batching::Priority::kInteractive);
    for (int c = 0; c < 3; ++c) {
      wi_one_[c] = request.wi(c);
      wo_one_[c] = request.wo(c);
    }
  }

  grpc::ServerUnaryReactor* reactor() const { return reactor_; }
  const std::string& client() const { return client_; }  // every task of the call takes this client's turn

  // On the host worker (never a gRPC callback thread: these are megabytes of work): the direction buffers,
  // the image, both chunk buffers, then the first chunk submitted (nothing else touches them yet).
  void Start() {
    if (!StillWanted()) return;
    if (!material_)
      if (grpc::Status s = PrepareMaterial(deps_, material_request_, &material_); !s.ok()) return Finish(s);
    // The kernel takes a direction per query: the one wi and wo, repeated, shared by both chunk buffers.
    wi_ = models::RepeatedDirection(wi_one_, chunk_queries_);
    wo_ = models::RepeatedDirection(wo_one_, chunk_queries_);
    image_.width = static_cast<int>(width_);
    image_.height = static_cast<int>(height_);
    image_.rgb.resize(size_t{3} * width_ * height_);
    Prepare(chunks_[0]);
    Prepare(chunks_[1]);
    Submit(0);
  }

 private:
  // A range of queries [first, first + count) of whole pixels and their texture coordinates; count 0: none
  // prepared. At most one chunk is in flight; the other is prepared (the next) or empty (no more).
  struct Chunk {
    uint64_t first = 0;
    size_t count = 0;
    std::vector<float> uv;
    std::vector<double> f;  // the kernel writes its results here (3 per query)
    std::unique_ptr<models::EvaluationPlan> plan;
  };

  // Takes the next queries into the chunk (a free buffer) and computes their sample positions.
  void Prepare(Chunk& chunk) {
    chunk.first = next_query_;
    chunk.count = static_cast<size_t>(std::min<uint64_t>(chunk_queries_, total_queries_ - next_query_));
    next_query_ += chunk.count;
    chunk.uv.resize(2 * chunk.count);
    chunk.f.resize(3 * chunk.count);
    models::SliceTexturePositions(sampling_, chunk.first, chunk.count, chunk.uv.data());
  }

  // Sends a prepared chunk to the batcher (a refusal arrives as its result); returns false, having finished the
  // call, when the call is no longer wanted.
  bool Submit(int index) {
    if (!StillWanted()) return false;
    Chunk& chunk = chunks_[index];
    // A slice's material has no layer (rejected above), so its plan is one part: the BTF kernel.
    chunk.plan = std::make_unique<models::EvaluationPlan>(*material_, wi_.data(), wo_.data(), chunk.uv.data(),
                                                          chunk.count);
    SubmitPlan(deps_.batcher, *chunk.plan, runtime::ResultSink{.f64 = chunk.f.data()}, fp64_,
               batching::Priority::kInteractive, deadline_, context_, client_,
               [self = shared_from_this(), index](size_t, batching::JobResult result) {
                 self->deps_.worker->Post(
                     [self, index, result = std::move(result)] { self->OnChunkDone(index, result); }, self->client_);
               });
    return true;
  }

  // On the worker: the next chunk goes to the device first; this one is then accumulated and its buffer
  // refilled with the chunk after next.
  void OnChunkDone(int index, const batching::JobResult& result) {
    if (!failure_.ok()) return Finish(failure_);
    if (result.status != batching::JobStatus::kOk) return Finish(ToStatus(result));
    Chunk& chunk = chunks_[index];
    deps_.metrics->Evaluated(material_->model->name(), fp64_, chunk.count, result.batch_queries,
                             result.batch_requests, result.queue_seconds, result.kernel_seconds);
    kernel_seconds_ += result.kernel_seconds;
    const bool last = chunks_[1 - index].count == 0;
    if (!last && !Submit(1 - index)) return;
    // Per-pixel means (in double, rounded once to the image's float).
    if (std::string error =
            models::AddPixelMeans(samples_, chunk.first, chunk.count, chunk.f.data(), &image_, &image_sum_);
        !error.empty()) {
      failure_ = {grpc::StatusCode::INTERNAL, error};
      if (last) Finish(failure_);
      return;
    }
    Prepare(chunk);  // empty when no queries are left
    if (last) EncodeAndFinish();
  }

  void EncodeAndFinish() {
    if (!StillWanted()) return;
    const imaging::ImageFormat format = ToImaging(format_);
    // The exposure scales the PNG only; EXR and RAW carry f unscaled (reported as 1).
    double exposure = 1.0;
    if (format == imaging::ImageFormat::kPng) exposure = exposure_ > 0 ? exposure_ : imaging::AutomaticExposure(image_);
    std::string bytes;
    const std::string error = imaging::EncodeImage(image_, format, exposure, &bytes);
    if (!error.empty()) return Finish({grpc::StatusCode::INTERNAL, error});
    response_->set_image(std::move(bytes));
    response_->set_format(format_);
    response_->set_width(width_);
    response_->set_height(height_);
    const double pixels = static_cast<double>(width_) * height_;
    for (double sum : image_sum_) response_->add_mean(sum / pixels);
    response_->set_exposure(exposure);
    response_->set_queries(total_queries_);
    response_->set_kernel_seconds(kernel_seconds_);
    response_->set_total_seconds(SecondsSince(received_));
    Finish(grpc::Status::OK);
  }

  // False (and the call finished) once the client went away or the deadline passed: no further work.
  bool StillWanted() {
    const grpc::Status stop = StopStatus(context_, deadline_);
    if (!stop.ok()) Finish(stop);
    return stop.ok();
  }

  void Finish(const grpc::Status& status) {
    admission_.EndSlots();
    FinishUnary(deps_.metrics, reactor_, kRpc, received_, status);
  }

  const TextureSliceDeps deps_;
  Admission admission_;  // the call's slots (given back as it finishes) and bytes (released with the call)
  grpc::CallbackServerContext* const context_;
  const std::string client_;  // FairShareKey
  grpc::ServerUnaryReactor* const reactor_;
  v1::TextureSliceResponse* const response_;
  std::shared_ptr<const models::PreparedMaterial> material_;  // set by Start
  const v1::Material material_request_;
  const Clock::time_point received_;
  Clock::time_point deadline_ = Clock::time_point::max();
  const bool fp64_;
  const uint32_t width_, height_, samples_;
  const models::SliceSampling sampling_;
  const v1::ImageFormat format_;
  const double exposure_;
  const uint64_t total_queries_;
  const uint64_t chunk_queries_;

  float wi_one_[3], wo_one_[3];  // the request's directions
  std::vector<float> wi_, wo_;  // read by the batcher for every chunk
  Chunk chunks_[2];
  uint64_t next_query_ = 0;     // the first query not yet in a chunk
  imaging::LinearRgbImage image_;
  std::array<double, 3> image_sum_ = {0, 0, 0};
  double kernel_seconds_ = 0;
  grpc::Status failure_;  // a chunk's output was unusable; reported when the chunk in flight returns
};

grpc::ServerUnaryReactor* Reject(const TextureSliceDeps& deps, grpc::CallbackServerContext* context,
                                 Clock::time_point received, const grpc::Status& status) {
  return AnswerNow(deps.metrics, context, kRpc, received, status);
}

}  // namespace

size_t SliceBytes(const v1::TextureSliceRequest& request) {
  const uint64_t queries = uint64_t{request.width()} * request.height() * SamplesPerPixel(request);
  const uint64_t chunk = std::min<uint64_t>(kSliceChunkQueries, queries);
  // Per chunk query: wi and wo (24), both chunks' uv (16), the kernel's result and its copy (48); per pixel:
  // the linear image (12) and its encoding (at most 16).
  return chunk * 88 + uint64_t{request.width()} * request.height() * 28;
}

std::string ValidateTextureSliceRequest(const v1::TextureSliceRequest& request) {
  for (const auto& [field, w] : {std::pair{"wi", &request.wi()}, std::pair{"wo", &request.wo()}})
    if (std::string error = ValidateOneDirection(*w, field); !error.empty()) return error;
  if (request.has_region())
    if (std::string error = ValidateRegion(request.region()); !error.empty()) return error;
  if (std::string error = ValidateSide(request.width(), "width"); !error.empty()) return error;
  if (std::string error = ValidateSide(request.height(), "height"); !error.empty()) return error;
  if (request.samples_per_pixel() > kMaxSamplesPerPixel)
    return "samples_per_pixel: " + std::to_string(request.samples_per_pixel()) + " is outside 0.." +
           std::to_string(kMaxSamplesPerPixel);
  const uint64_t samples = uint64_t{request.width()} * request.height() * SamplesPerPixel(request);
  if (samples > kMaxSliceSamples)
    return "samples_per_pixel: width x height x samples_per_pixel = " + std::to_string(samples) +
           " exceeds the limit of " + std::to_string(kMaxSliceSamples) + " per call";
  if (!v1::ImageFormat_IsValid(request.format()))
    return "format: unknown value " + std::to_string(request.format());
  if (!v1::Precision_IsValid(request.precision()))
    return "precision: unknown value " + std::to_string(request.precision());
  if (!std::isfinite(request.exposure()) || request.exposure() < 0)
    return "exposure: " + std::to_string(request.exposure()) + " must be finite and >= 0 (0 = automatic)";
  return "";
}

grpc::ServerUnaryReactor* HandleTextureSlice(const TextureSliceDeps& deps, grpc::CallbackServerContext* context,
                                             const v1::TextureSliceRequest* request,
                                             v1::TextureSliceResponse* response) {
  const auto received = Clock::now();
  const models::Model* model = nullptr;
  std::shared_ptr<const models::PreparedMaterial> material;  // null until packed, on the host worker
  if (std::string error = deps.materials->Peek(request->material(), *deps.registry, &model, &material); !error.empty())
    return Reject(deps, context, received, MaterialError(error));
  if (!model->spatially_varying())
    return Reject(deps, context, received,
                  Invalid("material: model '" + model->name() +
                          "' is not spatially varying (no BTF); a texture slice needs one, e.g. preset cotton_twill"));
  // A slice images the reflection BTF; a curtain's transmission layer would be silently ignored, so say so.
  if (request->material().has_transmission())
    return Reject(deps, context, received,
                  Invalid("material.transmission: a texture slice shows the BTF only; send no transmission layer"));
  if (std::string error = ValidateTextureSliceRequest(*request); !error.empty())
    return Reject(deps, context, received, Invalid(error));
  if (request->precision() == v1::PRECISION_FP64 && !deps.has_fp64)
    return Reject(deps, context, received, {grpc::StatusCode::FAILED_PRECONDITION, "precision: the OpenCL device has no fp64"});

  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, SliceBytes(*request), &admission); !s.ok())
    return Reject(deps, context, received, s);
  auto call = std::make_shared<SliceCall>(deps, context, *request, response, std::move(material),
                                          std::move(admission), received);
  grpc::ServerUnaryReactor* reactor = call->reactor();
  deps.worker->Post([call] { call->Start(); }, call->client());  // on failure it finishes the call itself
  return reactor;
}

}  // namespace loomlight::api
