#include "server/api/yarn_rpc.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <thread>
#include <utility>
#include <vector>

#include "server/api/admission.h"
#include "server/api/job_status.h"
#include "server/api/stream_call.h"
#include "server/models/material.h"
#include "server/models/quote.h"
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
  job->woven = true;
  return "";
}

std::string Validate(const models::Registry& registry, const v1::YarnGeometryRequest& r, YarnJob* job) {
  if (std::string e = DetailOf(r.detail(), &job->detail); !e.empty()) return e;
  if (std::string e = LimitsOf(r, &job->limits); !e.empty()) return e;
  return YarnJobOf(registry, r.yarn(), r.has_woven() ? &r.woven() : nullptr, r.straight().length(), job);
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
        // Only the limits can stop a validated request here (they need the geometry's size to check).
        const bool limit = error.rfind("max_", 0) == 0;
        if (status_.ok())
          status_ = limit ? Invalid(error) : grpc::Status(grpc::StatusCode::INTERNAL, error);
      } else {
        geometry_ = geometry;
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
    uint64_t fibers = 0, points = 0;
    double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (const yarn::YarnGeometry& g : geometry_->yarns) {
      fibers += g.fibers.size();
      points += static_cast<uint64_t>(g.control_points);
      for (const yarn::FiberCurve& c : g.fibers)
        for (const yarn::Vec3& p : c.points) {
          const double v[3] = {p.x, p.y, p.z};
          for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], v[k] - 0.5 * c.width);
            hi[k] = std::max(hi[k], v[k] + 0.5 * c.width);
          }
        }
    }
    if (fibers == 0) std::fill(lo, lo + 3, 0.0), std::fill(hi, hi + 3, 0.0);
    s->set_fibers(fibers);
    s->set_control_points(points);
    // Every yarn of one call has the same level of detail (one footprint, one yarn model).
    s->set_lambda(geometry_->yarns.front().lambda);
    s->set_points_per_twist(static_cast<uint32_t>(geometry_->yarns.front().points_per_twist));
    s->mutable_yarns()->Add(geometry_->laid.begin(), geometry_->laid.end());
    s->mutable_bounds_min()->Add(lo, lo + 3);
    s->mutable_bounds_max()->Add(hi, hi + 3);
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
    v1::FiberCurves* out = chunk_.mutable_curves();
    size_t bytes = 0;
    const auto& yarns = geometry_->yarns;
    while (next_yarn_ < yarns.size()) {
      if (next_fiber_ == yarns[next_yarn_].fibers.size()) {
        ++next_yarn_, next_fiber_ = 0;
        continue;
      }
      const yarn::FiberCurve& c = yarns[next_yarn_].fibers[next_fiber_];
      const size_t need = 12 * c.points.size() + 24;
      if (bytes > 0 && bytes + need > kYarnChunkBytes) break;
      bytes += need;
      out->add_point_counts(static_cast<uint32_t>(c.points.size()));
      for (const yarn::Vec3& p : c.points) {
        out->add_points(static_cast<float>(p.x));
        out->add_points(static_cast<float>(p.y));
        out->add_points(static_cast<float>(p.z));
      }
      out->add_widths(static_cast<float>(c.width));
      out->add_types(ToProto(c.type));
      out->add_yarns(static_cast<uint32_t>(next_yarn_));
      out->add_plies(static_cast<uint32_t>(c.ply));
      out->add_fibers(c.fiber);
      ++next_fiber_;
      ++fibers_sent_;
    }
    chunk_.set_fibers_sent(fibers_sent_);
    if (next_yarn_ == yarns.size()) {
      chunk_.set_total_seconds(SecondsSince(received_));
      geometry_.reset();  // all sent: free it while the last write is in flight
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
  size_t next_yarn_ = 0, next_fiber_ = 0;  // the next curve to send
  uint64_t fibers_sent_ = 0;
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

std::string YarnJobOf(const models::Registry& registry, const v1::Yarn& yarn, const v1::WovenYarnLayout* woven,
                      double straight_length, YarnJob* job) {
  if (std::string e = YarnParamsOf(yarn, &job->params); !e.empty()) return e;
  if (woven) return WovenOf(registry, *woven, job);
  const double length = straight_length == 0 ? 1.0 : straight_length;
  if (!(length >= yarn::kMinLength && length <= yarn::kMaxLength))
    return "straight.length: must be a finite number in [" + std::to_string(yarn::kMinLength) + ", " +
           std::to_string(yarn::kMaxLength) + "]";
  job->straight_length = length;
  job->params.length = length;  // set here, not only when generating, so SameFibers compares like with like
  return "";
}

std::string GenerateYarnJob(YarnJob* job, std::vector<yarn::YarnGeometry>* yarns, std::vector<LaidYarn>* laid) {
  yarns->clear();
  laid->clear();
  std::string error;
  if (job->woven) {
    yarn::WovenLayout layout;
    error = yarn::BuildLayout(job->pattern, job->layout, &layout);
    yarn::LayoutGeometry fibers;
    if (error.empty()) error = yarn::GenerateLayout(job->params, layout, job->detail, job->limits, &fibers);
    if (error.empty()) {
      *yarns = std::move(fibers.yarns);
      for (const yarn::LayoutYarn& y : layout.yarns)
        laid->push_back({y.warp, y.thread, y.curve.Length(), std::make_shared<yarn::PolylineYarnCurve>(y.curve)});
    }
  } else {
    job->params.length = job->straight_length;
    error = yarn::GenerateStraightYarn(job->params, job->detail, job->limits, &yarns->emplace_back());
    laid->push_back({false, 0, job->straight_length, std::make_shared<yarn::StraightYarnCurve>(job->straight_length)});
  }
  if (!error.empty()) {
    yarns->clear();
    laid->clear();
  }
  return error;
}

bool SameFibers(const YarnJob& a, const YarnJob& b) {
  return a.params == b.params && a.detail.SameOutput(b.detail) && a.limits == b.limits && a.woven == b.woven &&
         (a.woven ? a.pattern == b.pattern && a.layout == b.layout : a.straight_length == b.straight_length);
}

bool FiberSceneCache::Find(const YarnJob& job, bool need_visibility, Scene* out) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = entries_.begin(); it != entries_.end(); ++it) {
    if (!SameFibers(it->job, job) || (need_visibility && !it->scene.visibility)) continue;
    entries_.splice(entries_.begin(), entries_, it);
    *out = entries_.front().scene;
    return true;
  }
  return false;
}

void FiberSceneCache::Keep(const YarnJob& job, Scene scene, size_t bytes) {
  if (bytes > capacity_bytes_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  entries_.remove_if([&](const Entry& e) {
    const bool same = SameFibers(e.job, job);
    if (same) bytes_ -= e.bytes;
    return same;
  });
  while (!entries_.empty() && bytes_ + bytes > capacity_bytes_) {
    bytes_ -= entries_.back().bytes;
    entries_.pop_back();
  }
  Entry entry{job, std::move(scene), bytes};
  entry.job.detail.stop = nullptr;  // it may reach into the call that built the scene
  entries_.push_front(std::move(entry));
  bytes_ += bytes;
}

size_t FiberSceneCache::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bytes_;
}

size_t FiberSceneCache::entries() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return entries_.size();
}

grpc::Status BuildFiberScene(YarnJob* job, const std::function<grpc::Status()>& stop,
                             const std::function<bool(size_t)>& grow, std::shared_ptr<const yarn::FiberScene>* scene,
                             std::shared_ptr<const yarn::YarnVisibility>* visibility, FiberSceneCache* cache,
                             const std::string& yarn_field) {
  if (FiberSceneCache::Scene found; cache && cache->Find(*job, visibility != nullptr, &found)) {
    *scene = std::move(found.fibers);
    if (visibility) *visibility = std::move(found.visibility);
    return grpc::Status::OK;
  }
  const auto stopped = [stop] { return !stop().ok(); };  // a copy: job->detail keeps it
  job->detail.stop = stopped;
  std::vector<yarn::YarnGeometry> yarns;
  std::vector<LaidYarn> laid;
  if (std::string e = GenerateYarnJob(job, &yarns, &laid); !e.empty()) {
    if (grpc::Status s = stop(); !s.ok()) return s;
    return Invalid(yarn_field + ": " + e + " (the fiber limits; README \"Render: fibers\")");
  }
  std::vector<const yarn::YarnGeometry*> pointers;
  for (const yarn::YarnGeometry& y : yarns) pointers.push_back(&y);
  const yarn::FiberSceneEstimate estimate = yarn::EstimateFiberScene(pointers);
  if (!grow(static_cast<size_t>(estimate.total_bytes)))
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, "bvh_memory: the fibers' BVH needs up to " +
                                                      std::to_string(estimate.total_bytes) +
                                                      " bytes, more than the server has free now"};
  yarn::FiberSceneOptions options;
  options.max_bytes = std::max<int64_t>(estimate.total_bytes, 1);
  options.threads = 2;
  options.cancel = stopped;
  auto built = std::make_shared<yarn::FiberScene>();
  if (std::string e = yarn::FiberScene::Build(pointers, options, built.get()); !e.empty()) {
    if (grpc::Status s = stop(); !s.ok()) return s;
    if (e.rfind("bvh_memory", 0) == 0) return {grpc::StatusCode::RESOURCE_EXHAUSTED, e};
    return {grpc::StatusCode::INTERNAL, "building the fibers' BVH: " + e};
  }
  *scene = std::move(built);
  if (!visibility) {
    if (cache) cache->Keep(*job, {*scene, nullptr}, static_cast<size_t>(estimate.total_bytes));
    return grpc::Status::OK;
  }
  // A few tubes and a shared cross-section (the other yarns as tubes of the layout's radius).
  std::vector<std::shared_ptr<const yarn::YarnCurve>> centres;
  for (const LaidYarn& l : laid) centres.push_back(l.centre);
  const double tube_radius = job->woven ? job->layout.yarn_radius : job->params.yarn_radius;
  auto made = std::make_shared<yarn::YarnVisibility>();
  if (std::string v = yarn::YarnVisibility::Make(job->params, std::move(centres), tube_radius, {}, stopped, made.get());
      !v.empty()) {
    if (grpc::Status s = stop(); !s.ok()) return s;
    return {grpc::StatusCode::INTERNAL, "the yarn's cross-section: " + v};
  }
  // The other yarns' openness table (at most YarnVisibility::kMaxOpennessBytes), filled while rendering.
  if (!grow(made->openness_bytes()))
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, "bvh_memory: the other yarns' openness table needs " +
                                                      std::to_string(made->openness_bytes()) +
                                                      " bytes, more than the server has free now"};
  if (cache) cache->Keep(*job, {*scene, made}, static_cast<size_t>(estimate.total_bytes) + made->openness_bytes() + job->layout_bytes);
  *visibility = std::move(made);
  return grpc::Status::OK;
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
