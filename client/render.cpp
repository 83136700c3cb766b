// `loomlight render`: a thumbnail of a material on a preset scene (Render RPC), written as PNG, JPEG or
// EXR, with a progress bar on stderr and a report of the fidelity the server chose per object.
#include <cctype>
#include <cstdio>
#include <fstream>
#include <optional>
#include <stdexcept>
#include <string>

#include "client/commands.h"
#include "client/job_requests.h"
#include "client/material.h"
#include "client/progress.h"
#include "client/rpc.h"
#include "client/yarn_layouts.h"

namespace loomlight::client {
namespace {

std::string lower(std::string text) {
  for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return text;
}

v1::RenderFormat parse_format(const std::string& name, const std::string& what) {
  const std::string n = lower(name);
  if (n == "png") return v1::RENDER_FORMAT_PNG;
  if (n == "jpg" || n == "jpeg") return v1::RENDER_FORMAT_JPEG;
  if (n == "exr") return v1::RENDER_FORMAT_EXR;
  if (n == "webp") return v1::RENDER_FORMAT_WEBP;
  throw UsageError(what + ": expected png, jpeg, webp or exr, got '" + name + "'");
}

// --format, else the output file's extension.
v1::RenderFormat output_format(const ParsedOptions& options, const std::string& out) {
  if (auto format = options.last("format")) return parse_format(*format, "--format");
  const auto dot = out.rfind('.');
  if (dot == std::string::npos) throw UsageError("cannot tell the format from '" + out + "': give --format");
  return parse_format(out.substr(dot + 1), "--format (from the extension of " + out + ")");
}

// --scene: the names this client always took as their ScenePreset (servers before ListScenes know only those),
// any other as a registered scene's name (`loomlight scenes`), which the server checks.
void set_scene(const std::string& name, v1::RenderRequest& request) {
  const std::string n = lower(name);
  if (n == "sphere") request.set_scene(v1::SCENE_SPHERE);
  else if (n == "cylinders") request.set_scene(v1::SCENE_CYLINDERS);
  else if (n == "swatch") request.set_scene(v1::SCENE_SWATCH);
  else if (n == "curtain") request.set_scene(v1::SCENE_CURTAIN);
  else if (n == "yarn") request.set_scene(v1::SCENE_YARN);
  else if (n == "woven-patch") request.set_scene(v1::SCENE_WOVEN_PATCH);
  else request.set_scene_name(name);
}

void add_triple(google::protobuf::RepeatedField<double>* out, const std::string& text, const std::string& what) {
  for (double v : parse_numbers(text, what, 3)) out->Add(v);
}

// "dir:X,Y,Z:R,G,B" (toward the light; RGB irradiance) or "point:X,Y,Z:R,G,B" (position; RGB intensity).
void add_light(v1::RenderRequest& request, const std::string& text) {
  const auto first = text.find(':'), second = text.find(':', first == std::string::npos ? 0 : first + 1);
  if (first == std::string::npos || second == std::string::npos)
    throw UsageError("--light needs dir:X,Y,Z:R,G,B or point:X,Y,Z:R,G,B, got '" + text + "'");
  const std::string kind = text.substr(0, first);
  v1::RenderLight* light = request.add_lights();
  const std::string where = text.substr(first + 1, second - first - 1), rgb = text.substr(second + 1);
  if (kind == "dir") {
    light->set_type(v1::RenderLight::TYPE_DIRECTIONAL);
    add_triple(light->mutable_direction(), where, "--light direction");
  } else if (kind == "point") {
    light->set_type(v1::RenderLight::TYPE_POINT);
    add_triple(light->mutable_position(), where, "--light position");
  } else {
    throw UsageError("--light: expected dir or point, got '" + kind + "'");
  }
  add_triple(light->mutable_rgb(), rgb, "--light rgb");
}

// --name VALUE as the proto enum value PREFIX + VALUE in capitals (its generated parser; "" when absent).
template <class Enum>
std::optional<Enum> enum_option(const ParsedOptions& options, const std::string& name, const std::string& prefix,
                                bool (*parse)(const std::string&, Enum*)) {
  const auto text = options.last(name);
  if (!text) return std::nullopt;
  std::string upper = *text;
  for (char& c : upper) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  Enum value{};
  if (!parse(prefix + upper, &value)) throw UsageError("--" + name + ": unknown value '" + *text + "' (see --help)");
  return value;
}

void parse_size(const std::string& text, v1::RenderRequest& request) {
  const auto x = text.find('x');
  if (x == std::string::npos) throw UsageError("--size needs WIDTHxHEIGHT, got '" + text + "'");
  request.set_width(parse_int(text.substr(0, x), "--size width", 1, 1 << 20));
  request.set_height(parse_int(text.substr(x + 1), "--size height", 1, 1 << 20));
}

}  // namespace

// --mesh FILE (sent with the request) or --mesh-name NAME (stored: `loomlight mesh upload`) into *mesh (left
// unset without them), and each --material MESH_MATERIAL=PRESET binding into *bindings (render and fit).
void mesh_from_options(const ParsedOptions& options, v1::MeshSource* mesh,
                       google::protobuf::RepeatedPtrField<v1::MaterialBinding>* bindings) {
  bool has_mesh = true;
  if (auto file = options.last("mesh")) mesh->mutable_data()->set_data(read_local_file(*file, "--mesh"));
  else if (auto name = options.last("mesh-name")) mesh->set_name(*name);
  else has_mesh = false;
  for (const auto& entry : options.matching({"material"})) {
    const auto eq = entry.value.find('=');
    if (eq == std::string::npos || eq == 0 || eq + 1 == entry.value.size())
      throw UsageError("--material: expected MESH_MATERIAL=PRESET, got '" + entry.value + "'");
    if (!has_mesh) throw UsageError("--material binds a mesh's material: give --mesh or --mesh-name");
    v1::MaterialBinding* binding = bindings->Add();
    binding->set_mesh_material(entry.value.substr(0, eq));
    binding->mutable_material()->set_preset(entry.value.substr(eq + 1));
  }
}

v1::RenderRequest render_request(const ParsedOptions& options, const std::string& out) {
  v1::RenderRequest request;
  v1::MeshSource mesh;
  mesh_from_options(options, &mesh, request.mutable_materials());
  if (mesh.source_case() != v1::MeshSource::SOURCE_NOT_SET) *request.mutable_mesh() = std::move(mesh);
  // A mesh whose materials are all bound by --material needs no MATERIAL.
  const bool bound_only = request.materials_size() > 0 && !options.has("preset") && !options.has("model") &&
                          !options.has("btf");
  if (!bound_only) {
    const v1::EvaluateRequest material = material_request(options);
    *request.mutable_material() = material.material();
    request.set_precision(material.precision());
  }
  const bool knit = knit_from_options(options, request.mutable_knit());
  if (!knit) request.clear_knit();
  const bool curves = curves_from_options(options, request.mutable_curves());
  if (!curves) request.clear_curves();
  // A knit or curves without --scene: the scene that shows them.
  const char* default_scene = knit ? "knit_patch" : curves ? "yarn_curves" : "sphere";
  if (!request.has_mesh()) set_scene(options.last("scene").value_or(default_scene), request);
  else if (options.has("scene")) throw UsageError("--scene: a mesh is the scene; give one or the other");
  if (auto v = enum_option(options, "background", "BACKGROUND_", v1::Background_Parse)) request.set_background(*v);
  if (auto views = options.last("views")) request.set_views(static_cast<uint32_t>(parse_int(*views, "--views", 1, 1000)));
  if (auto lighting = options.last("lighting")) request.set_lighting(*lighting);
  if (auto unit = options.last("texture-unit")) {
    if (*unit == "uv") request.set_texture_scale_unit(v1::TEXTURE_SCALE_UNIT_PER_UV_UNIT);
    else if (*unit == "metre" || *unit == "meter") request.set_texture_scale_unit(v1::TEXTURE_SCALE_UNIT_PER_METRE);
    else throw UsageError("--texture-unit: expected uv or metre, got '" + *unit + "'");
  }
  for (const auto& entry : options.matching({"scene-param"}))
    *request.add_scene_params() = parse_param(entry.value, "--scene-param");
  parse_size(options.last("size").value_or("256x256"), request);
  if (auto spp = options.last("spp")) request.set_samples_per_pixel(parse_int(*spp, "--spp", 1, 1 << 20));
  if (auto seed = options.last("seed")) request.set_seed(static_cast<uint64_t>(parse_int(*seed, "--seed", 0, 1 << 30)));
  if (auto scale = options.last("texture-scale")) request.set_texture_scale(parse_number(*scale, "--texture-scale"));
  if (auto rotation = options.last("texture-rotation"))
    request.set_texture_rotation_deg(parse_number(*rotation, "--texture-rotation"));
  for (const auto& entry : options.matching({"light"})) add_light(request, entry.value);
  if (auto env = options.last("env"); env && *env != "builtin") request.mutable_environment()->set_name(*env);
  if (auto file = options.last("env-file"))
    request.mutable_environment()->set_data(read_local_file(*file, "--env-file"));
  if ((options.last("env") || options.last("env-file")) && !request.has_environment())
    request.mutable_environment();  // the built-in sky, explicitly
  if (auto intensity = options.last("env-intensity"))
    request.mutable_environment()->set_intensity(parse_number(*intensity, "--env-intensity"));
  if (auto rotation = options.last("env-rotation"))
    request.mutable_environment()->set_rotation_deg(parse_number(*rotation, "--env-rotation"));
  const auto eye = options.last("camera"), target = options.last("look-at");
  if (eye || target) {
    if (!eye || !target) throw UsageError("--camera and --look-at go together");
    add_triple(request.mutable_camera()->mutable_position(), *eye, "--camera");
    add_triple(request.mutable_camera()->mutable_look_at(), *target, "--look-at");
    if (auto fov = options.last("fov")) request.mutable_camera()->set_fov_deg(parse_number(*fov, "--fov"));
  } else if (options.has("fov")) {
    throw UsageError("--fov needs --camera and --look-at");
  }
  if (auto target_error = options.last("error-target"))
    request.set_error_target(parse_number(*target_error, "--error-target"));
  request.set_force_full_fidelity(options.has("full-fidelity"));
  if (auto exposure = options.last("exposure")) request.set_exposure(parse_number(*exposure, "--exposure"));
  if (options.has("yarn") || options.has("yarn-param")) yarn_from_options(options, request.mutable_yarn());
  if (auto weave = options.last("weave")) request.mutable_woven()->mutable_weave()->set_preset(*weave);
  if (auto v = enum_option(options, "fiber-detail", "FIBER_DETAIL_", v1::FiberDetail_Parse)) request.set_fiber_detail(*v);
  if (auto v = enum_option(options, "fiber-shadows", "FIBER_SHADOWS_", v1::FiberShadows_Parse))
    request.set_fiber_shadows(*v);
  if (auto v = enum_option(options, "fiber-occlusion", "FIBER_OCCLUSION_", v1::FiberOcclusion_Parse))
    request.set_fiber_occlusion(*v);
  if (auto ambient = options.last("ambient")) request.set_ambient(parse_number(*ambient, "--ambient"));
  if (auto v = enum_option(options, "btf-environment", "BTF_ENVIRONMENT_", v1::BtfEnvironment_Parse))
    request.set_btf_environment(*v);
  if (auto v = enum_option(options, "sampling", "SAMPLING_", v1::Sampling_Parse)) request.set_sampling(*v);
  request.set_format(output_format(options, out));
  return request;
}

namespace {

const char* format_name(v1::RenderFormat format) {
  switch (format) {
    case v1::RENDER_FORMAT_JPEG: return "JPEG";
    case v1::RENDER_FORMAT_EXR: return "EXR";
    case v1::RENDER_FORMAT_WEBP: return "WebP";
    default: return "PNG";
  }
}

void print_fidelity(const v1::RenderUpdate& update) {
  std::printf("fidelity (error target %.3g):\n", update.error_target());
  for (const v1::ObjectFidelity& object : update.fidelity()) {
    std::printf("  %s [%s], estimated error %.3g:\n", object.object().c_str(), object.model().c_str(),
                object.estimated_error());
    for (const v1::RungShare& rung : object.rungs())
      std::printf("    %.1f%% of its samples: %s\n", 100 * rung.share(), rung.rung().c_str());
    for (const v1::FidelityChoice& c : object.choices())
      std::printf("    %s %s (full %s, error %.3g): %s\n", c.aspect().c_str(), c.chosen().c_str(), c.full().c_str(),
                  c.estimated_error(), c.reason().c_str());
  }
}

int run_render(const ParsedOptions& options) {
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("render needs --out FILE (.png, .jpg, .webp or .exr)");
  const v1::RenderRequest request = render_request(options, *out);
  ProgressBar progress("samples");
  v1::RenderUpdate last;
  try {
    Client(options).render(request, [&](const v1::RenderUpdate& update) {
      progress.update(update.samples_done(), update.samples_total());
      if (!update.image().empty()) last = update;
    });
  } catch (...) {
    progress.end();
    throw;
  }
  progress.end();
  if (last.image().empty()) throw std::runtime_error("the server finished without an image");
  const auto write = [](const std::string& path, const std::string& bytes) {
    std::ofstream file(path, std::ios::binary);
    file.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    if (!file) throw std::runtime_error("cannot write " + path);
  };
  if (last.views_size() > 1) {  // a turntable: FILE's stem, -NN, its extension
    const auto dot = out->rfind('.');
    const std::string stem = dot == std::string::npos ? *out : out->substr(0, dot);
    const std::string extension = dot == std::string::npos ? "" : out->substr(dot);
    for (int k = 0; k < last.views_size(); ++k) {
      char suffix[16];
      std::snprintf(suffix, sizeof suffix, "-%02d", k);
      write(stem + suffix + extension, last.views(k).image());
      std::printf("view %d: %s%s%s, the product fills %.1f%% of the frame\n", k, stem.c_str(), suffix,
                  extension.c_str(), 100 * last.views(k).fill());
    }
  } else {
    write(*out, last.image());
  }
  if (request.background() != v1::BACKGROUND_ENVIRONMENT)
    std::printf("the product fills %.1f%% of the frame\n", 100 * last.fill());
  std::printf("%ux%u %s, %s samples: %s queries in %.3f s (setup %.3f s, kernel %.3f s), exposure %.4g -> %s\n",
              last.width(), last.height(), format_name(last.format()), ProgressBar::grouped(last.samples_total()).c_str(),
              ProgressBar::grouped(last.queries()).c_str(), last.total_seconds(), last.setup_seconds(),
              last.kernel_seconds(), last.exposure(), out->c_str());
  if (last.adaptive_sampling())
    std::printf("adaptive sampling: %u to %u samples per pixel, by each pixel's noise in a first pass\n",
                last.min_samples_per_pixel(), last.max_samples_per_pixel());
  print_fidelity(last);
  return 0;
}

OptionList render_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"scene", "NAME", "sphere (default), cylinders, swatch, curtain; fiber scenes: yarn, woven-patch, knit_patch, yarn_curves (`loomlight scenes`)"},
      {"mesh", "FILE", "render this glTF 2.0 (.glb, .gltf with embedded buffers) or OBJ file, sent with the request"},
      {"mesh-name", "NAME", "render a mesh stored on the server (`loomlight mesh upload`)"},
      {"material", "MESH_MATERIAL=PRESET", "dress one of the mesh's materials in a preset (repeatable; the rest wear MATERIAL)"},
      {"texture-unit", "uv|metre", "meshes: --texture-scale counts repeats per UV unit (default) or per metre of surface"},
      {"background", "environment|white|transparent", "behind the product: the lighting's (default), pure white, or transparent (PNG, WebP, EXR)"},
      {"lighting", "PRESET", "a lighting preset, e.g. studio (`loomlight scenes` lists them; meshes default to studio)"},
      {"views", "N", "a turntable: N views around the vertical axis, written as FILE-00.png, FILE-01.png, ..."},
      {"scene-param", "NAME=V", "set a scene parameter (repeatable; names and ranges: `loomlight scenes`)"},
      {"yarn", "PRESET", "fiber scenes: the yarn, cotton1 (default), cotton2, polyester1, rayon2 or silk1"},
      {"yarn-param", "NAME=V", "fiber scenes: override a yarn parameter (repeatable; names: `loomlight models`)"},
      {"weave", "PRESET", "woven-patch: lay out warp and weft by this woven preset's pattern (default cotton_twill)"},
      {"fiber-detail", "auto|full|lod|cores",
       "fiber scenes: Eq. 4's level of detail (lod: from the pixel footprint; auto: lod where the pilot puts it within --error-target of full detail)"},
      {"fiber-shadows", "auto|traced|slices", "fiber scenes: light through the fibers traced, or the self-shadow slices"},
      {"fiber-occlusion", "auto|traced|texture|distance", "fiber scenes: ambient occlusion traced or approximated"},
      {"ambient", "X", "fiber scenes: constant ambient radiance (default: the scene's with default lighting)"},
      {"btf-environment", "auto|sampled|folded", "btf materials: the environment map sampled, or folded into the BTF (auto: folded where its estimated error is within --error-target)"},
      {"size", "WxH", "image size in pixels (default 256x256)"},
      {"spp", "N", "samples per pixel (default 16); adaptive sampling: their work, spent where pixels are noisy"},
      {"sampling", "auto|uniform|adaptive", "spread the samples evenly or by noise (auto: adaptive from 4 spp)"},
      {"seed", "N", "random seed (default 0): the same request and seed give the same image"},
      {"texture-scale", "X", "pattern repeats per scene unit (default: the scene's)"},
      {"texture-rotation", "DEG", "rotates the threads in the surface"},
      {"light", "dir:X,Y,Z:R,G,B|point:X,Y,Z:R,G,B", "a directional light (toward it; irradiance) or a point light (repeatable)"},
      {"env", "NAME|builtin", "one of the server's environment maps (see `models`) or the built-in sky"},
      {"env-file", "FILE", "a local environment map (EXR/HDR), sent to the server"},
      {"env-intensity", "X", "environment radiance scale (default 1)"},
      {"env-rotation", "DEG", "environment rotation about +y"},
      {"camera", "X,Y,Z", "camera position (with --look-at; default: the scene's camera)"},
      {"look-at", "X,Y,Z", "the point the camera looks at"},
      {"fov", "DEG", "vertical field of view (with --camera)"},
      {"error-target", "X", "relative error allowed per modelling choice (default 0.02)"},
      {"full-fidelity", "", "BTF, the most tangent samples and transmission everywhere"},
      {"exposure", "X", "PNG/JPEG: scale before the tone curve (default: automatic)"},
      {"format", "png|jpeg|webp|exr", "output format (default: from the --out extension)"},
      {"out", "FILE", "output file (required)"},
  });
  // knit_patch's knit and yarn_curves' curves (each, given without --scene, picks its scene).
  for (const OptionList& layout : {knit_options(), curves_options()}) options.insert(options.end(), layout.begin(), layout.end());
  return options;
}

}  // namespace

const Command& render_command() {
  static const Command command = {
      "render",
      "MATERIAL [--layer PRESET] --out FILE [--scene NAME] [--size WxH] [--spp N] [lighting, camera, fidelity options]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "render a thumbnail of a material on a preset scene",
      "The server traces the scene, chooses per object the cheapest model fidelity within --error-target\n"
      "(BTF or BRDF, tangent samples, transmission) and shades through the batched kernels. PNG and JPEG\n"
      "are tone-mapped (exposure, ACES filmic, sRGB); EXR holds linear radiance. With no --light and no --env\n"
      "the scene's default lighting is used (docs/thumbnails.md \"Lights\"). A progress bar is drawn on\n"
      "stderr (plain lines when it is not a terminal); the chosen fidelity is printed at the end.\n"
      "Example: loomlight render --preset polyester_satin_charmeuse_front --scene cylinders --size 512x256 \\\n"
      "           --spp 64 --out satin.png\n"
      "Fibers: loomlight render --preset cotton --scene yarn --yarn cotton1 --size 512x256 --out yarn.png\n"
      "A knit: loomlight render --preset cotton --scene knit_patch --knit jersey --stitches 8,8 --out knit.png\n"
      "A garment: loomlight render --mesh garment.glb --material body=polyester_satin_charmeuse_front \\\n"
      "           --material collar=cotton_twill --background white --views 8 --size 1600x1600 --out shot.png",
      render_options(),
      run_render,
  };
  return command;
}

}  // namespace loomlight::client
