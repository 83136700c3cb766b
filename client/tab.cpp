// `loomlight tab`: tabulates a material on a grid (Tabulate RPC) and writes the server's file as it streams
// in (RAW, EXR, MERL .binary or CSV), with a progress bar on stderr when it is a terminal.
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <string>

#include "client/commands.h"
#include "client/job_requests.h"
#include "client/material.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

v1::TableFormat parse_format(const std::string& name, const std::string& what) {
  if (name == "raw") return v1::TABLE_FORMAT_RAW;
  if (name == "exr") return v1::TABLE_FORMAT_EXR;
  if (name == "merl" || name == "binary") return v1::TABLE_FORMAT_MERL;
  if (name == "csv") return v1::TABLE_FORMAT_CSV;
  throw UsageError(what + ": expected raw, exr, merl (.binary) or csv, got '" + name + "'");
}

// --format, else the output file's extension.
v1::TableFormat output_format(const ParsedOptions& options, const std::string& out) {
  if (auto format = options.last("format")) return parse_format(*format, "--format");
  const auto dot = out.rfind('.');
  if (dot == std::string::npos) throw UsageError("cannot tell the format from '" + out + "': give --format");
  std::string extension = out.substr(dot + 1);
  for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return parse_format(extension, "--format (from the extension of " + out + ")");
}

uint32_t count_option(const ParsedOptions& options, const char* name, int fallback) {
  const auto text = options.last(name);
  return static_cast<uint32_t>(text ? parse_int(*text, std::string("--") + name, 1, 1 << 30) : fallback);
}

// The grid from --grid (default: merl for a MERL file, else inplane) and its options. The server checks
// ranges and limits; the client only checks the syntax.
void set_grid(const ParsedOptions& options, v1::TableFormat format, v1::TabulateRequest& request) {
  const std::string grid = options.last("grid").value_or(format == v1::TABLE_FORMAT_MERL ? "merl" : "inplane");
  if (grid == "inplane") {
    v1::InPlaneGrid* g = request.mutable_in_plane();
    if (auto incidence = options.last("incidence")) {
      for (double t : parse_numbers(*incidence, "--incidence")) g->add_theta_i_deg(t);
    } else {
      g->set_theta_i_count(count_option(options, "theta-i-count", 9));
    }
    g->set_theta_o_count(count_option(options, "theta-o-count", 181));
    if (auto phi = options.last("plane-phi")) g->set_phi_plane_deg(parse_number(*phi, "--plane-phi"));
    g->set_full_circle(options.has("full-circle"));
  } else if (grid == "4d") {
    const std::string dims = options.last("dims").value_or("32,32,32,32");
    parse_numbers(dims, "--dims", 4);  // exactly four numbers
    uint32_t counts[4];
    std::size_t start = 0;
    for (int d = 0; d < 4; ++d) {
      const std::size_t comma = dims.find(',', start);
      counts[d] = static_cast<uint32_t>(parse_int(dims.substr(start, comma - start), "--dims", 1, 1 << 30));
      start = comma + 1;
    }
    v1::AnisotropicGrid* g = request.mutable_anisotropic();
    g->set_theta_i_count(counts[0]);
    g->set_phi_i_count(counts[1]);
    g->set_theta_o_count(counts[2]);
    g->set_phi_o_count(counts[3]);
  } else if (grid == "merl") {
    request.mutable_merl()->set_phi_h_samples(
        options.last("phi-h-samples") ? count_option(options, "phi-h-samples", 1) : 0);
  } else {
    throw UsageError("--grid: expected inplane, 4d or merl, got '" + grid + "'");
  }
}

}  // namespace

v1::TabulateRequest tabulate_request(const ParsedOptions& options, const std::string& out) {
  const v1::EvaluateRequest material = material_request(options);
  v1::TabulateRequest request;
  *request.mutable_material() = material.material();
  request.set_precision(material.precision());
  request.set_format(output_format(options, out));
  set_grid(options, request.format(), request);
  return request;
}

namespace {

// "[#######.............]  35%  510,300 / 1,458,000 cells" redrawn in place on a terminal.
class Progress {
 public:
  Progress() : terminal_(isatty(STDERR_FILENO) == 1) {}
  void update(uint64_t done, uint64_t total) {
    if (!terminal_ || total == 0) return;
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(kWidth * done / total);
    std::fprintf(stderr, "\r[%s%s] %3d%%  %s / %s cells", std::string(filled, '#').c_str(),
                 std::string(kWidth - filled, '.').c_str(), static_cast<int>(100 * done / total), grouped(done).c_str(),
                 grouped(total).c_str());
    std::fflush(stderr);
    drawn_ = true;
  }
  void end() {
    if (drawn_) std::fputc('\n', stderr);
    drawn_ = false;
  }
  static std::string grouped(uint64_t n) {
    std::string digits = std::to_string(n), out;
    for (size_t i = 0; i < digits.size(); ++i) {
      if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
      out += digits[i];
    }
    return out;
  }

 private:
  bool terminal_;
  bool drawn_ = false;
};

const char* format_name(v1::TableFormat format) {
  switch (format) {
    case v1::TABLE_FORMAT_EXR: return "EXR";
    case v1::TABLE_FORMAT_MERL: return "MERL .binary";
    case v1::TABLE_FORMAT_CSV: return "CSV";
    default: return "raw float32";
  }
}

int run_tab(const ParsedOptions& options) {
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("tab needs --out FILE (.raw, .exr, .binary or .csv)");
  const v1::TabulateRequest request = tabulate_request(options, *out);

  std::ofstream file(*out, std::ios::binary | std::ios::trunc);
  if (!file) throw std::runtime_error("cannot write " + *out);
  Progress progress;
  v1::TabulateChunk first, last;
  uint64_t bytes = 0;
  const auto start = std::chrono::steady_clock::now();
  try {
    Client(options).tabulate(request, [&](const v1::TabulateChunk& chunk) {
      if (first.cells_total() == 0) {  // the first chunk names the model and the grid
        first = chunk;
        first.clear_data();
      }
      file.write(chunk.data().data(), static_cast<std::streamsize>(chunk.data().size()));
      if (!file) throw std::runtime_error("cannot write " + *out);
      bytes += chunk.data().size();
      last = chunk;
      last.clear_data();
      progress.update(chunk.cells_done(), chunk.cells_total());
    });
    file.close();
    if (!file) throw std::runtime_error("cannot write " + *out);
  } catch (...) {
    progress.end();
    file.close();
    std::remove(out->c_str());  // a partial table must not pass for a whole one
    throw;
  }
  progress.end();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("%s cells (%s, %s, %u queries/cell) in %.2f s (server %.2f s, kernel %.2f s): %s, %s bytes -> %s\n",
              Progress::grouped(last.cells_total()).c_str(), first.model().c_str(), precision_name(request.precision()),
              first.queries_per_cell(), seconds, last.total_seconds(), last.kernel_seconds(),
              format_name(request.format()), Progress::grouped(bytes).c_str(), out->c_str());
  return 0;
}

OptionList tab_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"out", "FILE", "output file (required); the extension picks the format unless --format is given"},
      {"format", "raw|exr|merl|csv", "raw float32 with a header, OpenEXR, MERL .binary, or CSV"},
      {"grid", "inplane|4d|merl", "the grid (default merl for MERL files, else inplane)"},
      {"incidence", "DEG,...", "inplane: incidence angles theta_i (the light at -theta_i in the plane)"},
      {"theta-i-count", "N", "inplane: N incidence angles at (k + 1/2) 90/N degrees (default 9)"},
      {"theta-o-count", "N", "inplane: outgoing angles across the plane (default 181)"},
      {"plane-phi", "DEG", "inplane: azimuth of the plane (default 0, the x-z plane)"},
      {"full-circle", "", "inplane: theta_o over the whole circle, also below the surface"},
      {"dims", "TI,PI,TO,PO", "4d: theta_i, phi_i, theta_o, phi_o counts (default 32,32,32,32)"},
      {"phi-h-samples", "N", "merl: half-vector azimuths averaged per cell (default: 1 isotropic, 8 otherwise)"},
  });
  return options;
}

}  // namespace

const Command& tab_command() {
  static const Command command = {
      "tab",
      "MATERIAL --out FILE [--grid inplane|4d|merl] [grid options] [--format raw|exr|merl|csv]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "tabulate f on a grid of directions into a RAW, EXR, MERL .binary or CSV file",
      "The server evaluates the grid in batches and streams the file; a progress bar is drawn on stderr\n"
      "when it is a terminal, and one summary line is printed at the end. Bin centres and file layouts are\n"
      "in docs/tabulation.md. Large tables may need a longer --timeout (0 = none).\n"
      "Example: loomlight tab --preset silk_shot --grid merl --out silk_shot.binary",
      tab_options(),
      run_tab,
  };
  return command;
}

}  // namespace loomlight::client
