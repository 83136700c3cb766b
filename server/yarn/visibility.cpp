#include "server/yarn/visibility.h"

#include <cmath>
#include <deque>
#include <mutex>
#include <numbers>
#include <utility>

namespace loomlight::yarn {
namespace {

constexpr double kTwoPi = 2 * std::numbers::pi;
constexpr size_t kSharedCrossSections = 4;  // ~4.7 MB each at the default 192 x 192 x 32

// The parameters a cross-section depends on; the others set to cotton1's so equal densities share one.
YarnParams DensityParams(const YarnParams& p) {
  YarnParams key;
  key.plies = p.plies;
  key.fibers_per_ply = p.fibers_per_ply;
  key.yarn_radius = p.yarn_radius;
  key.ellipse_n = p.ellipse_n;
  key.ellipse_b = p.ellipse_b;
  key.eps = p.eps;
  key.beta = p.beta;
  key.fiber_width = p.fiber_width;
  return key;
}

FiberRay RayOf(Vec3 p, Vec3 w, double max_distance) {
  return {{float(p.x), float(p.y), float(p.z)}, {float(w.x), float(w.y), float(w.z)}, 0.0f,
          std::isfinite(max_distance) ? float(max_distance) : std::numeric_limits<float>::infinity()};
}

}  // namespace

const char* ToString(ShadowMethod m) { return m == ShadowMethod::kTraced ? "traced" : "slices"; }
const char* ToString(OcclusionMethod m) {
  switch (m) {
    case OcclusionMethod::kTraced:
      return "traced";
    case OcclusionMethod::kTexture:
      return "texture";
    case OcclusionMethod::kDistance:
      return "distance";
  }
  return "traced";
}

std::string SharedCrossSection(const YarnParams& params, const CrossSectionOptions& options,
                               std::shared_ptr<const YarnCrossSection>* out) {
  struct Entry {
    YarnParams key;
    CrossSectionOptions options;
    std::shared_ptr<const YarnCrossSection> value;
  };
  static std::mutex mutex;
  static std::deque<Entry> entries;  // most recent first
  const YarnParams key = DensityParams(params);
  {
    std::lock_guard lock(mutex);
    for (auto it = entries.begin(); it != entries.end(); ++it) {
      if (it->key == key && it->options == options) {
        Entry hit = *it;
        entries.erase(it);
        entries.push_front(hit);
        *out = hit.value;
        return "";
      }
    }
  }
  // Built outside the lock (a quarter second): two calls may build the same one; both results are equal.
  auto built = std::make_shared<YarnCrossSection>();
  if (std::string e = YarnCrossSection::Make(params, options, built.get()); !e.empty()) return e;
  std::lock_guard lock(mutex);
  entries.push_front({key, options, built});
  if (entries.size() > kSharedCrossSections) entries.pop_back();
  *out = std::move(built);
  return "";
}

std::string YarnVisibility::Make(const YarnParams& params, std::vector<std::shared_ptr<const YarnCurve>> centres,
                                 double tube_radius, const CrossSectionOptions& options, std::function<bool()> stop,
                                 YarnVisibility* out) {
  if (centres.empty()) return "centres: no yarn";
  for (const auto& c : centres)
    if (!c) return "centres: a null curve";
  if (!std::isfinite(tube_radius) || tube_radius < kMinLength || tube_radius > kMaxLength)
    return "tube_radius: must be finite in the yarn lengths' range";
  YarnVisibility v;
  if (std::string e = SharedCrossSection(params, options, &v.cross_section_); !e.empty()) return e;
  v.alpha_yarn_ = params.alpha_yarn;
  if (centres.size() > 1) {
    // Each yarn a tube through its centre polyline (hit yarn index = its own index, so Occluded can skip it).
    std::vector<YarnGeometry> tubes(centres.size());
    std::vector<const YarnGeometry*> pointers;
    for (size_t i = 0; i < centres.size(); ++i) {
      FiberCurve tube;
      tube.type = FiberType::kCore;
      tube.width = 2 * tube_radius;
      // Vertices at least a tube radius apart: a tube overlaps itself less and a ray tests fewer segments
      // (measured on a cotton1 plain weave: 236 ns a ray instead of 300 at the layout's 16 points per
      // crossing); the chords cut into a crimped yarn's crest by under a tenth of its radius there.
      const std::vector<Vec3> polyline = centres[i]->CentrePolyline();
      for (size_t k = 0; k < polyline.size(); ++k)
        if (k == 0 || k + 1 == polyline.size() || Norm(polyline[k] - tube.points.back()) >= tube_radius)
          tube.points.push_back(polyline[k]);
      tubes[i].control_points = static_cast<int64_t>(tube.points.size());
      tubes[i].fibers.push_back(std::move(tube));
      pointers.push_back(&tubes[i]);
    }
    FiberSceneOptions scene_options;
    scene_options.cancel = std::move(stop);
    auto scene = std::make_shared<FiberScene>();
    if (std::string e = FiberScene::Build(pointers, scene_options, scene.get()); !e.empty()) return "tubes: " + e;
    v.tubes_ = std::move(scene);
  }
  v.centres_ = std::move(centres);
  *out = std::move(v);
  return "";
}

CrossSectionPoint YarnVisibility::Locate(int yarn, Vec3 p) const {
  CrossSectionPoint out;
  if (yarn < 0 || yarn >= yarns()) return out;
  const YarnCurve& curve = *centres_[size_t(yarn)];
  const double arc = curve.ClosestArc(p);
  const CurveFrame f = curve.At(arc);
  out.yarn = yarn;
  out.normal = f.normal;
  out.binormal = Cross(f.tangent, f.normal);
  const double phase = kTwoPi * arc / alpha_yarn_;
  out.cos_phase = std::cos(phase);
  out.sin_phase = std::sin(phase);
  const Vec3 d = p - f.position;
  const double n = Dot(d, out.normal), b = Dot(d, out.binormal);
  // Turned back by the phase: ply j's centre is then at angle 2 pi j / K, as in the cross-section.
  out.x = out.cos_phase * n + out.sin_phase * b;
  out.y = -out.sin_phase * n + out.cos_phase * b;
  return out;
}

double YarnVisibility::SelfShadow(const CrossSectionPoint& x, Vec3 w, double own_radius) const {
  if (x.yarn < 0) return 1;
  // The light's direction in the cross-section, turned back likewise (its component along the yarn does not
  // change the depth).
  const double n = Dot(w, x.normal), b = Dot(w, x.binormal);
  return cross_section_->ShadowToward(x.x, x.y, x.cos_phase * n + x.sin_phase * b, -x.sin_phase * n + x.cos_phase * b,
                                      own_radius);
}

bool YarnVisibility::OtherYarnsBlock(int yarn, Vec3 p, Vec3 w, double max_distance) const {
  if (!tubes_) return false;
  const FiberRay ray = RayOf(p, w, max_distance);
  uint8_t blocked = 0;
  return tubes_->Occluded({&ray, 1}, {&blocked, 1}, yarn).empty() && blocked;
}

double YarnVisibility::Occlusion(const CrossSectionPoint& x, OcclusionMethod method) const {
  if (method == OcclusionMethod::kTraced || x.yarn < 0) return 1;
  return method == OcclusionMethod::kTexture ? cross_section_->Occlusion(x.x, x.y)
                                             : cross_section_->DistanceOcclusion(std::hypot(x.x, x.y));
}

}  // namespace loomlight::yarn
