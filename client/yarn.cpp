// `loomlight yarn`: the fiber curves of a procedural yarn (YarnGeometry RPC), written as they stream in as
// pbrt-v4 `curve` shapes, so pbrt-v4 (and renderers that read its scenes) can render them.
#include <chrono>
#include <cstdio>
#include <fstream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "client/commands.h"
#include "client/material.h"
#include "client/progress.h"
#include "client/rpc.h"
#include "client/yarn_layouts.h"

namespace loomlight::client {
namespace {

// One yarn of a curves CSV as it is read: its points, and its optional columns as first given.
struct CsvYarn {
  std::vector<double> points;
  std::optional<std::string> preset;
  std::optional<double> radius;
  std::optional<bool> bspline;
};

// An optional column's value on one line: the first given for the yarn, or the same again.
template <class T>
void agree(std::optional<T>* kept, const T& value, const std::string& where, const std::string& column, int yarn) {
  if (!*kept) *kept = value;
  else if (**kept != value)
    throw UsageError(where + ": " + column + " differs from the one given before for yarn " + std::to_string(yarn));
}

void read_curves_csv(const std::string& text, const std::string& file, bool bspline, v1::CurveYarnLayout* out) {
  std::istringstream lines(text);
  std::string line;
  std::vector<CsvYarn> yarns;
  bool first = true;
  for (int number = 1; std::getline(lines, line); ++number) {
    const std::string where = file + ":" + std::to_string(number);
    const size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    const std::vector<std::string> fields = split_csv_record(line, where);
    // A header is a first line whose first field is not a number.
    const bool header = first && fields[0].find_first_of("0123456789") == std::string::npos;
    first = false;
    if (header) continue;
    if (fields.size() < 4 || fields.size() > 7)
      throw UsageError(where + ": expected yarn,x,y,z[,preset[,radius[,bspline]]], got " +
                       std::to_string(fields.size()) + " fields");
    // Far more yarns than the server takes (its limit, docs/fibers.md) stays cheap here and is refused there.
    const int k = parse_int(fields[0], where + " yarn", 0, 1 << 20);
    if (size_t(k) >= yarns.size()) yarns.resize(size_t(k) + 1);
    CsvYarn& y = yarns[size_t(k)];
    for (int c = 1; c <= 3; ++c) y.points.push_back(parse_number(fields[size_t(c)], where + " " + "xyz"[c - 1]));
    if (fields.size() > 4 && !fields[4].empty()) agree(&y.preset, fields[4], where, "preset", k);
    if (fields.size() > 5 && !fields[5].empty()) agree(&y.radius, parse_number(fields[5], where + " radius"), where, "radius", k);
    if (fields.size() > 6 && !fields[6].empty()) {
      if (fields[6] != "0" && fields[6] != "1")
        throw UsageError(where + ": bspline must be 1 (a B-spline) or 0 (a polyline), got '" + fields[6] + "'");
      agree(&y.bspline, fields[6] == "1", where, "bspline", k);
    }
  }
  if (yarns.empty()) throw UsageError(file + ": no control points");
  for (size_t k = 0; k < yarns.size(); ++k) {
    const CsvYarn& y = yarns[k];
    if (y.points.empty())
      throw UsageError(file + ": yarn " + std::to_string(k) + " has no points (yarns are numbered from 0 without gaps)");
    v1::YarnCentreCurve* c = out->add_yarns();
    c->mutable_points()->Add(y.points.begin(), y.points.end());
    c->set_bspline(y.bspline.value_or(bspline));
    if (y.preset) c->mutable_yarn()->set_preset(*y.preset);
    if (y.radius) c->set_radius(*y.radius);
  }
}

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
  // Read aside: the layouts are one oneof, and setting one clears another.
  v1::CurveYarnLayout curve_layout;
  v1::KnitYarnLayout knit_layout;
  const bool curves = curves_from_options(options, &curve_layout);
  const bool knit = knit_from_options(options, &knit_layout);
  if (int(curves) + int(knit) + int(options.has("weave")) + int(options.has("length")) > 1)
    throw UsageError("give one layout: --length, --weave, --curves or --knit");
  if (curves) *request.mutable_curves() = std::move(curve_layout);
  if (knit) *request.mutable_knit() = std::move(knit_layout);
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
  OptionList options = {
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
  for (const OptionList& layout : {curves_options(), knit_options()})  // after the woven layout's
    options.insert(options.begin() + 10, layout.begin(), layout.end());
  return options;
}

}  // namespace

bool curves_from_options(const ParsedOptions& options, v1::CurveYarnLayout* out) {
  const auto file = options.last("curves");
  if (!file) {
    if (options.has("bspline")) throw UsageError("--bspline is for --curves");
    return false;
  }
  read_curves_csv(read_local_file(*file, "--curves"), *file, options.has("bspline"), out);
  return true;
}

bool knit_from_options(const ParsedOptions& options, v1::KnitYarnLayout* out, bool stitches) {
  const auto stitch = options.last("knit");
  if (!stitch) {
    if (options.has("stitches") || options.has("wale-spacing") || options.has("course-spacing"))
      throw UsageError("--stitches, --wale-spacing and --course-spacing need --knit jersey|rib");
    return false;
  }
  if (*stitch == "jersey") out->set_stitch(v1::KNIT_JERSEY);
  else if (*stitch == "rib") out->set_stitch(v1::KNIT_RIB_1X1);
  else throw UsageError("--knit: expected jersey or rib, got '" + *stitch + "'");
  if (auto n = options.last("stitches"); n && stitches) {
    const size_t comma = n->find(',');
    if (comma == std::string::npos) throw UsageError("--stitches needs WALES,COURSES, got '" + *n + "'");
    out->set_wales(uint32_t(parse_int(n->substr(0, comma), "--stitches wales", 1, 1 << 20)));
    out->set_courses(uint32_t(parse_int(n->substr(comma + 1), "--stitches courses", 1, 1 << 20)));
  }
  if (auto w = options.last("wale-spacing")) out->set_wale_spacing(parse_number(*w, "--wale-spacing"));
  if (auto c = options.last("course-spacing")) out->set_course_spacing(parse_number(*c, "--course-spacing"));
  return true;
}

OptionList knit_options(bool stitches) {
  OptionList options = {
      {"knit", "jersey|rib", "a weft knit: stockinette jersey or 1 x 1 rib, one yarn per course (docs/fibers.md \"Knits\")"},
      {"wale-spacing", "S", "with --knit: centre to centre of neighbouring wales (default: the server's for the yarn)"},
      {"course-spacing", "S", "with --knit: centre to centre of neighbouring courses (default: the server's)"},
  };
  if (stitches)
    options.insert(options.begin() + 1, {"stitches", "WALES,COURSES", "with --knit: stitches across and rows (default 8,8)"});
  return options;
}

OptionList curves_options() {
  return {
      {"curves", "FILE",
       "yarns along centre curves from a CSV, one line per control point: yarn,x,y,z[,preset[,radius[,bspline]]] "
       "(docs/fibers.md \"Yarn curves\")"},
      {"bspline", "", "with --curves: curves without a bspline column are cubic B-splines (default: polylines)"},
  };
}

const Command& yarn_command() {
  static const Command command = {
      "yarn",
      "--out FILE.pbrt [--yarn PRESET] [--yarn-param NAME=V]...\n"
      "  [--length L | --weave PRESET [layout options] | --curves FILE [--bspline] | --knit jersey|rib [knit options]]\n"
      "  [--footprint W] [--no-core] [--core-radius R] [--points-per-twist N] [--seed N]",
      "write a procedural yarn's fiber curves as pbrt-v4 curve shapes",
      "The server generates the yarn (plies, fibers, flyaways, core fibers; docs/fibers.md \"Yarn geometry\")\n"
      "and streams the curves; each becomes a pbrt-v4 \"curve\" shape (cylinder, cubic B-spline). Include the\n"
      "file from a pbrt-v4 scene. Example: loomlight yarn --yarn silk1 --length 2 --out silk1.pbrt\n"
      "Curves: loomlight yarn --curves yarns.csv --bspline --out curves.pbrt, yarns.csv holding lines\n"
      "  yarn,x,y,z[,preset[,radius[,bspline]]] (a header line is optional), e.g. \"0,0,0,0,silk1,0.05,1\"\n"
      "Knits:  loomlight yarn --knit jersey --stitches 40,40 --footprint 0.01 --out jersey.pbrt",
      yarn_options(),
      run_yarn,
  };
  return command;
}

}  // namespace loomlight::client
