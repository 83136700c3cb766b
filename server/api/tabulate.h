// The Tabulate RPC: f of one material on a grid of directions (in-plane slice, full 4D, MERL half/diff),
// encoded on the server as a standard file (RAW with a header, OpenEXR, MERL .binary, CSV) and streamed as
// chunks of bytes with progress. Queries go through the batcher in chunks of at most one Evaluate call, so
// a big table takes turns with other clients; filling directions, averaging and encoding run on the
// service's HostWorker, never on the batcher's thread or a gRPC callback thread.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/host_worker.h"
#include "server/api/metrics.h"
#include "server/api/service.h"
#include "server/api/tabulate_grid.h"
#include "server/batching/batcher.h"
#include "server/models/registry.h"

namespace loomlight::api {

// Documented limits (README "Limits").
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

// RAW format header ("LLTB"), little-endian, kRawHeaderBytes long; then float32 RGB per cell.
constexpr uint32_t kRawVersion = 1;
constexpr uint32_t kRawHeaderBytes = 40;
enum class GridKind : uint32_t { kInPlane = 1, kAnisotropic = 2, kMerl = 3 };

using TabulateDeps = ServiceDeps;

// A validated request's grid: its dimensions and the directions of each query.
class TabulationGrid {
 public:
  // Resolves the request's grid for `model` (its isotropy picks the MERL default). Returns "" or the
  // INVALID_ARGUMENT message naming the field.
  static std::string Resolve(const v1::TabulateRequest& request, const models::Model& model, TabulationGrid* out);

  GridKind kind() const { return kind_; }
  const std::vector<uint32_t>& dims() const { return dims_; }  // slowest first
  uint64_t cells() const { return cells_; }
  uint32_t queries_per_cell() const { return queries_per_cell_; }
  uint64_t queries() const { return cells_ * queries_per_cell_; }
  // Cells per EXR row: the outgoing dimensions (in-plane: theta_o; 4D: theta_o x phi_o; MERL: phi_d).
  uint64_t row_cells() const { return row_cells_; }
  // Query q = cell * queries_per_cell + sample, as float xyz (what the kernels take).
  void Directions(uint64_t query, float* wi, float* wo) const;
  // The cell's grid angles in degrees, in the order of angle_names().
  std::vector<double> CellAngles(uint64_t cell) const;
  std::vector<std::string> angle_names() const;

 private:
  struct Axis {
    std::vector<double> deg;
    std::vector<tabulation::CosSin> trig;
    // A grid angle (reported in CSV) and the angle of the direction it stands for.
    void Add(double deg, double direction_deg);
  };
  // The index of dimension `dim` of a cell.
  uint32_t Index(uint64_t cell, size_t dim) const;

  GridKind kind_ = GridKind::kInPlane;
  std::vector<uint32_t> dims_;
  std::vector<Axis> axes_;  // one per dimension, plus phi_h for MERL
  tabulation::CosSin phi_plane_;
  uint64_t cells_ = 0, row_cells_ = 0;
  uint32_t queries_per_cell_ = 1;
};

// Turns cells (in grid order) into file bytes. Bytes that are final are appended as cells arrive, so a
// table streams while it is computed; the rest (MERL's G and B blocks, the whole EXR) at the end.
class TableEncoder {
 public:
  virtual ~TableEncoder() = default;
  // The file's first bytes (a header), before any cell.
  virtual void Begin(std::string* out) {}
  // `count` cells from `first`, RGB each (finite).
  virtual void AddCells(uint64_t first, const double* rgb, size_t count, std::string* out) = 0;
  // After the last cell: the rest of the file. Returns "" or the reason it cannot be encoded.
  virtual std::string End(std::string* out) { return ""; }
};
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
