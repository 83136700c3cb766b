#include "server/api/yarn_rpc.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <thread>
#include <utility>
#include <vector>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/stream_call.h"
#include "server/models/material.h"
#include "server/models/quote.h"
#include "server/yarn/geometry_stream.h"
#include "server/yarn/layout.h"
#include "server/yarn/yarn_schema.h"

namespace loomlight::api {
namespace {

using batching::Clock;
constexpr const char* kRpc = "YarnGeometry";
constexpr const char* kDefaultPreset = "cotton1";

v1::FiberType ToProto(yarn::FiberType type) {
  switch (type) {
    case yarn::FiberType::kCore: return v1::FIBER_CORE;
    case yarn::FiberType::kMigration: return v1::FIBER_MIGRATION;
    case yarn::FiberType::kLoop: return v1::FIBER_LOOP;
    case yarn::FiberType::kHair: return v1::FIBER_HAIR;
  }
  return v1::FIBER_MIGRATION;
}

std::string DetailOf(const v1::YarnDetail& d, yarn::DetailOptions* out) {
  if (d.has_core()) out->core = d.core();
  if (d.has_core_radius()) out->core_radius = d.core_radius();
  out->footprint = d.footprint();
  if (d.points_per_twist() != 0) out->points_per_twist = static_cast<int>(std::min<uint32_t>(d.points_per_twist(), 1u << 30));
  // Both cores, whatever the host has: generation is a one-off per call and the output does not depend on it.
  out->threads = static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 4u));
  if (std::string e = yarn::ValidateDetailOptions(*out); !e.empty()) return "detail." + e;
  return "";
}

std::string LimitsOf(const v1::YarnGeometryRequest& r, yarn::YarnLimits* out) {
  if (r.max_fibers() > kMaxYarnFibers)
    return "max_fibers: " + std::to_string(r.max_fibers()) + " is over the server's limit of " +
           std::to_string(kMaxYarnFibers);
  if (r.max_control_points() > kMaxYarnControlPoints)
    return "max_control_points: " + std::to_string(r.max_control_points()) + " is over the server's limit of " +
           std::to_string(kMaxYarnControlPoints);
  out->max_fibers = static_cast<int64_t>(r.max_fibers() ? r.max_fibers() : kMaxYarnFibers);
  out->max_control_points = static_cast<int64_t>(r.max_control_points() ? r.max_control_points() : kMaxYarnControlPoints);
  return "";
}

// The woven layout's pattern (from a material whose model has one) and parameters; the yarn's radius sets the
// crimp heights and, by default, the spacing (the tightest spacing free of contact: server/yarn/layout.h).
std::string WovenOf(const models::Registry& registry, const v1::WovenYarnLayout& w, YarnJob* job) {
  models::ResolvedMaterial weave;
  if (std::string e = models::ResolveMaterial(w.weave(), registry, &weave, "woven.weave"); !e.empty()) return e;
  if (std::string e = weave.model->WeavePatternOf(weave.values, &job->pattern); !e.empty()) return "woven.weave: " + e;
  yarn::LayoutParams& p = job->layout;
  const double scale = job->params.yarn_radius / p.yarn_radius;
  p.yarn_radius = job->params.yarn_radius;
  p.spacing = w.yarn_spacing() > 0 ? w.yarn_spacing() : p.spacing * scale;
  if (w.has_crimp()) p.crimp = w.crimp();
  p.repeats_u = static_cast<int>(std::min<uint32_t>(std::max(w.repeats_u(), 1u), 1u << 20));
  p.repeats_v = static_cast<int>(std::min<uint32_t>(std::max(w.repeats_v(), 1u), 1u << 20));
  if (!std::isfinite(w.yarn_spacing()) || w.yarn_spacing() < 0) return "woven.yarn_spacing: must be finite and >= 0";
  if (std::string e = yarn::ValidateLayoutParams(p); !e.empty()) {
    if (e.rfind("spacing", 0) == 0) return "woven.yarn_" + e;
    return "woven." + e;
  }
  // Centre polyline vertices: each warp yarn crosses every weft yarn, points_per_crossing segments apiece.
  const double warps = double(p.repeats_u) * job->pattern.warps, picks = double(p.repeats_v) * job->pattern.picks;
  const double vertices = warps * (picks * p.points_per_crossing + 1) + picks * (warps * p.points_per_crossing + 1);
  job->layout_bytes = static_cast<size_t>(std::min(vertices, 1e7) * kLayoutBytesPerVertex);
  job->kind = yarn::YarnLayoutKind::kWoven;
  return "";
}

// The client's centre curves, each with its yarn (the request's, seeded per curve, unless it names its own) at
// its radius. The counts are bounded before anything is allocated; the points themselves are checked when the
// centres are built (MakeCentreCurve), where the turn at a vertex is known.
std::string CurvesOf(const v1::CurveYarnLayout& c, YarnJob* job) {
  if (c.yarns().empty()) return "curves.yarns: no yarn given";
  if (c.yarns_size() > yarn::kMaxCurveYarns)
    return "curves.yarns: " + std::to_string(c.yarns_size()) + " yarns exceed the limit of " +
           std::to_string(yarn::kMaxCurveYarns);
  int64_t values = 0;
  for (const v1::YarnCentreCurve& y : c.yarns()) values += y.points_size();
  if (values > 3 * yarn::kMaxCurveLayoutPoints)
    return "curves.yarns: " + std::to_string(values / 3) + " points in all exceed the limit of " +
           std::to_string(yarn::kMaxCurveLayoutPoints);
  job->curves.reserve(size_t(c.yarns_size()));
  for (int k = 0; k < c.yarns_size(); ++k) {
    const v1::YarnCentreCurve& y = c.yarns(k);
    const std::string field = "curves.yarns[" + std::to_string(k) + "]";
    if (y.points_size() % 3 != 0)
      return field + ".points: " + std::to_string(y.points_size()) + " values are not whole xyz points";
    yarn::CurveYarn& out = job->curves.emplace_back();
    if (y.has_yarn()) {
      if (std::string e = YarnParamsOf(y.yarn(), &out.params); !e.empty()) return field + "." + e;
    } else {
      out.params = job->params;
    }
    // Neighbouring curves of one yarn get distinct fibers, each the same at every call.
    if (!y.has_yarn() || !y.yarn().has_seed()) out.params.seed = yarn::LayoutYarnSeed(job->params.seed, uint64_t(k));
    if (!std::isfinite(y.radius()) || y.radius() < 0)
      return field + ".radius: must be finite and >= 0 (0 = the yarn's own)";
    if (y.radius() > 0) {
      ScaleYarn(y.radius(), &out.params);
      if (std::string e = yarn::ValidateYarnParams(out.params); !e.empty())
        return field + ".radius: the yarn scaled to " + std::to_string(y.radius()) + " has " + e;
    }
    out.kind = y.bspline() ? yarn::CurveKind::kBSpline : yarn::CurveKind::kPolyline;
    out.points.reserve(size_t(y.points_size() / 3));
    for (int i = 0; i + 2 < y.points_size(); i += 3) out.points.push_back({y.points(i), y.points(i + 1), y.points(i + 2)});
  }
  // A B-spline's centre is sampled more finely than its control polygon: charged at its finest sampling.
  job->layout_bytes =
      size_t(std::min(yarn::CurveLayoutVerticesAtMost(job->curves), yarn::kMaxCurveLayoutVertices)) * kLayoutBytesPerVertex;
  job->kind = yarn::YarnLayoutKind::kCurves;
  return "";
}

// A knit's stitch, size and spacings; its yarn radius is the yarn's (the loops are shaped for it).
std::string KnitOf(const v1::KnitYarnLayout& k, YarnJob* job) {
  if (!v1::KnitStitch_IsValid(k.stitch())) return "knit.stitch: unknown value " + std::to_string(k.stitch());
  yarn::KnitParams& p = job->knit;
  p.stitch = k.stitch() == v1::KNIT_RIB_1X1 ? yarn::KnitStitch::kRib1x1 : yarn::KnitStitch::kJersey;
  // Past the limit stays past it (ValidateKnitParams names it) without overflowing int.
  p.wales = int(std::min<uint32_t>(k.wales() == 0 ? 8 : k.wales(), 1u << 20));
  p.courses = int(std::min<uint32_t>(k.courses() == 0 ? 8 : k.courses(), 1u << 20));
  p.yarn_radius = job->params.yarn_radius;
  for (const auto& [field, value] : {std::pair{"wale_spacing", k.wale_spacing()}, {"course_spacing", k.course_spacing()}})
    if (!std::isfinite(value) || value < 0) return std::string("knit.") + field + ": must be finite and >= 0 (0 = the default)";
  p.wale_spacing = k.wale_spacing();
  p.course_spacing = k.course_spacing();
  if (std::string e = yarn::ValidateKnitParams(p); !e.empty()) return "knit." + e;
  const int64_t vertices = int64_t(p.wales) * p.courses * p.points_per_loop + p.courses;
  job->layout_bytes = size_t(vertices) * kLayoutBytesPerVertex;
  job->kind = yarn::YarnLayoutKind::kKnit;
  return "";
}

std::string Validate(const models::Registry& registry, const v1::YarnGeometryRequest& r, YarnJob* job) {
  if (std::string e = DetailOf(r.detail(), &job->detail); !e.empty()) return e;
  if (std::string e = LimitsOf(r, &job->limits); !e.empty()) return e;
  YarnLayoutRequest layout;
  if (r.has_woven()) layout.woven = &r.woven();
  if (r.has_curves()) layout.curves = &r.curves();
  if (r.has_knit()) layout.knit = &r.knit();
  layout.straight_length = r.straight().length();
  return YarnJobOf(registry, r.yarn(), layout, job);
}

// One YarnGeometry call in flight: generation on the geometry worker, then chunks written from the host worker.
class YarnGeometryCall final : public WorkerStreamCall<v1::YarnGeometryChunk> {
 public:
  YarnGeometryCall(const ServiceDeps& deps, grpc::CallbackServerContext* context, YarnJob job, Admission admission,
                   Clock::time_point received)
      : WorkerStreamCall(deps, context, kRpc, received, std::move(admission)), job_(std::move(job)) {
    deps_.geometry->Post([this] { Generate(); }, client_);
  }

 private:
  // On the geometry worker: the whole geometry, or why not; then the host worker takes over.
  void Generate() {
    const auto started = Clock::now();
    // Polled between fibers: each poll is progress, so a long generation is not a stuck one.
    job_.detail.stop = ReportingProgress([this] { return !StopStatus(context_, deadline_).ok(); });
    auto geometry = std::make_shared<Geometry>();
    std::vector<LaidYarn> laid;
    std::string error = GenerateYarnJob(&job_, &geometry->yarns, &laid);
    for (const LaidYarn& y : laid) {
      v1::LaidYarn& out = geometry->laid.emplace_back();
      out.set_warp(y.warp);
      out.set_thread(static_cast<uint32_t>(y.thread));
      out.set_length(y.length);
    }
    const double seconds = SecondsSince(started);
    Post([this, geometry = std::move(geometry), error = std::move(error), seconds] {
      generated_ = true;
      if (error == "cancelled") {
        NoticeStop();
      } else if (!error.empty()) {
        // Only the limits and a curve's points can stop a validated request here (they need the geometry's size
        // or the curve's centre built to check).
        const bool limit = error.rfind("max_", 0) == 0;
        const std::string curve = CurveError(error);  // a bad curve is found as its centre is built
        if (status_.ok())
          status_ = limit             ? Invalid(error)
                    : !curve.empty()  ? Invalid(curve)
                                      : grpc::Status(grpc::StatusCode::INTERNAL, error);
      } else {
        geometry_ = geometry;
        curves_.emplace(geometry_->yarns);
        generate_seconds_ = seconds;
      }
      Pump();
    });
  }

  void Pump() override {
    if (finished_ || !generated_) return;  // before generation ends, OnCancel's pump waits for it
    NoticeStop();
    if (!status_.ok()) {
      if (!write_in_flight_) FinishCall(status_);
      return;
    }
    if (write_in_flight_) return;
    if (!done_sending_)
      WriteChunk();
    else
      FinishCall(grpc::Status::OK);
  }

  void Summarise(v1::YarnGeometrySummary* s) const {
    const yarn::GeometrySummary summary = yarn::Summarise(geometry_->yarns);
    s->set_fibers(summary.fibers);
    s->set_control_points(summary.control_points);
    // Every yarn of one call has the same level of detail (one footprint, one yarn model).
    s->set_lambda(geometry_->yarns.front().lambda);
    s->set_points_per_twist(static_cast<uint32_t>(geometry_->yarns.front().points_per_twist));
    s->mutable_yarns()->Add(geometry_->laid.begin(), geometry_->laid.end());
    s->mutable_bounds_min()->Add(summary.bounds_min.begin(), summary.bounds_min.end());
    s->mutable_bounds_max()->Add(summary.bounds_max.begin(), summary.bounds_max.end());
    s->set_generate_seconds(generate_seconds_);
  }

  // One write in flight at a time: the first chunk has the summary; each holds whole curves up to about
  // kYarnChunkBytes (at least one curve, so a long fiber still goes out).
  void WriteChunk() {
    chunk_.Clear();
    if (!sent_summary_) {
      sent_summary_ = true;
      Summarise(chunk_.mutable_summary());
    }
    yarn::CurveBatch batch;
    curves_->Next(kYarnChunkBytes, &batch);
    v1::FiberCurves* out = chunk_.mutable_curves();
    out->mutable_point_counts()->Add(batch.point_counts.begin(), batch.point_counts.end());
    out->mutable_points()->Add(batch.points.begin(), batch.points.end());
    out->mutable_widths()->Add(batch.widths.begin(), batch.widths.end());
    std::transform(batch.types.begin(), batch.types.end(),
                   google::protobuf::RepeatedFieldBackInserter(out->mutable_types()),
                   [](yarn::FiberType type) { return ToProto(type); });
    out->mutable_yarns()->Add(batch.yarns.begin(), batch.yarns.end());
    out->mutable_plies()->Add(batch.plies.begin(), batch.plies.end());
    out->mutable_fibers()->Add(batch.fibers.begin(), batch.fibers.end());
    chunk_.set_fibers_sent(curves_->curves_done());
    if (curves_->done()) {
      chunk_.set_total_seconds(SecondsSince(received_));
      curves_.reset();  // all sent: free the geometry while the last write is in flight
      geometry_.reset();
      done_sending_ = true;
    }
    write_in_flight_ = true;
    StartWrite(&chunk_);
  }

  // The generated curves, per yarn, and each yarn's place in the layout.
  struct Geometry {
    std::vector<yarn::YarnGeometry> yarns;
    std::vector<v1::LaidYarn> laid;
  };

  YarnJob job_;
  bool generated_ = false;
  std::shared_ptr<const Geometry> geometry_;
  double generate_seconds_ = 0;
  bool sent_summary_ = false;
  bool done_sending_ = false;
  std::optional<yarn::CurveBatcher> curves_;  // over geometry_'s curves, the next to send
  v1::YarnGeometryChunk chunk_;
};

}  // namespace

std::string YarnParamsOf(const v1::Yarn& y, yarn::YarnParams* out) {
  const std::string preset = y.preset().empty() ? kDefaultPreset : y.preset();
  if (std::string e = yarn::YarnPreset(preset, out); !e.empty()) return "yarn." + e;
  for (int i = 0; i < y.params_size(); ++i) {
    const v1::Param& p = y.params(i);
    const std::string field = "yarn.params[" + std::to_string(i) + "]";
    for (int j = 0; j < i; ++j)
      if (y.params(j).name() == p.name()) return field + ": " + models::Quote(p.name()) + " is given twice";
    if (p.values_size() != 1 || !p.text().empty())
      return field + ": " + models::Quote(p.name()) + " takes one value, got " + std::to_string(p.values_size());
    if (std::string e = yarn::SetYarnParam(p.name(), p.values(0), out); !e.empty()) return "yarn." + e;
  }
  if (y.has_seed()) out->seed = y.seed();
  if (std::string e = yarn::ValidateYarnParams(*out); !e.empty()) return "yarn." + e;
  return "";
}

void DescribeYarnModel(v1::YarnModelInfo* out) {
  out->set_description(
      "procedural yarn (Wu and Yuksel 2017 after Zhao et al. 2016; SPEC.md section 6): plies twisting around the "
      "yarn centre, fibers placed by D(R) and migrating (Eq. 2), loop and hair flyaways, core fibers and Eq. 4's "
      "level of detail");
  const yarn::YarnParams defaults;
  for (const yarn::YarnParamSpec& spec : yarn::YarnParamSpecs()) {
    v1::ParamSchema* s = out->add_params();
    s->set_name(spec.name);
    s->set_type(spec.integer ? v1::ParamSchema::TYPE_INT : v1::ParamSchema::TYPE_REAL);
    s->set_unit(spec.unit);
    s->set_min(spec.min);
    s->set_max(spec.max);
    s->add_default_values(yarn::GetYarnParam(defaults, spec.name));
    s->set_description(spec.description);
    s->set_min_count(1);
    s->set_max_count(1);
  }
  for (const std::string& name : yarn::YarnPresetNames()) {
    yarn::YarnParams p;
    yarn::YarnPreset(name, &p);
    v1::Preset* preset = out->add_presets();
    preset->set_name(name);
    preset->set_description("Zhao et al.'s fit " + name + " (SPEC.md section 6)");
    for (const yarn::YarnParamSpec& spec : yarn::YarnParamSpecs()) {
      v1::Param* param = preset->add_params();
      param->set_name(spec.name);
      param->add_values(yarn::GetYarnParam(p, spec.name));
    }
  }
  out->set_max_fibers(kMaxYarnFibers);
  out->set_max_control_points(kMaxYarnControlPoints);
}

std::string YarnJobOf(const models::Registry& registry, const v1::Yarn& yarn, const YarnLayoutRequest& layout,
                      YarnJob* job) {
  if (std::string e = YarnParamsOf(yarn, &job->params); !e.empty()) return e;
  if (layout.woven) return WovenOf(registry, *layout.woven, job);
  if (layout.curves) return CurvesOf(*layout.curves, job);
  if (layout.knit) return KnitOf(*layout.knit, job);
  const double length = layout.straight_length == 0 ? 1.0 : layout.straight_length;
  if (!(length >= yarn::kMinLength && length <= yarn::kMaxLength))
    return "straight.length: must be a finite number in [" + std::to_string(yarn::kMinLength) + ", " +
           std::to_string(yarn::kMaxLength) + "]";
  job->straight_length = length;
  job->params.length = length;  // set here, not only when generating, so SameFibers compares like with like
  return "";
}

std::string YarnJobOf(const models::Registry& registry, const v1::Yarn& yarn, const v1::WovenYarnLayout* woven,
                      double straight_length, YarnJob* job) {
  return YarnJobOf(registry, yarn, {.woven = woven, .straight_length = straight_length}, job);
}

void ScaleYarn(double radius, yarn::YarnParams* p) {
  const double k = radius / p->yarn_radius;
  for (double* length : {&p->yarn_radius, &p->ellipse_n, &p->ellipse_b, &p->fiber_width, &p->alpha, &p->alpha_yarn})
    *length *= k;
  p->yarn_radius = radius;  // exactly as asked
  p->hair_density /= k;
  p->loop_density /= k;
}

std::string CurveError(const std::string& error) {
  return error.rfind("yarns[", 0) == 0 ? "curves." + error : "";
}

grpc::Status BuildFiberScene(YarnJob* job, const std::function<grpc::Status()>& stop,
                             const std::function<bool(size_t)>& grow, std::shared_ptr<const yarn::FiberScene>* scene,
                             std::shared_ptr<const yarn::YarnVisibility>* visibility, yarn::FiberSceneCache* cache,
                             const std::string& yarn_field) {
  const yarn::FiberSceneOutcome outcome =
      yarn::BuildFiberScene(job, [stop] { return !stop().ok(); }, grow, scene, visibility, cache);
  using Kind = yarn::FiberSceneOutcome::Kind;
  switch (outcome.kind) {
    case Kind::kOk: return grpc::Status::OK;
    case Kind::kStopped: return stop();
    case Kind::kLimits:
      if (std::string curve = CurveError(outcome.message); !curve.empty()) return Invalid(curve);
      return Invalid(yarn_field + ": " + outcome.message +
                     " (the fiber limits; docs/fibers.md#shadows-ambient-occlusion-and-level-of-detail)");
    case Kind::kNoMemory: return {grpc::StatusCode::RESOURCE_EXHAUSTED, outcome.message};
    case Kind::kInternal: break;
  }
  return {grpc::StatusCode::INTERNAL, outcome.message};
}

grpc::ServerWriteReactor<v1::YarnGeometryChunk>* HandleYarnGeometry(const ServiceDeps& deps,
                                                                   grpc::CallbackServerContext* context,
                                                                   const v1::YarnGeometryRequest* request) {
  const auto received = Clock::now();
  const auto reject = [&](grpc::Status status) {
    return new RejectedStream<v1::YarnGeometryChunk>(deps.metrics, kRpc, received, std::move(status));
  };
  YarnJob job;
  if (std::string error = Validate(*deps.registry, *request, &job); !error.empty()) return reject(Invalid(error));
  const size_t bytes = static_cast<size_t>(job.limits.max_control_points) * kYarnBytesPerPoint +
                       static_cast<size_t>(job.limits.max_fibers) * kYarnBytesPerFiber + job.layout_bytes;
  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, bytes, &admission); !s.ok()) return reject(s);
  return new YarnGeometryCall(deps, context, std::move(job), std::move(admission), received);
}

}  // namespace loomlight::api
