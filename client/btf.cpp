// `loomlight btf ...`: BTF assets on the server (SPEC.md section 7, Sattler et al.): make one from a material
// (create) or from an image set on the client's disk (images renders such a set, upload sends one), list them
// with their compression error, plot that error, delete one. Any material names an asset with --btf NAME.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/btf_grid.h"
#include "client/canvas.h"
#include "client/commands.h"
#include "client/image_module.h"
#include "client/material.h"
#include "client/progress.h"
#include "client/rpc.h"
#include "client/yarn_layouts.h"

namespace loomlight::client {
namespace {

namespace fs = std::filesystem;

// The PSNR the summaries single out: reconstructions above it are hard to tell from the stored images.
constexpr double kGoodPsnrDb = 40.0;
constexpr int kMaxResolution = 128;          // texels per side of an asset (CreateBtfRequest, UploadBtfHeader)
constexpr int kMaxComponents = 64;           // BtfCompression.max_components
constexpr int kDefaultImageResolution = 64;  // the server's default for `create`, so both kinds compare
// The image files `upload` looks for, in this order.
constexpr const char* kImageExtensions[] = {"exr", "png", "jpg"};

double mib(uint64_t bytes) { return static_cast<double>(bytes) / (1 << 20); }

// ---- Options shared by create, upload and images ----

const OptionSpec kGridOption = {
    "grid", "h1|h2", "view and light directions: H1 (theta 0, 17, .. 85) or H2 (0, 15, .. 75), 81 each (default h1)"};

OptionList compression_options() {
  return {
      {"components", "N", "principal components kept per view slot (default 16, at most 64 and directions - 1)"},
      {"target-psnr", "DB", "keep the fewest components, up to --components, whose reconstruction reaches DB"},
      {"replace", "", "replace an asset of the same name (else the call fails with ALREADY_EXISTS)"},
  };
}

// --components and --target-psnr; the server checks them against the grid.
v1::BtfCompression compression(const ParsedOptions& options) {
  v1::BtfCompression c;
  if (auto n = options.last("components")) c.set_max_components(parse_int(*n, "--components", 1, kMaxComponents));
  if (auto db = options.last("target-psnr")) {
    const double v = parse_number(*db, "--target-psnr");
    if (!(v > 0) || !std::isfinite(v)) throw UsageError("--target-psnr must be a positive number of dB");
    c.set_target_psnr_db(v);
  }
  return c;
}

int resolution(const ParsedOptions& options, int fallback) {
  const auto text = options.last("resolution");
  return text ? parse_int(*text, "--resolution", 1, kMaxResolution) : fallback;
}

// ---- An asset's summary ----

// The error at the kept component count (errors run 0 .. kept; the last row if the server says otherwise).
const v1::BtfErrorRow* kept_row(const v1::BtfAssetInfo& asset) {
  for (const v1::BtfErrorRow& row : asset.errors())
    if (row.components() == asset.components()) return &row;
  return asset.errors().empty() ? nullptr : &*asset.errors().rbegin();
}

std::string psnr_text(const v1::BtfAssetInfo& asset) {
  const v1::BtfErrorRow* row = kept_row(asset);
  return row ? format_value("%.1f", row->psnr_db()) : "-";
}

void print_asset(const v1::BtfAssetInfo& asset) {
  std::printf("%s: %s\n", asset.name().c_str(), asset.source().c_str());
  std::printf("  grid %s (views and lights), %ux%u texels, %u components per view slot: %.2f MiB "
              "(the images as float16: %.2f MiB)\n",
              btf_grid_label(asset.grid()).c_str(), asset.width(), asset.height(), asset.components(),
              mib(asset.bytes()), mib(asset.images_float16_bytes()));
  std::printf("  peak %.4g, rms %.4g (1/sr); synthesis %.2f s, compression %.2f s\n", asset.peak(), asset.rms(),
              asset.synthesis_seconds(), asset.compression_seconds());
  const auto good = std::find_if(asset.errors().begin(), asset.errors().end(),
                                 [](const v1::BtfErrorRow& row) { return row.psnr_db() >= kGoodPsnrDb; });
  if (good != asset.errors().end())
    std::printf("  %g dB from %u components (%.2f MiB)\n", kGoodPsnrDb, good->components(), mib(good->bytes()));
  else
    std::printf("  no component count reaches %g dB\n", kGoodPsnrDb);
  std::printf("  %10s  %12s  %9s  %9s\n", "components", "rmse (1/sr)", "PSNR (dB)", "MiB");
  for (const v1::BtfErrorRow& row : asset.errors())
    std::printf("  %10u  %12.4g  %9.2f  %9.2f\n", row.components(), row.rmse(), row.psnr_db(), mib(row.bytes()));
}

const v1::BtfAssetInfo& find_asset(const v1::ListBtfsResponse& list, const std::string& name) {
  for (const v1::BtfAssetInfo& asset : list.assets())
    if (asset.name() == name) return asset;
  throw std::runtime_error("no BTF asset named '" + name + "' (see `loomlight btf list`)");
}

void print_list(const v1::ListBtfsResponse& list) {
  const std::string bound = list.max_bytes() ? format_value(" of %.2f MiB", mib(list.max_bytes())) : "";
  if (list.assets().empty()) {
    std::printf("no BTF assets (0 MiB%s)\n", bound.c_str());
    return;
  }
  int name_width = 4;
  for (const v1::BtfAssetInfo& asset : list.assets()) name_width = std::max<int>(name_width, asset.name().size());
  std::printf("%-*s  %-20s  %-9s  %10s  %9s  %9s  %s\n", name_width, "NAME", "DIRECTIONS", "TEXELS", "COMPONENTS",
              "MiB", "PSNR (dB)", "SOURCE");
  uint64_t total = 0;
  for (const v1::BtfAssetInfo& asset : list.assets()) {
    const std::string texels = std::to_string(asset.width()) + "x" + std::to_string(asset.height());
    std::printf("%-*s  %-20s  %-9s  %10u  %9.2f  %9s  %s\n", name_width, asset.name().c_str(),
                btf_grid_label(asset.grid()).c_str(), texels.c_str(), asset.components(), mib(asset.bytes()),
                psnr_text(asset).c_str(), asset.source().c_str());
    total += asset.bytes();
  }
  std::printf("%d assets, %.2f MiB%s\n", list.assets_size(), mib(total), bound.c_str());
}

// ---- The plot of an asset's error and size against its component count ----

// Layout in units of 1/800 of the width (client/canvas.h): the title block, the PSNR panel, the size panel.
constexpr double kTop = 120, kLeft = 80, kRight = 40, kPsnrHeight = 300, kPanelGap = 90, kSizeHeight = 200,
                 kBottom = 60;
constexpr int kPlotWidth = 800;
constexpr double kMarkerUnits = 4;

// One curve through the finite points (an exact reconstruction's PSNR is infinite), with a cross at each.
void draw_curve(Canvas& canvas, const Axes& axes, const std::vector<double>& x, const std::vector<double>& y,
                const Color& color) {
  const double m = kMarkerUnits * canvas.unit();
  for (std::size_t i = 0; i < x.size(); ++i) {
    if (!std::isfinite(y[i])) continue;
    const Point p = axes.at(x[i], y[i]);
    canvas.line({p.x - m, p.y - m}, {p.x + m, p.y + m}, color, kMarkerWidth);
    canvas.line({p.x - m, p.y + m}, {p.x + m, p.y - m}, color, kMarkerWidth);
    if (i + 1 < x.size() && std::isfinite(y[i + 1])) canvas.line(p, axes.at(x[i + 1], y[i + 1]), color, kCurveWidth);
  }
}

double finite_max(const std::vector<double>& v) {
  double top = 0;
  for (double y : v)
    if (std::isfinite(y)) top = std::max(top, y);
  return top;
}

void plot_asset(const v1::BtfAssetInfo& asset, const std::string& path) {
  if (asset.errors().empty()) throw std::runtime_error("asset '" + asset.name() + "' has no error table to plot");
  std::vector<double> components, psnr, size;
  for (const v1::BtfErrorRow& row : asset.errors()) {
    components.push_back(row.components());
    psnr.push_back(row.psnr_db());
    size.push_back(mib(row.bytes()));
  }
  const double x_max = std::max(1.0, *std::max_element(components.begin(), components.end()));
  const double x_step = std::max(1.0, nice_step(x_max));

  const double height_units = kTop + kPsnrHeight + kPanelGap + kSizeHeight + kBottom;
  Canvas canvas(kPlotWidth, static_cast<int>(std::lround(kPlotWidth * height_units / kUnitsPerWidth)));
  const double u = canvas.unit(), left = kLeft * u, right = (kUnitsPerWidth - kRight) * u;
  // The 40 dB line stays in view, so a curve below it shows how far off it is.
  const double psnr_top = std::max(finite_max(psnr), kGoodPsnrDb) * 1.1;
  const Axes psnr_axes{{left, kTop * u}, {right, (kTop + kPsnrHeight) * u}, x_max, psnr_top};
  const double size_top_units = kTop + kPsnrHeight + kPanelGap;
  const double size_max = finite_max(size) > 0 ? finite_max(size) * 1.1 : 1.0;
  const Axes size_axes{{left, size_top_units * u}, {right, (size_top_units + kSizeHeight) * u}, x_max, size_max};

  draw_axes(canvas, psnr_axes, x_step, nice_step(psnr_top), "components per view slot",
            "PSNR (dB) of the reconstruction against the stored images", true);
  canvas.dashed_line(psnr_axes.at(0, kGoodPsnrDb), psnr_axes.at(x_max, kGoodPsnrDb), kRim, kMarkerWidth);
  canvas.text({psnr_axes.bottom_right.x - 6 * u, psnr_axes.at(0, kGoodPsnrDb).y - 10 * u},
              format_value("%g dB", kGoodPsnrDb), kLabelFont, kFaintText, Align::kEnd);
  draw_curve(canvas, psnr_axes, components, psnr, kChannelColors[2]);
  draw_axes(canvas, size_axes, x_step, nice_step(size_max), "components per view slot",
            "size of the asset (MiB, float32)", true);
  draw_curve(canvas, size_axes, components, size, kChannelColors[0]);

  draw_title(canvas, "BTF asset " + asset.name(),
             {asset.source(), "grid " + btf_grid_label(asset.grid()) + ", " + std::to_string(asset.width()) + "x" +
                                  std::to_string(asset.height()) + " texels; kept " +
                                  std::to_string(asset.components()) + " components, " +
                                  format_value("%.2f MiB", mib(asset.bytes())) + " (images as float16: " +
                                  format_value("%.2f MiB)", mib(asset.images_float16_bytes()))});
  canvas.write(path);
}

// ---- Commands ----

int run_create(const ParsedOptions& options) {
  v1::CreateBtfRequest request;
  request.set_name(options.positional[0]);
  *request.mutable_material() = material_request(options).material();
  request.mutable_grid()->set_preset(btf_grid_option(options));
  if (options.has("resolution")) request.set_resolution(resolution(options, 0));
  *request.mutable_compression() = compression(options);
  request.set_replace(options.has("replace"));
  const bool fibers = options.has("fibers");
  if (!fibers && (options.has("yarn") || options.has("weave") || options.has("spacing") || options.has("crimp") ||
                  options.has("rays") || options.has("knit")))
    throw UsageError("--yarn, --weave, --spacing, --crimp, --knit and --rays are for --fibers");
  if (fibers) {
    v1::FiberBtfSource& source = *request.mutable_fibers();
    if (!knit_from_options(options, source.mutable_knit(), false)) source.clear_knit();
    else if (options.has("weave") || options.has("spacing") || options.has("crimp"))
      throw UsageError("--knit: a knit has no --weave, --spacing or --crimp (its spacings: --wale-spacing, --course-spacing)");
    if (auto yarn = options.last("yarn")) source.mutable_yarn()->set_preset(*yarn);
    if (auto weave = options.last("weave")) source.mutable_woven()->mutable_weave()->set_preset(*weave);
    if (auto spacing = options.last("spacing"))
      source.mutable_woven()->set_yarn_spacing(parse_number(*spacing, "--spacing"));
    if (auto crimp = options.last("crimp")) source.mutable_woven()->set_crimp(parse_number(*crimp, "--crimp"));
    if (auto rays = options.last("rays")) source.set_samples_per_texel(uint32_t(parse_int(*rays, "--rays", 1, 64)));
  }

  // One bar per stage: synthesis and compression each count the view slots.
  std::string stage;
  std::optional<ProgressBar> progress;
  std::optional<v1::BtfAssetInfo> asset;
  try {
    Client(options).create_btf(request, [&](const v1::CreateBtfProgress& update) {
      if (update.stage() != stage || !progress) {
        if (progress) progress->end();
        stage = update.stage();
        progress.emplace("views (" + stage + ")");
      }
      progress->update(update.views_done(), update.views());
      if (update.has_asset()) asset = update.asset();
    });
  } catch (...) {
    if (progress) progress->end();
    throw;
  }
  if (progress) progress->end();
  if (!asset) throw std::runtime_error("the server finished without the asset");
  print_asset(*asset);
  return 0;
}

int run_list(const ParsedOptions& options) {
  const auto plot = options.last("plot");
  if (plot && options.positional.empty()) throw UsageError("--plot needs the asset's NAME");
  const v1::ListBtfsResponse list = Client(options).list_btfs();
  if (options.positional.empty()) {
    print_list(list);
    return 0;
  }
  const v1::BtfAssetInfo& asset = find_asset(list, options.positional[0]);
  if (!plot) {
    print_asset(asset);
    return 0;
  }
  plot_asset(asset, *plot);
  std::printf("%s: PSNR and size against components -> %s\n", asset.name().c_str(), plot->c_str());
  return 0;
}

int run_delete(const ParsedOptions& options) {
  Client(options).delete_btf(options.positional[0]);
  std::printf("deleted %s\n", options.positional[0].c_str());
  return 0;
}

v1::ImageFormat image_format(const ParsedOptions& options) {
  const std::string name = options.last("format").value_or("exr");
  if (name == "exr") return v1::IMAGE_FORMAT_EXR;
  if (name == "png") return v1::IMAGE_FORMAT_PNG;
  throw UsageError("--format: expected exr or png, got '" + name + "'");
}

int run_images(const ParsedOptions& options) {
  const fs::path dir = options.positional[0];
  const v1::EvaluateRequest material = material_request(options);
  const std::string grid = btf_grid_option(options);
  const std::vector<Vec3> directions = btf_grid_directions(btf_grid_rings(grid));
  v1::TextureSliceRequest request;
  *request.mutable_material() = material.material();
  request.set_precision(material.precision());
  request.mutable_region()->set_u_max(1);  // one pattern repeat
  request.mutable_region()->set_v_max(1);
  request.set_width(resolution(options, kDefaultImageResolution));
  request.set_height(request.width());
  request.set_samples_per_pixel(1);
  request.set_format(image_format(options));
  const std::string extension = request.format() == v1::IMAGE_FORMAT_EXR ? "exr" : "png";
  if (request.format() == v1::IMAGE_FORMAT_PNG) {
    // One exposure for the whole set (the slice's automatic one differs per image); upload with
    // --value-scale 1/X to get f back.
    const double exposure = parse_number(options.last("exposure").value_or("1"), "--exposure");
    if (!(exposure > 0) || !std::isfinite(exposure)) throw UsageError("--exposure must be a positive number");
    request.set_exposure(exposure);
  } else if (options.has("exposure")) {
    throw UsageError("--exposure is for --format png (EXR holds f unscaled)");
  }
  std::error_code error;
  fs::create_directories(dir, error);
  if (error) throw std::runtime_error("cannot create " + dir.string() + ": " + error.message());

  Client client(options);
  ProgressBar progress("images");
  const std::size_t total = directions.size() * directions.size();
  double server_seconds = 0;
  const auto start = std::chrono::steady_clock::now();
  try {
    for (std::size_t view = 0; view < directions.size(); ++view)
      for (std::size_t light = 0; light < directions.size(); ++light) {
        request.clear_wi();
        request.clear_wo();
        for (double c : directions[light]) request.add_wi(static_cast<float>(c));
        for (double c : directions[view]) request.add_wo(static_cast<float>(c));
        const v1::TextureSliceResponse response = client.texture_slice(request);
        write_local_file((dir / btf_image_name(view, light, extension)).string(), response.image());
        server_seconds += response.total_seconds();
        progress.update(view * directions.size() + light + 1, total);
      }
  } catch (...) {
    progress.end();
    throw;
  }
  progress.end();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const std::string format =
      request.format() == v1::IMAGE_FORMAT_EXR ? "EXR" : format_value("PNG at exposure %g", request.exposure());
  std::printf("%s images (grid %s, views x lights), %ux%u %s, in %.1f s (server %.1f s) -> %s\n",
              ProgressBar::grouped(total).c_str(), btf_grid_label(btf_grid_rings(grid)).c_str(), request.width(),
              request.height(), format.c_str(), seconds, server_seconds,
              (dir / ("view_VVV_light_LLL." + extension)).string().c_str());
  return 0;
}

// The file of one (view, light) pair: DIR/view_VVV_light_LLL with the first extension found.
std::string image_file(const fs::path& dir, std::size_t view, std::size_t light) {
  for (const char* extension : kImageExtensions) {
    const fs::path path = dir / btf_image_name(view, light, extension);
    if (fs::is_regular_file(path)) return path.string();
  }
  throw UsageError("no image " + (dir / btf_image_name(view, light, "{exr,png,jpg}")).string());
}

// The header announces one size for every image: the first one's (the server checks the others).
void set_image_size(const std::string& path, v1::UploadBtfHeader& header) {
  int width = 0, height = 0;
  if (std::string error = image_module().image_size(path, &width, &height); !error.empty()) throw UsageError(error);
  header.set_width(static_cast<uint32_t>(width));
  header.set_height(static_cast<uint32_t>(height));
}

int run_upload(const ParsedOptions& options) {
  const fs::path dir = options.positional[1];
  const std::string grid = btf_grid_option(options);
  const std::vector<Vec3> directions = btf_grid_directions(btf_grid_rings(grid));
  // Every file is found before anything is sent: a gap would otherwise fail the upload part way.
  std::vector<std::string> files;
  for (std::size_t view = 0; view < directions.size(); ++view)
    for (std::size_t light = 0; light < directions.size(); ++light) files.push_back(image_file(dir, view, light));

  v1::UploadBtfHeader header;
  header.set_name(options.positional[0]);
  header.mutable_grid()->set_preset(grid);
  set_image_size(files.front(), header);
  *header.mutable_compression() = compression(options);
  header.set_replace(options.has("replace"));
  if (auto scale = options.last("value-scale")) {
    const double s = parse_number(*scale, "--value-scale");
    if (!(s > 0) || !std::isfinite(s)) throw UsageError("--value-scale must be a positive number");
    header.set_value_scale(s);
  }

  ProgressBar progress("images sent");
  std::size_t sent = 0;
  v1::BtfAssetInfo asset;
  try {
    asset = Client(options).upload_btf(header, [&](v1::BtfImage& image) {
      if (sent == files.size()) return false;
      for (double c : directions[sent / directions.size()]) image.add_view(static_cast<float>(c));
      for (double c : directions[sent % directions.size()]) image.add_light(static_cast<float>(c));
      image.set_data(read_local_file(files[sent], "btf upload"));
      progress.update(++sent, files.size());
      return true;
    });
  } catch (...) {
    progress.end();
    throw;
  }
  progress.end();
  print_asset(asset);
  return 0;
}

OptionList create_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      kGridOption,
      {"resolution", "N", "texels per side of the tile, one pattern repeat (default 64, at most 128)"},
      {"fibers", "", "capture a fiber-level woven patch instead (MATERIAL: a fiber model, e.g. --preset cotton)"},
      {"yarn", "PRESET", "--fibers: the yarn, cotton1 (default), cotton2, polyester1, rayon2 or silk1"},
      {"weave", "PRESET", "--fibers: the weave, a woven preset's pattern (default cotton_twill)"},
      {"spacing", "S", "--fibers: yarn centre spacing (default: the server's)"},
      {"crimp", "C", "--fibers: how far yarns bend over and under, 0..1 (default 1)"},
      {"rays", "N", "--fibers: rays per texel, 1..64 (default 4)"},
  });
  // --fibers --knit: a knit's tile (one repeat of its stitch; the server lays out the patch around it).
  const OptionList knit = knit_options(false);
  options.insert(options.end(), knit.begin(), knit.end());
  const OptionList compression = compression_options();
  options.insert(options.end(), compression.begin(), compression.end());
  return options;
}

OptionList upload_options() {
  OptionList options = {kGridOption};
  const OptionList compression = compression_options();
  options.insert(options.end(), compression.begin(), compression.end());
  options.push_back({"value-scale", "S", "f = pixel value x S (default 1), e.g. 1/X for PNGs written at exposure X"});
  return options;
}

OptionList images_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      kGridOption,
      {"resolution", "N", "pixels per side of each image, one pattern repeat (default 64, at most 128)"},
      {"format", "exr|png", "OpenEXR of f unscaled (default), or 8-bit sRGB PNG after --exposure"},
      {"exposure", "X", "png: f x X, clamped to 1, for every image alike (default 1)"},
  });
  return options;
}

const Command& create_command() {
  static const Command command = {
      "btf create",
      "NAME MATERIAL [--grid h1|h2] [--resolution N] [--components N] [--target-psnr DB] [--replace]\n"
      "  [--fibers [--yarn PRESET] [--weave PRESET [--spacing S] [--crimp C] | --knit jersey|rib] [--rays N]]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "make a BTF asset from a spatially varying material, or rendered fibers, on the server",
      "The server samples f at the texel centres of one pattern repeat for every view and light of the grid,\n"
      "compresses each view slot's light images with PCA and stores the asset as NAME (1-64 of A-Za-z0-9_.-).\n"
      "With --fibers it renders instead a fiber-level woven patch (the yarn laid out by the weave, each fiber\n"
      "shaded by MATERIAL, a fiber model), one repeat seen by parallel rays from each view and lit from each light;\n"
      "with --knit a knit's instead, its tile one repeat of the stitch.\n"
      "A progress bar per stage is drawn on stderr when it is a terminal; then the asset's summary is\n"
      "printed: grid, texels, components, size, the fewest components reaching 40 dB, and the error table.\n"
      "Large assets may need a longer --timeout (0 = none).\n"
      "Example: loomlight btf create twill --preset cotton_twill --components 16 --target-psnr 40\n"
      "Fibers:  loomlight btf create twill_fibers --preset cotton --fibers --grid h2 --resolution 32\n"
      "A knit:  loomlight btf create jersey_fibers --preset cotton --fibers --knit jersey --grid h2 --resolution 32",
      create_options(),
      run_create,
      1,
      1,
  };
  return command;
}

const Command& list_command() {
  static const Command command = {
      "btf list",
      "[NAME [--plot FILE.png]]",
      "list the BTF assets, or show one, or plot its error against its components",
      "Without NAME: one line per asset (name, directions, texels, components kept, MiB, PSNR at the kept\n"
      "components, source) and the store's total. With NAME: that asset's summary and error table; with\n"
      "--plot as well, a PNG of PSNR (above) and size (below) against the components kept.\n"
      "Example: loomlight btf list twill --plot twill_error.png",
      {{"plot", "FILE.png", "write a plot of asset NAME's PSNR and size against components"}},
      run_list,
      0,
      1,
  };
  return command;
}

const Command& delete_command() {
  static const Command command = {
      "btf delete",
      "NAME",
      "delete a BTF asset",
      "",
      {},
      run_delete,
      1,
      1,
  };
  return command;
}

const Command& images_command() {
  static const Command command = {
      "btf images",
      "DIR MATERIAL [--grid h1|h2] [--resolution N] [--format exr|png] [--exposure X]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "render a material's BTF image set into a directory (TextureSlice per view and light)",
      "Writes DIR/view_VVV_light_LLL.exr (or .png) for every pair of grid directions: one pattern repeat,\n"
      "N x N pixels at their centres, f in 1/sr (EXR: exact floats). Directions are numbered ring by ring\n"
      "from theta 0; within a ring at azimuths 360 j / count degrees, j from 0. `btf upload` reads them back.\n"
      "Example: loomlight btf images twill_images --preset cotton_twill --grid h1 --resolution 64",
      images_options(),
      run_images,
      1,
      1,
  };
  return command;
}

const Command& upload_command() {
  static const Command command = {
      "btf upload",
      "NAME DIR [--grid h1|h2] [--components N] [--target-psnr DB] [--replace] [--value-scale S]",
      "make a BTF asset from an image set on this machine",
      "Reads DIR/view_VVV_light_LLL.exr, .png or .jpg for every pair of grid directions (numbered as\n"
      "`btf images` writes them), sends each file's bytes with its view and light directions, and prints\n"
      "the stored asset's summary as `btf create` does. Every image must be the size of the first.\n"
      "Large sets may need a longer --timeout (0 = none).\n"
      "Example: loomlight btf upload twill_measured twill_images --components 16",
      upload_options(),
      run_upload,
      2,
      2,
  };
  return command;
}

}  // namespace

const Command& btf_command() {
  static const Command command = {
      "btf",
      "COMMAND ARGUMENTS [options]",
      "make, list and delete BTF assets: compressed image sets of a material",
      "A BTF asset (SPEC.md section 7) is a material's f over one pattern repeat for a grid of view and light\n"
      "directions, compressed per view slot with PCA. Use one anywhere a material is given: --btf NAME\n"
      "(model btf, parameter asset=NAME; other parameters with --param, e.g. --param components=8).",
      {},
      nullptr,
      0,
      0,
      {&create_command(), &list_command(), &delete_command(), &images_command(), &upload_command()},
  };
  return command;
}

}  // namespace loomlight::client
