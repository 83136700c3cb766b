#include "client/material.h"

#include <fstream>
#include <stdexcept>
#include <sstream>

namespace loomlight::client {
namespace {

namespace v1 = loomlight::v1;

// "name=path" -> Param with the file's text (e.g. pattern.wif=draft.wif).
v1::Param parse_param_file(const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    throw UsageError("--param-file needs NAME=PATH, got '" + text + "'");
  v1::Param param;
  param.set_name(text.substr(0, eq));
  param.set_text(read_local_file(text.substr(eq + 1), "--param-file"));
  return param;
}

// The model of BTF assets (SPEC.md section 7): its parameter `asset` names one stored on the server.
constexpr const char* kBtfModel = "btf";
// A text parameter this short on one line (an asset's name) is shown as it is, longer ones by their size.
constexpr std::size_t kShownTextBytes = 64;

std::string join_values(const v1::Param& param) {
  if (!param.text().empty()) {
    if (param.text().size() <= kShownTextBytes && param.text().find('\n') == std::string::npos) return param.text();
    return "<" + std::to_string(param.text().size()) + " bytes of text>";
  }
  std::ostringstream out;
  for (int i = 0; i < param.values_size(); ++i) out << (i ? "," : "") << param.values(i);
  return out.str();
}

}  // namespace

v1::Param parse_param(const std::string& text, const std::string& option) {
  const auto eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    throw UsageError(option + " needs NAME=V1[,V2...], got '" + text + "'");
  v1::Param param;
  param.set_name(text.substr(0, eq));
  for (double v : parse_numbers(std::string_view(text).substr(eq + 1), option + " " + param.name()))
    param.add_values(v);
  return param;
}

void yarn_from_options(const ParsedOptions& options, v1::Yarn* yarn) {
  if (auto preset = options.last("yarn")) yarn->set_preset(*preset);
  for (const auto& entry : options.matching({"yarn-param"})) *yarn->add_params() = parse_param(entry.value, "--yarn-param");
}

void write_local_file(const std::string& path, const std::string& bytes) {
  std::ofstream file(path, std::ios::binary);
  file.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!file) throw std::runtime_error("cannot write " + path);
}

std::string read_local_file(const std::string& path, const std::string& option) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw UsageError(option + ": cannot read '" + path + "'");
  std::ostringstream contents;
  contents << in.rdbuf();
  return contents.str();
}

const OptionList& material_options() {
  static const OptionList options = {
      {"preset", "NAME", "a preset material (see `loomlight models`)"},
      {"model", "NAME", "a model; with --preset it must be the preset's model"},
      {"btf", "ASSET", "a BTF asset stored on the server (`loomlight btf list`): model btf, parameter asset=ASSET"},
      {"param", "NAME=V1[,V2...]", "set a parameter (repeatable); overrides the preset's value"},
      {"param-file", "NAME=PATH", "set a text parameter from a file, e.g. pattern.wif=draft.wif (repeatable)"},
      {"layer", "PRESET", "a curtain: add this thin_layer preset's transmission to the material"},
      {"fp64", "", "evaluate with the double-precision reference kernels"},
  };
  return options;
}

v1::EvaluateRequest material_request(const ParsedOptions& options) {
  v1::EvaluateRequest request;
  v1::Material& material = *request.mutable_material();
  if (auto preset = options.last("preset")) material.set_preset(*preset);
  if (auto model = options.last("model")) material.set_model(*model);
  if (auto asset = options.last("btf")) {
    if (!material.preset().empty() || (!material.model().empty() && material.model() != kBtfModel))
      throw UsageError("--btf names the material: give it without --preset and --model");
    material.set_model(kBtfModel);
    v1::Param* param = material.add_params();
    param->set_name("asset");
    param->set_text(*asset);
  }
  if (material.preset().empty() && material.model().empty())
    throw UsageError("give --preset NAME, --model NAME or --btf ASSET");
  for (const auto& entry : options.matching({"param"})) *material.add_params() = parse_param(entry.value, "--param");
  for (const auto& entry : options.matching({"param-file"})) *material.add_params() = parse_param_file(entry.value);
  if (auto layer = options.last("layer")) material.mutable_transmission()->set_preset(*layer);
  request.set_precision(options.has("fp64") ? v1::PRECISION_FP64 : v1::PRECISION_FP32);
  return request;
}

std::string material_label(const v1::Material& material) {
  std::string label = material.preset().empty() ? material.model() : material.preset();
  std::string overrides;
  for (const v1::Param& p : material.params())
    overrides += (overrides.empty() ? "" : " ") + p.name() + "=" + join_values(p);
  if (material.has_transmission()) label.append(" + ").append(material_label(material.transmission()));
  return overrides.empty() ? label : label + " (" + overrides + ")";
}

}  // namespace loomlight::client
