// `loomlight models`: the server's registry, readable.
#include <algorithm>
#include <iomanip>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "client/commands.h"
#include "client/param_schema.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

using Row = std::vector<std::string>;

// Long defaults (tangent curves) are cut so the table stays one line per parameter; presets list everything.
constexpr int kMaxListedValues = 6;
constexpr int kAllValues = std::numeric_limits<int>::max();

// Pads every column but the last to its widest cell.
void print_table(std::ostream& out, const std::vector<Row>& rows, std::string_view indent) {
  std::vector<std::size_t> widths;
  for (const Row& row : rows) {
    widths.resize(std::max(widths.size(), row.size()));
    for (std::size_t c = 0; c < row.size(); ++c) widths[c] = std::max(widths[c], row[c].size());
  }
  for (const Row& row : rows) {
    std::string line(indent);
    for (std::size_t c = 0; c < row.size(); ++c)
      line += c + 1 < row.size() ? row[c] + std::string(widths[c] - row[c].size() + 2, ' ') : row[c];
    out << line.substr(0, line.find_last_not_of(' ') + 1) << '\n';
  }
}

template <typename Values>
std::string format_values(const Values& values, int max_listed) {
  std::ostringstream out;
  out << std::setprecision(9);
  const int n = static_cast<int>(values.size());
  const int shown = n > max_listed ? max_listed - 1 : n;
  for (int i = 0; i < shown; ++i) out << (i ? "," : "") << values[i];
  if (shown < n) out << ",... (" << n << " values)";
  return out.str();
}

std::string type_name(v1::ParamSchema::Type type) {
  switch (type) {
    case v1::ParamSchema::TYPE_REAL: return "real";
    case v1::ParamSchema::TYPE_INT: return "int";
    case v1::ParamSchema::TYPE_RGB: return "rgb";
    case v1::ParamSchema::TYPE_REAL_LIST: return "real list";
    case v1::ParamSchema::TYPE_TEXT: return "text";
    default: return "?";
  }
}

std::string count_text(const v1::ParamSchema& p) {
  if (p.type() == v1::ParamSchema::TYPE_TEXT) return "<=" + std::to_string(p.max_count()) + " bytes";
  if (p.min_count() == p.max_count()) return std::to_string(p.min_count());
  return std::to_string(p.min_count()) + ".." + std::to_string(p.max_count());
}

std::string range_text(const v1::ParamSchema& p) {
  if (p.type() == v1::ParamSchema::TYPE_TEXT) return "-";
  std::ostringstream out;
  out << std::setprecision(9) << '[' << p.min() << ", " << p.max() << ']';
  return out.str();
}

using ParamSchemas = google::protobuf::RepeatedPtrField<v1::ParamSchema>;
using Presets = google::protobuf::RepeatedPtrField<v1::Preset>;

}  // namespace

void print_parameters(std::ostream& out, const ParamSchemas& params) {
  std::vector<Row> rows = {{"NAME", "TYPE", "UNIT", "RANGE", "COUNT", "DEFAULT", "DESCRIPTION"}};
  for (const v1::ParamSchema& p : params)
    rows.push_back({p.name(), type_name(p.type()), p.unit().empty() ? "-" : p.unit(), range_text(p), count_text(p),
                    format_values(p.default_values(), kMaxListedValues), p.description()});
  if (params.empty()) {
    out << "  parameters: none\n";
    return;
  }
  out << "  parameters:\n";
  print_table(out, rows, "    ");
}

namespace {

// With `values`, every parameter of each preset follows its line.
void print_presets(std::ostream& out, const Presets& presets, bool values) {
  if (presets.empty()) return;
  std::size_t width = 0;
  for (const v1::Preset& preset : presets) width = std::max(width, preset.name().size());
  out << "  presets:\n";
  for (const v1::Preset& preset : presets) {
    out << "    " << std::left << std::setw(static_cast<int>(width) + 2) << preset.name() << preset.description()
        << '\n';
    if (!values) continue;
    std::vector<Row> rows;
    for (const v1::Param& p : preset.params()) rows.push_back({p.name(), format_values(p.values(), kAllValues)});
    print_table(out, rows, "        ");
  }
}

void print_model(std::ostream& out, const v1::ModelInfo& model, bool preset_values) {
  out << "\nmodel " << model.name() << ": " << model.description() << '\n';
  out << "  " << (model.transmission() ? "reflection and transmission" : "reflection only") << ", "
      << (model.spatially_varying() ? "spatially varying (takes uv)" : "uniform") << '\n';
  print_parameters(out, model.params());
  if (model.has_accuracy_knob() && !model.accuracy_knob().param().empty())
    out << "  accuracy knob: " << model.accuracy_knob().param() << " = "
        << format_values(model.accuracy_knob().settings(), kAllValues) << " (cheapest to exact; "
        << model.accuracy_knob().error_estimate() << ")\n";
  print_presets(out, model.presets(), preset_values);
}

int run_models(const ParsedOptions& options) {
  Client client(options);
  const v1::ListModelsResponse response = client.list_models();
  std::cout << "server limits: " << response.max_queries_per_call() << " queries per call, |w| within "
            << response.unit_tolerance() << " of 1\n";
  std::cout << "environment maps (render --env NAME):";
  for (const std::string& name : response.environment_maps()) std::cout << " " << name;
  std::cout << (response.environment_maps().empty() ? " none (the server has no --environment-dir)\n" : "\n");
  for (const v1::ModelInfo& model : response.models()) print_model(std::cout, model, options.has("verbose"));
  const v1::YarnModelInfo& yarn = response.yarn();
  if (!yarn.params().empty()) {
    std::cout << "\nyarn (fiber scenes: render --yarn, --yarn-param; the yarn command): " << yarn.description()
              << "\n  at most " << yarn.max_fibers() << " fibers and " << yarn.max_control_points()
              << " control points per yarn call\n";
    print_parameters(std::cout, yarn.params());
    print_presets(std::cout, yarn.presets(), options.has("verbose"));
  }
  return 0;
}

}  // namespace

const Command& models_command() {
  static const Command command = {
      "models",
      "[--verbose]",
      "list the models with their parameter schemas and presets, and the procedural yarn's",
      "Ranges are inclusive; COUNT is the number of values a parameter takes. Angles are in degrees.",
      {{"verbose", "", "also list every parameter value of each preset"}},
      run_models,
  };
  return command;
}

}  // namespace loomlight::client
