// A yarn generation job: what a validated request asks for (YarnGeometry, Render's fiber scenes, CreateBtf's
// fiber source; server/api/yarn_rpc.h translates requests into it) and its generation into fibers.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"
#include "server/yarn/curve.h"
#include "server/yarn/curve_layout.h"
#include "server/yarn/knit.h"
#include "server/yarn/layout.h"
#include "server/yarn/yarn.h"

namespace loomlight::yarn {

// Where a job's yarns run.
enum class YarnLayoutKind { kStraight, kWoven, kCurves, kKnit };

// Everything GenerateYarnJob needs: one straight yarn, the warp and weft of a woven layout, the client's curves
// or the courses of a knit.
struct YarnJob {
  YarnParams params;  // the yarn (a curve's own `params` win for it; a knit's courses use these)
  DetailOptions detail;
  YarnLimits limits;
  YarnLayoutKind kind = YarnLayoutKind::kStraight;
  double straight_length = 1;
  models::weave::WeavePattern pattern;  // kWoven
  LayoutParams layout;                  // kWoven
  std::vector<CurveYarn> curves;        // kCurves
  KnitParams knit;                      // kKnit (its yarn_radius: params.yarn_radius)
  size_t layout_bytes = 0;  // the centre polylines' estimated size
};

// One generated yarn of a job: a layout's warp or weft, the straight yarn, a client curve or a knit's course.
struct LaidYarn {
  bool warp = false;  // false but for a woven layout's warp yarns
  int thread = 0;     // woven: the pattern thread; curves: the curve's index; knit: the course, from y = 0 up
  double length = 0;
  std::shared_ptr<const YarnCurve> centre;  // the centre curve its fibers were generated along
};

// Generates a job's fibers (GenerateLayout, GenerateCurveLayout or GenerateStraightYarn): one YarnGeometry per
// yarn. A knit's course c is a polyline yarn with the job's params and seed LayoutYarnSeed(params.seed, c).
// Returns "" or their error ("cancelled", "max_fibers: ...", "yarns[k].points: ..." for a curve, ...), leaving
// both outputs empty.
std::string GenerateYarnJob(YarnJob* job, std::vector<YarnGeometry>* yarns, std::vector<LaidYarn>* laid);

// Whether two jobs generate the same fibers along the same centres.
bool SameFibers(const YarnJob& a, const YarnJob& b);

}  // namespace loomlight::yarn
