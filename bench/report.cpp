#include "bench/report.h"

#include <CL/cl.h>
#include <sys/utsname.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <sstream>
#include <thread>

namespace loomlight::bench {

std::string Table::Markdown() const {
  std::vector<size_t> width(header_.size(), 3);
  for (size_t c = 0; c < header_.size(); ++c) width[c] = std::max(width[c], header_[c].size());
  for (const auto& row : rows_)
    for (size_t c = 0; c < row.size() && c < width.size(); ++c) width[c] = std::max(width[c], row[c].size());
  auto line = [&](const std::vector<std::string>& cells) {
    std::string s = "|";
    for (size_t c = 0; c < width.size(); ++c) {
      const std::string cell = c < cells.size() ? cells[c] : "";
      const std::string pad(width[c] - cell.size(), ' ');
      s += " " + (c < text_columns_ ? cell + pad : pad + cell) + " |";
    }
    return s + "\n";
  };
  std::string rule = "|";
  for (size_t c = 0; c < width.size(); ++c)
    rule += c < text_columns_ ? " " + std::string(width[c], '-') + " |" : " " + std::string(width[c] - 1, '-') + ": |";
  std::string out = line(header_) + rule + "\n";
  for (const auto& row : rows_) out += line(row);
  return out;
}

std::string Section(const std::string& title, const std::string& method, const std::string& body) {
  return "## " + title + "\n\n" + method + "\n\n" + body;
}

std::string TableBlock(const std::string& how_to_read, const Table& table) {
  return "*How to read:* " + how_to_read + "\n\n" + table.Markdown() + "\n";
}

namespace {
std::string Format(const char* fmt, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}
}  // namespace

std::string Fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::string Sci(double v) { return v == 0 ? "0" : Format("%.1e", v); }

std::string Rate(double per_second) {
  if (per_second >= 1e6) return Format("%.3g M", per_second / 1e6);
  if (per_second >= 1e3) return Format("%.3g k", per_second / 1e3);
  return Format("%.3g", per_second);
}

std::string Millis(double seconds) {
  const double ms = seconds * 1e3;
  return ms >= 100 ? Format("%.0f", ms) : Format("%.3g", ms);
}

std::string Count(size_t n) {
  std::string digits = std::to_string(n), out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

namespace {

// The value after "key" and its colon on the first matching line of a /proc file, or "".
std::string ProcField(const char* file, const std::string& key) {
  std::ifstream in(file);
  for (std::string line; std::getline(in, line);)
    if (line.rfind(key, 0) == 0) {
      const size_t colon = line.find(':');
      if (colon == std::string::npos) continue;
      const size_t start = line.find_first_not_of(" \t", colon + 1);
      return start == std::string::npos ? "" : line.substr(start);
    }
  return "";
}

std::string Command(const std::string& command) {
  std::string out;
  if (FILE* p = popen(command.c_str(), "r")) {
    char buf[256];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    pclose(p);
  }
  while (!out.empty() && (out.back() == '\n' || out.back() == ' ')) out.pop_back();
  return out;
}

std::string SourceRevision() {
  const std::string dir = LOOMLIGHT_SOURCE_DIR;
  const std::string head = Command("git -C '" + dir + "' rev-parse --short HEAD 2>/dev/null");
  if (head.empty()) return "unknown";
  // bench/ holds this report, rewritten by every run: only changes elsewhere make the build differ from HEAD.
  const bool dirty =
      !Command("git -C '" + dir + "' status --porcelain --untracked-files=no -- ':(exclude)bench' 2>/dev/null").empty();
  return head + (dirty ? " + uncommitted changes outside bench/" : "");
}

// CL_PLATFORM_VERSION of the platform with this name (the PoCL version), or "".
std::string PlatformVersion(const std::string& name) {
  cl_uint n = 0;
  if (clGetPlatformIDs(0, nullptr, &n) != CL_SUCCESS) return "";
  std::vector<cl_platform_id> platforms(n);
  clGetPlatformIDs(n, platforms.data(), nullptr);
  for (cl_platform_id p : platforms) {
    char buf[512] = {};
    clGetPlatformInfo(p, CL_PLATFORM_NAME, sizeof buf - 1, buf, nullptr);
    if (name != buf) continue;
    clGetPlatformInfo(p, CL_PLATFORM_VERSION, sizeof buf - 1, buf, nullptr);
    return buf;
  }
  return "";
}

// MemTotal ("24684092 kB") in GiB.
std::string MemoryGiB() {
  const double kib = std::atof(ProcField("/proc/meminfo", "MemTotal").c_str());
  return Fixed(kib / (1024.0 * 1024.0), 1) + " GiB";
}

std::string CompilerName() {
#if defined(__clang__)
  return std::string("Clang ") + __clang_version__;
#elif defined(__GNUC__)
  return std::string("GCC ") + __VERSION__;
#else
  return "unknown compiler";
#endif
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  char buf[64];
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  return buf;
}

}  // namespace

// A fixed single-thread loop (2^26 dependent steps of an xorshift and a multiply-add), best of 3, in
// milliseconds: the same work on every run, so times in reports of different days can be put on one scale.
double CalibrationMilliseconds() {
  double best = 1e300;
  for (int run = 0; run < 3; ++run) {
    const auto start = std::chrono::steady_clock::now();
    uint64_t x = 0x9E3779B97F4A7C15ull;
    double y = 1;
    for (uint32_t i = 0; i < (1u << 26); ++i) {
      x ^= x << 13;
      x ^= x >> 7;
      x ^= x << 17;
      y = y * 0.999999 + double(x >> 40) * 1e-12;  // dependent on the last step: no vectorising it away
    }
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    if (y < 0) std::fprintf(stderr, "%g\n", y);  // keeps y (never true)
    best = std::min(best, ms);
  }
  return best;
}

std::string MachineDescription(const std::string& cl_platform, const std::string& cl_device, bool quick) {
  utsname u{};
  uname(&u);
  std::ostringstream s;
  s << "- Date: " << UtcNow() << (quick ? " (**--quick smoke run: small sizes, numbers not representative**)" : "")
    << "\n"
    << "- CPU: " << ProcField("/proc/cpuinfo", "model name") << ", " << std::thread::hardware_concurrency()
    << " hardware threads, " << MemoryGiB() << " memory\n"
    << "- CPU calibration: a fixed single-thread loop (2^26 dependent xorshift and multiply-add steps) took "
    << CalibrationMilliseconds() << " ms, best of 3 (divide a time by it to compare reports of different days)\n"
    << "- OS: " << u.sysname << " " << u.release << " " << u.machine << "\n"
    << "- OpenCL: " << cl_platform << " (" << PlatformVersion(cl_platform) << "), device `" << cl_device << "`\n"
    << "- Compiler: " << CompilerName() << "; native baseline -O3 -march=native on all hardware threads\n"
    << "- Source revision: " << SourceRevision() << "\n";
  return s.str();
}

}  // namespace loomlight::bench
