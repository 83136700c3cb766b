// The Sample RPC's host side (server/api/sample_rpc.h): a direction drawn per query from a material's sampler
// and, once f is evaluated, each query's weight f |cos| / pdf.
#pragma once

#include <cstddef>
#include <cstdint>

#include "server/models/direction_sampler.h"

namespace loomlight::models {

// Draws queries [begin, end): for each wo (xyz, unit within the API's tolerance, renormalised here) a wi (unit,
// or zero) and its pdf (0 where it is not finite and positive). The three uniform numbers of query q are
// random[3 q..3 q + 2] when random is not null, else the floats a client would send for `seed`: number d of
// CounterRng(seed, q), rounded to the nearest float, at most the largest float below 1.
void DrawSampleQueries(const DirectionSampler& sampler, const float* wo, const float* random, uint64_t seed,
                       size_t begin, size_t end, float* wi, float* pdf);

// weight = f cos / pdf per query and channel (0 where pdf is 0 or the product is not finite), for n queries.
void SampleWeights(const DirectionSampler& sampler, size_t n, const float* wi, const float* pdf, const float* f,
                   float* weight);

}  // namespace loomlight::models
