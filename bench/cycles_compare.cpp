#include "bench/cycles_compare.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <sstream>

#include "bench/bench.h"
#include "bench/report.h"
#include "bench/stats.h"

// After the protobuf headers: OpenImageIO's byte-swap macros clash with protobuf's port.h.
#include <OpenImageIO/imageio.h>

namespace loomlight::bench {

void Curve::Add(uint32_t spp, double seconds, double client_seconds, const ImageError& error) {
  Point p{spp, seconds, client_seconds, error};
  const double own_mse = error.mse - reference_noise.mse, least = reference_noise.mse / 4;
  p.own_is_floor = own_mse < least;
  p.own_psnr_db = error.psnr_db + 10 * std::log10(error.mse / std::max(own_mse, least));
  points.push_back(p);
}

std::vector<float> FromHalves(const std::vector<float>& a, const std::vector<float>& b, ImageError* noise) {
  std::vector<float> mean(std::min(a.size(), b.size()));
  for (size_t i = 0; i < mean.size(); ++i) mean[i] = 0.5f * (a[i] + b[i]);
  const ImageError between = Compare(a, b);
  const double peak = mean.empty() ? 0 : *std::max_element(mean.begin(), mean.end());
  noise->mse = between.mse / 4;
  noise->relative_mse = between.relative_mse / 4;
  noise->psnr_db = noise->mse > 0 ? 10 * std::log10(peak * peak / noise->mse) : 0;
  return mean;
}

std::optional<Crossing> Reach(const Curve& curve, double db) {
  const std::vector<Point>& p = curve.points;
  if (p.empty()) return std::nullopt;
  if (p[0].own_psnr_db >= db) return Crossing{p[0].seconds, double(p[0].spp)};
  for (size_t i = 0; i + 1 < p.size(); ++i)
    if (p[i].own_psnr_db < db && p[i + 1].own_psnr_db >= db) {
      const double f = (db - p[i].own_psnr_db) / (p[i + 1].own_psnr_db - p[i].own_psnr_db);
      const auto log_lerp = [f](double a, double b) { return std::exp((1 - f) * std::log(a) + f * std::log(b)); };
      return Crossing{log_lerp(p[i].seconds, p[i + 1].seconds), log_lerp(p[i].spp, p[i + 1].spp)};
    }
  return std::nullopt;
}

std::string ReachText(const Curve& curve, double db) {
  const std::optional<Crossing> c = Reach(curve, db);
  if (!c) return "not reached";
  return (c->spp <= curve.points[0].spp ? "<= " : "") + Fixed(c->seconds, 3) + " s (" + Fixed(c->spp, 0) + " spp)";
}

double SecondsTo(const Curve& curve, double db) { return Reach(curve, db).value_or(Crossing{0, 0}).seconds; }

std::string Pixels(uint32_t side) { return std::to_string(side) + "x" + std::to_string(side); }

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return bytes.str();
}

std::string WriteExr(const std::string& path, const std::vector<float>& rgb, int width, int height) {
  auto out = OIIO::ImageOutput::create(path);
  if (!out || !out->open(path, OIIO::ImageSpec(width, height, 3, OIIO::TypeDesc::FLOAT)) ||
      !out->write_image(OIIO::TypeDesc::FLOAT, rgb.data()) || !out->close())
    return "cannot write " + path + (out ? ": " + out->geterror() : "");
  return "";
}

std::string WriteEnvironment(const std::string& path, const render::Environment& environment, int width,
                             double* brightest) {
  const int height = width / 2;
  std::vector<float> rgb(size_t{3} * width * height);
  *brightest = 0;
  for (int j = 0; j < height; ++j)
    for (int i = 0; i < width; ++i) {
      const double azimuth = (0.5 - (i + 0.5) / width) * 2 * std::numbers::pi;
      const double elevation = (0.5 - (j + 0.5) / height) * std::numbers::pi;
      const double bx = std::cos(elevation) * std::cos(azimuth), by = std::cos(elevation) * std::sin(azimuth),
                   bz = std::sin(elevation);
      const render::Rgb radiance = environment.Radiance({bx, bz, -by});
      for (int c = 0; c < 3; ++c) {
        rgb[3 * (size_t(j) * width + i) + c] = static_cast<float>(radiance[c]);
        *brightest = std::max(*brightest, radiance[c]);
      }
    }
  return WriteExr(path, rgb, width, height);
}

namespace {

std::string FindOnPath(const char* name) {
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path ? path : "");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const std::string candidate = (dir.empty() ? "." : dir) + "/" + name;
    if (access(candidate.c_str(), X_OK) == 0) return candidate;
  }
  return "";
}

}  // namespace

bool PrepareBlender(const std::string& prefix, BlenderRun* run) {
  if (FindOnPath("blender").empty()) {
    run->skipped = "`blender` is not on PATH (Debian: `apt-get install blender`)";
    return false;
  }
  std::string dir_template = (std::filesystem::temp_directory_path() / (prefix + "-XXXXXX")).string();
  if (!mkdtemp(dir_template.data())) {
    run->skipped = "no temporary directory";
    return false;
  }
  run->dir = dir_template;
  run->log = (run->dir / "blender.log").string();
  return true;
}

void RunBlender(const std::string& script, const std::string& args, BlenderRun* run) {
  const std::string command = "'" + FindOnPath("blender") +
                              "' -b --factory-startup -noaudio --python-exit-code 1 --python '" +
                              LOOMLIGHT_SOURCE_DIR + "/bench/cycles/" + script + "' -- " + args + " --out '" +
                              run->dir.string() + "' > '" + run->log + "' 2>&1";
  const Clock::time_point start = Clock::now();
  const int status = std::system(command.c_str());
  run->process_seconds = SecondsSince(start);
  if (status != 0) {
    run->skipped = "Blender failed (exit status " + std::to_string(status) + "; its log: " + run->log + ")";
    return;
  }
  std::istringstream(ReadFile(run->dir / "version.txt")) >> run->version;
  std::istringstream lines(ReadFile(run->dir / "times.tsv"));
  for (std::string name, spp, seed, s; lines >> name >> spp >> seed >> s;) run->seconds[name] = std::stod(s);
}

std::string RenderJob(const std::string& name, uint32_t spp, uint64_t seed, int runs) {
  return name + ":" + std::to_string(spp) + ":" + std::to_string(seed) + ":" + std::to_string(runs);
}

}  // namespace loomlight::bench
