#include "bench/render_client.h"

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>

#include "bench/bench.h"
#include "bench/stats.h"
#include "server/api/render_rpc.h"

// After the protobuf headers: OpenImageIO's byte-swap macros clash with protobuf's port.h.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace loomlight::bench {

v1::RenderRequest SquareRequest(const char* preset, v1::ScenePreset scene, uint32_t side, uint32_t spp, uint64_t seed) {
  v1::RenderRequest r;
  r.mutable_material()->set_preset(preset);
  r.set_scene(scene);
  r.set_width(side);
  r.set_height(side);
  r.set_samples_per_pixel(spp);
  r.set_seed(seed);
  r.set_format(v1::RENDER_FORMAT_EXR);
  return r;
}

std::vector<float> DecodeExr(const std::string& bytes, int channels) {
  OIIO::Filesystem::IOMemReader reader(bytes.data(), bytes.size());
  auto in = OIIO::ImageInput::open("render.exr", nullptr, &reader);
  if (!in || in->spec().nchannels < channels) return {};
  std::vector<float> pixels(size_t(in->spec().width) * in->spec().height * channels);
  if (!in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, pixels.data())) return {};
  return pixels;
}

RenderResult RenderOnce(v1::Loomlight::Stub& stub, const v1::RenderRequest& request) {
  RenderResult result;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(30));
  const Clock::time_point start = Clock::now();
  auto reader = stub.Render(&ctx, request);
  v1::RenderUpdate update;
  while (reader->Read(&update))
    if (!update.image().empty()) result.last = update;
  const grpc::Status status = reader->Finish();
  result.client_seconds = SecondsSince(start);
  if (!status.ok()) {
    std::fprintf(stderr, "render bench: call failed: %s\n", status.error_message().c_str());
    std::exit(1);
  }
  result.image = DecodeExr(result.last.image());
  return result;
}

RenderResult TimeRender(v1::Loomlight::Stub& stub, const v1::RenderRequest& request, int runs, bool warm_up) {
  if (warm_up) RenderOnce(stub, request);
  RenderResult best;
  best.client_seconds = 1e30;
  for (int r = 0; r < runs; ++r) {
    RenderResult result = RenderOnce(stub, request);
    if (result.client_seconds < best.client_seconds) best = std::move(result);
  }
  return best;
}

std::vector<float> MeanRender(v1::Loomlight::Stub& stub, v1::RenderRequest request, uint32_t spp, uint64_t first_seed) {
  const uint64_t pixels = uint64_t{request.width()} * request.height();
  const uint32_t per_call = static_cast<uint32_t>(
      std::min<uint64_t>({spp, api::kMaxRenderSamplesPerPixel, api::kMaxRenderSamples / pixels}));
  const uint32_t calls = (spp + per_call - 1) / per_call;
  request.set_samples_per_pixel(per_call);
  std::vector<double> sum;
  for (uint32_t c = 0; c < calls; ++c) {
    Progress("  mean of renders %ux%u, call %u of %u (%u samples per pixel)\n", request.width(), request.height(),
             c + 1, calls, per_call);
    request.set_seed(first_seed + c);
    const RenderResult r = RenderOnce(stub, request);
    sum.resize(r.image.size(), 0.0);
    for (size_t i = 0; i < r.image.size(); ++i) sum[i] += r.image[i];
  }
  std::vector<float> mean(sum.size());
  for (size_t i = 0; i < sum.size(); ++i) mean[i] = static_cast<float>(sum[i] / calls);
  return mean;
}

ImageError Compare(const std::vector<float>& image, const std::vector<float>& reference) {
  double diff = 0, total = 0, peak = 0;
  for (size_t i = 0; i < reference.size() && i < image.size(); ++i) {
    const double d = double(image[i]) - reference[i];
    diff += d * d;
    total += double(reference[i]) * reference[i];
    peak = std::max(peak, double(reference[i]));
  }
  const double mse = diff / std::max<size_t>(1, reference.size());
  return {mse, total > 0 ? diff / total : 0, mse > 0 ? 10 * std::log10(peak * peak / mse) : 0};
}

double MeanDifference(const std::vector<float>& image, const std::vector<float>& reference) {
  double a = 0, b = 0;
  for (size_t i = 0; i < reference.size() && i < image.size(); ++i) a += image[i], b += reference[i];
  return b > 0 ? a / b - 1 : 0;
}

std::string ChosenSummary(const v1::RenderUpdate& update) {
  std::map<std::string, std::string> by_aspect;
  for (const v1::ObjectFidelity& object : update.fidelity())
    for (const v1::FidelityChoice& c : object.choices()) {
      std::string& s = by_aspect[c.aspect()];
      s += (s.empty() ? "" : "/") + c.chosen();
    }
  std::string out;
  for (const auto& [aspect, chosen] : by_aspect) out += (out.empty() ? "" : ", ") + aspect + " " + chosen;
  return out;
}

}  // namespace loomlight::bench
