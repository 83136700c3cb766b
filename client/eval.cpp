// `loomlight eval`: f(wi, wo) for directions given on the command line or in a CSV file, as CSV.
#include <cctype>
#include <stdexcept>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <string>
#include <utility>

#include "client/commands.h"
#include "client/directions.h"
#include "client/material.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

// The n-th wi pairs with the n-th wo, whichever form each was given in.
void add_option_queries(const ParsedOptions& options, v1::EvaluateRequest& request) {
  const auto wi = options.matching({"wi", "wi-deg"});
  const auto wo = options.matching({"wo", "wo-deg"});
  if (wi.size() != wo.size())
    throw UsageError("got " + std::to_string(wi.size()) + " incoming and " + std::to_string(wo.size()) +
                     " outgoing directions; they pair up in order");
  for (std::size_t i = 0; i < wi.size(); ++i) add_query(request, direction_option(wi[i]), direction_option(wo[i]));
}

bool is_header(const std::string& line) {
  const auto first = line.find_first_not_of(" \t");
  return first != std::string::npos && std::isalpha(static_cast<unsigned char>(line[first]));
}

// Rows "wix,wiy,wiz,wox,woy,woz"; blank lines are skipped, and a first row starting with a letter is a header.
void add_csv_queries(std::istream& in, const std::string& name, v1::EvaluateRequest& request) {
  std::string line;
  bool first_row = true;
  for (int number = 1; std::getline(in, line); ++number) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    if (std::exchange(first_row, false) && is_header(line)) continue;
    const auto v = parse_numbers(line, name + ":" + std::to_string(number), 6);
    add_query(request, {v[0], v[1], v[2]}, {v[3], v[4], v[5]});
  }
  if (in.bad()) throw std::runtime_error("cannot read " + name);
}

void add_csv_file_queries(const std::string& path, v1::EvaluateRequest& request) {
  if (path == "-") return add_csv_queries(std::cin, "stdin", request);
  std::ifstream file(path);
  if (!file) throw std::runtime_error("cannot open " + path);
  add_csv_queries(file, path, request);
}

// Each row repeats its directions as sent (float), so rows can be matched to inputs; %.9g round-trips a float.
void print_csv(const v1::EvaluateRequest& request, const v1::EvaluateResponse& response) {
  const bool transmittance = response.transmittance_size() > 0;
  std::printf("wix,wiy,wiz,wox,woy,woz,r,g,b%s\n", transmittance ? ",t" : "");
  for (int q = 0; q < response.f_size() / 3; ++q) {
    for (int c = 0; c < 3; ++c) std::printf("%.9g,", request.wi(3 * q + c));
    for (int c = 0; c < 3; ++c) std::printf("%.9g,", request.wo(3 * q + c));
    std::printf("%.9g,%.9g,%.9g", response.f(3 * q), response.f(3 * q + 1), response.f(3 * q + 2));
    if (transmittance) std::printf(",%.9g", response.transmittance(q));
    std::printf("\n");
  }
}

// --ambient: the ambient factor of fiber models toward each wo (EvaluateRequest.quantity AMBIENT).
int run_ambient(const ParsedOptions& options, v1::EvaluateRequest request) {
  if (!options.matching({"wi", "wi-deg"}).empty() || options.last("csv"))
    throw UsageError("--ambient takes outgoing directions only (--wo or --wo-deg)");
  for (const auto& wo : options.matching({"wo", "wo-deg"})) {
    for (double c : direction_option(wo)) request.add_wo(static_cast<float>(c));
  }
  if (request.wo_size() == 0) throw UsageError("no directions: give --wo or --wo-deg");
  request.set_quantity(v1::QUANTITY_AMBIENT);
  Client client(options);
  const v1::EvaluateResponse response = client.evaluate(request);
  if (options.has("verbose")) print_timing(std::cerr, response, request.wo_size() / 3);
  std::printf("wox,woy,woz,r,g,b\n");
  for (int q = 0; q < response.f_size() / 3; ++q)
    std::printf("%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n", request.wo(3 * q), request.wo(3 * q + 1), request.wo(3 * q + 2),
                response.f(3 * q), response.f(3 * q + 1), response.f(3 * q + 2));
  return 0;
}

int run_eval(const ParsedOptions& options) {
  v1::EvaluateRequest request = material_request(options);
  if (options.has("ambient")) return run_ambient(options, std::move(request));
  const bool from_args = !options.matching({"wi", "wi-deg", "wo", "wo-deg"}).empty();
  if (auto csv = options.last("csv")) {
    if (from_args) throw UsageError("give directions either with --csv or with --wi/--wo, not both");
    add_csv_file_queries(*csv, request);
  } else {
    add_option_queries(options, request);
  }
  if (request.wi_size() == 0) throw UsageError("no directions: give --wi and --wo, or --csv FILE");

  Client client(options);
  const v1::EvaluateResponse response = client.evaluate(request);
  if (options.has("verbose")) print_timing(std::cerr, response, request.wi_size() / 3);
  print_csv(request, response);
  return 0;
}

OptionList eval_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"wi", "X,Y,Z", "incoming direction, toward the light (repeatable)"},
      {"wo", "X,Y,Z", "outgoing direction, toward the viewer (repeatable)"},
      {"wi-deg", "THETA,PHI", "incoming direction by angles in degrees (repeatable)"},
      {"wo-deg", "THETA,PHI", "outgoing direction by angles in degrees (repeatable)"},
      {"csv", "FILE", "read rows wix,wiy,wiz,wox,woy,woz from FILE ('-' = stdin)"},
      {"ambient", "", "fiber models: the ambient factor toward each wo instead of f (no wi; Eqs. 7-10)"},
      {"verbose", "", "print the server's timing and batching to stderr"},
  });
  return options;
}

}  // namespace

const Command& eval_command() {
  static const Command command = {
      "eval",
      "MATERIAL DIRECTIONS [--verbose]\n"
      "  MATERIAL:   " LOOMLIGHT_MATERIAL_SYNOPSIS "\n"
      "  DIRECTIONS: (--wi X,Y,Z | --wi-deg THETA,PHI) (--wo X,Y,Z | --wo-deg THETA,PHI), in pairs, repeatable;\n"
      "              or --csv FILE",
      "evaluate f(wi, wo) and print CSV",
      "Directions are unit vectors in the local frame (normal +z, thread 1 along +x, thread 2 along +y);\n"
      "the n-th incoming direction pairs with the n-th outgoing one. THETA is measured from +z, PHI from +x.\n"
      "In --csv input a first line starting with a letter is a header and is skipped.\n"
      "Output: CSV wix,wiy,wiz,wox,woy,woz,r,g,b (f in 1/sr, without the cosine), one row per query,\n"
      "plus a column t (direct transmittance) for models with transmission.\n"
      "--ambient (fiber models): the integral of f(wi, wo) cos(theta_i) over the sphere of wi per --wo, as\n"
      "CSV wox,woy,woz,r,g,b: the radiance out per unit of constant ambient radiance.\n"
      "Example: loomlight eval --preset linen_plain --wi-deg 30,0 --wo-deg 30,180",
      eval_options(),
      run_eval,
  };
  return command;
}

}  // namespace loomlight::client
