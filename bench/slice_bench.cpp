// Section 5: TextureSlice through an in-process server: render time against resolution and samples per
// pixel for cotton_twill over one pattern repeat, with the slice mean's error against the BRDF; and what
// each output format adds.
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "bench/bench.h"
#include "bench/in_process.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/api/texture_slice.h"

namespace loomlight::bench {
namespace {

constexpr const char* kPreset = "cotton_twill";
constexpr double kThetaI = 25, kPhiI = 30, kThetaO = 35, kPhiO = 200;  // degrees; as in tests/slice_test.cpp

void AddDirection(google::protobuf::RepeatedField<float>* out, double theta_deg, double phi_deg) {
  const double t = theta_deg * std::numbers::pi / 180, p = phi_deg * std::numbers::pi / 180;
  out->Add(static_cast<float>(std::sin(t) * std::cos(p)));
  out->Add(static_cast<float>(std::sin(t) * std::sin(p)));
  out->Add(static_cast<float>(std::cos(t)));
}

v1::TextureSliceRequest SliceRequest(uint32_t side, uint32_t spp, v1::ImageFormat format) {
  v1::TextureSliceRequest r;
  r.mutable_material()->set_preset(kPreset);
  AddDirection(r.mutable_wi(), kThetaI, kPhiI);
  AddDirection(r.mutable_wo(), kThetaO, kPhiO);
  r.set_width(side);
  r.set_height(side);
  r.set_samples_per_pixel(spp);
  r.set_format(format);
  return r;  // region unset: one repeat
}

// f of the BRDF (Evaluate without uv) for the same directions: what the slice mean tends to.
std::array<double, 3> Brdf(v1::Loomlight::Stub& stub) {
  v1::EvaluateRequest r;
  r.mutable_material()->set_preset(kPreset);
  AddDirection(r.mutable_wi(), kThetaI, kPhiI);
  AddDirection(r.mutable_wo(), kThetaO, kPhiO);
  grpc::ClientContext ctx;
  v1::EvaluateResponse response;
  if (!stub.Evaluate(&ctx, r, &response).ok() || response.f_size() != 3) {
    std::fprintf(stderr, "slice bench: the BRDF call failed\n");
    std::exit(1);
  }
  return {response.f(0), response.f(1), response.f(2)};
}

struct SliceTiming {
  double client_seconds = 1e30;  // best of the timed runs, as the client sees it
  v1::TextureSliceResponse response;  // of that run
};

SliceTiming TimeSlice(v1::Loomlight::Stub& stub, const v1::TextureSliceRequest& request, int runs) {
  SliceTiming best;
  for (int r = 0; r <= runs; ++r) {  // run 0 is the untimed warm-up
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
    v1::TextureSliceResponse response;
    const Clock::time_point start = Clock::now();
    const grpc::Status status = stub.TextureSlice(&ctx, request, &response);
    const double seconds = SecondsSince(start);
    if (!status.ok()) {
      std::fprintf(stderr, "slice bench: call failed: %s\n", status.error_message().c_str());
      std::exit(1);
    }
    if (r > 0 && seconds < best.client_seconds) best = {seconds, std::move(response)};
  }
  return best;
}

double MeanError(const v1::TextureSliceResponse& response, const std::array<double, 3>& brdf) {
  double error = 0;
  for (int c = 0; c < 3; ++c) error = std::max(error, std::fabs(response.mean(c) - brdf[c]) / brdf[c]);
  return error;
}

}  // namespace

std::string SliceSection(const Sizes& sizes) {
  const std::vector<uint32_t> sides = sizes.quick ? std::vector<uint32_t>{64, 128} : std::vector<uint32_t>{128, 256, 512, 1024};
  const std::vector<uint32_t> samples = sizes.quick ? std::vector<uint32_t>{1, 4} : std::vector<uint32_t>{1, 4, 16};
  const std::unique_ptr<api::LoomlightServer> server = StartServer(true);
  const std::unique_ptr<v1::Loomlight::Stub> stub = Connect(server->port(), -1);
  const std::array<double, 3> brdf = Brdf(*stub);

  Table table({"pixels", "samples/pixel", "queries", "client ms", "server ms", "kernel ms", "queries/s",
               "mean rel. error vs BRDF"},
              2);
  for (uint32_t side : sides)
    for (uint32_t spp : samples) {
      Progress("slice: %ux%u, %u samples per pixel\n", side, side, spp);
      const SliceTiming t = TimeSlice(*stub, SliceRequest(side, spp, v1::IMAGE_FORMAT_RAW), sizes.timed_runs);
      const uint64_t queries = t.response.queries();
      table.Add({std::to_string(side) + "x" + std::to_string(side), std::to_string(spp), Count(queries),
                 Millis(t.client_seconds), Millis(t.response.total_seconds()), Millis(t.response.kernel_seconds()),
                 Rate(static_cast<double>(queries) / t.response.total_seconds()), Sci(MeanError(t.response, brdf))});
    }

  const uint32_t format_side = sides.back();
  Table formats({"format", "bytes", "client ms", "server ms", "kernel ms"});
  for (const auto& [name, format] : {std::pair{"raw", v1::IMAGE_FORMAT_RAW}, std::pair{"EXR (zip)", v1::IMAGE_FORMAT_EXR},
                                     std::pair{"PNG (auto exposure)", v1::IMAGE_FORMAT_PNG}}) {
    Progress("slice: %ux%u as %s\n", format_side, format_side, name);
    const SliceTiming t = TimeSlice(*stub, SliceRequest(format_side, 1, format), sizes.timed_runs);
    formats.Add({name, Count(t.response.image().size()), Millis(t.client_seconds), Millis(t.response.total_seconds()),
                 Millis(t.response.kernel_seconds())});
  }

  const std::string method =
      "An in-process `LoomlightServer` (batching on) and one synchronous gRPC client in the same process. "
      "TextureSlice of preset `" + std::string(kPreset) + "` over one pattern repeat ([0, 1]^2), wi at (theta, phi) = (" +
      Fixed(kThetaI, 0) + ", " + Fixed(kPhiI, 0) + ") degrees, wo at (" + Fixed(kThetaO, 0) + ", " + Fixed(kPhiO, 0) +
      "), fp32; best of " + std::to_string(sizes.timed_runs) + " timed calls after one warm-up. The server evaluates "
      "chunks of at most " + Count(api::kSliceChunkQueries) + " queries through the batcher, filling and "
      "averaging the next and previous chunk on its host worker while one is on the device. The error is the "
      "largest over R, G, B of |slice mean - BRDF| / BRDF, the BRDF from Evaluate without uv.";
  const std::string body =
      TableBlock("raw float output (no encoding); server ms is the time in the server (sample positions, "
                 "kernels, averaging), kernel ms the launches alone; the error falls with pixel size and samples "
                 "(the BTF is discontinuous at cell and ellipse edges).",
                 table) +
      TableBlock("the cost of each output format at " + std::to_string(format_side) + "x" +
                     std::to_string(format_side) + ", 1 sample per pixel (encoding runs on the host worker).",
                 formats);
  return Section("5. Texture slices (TextureSlice)", method, body);
}

}  // namespace loomlight::bench
