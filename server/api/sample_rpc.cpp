#include "server/api/sample_rpc.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <mutex>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/unary_call.h"
#include "server/models/direction_sampler.h"
#include "server/models/material_plan.h"
#include "server/models/sample_queries.h"

namespace loomlight::api {
namespace {

// One Sample call (server/api/unary_call.h). The gRPC thread checks what is cheap and admits the bytes; on the
// preparer, Start gets the material and checks the rest, Draw draws wi chunk by chunk (the first chunk of a new
// material builds its sampling table), then f(wi, wo) is evaluated through the batcher as Evaluate does (the
// kernels write f straight into the response), and Complete turns f into weights and finishes.
struct SampleCall : PlanCall<v1::SampleRequest, v1::SampleResponse> {
  using PlanCall::PlanCall;
  size_t n = 0;
  double sampling_seconds = 0;

  static void Start(const std::shared_ptr<SampleCall>& call) {
    const v1::SampleRequest& request = *call->request;
    if (std::string error = call->deps->materials->GetWithin(request.material(), *call->deps->registry,
                                                              request.error_target(), &call->material,
                                                              &call->approximation);
        !error.empty())
      return call->Finish(MaterialError(error));
    if (std::string error = CheckSampleQueries(request, *call->material->model); !error.empty())
      return call->Finish(Invalid(error));
    const int n = static_cast<int>(call->n);
    call->response->mutable_wi()->Resize(3 * n, 0.0f);
    call->response->mutable_pdf()->Resize(n, 0.0f);
    call->response->mutable_weight()->Resize(3 * n, 0.0f);
    call->response->mutable_f()->Resize(3 * n, 0.0f);
    Draw(call, 0);
  }

  // Draws queries [begin, begin + kSampleDrawChunk), then posts the next chunk or submits f's evaluation.
  static void Draw(const std::shared_ptr<SampleCall>& call, size_t begin) {
    if (grpc::Status s = StopStatus(call->context, call->deadline); !s.ok()) return call->Finish(s);
    const auto started = batching::Clock::now();
    const bool built = call->material->SamplerBuilt();
    const models::DirectionSampler& sampler = call->material->Sampler();  // built here on first use
    if (!built) call->deps->materials->ChargeSampler(*call->material);
    const v1::SampleRequest& request = *call->request;
    const size_t end = std::min(call->n, begin + kSampleDrawChunk);
    const float* random = request.random_size() > 0 ? request.random().data() : nullptr;  // else from the seed
    models::DrawSampleQueries(sampler, request.wo().data(), random, request.seed(), begin, end,
                              call->response->mutable_wi()->mutable_data(), call->response->mutable_pdf()->mutable_data());
    call->sampling_seconds += SecondsSince(started);
    if (end < call->n) {
      call->deps->preparer->Post([call, end] { Draw(call, end); }, call->client);
      return;
    }
    call->plan = std::make_unique<models::EvaluationPlan>(*call->material, call->response->wi().data(),
                                                          request.wo().data(),
                                                          request.uv_size() > 0 ? request.uv().data() : nullptr, call->n);
    SubmitParts(call, call->response->mutable_f()->mutable_data(), call->n <= kInlineSampleWeights,
                &SampleCall::Complete);
  }

  // weight = f cos / pdf per query (0 where pdf is 0 or the product is not finite), then finishes.
  void Complete() {
    models::SampleWeights(material->Sampler(), n, response->wi().data(), response->pdf().data(), response->f().data(),
                          response->mutable_weight()->mutable_data());
    response->set_sampling_seconds(sampling_seconds);
    Finish(grpc::Status::OK);
  }
};

std::string FormatNumber(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%.9g", v);
  return text;
}

}  // namespace

std::string ValidateSampleRandom(const google::protobuf::RepeatedField<float>& random, size_t n) {
  if (random.empty()) return "";
  if (static_cast<size_t>(random.size()) != 3 * n)
    return "random: length " + std::to_string(random.size()) + " is not 3 per query (" + std::to_string(3 * n) +
           " for " + std::to_string(n) + " queries), or empty to draw them from seed";
  for (int i = 0; i < random.size(); ++i)
    if (!(random[i] >= 0.0f && random[i] < 1.0f))  // NaN fails too
      return "random[" + std::to_string(i) + "]: " + FormatNumber(random[i]) + " is outside [0, 1)";
  return "";
}

grpc::Status CheckSampleRequest(const v1::SampleRequest& request, bool has_fp64) {
  if (grpc::Status s = CheckPrecision(request.precision(), has_fp64); !s.ok()) return s;
  if (request.wo_size() == 0) return Invalid("wo: no directions; give one xyz triple per sample");
  return CheckQueriesAndTarget(request.wo_size() / 3, "wo", request.error_target());
}

std::string CheckSampleQueries(const v1::SampleRequest& request, const models::Model& model) {
  const size_t n = request.wo_size() / 3;
  if (std::string error = ValidateDirections(request.wo(), "wo"); !error.empty()) return error;
  if (request.uv_size() > 0) {
    if (!model.spatially_varying()) return "uv: model '" + model.name() + "' is not spatially varying; send no uv";
    if (std::string error = ValidateTextureCoordinates(request.uv(), n, "uv"); !error.empty()) return error;
  }
  return ValidateSampleRandom(request.random(), n);
}

grpc::ServerUnaryReactor* HandleSample(const ServiceDeps& deps, grpc::CallbackServerContext* context,
                                       const v1::SampleRequest* request, v1::SampleResponse* response) {
  const auto received = batching::Clock::now();
  const auto reject = [&](const grpc::Status& status) { return AnswerNow(deps.metrics, context, "Sample", received, status); };
  if (grpc::Status s = CheckSampleRequest(*request, deps.has_fp64); !s.ok()) return reject(s);
  const size_t n = request->wo_size() / 3;
  auto call = std::make_shared<SampleCall>(deps, "Sample", context, request, response, received,
                                           request->precision() == v1::PRECISION_FP64);
  if (grpc::Status s = Admit(deps.memory, nullptr, n * kSampleBytesPerQuery, &call->admission, call->client); !s.ok())
    return reject(s);
  call->n = n;
  // Resolving or packing the material, building its sampling table and drawing all go to the preparer.
  deps.preparer->Post([call] { SampleCall::Start(call); }, call->client);
  return call->reactor;
}

}  // namespace loomlight::api
