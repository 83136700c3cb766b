// `loomlight yarn`: the fiber curves of a procedural yarn (YarnGeometry RPC), written as they stream in as
// pbrt-v4 `curve` shapes, so pbrt-v4 (and renderers that read its scenes) can render them.
#include <chrono>
#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <string>

#include "client/commands.h"
#include "client/material.h"
#include "client/progress.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

const char* fiber_type_name(int type) {
  switch (type) {
    case v1::FIBER_CORE: return "core";
    case v1::FIBER_MIGRATION: return "migration";
    case v1::FIBER_LOOP: return "loop";
    case v1::FIBER_HAIR: return "hair";
  }
  return "unknown";
}

v1::YarnGeometryRequest yarn_request(const ParsedOptions& options) {
  v1::YarnGeometryRequest request;
  v1::Yarn& yarn = *request.mutable_yarn();
  yarn_from_options(options, &yarn);
  if (auto seed = options.last("seed")) {
    const double s = parse_number(*seed, "--seed");
    if (!(s >= 0 && s <= 9007199254740992.0) || s != static_cast<double>(static_cast<uint64_t>(s)))
      throw UsageError("--seed: expected an integer in [0, 2^53], got '" + *seed + "'");
    yarn.set_seed(static_cast<uint64_t>(s));
  }
  if (auto weave = options.last("weave")) {
    v1::WovenYarnLayout& woven = *request.mutable_woven();
    woven.mutable_weave()->set_preset(*weave);
    if (auto wif = options.last("weave-wif")) {
      v1::Param* p = woven.mutable_weave()->add_params();
      p->set_name("pattern.wif");
      p->set_text(read_local_file(*wif, "--weave-wif"));
    }
    if (auto spacing = options.last("spacing")) woven.set_yarn_spacing(parse_number(*spacing, "--spacing"));
    if (auto crimp = options.last("crimp")) woven.set_crimp(parse_number(*crimp, "--crimp"));
    if (auto repeats = options.last("repeats")) {
      const auto r = parse_numbers(*repeats, "--repeats", 2);
      woven.set_repeats_u(static_cast<uint32_t>(parse_int(std::to_string(r[0]), "--repeats", 1, 1 << 20)));
      woven.set_repeats_v(static_cast<uint32_t>(parse_int(std::to_string(r[1]), "--repeats", 1, 1 << 20)));
    }
  } else {
    if (options.has("weave-wif") || options.has("spacing") || options.has("crimp") || options.has("repeats"))
      throw UsageError("--weave-wif, --spacing, --crimp and --repeats need --weave PRESET");
    if (auto length = options.last("length")) request.mutable_straight()->set_length(parse_number(*length, "--length"));
  }
  v1::YarnDetail& detail = *request.mutable_detail();
  if (options.has("no-core")) detail.set_core(false);
  if (auto r = options.last("core-radius")) detail.set_core_radius(parse_number(*r, "--core-radius"));
  if (auto f = options.last("footprint")) detail.set_footprint(parse_number(*f, "--footprint"));
  if (auto n = options.last("points-per-twist"))
    detail.set_points_per_twist(static_cast<uint32_t>(parse_int(*n, "--points-per-twist", 1, 1 << 20)));
  if (auto n = options.last("max-fibers"))
    request.set_max_fibers(static_cast<uint64_t>(parse_int(*n, "--max-fibers", 1, 1 << 30)));
  if (auto n = options.last("max-points"))
    request.set_max_control_points(static_cast<uint64_t>(parse_int(*n, "--max-points", 1, 1 << 30)));
  return request;
}

// One pbrt-v4 curve per fiber: a uniform cubic B-spline whose control polygon is the server's polyline, the
// end points repeated three times so the curve starts and ends on them (the points are dense, a few per
// twist, so the spline stays within a small fraction of a fiber width of the polyline).
void write_curves(std::ostream& out, const v1::FiberCurves& curves) {
  size_t first = 0;  // the curve's first point
  for (int c = 0; c < curves.point_counts_size(); ++c) {
    const uint32_t n = curves.point_counts(c);
    out << "# " << fiber_type_name(curves.types(c)) << " yarn " << curves.yarns(c) << " ply " << curves.plies(c)
        << " fiber " << curves.fibers(c) << "\nShape \"curve\" \"string type\" \"cylinder\" \"string basis\" "
        << "\"bspline\" \"integer degree\" [ 3 ] \"float width0\" [ " << curves.widths(c) << " ] \"float width1\" [ "
        << curves.widths(c) << " ]\n  \"point3 P\" [";
    const auto point = [&](size_t k) {
      out << ' ' << curves.points(3 * k) << ' ' << curves.points(3 * k + 1) << ' ' << curves.points(3 * k + 2);
    };
    point(first), point(first);
    for (uint32_t k = 0; k < n; ++k) point(first + k);
    point(first + n - 1), point(first + n - 1);
    out << " ]\n";
    first += n;
  }
}

int run_yarn(const ParsedOptions& options) {
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("yarn needs --out FILE.pbrt");
  const v1::YarnGeometryRequest request = yarn_request(options);
  std::ofstream file(*out, std::ios::trunc);
  if (!file) throw std::runtime_error("cannot write " + *out);
  file.precision(9);  // float round trip
  ProgressBar progress("fibers");
  v1::YarnGeometrySummary summary;
  v1::YarnGeometryChunk last;
  const auto start = std::chrono::steady_clock::now();
  try {
    Client(options).yarn_geometry(request, [&](const v1::YarnGeometryChunk& chunk) {
      if (chunk.has_summary()) {
        summary = chunk.summary();
        file << "# Loomlight procedural yarn: preset "
             << (request.yarn().preset().empty() ? "cotton1" : request.yarn().preset()) << ", " << summary.fibers()
             << " fibers, " << summary.control_points() << " control points, lambda " << summary.lambda()
             << "\n# bounds [" << summary.bounds_min(0) << ' ' << summary.bounds_min(1) << ' ' << summary.bounds_min(2)
             << "] - [" << summary.bounds_max(0) << ' ' << summary.bounds_max(1) << ' ' << summary.bounds_max(2)
             << "]\n";
      }
      write_curves(file, chunk.curves());
      if (!file) throw std::runtime_error("cannot write " + *out);
      progress.update(chunk.fibers_sent(), summary.fibers());
      last = chunk;
      last.clear_curves();
    });
    file.close();
    if (!file) throw std::runtime_error("cannot write " + *out);
  } catch (...) {
    progress.end();
    file.close();
    std::remove(out->c_str());  // partial geometry must not pass for the whole yarn
    throw;
  }
  progress.end();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("%s fibers, %s control points (lambda %.3g, %u points per twist) in %.2f s (server %.2f s, generation "
              "%.2f s) -> %s\n",
              ProgressBar::grouped(summary.fibers()).c_str(), ProgressBar::grouped(summary.control_points()).c_str(),
              summary.lambda(), summary.points_per_twist(), seconds, last.total_seconds(), summary.generate_seconds(),
              out->c_str());
  return 0;
}

OptionList yarn_options() {
  return {
      {"out", "FILE", "output pbrt-v4 scene fragment (required): one `curve` shape per fiber"},
      {"yarn", "PRESET", "cotton1 (default), cotton2, polyester1, rayon2 or silk1 (see `loomlight models`)"},
      {"yarn-param", "NAME=V", "override a yarn parameter (repeatable)"},
      {"seed", "N", "random seed (default 1): same seed, same curves"},
      {"length", "L", "a straight yarn along +z of this length (default 1)"},
      {"weave", "PRESET", "lay out warp and weft by this woven preset's pattern instead of one straight yarn"},
      {"weave-wif", "FILE", "with --weave: the pattern from a WIF draft"},
      {"spacing", "S", "with --weave: centre-to-centre yarn spacing"},
      {"crimp", "C", "with --weave: over/under bending in [0, 1] (default 1)"},
      {"repeats", "U,V", "with --weave: pattern repeats along x and y (default 1,1)"},
      {"footprint", "W", "level of detail (Eq. 4) for a pixel footprint of W at the yarn (default 0: full detail)"},
      {"no-core", "", "generate every fiber, no core fibers"},
      {"core-radius", "R", "fibers within R ply radii become the core fiber (default 0.5)"},
      {"points-per-twist", "N", "control points per shortest period (default 16)"},
      {"max-fibers", "N", "refuse geometry with more fiber curves than N"},
      {"max-points", "N", "refuse geometry with more control points than N"},
  };
}

}  // namespace

const Command& yarn_command() {
  static const Command command = {
      "yarn",
      "--out FILE.pbrt [--yarn PRESET] [--yarn-param NAME=V]... [--length L | --weave PRESET [layout options]]\n"
      "  [--footprint W] [--no-core] [--core-radius R] [--points-per-twist N] [--seed N]",
      "write a procedural yarn's fiber curves as pbrt-v4 curve shapes",
      "The server generates the yarn (plies, fibers, flyaways, core fibers; docs/fibers.md \"Yarn geometry\")\n"
      "and streams the curves; each becomes a pbrt-v4 \"curve\" shape (cylinder, cubic B-spline). Include the\n"
      "file from a pbrt-v4 scene. Example: loomlight yarn --yarn silk1 --length 2 --out silk1.pbrt",
      yarn_options(),
      run_yarn,
  };
  return command;
}

}  // namespace loomlight::client
