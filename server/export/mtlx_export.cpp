#include "server/export/mtlx_export.h"

#include <pugixml.hpp>

#include <charconv>
#include <cmath>
#include <set>
#include <sstream>

#include "server/models/quote.h"

namespace loomlight::exporting {
namespace {

using models::Number;

// The most characters of a client's name a MaterialX name keeps (before a suffix that makes it unique).
constexpr size_t kMaxNameChars = 64;

// What an open_pbr_surface input takes from an openpbr material: its parameter, or a fixed value for the inputs
// the openpbr model holds at OpenPBR's defaults (a dielectric base, white specular). Types as MaterialX's nodedef
// ND_open_pbr_surface_surfaceshader declares them (libraries/bxdf/open_pbr_surface.mtlx).
struct OpenPbrInput {
  const char* name;
  const char* type;   // "float" or "color3"
  const char* param;  // the openpbr parameter, or nullptr for `fixed`
  const char* fixed;
};
constexpr OpenPbrInput kInputs[] = {
    {"base_weight", "float", nullptr, "1"},
    {"base_color", "color3", "base_color", nullptr},
    {"base_diffuse_roughness", "float", nullptr, "0"},
    {"base_metalness", "float", nullptr, "0"},
    {"specular_weight", "float", nullptr, "1"},
    {"specular_color", "color3", nullptr, "1, 1, 1"},
    {"specular_roughness", "float", "specular_roughness", nullptr},
    {"specular_ior", "float", "specular_ior", nullptr},
    {"fuzz_weight", "float", "fuzz_weight", nullptr},
    {"fuzz_color", "color3", "fuzz_color", nullptr},
    {"fuzz_roughness", "float", "fuzz_roughness", nullptr},
};

// The shortest text that reads back as the same double (std::to_chars), so a value round-trips exactly.
std::string RoundTrip(double v) {
  char buf[32];
  const auto result = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, result.ptr);
}

std::string CheckMaterial(const MtlxMaterial& material, size_t index) {
  const std::string where = "materials[" + std::to_string(index) + "]";
  for (const OpenPbrInput& input : kInputs) {
    if (!input.param) continue;
    const size_t size = std::string_view(input.type) == "color3" ? 3 : 1;
    const auto it = material.params.find(input.param);
    if (it == material.params.end()) return where + ": no parameter '" + input.param + "'";
    if (it->second.size() != size) {
      return where + "." + input.param + ": " + std::to_string(it->second.size()) + " values, not " +
             std::to_string(size);
    }
    for (double v : it->second) {
      if (!std::isfinite(v)) return where + "." + input.param + ": " + Number(v) + " is not finite";
    }
  }
  return "";
}

// A client's text as a MaterialX name: ASCII letters, digits and underscores (every other character, or byte
// that is not well-formed UTF-8, one underscore), at most kMaxNameChars of them, never starting with a digit,
// "material" when empty.
std::string IdentifierFrom(std::string_view text) {
  std::string out;
  size_t i = 0;
  while (i < text.size() && out.size() < kMaxNameChars) {
    uint32_t cp = 0;
    const size_t n = models::quote_detail::Utf8Sequence(text.substr(i), &cp);
    const bool keep = n == 1 && ((cp >= 'a' && cp <= 'z') || (cp >= 'A' && cp <= 'Z') || (cp >= '0' && cp <= '9') ||
                                 cp == '_');
    out += keep ? char(cp) : '_';
    i += n == 0 ? 1 : n;
  }
  if (out.empty()) return "material";
  if (out[0] >= '0' && out[0] <= '9') out.insert(0, "m_");
  return out;
}

void AddInput(pugi::xml_node shader, const char* name, const char* type, const std::string& value) {
  pugi::xml_node input = shader.append_child("input");
  input.append_attribute("name") = name;
  input.append_attribute("type") = type;
  input.append_attribute("value") = value.c_str();
}

}  // namespace

std::string WriteMtlx(const std::vector<MtlxMaterial>& materials, std::string* out) {
  if (materials.empty()) return "no materials";
  for (size_t m = 0; m < materials.size(); ++m) {
    std::string error = CheckMaterial(materials[m], m);
    if (!error.empty()) return error;
  }
  pugi::xml_document doc;
  pugi::xml_node declaration = doc.append_child(pugi::node_declaration);
  declaration.append_attribute("version") = "1.0";
  pugi::xml_node root = doc.append_child("materialx");
  root.append_attribute("version") = "1.39";
  root.append_attribute("colorspace") = "lin_rec709";  // the fits' colours are linear Rec.709

  std::set<std::string> taken;  // every element name so far: MaterialX names are unique within their parent
  for (const MtlxMaterial& material : materials) {
    const std::string base = IdentifierFrom(material.name);
    std::string name = base;
    for (int suffix = 2; taken.count(name) || taken.count(name + "_shader"); ++suffix) {
      name = base + "_" + std::to_string(suffix);
    }
    const std::string shader_name = name + "_shader";
    taken.insert(name);
    taken.insert(shader_name);

    pugi::xml_node shader = root.append_child("open_pbr_surface");
    shader.append_attribute("name") = shader_name.c_str();
    shader.append_attribute("type") = "surfaceshader";
    for (const OpenPbrInput& input : kInputs) {
      if (!input.param) {
        AddInput(shader, input.name, input.type, input.fixed);
        continue;
      }
      std::string value;
      for (double v : material.params.at(input.param)) value += (value.empty() ? "" : ", ") + RoundTrip(v);
      AddInput(shader, input.name, input.type, value);
    }
    pugi::xml_node surface = root.append_child("surfacematerial");
    surface.append_attribute("name") = name.c_str();
    surface.append_attribute("type") = "material";
    pugi::xml_node input = surface.append_child("input");
    input.append_attribute("name") = "surfaceshader";
    input.append_attribute("type") = "surfaceshader";
    input.append_attribute("nodename") = shader_name.c_str();
  }
  std::ostringstream stream;
  doc.save(stream, "  ");
  *out = stream.str();
  return "";
}

}  // namespace loomlight::exporting
