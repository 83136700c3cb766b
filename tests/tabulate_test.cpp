// Tabulate end to end against a real server, for every model in ListModels: a MERL .binary read back by a
// reader written here from the format's description, EXR, RAW and CSV tables equal Evaluate at the
// documented bin centres; progress is monotone and ends at the total; a table keeps two chunks queued at once;
// cancellation and deadlines stop the work (the server's tabulated-cell counter proves it); bad fields are
// named; and the client's `tab` command and plot views write files that decode.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <numbers>
#include <sstream>
#include <thread>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/api/tabulate.h"
#include "server/models/query_means.h"
#include "server/models/tabulation/grid.h"
#include "tests/testing.h"

// After the protobuf headers: OpenImageIO's byte-swap macros clash with protobuf's port.h.
#include <OpenImageIO/imageio.h>

namespace loomlight {
namespace {

using Vec = std::array<double, 3>;

// ---- Directions at the documented bin centres, written here from docs/tabulation.md, not from the server ----

double Rad(double deg) { return deg * std::numbers::pi / 180.0; }
Vec Spherical(double theta_deg, double phi_deg) {
  const double t = Rad(theta_deg), p = Rad(phi_deg);
  return {std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t)};
}
double Centre(uint32_t k, uint32_t n, double range) { return (k + 0.5) * range / n; }

// The half-vector frame: h at (theta_h, phi_h), x_h = dh/dtheta_h, y_h = the azimuthal direction.
std::pair<Vec, Vec> HalfDiff(double theta_h, double phi_h, double theta_d, double phi_d) {
  const double th = Rad(theta_h), ph = Rad(phi_h);
  const Vec h = Spherical(theta_h, phi_h);
  const Vec xh = {std::cos(th) * std::cos(ph), std::cos(th) * std::sin(ph), -std::sin(th)};
  const Vec yh = {-std::sin(ph), std::cos(ph), 0.0};
  const Vec d = Spherical(theta_d, phi_d);
  Vec wi, wo;
  for (int c = 0; c < 3; ++c) {
    wi[c] = d[0] * xh[c] + d[1] * yh[c] + d[2] * h[c];
    wo[c] = -d[0] * xh[c] - d[1] * yh[c] + d[2] * h[c];
  }
  return {wi, wo};
}

struct Queries {
  std::vector<float> wi, wo;
  void Add(const Vec& i, const Vec& o) {
    for (int c = 0; c < 3; ++c) {
      wi.push_back(static_cast<float>(i[c]));
      wo.push_back(static_cast<float>(o[c]));
    }
  }
  size_t size() const { return wi.size() / 3; }
};

Queries MerlQueries() {  // one phi_h sample: phi_h = 0
  Queries q;
  for (int i = 0; i < 90; ++i)
    for (int j = 0; j < 90; ++j)
      for (int k = 0; k < 180; ++k) {
        const double x = (i + 0.5) / 90.0;
        const auto [wi, wo] = HalfDiff(x * x * 90.0, 0.0, j + 0.5, k + 0.5);
        q.Add(wi, wo);
      }
  return q;
}

Queries AnisotropicQueries(uint32_t ti, uint32_t pi, uint32_t to, uint32_t po) {
  Queries q;
  for (uint32_t a = 0; a < ti; ++a)
    for (uint32_t b = 0; b < pi; ++b)
      for (uint32_t c = 0; c < to; ++c)
        for (uint32_t d = 0; d < po; ++d)
          q.Add(Spherical(Centre(a, ti, 90), Centre(b, pi, 360)), Spherical(Centre(c, to, 90), Centre(d, po, 360)));
  return q;
}

// Signed in-plane angles: the light at -theta_i, theta_o over the whole circle.
Queries InPlaneQueries(const std::vector<double>& theta_i, uint32_t theta_o_count, double phi, bool full_circle) {
  Queries q;
  const double range = full_circle ? 360 : 180;
  for (double ti : theta_i)
    for (uint32_t k = 0; k < theta_o_count; ++k) q.Add(Spherical(-ti, phi), Spherical(-range / 2 + Centre(k, theta_o_count, range), phi));
  return q;
}

// ---- Calls ----

// A material for a model as ListModels describes it: its first preset, else its defaults.
v1::Material MaterialOf(const v1::ModelInfo& model) {
  v1::Material m;
  if (model.presets_size() > 0)
    m.set_preset(model.presets(0).name());
  else
    m.set_model(model.name());
  return m;
}

// f from Evaluate, in calls of at most the per-call limit.
std::vector<float> Evaluate(v1::Loomlight::Stub& stub, const v1::Material& material, v1::Precision precision,
                            const Queries& q) {
  std::vector<float> f;
  for (size_t first = 0; first < q.size(); first += api::kMaxQueriesPerCall) {
    const size_t n = std::min(api::kMaxQueriesPerCall, q.size() - first);
    v1::EvaluateRequest r;
    *r.mutable_material() = material;
    r.set_precision(precision);
    r.mutable_wi()->Add(q.wi.begin() + 3 * first, q.wi.begin() + 3 * (first + n));
    r.mutable_wo()->Add(q.wo.begin() + 3 * first, q.wo.begin() + 3 * (first + n));
    v1::EvaluateResponse response;
    grpc::ClientContext ctx;
    const grpc::Status status = stub.Evaluate(&ctx, r, &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    f.insert(f.end(), response.f().begin(), response.f().end());
  }
  return f;
}

struct Table {
  grpc::Status status;
  std::string file;                        // the concatenated data
  std::vector<v1::TabulateChunk> chunks;   // without their data
  std::vector<size_t> data_sizes;
};

// Reads the whole stream; `after_chunk` may cancel the context (it returns true to stop reading).
Table Tabulate(v1::Loomlight::Stub& stub, const v1::TabulateRequest& request,
               std::chrono::milliseconds timeout = std::chrono::seconds(120),
               std::function<bool(grpc::ClientContext&, const v1::TabulateChunk&)> after_chunk = nullptr) {
  Table t;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + timeout);
  auto reader = stub.Tabulate(&ctx, request);
  v1::TabulateChunk chunk;
  bool stopped = false;
  while (reader->Read(&chunk)) {
    t.file += chunk.data();
    t.data_sizes.push_back(chunk.data().size());
    chunk.clear_data();
    t.chunks.push_back(chunk);
    if (!stopped && after_chunk && after_chunk(ctx, chunk)) stopped = true;
  }
  t.status = reader->Finish();
  return t;
}

v1::TabulateRequest Request(const v1::Material& material, v1::TableFormat format,
                            v1::Precision precision = v1::PRECISION_FP32) {
  v1::TabulateRequest r;
  *r.mutable_material() = material;
  r.set_format(format);
  r.set_precision(precision);
  return r;
}

// Little-endian reads of the documented binary layouts.
template <typename T>
T ReadLe(const std::string& bytes, size_t offset) {
  using Bits = std::conditional_t<sizeof(T) == 8, uint64_t, uint32_t>;
  Bits bits = 0;
  for (size_t b = 0; b < sizeof(T); ++b) bits |= Bits(static_cast<unsigned char>(bytes.at(offset + b))) << (8 * b);
  return std::bit_cast<T>(bits);
}

// |a - b| within `rel` of the larger, or both tiny.
void ExpectClose(double actual, double expected, double rel, const std::string& where) {
  ASSERT_TRUE(std::isfinite(actual)) << where;
  ASSERT_NEAR(actual, expected, rel * std::max(std::fabs(actual), std::fabs(expected)) + 1e-30) << where;
}

class TabulateTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    api::ServerOptions options;
    options.address = "127.0.0.1:0";
    options.metrics_address = "127.0.0.1:0";  // DeadlineStopsTabulation reads how calls ended
    std::string error;
    server_ = api::LoomlightServer::Start(options, &error).release();
    ASSERT_NE(server_, nullptr) << error;
    stub_ = testing::Connect(server_->port()).release();
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub_->ListModels(&ctx, v1::ListModelsRequest(), &models_).ok());
    ASSERT_GT(models_.models_size(), 0);
  }
  static void TearDownTestSuite() {
    delete stub_;
    delete server_;
  }
  static api::LoomlightServer* server_;
  static v1::Loomlight::Stub* stub_;
  static v1::ListModelsResponse models_;
};
api::LoomlightServer* TabulateTest::server_ = nullptr;
v1::Loomlight::Stub* TabulateTest::stub_ = nullptr;
v1::ListModelsResponse TabulateTest::models_;

TEST_F(TabulateTest, MerlExportReadBackEqualsEvaluateAtBinCentres) {
  const Queries q = MerlQueries();
  for (const v1::ModelInfo& model : models_.models()) {
    SCOPED_TRACE(model.name());
    v1::TabulateRequest r = Request(MaterialOf(model), v1::TABLE_FORMAT_MERL);
    r.mutable_merl()->set_phi_h_samples(1);
    const Table t = Tabulate(*stub_, r);
    ASSERT_TRUE(t.status.ok()) << t.status.error_message();
    // The reader: three int32 dims, then n float64 R, n G, n B; f = stored value x channel scale.
    const int32_t dims[3] = {ReadLe<int32_t>(t.file, 0), ReadLe<int32_t>(t.file, 4), ReadLe<int32_t>(t.file, 8)};
    ASSERT_EQ(dims[0], 90);
    ASSERT_EQ(dims[1], 90);
    ASSERT_EQ(dims[2], 180);
    const size_t n = size_t(dims[0]) * dims[1] * dims[2];
    ASSERT_EQ(t.file.size(), 12 + 3 * 8 * n);
    const double scale[3] = {1.0 / 1500, 1.15 / 1500, 1.66 / 1500};
    const std::vector<float> f = Evaluate(*stub_, MaterialOf(model), v1::PRECISION_FP32, q);
    ASSERT_EQ(f.size(), 3 * n);
    double max_f = 0;
    for (size_t cell = 0; cell < n; ++cell)
      for (int c = 0; c < 3; ++c) {
        const double value = ReadLe<double>(t.file, 12 + 8 * (c * n + cell)) * scale[c];
        ExpectClose(value, f[3 * cell + c], 1e-6, "cell " + std::to_string(cell) + " channel " + std::to_string(c));
        ASSERT_GE(value, 0.0);
        max_f = std::max(max_f, value);
      }
    EXPECT_GT(max_f, 0.0);
  }
}

TEST_F(TabulateTest, ExrRoundTripEqualsEvaluate) {
  constexpr uint32_t ti = 4, pi = 3, to = 5, po = 6;
  const Queries q = AnisotropicQueries(ti, pi, to, po);
  for (const v1::ModelInfo& model : models_.models()) {
    SCOPED_TRACE(model.name());
    v1::TabulateRequest r = Request(MaterialOf(model), v1::TABLE_FORMAT_EXR);
    auto* grid = r.mutable_anisotropic();
    grid->set_theta_i_count(ti);
    grid->set_phi_i_count(pi);
    grid->set_theta_o_count(to);
    grid->set_phi_o_count(po);
    const Table t = Tabulate(*stub_, r);
    ASSERT_TRUE(t.status.ok()) << t.status.error_message();
    const std::string path = ::testing::TempDir() + "/table_" + model.name() + ".exr";
    std::ofstream(path, std::ios::binary) << t.file;
    auto in = OIIO::ImageInput::open(path);
    ASSERT_TRUE(in) << OIIO::geterror();
    ASSERT_EQ(in->spec().width, int(to * po));  // one column per outgoing cell
    ASSERT_EQ(in->spec().height, int(ti * pi));  // one row per incoming cell
    ASSERT_EQ(in->spec().nchannels, 3);
    std::vector<float> pixels(q.size() * 3);
    ASSERT_TRUE(in->read_image(0, 0, 0, 3, OIIO::TypeDesc::FLOAT, pixels.data()));
    const std::vector<float> f = Evaluate(*stub_, MaterialOf(model), v1::PRECISION_FP32, q);
    for (size_t i = 0; i < f.size(); ++i) ExpectClose(pixels[i], f[i], 1e-6, "value " + std::to_string(i));
  }
}

TEST_F(TabulateTest, RawRoundTripEqualsEvaluateFp64IncludingBackLitDirections) {
  const std::vector<double> theta_i = {-30, 0, 45, 170};  // 170: lit from below (transmission models)
  constexpr uint32_t kThetaO = 37;
  constexpr double kPhi = 30;
  const Queries q = InPlaneQueries(theta_i, kThetaO, kPhi, true);
  for (const v1::ModelInfo& model : models_.models()) {
    SCOPED_TRACE(model.name());
    v1::TabulateRequest r = Request(MaterialOf(model), v1::TABLE_FORMAT_RAW, v1::PRECISION_FP64);
    auto* grid = r.mutable_in_plane();
    grid->mutable_theta_i_deg()->Add(theta_i.begin(), theta_i.end());
    grid->set_theta_o_count(kThetaO);
    grid->set_phi_plane_deg(kPhi);
    grid->set_full_circle(true);
    const Table t = Tabulate(*stub_, r);
    ASSERT_TRUE(t.status.ok()) << t.status.error_message();
    // Header: "LLTB", version 1, header bytes 40, grid kind 1 (in-plane), 2 dims, dims[4], 3 channels.
    ASSERT_GE(t.file.size(), 40u);
    EXPECT_EQ(t.file.substr(0, 4), "LLTB");
    EXPECT_EQ(ReadLe<uint32_t>(t.file, 4), 1u);
    const uint32_t header = ReadLe<uint32_t>(t.file, 8);
    EXPECT_EQ(header, 40u);
    EXPECT_EQ(ReadLe<uint32_t>(t.file, 12), 1u);
    EXPECT_EQ(ReadLe<uint32_t>(t.file, 16), 2u);
    EXPECT_EQ(ReadLe<uint32_t>(t.file, 20), theta_i.size());
    EXPECT_EQ(ReadLe<uint32_t>(t.file, 24), kThetaO);
    EXPECT_EQ(ReadLe<uint32_t>(t.file, 36), 3u);
    ASSERT_EQ(t.file.size(), header + 4 * 3 * q.size());
    const std::vector<float> f = Evaluate(*stub_, MaterialOf(model), v1::PRECISION_FP64, q);
    for (size_t i = 0; i < f.size(); ++i)
      ExpectClose(ReadLe<float>(t.file, header + 4 * i), f[i], 1e-6, "value " + std::to_string(i));
  }
}

// A curtain (reflection plus a thin layer behind it) tabulates as Evaluate evaluates it, on both sides of the
// cloth: the material plan is one definition for both RPCs (it once gave zeros below the surface here).
TEST_F(TabulateTest, CurtainTableEqualsEvaluateOnBothSides) {
  const std::vector<double> theta_i = {30, 150};  // lit from the front, and from behind
  constexpr uint32_t kThetaO = 72;
  const Queries q = InPlaneQueries(theta_i, kThetaO, 0, true);
  v1::Material curtain;
  curtain.set_preset("linen_plain");
  curtain.mutable_transmission()->set_preset("cotton_curtain");
  for (v1::Precision precision : {v1::PRECISION_FP32, v1::PRECISION_FP64}) {
    v1::TabulateRequest r = Request(curtain, v1::TABLE_FORMAT_RAW, precision);
    auto* grid = r.mutable_in_plane();
    grid->mutable_theta_i_deg()->Add(theta_i.begin(), theta_i.end());
    grid->set_theta_o_count(kThetaO);
    grid->set_full_circle(true);
    const Table t = Tabulate(*stub_, r);
    ASSERT_TRUE(t.status.ok()) << t.status.error_message();
    const uint32_t header = ReadLe<uint32_t>(t.file, 8);
    ASSERT_EQ(t.file.size(), header + 4 * 3 * q.size());
    const std::vector<float> f = Evaluate(*stub_, curtain, precision, q);
    ASSERT_EQ(f.size(), 3 * q.size());
    double transmitted = 0, reflected = 0;
    for (size_t i = 0; i < f.size(); ++i) {
      ExpectClose(ReadLe<float>(t.file, header + 4 * i), f[i], 1e-6, "value " + std::to_string(i));
      const size_t query = i / 3;
      (q.wi[3 * query + 2] * q.wo[3 * query + 2] < 0 ? transmitted : reflected) += f[i];
    }
    EXPECT_GT(transmitted, 0);  // light through the cloth, both ways
    EXPECT_GT(reflected, 0);
  }
}

TEST_F(TabulateTest, CsvParsesToTheGridAnglesAndEvaluate) {
  const v1::ModelInfo& model = models_.models(0);
  v1::TabulateRequest r = Request(MaterialOf(model), v1::TABLE_FORMAT_CSV);
  r.mutable_in_plane()->set_theta_i_count(3);
  r.mutable_in_plane()->set_theta_o_count(5);
  const Table t = Tabulate(*stub_, r);
  ASSERT_TRUE(t.status.ok()) << t.status.error_message();
  std::vector<double> centres_i, centres_o;
  for (uint32_t k = 0; k < 3; ++k) centres_i.push_back(Centre(k, 3, 90));
  for (uint32_t k = 0; k < 5; ++k) centres_o.push_back(-90 + Centre(k, 5, 180));
  const std::vector<float> f = Evaluate(*stub_, MaterialOf(model), v1::PRECISION_FP32, InPlaneQueries(centres_i, 5, 0, false));
  std::istringstream lines(t.file);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "theta_i_deg,theta_o_deg,r,g,b");
  size_t row = 0;
  for (; std::getline(lines, line); ++row) {
    std::vector<double> v;
    std::istringstream cells(line);
    for (std::string cell; std::getline(cells, cell, ',');) v.push_back(std::stod(cell));
    ASSERT_EQ(v.size(), 5u) << line;
    ASSERT_LT(row, 15u);
    EXPECT_DOUBLE_EQ(v[0], centres_i[row / 5]);
    EXPECT_DOUBLE_EQ(v[1], centres_o[row % 5]);
    for (int c = 0; c < 3; ++c) EXPECT_EQ(static_cast<float>(v[2 + c]), f[3 * row + c]) << line;
  }
  EXPECT_EQ(row, 15u);
}

TEST_F(TabulateTest, ProgressIsMonotoneChunksAreBoundedAndTheLastReportsTheTotal) {
  v1::TabulateRequest r = Request(MaterialOf(models_.models(0)), v1::TABLE_FORMAT_RAW);
  auto* grid = r.mutable_anisotropic();
  grid->set_theta_i_count(32);
  grid->set_phi_i_count(32);
  grid->set_theta_o_count(32);
  grid->set_phi_o_count(64);  // 2,097,152 cells: two batcher jobs, 24 MiB of floats
  const Table t = Tabulate(*stub_, r);
  ASSERT_TRUE(t.status.ok()) << t.status.error_message();
  const uint64_t total = 32 * 32 * 32 * 64;
  ASSERT_GE(t.chunks.size(), 7u);
  EXPECT_EQ(t.chunks.front().dims_size(), 4);
  EXPECT_EQ(t.chunks.front().model(), models_.models(0).name());
  uint64_t previous = 0;
  for (size_t i = 0; i < t.chunks.size(); ++i) {
    EXPECT_EQ(t.chunks[i].cells_total(), total);
    EXPECT_GE(t.chunks[i].cells_done(), previous) << i;
    EXPECT_LE(t.data_sizes[i], api::kMaxChunkDataBytes) << i;
    previous = t.chunks[i].cells_done();
  }
  EXPECT_EQ(t.chunks.back().cells_done(), total);
  EXPECT_GT(t.chunks.back().total_seconds(), 0.0);
  EXPECT_EQ(t.file.size(), 40 + 12 * total);
}

// Velvet at its most tangent samples: 23 M queries of its costliest setting, a table no CPU finishes before a
// cancel or a 300 ms deadline reaches the server.
v1::Material SlowMaterial() {
  v1::Material velvet;
  velvet.set_preset("velvet");
  v1::Param* samples = velvet.add_params();
  samples->set_name("tangent_samples");
  samples->add_values(256);
  return velvet;
}

// A tabulation cancelled as soon as the first cells arrive: the server stops. What the mechanism guarantees,
// whatever the machine's speed: the server ends the call only when its chunks in flight are back and encodes
// nothing after it noticed the cancel, so once the call is counted CANCELLED the cell count never grows again.
TEST_F(TabulateTest, CancelledTabulationStopsEarly) {
  v1::TabulateRequest r = Request(SlowMaterial(), v1::TABLE_FORMAT_MERL);
  r.mutable_merl()->set_phi_h_samples(16);
  const double calls_before = testing::CallsEnded(server_->metrics_port(), "Tabulate", "CANCELLED");
  const uint64_t before = server_->metrics().tabulated_cells();
  const Table t = Tabulate(*stub_, r, std::chrono::seconds(120), [](grpc::ClientContext& ctx, const v1::TabulateChunk& c) {
    if (c.cells_done() == 0) return false;
    ctx.TryCancel();
    return true;
  });
  EXPECT_EQ(t.status.error_code(), grpc::StatusCode::CANCELLED) << t.status.error_message();
  ASSERT_FALSE(t.chunks.empty());
  EXPECT_EQ(t.chunks.front().queries_per_cell(), 16u);
  ASSERT_TRUE(testing::WaitForCallsEnded(server_->metrics_port(), "Tabulate", "CANCELLED", calls_before + 1))
      << "the server never ended the call";
  const uint64_t done = server_->metrics().tabulated_cells() - before;
  const uint64_t total = 90 * 90 * 180;
  std::printf("cancelled MERL tabulation (velvet, 16 phi_h samples): %llu of %llu cells evaluated (%.1f%%)\n",
              (unsigned long long)done, (unsigned long long)total, 100.0 * done / total);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_EQ(server_->metrics().tabulated_cells() - before, done) << "cells encoded after the call ended";
  EXPECT_GT(done, 0u);
  EXPECT_LT(done, total);
}

// What the mechanism guarantees, whatever the machine's speed (issue 44: a bound of a quarter of the table failed
// on a faster machine): a call stopped by its deadline encodes nothing more once the server noticed it, and the
// server ends it only when its chunks in flight are back, so once the call is counted DEADLINE_EXCEEDED the cell
// count never grows again.
TEST_F(TabulateTest, DeadlineStopsTabulation) {
  v1::TabulateRequest r = Request(SlowMaterial(), v1::TABLE_FORMAT_MERL);
  r.mutable_merl()->set_phi_h_samples(16);
  const double calls_before = testing::CallsEnded(server_->metrics_port(), "Tabulate", "DEADLINE_EXCEEDED");
  const uint64_t before = server_->metrics().tabulated_cells();
  const Table t = Tabulate(*stub_, r, std::chrono::milliseconds(300));
  EXPECT_EQ(t.status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << t.status.error_message();
  ASSERT_TRUE(testing::WaitForCallsEnded(server_->metrics_port(), "Tabulate", "DEADLINE_EXCEEDED", calls_before + 1))
      << "the server never ended the call";
  const uint64_t at_end = server_->metrics().tabulated_cells();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_EQ(server_->metrics().tabulated_cells(), at_end) << "cells encoded after the call ended";
  EXPECT_LT(at_end - before, uint64_t{90 * 90 * 180}) << "the whole table within the deadline";
}


// Issue 15: a table keeps its next chunk queued while one runs, or it misses every launch that starts while its
// next chunk is on its way, however fair the batcher is. Here the bulk queue holds a launch until two chunks
// have queued (or the first has waited 30 s), so the two chunks of this table ride one launch only if both
// are queued at once; with one chunk in flight each waits out the delay and launches alone.
TEST(TabulateChunks, TwoChunksOfOneTableAreQueuedAtOnce) {
  api::ServerOptions options;
  options.metrics_address = "127.0.0.1:0";
  options.batcher.max_batch_queries = 2 * api::kTabulateChunkQueries;
  options.batcher.bulk.max_queue_delay = std::chrono::seconds(30);
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  v1::Material material;
  material.set_preset("linen_plain");
  const std::vector<double> theta_i = {20, 60};  // one chunk each
  const uint32_t theta_o_count = static_cast<uint32_t>(api::kTabulateChunkQueries);
  v1::TabulateRequest r = Request(material, v1::TABLE_FORMAT_RAW);
  r.mutable_in_plane()->mutable_theta_i_deg()->Add(theta_i.begin(), theta_i.end());
  r.mutable_in_plane()->set_theta_o_count(theta_o_count);
  const Table t = Tabulate(*stub, r);
  ASSERT_TRUE(t.status.ok()) << t.status.error_message();
  // Each chunk's job records the launch it rode in before the table's last bytes are sent.
  const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
  EXPECT_EQ(testing::MetricValue(text, "loomlight_launch_requests_count"), 2.0) << text;
  EXPECT_EQ(testing::MetricValue(text, "loomlight_launch_requests_sum"), 4.0) << "each chunk launched alone";
  // Encoded in query order, as Evaluate answers.
  const Queries q = InPlaneQueries(theta_i, theta_o_count, 0, false);
  ASSERT_EQ(t.file.size(), api::kRawHeaderBytes + 4 * 3 * q.size());
  const std::vector<float> f = Evaluate(*stub, material, v1::PRECISION_FP32, q);
  ASSERT_EQ(f.size(), 3 * q.size());
  for (size_t i = 0; i < f.size(); ++i)
    ExpectClose(ReadLe<float>(t.file, api::kRawHeaderBytes + 4 * i), f[i], 1e-6, "value " + std::to_string(i));
}

TEST_F(TabulateTest, DefaultPhiHSamplesFollowTheModelsIsotropy) {
  for (const v1::ModelInfo& model : models_.models()) {
    v1::TabulateRequest r = Request(MaterialOf(model), v1::TABLE_FORMAT_MERL);
    r.mutable_merl();
    const Table t = Tabulate(*stub_, r, std::chrono::seconds(120),
                             [](grpc::ClientContext& ctx, const v1::TabulateChunk&) { ctx.TryCancel(); return true; });
    ASSERT_FALSE(t.chunks.empty()) << model.name() << ": " << t.status.error_message();
    const bool isotropic = models::Registry::Global().FindModel(model.name())->isotropic();
    EXPECT_EQ(t.chunks.front().queries_per_cell(), isotropic ? 1u : api::kDefaultAnisotropicPhiHSamples) << model.name();
  }
}

TEST_F(TabulateTest, BadFieldsAndOverLimitGridsAreNamed) {
  const v1::Material material = MaterialOf(models_.models(0));
  struct Case {
    std::function<void(v1::TabulateRequest&)> mutate;
    std::string field;
  };
  const auto aniso = [](uint32_t a, uint32_t b, uint32_t c, uint32_t d) {
    return [=](v1::TabulateRequest& r) {
      auto* g = r.mutable_anisotropic();
      g->set_theta_i_count(a);
      g->set_phi_i_count(b);
      g->set_theta_o_count(c);
      g->set_phi_o_count(d);
    };
  };
  const auto plane = [](v1::TabulateRequest& r) {
    r.mutable_in_plane()->set_theta_i_count(2);
    r.mutable_in_plane()->set_theta_o_count(3);
  };
  const std::vector<Case> cases = {
      {[](v1::TabulateRequest&) {}, "grid:"},
      {[&](v1::TabulateRequest& r) { plane(r); r.mutable_in_plane()->add_theta_i_deg(10); }, "in_plane.theta_i_count:"},
      {[](v1::TabulateRequest& r) { r.mutable_in_plane()->set_theta_o_count(3); }, "in_plane.theta_i_count:"},
      {[](v1::TabulateRequest& r) {
         r.mutable_in_plane()->add_theta_i_deg(10);
         r.mutable_in_plane()->add_theta_i_deg(NAN);
         r.mutable_in_plane()->set_theta_o_count(3);
       }, "in_plane.theta_i_deg[1]:"},
      {[](v1::TabulateRequest& r) {
         r.mutable_in_plane()->add_theta_i_deg(181);
         r.mutable_in_plane()->set_theta_o_count(3);
       }, "in_plane.theta_i_deg[0]:"},
      {[](v1::TabulateRequest& r) { r.mutable_in_plane()->set_theta_i_count(2); }, "in_plane.theta_o_count:"},
      {[&](v1::TabulateRequest& r) { plane(r); r.mutable_in_plane()->set_phi_plane_deg(INFINITY); }, "in_plane.phi_plane_deg:"},
      {[](v1::TabulateRequest& r) {
         r.mutable_in_plane()->set_theta_i_count(1 << 13);
         r.mutable_in_plane()->set_theta_o_count(1 << 13);
       }, "in_plane:"},
      {aniso(2, 0, 2, 2), "anisotropic.phi_i_count:"},
      {aniso(128, 128, 128, 32), "anisotropic:"},  // 2^26 cells
      {aniso(65535, 65535, 65535, 65535), "anisotropic:"},  // would overflow 64 bits
      {[](v1::TabulateRequest& r) { r.mutable_merl()->set_phi_h_samples(24); }, "merl.phi_h_samples:"},
      {[](v1::TabulateRequest& r) { r.mutable_merl()->set_phi_h_samples(5000); }, "merl.phi_h_samples:"},
      {[&](v1::TabulateRequest& r) { plane(r); r.set_format(v1::TABLE_FORMAT_MERL); }, "format:"},
      {[](v1::TabulateRequest& r) { r.mutable_merl(); r.set_format(v1::TABLE_FORMAT_CSV); }, "format:"},
      {[&](v1::TabulateRequest& r) { aniso(64, 64, 64, 32)(r); r.set_format(v1::TABLE_FORMAT_EXR); }, "format:"},
      {[&](v1::TabulateRequest& r) { plane(r); r.set_format(static_cast<v1::TableFormat>(9)); }, "format:"},
      {[&](v1::TabulateRequest& r) { plane(r); r.set_precision(static_cast<v1::Precision>(7)); }, "precision:"},
      {[&](v1::TabulateRequest& r) { plane(r); r.mutable_material()->set_preset("burlap"); }, "material.preset"},
  };
  // The earlier tests' tabulations may still be finishing on the server after their clients saw the deadline or
  // the cancel (jobs in flight complete, and a job done before the call notices its stop is counted): the count is
  // taken once no long call holds a slot, i.e. every earlier call object is gone.
  for (int i = 0; i < 6000 && server_->long_calls_in_use() > 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_EQ(server_->long_calls_in_use(), 0u) << "earlier tabulations never ended";
  const uint64_t before = server_->metrics().tabulated_cells();
  for (size_t i = 0; i < cases.size(); ++i) {
    v1::TabulateRequest r = Request(material, v1::TABLE_FORMAT_RAW);
    cases[i].mutate(r);
    const Table t = Tabulate(*stub_, r);
    EXPECT_EQ(t.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << "case " << i << ": " << t.status.error_message();
    EXPECT_EQ(t.status.error_message().rfind(cases[i].field, 0), 0u)
        << "case " << i << ": '" << t.status.error_message() << "' should start with " << cases[i].field;
    EXPECT_TRUE(t.chunks.empty()) << "case " << i;
  }
  EXPECT_EQ(server_->metrics().tabulated_cells(), before);
}

// A server shut down with tabulations streaming neither crashes nor hangs (a short grace: they are cancelled).
TEST(TabulateShutdown, ServerShutsDownWithTabulationsInFlight) {
  api::ServerOptions options;
  options.address = "127.0.0.1:0";
  options.shutdown_grace = std::chrono::milliseconds(200);
  std::string error;
  auto server = api::LoomlightServer::Start(options, &error);
  ASSERT_NE(server, nullptr) << error;
  auto stub = testing::Connect(server->port());
  grpc::ClientContext ctx;
  v1::ListModelsResponse models;
  ASSERT_TRUE(stub->ListModels(&ctx, v1::ListModelsRequest(), &models).ok());
  std::vector<std::thread> clients;
  std::atomic<int> started{0};
  for (int c = 0; c < 2; ++c)
    clients.emplace_back([&, c] {
      v1::TabulateRequest r = Request(MaterialOf(models.models(c % models.models_size())), v1::TABLE_FORMAT_MERL);
      r.mutable_merl()->set_phi_h_samples(16);
      Tabulate(*stub, r, std::chrono::seconds(60), [&](grpc::ClientContext&, const v1::TabulateChunk&) {
        ++started;
        return false;
      });
    });
  while (started < 2) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  server.reset();
  for (auto& t : clients) t.join();
}

// ---- The client: `loomlight tab` and the plot views ----

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

TEST_F(TabulateTest, ClientTabWritesEachFormat) {
  const std::string material = "--model " + models_.models(0).name();
  const std::string dir = ::testing::TempDir();
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->port(), "tab " + material + " --grid 4d --dims 3,4,5,6 --out " + dir + "/t.raw", &out), 0) << out;
  EXPECT_NE(out.find("360 cells"), std::string::npos) << out;  // a plain final line when stderr is no terminal
  const std::string raw = ReadFile(dir + "/t.raw");
  ASSERT_EQ(raw.size(), 40u + 12 * 360);
  EXPECT_EQ(raw.substr(0, 4), "LLTB");
  ASSERT_EQ(testing::RunClient(server_->port(), "tab " + material + " --grid inplane --incidence 0,45 --theta-o-count 9 --out " + dir + "/t.csv", &out), 0) << out;
  const std::string csv = ReadFile(dir + "/t.csv");
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 19);  // a header and 2 x 9 cells
  ASSERT_EQ(testing::RunClient(server_->port(), "tab " + material + " --grid merl --phi-h-samples 1 --out " + dir + "/t.binary", &out), 0) << out;
  EXPECT_EQ(ReadFile(dir + "/t.binary").size(), 12u + 24 * 90 * 90 * 180);
  ASSERT_EQ(testing::RunClient(server_->port(), "tab " + material + " --grid 4d --dims 2,2,2,2 --out " + dir + "/t.exr", &out), 0) << out;
  auto in = OIIO::ImageInput::open(dir + "/t.exr");
  ASSERT_TRUE(in) << OIIO::geterror();
  EXPECT_EQ(in->spec().width, 4);
  // Errors come back named, with exit status 1.
  EXPECT_EQ(testing::RunClient(server_->port(), "tab " + material + " --grid 4d --dims 128,128,128,32 --out " + dir + "/big.raw", &out), 1);
  EXPECT_NE(out.find("INVALID_ARGUMENT: anisotropic"), std::string::npos) << out;
}

// Decodes a PNG; returns its size and the share of pixels that are not the white background.
struct Png {
  int width = 0, height = 0;
  double drawn = 0;
};
Png ReadPng(const std::string& path) {
  Png png;
  auto in = OIIO::ImageInput::open(path);
  EXPECT_TRUE(in) << path << ": " << OIIO::geterror();
  if (!in) return png;
  const OIIO::ImageSpec& spec = in->spec();
  png.width = spec.width;
  png.height = spec.height;
  std::vector<unsigned char> pixels(size_t(spec.width) * spec.height * spec.nchannels);
  EXPECT_TRUE(in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::UINT8, pixels.data()));
  size_t drawn = 0;
  for (size_t p = 0; p < pixels.size(); p += spec.nchannels)
    if (pixels[p] < 240 || pixels[p + 1] < 240 || pixels[p + 2] < 240) ++drawn;
  png.drawn = double(drawn) / (double(spec.width) * spec.height);
  return png;
}

TEST_F(TabulateTest, PlotViewsWritePngsOfTheRequestedSize) {
  for (const v1::ModelInfo& model : models_.models()) {
    SCOPED_TRACE(model.name());
    const std::string material =
        model.presets_size() > 0 ? "--preset " + model.presets(0).name() : "--model " + model.name();
    for (const char* view : {"polar", "thd", "albedo", "sphere"}) {
      const std::string path = ::testing::TempDir() + "/view_" + model.name() + "_" + view + ".png";
      std::remove(path.c_str());
      std::string out;
      ASSERT_EQ(testing::RunClient(server_->port(), std::string("plot ") + material + " --view " + view + " --size 320 --out " + path, &out), 0)
          << view << ": " << out;
      const Png png = ReadPng(path);
      EXPECT_EQ(png.width, 320) << view;
      EXPECT_GT(png.height, 150) << view;
      EXPECT_GT(png.drawn, 0.01) << view;
    }
  }
}

// ---- The grid and the means without a server (server/models/tabulation/, server/models/query_means.h) ----

// The server tests ask MERL tables for one phi_h sample (phi_h = 0); here a cell of four: query s at phi_h =
// s 90 degrees, each the half/diff directions written above.
TEST(TabulationGrid, MerlQueriesOfACellTurnAboutTheNormalAtEvenPhiH) {
  const uint32_t samples = 4;
  const tabulation::Grid grid = tabulation::Grid::Merl(samples);
  ASSERT_EQ(grid.cells(), uint64_t{90 * 90 * 180});
  ASSERT_EQ(grid.queries(), grid.cells() * samples);
  for (const auto& [i, j, k] : {std::array<int, 3>{0, 0, 0}, {37, 12, 101}, {89, 89, 179}}) {
    const uint64_t cell = (uint64_t(i) * 90 + j) * 180 + k;
    std::vector<float> wi(3 * samples), wo(3 * samples);
    grid.FillDirections(cell * samples, samples, wi.data(), wo.data());
    const double x = (i + 0.5) / 90.0;
    EXPECT_EQ(grid.CellAngles(cell), (std::vector<double>{x * x * 90.0, j + 0.5, k + 0.5}));
    for (uint32_t s = 0; s < samples; ++s) {
      const auto [expected_wi, expected_wo] = HalfDiff(x * x * 90.0, s * 90.0, j + 0.5, k + 0.5);
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(wi[3 * s + c], expected_wi[c], 1e-6) << i << " " << j << " " << k << " sample " << s;
        EXPECT_NEAR(wo[3 * s + c], expected_wo[c], 1e-6) << i << " " << j << " " << k << " sample " << s;
      }
    }
  }
}

// The CSV of a 4D table names each cell by its bin centres, theta_i slowest and phi_o fastest (the server's CSV
// test is in-plane).
TEST(TabulationGrid, AnisotropicCellsAreBinCentresThetaISlowestPhiOFastest) {
  const tabulation::Grid grid = tabulation::Grid::Anisotropic(2, 3, 4, 5);
  EXPECT_EQ(grid.cells(), 120u);
  EXPECT_EQ(grid.row_cells(), 20u);
  EXPECT_EQ(grid.angle_names(), (std::vector<std::string>{"theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"}));
  uint64_t cell = 0;
  for (uint32_t a = 0; a < 2; ++a)
    for (uint32_t b = 0; b < 3; ++b)
      for (uint32_t c = 0; c < 4; ++c)
        for (uint32_t d = 0; d < 5; ++d, ++cell)
          EXPECT_EQ(grid.CellAngles(cell),
                    (std::vector<double>{Centre(a, 2, 90), Centre(b, 3, 360), Centre(c, 4, 90), Centre(d, 5, 360)}))
              << cell;
}

// A cell's value is the mean of its queries (MERL's phi_h samples), written where the cell's mean belongs; a
// non-finite mean names its group.
TEST(QueryMeans, EachGroupsMeanLandsInPlaceAndTheFirstNonFiniteGroupIsNamed) {
  std::vector<double> f(3 * 12);
  for (size_t q = 0; q < 12; ++q)
    for (int c = 0; c < 3; ++c) f[3 * q + c] = 10.0 * q + c;
  EXPECT_EQ(models::GroupMeansInPlace(f.data(), 3, 4), 3u);
  for (size_t g = 0; g < 3; ++g)
    for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(f[3 * g + c], 10.0 * (4 * g + 1.5) + c) << g << " " << c;
  std::vector<double> bad(3 * 12, 1.0);
  bad[3 * 9 + 2] = HUGE_VAL;  // group 2
  bad[3 * 5 + 1] = std::nan("");  // group 1
  EXPECT_EQ(models::GroupMeansInPlace(bad.data(), 3, 4), 1u);
}

}  // namespace
}  // namespace loomlight
