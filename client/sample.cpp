// `loomlight sample`: importance samples of a material (Sample RPC) for given outgoing directions, as CSV
// (wi, pdf, weight, f per sample), with the mean weight per direction: an estimate of its directional albedo.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/commands.h"
#include "client/directions.h"
#include "client/material.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

void write_csv(std::ostream& out, const v1::SampleRequest& request, const v1::SampleResponse& response) {
  out << "wox,woy,woz,wix,wiy,wiz,pdf,weight_r,weight_g,weight_b,f_r,f_g,f_b\n";
  char line[512];
  for (int q = 0; q < response.pdf_size(); ++q) {
    std::snprintf(line, sizeof line, "%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n",
                  request.wo(3 * q), request.wo(3 * q + 1), request.wo(3 * q + 2), response.wi(3 * q),
                  response.wi(3 * q + 1), response.wi(3 * q + 2), response.pdf(q), response.weight(3 * q),
                  response.weight(3 * q + 1), response.weight(3 * q + 2), response.f(3 * q), response.f(3 * q + 1),
                  response.f(3 * q + 2));
    out << line;
  }
}

// One line per outgoing direction: the mean weight and its standard error per channel.
void print_means(const v1::SampleRequest& request, const v1::SampleResponse& response, int directions, int count) {
  for (int d = 0; d < directions; ++d) {
    double sum[3] = {0, 0, 0}, squares[3] = {0, 0, 0};
    for (int q = d * count; q < (d + 1) * count; ++q)
      for (int c = 0; c < 3; ++c) {
        const double w = response.weight(3 * q + c);
        sum[c] += w;
        squares[c] += w * w;
      }
    double mean[3], error[3];
    for (int c = 0; c < 3; ++c) {
      mean[c] = sum[c] / count;
      error[c] = count > 1 ? std::sqrt(std::max(0.0, squares[c] / count - mean[c] * mean[c]) / (count - 1)) : 0;
    }
    const int q = d * count;
    std::printf("wo %.6g,%.6g,%.6g: %d samples, mean weight %.6g,%.6g,%.6g (+- %.2g,%.2g,%.2g)\n", request.wo(3 * q),
                request.wo(3 * q + 1), request.wo(3 * q + 2), count, mean[0], mean[1], mean[2], error[0], error[1],
                error[2]);
  }
}

int run_sample(const ParsedOptions& options) {
  const v1::EvaluateRequest material = material_request(options);
  v1::SampleRequest request;
  *request.mutable_material() = material.material();
  request.set_precision(material.precision());
  const int count = options.last("count") ? parse_int(*options.last("count"), "--count", 1, 1 << 20) : 1;
  if (auto seed = options.last("seed")) {
    const double s = parse_number(*seed, "--seed");
    if (!(s >= 0 && s < 0x1p64) || s != std::floor(s)) throw UsageError("--seed must be an integer >= 0");
    request.set_seed(static_cast<uint64_t>(s));
  }
  std::vector<double> uv;
  if (auto text = options.last("uv")) uv = parse_numbers(*text, "--uv", 2);
  const auto wo = options.matching({"wo", "wo-deg"});
  if (wo.empty()) throw UsageError("no directions: give --wo X,Y,Z or --wo-deg THETA,PHI");
  for (const auto& entry : wo) {
    const Vec3 w = direction_option(entry);
    for (int k = 0; k < count; ++k) {
      for (double c : w) request.add_wo(static_cast<float>(c));
      for (double c : uv) request.add_uv(static_cast<float>(c));
    }
  }

  const v1::SampleResponse response = Client(options).sample(request);
  if (options.has("verbose"))
    std::cerr << "model=" << response.model() << " precision=" << precision_name(response.precision())
              << " samples=" << response.pdf_size() << " sampling_seconds=" << response.sampling_seconds()
              << " queue_seconds=" << response.queue_seconds() << " kernel_seconds=" << response.kernel_seconds()
              << " total_seconds=" << response.total_seconds() << '\n';
  const auto out = options.last("out");
  if (!out) {
    write_csv(std::cout, request, response);
    return 0;
  }
  std::ofstream file(*out, std::ios::trunc);
  if (!file) throw std::runtime_error("cannot write " + *out);
  write_csv(file, request, response);
  file.close();
  if (!file) throw std::runtime_error("cannot write " + *out);
  print_means(request, response, static_cast<int>(wo.size()), count);
  return 0;
}

OptionList sample_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"wo", "X,Y,Z", "outgoing direction, toward the viewer (repeatable)"},
      {"wo-deg", "THETA,PHI", "outgoing direction by angles in degrees (repeatable)"},
      {"count", "N", "samples per outgoing direction (default 1)"},
      {"seed", "S", "the server draws the random numbers from this seed (default 0)"},
      {"uv", "U,V", "texture position of every sample (spatially varying models: woven)"},
      {"out", "FILE", "write the CSV to FILE and print the mean weight per direction instead"},
      {"verbose", "", "print the server's timing to stderr"},
  });
  return options;
}

}  // namespace

const Command& sample_command() {
  static const Command command = {
      "sample",
      "MATERIAL (--wo X,Y,Z | --wo-deg THETA,PHI)... [--count N] [--seed S] [--uv U,V] [--out FILE]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "importance-sample wi for outgoing directions: wi, pdf and weight f |cos| / pdf",
      "The server draws wi from the material's sampling density (docs/api.md \"Sample\"),\n"
      "deterministic per --seed.\n"
      "Output: CSV wox,woy,woz,wix,wiy,wiz,pdf,weight_r,weight_g,weight_b,f_r,f_g,f_b, one row per sample\n"
      "(pdf per steradian; weight = f |cos| / pdf, whose mean estimates the directional albedo). With --out\n"
      "the CSV goes to FILE and one line per direction gives the mean weight and its standard error.\n"
      "Example: loomlight sample --preset cotton_twill --wo 0,0.5,0.866 --count 1000 --seed 1 --out twill.csv",
      sample_options(),
      run_sample,
  };
  return command;
}

}  // namespace loomlight::client
