#include "server/yarn/yarn_job.h"

#include <utility>

namespace loomlight::yarn {

std::string GenerateYarnJob(YarnJob* job, std::vector<YarnGeometry>* yarns, std::vector<LaidYarn>* laid) {
  yarns->clear();
  laid->clear();
  std::string error;
  if (job->kind == YarnLayoutKind::kWoven) {
    WovenLayout layout;
    error = BuildLayout(job->pattern, job->layout, &layout);
    LayoutGeometry fibers;
    if (error.empty()) error = GenerateLayout(job->params, layout, job->detail, job->limits, &fibers);
    if (error.empty()) {
      *yarns = std::move(fibers.yarns);
      for (const LayoutYarn& y : layout.yarns)
        laid->push_back({y.warp, y.thread, y.curve.Length(), std::make_shared<PolylineYarnCurve>(y.curve)});
    }
  } else if (job->kind == YarnLayoutKind::kCurves || job->kind == YarnLayoutKind::kKnit) {
    error = "internal: curve and knit layouts are not generated yet";
  } else {
    job->params.length = job->straight_length;
    error = GenerateStraightYarn(job->params, job->detail, job->limits, &yarns->emplace_back());
    laid->push_back({false, 0, job->straight_length, std::make_shared<StraightYarnCurve>(job->straight_length)});
  }
  if (!error.empty()) {
    yarns->clear();
    laid->clear();
  }
  return error;
}

bool SameFibers(const YarnJob& a, const YarnJob& b) {
  return a.params == b.params && a.detail.SameOutput(b.detail) && a.limits == b.limits && a.kind == b.kind &&
         a.pattern == b.pattern && a.layout == b.layout && a.straight_length == b.straight_length &&
         a.curves == b.curves && a.knit == b.knit;
}

}  // namespace loomlight::yarn
