// Render calls shared by the render and noise sections: a square EXR request, one call as the client sees it,
// the EXR's pixels, the mean of several seeds' renders, and an image's error against a reference.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"

namespace loomlight::bench {

// A square EXR render of `preset` on `scene`.
v1::RenderRequest SquareRequest(const char* preset, v1::ScenePreset scene, uint32_t side, uint32_t spp, uint64_t seed);

struct RenderResult {
  double client_seconds = 0;
  v1::RenderUpdate last;     // the final update (image, fidelity, timings)
  std::vector<float> image;  // linear RGB, rows from the top
};

// The first `channels` channels of an EXR file's bytes as floats; empty when they cannot be decoded.
std::vector<float> DecodeExr(const std::string& bytes, int channels = 3);

// One call; a failed call ends the benchmark.
RenderResult RenderOnce(v1::Loomlight::Stub& stub, const v1::RenderRequest& request);

// The fastest of `runs` timed renders (all give the same image), after one untimed warm-up unless the caller
// has warmed the server up for this material and scene already.
RenderResult TimeRender(v1::Loomlight::Stub& stub, const v1::RenderRequest& request, int runs, bool warm_up = true);

// The mean of renders of `request` with seeds first_seed, first_seed + 1, ... totalling `spp` samples per pixel
// (one call holds at most kMaxRenderSamplesPerPixel, and kMaxRenderSamples over the image).
std::vector<float> MeanRender(v1::Loomlight::Stub& stub, v1::RenderRequest request, uint32_t spp, uint64_t first_seed);

struct ImageError {
  double mse = 0;           // mean over all pixels and channels of (x - ref)^2
  double relative_mse = 0;  // sum (x - ref)^2 / sum ref^2
  double psnr_db = 0;       // 10 log10(peak^2 / MSE), peak = the reference's largest value
};
ImageError Compare(const std::vector<float>& image, const std::vector<float>& reference);
// sum image / sum reference - 1: the image's bias, apart from its noise.
double MeanDifference(const std::vector<float>& image, const std::vector<float>& reference);

// The server's fidelity choices over the objects, e.g. "tangent_samples 32/32/32" over the three cylinders.
std::string ChosenSummary(const v1::RenderUpdate& update);

}  // namespace loomlight::bench
