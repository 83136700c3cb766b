// Materials out (issue 48's figures): every surface preset fitted to both standard lobes (server/models/fit/
// lobe_fit.h: the glTF sheen model `gltf_sheen` and OpenPBR's fuzz `openpbr`), with the fit's error, time,
// iterations and worst region, the source's reference on the fit's pairs as the baseline and its anisotropy (what
// an isotropic lobe cannot follow); and for three presets a side-by-side on the sphere scene: Loomlight's render of
// the preset, Loomlight's render of its gltf_sheen fit, and the fit written as glTF (server/export/gltf_export.h)
// imported into Blender and rendered by Cycles (bench/cycles/gltf_fit.py) under the same camera and sky, with
// the image differences that separate the fit's error from the viewer's.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "bench/bench.h"
#include "bench/cycles_compare.h"
#include "bench/in_process.h"
#include "bench/render_client.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/export/gltf_export.h"
#include "server/models/fit/lobe_fit.h"
#include "server/models/registry.h"
#include "server/render/environment.h"
#include "server/render/renderer.h"
#include "server/render/scene.h"

namespace loomlight::bench {
namespace {

namespace fit = models::fit;

constexpr const char* kTargets[] = {"gltf_sheen", "openpbr"};
// The side-by-side: a microcylinder silk, a woven cotton and the microcylinder velvet.
constexpr const char* kPictured[] = {"silk_shot", "cotton_twill", "velvet"};
// Rotations about the normal averaged into a source's azimuthal mean (its anisotropy, below).
constexpr int kAzimuthRotations = 16;
// Cycles' sky map: twice the server's 512 x 256 each way, so that each server texel is exactly 2 x 2 of it (as
// the noise section writes it).
constexpr int kSkyWidth = 1024;
constexpr uint64_t kSeed = 1;

struct MaterialsOutSizes {
  int runs;                // timed reference evaluations, the fastest counts
  uint32_t side;           // the pictures' pixels per side
  uint32_t loomlight_spp;  // Loomlight's samples per pixel (the mean of several calls where one cannot hold them)
  uint32_t cycles_spp;
};

// Sized to 2 to 4 minutes on 2 cores: 36 fits of 0.2 to 2 s, and the pictures about a minute in each renderer.
// 64 and 256 samples per pixel put both renderers' noise on the sphere near 55 dB (bench/report-noise.md), far
// below the differences between them.
MaterialsOutSizes SizesFor(const Sizes& sizes) {
  if (sizes.quick) return {1, 64, 4, 16};
  return {3, 256, 64, 256};
}

// ---- The fits ----

struct Source {
  const models::Model* model = nullptr;
  std::string preset;
  models::ParamValues values;
  bool sanity = false;  // a preset of a target model itself
};

struct FitRow {
  std::string target;
  fit::FitResult result;
  double evaluation_seconds = 0;  // one MeasureFit of the target on every pair: what one error evaluation costs
};

struct SourceFits {
  Source source;
  double reference_seconds = 0;  // one ReferenceOnFitDirections of the source
  double anisotropy = 0;         // relative L1 of f cos between f and its azimuthal mean
  std::vector<FitRow> fits;
  std::string failed;  // why the source could not be fitted, or ""
};

// Every preset of every registered surface model; why the others are left out.
std::vector<Source> Sources(std::vector<std::string>* skipped) {
  std::vector<Source> out;
  for (const auto& model : models::Registry::Global().models()) {
    if (!model->fiber_axis_param().empty()) {
      skipped->push_back("`" + model->name() + "` (a fiber model: its f is about a fibre's axis, not a surface's "
                         "normal, and the standard lobes are surface lobes)");
      continue;
    }
    const bool target = std::find(std::begin(kTargets), std::end(kTargets), model->name()) != std::end(kTargets);
    for (const models::PresetSpec& preset : model->presets()) {
      models::ParamValues values = model->PresetValues(preset);
      if (std::string e = model->Validate(values); !e.empty()) {
        skipped->push_back("`" + preset.name + "` (" + model->name() + ": " + e + ")");
        continue;
      }
      out.push_back({model.get(), preset.name, std::move(values), target});
    }
  }
  return out;
}

// The fit's pairs rotated by `angle` about the normal (both directions alike).
void RotatedPairs(double angle, std::vector<float>* wi, std::vector<float>* wo) {
  const fit::FitDirectionSet& d = fit::FitDirections();
  const double c = std::cos(angle), s = std::sin(angle);
  wi->resize(d.wi.size());
  wo->resize(d.wo.size());
  for (size_t k = 0; k < d.size(); ++k)
    for (const auto& [from, to] : {std::pair{&d.wi, wi}, std::pair{&d.wo, wo}}) {
      const double x = (*from)[3 * k], y = (*from)[3 * k + 1];
      (*to)[3 * k] = float(c * x - s * y);
      (*to)[3 * k + 1] = float(s * x + c * y);
      (*to)[3 * k + 2] = (*from)[3 * k + 2];
    }
}

// How far f is from isotropic, in the fit's own error: sum |f_iso - f| / sum |f| over the fit's pairs and channels,
// f_iso the mean of f over kAzimuthRotations rotations of each pair about the normal. An isotropic lobe (both
// targets are) sees only f_iso's part of the source: this is about what it must miss, whatever its parameters.
double Anisotropy(const models::Model& model, const models::PackedMaterial& material, const std::vector<double>& f) {
  const size_t n = fit::FitDirections().size();
  std::vector<double> mean(f.size(), 0.0), rotated(f.size());
  std::vector<float> wi, wo;
  for (int r = 0; r < kAzimuthRotations; ++r) {
    RotatedPairs(2 * std::numbers::pi * r / kAzimuthRotations, &wi, &wo);
    model.ReferenceEval(material, wi.data(), wo.data(), nullptr, n, rotated.data());
    for (size_t i = 0; i < f.size(); ++i) mean[i] += (std::isfinite(rotated[i]) ? rotated[i] : 0.0) / kAzimuthRotations;
  }
  double diff = 0, total = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    const double v = std::isfinite(f[i]) ? f[i] : 0.0;
    diff += std::abs(mean[i] - v);
    total += std::abs(v);
  }
  return total > 0 ? diff / total : 0;
}

SourceFits FitSource(const Source& source, const std::vector<const models::Model*>& targets, int runs) {
  SourceFits out;
  out.source = source;
  try {
    const models::PackedMaterial packed = source.model->Pack(source.values);
    std::vector<double> f;
    out.reference_seconds = BestOf(runs, [&] { f = fit::ReferenceOnFitDirections(*source.model, packed); });
    out.anisotropy = Anisotropy(*source.model, packed, f);
    for (const models::Model* target : targets) {
      Progress("materials-out: %s to %s\n", source.preset.c_str(), target->name().c_str());
      FitRow row{target->name(), fit::FitLobe(*target, f), 0};
      row.evaluation_seconds = BestOf(runs, [&] { fit::MeasureFit(*target, row.result.params, f); });
      out.fits.push_back(std::move(row));
    }
  } catch (const std::exception& e) {
    out.failed = e.what();
  }
  return out;
}

// "grazing view (75-90 deg), back-scatter" from a region's full name (FitRegionNames: "ELEVATION, AZIMUTH"): the
// elevation with its range (its name alone is vague), the azimuth's name without its explanation.
std::string ShortRegion(const std::string& region) {
  const size_t comma = region.find(", ");
  if (comma == std::string::npos) return region;
  const std::string azimuth = region.substr(comma + 2);
  return region.substr(0, comma + 2) + azimuth.substr(0, azimuth.find(" ("));
}

const fit::RegionError* LargestShare(const fit::FitResult& r) {
  const fit::RegionError* best = nullptr;
  for (const fit::RegionError& region : r.regions)
    if (!best || region.share > best->share) best = &region;
  return best;
}

std::string Percent(double x) { return Fixed(100 * x, 1) + "%"; }

// Why a model's materials are hard for the standard lobes: what its source says its reflection is.
std::string ModelExplanation(const std::string& model) {
  if (model == "microcylinder")
    return "Sadeghi et al.'s microcylinder model reflects each thread's specular along a cone about the thread's "
           "tangent, summed over the samples of its tangent curve, which tilts the tangent out of the cloth "
           "(`kernels/models/microcylinder.h`): a band of highlight whose place turns with the pair's azimuth "
           "relative to the threads, two thread directions with their own colours and curves. The glTF sheen and "
           "OpenPBR fuzz lobes (and their GGX or Lambertian bases) are isotropic: they depend on the pair only "
           "through its angles to the normal and to each other, so the band's turning with azimuth is what no "
           "parameter of theirs can follow";
  if (model == "woven")
    return "Irawan and Marschner's woven model reflects elliptical highlights along each thread segment the weave "
           "leaves visible (`kernels/models/woven.h`): anisotropic, its highlight's place set by the warp and weft "
           "directions, which an isotropic lobe cannot follow";
  if (model == "thin_layer")
    return "Frisvad et al.'s thin layer reflects by scattering inside a slab (`kernels/models/thin_layer.h`): no "
           "specular peak, a reflection that rises toward grazing angles as the path in the slab lengthens, a shape "
           "neither a Lambertian base nor a sheen lobe has";
  if (model == "btf")
    return "a BTF asset's BRDF is the mean of its measured or synthesised images, interpolated between 4 light and "
           "4 view directions: a tabulated shape no analytic lobe is built to match";
  return "";
}

// " Its tangent curves: thread1 from -90 to -50 degrees, ..." for a microcylinder material, else "".
std::string TangentCurves(const models::ParamValues& values) {
  std::string out;
  for (const char* thread : {"thread1", "thread2"}) {
    const auto offsets = values.find(std::string(thread) + ".tangent_offsets");
    if (offsets == values.end() || offsets->second.empty()) return "";
    const auto [low, high] = std::minmax_element(offsets->second.begin(), offsets->second.end());
    out += (out.empty() ? "" : ", ") + std::string(thread) + " from " + Fixed(*low, 0) + " to " + Fixed(*high, 0);
  }
  return " Its tangent curves (offsets out of the cloth): " + out + " degrees.";
}

// ---- The pictures ----

struct Picture {
  std::string preset;
  const fit::FitResult* sheen = nullptr;     // the gltf_sheen fit
  std::vector<float> source, fitted, cycles;  // linear RGB renders, rows from the top
  double source_seconds = 0, fitted_seconds = 0, cycles_seconds = 0;
  std::string cycles_nodes;  // what Cycles rendered: the imported shader nodes
  std::string glb_error;
};

// The pixels wholly on the sphere (all four corners' rays hit it: no sky blended in), and of those the ones facing
// the camera (the normal at the pixel centre within 60 degrees of the view) and the rim (the rest): a sheen lobe's
// shape shows as how it divides its light between them.
struct SphereRegions {
  std::vector<size_t> all, facing, rim;
};
constexpr double kFacingCos = 0.5;

SphereRegions SpherePixels(const render::CameraSpec& spec, double radius, uint32_t side) {
  const render::PinholeCamera camera(spec, int(side), int(side));
  const render::Vec3 o = camera.position();
  // The cosine between the normal and the view where the ray through (px, py) meets the sphere, or -1 on a miss.
  const auto view_cos = [&](double px, double py) {
    const render::Vec3 d = camera.Direction(px, py);
    const double b = render::Dot(o, d), c = render::Dot(o, o) - radius * radius, disc = b * b - c;
    if (disc <= 0 || b >= 0) return -1.0;
    const render::Vec3 hit = o + (-b - std::sqrt(disc)) * d;
    return -render::Dot(hit, d) / radius;
  };
  SphereRegions regions;
  for (uint32_t y = 0; y < side; ++y)
    for (uint32_t x = 0; x < side; ++x) {
      if (view_cos(x, y) < 0 || view_cos(x + 1, y) < 0 || view_cos(x, y + 1) < 0 || view_cos(x + 1, y + 1) < 0)
        continue;
      const size_t pixel = size_t(y) * side + x;
      regions.all.push_back(pixel);
      (view_cos(x + 0.5, y + 0.5) >= kFacingCos ? regions.facing : regions.rim).push_back(pixel);
    }
  return regions;
}

std::vector<float> Masked(const std::vector<float>& image, const std::vector<size_t>& pixels) {
  std::vector<float> out;
  if (image.empty()) return out;
  out.reserve(3 * pixels.size());
  for (size_t p : pixels)
    for (int c = 0; c < 3; ++c) out.push_back(image[3 * p + c]);
  return out;
}

// sum |image - reference| / sum reference: the mean relative difference.
double MeanAbsoluteDifference(const std::vector<float>& image, const std::vector<float>& reference) {
  double diff = 0, total = 0;
  for (size_t i = 0; i < image.size() && i < reference.size(); ++i) {
    diff += std::abs(double(image[i]) - reference[i]);
    total += std::abs(double(reference[i]));
  }
  return total > 0 ? diff / total : 0;
}

// The median over pixels of sum_c image / sum_c reference: a typical pixel's brightness ratio, which a few
// fireflies do not move as they move the sums.
double MedianRatio(const std::vector<float>& image, const std::vector<float>& reference) {
  std::vector<double> ratios;
  for (size_t i = 0; i + 2 < image.size() && i + 2 < reference.size(); i += 3) {
    const double r = double(reference[i]) + reference[i + 1] + reference[i + 2];
    if (r > 0) ratios.push_back((double(image[i]) + image[i + 1] + image[i + 2]) / r);
  }
  if (ratios.empty()) return 0;
  std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
  return ratios[ratios.size() / 2];
}

v1::Material FittedMaterial(const fit::FitResult& r) {
  v1::Material m;
  m.set_model("gltf_sheen");
  for (const auto& [name, values] : r.params) {
    v1::Param* p = m.add_params();
    p->set_name(name);
    for (double v : values) p->add_values(v);
  }
  return m;
}

std::string CameraArg(const render::CameraSpec& c) {
  std::ostringstream out;
  out.precision(9);
  out << c.position.x << ',' << c.position.y << ',' << c.position.z << ',' << c.look_at.x << ',' << c.look_at.y
      << ',' << c.look_at.z << ',' << c.fov_deg;
  return out.str();
}

// "Principled BSDF (Base_Color 0.1 0.2 0.3 1, ...); Velvet BSDF (...)" from gltf_fit.py's NAME.nodes.txt.
std::string NodesText(const std::string& lines) {
  std::map<std::string, std::string> inputs;
  std::vector<std::string> order;
  std::istringstream in(lines);
  for (std::string line; std::getline(in, line);) {
    std::istringstream words(line);
    std::string node, input, value, values;
    words >> node >> input;
    if (node.empty()) continue;
    if (!inputs.count(node)) order.push_back(node);
    std::string& text = inputs[node];
    if (input.empty()) continue;
    int count = 0;
    while (words >> value && count < 3) values += (count++ ? " " : "") + value;  // RGB; alpha left out
    std::replace(input.begin(), input.end(), '_', ' ');
    text += (text.empty() ? "" : ", ") + input + " " + values;
  }
  std::string out;
  for (const std::string& node : order)
    if (node != "OUTPUT_MATERIAL" && node != "ADD_SHADER")
      out += (out.empty() ? "" : "; ") + node + (inputs[node].empty() ? "" : " (" + inputs[node] + ")");
  return out;
}

// Renders each pictured preset and its fit in Loomlight.
void RenderLoomlight(const MaterialsOutSizes& n, std::vector<Picture>* pictures) {
  const std::unique_ptr<api::LoomlightServer> server = StartServer(true);
  const std::unique_ptr<v1::Loomlight::Stub> stub = Connect(server->port(), -1);
  for (Picture& p : *pictures) {
    v1::RenderRequest request = SquareRequest(p.preset.c_str(), v1::SCENE_SPHERE, n.side, n.loomlight_spp, kSeed);
    Progress("materials-out: Loomlight renders %s and its gltf_sheen fit\n", p.preset.c_str());
    Clock::time_point start = Clock::now();
    p.source = MeanRender(*stub, request, n.loomlight_spp, kSeed);
    p.source_seconds = SecondsSince(start);
    *request.mutable_material() = FittedMaterial(*p.sheen);
    start = Clock::now();
    p.fitted = MeanRender(*stub, request, n.loomlight_spp, kSeed);
    p.fitted_seconds = SecondsSince(start);
  }
}

// Writes each fit as a .glb and renders them all in one Blender process.
BlenderRun RenderCycles(const MaterialsOutSizes& n, const render::CameraSpec& camera, double radius,
                        std::vector<Picture>* pictures) {
  BlenderRun b;
  if (!PrepareBlender("loomlight-materials-out", &b)) return b;
  const std::string sky = (b.dir / "sky.exr").string();
  double brightest = 0;
  if (std::string e = WriteEnvironment(sky, render::Environment::Builtin(), kSkyWidth, &brightest); !e.empty()) {
    b.skipped = e;
    return b;
  }
  std::string glbs;
  for (Picture& p : *pictures) {
    exporting::GltfScene scene;
    scene.name = p.preset;
    scene.materials = {{p.preset, p.sheen->params}};
    scene.slot_material = {0};
    std::string bytes;
    if (p.glb_error = exporting::WriteGltf(scene, true, &bytes); !p.glb_error.empty()) continue;
    const std::filesystem::path path = b.dir / (p.preset + ".glb");
    std::ofstream(path, std::ios::binary) << bytes;
    glbs += " --glb '" + p.preset + "=" + path.string() + "'";
  }
  if (glbs.empty()) {
    b.skipped = "no fit could be written as glTF";
    return b;
  }
  Progress("materials-out: Cycles renders %zu glTF files at %u samples per pixel (log: %s)\n", pictures->size(),
           n.cycles_spp, b.log.c_str());
  RunBlender("gltf_fit.py",
             "--sky '" + sky + "' --camera=" + CameraArg(camera) + " --radius " + Fixed(radius, 6) + " --size " +
                 std::to_string(n.side) + " --threads 2 --samples " + std::to_string(n.cycles_spp) + " --seed " +
                 std::to_string(kSeed) + glbs,
             &b);
  if (!b.skipped.empty()) return b;
  for (Picture& p : *pictures) {
    p.cycles = DecodeExr(ReadFile(b.dir / (p.preset + ".exr")));
    p.cycles_seconds = b.seconds.count(p.preset) ? b.seconds[p.preset] : 0;
    p.cycles_nodes = NodesText(ReadFile(b.dir / (p.preset + ".nodes.txt")));
  }
  return b;
}

// The five panels side by side at the source's exposure: Loomlight's preset, Loomlight's fit, Cycles' glTF,
// |fit - preset| and |Cycles - fit|, the differences times kDifferenceGain.
constexpr float kDifferenceGain = 4;

// Writes them to `path` ("": only the exposure) and sets *exposure.
std::string WritePanels(const Picture& p, uint32_t side, const std::string& path, double* exposure) {
  const std::vector<float> empty(size_t{3} * side * side, 0.0f);
  const std::vector<float>& cycles = p.cycles.empty() ? empty : p.cycles;
  std::vector<float> fit_difference(empty.size()), viewer_difference(empty.size());
  for (size_t i = 0; i < empty.size(); ++i) {
    fit_difference[i] = kDifferenceGain * std::abs(p.fitted[i] - p.source[i]);
    viewer_difference[i] = p.cycles.empty() ? 0 : kDifferenceGain * std::abs(cycles[i] - p.fitted[i]);
  }
  const std::vector<const std::vector<float>*> panels = {&p.source, &p.fitted, &cycles, &fit_difference,
                                                         &viewer_difference};
  imaging::LinearRgbImage image{int(side * panels.size()), int(side), {}};
  image.rgb.resize(size_t{3} * image.width * side);
  for (uint32_t y = 0; y < side; ++y)
    for (size_t k = 0; k < panels.size(); ++k)
      std::copy_n(panels[k]->begin() + 3 * size_t(y) * side, 3 * side,
                  image.rgb.begin() + 3 * (size_t(y) * image.width + k * side));
  *exposure = imaging::AutomaticExposure({int(side), int(side), p.source});
  if (path.empty()) return "";
  std::string png;
  double used = 0;
  if (std::string e = render::EncodeRendered(image, nullptr, imaging::Background::kScene, imaging::ImageFormat::kPng,
                                             *exposure, &png, &used);
      !e.empty())
    return e;
  std::ofstream out(path, std::ios::binary);
  out << png;
  return out ? "" : "cannot write " + path;
}

// ---- The report ----

// The roughness of a fit's GGX base: gltf_sheen's `roughness`, openpbr's `specular_roughness`.
double BaseRoughness(const models::ParamValues& params) {
  for (const char* name : {"roughness", "specular_roughness"})
    if (auto p = params.find(name); p != params.end() && !p->second.empty()) return p->second[0];
  return 0;
}

std::string FitTable(const std::vector<SourceFits>& all) {
  Table table({"preset", "model", "target", "worst region (its error)", "most of the error (share, bias)", "error",
               "fit s", "iterations", "base roughness"},
              5);
  for (const SourceFits& s : all) {
    if (!s.failed.empty()) {
      table.Add({s.source.preset, s.source.model->name(), "-", "failed: " + s.failed, "-", "-", "-", "-", "-"});
      continue;
    }
    for (const FitRow& row : s.fits) {
      const fit::FitResult& r = row.result;
      const fit::RegionError* most = LargestShare(r);
      table.Add({s.source.preset + (s.source.sanity ? " (sanity)" : ""), s.source.model->name(), row.target,
                 r.regions.empty() ? "-" : ShortRegion(r.regions[0].region) + " (" + Fixed(r.regions[0].error, 3) + ")",
                 most ? ShortRegion(most->region) + " (" + Percent(most->share) + ", " +
                            (most->bias >= 0 ? "+" : "") + Fixed(most->bias, 3) + ")"
                      : "-",
                 Fixed(r.error, 3) + (r.error > fit::kPoorFitError ? " (poor)" : ""), Fixed(r.seconds, 2),
                 std::to_string(r.iterations), Fixed(BaseRoughness(r.params), 3)});
    }
  }
  return TableBlock(
      "error is the stated error of `server/models/fit/lobe_fit.h` (relative L1 of f cos over its 4,096 fixed "
      "cosine-weighted pairs and three channels), `(poor)` above " + Fixed(fit::kPoorFitError, 1) +
          "; fit s is `FitResult.seconds` (the optimiser's wall time, one thread), iterations its Levenberg-Marquardt "
          "iterations over every start; base roughness the fit's GGX roughness (gltf_sheen `roughness`, openpbr "
          "`specular_roughness`); the worst region is the one of highest relative error (elevation of the "
          "view, azimuth of the light from the view's), the last column the region holding the largest share of "
          "the absolute error, with its signed bias (sum (f_fit - f) / sum |f| there; > 0 the fit is too bright). "
          "(sanity): a target model's own preset, which its own lobe should fit to near zero.",
      table);
}

std::string BaselineTable(const std::vector<SourceFits>& all) {
  Table table({"preset", "model", "reference on 4,096 pairs ms", "anisotropy", "gltf_sheen eval ms",
               "openpbr eval ms"},
              2);
  for (const SourceFits& s : all) {
    if (!s.failed.empty()) continue;
    std::vector<std::string> row = {s.source.preset, s.source.model->name(), Millis(s.reference_seconds),
                                    Fixed(s.anisotropy, 3)};
    for (const char* target : kTargets) {
      std::string cell = "-";
      for (const FitRow& f : s.fits)
        if (f.target == target) cell = Millis(f.evaluation_seconds);
      row.push_back(cell);
    }
    table.Add(row);
  }
  return TableBlock(
      "the baseline, measured in the same run: reference is one `ReferenceOnFitDirections` of the source (4,096 "
      "evaluations of its double reference, one thread, best of the runs), computed once per fit; anisotropy is "
      "sum |f_iso - f| / sum |f| over the same pairs, f_iso the mean of f over " + std::to_string(kAzimuthRotations) +
          " rotations of each pair about the normal (0 for an isotropic material): roughly the part of the source "
          "an isotropic lobe cannot represent; eval ms is one `MeasureFit` of the target at its fit (4,096 target "
          "evaluations and the error): what one error evaluation in the optimiser costs, so fit s / eval s is about "
          "the number of full-set evaluations a fit spends (its start stage runs on 512 pairs).",
      table);
}

std::string WorstText(const std::vector<SourceFits>& all) {
  std::string out, explained_model, explained_for;  // a model's explanation is given once
  for (const char* target : kTargets) {
    const SourceFits* worst = nullptr;
    const FitRow* worst_row = nullptr;
    for (const SourceFits& s : all) {
      if (s.source.sanity || !s.failed.empty()) continue;
      for (const FitRow& row : s.fits)
        if (row.target == target && (!worst_row || row.result.error > worst_row->result.error)) {
          worst = &s;
          worst_row = &row;
        }
    }
    if (!worst_row) continue;
    const fit::FitResult& r = worst_row->result;
    std::vector<fit::RegionError> by_share = r.regions;
    std::stable_sort(by_share.begin(), by_share.end(),
                     [](const fit::RegionError& a, const fit::RegionError& b) { return a.share > b.share; });
    std::string regions;
    for (size_t i = 0; i < std::min<size_t>(3, by_share.size()); ++i)
      regions += (i ? "; " : "") + by_share[i].region + ": " + Percent(by_share[i].share) + " of the error, " +
                 "relative error " + Fixed(by_share[i].error, 3) + ", " +
                 (by_share[i].bias >= 0 ? "too bright by " : "too dark by ") + Percent(std::abs(by_share[i].bias));
    out += "- **" + std::string(target) + "** fits `" + worst->source.preset + "` (" + worst->source.model->name() +
           ") worst: error " + Fixed(r.error, 3) + ". Where: " + regions + ". Its anisotropy is " +
           Fixed(worst->anisotropy, 3) + " (" + Percent(worst->anisotropy / std::max(r.error, 1e-12)) +
           " of the fit's error). Why: " +
           (worst->source.model->name() == explained_model
                ? "as for " + explained_for + "."
                : ModelExplanation(worst->source.model->name()) + "." + TangentCurves(worst->source.values)) +
           "\n";
    if (explained_model.empty()) {
      explained_model = worst->source.model->name();
      explained_for = target;
    }
  }
  return out.empty() ? "" : "The preset each target fits worst:\n\n" + out + "\n";
}

// Image a against image b over the sphere's pixels.
struct Comparison {
  bool valid = false;  // both images there
  ImageError error;
  double mean_difference = 0, brightness = 0, facing = 0, rim = 0, median_ratio = 0;
};

Comparison Compared(const std::vector<float>& a, const std::vector<float>& b, const SphereRegions& regions) {
  Comparison c;
  if (a.empty() || b.empty()) return c;
  const std::vector<float> image = Masked(a, regions.all), reference = Masked(b, regions.all);
  c.valid = true;
  c.error = Compare(image, reference);
  c.mean_difference = MeanAbsoluteDifference(image, reference);
  c.brightness = MeanDifference(image, reference);
  c.facing = MeanDifference(Masked(a, regions.facing), Masked(b, regions.facing));
  c.rim = MeanDifference(Masked(a, regions.rim), Masked(b, regions.rim));
  c.median_ratio = MedianRatio(image, reference);
  return c;
}

std::string Signed(double x) { return (x >= 0 ? "+" : "") + Percent(x); }

std::string PictureTable(const std::vector<Picture>& pictures, const SphereRegions& regions) {
  Table table({"preset", "images", "PSNR dB", "mean rel. difference", "brightness", "facing", "rim",
               "median pixel ratio"},
              2);
  for (const Picture& p : pictures) {
    const auto add = [&](const std::string& what, const std::vector<float>& a, const std::vector<float>& b) {
      const Comparison c = Compared(a, b, regions);
      if (!c.valid) return;
      table.Add({p.preset, what, Fixed(c.error.psnr_db, 1), Fixed(c.mean_difference, 3), Signed(c.brightness),
                 Signed(c.facing), Signed(c.rim), Fixed(c.median_ratio, 3)});
    };
    add("Loomlight fit against Loomlight preset (the fit's error)", p.fitted, p.source);
    add("Cycles glTF against Loomlight fit (the viewer's)", p.cycles, p.fitted);
    add("Cycles glTF against Loomlight preset (both)", p.cycles, p.source);
  }
  return TableBlock("a against b over the " + Count(regions.all.size()) +
                        " pixels wholly on the sphere (all four corners' rays hit it; the sky behind is the same map "
                        "in both renderers and left out): PSNR = 10 log10(peak^2 / MSE), peak b's largest value "
                        "there; mean rel. difference = sum |a - b| / sum b over pixels and channels; brightness = "
                        "sum a / sum b - 1, and the same over the " + Count(regions.facing.size()) +
                        " pixels facing the camera (normal within 60 degrees of the view) and the " +
                        Count(regions.rim.size()) + " of the rim (the rest); median pixel ratio = the median over "
                        "pixels of a pixel's sum over channels of a / b (a typical pixel).",
                    table);
}

// What the preset's own render shows that a fit cannot, as seen in this section's pictures.
std::string PresetLook(const std::string& preset) {
  if (preset == "silk_shot")
    return "the preset shows the shot silk's highlights as bands that follow the two thread directions over the "
           "sphere, green from one, pink-red from the other, which the isotropic fit averages into one even green";
  if (preset == "cotton_twill")
    return "Loomlight renders the woven model's BTF (the sphere's 8 pattern repeats per unit), so the preset shows "
           "the twill's diagonal floats and their highlights, warm on the warp, cool on the weft; the fit is a BRDF "
           "(the pattern's mean), uniform";
  if (preset == "velvet")
    return "the preset is dark where the sphere faces the camera and brightens toward the rim, most along the "
           "lower and right edges, where the view grazes the cloth and sees its near-vertical pile from the side";
  return "";
}

double MaxOf(const models::ParamValues& params, const char* name) {
  const auto p = params.find(name);
  return p == params.end() || p->second.empty() ? 0 : *std::max_element(p->second.begin(), p->second.end());
}

// How the three images of each picture compare and why: the fit's error (Loomlight's fit against the preset)
// and the viewer's (Cycles' glTF against Loomlight's fit), with this run's numbers.
std::string PictureNotes(const std::vector<Picture>& pictures, const SphereRegions& regions) {
  std::string out;
  for (const Picture& p : pictures) {
    const models::ParamValues& params = p.sheen->params;
    const double sheen = MaxOf(params, "sheen_color"), base = MaxOf(params, "base_color");
    const Comparison fit_error = Compared(p.fitted, p.source, regions), viewer = Compared(p.cycles, p.fitted, regions);
    std::string note = "- `" + p.preset + "`: " + PresetLook(p.preset) + (PresetLook(p.preset).empty() ? "" : "; ") +
                       "Loomlight's render of the fit against the preset: brightness " + Signed(fit_error.brightness) +
                       " (facing the camera " + Signed(fit_error.facing) + ", at the rim " + Signed(fit_error.rim) +
                       ").";
    if (viewer.valid) {
      const std::string against = Signed(viewer.brightness) + " against Loomlight's render of the same fit (facing " +
                                  Signed(viewer.facing) + ", rim " + Signed(viewer.rim) + ")";
      if (sheen < 0.01)
        note += " The fit leaves the sheen off (sheen_color at most " + Fixed(sheen, 3) +
                "), so Cycles renders the Principled BSDF alone, and it is " + against +
                ": Blender 3.4's Principled BSDF adds its GGX specular (Specular 0.5, F0 0.04, as glTF's ior 1.5) "
                "to a diffuse it does not dim by the specular's Fresnel, where glTF's dielectric BRDF, as the "
                "gltf_sheen model implements it, leaves the diffuse only 1 - F of the light "
                "(`kernels/models/gltf_sheen.h`)" +
                (viewer.rim > viewer.facing ? "; the excess is larger at the rim, where F is larger (and where the "
                                              "Principled BSDF's Disney diffuse adds its retro-reflection)"
                                            : "") +
                ". The fifth panel is that excess, and both images' noise.";
      else
        note += " Cycles renders the sheen as Blender's Velvet BSDF (Sigma = sheen_roughness " +
                Fixed(MaxOf(params, "sheen_roughness"), 3) +
                ") added to the Principled BSDF: not KHR_materials_sheen's Charlie distribution with its "
                "visibility term, and without the extension's albedo scaling of the base (1 - max(sheen_color) E); " +
                (base < 0.01 ? "the base is black here, so the scaling does not matter, only the lobe's shape"
                             : "the base is not dimmed, so Cycles is brighter where the sheen is strong") +
                ". Cycles is " + against + ": " +
                (viewer.rim > viewer.facing ? "the Velvet lobe puts more of its light toward grazing views than "
                                              "the Charlie sheen of the same roughness, less facing the camera"
                                            : "the Velvet lobe puts less of its light toward grazing views than "
                                              "the Charlie sheen of the same roughness, more facing the camera") +
                " (the fifth panel's ring).";
    }
    out += note + "\n";
  }
  return out;
}

}  // namespace

std::string MaterialsOutSection(const Sizes& sizes) {
  const MaterialsOutSizes n = SizesFor(sizes);
  const Clock::time_point start = Clock::now();
  std::vector<const models::Model*> targets;
  std::string missing;
  for (const char* name : kTargets) {
    if (const models::Model* m = models::Registry::Global().FindModel(name))
      targets.push_back(m);
    else
      missing += (missing.empty() ? "" : ", ") + std::string("`") + name + "`";
  }
  const std::string title = "14. Materials out: fits to glTF sheen and OpenPBR fuzz";
  if (targets.empty()) return Section(title, "Not run: no target model is registered (" + missing + ").", "");

  std::vector<std::string> skipped;
  std::vector<SourceFits> all;
  for (const Source& source : Sources(&skipped)) all.push_back(FitSource(source, targets, n.runs));
  const double fit_seconds = SecondsSince(start);

  // The pictures: the gltf_sheen fit of each pictured preset.
  const render::Scene sphere = render::MakeScene(render::SceneKind::kSphere);
  const render::CameraSpec camera = sphere.default_camera;
  const double radius = sphere.objects.at(0).shape.radius;
  std::vector<Picture> pictures;
  for (const char* preset : kPictured)
    for (const SourceFits& s : all)
      for (const FitRow& row : s.fits)
        if (s.source.preset == preset && row.target == "gltf_sheen") {
          Picture& p = pictures.emplace_back();
          p.preset = preset;
          p.sheen = &row.result;
        }
  const Clock::time_point render_start = Clock::now();
  if (!pictures.empty()) RenderLoomlight(n, &pictures);
  const double loomlight_seconds = SecondsSince(render_start);
  BlenderRun blender;
  if (pictures.empty())
    blender.skipped = "no pictured preset was fitted";
  else
    blender = RenderCycles(n, camera, radius, &pictures);
  const bool with_cycles = blender.skipped.empty();

  std::string picture_text;
  for (const Picture& p : pictures) {
    const std::string file = "docs/images/materials-out-" + p.preset + ".png";
    double exposure = 0;
    // A --quick run's small pictures would replace the committed ones: it writes none.
    const std::string path = sizes.quick ? "" : std::string(LOOMLIGHT_SOURCE_DIR) + "/" + file;
    if (std::string e = WritePanels(p, n.side, path, &exposure); !e.empty()) {
      picture_text += "- `" + p.preset + "`: no picture (" + e + ").\n";
      continue;
    }
    std::string fitted;
    for (const auto& [name, values] : p.sheen->params) {
      fitted += (fitted.empty() ? "" : ", ") + name + " ";
      for (size_t i = 0; i < values.size(); ++i) {
        if (i) fitted += ' ';
        fitted += Fixed(values[i], 3);
      }
    }
    picture_text += "- `" + p.preset + "` (" +
                    (path.empty() ? "--quick: no picture written" : "[" + file + "](../" + file + ")") + ", exposure " +
                    Fixed(exposure, 2) + "): the fit " + fitted + " (error " + Fixed(p.sheen->error, 3) + ")" +
                    (p.glb_error.empty() ? "" : "; its glTF could not be written: " + p.glb_error) +
                    (p.cycles_nodes.empty() ? "" : "; Cycles rendered " + p.cycles_nodes) +
                    ". Loomlight " + Fixed(p.source_seconds, 2) + " s (preset) and " + Fixed(p.fitted_seconds, 2) +
                    " s (fit), Cycles " + Fixed(p.cycles_seconds, 2) + " s.\n";
  }

  const SphereRegions regions = SpherePixels(camera, radius, n.side);
  std::string skipped_text;
  for (const std::string& s : skipped) skipped_text += (skipped_text.empty() ? "" : "; ") + s;
  const std::string method =
      "Every preset of every registered surface model (left out: " + (skipped_text.empty() ? "none" : skipped_text) +
      ") is fitted in process to each target model by `FitLobe` (`server/models/fit/lobe_fit.h`: Eigen's "
      "Levenberg-Marquardt on a reweighted least-squares form of the stated error, from fixed starts; one thread)" +
      (missing.empty() ? "" : "; not registered, so not fitted: " + missing) +
      ". The pictures: the sphere scene (radius " + Fixed(radius, 2) + ", its default camera at (" +
      Fixed(camera.position.x, 2) + ", " + Fixed(camera.position.y, 2) + ", " + Fixed(camera.position.z, 2) +
      ") looking at the origin, vertical fov " + Fixed(camera.fov_deg, 0) +
      " degrees, its default lighting: the built-in sky with its sun), " + Pixels(n.side) + ". Loomlight: an "
      "in-process `LoomlightServer` and the Render RPC, " + std::to_string(n.loomlight_spp) +
      " samples per pixel, seed " + std::to_string(kSeed) +
      ", the fidelity the server chooses; the preset, then `Material{model: \"gltf_sheen\", params: the fit}`. "
      "Cycles" +
      (with_cycles
           ? " (Blender " + blender.version + ", `bench/cycles/gltf_fit.py`): `WriteGltf`'s preview sphere with the "
             "fit (`.glb`) through Blender's own glTF importer, scaled to the scene's radius, the same camera, the "
             "server's sky written as a " + std::to_string(kSkyWidth) + " x " + std::to_string(kSkyWidth / 2) +
             " EXR from `Environment::Builtin()` (looked up closest, importance sampled at its resolution), CPU, 2 "
             "threads, direct light only, no denoiser, no adaptive sampling, a 1-pixel box filter, " +
             std::to_string(n.cycles_spp) + " samples per pixel, seed " + std::to_string(kSeed) + "."
           : ": skipped: " + blender.skipped + ".") +
      " Each picture `docs/images/materials-out-PRESET.png` is five " + Pixels(n.side) +
      " panels at the Loomlight preset render's automatic exposure through the server's PNG encoding (ACES, sRGB): "
      "Loomlight's preset, Loomlight's gltf_sheen fit, Cycles' glTF, then |fit - preset| and |Cycles - fit| times " +
      Fixed(kDifferenceGain, 0) + ". This section took " + Fixed(SecondsSince(start), 0) + " s: fits " +
      Fixed(fit_seconds, 0) + " s, Loomlight renders " + Fixed(loomlight_seconds, 0) + " s, the Blender process " +
      Fixed(blender.process_seconds, 0) + " s.";
  if (with_cycles) std::filesystem::remove_all(blender.dir);  // kept with Blender's log when it failed

  return Section(title, method,
                 FitTable(all) + "\n" + WorstText(all) + BaselineTable(all) + "\n" +
                     (pictures.empty() ? ""
                                       : "The side-by-side (the gltf_sheen fit):\n\n" + picture_text + "\n" +
                                             PictureTable(pictures, regions) + "\n" +
                                             "How they compare, and why (from looking at this run's pictures; the "
                                             "numbers over the sphere's pixels as in the table):\n\n" +
                                             PictureNotes(pictures, regions)));
}

}  // namespace loomlight::bench
