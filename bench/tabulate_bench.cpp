// Section: Tabulate throughput (cells/s) on the MERL grid and a 4D grid for every model in the registry,
// float32 and float64, and how far the float32 table is from the float64 one.
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>

#include "bench/bench.h"
#include "bench/in_process.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/tabulate.h"

namespace loomlight::bench {
namespace {

struct TableRun {
  bool ok = false;
  std::string error;
  double seconds = 0;
  uint64_t cells = 0;
  uint32_t queries_per_cell = 0;
  std::vector<float> values;  // the RAW table's floats
};

// One Tabulate call in RAW format, timed from the call to the end of the stream; the table decoded.
TableRun Run(v1::Loomlight::Stub& stub, v1::TabulateRequest request) {
  request.set_format(v1::TABLE_FORMAT_RAW);
  TableRun run;
  grpc::ClientContext ctx;
  std::string file;
  v1::TabulateChunk chunk;
  const auto start = std::chrono::steady_clock::now();
  auto reader = stub.Tabulate(&ctx, request);
  while (reader->Read(&chunk)) {
    file += chunk.data();
    run.cells = chunk.cells_total();
    if (chunk.queries_per_cell() > 0) run.queries_per_cell = chunk.queries_per_cell();
  }
  const grpc::Status status = reader->Finish();
  run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!status.ok() || file.size() < api::kRawHeaderBytes) {
    run.error = status.error_message();
    return run;
  }
  run.ok = true;
  const size_t header = api::kRawHeaderBytes;
  run.values.resize((file.size() - header) / 4);
  for (size_t i = 0; i < run.values.size(); ++i) {
    uint32_t bits = 0;
    for (int b = 0; b < 4; ++b) bits |= uint32_t(static_cast<unsigned char>(file[header + 4 * i + b])) << (8 * b);
    run.values[i] = std::bit_cast<float>(bits);
  }
  return run;
}

// Median and max relative difference of fp32 against fp64 over the values of fp64 above 1e-4 (1/sr), the
// threshold of the kernel accuracy section.
std::pair<double, double> RelativeDifference(const std::vector<float>& fp32, const std::vector<float>& fp64) {
  std::vector<double> rel;
  for (size_t i = 0; i < std::min(fp32.size(), fp64.size()); ++i)
    if (fp64[i] > 1e-4) rel.push_back(std::fabs(double(fp32[i]) - fp64[i]) / fp64[i]);
  if (rel.empty()) return {0, 0};
  const double max = *std::max_element(rel.begin(), rel.end());
  std::nth_element(rel.begin(), rel.begin() + rel.size() / 2, rel.end());
  return {rel[rel.size() / 2], max};
}

}  // namespace

std::string TabulateSection(const Sizes& sizes) {
  const std::unique_ptr<api::LoomlightServer> server = StartServer(true);
  const auto stub = Connect(server->port(), 0);
  const uint32_t side = sizes.quick ? 8 : 32;
  Table table({"model", "grid", "cells", "queries/cell", "fp32 cells/s", "fp64 cells/s", "fp32 vs fp64 rel. diff median / max"}, 2);
  for (const auto& model : models::Registry::Global().models()) {
    v1::TabulateRequest request;
    if (!model->presets().empty())
      request.mutable_material()->set_preset(model->presets().front().name);
    else
      request.mutable_material()->set_model(model->name());
    for (const bool merl : {true, false}) {
      if (merl) {
        request.mutable_merl()->set_phi_h_samples(sizes.quick ? 1 : 0);  // 0: the model's default
      } else {
        auto* grid = request.mutable_anisotropic();
        grid->set_theta_i_count(side);
        grid->set_phi_i_count(side);
        grid->set_theta_o_count(side);
        grid->set_phi_o_count(side);
      }
      const std::string grid_name = merl ? "MERL 90x90x180" : "4D " + std::to_string(side) + "^4";
      const std::string label = request.material().preset().empty() ? model->name() : request.material().preset();
      Progress("tabulate: %s, %s\n", label.c_str(), grid_name.c_str());
      TableRun runs[2];
      for (int fp64 = 0; fp64 < 2; ++fp64) {
        request.set_precision(fp64 ? v1::PRECISION_FP64 : v1::PRECISION_FP32);
        runs[fp64] = Run(*stub, request);
      }
      if (!runs[0].ok || !runs[1].ok) {
        table.Add({model->name() + " (" + label + ")", grid_name, "failed: " + runs[0].error + runs[1].error, "", "", "", ""});
        continue;
      }
      const auto [median, max] = RelativeDifference(runs[0].values, runs[1].values);
      table.Add({model->name() + " (" + label + ")", grid_name, Count(runs[0].cells), std::to_string(runs[0].queries_per_cell),
                 Rate(runs[0].cells / runs[0].seconds), Rate(runs[1].cells / runs[1].seconds),
                 Sci(median) + " / " + Sci(max)});
    }
  }
  const std::string method =
      "One client of an in-process `LoomlightServer` (batching on, nothing else running) tabulates each model's first "
      "preset (or its defaults) with `Tabulate` in RAW format, float32 and then float64 kernels; cells/s is the "
      "grid's cells over the time from the call to the end of the stream (kernels in jobs of 2^20 queries, "
      "directions filled, averaged and encoded on the service's host worker, bytes streamed over loopback). MERL "
      "cells average the model's default number of phi_h samples (1 isotropic, 8 otherwise" +
      std::string(sizes.quick ? "; this quick run uses 1" : "") +
      "). The difference compares the two tables value by value where the float64 value exceeds 1e-4 1/sr; both "
      "are stored as float32, so about 6e-8 is storage rounding.";
  return Section("7. Tabulation throughput", method,
                 TableBlock("cells/s per model and grid; the error column is the float32 table against the float64 one.",
                            table));
}

}  // namespace loomlight::bench
