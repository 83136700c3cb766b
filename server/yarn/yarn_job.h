// A yarn generation job: what a validated request asks for (YarnGeometry, Render's fiber scenes, CreateBtf's
// fiber source; server/api/yarn_rpc.h translates requests into it) and its generation into fibers.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"
#include "server/yarn/curve.h"
#include "server/yarn/layout.h"
#include "server/yarn/yarn.h"

namespace loomlight::yarn {

// Everything GenerateYarnJob needs: one straight yarn, or the warp and weft of a woven layout.
struct YarnJob {
  YarnParams params;
  DetailOptions detail;
  YarnLimits limits;
  double straight_length = 1;
  bool woven = false;  // else one straight yarn
  models::weave::WeavePattern pattern;
  LayoutParams layout;
  size_t layout_bytes = 0;  // the centre polylines' estimated size
};

// One generated yarn of a job: a layout's warp or weft, or the straight yarn.
struct LaidYarn {
  bool warp = false;
  int thread = 0;
  double length = 0;
  std::shared_ptr<const YarnCurve> centre;  // the centre curve its fibers were generated along
};

// Generates a job's fibers (GenerateLayout or GenerateStraightYarn): one YarnGeometry per yarn. Returns "" or
// their error ("cancelled", "max_fibers: ...", ...), leaving both outputs empty.
std::string GenerateYarnJob(YarnJob* job, std::vector<YarnGeometry>* yarns, std::vector<LaidYarn>* laid);

// Whether two jobs generate the same fibers along the same centres.
bool SameFibers(const YarnJob& a, const YarnJob& b);

}  // namespace loomlight::yarn
