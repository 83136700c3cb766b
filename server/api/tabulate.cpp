#include "server/api/tabulate.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <initializer_list>

#include "server/api/job_status.h"
#include "server/api/stream_call.h"
#include "server/models/material_plan.h"
#include "server/models/query_means.h"

namespace loomlight::api {
namespace {

constexpr const char* kRpc = "Tabulate";
constexpr uint32_t kMaxPhiHSamples = 1024;  // the cell limit binds first (23 for the MERL grid)

using Clock = batching::Clock;


// "1,048,576": limits in messages are read by people.
std::string Grouped(uint64_t n) {
  std::string digits = std::to_string(n), out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

// The product, or UINT64_MAX when it would overflow (only compared against limits).
uint64_t SaturatingProduct(std::initializer_list<uint64_t> factors) {
  uint64_t p = 1;
  for (uint64_t f : factors) {
    if (f != 0 && p > UINT64_MAX / f) return UINT64_MAX;
    p *= f;
  }
  return p;
}

std::string CheckCount(uint32_t count, const std::string& field) {
  if (count < 1) return field + ": must be at least 1";
  return "";
}

// The evaluation limit, counting every query of every cell.
std::string CheckQueries(uint64_t cells, uint32_t per_cell, const std::string& field, const std::string& shape) {
  const uint64_t queries = SaturatingProduct({cells, per_cell});
  if (queries <= kMaxTabulateQueries) return "";
  std::string what = shape + (cells == UINT64_MAX ? "" : " = " + Grouped(cells)) + " cells";
  if (per_cell > 1) what += " x " + std::to_string(per_cell) + " queries per cell";
  return field + ": " + what + " exceed the limit of " + Grouped(kMaxTabulateQueries) + " evaluations per call";
}

// One Tabulate call in flight, on the host worker (server/api/stream_call.h); batcher completions post there
// too. The call is finished only when neither a batcher job nor a write is outstanding, so nothing refers
// to it after OnDone.
class TabulateCall final : public WorkerStreamCall<v1::TabulateChunk> {
 public:
  TabulateCall(const TabulateDeps& deps, grpc::CallbackServerContext* context, const v1::TabulateRequest& request,
               std::shared_ptr<const models::PreparedMaterial> material, TabulationGrid grid, Admission admission,
               Clock::time_point received)
      : WorkerStreamCall(deps, context, kRpc, received, std::move(admission)),
        material_(std::move(material)),
        material_request_(request.material()),
        grid_(std::move(grid)),
        fp64_(request.precision() == v1::PRECISION_FP64),
        encoder_(MakeTableEncoder(request.format(), grid_, fp64_)),
        // Whole cells per job, so each cell's mean comes from one job.
        chunk_queries_(std::min<uint64_t>(kTabulateChunkQueries / grid_.queries_per_cell() * grid_.queries_per_cell(),
                                          grid_.queries())) {
    Post([this] {
      if (!material_) status_ = PrepareMaterial(deps_, material_request_, &material_);
      encoder_->Begin(&pending_);
      Pump();
    });
  }


 private:
  // One chunk of queries from its submission until its cells are encoded (then emptied).
  struct Chunk {
    std::vector<float> wi, wo;  // the batcher reads them until the chunk's done callbacks
    std::unique_ptr<models::EvaluationPlan> plan;  // its parts (a curtain: reflection and layer)
    std::vector<double> f;  // merged from its parts
    uint64_t first_query = 0;
    size_t jobs_in_flight = 0;
  };

  // The one step of the state machine: notice cancellation, keep kTabulateChunksInFlight chunks in flight
  // while the output buffer allows, keep one write in flight while there is something to say, finish when all
  // is done.
  void Pump() override {
    if (finished_) return;
    NoticeStop();
    MaybeSubmit();  // does nothing once stopping
    if (!status_.ok()) {
      if (!JobsInFlight() && !write_in_flight_) FinishCall(status_);
      return;
    }
    if (write_in_flight_) return;
    if (Unsent() > 0 || cells_done_ > cells_sent_ || !sent_first_)
      WriteChunk();
    else if (complete_)
      FinishCall(grpc::Status::OK);
  }

  size_t Unsent() const { return pending_.size() - pending_begin_; }

  // Chunk number s (in query order) lives in slot s % kTabulateChunksInFlight; those from chunks_encoded_ to
  // chunks_submitted_ are in flight.
  Chunk& Slot(uint64_t number) { return chunks_[number % kTabulateChunksInFlight]; }

  bool JobsInFlight() const {
    return std::any_of(chunks_.begin(), chunks_.end(), [](const Chunk& c) { return c.jobs_in_flight > 0; });
  }

  // Sends the next chunks' jobs (one per part of a chunk's plan: a curtain's reflection and layer) while a slot
  // is free and the output buffer allows.
  void MaybeSubmit() {
    while (status_.ok() && chunks_submitted_ - chunks_encoded_ < kTabulateChunksInFlight &&
           next_query_ < grid_.queries() && Unsent() <= kMaxBufferedBytes)
      Submit(chunks_submitted_++);
  }

  // Fills the next queries' directions into chunk `number`'s slot and queues its jobs.
  void Submit(uint64_t number) {
    Chunk& chunk = Slot(number);
    chunk.first_query = next_query_;
    const size_t count = static_cast<size_t>(std::min<uint64_t>(chunk_queries_, grid_.queries() - next_query_));
    chunk.wi.resize(3 * count);
    chunk.wo.resize(3 * count);
    grid_.FillDirections(next_query_, count, chunk.wi.data(), chunk.wo.data());
    chunk.plan = std::make_unique<models::EvaluationPlan>(*material_, chunk.wi.data(), chunk.wo.data(), nullptr, count);
    chunk.f.assign(3 * count, 0.0);
    next_query_ += count;
    chunk.jobs_in_flight = chunk.plan->parts();
    SubmitPlan(deps_.batcher, *chunk.plan, runtime::ResultSink{.f64 = chunk.f.data()}, fp64_,
               batching::Priority::kBulk, deadline_, context_, client_, [this, &chunk](size_t k, batching::JobResult result) {
                 Post([this, &chunk, k, result = std::move(result)] { OnJobDone(chunk, k, result); });
               });
  }

  // A part of a chunk in flight returned: the chunks that are complete are encoded in query order (a later
  // chunk that finishes first waits for the earlier one), each slot freed for the next chunk.
  void OnJobDone(Chunk& chunk, size_t part, const batching::JobResult& result) {
    --chunk.jobs_in_flight;
    if (result.status != batching::JobStatus::kOk) {
      if (status_.ok()) status_ = ToStatus(result);
      return Pump();
    }
    if (result.batch_queries > 0)
      deps_.metrics->Evaluated(chunk.plan->model(part).name(), fp64_, chunk.plan->size(part), result.batch_queries,
                               result.batch_requests, result.queue_seconds, result.kernel_seconds);
    kernel_seconds_ += result.kernel_seconds;
    NoticeStop();  // a stopped call encodes no more
    while (status_.ok() && chunks_encoded_ < chunks_submitted_ && Slot(chunks_encoded_).jobs_in_flight == 0) {
      Chunk& oldest = Slot(chunks_encoded_++);
      if (std::string error = AddCells(oldest.first_query, oldest.f.size() / 3, oldest.f); !error.empty())
        status_ = {grpc::StatusCode::INTERNAL, error};
      oldest = Chunk();  // a call held back by a slow reader keeps no chunk buffers
    }
    Pump();  // submits into the freed slots
  }

  // Means over each cell's queries (in place in f), encoded. Returns "" or what is wrong with the output.
  std::string AddCells(uint64_t first_query, size_t count, std::vector<double>& f) {
    if (f.size() != 3 * count)
      return "kernel returned " + std::to_string(f.size()) + " values for " + std::to_string(count) + " queries";
    const uint32_t per_cell = grid_.queries_per_cell();
    const uint64_t first_cell = first_query / per_cell;
    const size_t cells = count / per_cell;
    if (const size_t bad = models::GroupMeansInPlace(f.data(), cells, per_cell); bad < cells)
      return "model '" + material_->model->name() + "' returned a non-finite value in cell " +
             std::to_string(first_cell + bad);
    encoder_->AddCells(first_cell, f.data(), cells, &pending_);
    cells_done_ += cells;
    deps_.metrics->Tabulated(material_->model->name(), fp64_, cells);
    if (cells_done_ == grid_.cells()) {
      if (std::string error = encoder_->End(&pending_); !error.empty()) return "cannot encode the table: " + error;
      complete_ = true;
    }
    return "";
  }

  // One write in flight at a time (gRPC flow control): the next waits for OnWriteDone.
  void WriteChunk() {
    chunk_.Clear();
    if (!sent_first_) {
      sent_first_ = true;
      chunk_.mutable_dims()->Add(grid_.dims().begin(), grid_.dims().end());
      chunk_.set_queries_per_cell(grid_.queries_per_cell());
      chunk_.set_model(material_->model->name());
    }
    const size_t n = std::min(Unsent(), kMaxChunkDataBytes);
    chunk_.set_data(pending_.data() + pending_begin_, n);
    pending_begin_ += n;
    if (pending_begin_ == pending_.size()) {
      pending_.clear();
      pending_begin_ = 0;
    } else if (pending_begin_ > kMaxChunkDataBytes && pending_begin_ > pending_.size() / 2) {
      pending_.erase(0, pending_begin_);  // amortised: each byte moves at most once per halving
      pending_begin_ = 0;
    }
    chunk_.set_cells_done(cells_done_);
    chunk_.set_cells_total(grid_.cells());
    cells_sent_ = cells_done_;
    if (complete_ && Unsent() == 0) {
      chunk_.set_kernel_seconds(kernel_seconds_);
      chunk_.set_total_seconds(SecondsSince(received_));
    }
    write_in_flight_ = true;
    StartWrite(&chunk_);
  }

  std::shared_ptr<const models::PreparedMaterial> material_;  // set before the first Pump
  const v1::Material material_request_;
  const TabulationGrid grid_;
  const bool fp64_;
  const std::unique_ptr<TableEncoder> encoder_;
  const uint64_t chunk_queries_;

  std::array<Chunk, kTabulateChunksInFlight> chunks_;  // see Slot
  uint64_t chunks_submitted_ = 0, chunks_encoded_ = 0;
  uint64_t next_query_ = 0, cells_done_ = 0, cells_sent_ = 0;
  std::string pending_;  // encoded bytes; those from pending_begin_ on are not sent yet
  size_t pending_begin_ = 0;
  v1::TabulateChunk chunk_;  // the write in flight
  double kernel_seconds_ = 0;
  bool sent_first_ = false;
  bool complete_ = false;       // every cell encoded, the file's end in pending_
};

}  // namespace

std::string ResolveTabulationGrid(const v1::TabulateRequest& request, const models::Model& model,
                                  TabulationGrid* out) {
  switch (request.grid_case()) {
    case v1::TabulateRequest::kInPlane: {
      const v1::InPlaneGrid& p = request.in_plane();
      if (p.theta_i_deg_size() > 0 && p.theta_i_count() > 0)
        return "in_plane.theta_i_count: give incidence angles (theta_i_deg) or a count, not both";
      if (p.theta_i_deg_size() == 0 && p.theta_i_count() == 0)
        return "in_plane.theta_i_count: give incidence angles (theta_i_deg) or a count of at least 1";
      for (int i = 0; i < p.theta_i_deg_size(); ++i)
        if (!std::isfinite(p.theta_i_deg(i)) || std::fabs(p.theta_i_deg(i)) > 180.0)
          return "in_plane.theta_i_deg[" + std::to_string(i) + "]: " + std::to_string(p.theta_i_deg(i)) +
                 " is not finite within [-180, 180] degrees";
      if (std::string e = CheckCount(p.theta_o_count(), "in_plane.theta_o_count"); !e.empty()) return e;
      if (!std::isfinite(p.phi_plane_deg()) || std::fabs(p.phi_plane_deg()) > kMaxAngleDeg)
        return "in_plane.phi_plane_deg: " + std::to_string(p.phi_plane_deg()) + " is not finite within [-360, 360]";
      const uint32_t incidences = p.theta_i_deg_size() > 0 ? p.theta_i_deg_size() : p.theta_i_count();
      if (std::string e = CheckQueries(SaturatingProduct({incidences, p.theta_o_count()}), 1, "in_plane",
                                       std::to_string(incidences) + " x " + std::to_string(p.theta_o_count()));
          !e.empty())
        return e;
      *out = p.theta_i_deg_size() > 0
                 ? TabulationGrid::InPlane({p.theta_i_deg().begin(), p.theta_i_deg().end()}, p.theta_o_count(),
                                           p.full_circle(), p.phi_plane_deg())
                 : TabulationGrid::InPlaneBins(incidences, p.theta_o_count(), p.full_circle(), p.phi_plane_deg());
      return "";
    }
    case v1::TabulateRequest::kAnisotropic: {
      const v1::AnisotropicGrid& a = request.anisotropic();
      const uint32_t dims[4] = {a.theta_i_count(), a.phi_i_count(), a.theta_o_count(), a.phi_o_count()};
      const char* names[4] = {"theta_i_count", "phi_i_count", "theta_o_count", "phi_o_count"};
      for (int d = 0; d < 4; ++d)
        if (std::string e = CheckCount(dims[d], std::string("anisotropic.") + names[d]); !e.empty()) return e;
      const uint64_t cells = SaturatingProduct({dims[0], dims[1], dims[2], dims[3]});
      if (std::string e = CheckQueries(cells, 1, "anisotropic",
                                       std::to_string(dims[0]) + " x " + std::to_string(dims[1]) + " x " +
                                           std::to_string(dims[2]) + " x " + std::to_string(dims[3]));
          !e.empty())
        return e;
      *out = TabulationGrid::Anisotropic(dims[0], dims[1], dims[2], dims[3]);
      return "";
    }
    case v1::TabulateRequest::kMerl: {
      const uint32_t requested = request.merl().phi_h_samples();
      if (requested > kMaxPhiHSamples)
        return "merl.phi_h_samples: " + std::to_string(requested) + " is outside 0.." + std::to_string(kMaxPhiHSamples);
      const uint32_t samples = requested > 0 ? requested : model.isotropic() ? 1 : kDefaultAnisotropicPhiHSamples;
      if (std::string e = CheckQueries(tabulation::kMerlCells, samples, "merl.phi_h_samples", "90 x 90 x 180");
          !e.empty())
        return e;
      *out = TabulationGrid::Merl(samples);
      return "";
    }
    default:
      return "grid: set one of in_plane, anisotropic, merl";
  }
}

std::unique_ptr<TableEncoder> MakeTableEncoder(v1::TableFormat format, const TabulationGrid& grid, bool fp64) {
  switch (format) {
    case v1::TABLE_FORMAT_EXR: return tabulation::MakeTableEncoder(tabulation::TableFormat::kExr, grid, fp64);
    case v1::TABLE_FORMAT_MERL: return tabulation::MakeTableEncoder(tabulation::TableFormat::kMerl, grid, fp64);
    case v1::TABLE_FORMAT_CSV: return tabulation::MakeTableEncoder(tabulation::TableFormat::kCsv, grid, fp64);
    default: return tabulation::MakeTableEncoder(tabulation::TableFormat::kRaw, grid, fp64);
  }
}

size_t TabulateBytes(const v1::TabulateRequest& request, const TabulationGrid& grid) {
  const uint64_t chunk = std::min<uint64_t>(kTabulateChunkQueries, grid.queries());
  // Per chunk in flight: directions (24 per query; a curtain's parts copy them, with a scale and a
  // transmittance: 40) and the kernels' results (24, then the cell means in place);
  // unsent bytes up to the flow-control bound, plus a chunk message's bytes for what each chunk in flight may
  // encode past it (RAW: 12 bytes a cell, 3 MiB) and for the message being written; what the encoder keeps to
  // the end.
  size_t bytes = chunk * kTabulateChunksInFlight * 88 + kMaxBufferedBytes +
                 (kTabulateChunksInFlight + 1) * kMaxChunkDataBytes;
  if (request.format() == v1::TABLE_FORMAT_EXR) bytes += grid.cells() * 24;   // the image, then its encoding
  if (request.format() == v1::TABLE_FORMAT_MERL) bytes += grid.cells() * 16;  // G and B until the end
  return bytes;
}

std::string ValidateTabulateRequest(const v1::TabulateRequest& request, const TabulationGrid& grid) {
  if (!v1::Precision_IsValid(request.precision()))
    return "precision: unknown value " + std::to_string(request.precision());
  if (!v1::TableFormat_IsValid(request.format())) return "format: unknown value " + std::to_string(request.format());
  if (request.format() == v1::TABLE_FORMAT_MERL && grid.kind() != GridKind::kMerl)
    return "format: MERL .binary needs the merl grid";
  const auto limit = [&](uint64_t max_cells, const char* name) -> std::string {
    if (grid.cells() <= max_cells) return "";
    return std::string("format: ") + name + " tables are limited to " + Grouped(max_cells) + " cells; this grid has " +
           Grouped(grid.cells()) + " (use TABLE_FORMAT_RAW)";
  };
  if (request.format() == v1::TABLE_FORMAT_EXR) return limit(kMaxExrCells, "EXR");
  if (request.format() == v1::TABLE_FORMAT_CSV) return limit(kMaxCsvCells, "CSV");
  return "";
}

grpc::Status CheckTabulateRequest(const v1::TabulateRequest& request, const models::Model& model, bool has_fp64,
                                  TabulationGrid* grid) {
  if (std::string error = ResolveTabulationGrid(request, model, grid); !error.empty()) return Invalid(error);
  if (std::string error = ValidateTabulateRequest(request, *grid); !error.empty()) return Invalid(error);
  if (request.precision() == v1::PRECISION_FP64 && !has_fp64)
    return {grpc::StatusCode::FAILED_PRECONDITION, "precision: the OpenCL device has no fp64"};
  return grpc::Status::OK;
}

grpc::ServerWriteReactor<v1::TabulateChunk>* HandleTabulate(const TabulateDeps& deps,
                                                            grpc::CallbackServerContext* context,
                                                            const v1::TabulateRequest* request) {
  const auto received = Clock::now();
  const auto reject = [&](grpc::Status status) {
    return new RejectedStream<v1::TabulateChunk>(deps.metrics, kRpc, received, std::move(status));
  };
  const models::Model* model = nullptr;
  std::shared_ptr<const models::PreparedMaterial> material;  // null until packed, on the host worker
  if (std::string error = deps.materials->Peek(request->material(), *deps.registry, &model, &material); !error.empty())
    return reject(MaterialError(error));
  TabulationGrid grid;
  if (grpc::Status s = CheckTabulateRequest(*request, *model, deps.has_fp64, &grid); !s.ok()) return reject(s);
  Admission admission;
  if (grpc::Status s = AdmitLongCall(deps, *context, TabulateBytes(*request, grid), &admission); !s.ok())
    return reject(s);
  return new TabulateCall(deps, context, *request, std::move(material), std::move(grid), std::move(admission),
                          received);
}

}  // namespace loomlight::api
