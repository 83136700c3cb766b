// Product shots (issue 46): a garment mesh sent with the request, a woven material on its panels, on white under
// the studio preset, at catalogue size; Loomlight through an in-process server at increasing samples per pixel,
// each timed and compared with Loomlight's own converged image, and, when `blender` is on PATH, the same glTF
// through Blender's importer in Cycles (bench/cycles/product.py) under the same camera, softboxes and studio map,
// measured the same way against Cycles' own converged image; the time of each to 40 dB and their ratio.
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "bench/bench.h"
#include "bench/cycles_compare.h"
#include "bench/in_process.h"
#include "bench/render_client.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/assets/mesh_file.h"
#include "server/render/environment.h"
#include "server/render/lighting_presets.h"
#include "server/render/mesh_scene.h"
#include "server/render/renderer.h"

namespace loomlight::bench {
namespace {

constexpr const char* kMaterial = "cotton_twill";
constexpr const char* kLighting = "studio";
// The garment made for this benchmark when it is there, else the built-in drape over a stand.
constexpr const char* kMeshFiles[] = {"garment_bench.glb", "drape_stand.glb"};
constexpr double kTargetsDb[] = {30, 35, 40};
constexpr uint64_t kSeed = 1;  // the timed renders; the references' halves use others
// Cycles' studio map: twice the server's 256 x 128 each way, so that each server texel is exactly 2 x 2 of it.
constexpr int kEnvironmentWidth = 512;

struct ProductSizes {
  uint32_t side;
  std::vector<uint32_t> samples;  // per timed render, both renderers
  uint32_t reference_spp;         // Loomlight's, in two halves
  uint32_t cycles_reference_spp;  // Cycles', in two halves
  int runs;                       // timed renders per point, the fastest counts
};

// Sized to 6 to 11 minutes on 2 cores (as loaded by other processes): at 1600 x 1600 each renderer takes 2 to 3.5 s
// per sample per pixel here, more when loaded, and passes 40 dB at 3 to 6, so the ladder stops at 8 and the
// references are 2 x 24 samples per pixel (an 8-sample image's noise is still 6 times the reference's, which
// resolves it). One Loomlight call holds at most 2^26 samples (26 per pixel at 1600 x 1600): each half is one call.
ProductSizes SizesFor(const Sizes& sizes) {
  if (sizes.quick) return {160, {1, 4, 16}, 64, 64, 1};
  return {1600, {1, 2, 4, 8}, 48, 48, 2};
}

// The scene both renderers get: the mesh's bytes, and the camera and softboxes the benchmark places itself
// exactly as the server does for a mesh (render::SubjectOf, FramingCamera, PlaceLights), so Cycles can be
// given them.
struct ProductScene {
  std::string file_name;
  std::filesystem::path path;
  std::string bytes;
  assets::TriangleMesh mesh;
  render::CameraSpec camera;
  std::vector<render::Light> lights;
  double environment_intensity = 0;
};

// "" or what failed.
std::string LoadScene(uint32_t side, ProductScene* out) {
  const std::filesystem::path dir = std::string(LOOMLIGHT_SOURCE_DIR) + "/server/render/scenes/meshes";
  for (const char* name : kMeshFiles)
    if (std::filesystem::exists(dir / name)) {
      out->file_name = name;
      out->path = dir / name;
      break;
    }
  if (out->file_name.empty()) return "no product mesh in " + dir.string();
  out->bytes = ReadFile(out->path);
  if (std::string e = assets::ParseMesh(out->bytes, v1::MESH_FORMAT_GLB, assets::MeshLimits{}, &out->mesh);
      !e.empty())
    return out->file_name + ": " + e;
  const render::LightingPreset* preset = render::FindLightingPreset(kLighting);
  if (!preset) return std::string("no lighting preset ") + kLighting;
  const render::Subject subject = render::SubjectOf(out->mesh);
  out->camera = render::FramingCamera(out->mesh, int(side), int(side));
  out->lights = render::PlaceLights(*preset, subject.centre, subject.radius, out->camera);
  out->environment_intensity = preset->environment_intensity;
  return "";
}

v1::RenderRequest ProductRequest(const ProductScene& scene, uint32_t side, uint32_t spp, uint64_t seed,
                                 v1::RenderFormat format) {
  v1::RenderRequest r;
  r.mutable_mesh()->mutable_data()->set_format(v1::MESH_FORMAT_GLB);
  r.mutable_mesh()->mutable_data()->set_data(scene.bytes);
  r.mutable_material()->set_preset(kMaterial);  // for triangles of no named material
  for (const std::string& name : scene.mesh.material_names) {
    if (name.empty()) continue;
    v1::MaterialBinding* binding = r.add_materials();
    binding->set_mesh_material(name);
    binding->mutable_material()->set_preset(kMaterial);
  }
  r.set_background(v1::BACKGROUND_WHITE);
  r.set_lighting(kLighting);
  v1::RenderCamera* camera = r.mutable_camera();
  const auto set = [](google::protobuf::RepeatedField<double>* field, render::Vec3 v) {
    field->Add(v.x);
    field->Add(v.y);
    field->Add(v.z);
  };
  set(camera->mutable_position(), scene.camera.position);
  set(camera->mutable_look_at(), scene.camera.look_at);
  set(camera->mutable_up(), scene.camera.up);
  camera->set_fov_deg(scene.camera.fov_deg);
  r.set_width(side);
  r.set_height(side);
  r.set_samples_per_pixel(spp);
  r.set_seed(seed);
  r.set_format(format);
  return r;
}

// With LOOMLIGHT_PRODUCT_IMAGES=DIR set, the references (EXR, linear over white) and the looks (PNG) are kept
// there; "" when unset.
std::string ImageDir() {
  const char* dir = std::getenv("LOOMLIGHT_PRODUCT_IMAGES");
  return dir && *dir ? dir : "";
}

void KeepFile(const std::string& name, const std::string& bytes) {
  if (ImageDir().empty()) return;
  std::ofstream out(ImageDir() + "/" + name, std::ios::binary);
  out << bytes;
  if (!out) Progress("product: cannot write %s/%s\n", ImageDir().c_str(), name.c_str());
}

void KeepExr(const std::string& name, const std::vector<float>& rgb, uint32_t side) {
  if (ImageDir().empty()) return;
  if (std::string e = WriteExr(ImageDir() + "/" + name, rgb, int(side), int(side)); !e.empty())
    Progress("product: %s\n", e.c_str());
}

// The mean linear value of the product's pixels (those not exactly the white background), over channels: the
// two renderers' brightness.
double ProductMean(const std::vector<float>& over_white) {
  double sum = 0;
  size_t n = 0;
  for (size_t i = 0; i + 2 < over_white.size(); i += 3) {
    if (over_white[i] == 1 && over_white[i + 1] == 1 && over_white[i + 2] == 1) continue;
    sum += over_white[i] + over_white[i + 1] + over_white[i + 2];
    n += 3;
  }
  return n ? sum / double(n) : 0;
}

double Peak(const std::vector<float>& image) {
  return image.empty() ? 0 : *std::max_element(image.begin(), image.end());
}

struct Breakdown {
  double setup = 0, kernel = 0, total = 0;
};

struct LoomlightRun {
  Curve curve;
  std::vector<Breakdown> breakdown;  // per point
  std::string rungs;                 // the top point's rung shares
  double fill = 0, exposure = 0;     // the PNG's
  double reference_peak = 0, reference_mean = 0;
};

std::string RungText(const v1::RenderUpdate& update) {
  std::string out;
  for (const v1::RungShare& r : update.rungs())
    out += (out.empty() ? "" : ", ") + r.rung() + " " + Fixed(100 * r.share(), 0) + "%";
  return out.empty() ? "-" : out;
}

LoomlightRun RunLoomlight(const ProductScene& scene, const ProductSizes& n) {
  LoomlightRun run;
  Curve& curve = run.curve;
  curve = {"Loomlight", scene.file_name, kMaterial, "", n.side, n.reference_spp, {}, {}};
  const std::unique_ptr<api::LoomlightServer> server = StartServer(true);
  const std::unique_ptr<v1::Loomlight::Stub> stub = Connect(server->port(), -1);
  v1::RenderRequest request = ProductRequest(scene, n.side, 0, 0, v1::RENDER_FORMAT_EXR);
  Progress("product: Loomlight %s %s, reference of 2 x %u samples per pixel\n", scene.file_name.c_str(),
           Pixels(n.side).c_str(), n.reference_spp / 2);
  const std::vector<float> reference = FromHalves(MeanRender(*stub, request, n.reference_spp / 2, 1000),
                                                  MeanRender(*stub, request, n.reference_spp / 2, 2000),
                                                  &curve.reference_noise);
  run.reference_peak = Peak(reference);
  run.reference_mean = ProductMean(reference);
  KeepExr("loomlight-reference.exr", reference, n.side);
  request.set_seed(kSeed);
  for (uint32_t spp : n.samples) {
    Progress("product: Loomlight, %u samples per pixel\n", spp);
    request.set_samples_per_pixel(spp);
    // The reference's calls warmed the server up for this material and mesh (material cache, pilot).
    const RenderResult r = TimeRender(*stub, request, n.runs, false);
    curve.Add(spp, r.client_seconds, r.client_seconds, Compare(r.image, reference));
    run.breakdown.push_back({r.last.setup_seconds(), r.last.kernel_seconds(), r.last.total_seconds()});
    curve.fidelity = ChosenSummary(r.last);
    run.rungs = RungText(r.last);
  }
  // The look: the top point's samples as the catalogue PNG, the server's automatic exposure.
  v1::RenderRequest png = ProductRequest(scene, n.side, n.samples.back(), kSeed, v1::RENDER_FORMAT_PNG);
  const RenderResult look = RenderOnce(*stub, png);
  run.exposure = look.last.exposure();
  run.fill = look.last.fill();
  KeepFile("loomlight.png", look.last.image());
  return run;
}

// ---- Cycles ----

struct CyclesRun {
  BlenderRun blender;
  Curve curve;
  double import_seconds = 0;
  uint64_t imported_triangles = 0;
  double reference_peak = 0, reference_mean = 0;
};

// Cycles' RGBA (premultiplied, transparent film) over white as Loomlight's BACKGROUND_WHITE EXR is: the
// radiance plus (1 - coverage). The premultiplied RGB and the coverage go to *rgb and *alpha when not null.
std::vector<float> OverWhite(const std::vector<float>& rgba, std::vector<float>* rgb, std::vector<float>* alpha) {
  std::vector<float> out(rgba.size() / 4 * 3);
  for (size_t p = 0; p < rgba.size() / 4; ++p) {
    const float a = rgba[4 * p + 3];
    for (int c = 0; c < 3; ++c) out[3 * p + c] = rgba[4 * p + c] + (1 - a);
    if (alpha) alpha->push_back(a);
    if (rgb)
      for (int c = 0; c < 3; ++c) rgb->push_back(rgba[4 * p + c]);
  }
  return out;
}

std::string LightsTsv(const ProductScene& scene) {
  std::ostringstream out;
  out.precision(9);
  for (const render::Light& l : scene.lights)
    out << l.position.x << ' ' << l.position.y << ' ' << l.position.z << ' ' << l.direction.x << ' '
        << l.direction.y << ' ' << l.direction.z << ' ' << l.axis_v.x << ' ' << l.axis_v.y << ' ' << l.axis_v.z
        << ' ' << l.width << ' ' << l.height << ' ' << l.rgb[0] << ' ' << l.rgb[1] << ' ' << l.rgb[2] << '\n';
  return out.str();
}

std::string CameraArg(const render::CameraSpec& c) {
  std::ostringstream out;
  out.precision(9);
  out << c.position.x << ',' << c.position.y << ',' << c.position.z << ',' << c.look_at.x << ',' << c.look_at.y
      << ',' << c.look_at.z << ',' << c.up.x << ',' << c.up.y << ',' << c.up.z << ',' << c.fov_deg;
  return out.str();
}

// Renders the mesh in Cycles, the sweep and the reference's halves in one Blender process, and reads back its
// images and times. The look is encoded by the server's own PNG path at Loomlight's exposure, so the two PNGs
// differ only by the renderers. The temporary directory stays, with Blender's log, when something fails.
CyclesRun RunCycles(const ProductScene& scene, const ProductSizes& n, double exposure) {
  CyclesRun run;
  BlenderRun& b = run.blender;
  if (!PrepareBlender("loomlight-product", &b)) return run;
  render::Environment studio = render::Environment::Studio();
  studio.SetTransform(scene.environment_intensity, 0);
  const std::string environment = (b.dir / "studio.exr").string(), lights = (b.dir / "lights.tsv").string();
  double brightest = 0;
  if (std::string e = WriteEnvironment(environment, studio, kEnvironmentWidth, &brightest); !e.empty()) {
    b.skipped = e;
    return run;
  }
  std::ofstream(lights) << LightsTsv(scene);
  std::string renders;
  for (uint32_t spp : n.samples) renders += RenderJob("spp" + std::to_string(spp), spp, kSeed, n.runs) + ",";
  const uint32_t half = n.cycles_reference_spp / 2;
  renders += RenderJob("half_a", half, 1001, 1) + "," + RenderJob("half_b", half, 1002, 1);
  Progress("product: Cycles %s %s, %zu sample counts and a reference of 2 x %u (log: %s)\n", scene.file_name.c_str(),
           Pixels(n.side).c_str(), n.samples.size(), half, b.log.c_str());
  RunBlender("product.py",
             "--mesh '" + scene.path.string() + "' --environment '" + environment + "' --camera=" +
                 CameraArg(scene.camera) + " --lights '" + lights + "' --size " + std::to_string(n.side) +
                 " --threads 2 --renders " + renders,
             &b);
  if (!b.skipped.empty()) return run;
  std::istringstream(ReadFile(b.dir / "import.txt")) >> run.import_seconds >> run.imported_triangles;

  const auto rgba = [&](const std::string& name) { return DecodeExr(ReadFile(b.dir / (name + ".exr")), 4); };
  Curve& curve = run.curve;
  curve = {"Cycles", scene.file_name, "Principled BSDF (dark cotton, sheen)", "", n.side, n.cycles_reference_spp,
           {}, {}};
  std::vector<float> rgb_a, alpha_a, rgb_b, alpha_b;
  const std::vector<float> reference = FromHalves(OverWhite(rgba("half_a"), &rgb_a, &alpha_a),
                                                  OverWhite(rgba("half_b"), &rgb_b, &alpha_b), &curve.reference_noise);
  if (reference.empty()) {
    b.skipped = "Blender wrote no reference (its log: " + b.log + ")";
    return run;
  }
  run.reference_peak = Peak(reference);
  run.reference_mean = ProductMean(reference);
  for (uint32_t spp : n.samples) {
    const std::string name = "spp" + std::to_string(spp);
    const std::vector<float> image = OverWhite(rgba(name), nullptr, nullptr);
    if (!b.seconds.count(name) || image.empty()) {
      b.skipped = "Blender wrote no " + name + " (its log: " + b.log + ")";
      return run;
    }
    curve.Add(spp, b.seconds[name], 0, Compare(image, reference));
  }
  KeepExr("cycles-reference.exr", reference, n.side);
  if (!ImageDir().empty()) {
    // The reference's premultiplied radiance and coverage through the server's PNG encoding.
    imaging::LinearRgbImage premultiplied{int(n.side), int(n.side), std::vector<float>(rgb_a.size())};
    std::vector<float> coverage(alpha_a.size());
    for (size_t i = 0; i < rgb_a.size() && i < rgb_b.size(); ++i) premultiplied.rgb[i] = 0.5f * (rgb_a[i] + rgb_b[i]);
    for (size_t i = 0; i < alpha_a.size() && i < alpha_b.size(); ++i) coverage[i] = 0.5f * (alpha_a[i] + alpha_b[i]);
    std::string png;
    double used = 0;
    if (std::string e = render::EncodeRendered(premultiplied, &coverage, imaging::Background::kWhite,
                                               imaging::ImageFormat::kPng, exposure, &png, &used);
        !e.empty())
      Progress("product: cannot encode Cycles' PNG: %s\n", e.c_str());
    KeepFile("cycles.png", png);
  }
  std::filesystem::remove_all(b.dir);
  return run;
}

// ---- The report ----

std::string Method(const ProductScene& scene, const ProductSizes& n, const LoomlightRun& loomlight,
                   const CyclesRun& cycles, double loomlight_seconds) {
  std::string lights;
  for (const render::Light& l : scene.lights)
    lights += (lights.empty() ? "" : ", ") + Fixed(l.width, 2) + " x " + Fixed(l.height, 2) + " at radiance " +
              Fixed(l.rgb[0], 1);
  const auto point = [](render::Vec3 v) {
    return "(" + Fixed(v.x, 3) + ", " + Fixed(v.y, 3) + ", " + Fixed(v.z, 3) + ")";
  };
  std::string method =
      "The mesh: `server/render/scenes/meshes/" + scene.file_name + "` (" + Count(scene.mesh.triangles.size()) +
      " triangles, " + std::to_string(scene.mesh.material_names.size()) + " material(s))" +
      (scene.file_name == kMeshFiles[0] ? "" : std::string(" (`") + kMeshFiles[0] + "` was not there)") +
      ", its bytes sent with every request (`RenderRequest.mesh.data`: each call parses it and builds its BVH). "
      "Loomlight: an in-process `LoomlightServer` (batching on) and one gRPC client; every mesh material bound to `" +
      kMaterial + "` (`RenderRequest.materials`), the default texture scale, `BACKGROUND_WHITE`, lighting `" +
      kLighting + "` (softboxes " + lights + ", and the studio map at intensity " +
      Fixed(scene.environment_intensity, 1) + "), the camera given explicitly as the server would frame the mesh (" +
      point(scene.camera.position) + " looking at " + point(scene.camera.look_at) + ", vertical fov " +
      Fixed(scene.camera.fov_deg, 0) + " degrees), " + Pixels(n.side) +
      ", EXR (linear, over white: radiance + 1 - coverage), the fidelity the server chooses (" +
      loomlight.curve.fidelity + "; rungs at the top point: " + loomlight.rungs +
      "). Renders at " + std::to_string(n.samples.front()) + " to " + std::to_string(n.samples.back()) +
      " samples per pixel with seed " + std::to_string(kSeed) + ", the fastest of " + std::to_string(n.runs) +
      " call(s) after the reference's calls warmed the server up; time = the call as the client sees it (wall), "
      "beside the server's `setup_seconds`, `kernel_seconds` and `total_seconds` from the last `RenderUpdate`. "
      "Each renderer is compared with its own converged image, the mean of two independent halves of the "
      "reference's samples (Loomlight: " + std::to_string(n.reference_spp) +
      " samples per pixel, seeds 1000 and 2000 onward, several calls where one cannot hold them; Cycles: " +
      std::to_string(n.cycles_reference_spp) +
      "). PSNR is on the linear image over white (both renderers alike): 10 log10(peak^2 / MSE) over all pixels and "
      "channels, white background included, peak = the reference's largest value; rel. MSE = sum (x - ref)^2 / "
      "sum ref^2. The reference's own noise is estimated as MSE(half a, half b) / 4; `own PSNR` takes it out "
      "(`>=`: within a quarter of the reference's own MSE, which cannot resolve it). Time to 30, 35, 40 dB (own "
      "PSNR): linear in PSNR against log time between the two measured sample counts around it.\n\n";
  if (!cycles.blender.skipped.empty())
    return method + "Cycles: skipped: " + cycles.blender.skipped + ". This section took " +
           Fixed(loomlight_seconds, 0) + " s.";
  return method + "Cycles (Blender " + cycles.blender.version +
         ", `bench/cycles/product.py`): the same `.glb` through Blender's glTF importer (" +
         Count(cycles.imported_triangles) + " triangles imported in " + Fixed(cycles.import_seconds, 2) +
         " s, not counted), the same camera (vertical sensor fit), the same softboxes as rectangular area lights "
         "(same centres, sizes, facing and radiance: power = 4 x area x radiance, Cycles' convention), invisible "
         "to the camera, and the same studio map written from `Environment::Studio()` as a " +
         std::to_string(kEnvironmentWidth) + " x " + std::to_string(kEnvironmentWidth / 2) +
         " EXR; a transparent film put over white as Loomlight's EXR is; the cloth a Principled BSDF of about the "
         "twill's look (see the script). CPU, 2 threads, no denoiser, no adaptive sampling, direct light only "
         "(max bounces 0, as Loomlight shades), a 1-pixel box filter, seed " +
         std::to_string(kSeed) + "; reference halves with seeds 1001 and 1002. Time = the render operator's wall "
         "time inside Blender (scene sync, BVH, world map, sampling; not Blender's start-up, the import nor the "
         "file write), the fastest of " +
         std::to_string(n.runs) + ". This section took " +
         Fixed(loomlight_seconds + cycles.blender.process_seconds, 0) + " s: Loomlight " + Fixed(loomlight_seconds, 0) +
         " s, the Blender process " + Fixed(cycles.blender.process_seconds, 0) + " s.";
}

std::string Targets(const LoomlightRun& loomlight, const CyclesRun& cycles, const ProductSizes& n) {
  const double seconds = SecondsTo(loomlight.curve, 40);
  const double cycles_40 = cycles.blender.skipped.empty() ? SecondsTo(cycles.curve, 40) : 0;
  std::string out = "Targets (issue 46, client wall time, noise only):\n\n- " + Pixels(n.side) +
                    " at 40 dB in at most 3 s: " +
                    (seconds > 0 ? Fixed(seconds, 3) + " s, " + (seconds <= 3 ? "reached" : "not reached")
                                 : "not reached within " + std::to_string(n.samples.back()) + " samples per pixel") +
                    ".\n";
  if (cycles_40 > 0)
    out += "- At most a quarter of Cycles' time to 40 dB (" + Fixed(cycles_40, 3) + " s): " +
           (seconds > 0 ? "Loomlight takes " + Fixed(seconds / cycles_40, 3) + " of it, " +
                              (seconds <= cycles_40 / 4 ? "reached" : "not reached")
                        : "not reached") +
           ".\n";
  else if (cycles.blender.skipped.empty())
    out += "- Against Cycles: Cycles did not reach 40 dB within " + std::to_string(n.samples.back()) +
           " samples per pixel, so the ratio is not measured.\n";
  return out;
}

}  // namespace

std::string ProductSection(const Sizes& sizes) {
  const ProductSizes n = SizesFor(sizes);
  ProductScene scene;
  if (std::string e = LoadScene(n.side, &scene); !e.empty())
    return Section("12. Product shots", "Not run: " + e + ".", "");
  const Clock::time_point start = Clock::now();
  const LoomlightRun loomlight = RunLoomlight(scene, n);  // its server stops before Blender starts
  const double loomlight_seconds = SecondsSince(start);
  const CyclesRun cycles = RunCycles(scene, n, loomlight.exposure);
  const bool with_cycles = cycles.blender.skipped.empty();

  Table points({"renderer", "samples/pixel", "time s", "server setup s", "server kernel s", "server total s",
                "rel. MSE", "PSNR dB", "own PSNR dB"},
               1);
  const auto add_points = [&points](const Curve& c, const std::vector<Breakdown>* breakdown) {
    for (size_t i = 0; i < c.points.size(); ++i) {
      const Point& p = c.points[i];
      const bool server = breakdown && i < breakdown->size();
      points.Add({c.renderer, std::to_string(p.spp), Fixed(p.seconds, 3),
                  server ? Fixed((*breakdown)[i].setup, 3) : "-", server ? Fixed((*breakdown)[i].kernel, 3) : "-",
                  server ? Fixed((*breakdown)[i].total, 3) : "-", Sci(p.error.relative_mse), Fixed(p.error.psnr_db, 1),
                  (p.own_is_floor ? ">= " : "") + Fixed(p.own_psnr_db, 1)});
    }
  };
  add_points(loomlight.curve, &loomlight.breakdown);
  if (with_cycles) add_points(cycles.curve, nullptr);

  Table reach({"renderer", "reference spp", "reference peak", "product mean", "reference PSNR dB", "30 dB", "35 dB",
               "40 dB"},
              1);
  const auto add_reach = [&reach](const Curve& c, double peak, double mean) {
    std::vector<std::string> row = {c.renderer, std::to_string(c.reference_spp), Fixed(peak, 2), Fixed(mean, 3),
                                    Fixed(c.reference_noise.psnr_db, 1)};
    for (double db : kTargetsDb) row.push_back(ReachText(c, db));
    reach.Add(row);
  };
  add_reach(loomlight.curve, loomlight.reference_peak, loomlight.reference_mean);
  if (with_cycles) add_reach(cycles.curve, cycles.reference_peak, cycles.reference_mean);

  const std::string look =
      "The look (`LOOMLIGHT_PRODUCT_IMAGES=DIR` keeps `loomlight.png`, the server's PNG at " +
      std::to_string(n.samples.back()) + " samples per pixel, automatic exposure " + Fixed(loomlight.exposure, 2) +
      ", fill " + Fixed(100 * loomlight.fill, 1) +
      "%; `cycles.png`, Cycles' reference through the server's PNG encoding at that exposure; and both references "
      "as EXR).\n";
  return Section("12. Product shots", Method(scene, n, loomlight, cycles, loomlight_seconds),
                 TableBlock("each render against its renderer's converged reference; time s is the whole Loomlight "
                            "call as the client sees it, or Cycles' render operator; the server's breakdown beside "
                            "Loomlight's; own PSNR is the image's noise alone (the reference's taken out).",
                            points) +
                     "\n" +
                     TableBlock("time (and samples per pixel) to reach each own PSNR, interpolated from the table "
                                "above; reference peak is the PSNR's peak, product mean the mean linear value of the "
                                "product's pixels (brightness), reference PSNR the reference's own noise.",
                                reach) +
                     "\n" + look + (sizes.quick ? "" : "\n" + Targets(loomlight, cycles, n)));
}

}  // namespace loomlight::bench
