// Fabrics as they are designed (issue 47's figures): a tartan weaving draft with its thread colours
// (tests/data/wif/tartan.wif) on the swatch scene and as a texture slice, through an in-process server; the
// 40 x 40 stitch jersey at fiber level, generated and built into an Embree BVH in process (the yarn library and
// yarn::FiberScene, as yarn::BuildFiberScene does for the server) at full detail and at Eq. 4's level of detail
// for a close-up's and a distant view's pixel footprint; and a 512 x 512 close-up of a knit on the knit_patch
// scene at full detail and LoD, with the LoD's error against full detail and the noise floor beside it.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>

#include "bench/bench.h"
#include "bench/cycles_compare.h"
#include "bench/in_process.h"
#include "bench/render_client.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/api/render_rpc.h"
#include "server/models/weave/wif.h"
#include "server/render/scene_registry.h"
#include "server/yarn/fiber_scene.h"
#include "server/yarn/knit.h"
#include "server/yarn/yarn_job.h"

namespace loomlight::bench {
namespace {

// ---- The tartan ----

constexpr const char* kTartanFile = "tests/data/wif/tartan.wif";
// The woven preset whose yarn parameters (all but the colours, which are the draft's) the tartan takes: a twill,
// as a tartan is woven.
constexpr const char* kTartanPreset = "cotton_twill";
// Swatch: pattern repeats per scene unit, so that the 1 x 1 swatch shows two setts with each thread a few pixels wide.
constexpr double kTartanTextureScale = 2;
// Slice: two setts each way, the light and view as in docs/designs.md.
constexpr double kSliceRegion = 2;
constexpr double kSliceWi[2] = {30, 60}, kSliceWo[2] = {20, 250};  // theta, phi in degrees

struct FabricSizes {
  uint32_t side;           // the swatch's and the close-up's pixels per side
  uint32_t spp;            // their samples per pixel
  uint32_t reference_spp;  // the swatch reference's, in two halves
  uint32_t slice_spp;
  int runs;                // timed calls, the fastest counts
  int stitches;            // the knit generated in process, per side
};

FabricSizes SizesFor(const Sizes& sizes) {
  if (sizes.quick) return {64, 4, 16, 1, 1, 6};
  return {512, 16, 256, 4, 2, 40};
}

v1::Material TartanMaterial(const std::string& wif) {
  v1::Material m;
  m.set_preset(kTartanPreset);
  v1::Param* p = m.add_params();
  p->set_name("pattern.wif");
  p->set_text(wif);
  return m;
}

void AddDirection(google::protobuf::RepeatedField<float>* out, const double (&deg)[2]) {
  const double t = deg[0] * std::numbers::pi / 180, p = deg[1] * std::numbers::pi / 180;
  out->Add(static_cast<float>(std::sin(t) * std::cos(p)));
  out->Add(static_cast<float>(std::sin(t) * std::sin(p)));
  out->Add(static_cast<float>(std::cos(t)));
}

std::string Percent(double fraction) { return Fixed(100 * fraction, 2) + "%"; }

// What the draft is: its repeat and colours, read independently of the server.
std::string DraftSummary(const std::string& wif) {
  models::weave::WeavePattern pattern;
  models::weave::WifColors colors;
  if (std::string e = models::weave::ParseWif(wif, &pattern, &colors); !e.empty()) return "unreadable (" + e + ")";
  return std::to_string(pattern.warps) + " warps x " + std::to_string(pattern.picks) + " picks, " +
         std::to_string(colors.table.size()) + " colours";
}

// What a photograph of the draft's cloth shows (its source comment) and how the pictures compare: written by looking
// at docs/images/design-tartan-*.png, which docs/designs.md makes with this section's settings.
constexpr const char* kTartanLooks =
    "**Photograph and render.** The draft's source comment describes a photograph of Royal Stewart cloth: a bright "
    "scarlet ground in large squares; across it, both ways, a navy stripe beside a wide black band carrying a thin "
    "yellow and a thin white line, then a wide green band, and a fine white line in the small red square; where "
    "bands cross the red they mix into darker blocks, and the 2/2 twill shows as fine diagonal steps along every "
    "colour edge. The swatch render shows that sett, two repeats each way: the large red squares, the green bands "
    "edged in navy and black, the yellow and white lines, and where two green bands cross a solid green block. "
    "Where a stripe crosses the red ground (or another stripe) the warp and weft colours alternate along the twill's "
    "diagonal, red and green steps, navy and green, at 2.5 pixels a thread: the mixed block a photograph from a "
    "metre away shows as one darker colour is resolved into its two threads here, as in a macro photograph. The "
    "twill line runs through every block, a fine diagonal hatching even on the plain red. The thin lines of one or "
    "two threads show as dashes, each thread over two picks and under two, not as the continuous lines seen from "
    "further away. The red reads lighter and pinker than scarlet cloth under a lamp: the swatch scene's sky adds "
    "the preset's specular sheen (its ks, white) over the dyed diffuse colour; the texture slice, one light and no "
    "sky, is a deeper red, with the same sett, dashes and twill steps.\n\n";

// The tartan on the swatch and as a slice, or a paragraph saying why not.
std::string TartanPart(v1::Loomlight::Stub& stub, const FabricSizes& n) {
  const std::filesystem::path path = std::filesystem::path(LOOMLIGHT_SOURCE_DIR) / kTartanFile;
  if (!std::filesystem::exists(path)) return std::string("Not run: ") + kTartanFile + " is not in the source tree.\n\n";
  const std::string wif = ReadFile(path);

  v1::RenderRequest swatch = SquareRequest(kTartanPreset, v1::SCENE_SWATCH, n.side, n.spp, 1);
  *swatch.mutable_material() = TartanMaterial(wif);
  swatch.set_texture_scale(kTartanTextureScale);
  Progress("fabrics: tartan swatch %s, reference of 2 x %u samples per pixel\n", Pixels(n.side).c_str(),
           n.reference_spp / 2);
  ImageError reference_noise;
  const std::vector<float> reference = FromHalves(MeanRender(stub, swatch, n.reference_spp / 2, 1000),
                                                  MeanRender(stub, swatch, n.reference_spp / 2, 2000), &reference_noise);
  swatch.set_seed(1);
  swatch.set_samples_per_pixel(n.spp);
  Progress("fabrics: tartan swatch, %u samples per pixel\n", n.spp);
  // The reference's calls warmed the server up for this material and scene.
  const RenderResult r = TimeRender(stub, swatch, n.runs, false);
  const ImageError e = Compare(r.image, reference);

  v1::TextureSliceRequest slice;
  *slice.mutable_material() = TartanMaterial(wif);
  AddDirection(slice.mutable_wi(), kSliceWi);
  AddDirection(slice.mutable_wo(), kSliceWo);
  slice.mutable_region()->set_u_max(kSliceRegion);
  slice.mutable_region()->set_v_max(kSliceRegion);
  slice.set_width(n.side);
  slice.set_height(n.side);
  slice.set_samples_per_pixel(n.slice_spp);
  slice.set_format(v1::IMAGE_FORMAT_PNG);
  Progress("fabrics: tartan slice %s, %u samples per pixel\n", Pixels(n.side).c_str(), n.slice_spp);
  double slice_client = 1e30;
  v1::TextureSliceResponse slice_response;
  for (int run = 0; run <= n.runs; ++run) {  // the first call warms up
    grpc::ClientContext ctx;
    v1::TextureSliceResponse response;
    const Clock::time_point start = Clock::now();
    const grpc::Status status = stub.TextureSlice(&ctx, slice, &response);
    const double seconds = SecondsSince(start);
    if (!status.ok()) {
      std::fprintf(stderr, "fabrics bench: the tartan slice failed: %s\n", status.error_message().c_str());
      std::exit(1);
    }
    if (run > 0 && seconds < slice_client) slice_client = seconds, slice_response = response;
  }

  Table table({"image", "pixels", "samples/pixel", "chosen", "client ms", "server ms", "kernel ms", "rel. MSE",
               "PSNR dB", "mean vs ref."},
              4);
  table.Add({"swatch render", Pixels(n.side), std::to_string(n.spp), ChosenSummary(r.last), Millis(r.client_seconds),
             Millis(r.last.total_seconds()), Millis(r.last.kernel_seconds()), Sci(e.relative_mse), Fixed(e.psnr_db, 1),
             Percent(MeanDifference(r.image, reference))});
  table.Add({"swatch reference", Pixels(n.side), std::to_string(n.reference_spp), "", "", "", "",
             Sci(reference_noise.relative_mse), Fixed(reference_noise.psnr_db, 1), ""});
  table.Add({"texture slice (PNG)", Pixels(n.side), std::to_string(n.slice_spp), "BTF", Millis(slice_client),
             Millis(slice_response.total_seconds()), Millis(slice_response.kernel_seconds()), "", "", ""});
  return "**Tartan.** `" + std::string(kTartanFile) + "` (" + DraftSummary(wif) + ") as the `pattern.wif` of `" +
         kTartanPreset + "`: its colours are the yarn types' diffuse colours, the rest the preset's. The swatch "
         "scene (the default camera, tilt and sky) at " + Fixed(kTartanTextureScale, 0) + " setts per scene unit, "
         "seed 1, best of " + std::to_string(n.runs) + " calls after the reference's; its reference is the mean of "
         "two halves of " + std::to_string(n.reference_spp / 2) + " samples per pixel (seeds from 1000 and 2000; "
         "the row gives the reference's own noise, estimated from the halves' difference). The slice is f over " +
         Fixed(kSliceRegion, 0) + " x " + Fixed(kSliceRegion, 0) + " setts, wi (theta, phi) = (" +
         Fixed(kSliceWi[0], 0) + ", " + Fixed(kSliceWi[1], 0) + ") and wo = (" + Fixed(kSliceWo[0], 0) + ", " +
         Fixed(kSliceWo[1], 0) + ") degrees, PNG, best of " + std::to_string(n.runs) + " after a warm-up. The "
         "pictures are docs/images/design-tartan-swatch.png and design-tartan-slice.png, made by docs/designs.md's "
         "commands with these settings.\n\n" +
         TableBlock("client ms is the call as the client sees it, server ms the server's own total, kernel ms its "
                    "time in kernel launches; rel. MSE = sum (x - ref)^2 / sum ref^2, PSNR against the reference's "
                    "peak; mean vs ref. = the image's sum over the reference's, less 1.",
                    table) +
         kTartanLooks;
}

// ---- The knit in process ----

// The pixel footprints of the renders' views (Eq. 4's omega^LoD as the server computed it), by view.
using Footprints = std::vector<std::pair<std::string, double>>;

struct KnitMeasure {
  std::string name;
  double footprint = 0;  // Eq. 4's omega^LoD; 0 = full detail
  double lambda = 1;
  int64_t fibers = 0, control_points = 0;
  double generate_seconds = 0;
  yarn::FiberSceneEstimate estimate;
  yarn::FiberSceneStats stats;
  std::string skipped;  // why no BVH was built, or ""
};

// The in-process limits: the server's request limits (kMaxYarnFibers, kMaxYarnControlPoints) are for one call's
// stream; here the whole patch is generated, bounded by what this machine's memory holds (24 bytes a point in
// double, and the BVH below).
constexpr int64_t kBenchMaxFibers = 50'000'000;
constexpr int64_t kBenchMaxControlPoints = 200'000'000;
// The BVH is built only when FiberScene's pre-build bound is within this.
constexpr int64_t kBenchMaxBvhBytes = int64_t{8} << 30;

yarn::YarnJob KnitJob(int stitches, double footprint) {
  yarn::YarnJob job;
  yarn::YarnPreset("cotton1", &job.params);
  job.kind = yarn::YarnLayoutKind::kKnit;
  job.knit.stitch = yarn::KnitStitch::kJersey;
  job.knit.wales = job.knit.courses = stitches;
  job.knit.yarn_radius = job.params.yarn_radius;
  job.detail.threads = 2;
  job.detail.footprint = footprint;
  job.limits = {kBenchMaxFibers, kBenchMaxControlPoints};
  return job;
}

KnitMeasure MeasureKnit(const std::string& name, int stitches, double footprint) {
  KnitMeasure m;
  m.name = name;
  m.footprint = footprint;
  yarn::YarnJob job = KnitJob(stitches, footprint);
  std::vector<yarn::YarnGeometry> yarns;
  std::vector<yarn::LaidYarn> laid;
  Progress("fabrics: knit %dx%d, %s: generating\n", stitches, stitches, name.c_str());
  const Clock::time_point start = Clock::now();
  if (std::string e = yarn::GenerateYarnJob(&job, &yarns, &laid); !e.empty()) {
    m.skipped = "generation failed: " + e;
    return m;
  }
  m.generate_seconds = SecondsSince(start);
  std::vector<const yarn::YarnGeometry*> pointers;
  for (const yarn::YarnGeometry& y : yarns) {
    pointers.push_back(&y);
    m.fibers += static_cast<int64_t>(y.fibers.size());
    m.control_points += y.control_points;
    m.lambda = y.lambda;
  }
  m.estimate = yarn::EstimateFiberScene(pointers);
  if (m.estimate.total_bytes > kBenchMaxBvhBytes) {
    m.skipped = "the BVH's bound " + Fixed(double(m.estimate.total_bytes) / (1 << 30), 1) + " GiB is over the " +
                Fixed(double(kBenchMaxBvhBytes) / (1 << 30), 0) + " GiB this benchmark allows itself";
    return m;
  }
  yarn::FiberSceneOptions options;  // as yarn::BuildFiberScene sets them for the server
  options.max_bytes = std::max<int64_t>(m.estimate.total_bytes, 1);
  options.threads = 2;
  Progress("fabrics: knit %s: building the BVH of %s fibers\n", name.c_str(), Count(size_t(m.fibers)).c_str());
  yarn::FiberScene scene;
  if (std::string e = yarn::FiberScene::Build(pointers, options, &scene, &m.stats); !e.empty())
    m.skipped = "the BVH build failed: " + e;
  return m;
}

std::string MiB(int64_t bytes) { return Fixed(double(bytes) / (1 << 20), 1); }

std::string KnitPart(const FabricSizes& n, const Footprints& footprints, std::vector<KnitMeasure>* measures) {
  yarn::KnitParams params;
  params.wales = params.courses = n.stitches;
  params.yarn_radius = KnitJob(1, 0).params.yarn_radius;
  yarn::KnitLayout layout;
  if (std::string e = yarn::BuildKnit(params, &layout); !e.empty())
    return "**Knit at fiber level.** Not run: the knit layout failed (" + e + ").\n\n";
  const double width = std::max(layout.upper.x - layout.lower.x, layout.upper.y - layout.lower.y);
  const double distant_footprint = width / n.side;
  measures->push_back(MeasureKnit("full detail", n.stitches, 0));
  std::string same;  // the views whose footprint keeps full detail
  const double fiber_width = KnitJob(1, 0).params.fiber_width;
  for (const auto& [view, footprint] : footprints) {
    if (footprint <= fiber_width)
      same += "- LoD at the footprint of the render's " + view + " (" + Sci(footprint) + ", a fiber is " +
              Fixed(fiber_width / footprint, 2) + " pixels wide there): Eq. 4 keeps full detail (lambda 1), the "
              "first row.\n";
    else
      measures->push_back(MeasureKnit("LoD, footprint of the render's " + view, n.stitches, footprint));
  }
  measures->push_back(MeasureKnit("LoD, distant (the patch fills " + std::to_string(n.side) + " pixels)", n.stitches,
                                  distant_footprint));

  Table table({"detail", "footprint", "lambda", "fibers", "control points", "generation s", "fibers/s", "points/s",
               "BVH bound MiB", "BVH peak MiB", "Embree MiB", "build s"},
              1);
  std::string notes = same;
  for (const KnitMeasure& m : *measures) {
    const bool built = m.skipped.empty();
    table.Add({m.name, m.footprint > 0 ? Sci(m.footprint) : "0", Fixed(m.lambda, 3), Count(size_t(m.fibers)),
               Count(size_t(m.control_points)), Fixed(m.generate_seconds, 2),
               Rate(double(m.fibers) / std::max(m.generate_seconds, 1e-9)),
               Rate(double(m.control_points) / std::max(m.generate_seconds, 1e-9)), MiB(m.estimate.total_bytes),
               built ? MiB(m.stats.peak_bytes) : "-", built ? MiB(m.stats.embree_bytes) : "-",
               built ? Fixed(m.stats.build_seconds, 2) : "-"});
    if (!built) notes += "- " + m.name + ": no BVH: " + m.skipped + ".\n";
  }
  const KnitMeasure& full = measures->front();
  const KnitMeasure& distant = measures->back();
  if (full.skipped.empty() && distant.skipped.empty() && distant.stats.embree_bytes > 0)
    notes += "- The distant view's LoD holds " + Fixed(double(full.stats.embree_bytes) / distant.stats.embree_bytes, 1) +
             " times fewer BVH bytes than full detail (" + MiB(distant.stats.embree_bytes) + " MiB against " +
             MiB(full.stats.embree_bytes) + "), generates " +
             Fixed(double(full.control_points) / std::max<int64_t>(distant.control_points, 1), 1) +
             " times fewer control points and builds in " +
             Fixed(distant.stats.build_seconds / std::max(full.stats.build_seconds, 1e-9), 2) +
             " of full detail's time; generation takes " +
             Fixed(distant.generate_seconds / std::max(full.generate_seconds, 1e-9), 2) + " of its time.\n";
  return "**Knit at fiber level (in process).** A " + std::to_string(n.stitches) + " x " + std::to_string(n.stitches) +
         " stitch jersey (yarn::BuildKnit's defaults for cotton1: wale spacing " + Fixed(layout.wale_spacing, 4) +
         ", course spacing " + Fixed(layout.course_spacing, 4) + ", " + Count(size_t(layout.vertices)) +
         " centre vertices; the patch " + Fixed(layout.upper.x - layout.lower.x, 2) + " x " +
         Fixed(layout.upper.y - layout.lower.y, 2) + ") in yarn cotton1 (seed 1), generated by yarn::GenerateYarnJob "
         "on 2 threads and built into an Embree BVH by yarn::FiberScene::Build on 2 threads with the server's "
         "options (yarn::BuildFiberScene: its memory bound is the pre-build estimate). Full detail, and Eq. 4's level "
         "of detail at the pixel footprints of the renders below (as the server computed them for those views, at "
         "the camera's look-at point) and of a distant view where the whole patch fills " +
         std::to_string(n.side) + " pixels (patch width / " + std::to_string(n.side) + "). The server's request "
         "limits (YarnGeometry: " + Count(api::kMaxYarnFibers) + " fibers, " + Count(api::kMaxYarnControlPoints) +
         " control points; Render: " + Count(api::kMaxRenderFibers) + " and " + Count(api::kMaxRenderFiberPoints) +
         ") do not apply in process: the limits are raised to " + Count(kBenchMaxFibers) + " fibers and " +
         Count(kBenchMaxControlPoints) + " control points, and the BVH is built when its bound is within " +
         Fixed(double(kBenchMaxBvhBytes) / (1 << 30), 0) + " GiB.\n\n" +
         TableBlock("footprint = Eq. 4's omega^LoD in scene units (0: full detail); lambda = Eq. 4's factor (the "
                    "fibers kept per ply are lambda^2 of them); fibers = fiber curves generated (cores, migration "
                    "runs, loops and hairs); BVH bound = FiberScene's pre-build estimate (EstimateFiberScene, what "
                    "the server admits against its memory budget); BVH peak = the most bytes Embree held during the "
                    "build (its memory monitor); Embree = what it holds for the built scene (buffers and BVH).",
                    table) +
         notes + "\n";
}

// ---- The close-up render ----

constexpr const char* kKnitScene = "knit_patch";
constexpr const char* kFiberPreset = "cotton";

// The close-up: the knit_patch scene's line of sight, from kCloseUpDistance to the knit's centre, at
// kCloseUpFovDeg: about 5 stitches across, the fibers a pixel or more wide at 512 pixels. A camera of its own (not the
// scene's framing) so that Cycles can be given the same.
constexpr double kCloseUpDistance = 11;
constexpr double kCloseUpFovDeg = 8;

struct KnitCamera {
  render::Vec3 position, look_at;
  double fov_deg = 0;
};

// The close-up camera on a knit of `stitches` a side; fov_deg 0 when the scene or the knit cannot be made.
KnitCamera CloseUpCamera(int stitches) {
  const render::SceneSpec* scene = render::SceneRegistry::Global().Find(kKnitScene);
  yarn::KnitParams params;
  params.wales = params.courses = stitches;
  params.yarn_radius = KnitJob(1, 0).params.yarn_radius;
  yarn::KnitLayout layout;
  if (!scene || !yarn::BuildKnit(params, &layout).empty()) return {};
  const render::CameraSpec framing = scene->build(models::DefaultValues(scene->params)).default_camera;
  const render::Vec3 centre{0.5 * (layout.lower.x + layout.upper.x), 0.5 * (layout.lower.y + layout.upper.y),
                            0.5 * (layout.lower.z + layout.upper.z)};
  return {centre + kCloseUpDistance * render::Normalize(framing.position - framing.look_at), centre, kCloseUpFovDeg};
}

std::string Triple(render::Vec3 v) { return Fixed(v.x, 3) + "," + Fixed(v.y, 3) + "," + Fixed(v.z, 3); }

// `camera` null: the scene's, framing the knit whole.
v1::RenderRequest KnitRequest(const FabricSizes& n, int stitches, const KnitCamera* camera, v1::FiberDetail detail,
                              uint64_t seed) {
  v1::RenderRequest r;
  if (camera) {
    for (double v : {camera->position.x, camera->position.y, camera->position.z}) r.mutable_camera()->add_position(v);
    for (double v : {camera->look_at.x, camera->look_at.y, camera->look_at.z}) r.mutable_camera()->add_look_at(v);
    r.mutable_camera()->set_fov_deg(camera->fov_deg);
  }
  r.mutable_material()->set_preset(kFiberPreset);
  r.set_scene_name(kKnitScene);
  r.mutable_knit()->set_stitch(v1::KNIT_JERSEY);
  r.mutable_knit()->set_wales(uint32_t(stitches));
  r.mutable_knit()->set_courses(uint32_t(stitches));
  r.set_width(n.side);
  r.set_height(n.side);
  r.set_samples_per_pixel(n.spp);
  r.set_seed(seed);
  r.set_format(v1::RENDER_FORMAT_EXR);
  r.set_fiber_detail(detail);
  // Light and ambient traced through the fibers in every row, so that the rows differ in the geometry alone.
  r.set_fiber_shadows(v1::FIBER_SHADOWS_TRACED);
  r.set_fiber_occlusion(v1::FIBER_OCCLUSION_TRACED);
  return r;
}

// The "geometry" choice of a fiber render's fidelity report, e.g. "lod: ... keeps 12 of 75 fibers per ply".
std::string GeometryChoice(const v1::RenderUpdate& update) {
  for (const v1::ObjectFidelity& object : update.fidelity())
    for (const v1::FidelityChoice& c : object.choices())
      if (c.aspect() == "geometry") return c.chosen() + ": " + c.reason();
  return "";
}

// What the knit pictures show beside Wu and Yuksel's figures (their captions in ../shared/papers/): written by
// looking at docs/images/design-knit-*.png (docs/designs.md, this section's requests) and the Cycles close-up
// (LOOMLIGHT_FABRICS_IMAGES).
constexpr const char* kKnitLooks =
    "**The pictures beside the paper's figures.** The close-up (design-knit-closeup.png) fills the frame with about "
    "five wales of V-shaped jersey loops, each leg a three-ply yarn whose plies twist visibly, the regular fibers "
    "drawn as separate tubes with loop and hair flyaways standing off the surface, specular glints along single "
    "fibers, and dark gaps where the loops of neighbouring courses interlock: the fiber-level look of the paper's "
    "close-up (Fig. 16) and of its yarn model with regular fibers over the core (Fig. 9, whose cores alone look too "
    "regular: here they are hidden under the 75-fiber plies). Shadows between loops and within the plies are traced "
    "through the fibers, the combination Fig. 12 builds up from a shadow map, self-shadows and ambient occlusion. "
    "The whole 14 x 14 patch (design-knit-full.png) shows its wales of V's through a haze of hairs, the open loops "
    "of the edge course along the bottom: at half a pixel per fiber the hairs still change the patch's look, as "
    "Fig. 1's caption says fiber geometry changes a sweater's; its level of detail (design-knit-lod.png) keeps a "
    "fifth of the fibers and of their "
    "flyaways, and the V's read sharper and brighter than at full detail: not Fig. 11's 'minimal' difference, "
    "because Eq. 4 thins the hairs with the fibers, and the table's error says by how much; auto detail catches "
    "it and renders full detail. The "
    "40 x 40 patch at LoD (design-knit-40.png) is a regular fine grid of V's with the open loops of the edge "
    "course along its bottom, one core and a fiber per ply; its yarn centre vertices and full-detail fibers (the "
    "table above) against the 356K yarn control points and 20M fiber curves of Fig. 1's sweater. Fig. 10's "
    "other yarn types are not rendered here. Cycles' close-up of the same fibers (not committed; kept with "
    "LOOMLIGHT_FABRICS_IMAGES) shows the same loops fiber for fiber, lit harder: its hair BSDF leaves the loops' "
    "sunlit tops bright and their sides dark and grainy, where Loomlight's fiber model and ambient term light them "
    "more evenly with sparkling highlights.\n\n";

// Whether a full-detail knit of this many stitches a side is within the Render RPC's fiber limits (generated in
// process at those limits, as the server would).
bool Renderable(int stitches) {
  yarn::YarnJob job = KnitJob(stitches, 0);
  job.limits = {int64_t(api::kMaxRenderFibers), int64_t(api::kMaxRenderFiberPoints)};
  std::vector<yarn::YarnGeometry> yarns;
  std::vector<yarn::LaidYarn> laid;
  return yarn::GenerateYarnJob(&job, &yarns, &laid).empty();
}

// The largest square knit, at most `stitches` a side, whose full detail the Render RPC accepts: from a 4 x 4's
// control points and fibers per stitch (a knit's cost grows with its stitches), then down one by one.
int RenderableStitches(int stitches) {
  constexpr int kProbe = 4;
  yarn::YarnJob job = KnitJob(kProbe, 0);
  std::vector<yarn::YarnGeometry> yarns;
  std::vector<yarn::LaidYarn> laid;
  if (!yarn::GenerateYarnJob(&job, &yarns, &laid).empty()) return 0;
  double points = 0, fibers = 0;
  for (const yarn::YarnGeometry& y : yarns) points += double(y.control_points), fibers += double(y.fibers.size());
  const double stitches_within = std::min(double(api::kMaxRenderFiberPoints) / points,
                                          double(api::kMaxRenderFibers) / fibers) * kProbe * kProbe;
  int side = std::min(stitches, int(std::sqrt(stitches_within)));
  while (side > 1 && !Renderable(side)) --side;
  return side;
}

// The pixel footprint the server used for Eq. 4 ("a pixel covers X at the look-at point" in the geometry choice's
// reason), or 0.
double FootprintOf(const std::string& reason) {
  const std::string key = "a pixel covers ";
  const size_t at = reason.find(key);
  return at == std::string::npos ? 0 : std::strtod(reason.c_str() + at + key.size(), nullptr);
}

// The close-up's fibers for Cycles (bench/cycles/knit.py's format): int64 curves and points, uint32 points per
// curve, float32 xyz per point, float32 width per curve, little-endian as this machine is. "" or what failed.
std::string WriteFiberCurves(const std::string& path, int stitches) {
  yarn::YarnJob job = KnitJob(stitches, 0);
  std::vector<yarn::YarnGeometry> yarns;
  std::vector<yarn::LaidYarn> laid;
  if (std::string e = yarn::GenerateYarnJob(&job, &yarns, &laid); !e.empty()) return "the knit: " + e;
  std::vector<uint32_t> counts;
  std::vector<float> points, widths;
  for (const yarn::YarnGeometry& y : yarns)
    for (const yarn::FiberCurve& c : y.fibers) {
      counts.push_back(uint32_t(c.points.size()));
      widths.push_back(float(c.width));
      for (const yarn::Vec3& p : c.points) points.insert(points.end(), {float(p.x), float(p.y), float(p.z)});
    }
  const int64_t header[2] = {int64_t(counts.size()), int64_t(points.size() / 3)};
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(header), sizeof header);
  out.write(reinterpret_cast<const char*>(counts.data()), std::streamsize(counts.size() * sizeof(uint32_t)));
  out.write(reinterpret_cast<const char*>(points.data()), std::streamsize(points.size() * sizeof(float)));
  out.write(reinterpret_cast<const char*>(widths.data()), std::streamsize(widths.size() * sizeof(float)));
  return out ? "" : "cannot write " + path;
}

// Two renders of one view at different seeds, the fastest time of the first: each renderer's noise at equal samples.
struct SeedPair {
  double seconds = 0;
  std::vector<float> first, second;
};

// The close-up in Blender Cycles: the same fibers (written from the in-process generation, which is the server's
// for the same request), camera, sun and ambient; the same samples per pixel at two seeds. A paragraph.
std::string CyclesCloseUp(const FabricSizes& n, int stitches, const KnitCamera& camera, const SeedPair& loomlight) {
  BlenderRun b;
  if (!PrepareBlender("loomlight-fabrics", &b)) return "Cycles: not run: " + b.skipped + ".\n\n";
  const std::string curves = (b.dir / "fibers.bin").string();
  if (std::string e = WriteFiberCurves(curves, stitches); !e.empty()) return "Cycles: not run: " + e + ".\n\n";
  const render::Scene scene = render::SceneRegistry::Global().Find(kKnitScene)->build(
      models::DefaultValues(render::SceneRegistry::Global().Find(kKnitScene)->params));
  const render::Light& sun = scene.default_lights.front();
  Progress("fabrics: the close-up in Blender Cycles\n");
  RunBlender("knit.py",
             "--curves '" + curves + "' --size " + std::to_string(n.side) + " --threads 2 --camera=" +
                 Triple(camera.position) + " --look-at=" + Triple(camera.look_at) + " --fov " +
                 Fixed(camera.fov_deg, 3) + " --toward-light=" + Triple(sun.direction) + " --irradiance " +
                 Fixed(sun.rgb.x, 3) + " --ambient " + Fixed(scene.default_ambient, 3) + " --renders " +
                 RenderJob("seed1", n.spp, 1, n.runs) + "," + RenderJob("seed2", n.spp, 2, 1),
             &b);
  const auto image = [&](const std::string& name) { return DecodeExr(ReadFile(b.dir / (name + ".exr"))); };
  const std::vector<float> first = b.skipped.empty() ? image("seed1") : std::vector<float>{};
  const std::vector<float> second = b.skipped.empty() ? image("seed2") : std::vector<float>{};
  if (b.skipped.empty() && (first.empty() || second.empty())) b.skipped = "Blender wrote no images (its log: " + b.log + ")";
  if (!b.skipped.empty()) return "Cycles: not run: " + b.skipped + ".\n\n";
  // LOOMLIGHT_FABRICS_IMAGES=DIR keeps both renderers' seed-1 close-ups there (EXR, linear) to be looked at.
  if (const char* keep = std::getenv("LOOMLIGHT_FABRICS_IMAGES"); keep && *keep) {
    std::filesystem::copy_file(b.dir / "seed1.exr", std::filesystem::path(keep) / "knit-closeup-cycles.exr",
                               std::filesystem::copy_options::overwrite_existing);
    if (std::string e = WriteExr(std::string(keep) + "/knit-closeup-loomlight.exr", loomlight.first, int(n.side),
                                 int(n.side));
        !e.empty())
      Progress("fabrics: %s\n", e.c_str());
  }
  std::filesystem::remove_all(b.dir);
  const ImageError ours = Compare(loomlight.second, loomlight.first), theirs = Compare(second, first);
  Table table({"renderer", "samples/pixel", "seconds", "PSNR dB, seed 2 vs seed 1", "rel. MSE", "mean radiance"}, 1);
  const auto mean = [](const std::vector<float>& v) {
    double sum = 0;
    for (float x : v) sum += x;
    return v.empty() ? 0 : sum / double(v.size());
  };
  table.Add({"Loomlight (client time)", std::to_string(n.spp), Fixed(loomlight.seconds, 2), Fixed(ours.psnr_db, 1),
             Sci(ours.relative_mse), Fixed(mean(loomlight.first), 4)});
  table.Add({"Cycles " + b.version + " (render operator)", std::to_string(n.spp), Fixed(b.seconds["seed1"], 2),
             Fixed(theirs.psnr_db, 1), Sci(theirs.relative_mse), Fixed(mean(first), 4)});
  return "**Cycles on the close-up** (`bench/cycles/knit.py`): the full-detail fibers of the same knit (generated in "
         "process with the server's job, so the same curves), as Cycles hair curves (round 3D curves, each fiber its "
         "own width) with the Principled Hair BSDF (an off-white cotton colour, roughness 0.4: alike, not Loomlight's "
         "fiber model), the same camera, the scene's sun (irradiance " + Fixed(sun.rgb.x, 1) + ") and a constant "
         "world of its ambient radiance (" + Fixed(scene.default_ambient, 2) + ", not seen by the camera), CPU, 2 "
         "threads, direct light only, no denoiser, " + std::to_string(n.spp) + " samples per pixel at seeds 1 and 2. "
         "Each renderer's two seeds against each other give its noise at equal samples (an image's own PSNR against "
         "a converged one is about 3 dB above); Cycles' time is inside its render operator (scene sync, curve BVH "
         "and sampling, not Blender's start-up nor the file write), best of " + std::to_string(n.runs) + ".\n\n" +
         TableBlock("mean radiance = over all pixels and channels (the materials differ, so the levels do too).",
                    table);
}

// The largest knit the server renders at full detail, seen close up (CloseUpCamera) and whole, at full detail and
// LoD, and the whole `n.stitches` patch at LoD (its full detail is over the server's limits); then Cycles on the
// close-up. `footprints`: the pixel footprints the server computed for Eq. 4 in the views of `stitches`.
std::string CloseUpPart(v1::Loomlight::Stub& stub, const FabricSizes& n, int stitches, Footprints* footprints) {
  struct Row {
    const char* name;
    v1::FiberDetail detail;
    uint64_t seed;
  };
  struct View {
    std::string name;
    int stitches;
    KnitCamera camera;      // fov_deg 0: the scene's framing
    std::vector<Row> rows;  // the first is the reference of the others
  };
  const Row full{"full detail", v1::FIBER_DETAIL_FULL, 1}, noise{"full detail, seed 2 (noise floor)", v1::FIBER_DETAIL_FULL, 2},
      lod{"LoD (Eq. 4)", v1::FIBER_DETAIL_LOD, 1}, automatic{"auto (Eq. 4, checked)", v1::FIBER_DETAIL_AUTO, 1};
  const KnitCamera close = CloseUpCamera(stitches);
  std::vector<View> views = {{"close-up", stitches, close, {full, noise, lod}},
                             {"whole patch", stitches, {}, {full, noise, lod, automatic}}};
  if (stitches < n.stitches) views.push_back({"whole patch", n.stitches, {}, {lod}});
  Table table({"knit", "view", "detail", "first call s", "set-up ms", "client ms", "kernel ms", "geometry",
               "mean vs full", "rel. MSE vs full", "PSNR dB vs full"},
              3);
  std::string choices;
  SeedPair close_up;
  for (const View& view : views) {
    const std::string knit = std::to_string(view.stitches) + " x " + std::to_string(view.stitches);
    std::vector<float> reference;
    for (const Row& row : view.rows) {
      Progress("fabrics: knit %s, %s, %s\n", knit.c_str(), view.name.c_str(), row.name);
      const v1::RenderRequest request =
          KnitRequest(n, view.stitches, view.camera.fov_deg > 0 ? &view.camera : nullptr, row.detail, row.seed);
      // The first call generates the fibers and builds the BVH (the server keeps them for the calls after).
      const RenderResult first = RenderOnce(stub, request);
      const RenderResult r = TimeRender(stub, request, n.runs, false);
      if (&row == &view.rows.front()) reference = r.image;
      const ImageError e = Compare(r.image, reference);
      const std::string geometry = GeometryChoice(r.last);
      if (row.detail == v1::FIBER_DETAIL_LOD && view.stitches == stitches && FootprintOf(geometry) > 0)
        footprints->push_back({knit + " " + view.name, FootprintOf(geometry)});
      if (&view == &views.front() && row.detail == v1::FIBER_DETAIL_FULL) {  // the close-up's two seeds
        (row.seed == 1 ? close_up.first : close_up.second) = r.image;
        if (row.seed == 1) close_up.seconds = r.client_seconds;
      }
      const bool against = &row != &view.rows.front();  // a view of one row has no reference
      table.Add({knit, view.name, row.name, Fixed(first.client_seconds, 2), Millis(first.last.setup_seconds()),
                 Millis(r.client_seconds), Millis(r.last.kernel_seconds()), geometry.substr(0, geometry.find(':')),
                 against ? Percent(MeanDifference(r.image, reference)) : "", against ? Sci(e.relative_mse) : "",
                 !against ? "" : e.mse > 0 ? Fixed(e.psnr_db, 1) : "identical"});
      choices += "- " + knit + ", " + view.name + ", " + row.name + ": " + geometry + "\n";
    }
  }
  const std::string whole = std::to_string(n.stitches) + " x " + std::to_string(n.stitches);
  const std::string within =
      stitches < n.stitches
          ? "The " + whole + " patch's full detail is over the Render RPC's fiber limits (" +
                Count(api::kMaxRenderFibers) + " fibers, " + Count(api::kMaxRenderFiberPoints) +
                " control points, fixed in server/api/render_rpc.h), so the comparisons are on the largest square "
                "knit within them (found by generating it in process at those limits), and the " + whole +
                " patch is rendered at LoD alone (its full-detail numbers are the table above). "
          : "";
  return "**Knit close-up (render).** Scene `" + std::string(kKnitScene) + "`, its light, a jersey in yarn cotton1 "
         "(seed 1), fiber preset `" + kFiberPreset + "`, " + Pixels(n.side) + " at " + std::to_string(n.spp) +
         " samples per pixel (the server's default sampling), shadows and ambient occlusion traced through the "
         "fibers, through an in-process server; seen close up (camera " + Triple(close.position) + " looking at " +
         Triple(close.look_at) + ", fov " + Fixed(kCloseUpFovDeg, 0) + " degrees: the knit's centre along the "
         "scene camera's line of sight from " + Fixed(kCloseUpDistance, 0) + " units, about 5 stitches across) and "
         "whole (the scene's camera, moved to frame the knit). " + within +
         "The first call generates the fibers and builds the BVH; the others find the server's scene cache. In "
         "each view the full-detail render at seed 1 is the reference; the same at seed 2 is the noise floor: an "
         "LoD image whose error is near it differs from full detail by no more than two renders' noise. The "
         "pictures are docs/images/design-knit-closeup.png, design-knit-full.png, design-knit-lod.png and "
         "design-knit-40.png (docs/designs.md's commands, the same requests).\n\n" +
         TableBlock("first call s = the first call as the client sees it (generation, BVH, the pilot and the "
                    "render); set-up ms = that call's scene set-up; client and kernel ms = the fastest of " +
                        std::to_string(n.runs) + " later calls; mean vs full = the image's sum over the view's "
                        "full-detail image's, less 1; rel. MSE = sum (x - full)^2 / sum full^2; geometry = the "
                        "server's choice.",
                    table) +
         "The server's geometry choices in full:\n\n" + choices + "\n" + kKnitLooks +
         CyclesCloseUp(n, stitches, close, close_up);
}

}  // namespace

std::string FabricsSection(const Sizes& sizes) {
  const FabricSizes n = SizesFor(sizes);
  const std::unique_ptr<api::LoomlightServer> server = StartServer(true);
  const std::unique_ptr<v1::Loomlight::Stub> stub = Connect(server->port(), -1);
  const std::string tartan = TartanPart(*stub, n);
  // The close-up first: the server's footprint for it is one of the in-process knit's levels of detail.
  std::string close_up;
  Footprints footprints;
  if (!render::SceneRegistry::Global().Find(kKnitScene))
    close_up = std::string("**Knit close-up (render).** Not run: the server has no scene `") + kKnitScene + "`.\n\n";
  else if (const int stitches = RenderableStitches(n.stitches); stitches < 1)
    close_up = "**Knit close-up (render).** Not run: no knit is within the Render RPC's fiber limits.\n\n";
  else
    close_up = CloseUpPart(*stub, n, stitches, &footprints);
  std::vector<KnitMeasure> measures;
  const std::string knit = KnitPart(n, footprints, &measures);

  const std::string method =
      "Issue 47's figures: a coloured weaving draft and a knit at fiber level. An in-process `LoomlightServer` "
      "(batching on) and one gRPC client for the renders and the slice; the knit's generation and BVH in process. "
      "Blender Cycles renders the knit's close-up from the same fibers when `blender` is on PATH; the tartan has "
      "no Cycles baseline: the woven model's BTF has no Cycles counterpart (a Cycles swatch would show a texture "
      "of our making, not the same material).";
  return Section("13. Fabrics as they are designed", method, tartan + knit + close_up);
}

}  // namespace loomlight::bench
