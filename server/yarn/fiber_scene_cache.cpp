#include "server/yarn/fiber_scene_cache.h"

#include <algorithm>
#include <utility>
#include <vector>

namespace loomlight::yarn {

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

FiberSceneOutcome BuildFiberScene(YarnJob* job, const std::function<bool()>& stopped,
                                  const std::function<bool(size_t)>& grow, std::shared_ptr<const FiberScene>* scene,
                                  std::shared_ptr<const YarnVisibility>* visibility, FiberSceneCache* cache) {
  using Kind = FiberSceneOutcome::Kind;
  if (FiberSceneCache::Scene found; cache && cache->Find(*job, visibility != nullptr, &found)) {
    *scene = std::move(found.fibers);
    if (visibility) *visibility = std::move(found.visibility);
    return {};
  }
  job->detail.stop = stopped;
  std::vector<YarnGeometry> yarns;
  std::vector<LaidYarn> laid;
  if (std::string e = GenerateYarnJob(job, &yarns, &laid); !e.empty())
    return {stopped() ? Kind::kStopped : Kind::kLimits, e};
  std::vector<const YarnGeometry*> pointers;
  for (const YarnGeometry& y : yarns) pointers.push_back(&y);
  const FiberSceneEstimate estimate = EstimateFiberScene(pointers);
  if (!grow(static_cast<size_t>(estimate.total_bytes)))
    return {Kind::kNoMemory, "bvh_memory: the fibers' BVH needs up to " + std::to_string(estimate.total_bytes) +
                                 " bytes, more than the server has free now"};
  FiberSceneOptions options;
  options.max_bytes = std::max<int64_t>(estimate.total_bytes, 1);
  options.threads = 2;
  options.cancel = stopped;
  auto built = std::make_shared<FiberScene>();
  if (std::string e = FiberScene::Build(pointers, options, built.get()); !e.empty()) {
    if (stopped()) return {Kind::kStopped, e};
    if (e.rfind("bvh_memory", 0) == 0) return {Kind::kNoMemory, e};
    return {Kind::kInternal, "building the fibers' BVH: " + e};
  }
  *scene = std::move(built);
  if (!visibility) {
    if (cache) cache->Keep(*job, {*scene, nullptr}, static_cast<size_t>(estimate.total_bytes));
    return {};
  }
  // A few tubes and a shared cross-section (the other yarns as tubes of the layout's radius).
  std::vector<std::shared_ptr<const YarnCurve>> centres;
  for (const LaidYarn& l : laid) centres.push_back(l.centre);
  const double tube_radius = job->kind == YarnLayoutKind::kWoven ? job->layout.yarn_radius : job->params.yarn_radius;
  auto made = std::make_shared<YarnVisibility>();
  if (std::string v = YarnVisibility::Make(job->params, std::move(centres), tube_radius, {}, stopped, made.get());
      !v.empty())
    return {stopped() ? Kind::kStopped : Kind::kInternal, "the yarn's cross-section: " + v};
  // The other yarns' openness table (at most YarnVisibility::kMaxOpennessBytes), filled while rendering.
  if (!grow(made->openness_bytes()))
    return {Kind::kNoMemory, "bvh_memory: the other yarns' openness table needs " +
                                 std::to_string(made->openness_bytes()) + " bytes, more than the server has free now"};
  if (cache)
    cache->Keep(*job, {*scene, made},
                static_cast<size_t>(estimate.total_bytes) + made->openness_bytes() + job->layout_bytes);
  *visibility = std::move(made);
  return {};
}

}  // namespace loomlight::yarn
