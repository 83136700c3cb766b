#include "server/yarn/yarn_job.h"

#include <algorithm>
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
    std::vector<CurveYarn> knit_courses;
    if (job->kind == YarnLayoutKind::kKnit) {
      KnitParams knit = job->knit;
      knit.yarn_radius = job->params.yarn_radius;
      KnitLayout layout;
      error = BuildKnit(knit, &layout);
      // Course c (from y = 0 up) is yarn c of the layout, seeded as a woven layout seeds its yarns.
      for (size_t c = 0; error.empty() && c < layout.courses.size(); ++c) {
        CurveYarn& course = knit_courses.emplace_back();
        course.points = std::move(layout.courses[c]);
        course.params = job->params;
        course.params.seed = LayoutYarnSeed(job->params.seed, c);
      }
    }
    const std::vector<CurveYarn>& curves = job->kind == YarnLayoutKind::kKnit ? knit_courses : job->curves;
    LayoutGeometry fibers;
    std::vector<PolylineYarnCurve> centres;
    if (error.empty()) error = GenerateCurveLayout(curves, job->detail, job->limits, &fibers, &centres);
    // A course BuildKnit made that the curve layout refuses is the knit's fault, not the client's.
    if (job->kind == YarnLayoutKind::kKnit && error.rfind("yarns", 0) == 0) error = "internal: knit " + error;
    if (error.empty()) {
      *yarns = std::move(fibers.yarns);
      for (size_t k = 0; k < centres.size(); ++k) {
        const double length = centres[k].Length();
        laid->push_back({false, int(k), length, std::make_shared<PolylineYarnCurve>(std::move(centres[k]))});
      }
    }
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

namespace {

// The job's detail as its fibers see it: a footprint at which Eq. 4 keeps every fiber of every yarn (lambda 1, at
// or under a fiber's width) generates exactly the full-detail fibers, so it is footprint 0; a render that asks
// for LOD or AUTO close up then finds the FULL render's scene in the cache instead of generating it again.
DetailOptions EffectiveDetail(const YarnJob& job) {
  DetailOptions d = job.detail;
  const auto keeps_all = [&](const YarnParams& p) {
    return LodLambda(p.fiber_width, PlyWidth(p), d.footprint) >= 1;
  };
  const bool all = job.kind == YarnLayoutKind::kCurves
                       ? std::all_of(job.curves.begin(), job.curves.end(),
                                     [&](const CurveYarn& c) { return keeps_all(c.params); })
                       : keeps_all(job.params);
  if (all) d.footprint = 0;
  return d;
}

}  // namespace

bool SameFibers(const YarnJob& a, const YarnJob& b) {
  return a.params == b.params && EffectiveDetail(a).SameOutput(EffectiveDetail(b)) && a.limits == b.limits &&
         a.kind == b.kind &&
         a.pattern == b.pattern && a.layout == b.layout && a.straight_length == b.straight_length &&
         a.curves == b.curves && a.knit == b.knit;
}

}  // namespace loomlight::yarn
