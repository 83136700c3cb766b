// The Tabulate RPC: f of one material on a grid of directions (in-plane slice, full 4D, MERL half/diff),
// encoded on the server as a standard file (RAW with a header, OpenEXR, MERL .binary, CSV) and streamed as
// chunks of bytes with progress. The grid, the means per cell and the encoders are the model side's
// (server/models/tabulation/); this handler validates, admits, sends queries through the batcher in chunks of
// at most one Evaluate call (so a big table takes turns with other clients) and streams the bytes. Filling
// directions, averaging and encoding run on the service's HostWorker, never on the batcher's thread or a gRPC
// callback thread.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/metrics.h"
#include "server/api/service.h"
#include "server/batching/batcher.h"
#include "server/models/registry.h"
#include "server/models/tabulation/formats.h"
#include "server/models/tabulation/grid.h"

namespace loomlight::api {

// Documented limits (docs/tabulation.md "Limits").
constexpr uint64_t kMaxTabulateQueries = uint64_t{1} << 25;  // cells x queries per cell (MERL phi_h samples)
constexpr uint64_t kMaxExrCells = uint64_t{1} << 22;         // the EXR is encoded in memory at the end
constexpr uint64_t kMaxCsvCells = uint64_t{1} << 16;         // text: about 50 bytes per cell
constexpr uint32_t kDefaultAnisotropicPhiHSamples = 8;       // MERL grid, anisotropic models, phi_h_samples 0
constexpr double kMaxAngleDeg = 360.0;                       // |phi_plane_deg|; incidence angles within 180
// Queries per batcher job (whole cells): a quarter of one Evaluate call, as a render's chunks, so that an
// interactive call queued behind a bulk launch waits for a short one (server/batching/batcher.h).
constexpr size_t kTabulateChunkQueries = kMaxQueriesPerCall / 4;
constexpr size_t kTabulateChunksInFlight = 2;  // one queued while one runs: a job waits whenever a launch ends
constexpr size_t kMaxChunkDataBytes = size_t{4} << 20;       // per TabulateChunk, well under kMaxMessageBytes
// Encoded bytes waiting to be sent beyond which no further chunk is evaluated (flow control: a slow reader
// holds the evaluation, not the server's memory).
constexpr size_t kMaxBufferedBytes = size_t{16} << 20;

// The grid and the file formats are the model side's (server/models/tabulation/); tests, benches and the
// fuzzer name them through this header.
using tabulation::GridKind;
using tabulation::kRawHeaderBytes;
using tabulation::kRawVersion;
using tabulation::TableEncoder;
using TabulationGrid = tabulation::Grid;

using TabulateDeps = ServiceDeps;

// Checks the request's grid and builds it for `model` (its isotropy picks the MERL default). Returns "" or the
// INVALID_ARGUMENT message naming the field.
std::string ResolveTabulationGrid(const v1::TabulateRequest& request, const models::Model& model,
                                  TabulationGrid* out);

// The encoder of a validated format and grid; fp64 only sets CSV's printed digits.
std::unique_ptr<TableEncoder> MakeTableEncoder(v1::TableFormat format, const TabulationGrid& grid, bool fp64);

// Checks the fields that do not depend on the model (format, precision, grid shape, limits are checked
// with the grid). Returns "" or "field: reason".
std::string ValidateTabulateRequest(const v1::TabulateRequest& request, const TabulationGrid& grid);

// Every check of a request once its material's model is known (no packing): its grid (into *grid), the other
// fields, and fp64 where the device has it. OK or the status to reply.
grpc::Status CheckTabulateRequest(const v1::TabulateRequest& request, const models::Model& model, bool has_fp64,
                                  TabulationGrid* grid);

// The bytes a validated request's call holds (its admission).
size_t TabulateBytes(const v1::TabulateRequest& request, const TabulationGrid& grid);

// Serves one call: validation errors finish at once; otherwise the reactor streams the table.
grpc::ServerWriteReactor<v1::TabulateChunk>* HandleTabulate(const TabulateDeps& deps,
                                                            grpc::CallbackServerContext* context,
                                                            const v1::TabulateRequest* request);

}  // namespace loomlight::api
