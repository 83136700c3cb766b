// Noise against time (issue 14): thumbnails at 1 to 64 samples per pixel through an in-process server, each
// timed, with its error against a converged reference of the same renderer, and the time to 30, 35 and 40 dB;
// and, when `blender` is on PATH, the cylinders scene rebuilt in Cycles (bench/cycles/cylinders.py) and measured
// the same way against its own converged image, side by side.
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "bench/bench.h"
#include "bench/cycles_compare.h"
#include "bench/in_process.h"
#include "bench/render_client.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/render/environment.h"

namespace loomlight::bench {
namespace {

constexpr const char* kSatin = "polyester_satin_charmeuse_front";
constexpr const char* kTwill = "cotton_twill";
constexpr double kTargetsDb[] = {30, 35, 40};
constexpr uint64_t kSeed = 1;  // the timed renders; the references' halves use others
// Cycles' sky map: twice the server's 512 x 256 each way, so that each server texel is exactly 2 x 2 of it.
constexpr int kSkyWidth = 1024;

struct NoiseScene {
  const char* name;  // for the report
  v1::ScenePreset scene;
  const char* preset;
  uint32_t side;
  uint32_t reference_spp;  // in two halves
};

struct NoiseSizes {
  std::vector<NoiseScene> scenes;
  std::vector<uint32_t> samples;  // per timed render
  uint32_t cycles_side, cycles_reference_spp;
  int runs;  // timed renders per point, the fastest counts
};

// Sized to about 10 minutes on 2 cores (the renderer of issue 14's start: about 1 us per pixel sample in
// Loomlight, 33 ms per 256 x 256 sample pass in Cycles). The references are the bulk: 2^26 pixel samples each,
// so 512 x 512 gets a quarter of 256 x 256's samples per pixel.
NoiseSizes SizesFor(const Sizes& sizes) {
  if (sizes.quick)
    return {{{"cylinders", v1::SCENE_CYLINDERS, kSatin, 48, 64}, {"sphere", v1::SCENE_SPHERE, kSatin, 32, 64}},
            {1, 4, 16},
            48,
            64,
            1};
  return {{{"cylinders", v1::SCENE_CYLINDERS, kSatin, 256, 1024},
           {"cylinders", v1::SCENE_CYLINDERS, kTwill, 256, 1024},
           {"sphere", v1::SCENE_SPHERE, kSatin, 256, 1024},
           {"cylinders", v1::SCENE_CYLINDERS, kSatin, 512, 256},
           {"cylinders", v1::SCENE_CYLINDERS, kTwill, 512, 256}},
          {1, 2, 4, 8, 16, 32, 64},
          256,
          1024,
          2};
}

std::string CurveName(const Curve& c) { return c.scene + ", " + c.material; }

// With LOOMLIGHT_NOISE_IMAGES=DIR set, each curve's reference and its 16-sample render are kept there as EXR,
// to look at (the two renderers' framing, the grain).
void KeepImage(const Curve& curve, const std::string& what, const std::vector<float>& image) {
  const char* dir = std::getenv("LOOMLIGHT_NOISE_IMAGES");
  if (!dir || !*dir) return;
  std::string name = curve.renderer + "-" + curve.scene + "-" + curve.material + "-" + Pixels(curve.side) + "-" + what;
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-') c = '_';
  if (std::string e = WriteExr(std::string(dir) + "/" + name + ".exr", image, int(curve.side), int(curve.side));
      !e.empty())
    Progress("noise: %s\n", e.c_str());
}

Curve LoomlightCurve(v1::Loomlight::Stub& stub, const NoiseScene& s, const NoiseSizes& n) {
  Curve curve{"Loomlight", s.name, s.preset, "", s.side, s.reference_spp, {}, {}};
  v1::RenderRequest request = SquareRequest(s.preset, s.scene, s.side, 0, 0);
  Progress("noise: %s %s %s, reference of 2 x %u samples per pixel\n", s.name, s.preset, Pixels(s.side).c_str(),
           s.reference_spp / 2);
  const std::vector<float> reference = FromHalves(MeanRender(stub, request, s.reference_spp / 2, 1000),
                                                  MeanRender(stub, request, s.reference_spp / 2, 2000),
                                                  &curve.reference_noise);
  request.set_seed(kSeed);
  for (uint32_t spp : n.samples) {
    Progress("noise: %s %s %s, %u samples per pixel\n", s.name, s.preset, Pixels(s.side).c_str(), spp);
    request.set_samples_per_pixel(spp);
    // The reference's calls warmed the server up for this material and scene (material cache, pilot).
    const RenderResult r = TimeRender(stub, request, n.runs, false);
    curve.Add(spp, r.last.total_seconds(), r.client_seconds, Compare(r.image, reference));
    curve.fidelity = ChosenSummary(r.last);
    if (spp == 16) KeepImage(curve, "16spp", r.image);
  }
  KeepImage(curve, "reference", reference);
  return curve;
}

// ---- Cycles ----

struct CyclesRun {
  BlenderRun blender;
  double sky_brightest = 0;
  Curve curve;
};

// Renders the cylinders in Cycles, the sweep and the reference's halves in one Blender process, and reads
// back its images and times. The temporary directory stays, with Blender's log, when something fails.
CyclesRun RunCycles(const NoiseSizes& n) {
  CyclesRun run;
  BlenderRun& b = run.blender;
  if (!PrepareBlender("loomlight-noise", &b)) return run;
  const std::string sky = (b.dir / "sky.exr").string();
  if (std::string e = WriteEnvironment(sky, render::Environment::Builtin(), kSkyWidth, &run.sky_brightest);
      !e.empty()) {
    b.skipped = e;
    return run;
  }
  std::string renders;  // NAME:SPP:SEED:RUNS,...
  for (uint32_t spp : n.samples) renders += RenderJob("spp" + std::to_string(spp), spp, kSeed, n.runs) + ",";
  const uint32_t half = n.cycles_reference_spp / 2;
  renders += RenderJob("half_a", half, 1001, 1) + "," + RenderJob("half_b", half, 1002, 1);
  Progress("noise: Cycles, cylinders %s, %zu sample counts and a reference of 2 x %u (log: %s)\n",
           Pixels(n.cycles_side).c_str(), n.samples.size(), half, b.log.c_str());
  RunBlender("cylinders.py",
             "--sky '" + sky + "' --size " + std::to_string(n.cycles_side) + " --threads 2 --renders " + renders, &b);
  if (!b.skipped.empty()) return run;

  const auto image = [&](const std::string& name) { return DecodeExr(ReadFile(b.dir / (name + ".exr"))); };
  Curve& curve = run.curve;
  curve = {"Cycles", "cylinders", "Principled BSDF (satin-like)", "", n.cycles_side, n.cycles_reference_spp, {}, {}};
  const std::vector<float> reference = FromHalves(image("half_a"), image("half_b"), &curve.reference_noise);
  for (uint32_t spp : n.samples) {
    const std::string name = "spp" + std::to_string(spp);
    const std::vector<float> render = image(name);
    if (!b.seconds.count(name) || render.empty() || reference.empty()) {
      b.skipped = "Blender wrote no " + name + " or no reference (its log: " + b.log + ")";
      return run;
    }
    curve.Add(spp, b.seconds[name], 0, Compare(render, reference));
    if (spp == 16) KeepImage(curve, "16spp", render);
  }
  KeepImage(curve, "reference", reference);
  std::filesystem::remove_all(b.dir);
  return run;
}

// ---- The report ----

// The figures: 256 x 256 and 512 x 512 cylinders at 40 dB within a time, and a third of Cycles' time.
std::string Targets(const std::vector<Curve>& curves, const CyclesRun& cycles) {
  const double cycles_40 = cycles.blender.skipped.empty() ? SecondsTo(cycles.curve, 40) : 0;
  std::string lines;
  for (const Curve& c : curves) {
    if (c.scene != "cylinders") continue;
    const double limit = c.side <= 256 ? 0.3 : 1.2, seconds = SecondsTo(c, 40);
    lines += "- " + CurveName(c) + " " + Pixels(c.side) + " at 40 dB in at most " + Fixed(limit, 1) + " s: " +
             (seconds > 0 ? Fixed(seconds, 3) + " s, " + (seconds <= limit ? "reached" : "not reached")
                          : "not reached within " + std::to_string(c.points.back().spp) + " samples per pixel");
    if (c.side == cycles.curve.side && cycles_40 > 0)
      lines += "; at most a third of Cycles' " + Fixed(cycles_40, 3) + " s: " +
               (seconds > 0 && seconds <= cycles_40 / 3 ? "reached" : "not reached");
    lines += ".\n";
  }
  return lines.empty() ? "" : "Targets (issue 14, server time, noise only):\n\n" + lines;
}

std::string Method(const NoiseSizes& n, const std::vector<Curve>& curves, const CyclesRun& cycles,
                   double loomlight_seconds) {
  std::string fidelity;
  for (const Curve& c : curves) fidelity += "; " + CurveName(c) + " " + Pixels(c.side) + ": " + c.fidelity;
  std::string method =
      "Loomlight: an in-process `LoomlightServer` (batching on) and one gRPC client; scenes `SCENE_CYLINDERS` and "
      "`SCENE_SPHERE` under their default lighting (the built-in sky with its sun), presets `" +
      std::string(kSatin) + "` (satin) and `" + kTwill +
      "` (twill), at the fidelity the server chooses, as a thumbnail gets it (" + fidelity.substr(2) +
      "), EXR output. Renders at " + std::to_string(n.samples.front()) + " to " + std::to_string(n.samples.back()) +
      " samples per pixel with seed " + std::to_string(kSeed) + ", the fastest of " + std::to_string(n.runs) +
      " calls after the reference's calls warmed the server up; time = the server's `total_seconds` in the last "
      "`RenderUpdate` (set-up, tracing, kernels, accumulation, encoding), client ms = the call as the client sees "
      "it. Each renderer is compared with its own converged image, the mean of two independent halves of the "
      "reference's samples (Loomlight: seeds 1000 and 2000 onward, several calls where one cannot hold them). "
      "rel. MSE = sum (x - ref)^2 / sum ref^2 over all pixels and channels; PSNR = 10 log10(peak^2 / MSE), peak = "
      "the reference's largest value. The reference's own noise is estimated as MSE(half a, half b) / 4 (reference "
      "PSNR); an image's MSE against the reference is its own plus that, so `own PSNR` takes it out: the image "
      "against the noise-free image, estimated (`>=`: within a quarter of the reference's own MSE, which cannot "
      "resolve it). Time to 30, 35, 40 dB (own PSNR): linear in PSNR against log time (and log samples) between "
      "the two measured sample counts around it; not reached: not within " +
      std::to_string(n.samples.back()) + " samples per pixel.\n\n";
  if (!cycles.blender.skipped.empty())
    return method + "Cycles: skipped: " + cycles.blender.skipped + ". This section took " +
           Fixed(loomlight_seconds, 0) + " s.";
  return method + "Cycles (Blender " + cycles.blender.version +
         ", `bench/cycles/cylinders.py`): the cylinders scene rebuilt, the three open tubes as 512-segment smooth "
         "meshes, the same camera, and the server's own sky written as a " +
         std::to_string(kSkyWidth) + " x " + std::to_string(kSkyWidth / 2) +
         " EXR from `Environment::Builtin()` (texel for texel the server's map; brightest texel, the sun, " +
         Fixed(cycles.sky_brightest, 0) +
         "), looked up closest and importance sampled at its resolution; the cloth a Principled BSDF of the satin's "
         "look (see the script). CPU, 2 threads, no denoiser, no adaptive sampling, direct light only (max "
         "bounces 0), a 1-pixel box filter, the default sampling pattern, seed " +
         std::to_string(kSeed) + "; reference halves with seeds 1001 and 1002. Time = the render operator's wall "
         "time inside Blender (scene sync, BVH, world map, sampling; not Blender's start-up nor the file write), "
         "the fastest of " +
         std::to_string(n.runs) + ". This section took " +
         Fixed(loomlight_seconds + cycles.blender.process_seconds, 0) +
         " s: Loomlight " + Fixed(loomlight_seconds, 0) + " s, the Blender process " +
         Fixed(cycles.blender.process_seconds, 0) + " s.";
}

}  // namespace

std::string NoiseSection(const Sizes& sizes) {
  const NoiseSizes n = SizesFor(sizes);
  std::vector<Curve> curves;
  const Clock::time_point start = Clock::now();
  {
    const std::unique_ptr<api::LoomlightServer> server = StartServer(true);
    const std::unique_ptr<v1::Loomlight::Stub> stub = Connect(server->port(), -1);
    for (const NoiseScene& s : n.scenes) curves.push_back(LoomlightCurve(*stub, s, n));
  }  // the server stops before Blender starts: the two never share the cores
  const double loomlight_seconds = SecondsSince(start);
  const CyclesRun cycles = RunCycles(n);
  std::vector<const Curve*> all;
  for (const Curve& c : curves) all.push_back(&c);
  if (cycles.blender.skipped.empty()) all.push_back(&cycles.curve);

  Table points({"renderer", "scene", "pixels", "samples/pixel", "time ms", "client ms", "rel. MSE", "PSNR dB",
                "own PSNR dB"},
               3);
  Table reach({"renderer", "scene", "pixels", "reference spp", "reference PSNR dB", "30 dB", "35 dB", "40 dB"}, 3);
  for (const Curve* c : all) {
    for (const Point& p : c->points)
      points.Add({c->renderer, CurveName(*c), Pixels(c->side), std::to_string(p.spp), Millis(p.seconds),
                  p.client_seconds > 0 ? Millis(p.client_seconds) : "-", Sci(p.error.relative_mse),
                  Fixed(p.error.psnr_db, 1), (p.own_is_floor ? ">= " : "") + Fixed(p.own_psnr_db, 1)});
    std::vector<std::string> row = {c->renderer, CurveName(*c), Pixels(c->side), std::to_string(c->reference_spp),
                                    Fixed(c->reference_noise.psnr_db, 1)};
    for (double db : kTargetsDb) row.push_back(ReachText(*c, db));
    reach.Add(row);
  }
  return Section("9. Noise against time", Method(n, curves, cycles, loomlight_seconds),
                 TableBlock("each render against its renderer's converged reference; time ms is the server's time "
                            "(Loomlight) or Cycles' render time, client ms the whole Loomlight call; own PSNR is "
                            "the image's noise alone (the reference's taken out).",
                            points) +
                     "\n" +
                     TableBlock("time (and samples per pixel) to reach each own PSNR, interpolated from the table "
                                "above; reference PSNR is the reference's own noise.",
                                reach) +
                     (sizes.quick ? "" : "\n" + Targets(curves, cycles)));
}

}  // namespace loomlight::bench
