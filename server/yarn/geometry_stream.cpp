#include "server/yarn/geometry_stream.h"

#include <algorithm>
#include <cmath>

namespace loomlight::yarn {

GeometrySummary Summarise(const std::vector<YarnGeometry>& yarns) {
  GeometrySummary s;
  std::array<double, 3> lo{HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (const YarnGeometry& g : yarns) {
    s.fibers += g.fibers.size();
    s.control_points += static_cast<uint64_t>(g.control_points);
    for (const FiberCurve& c : g.fibers)
      for (const Vec3& p : c.points) {
        const double v[3] = {p.x, p.y, p.z};
        for (int k = 0; k < 3; ++k) {
          lo[k] = std::min(lo[k], v[k] - 0.5 * c.width);
          hi[k] = std::max(hi[k], v[k] + 0.5 * c.width);
        }
      }
  }
  if (s.fibers > 0) s.bounds_min = lo, s.bounds_max = hi;
  return s;
}

size_t CurveBatchBytes(const FiberCurve& curve) { return 12 * curve.points.size() + 24; }

void CurveBatcher::Next(size_t max_bytes, CurveBatch* batch) {
  *batch = CurveBatch();
  size_t bytes = 0;
  while (next_yarn_ < yarns_.size()) {
    if (next_fiber_ == yarns_[next_yarn_].fibers.size()) {
      ++next_yarn_, next_fiber_ = 0;
      continue;
    }
    const FiberCurve& c = yarns_[next_yarn_].fibers[next_fiber_];
    const size_t need = CurveBatchBytes(c);
    if (bytes > 0 && bytes + need > max_bytes) break;
    bytes += need;
    batch->point_counts.push_back(static_cast<uint32_t>(c.points.size()));
    for (const Vec3& p : c.points) {
      batch->points.push_back(static_cast<float>(p.x));
      batch->points.push_back(static_cast<float>(p.y));
      batch->points.push_back(static_cast<float>(p.z));
    }
    batch->widths.push_back(static_cast<float>(c.width));
    batch->types.push_back(c.type);
    batch->yarns.push_back(static_cast<uint32_t>(next_yarn_));
    batch->plies.push_back(static_cast<uint32_t>(c.ply));
    batch->fibers.push_back(c.fiber);
    ++next_fiber_;
    ++curves_done_;
  }
}

}  // namespace loomlight::yarn
