// A texture slice's host side: where in texture space each query of a slice samples (pixels of a region, several
// samples per pixel) and the per-pixel means of the BTF's output. The TextureSlice RPC (server/api/texture_slice.h)
// validates a request, sends the queries through the batcher in chunks of whole pixels and encodes the image.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "server/imaging/image_encode.h"

namespace loomlight::models {

// A region [u_min, u_max) x [v_min, v_max) of texture space imaged at width x height pixels (row 0 at v_max),
// `samples` queries per pixel: query q is sample q % samples of pixel q / samples (index y * width + x).
struct SliceSampling {
  double u_min = 0, v_min = 0, u_max = 1, v_max = 1;
  uint32_t width = 1, height = 1, samples = 1;
};

// The position in [0, 1)^2 inside pixel `pixel` (index y * width + x) of its sample `sample` of `samples`:
// the centre for one sample; otherwise the R2 sequence (i + 1/2) (0.7548776662, 0.5698402910) mod 1, shifted
// mod 1 by a fixed hash of the pixel index (a Cranley-Patterson rotation), so the result is deterministic
// but neighbouring pixels do not share one point set.
std::array<double, 2> PixelSampleOffset(uint64_t pixel, uint32_t sample, uint32_t samples);

// The texture coordinates (u, v as float) of queries [first, first + count), whole pixels, into uv.
void SliceTexturePositions(const SliceSampling& slice, uint64_t first, size_t count, float* uv);

// Each pixel's mean of the BTF's output f (RGB per query) for queries [first, first + count), whole pixels:
// computed in double (in place in f), rounded once into the image's float, and added to sum. Returns "" or
// what is wrong with the output.
std::string AddPixelMeans(uint32_t samples, uint64_t first, size_t count, double* f, imaging::LinearRgbImage* image,
                          std::array<double, 3>* sum);

// One direction repeated for `count` queries (xyz each), as the kernels take a direction per query.
std::vector<float> RepeatedDirection(const float xyz[3], size_t count);

}  // namespace loomlight::models
