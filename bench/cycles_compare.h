// Noise against time, each renderer against its own converged image, and Blender Cycles run beside Loomlight:
// shared by the noise section (the cylinders, bench/cycles/cylinders.py) and the product section (a garment
// mesh, bench/cycles/product.py).
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "bench/render_client.h"
#include "server/render/environment.h"

namespace loomlight::bench {

struct Point {
  uint32_t spp = 0;
  double seconds = 0;         // the server's total (Loomlight) or the render operator's (Cycles)
  double client_seconds = 0;  // the call as the client sees it (Loomlight only)
  ImageError error;           // against the renderer's own reference
  double own_psnr_db = 0;     // against the noise-free image (estimated): the reference's noise taken out
  bool own_is_floor = false;  // the reference cannot resolve the image's noise: own_psnr_db is a lower bound
};

// One renderer's sweep over one scene.
struct Curve {
  std::string renderer, scene, material, fidelity;
  uint32_t side = 0, reference_spp = 0;
  ImageError reference_noise;  // the reference's own, against the noise-free image (estimated)
  std::vector<Point> points;

  // An image's error against the reference is its own plus the reference's (independent seeds), so its own
  // MSE is the difference. Under a quarter of the reference's own MSE that difference is not resolved: the
  // PSNR is then given as a floor, 6 dB above the reference's.
  void Add(uint32_t spp, double seconds, double client_seconds, const ImageError& error);
};

// The mean of two independent halves is the reference. Their difference has twice a half's variance and
// the mean half of one, so the mean's MSE against the noise-free image is about MSE(a, b) / 4.
std::vector<float> FromHalves(const std::vector<float>& a, const std::vector<float>& b, ImageError* noise);

struct Crossing {
  double seconds, spp;
};
// Where the curve's own PSNR reaches `db`: linear in PSNR against log time (and log samples) between the two
// measured points around it (when noise dominates, PSNR grows by 10 dB per tenfold time). Nothing past the
// last point.
std::optional<Crossing> Reach(const Curve& curve, double db);
// "1.234 s (56 spp)", "<= ..." when the first point is past it already, or "not reached".
std::string ReachText(const Curve& curve, double db);
// The seconds to reach `db`, 0 when not reached.
double SecondsTo(const Curve& curve, double db);

std::string Pixels(uint32_t side);  // "256x256"
std::string ReadFile(const std::filesystem::path& path);
// Writes linear RGB rows from the top as a float EXR; returns "" or what failed.
std::string WriteExr(const std::string& path, const std::vector<float>& rgb, int width, int height);
// `environment` as an equirectangular EXR in Blender's convention, width x width / 2: z up, column 0.5 W looking
// along +x, +y at 0.25 W (Cycles' direction_to_equirectangular), row 0 straight up. Each texel holds the
// radiance toward its centre; a Loomlight direction (x, y, z) is Blender's (x, -z, y). Returns "" or what
// failed, and the brightest texel.
std::string WriteEnvironment(const std::string& path, const render::Environment& environment, int width,
                             double* brightest);

// A Blender process run in the background on a script of bench/cycles/, which writes into `dir`: NAME.exr per
// render, times.tsv ("NAME SPP SEED SECONDS" lines) and version.txt.
struct BlenderRun {
  std::string skipped;  // why Blender did not run or failed, or ""
  std::string version;  // "3.4.1"
  std::filesystem::path dir;
  std::string log;
  double process_seconds = 0;
  std::map<std::string, double> seconds;  // by render name, from times.tsv
};
// A fresh temporary directory for a run (`prefix` names it); sets run->skipped and returns false without one, or
// when `blender` is not on PATH.
bool PrepareBlender(const std::string& prefix, BlenderRun* run);
// Runs `blender -b --factory-startup -noaudio --python-exit-code 1 --python bench/cycles/SCRIPT -- ARGS
// --out DIR` (args quoted by the caller), its output in DIR/blender.log, then reads version.txt and times.tsv.
// The directory stays, with the log, when it fails; the caller removes it when done.
void RunBlender(const std::string& script, const std::string& args, BlenderRun* run);
// "NAME:SPP:SEED:RUNS" for the scripts' --renders list.
std::string RenderJob(const std::string& name, uint32_t spp, uint64_t seed, int runs);

}  // namespace loomlight::bench
