// `loomlight slice`: an image of a woven material's BTF over a region of texture space (TextureSlice RPC).
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <string>

#include "client/commands.h"
#include "client/directions.h"
#include "client/material.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

// Exactly one direction from "--NAME X,Y,Z" or "--NAME-deg THETA,PHI".
Vec3 single_direction(const ParsedOptions& options, const std::string& name) {
  const auto given = options.matching({name, name + "-deg"});
  if (given.size() != 1)
    throw UsageError("give exactly one --" + name + " or --" + name + "-deg (got " + std::to_string(given.size()) + ")");
  return direction_option(given[0]);
}

void set_direction(google::protobuf::RepeatedField<float>* out, const Vec3& w) {
  for (double c : w) out->Add(static_cast<float>(c));
}

// "WxH", e.g. "512x512".
void parse_size(const std::string& text, v1::TextureSliceRequest& request) {
  const auto x = text.find('x');
  if (x == std::string::npos) throw UsageError("--size needs WIDTHxHEIGHT, got '" + text + "'");
  request.set_width(parse_int(text.substr(0, x), "--size width", 1, 1 << 20));
  request.set_height(parse_int(text.substr(x + 1), "--size height", 1, 1 << 20));
}

v1::ImageFormat parse_format(const std::string& name, const std::string& what) {
  if (name == "png") return v1::IMAGE_FORMAT_PNG;
  if (name == "exr") return v1::IMAGE_FORMAT_EXR;
  if (name == "raw") return v1::IMAGE_FORMAT_RAW;
  throw UsageError(what + ": expected png, exr or raw, got '" + name + "'");
}

// --format, else the output file's extension.
v1::ImageFormat output_format(const ParsedOptions& options, const std::string& out) {
  if (auto format = options.last("format")) return parse_format(*format, "--format");
  const auto dot = out.rfind('.');
  if (dot == std::string::npos) throw UsageError("cannot tell the format from '" + out + "': give --format");
  std::string extension = out.substr(dot + 1);
  for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return parse_format(extension, "--format (from the extension of " + out + ")");
}

const char* format_name(v1::ImageFormat format) {
  switch (format) {
    case v1::IMAGE_FORMAT_EXR: return "EXR";
    case v1::IMAGE_FORMAT_RAW: return "raw float32";
    default: return "PNG";
  }
}

v1::TextureSliceRequest slice_request(const ParsedOptions& options, const std::string& out) {
  const v1::EvaluateRequest material = material_request(options);
  v1::TextureSliceRequest request;
  *request.mutable_material() = material.material();
  request.set_precision(material.precision());
  set_direction(request.mutable_wi(), single_direction(options, "wi"));
  set_direction(request.mutable_wo(), single_direction(options, "wo"));
  parse_size(options.last("size").value_or("512x512"), request);
  if (auto region = options.last("region")) {
    const auto r = parse_numbers(*region, "--region", 4);
    v1::TextureRegion* out_region = request.mutable_region();
    out_region->set_u_min(r[0]);
    out_region->set_v_min(r[1]);
    out_region->set_u_max(r[2]);
    out_region->set_v_max(r[3]);
  }
  if (auto spp = options.last("spp")) request.set_samples_per_pixel(parse_int(*spp, "--spp", 1, 1 << 20));
  if (auto exposure = options.last("exposure")) request.set_exposure(parse_number(*exposure, "--exposure"));
  request.set_format(output_format(options, out));
  return request;
}

int run_slice(const ParsedOptions& options) {
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("slice needs --out FILE (.png, .exr or .raw)");
  const v1::TextureSliceRequest request = slice_request(options, *out);

  Client client(options);
  const v1::TextureSliceResponse response = client.texture_slice(request);
  write_local_file(*out, response.image());
  const auto mean = [&](int c) { return response.mean_size() == 3 ? response.mean(c) : 0.0; };
  std::printf("%ux%u %s, %u samples/pixel: mean RGB %.6g %.6g %.6g (1/sr), exposure %.4g, %.3f s (kernel %.3f s) -> %s\n",
              response.width(), response.height(), format_name(response.format()),
              std::max<uint32_t>(request.samples_per_pixel(), 1), mean(0), mean(1), mean(2), response.exposure(),
              response.total_seconds(), response.kernel_seconds(), out->c_str());
  return 0;
}

OptionList slice_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"wi", "X,Y,Z", "incoming direction, toward the light"},
      {"wo", "X,Y,Z", "outgoing direction, toward the viewer"},
      {"wi-deg", "THETA,PHI", "incoming direction by angles in degrees"},
      {"wo-deg", "THETA,PHI", "outgoing direction by angles in degrees"},
      {"size", "WxH", "image size in pixels (default 512x512)"},
      {"region", "U0,V0,U1,V1", "texture region in pattern repeats (default 0,0,1,1: one repeat)"},
      {"spp", "N", "samples per pixel, averaged (default 1: the pixel centre)"},
      {"format", "png|exr|raw", "output format (default: from the --out extension)"},
      {"exposure", "X", "PNG: scale before clamping (default: automatic, the 99th percentile maps to 1)"},
      {"out", "FILE", "output file (required)"},
  });
  return options;
}

}  // namespace

const Command& slice_command() {
  static const Command command = {
      "slice",
      "MATERIAL (--wi X,Y,Z | --wi-deg THETA,PHI) (--wo X,Y,Z | --wo-deg THETA,PHI) --out FILE [options]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "write an image of a woven material's BTF over a texture region",
      "The image shows f(u, v, wi, wo) (1/sr) for one light and view direction; u grows to the right, v\n"
      "upwards, in pattern repeats. PNG is 8-bit sRGB after the exposure; EXR and raw (little-endian\n"
      "float32 RGB, top row first) hold f unscaled. Prints one summary line.\n"
      "Example: loomlight slice --preset cotton_twill --wi 0,0,1 --wo-deg 30,0 --size 512x512 --region 0,0,2,2 \\\n"
      "           --spp 4 --out twill.png",
      slice_options(),
      run_slice,
  };
  return command;
}

}  // namespace loomlight::client
