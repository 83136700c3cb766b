// A generated yarn geometry as YarnGeometry streams it (server/api/yarn_rpc.h): its summary (counts and bounds)
// and its curves in batches of whole curves, bounded in bytes, as the float arrays the messages carry.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "server/yarn/yarn.h"

namespace loomlight::yarn {

struct GeometrySummary {
  uint64_t fibers = 0, control_points = 0;
  // The control points' box widened by half of each curve's width; all zero without fibers.
  std::array<double, 3> bounds_min{0, 0, 0}, bounds_max{0, 0, 0};
};
GeometrySummary Summarise(const std::vector<YarnGeometry>& yarns);

// Whole curves, in order, as float arrays: curve k has point_counts[k] points (xyz each in `points`) and
// widths[k], types[k], yarns[k] (its yarn's index), plies[k] and fibers[k] (FiberCurve's ply and fiber).
struct CurveBatch {
  std::vector<uint32_t> point_counts;
  std::vector<float> points;
  std::vector<float> widths;
  std::vector<FiberType> types;
  std::vector<uint32_t> yarns, plies;
  std::vector<int32_t> fibers;
};

// Bytes a curve takes in a batch as sent: 12 per control point (float xyz) and 24 of attributes.
size_t CurveBatchBytes(const FiberCurve& curve);

// Walks the curves of `yarns` (which outlive it) in order, a batch at a time.
class CurveBatcher {
 public:
  explicit CurveBatcher(const std::vector<YarnGeometry>& yarns) : yarns_(yarns) {}
  // The next curves up to max_bytes (CurveBatchBytes), at least one while any are left (a long fiber still goes
  // out), into *batch (cleared first).
  void Next(size_t max_bytes, CurveBatch* batch);
  bool done() const { return next_yarn_ == yarns_.size(); }
  uint64_t curves_done() const { return curves_done_; }

 private:
  const std::vector<YarnGeometry>& yarns_;
  size_t next_yarn_ = 0, next_fiber_ = 0;  // the next curve
  uint64_t curves_done_ = 0;
};

}  // namespace loomlight::yarn
