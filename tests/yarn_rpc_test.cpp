// The YarnGeometry RPC and `loomlight yarn` end to end: the presets ListModels lists against SPEC.md's table,
// streamed curves against their summary, determinism, bad requests naming their field, limits, deadlines
// (with Evaluate still served meanwhile) and the pbrt-v4 file the client writes.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/api/yarn_rpc.h"
#include "server/yarn/geometry_stream.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

struct Streamed {
  grpc::Status status;
  v1::YarnGeometrySummary summary;
  std::vector<v1::YarnGeometryChunk> chunks;
  v1::FiberCurves curves;  // all chunks' curves, concatenated
};

Streamed Fetch(v1::Loomlight::Stub& stub, const v1::YarnGeometryRequest& request, double timeout_s = 60) {
  Streamed out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::microseconds(int64_t(timeout_s * 1e6)));
  auto reader = stub.YarnGeometry(&ctx, request);
  v1::YarnGeometryChunk chunk;
  while (reader->Read(&chunk)) {
    if (chunk.has_summary()) out.summary = chunk.summary();
    out.curves.MergeFrom(chunk.curves());
    out.chunks.push_back(chunk);
  }
  out.status = reader->Finish();
  return out;
}

v1::YarnGeometryRequest Straight(const std::string& preset, double length = 1) {
  v1::YarnGeometryRequest r;
  r.mutable_yarn()->set_preset(preset);
  r.mutable_straight()->set_length(length);
  return r;
}

void SetParam(v1::YarnGeometryRequest* r, const std::string& name, double value) {
  v1::Param* p = r->mutable_yarn()->add_params();
  p->set_name(name);
  p->add_values(value);
}

// The streamed batches (server/yarn/geometry_stream.h) on hand-made curves, where the server's stream is too
// big to show the rules: every curve once, in order, across a yarn with no fibers; whole curves up to the
// byte bound; a curve over the bound alone in its batch; the summary's box holds every point widened by half
// its curve's width.
TEST(CurveBatcher, BatchesWholeCurvesInOrderWithinTheBoundAndALongCurveAlone) {
  const auto curve = [](int fiber, size_t points, double width) {
    yarn::FiberCurve c;
    c.fiber = fiber;
    c.ply = fiber % 2;
    c.width = width;
    c.type = fiber < 0 ? yarn::FiberType::kCore : yarn::FiberType::kHair;
    for (size_t k = 0; k < points; ++k) c.points.push_back({double(fiber), double(k), -double(k)});
    return c;
  };
  std::vector<yarn::YarnGeometry> yarns(3);
  yarns[0].fibers = {curve(-1, 3, 0.5), curve(0, 3, 0.25)};  // 60 bytes each
  yarns[2].fibers = {curve(1, 10, 0.125), curve(2, 2, 1), curve(3, 2, 1)};  // 144, 48, 48
  const size_t bound = 130;
  yarn::CurveBatcher batcher(yarns);
  std::vector<std::vector<int32_t>> batches;
  std::vector<uint32_t> yarn_of;
  while (!batcher.done()) {
    yarn::CurveBatch batch;
    batcher.Next(bound, &batch);
    ASSERT_FALSE(batch.fibers.empty()) << "an empty batch before the end";
    size_t bytes = 0, points = 0;
    for (uint32_t n : batch.point_counts) bytes += 12 * n + 24, points += n;
    if (batch.fibers.size() > 1) {
      EXPECT_LE(bytes, bound);
    }
    EXPECT_EQ(batch.points.size(), 3 * points);
    EXPECT_EQ(batch.widths.size(), batch.fibers.size());
    yarn_of.insert(yarn_of.end(), batch.yarns.begin(), batch.yarns.end());
    batches.push_back(batch.fibers);
    ASSERT_LE(batches.size(), 5u);
  }
  EXPECT_EQ(batches, (std::vector<std::vector<int32_t>>{{-1, 0}, {1}, {2, 3}}));
  EXPECT_EQ(yarn_of, (std::vector<uint32_t>{0, 0, 2, 2, 2}));
  EXPECT_EQ(batcher.curves_done(), 5u);

  const yarn::GeometrySummary summary = yarn::Summarise(yarns);
  EXPECT_EQ(summary.fibers, 5u);
  EXPECT_EQ(summary.bounds_min, (std::array<double, 3>{-1.25, -0.5, -9.0625}));
  EXPECT_EQ(summary.bounds_max, (std::array<double, 3>{3.5, 9.0625, 0.5}));
  EXPECT_EQ(yarn::Summarise({}).bounds_max, (std::array<double, 3>{0, 0, 0}));
}

// The fiber-scene cache: a job with the same fibers gets the scene built before (nothing admitted, the same
// objects); any field that changes the fibers misses; least recently used first out, by bytes.
TEST(FiberSceneCache, FindsTheSameFibersOnlyAndBoundsItsBytes) {
  const auto job = [](uint64_t seed, double footprint, double length) {
    api::YarnJob j;
    v1::Yarn yarn;
    yarn.set_preset("cotton1");
    yarn.set_seed(seed);
    EXPECT_EQ(api::YarnJobOf(models::Registry::Global(), yarn, nullptr, length, &j), "");
    j.detail.footprint = footprint;
    return j;
  };
  struct Built {
    grpc::Status status;
    size_t admitted = 0;
    std::shared_ptr<const yarn::FiberScene> fibers;
    std::shared_ptr<const yarn::YarnVisibility> visibility;
  };
  const auto build = [](api::YarnJob j, yarn::FiberSceneCache* cache, bool visibility) {
    Built b;
    b.status = api::BuildFiberScene(
        &j, [] { return grpc::Status::OK; }, [&b](size_t bytes) { return b.admitted += bytes, true; }, &b.fibers,
        visibility ? &b.visibility : nullptr, cache);
    return b;
  };
  yarn::FiberSceneCache cache(size_t{1} << 30);
  const Built first = build(job(1, 0, 0.2), &cache, true);
  ASSERT_TRUE(first.status.ok()) << first.status.error_message();
  EXPECT_GT(first.admitted, 0u);
  EXPECT_EQ(cache.entries(), 1u);
  const Built again = build(job(1, 0, 0.2), &cache, true);
  ASSERT_TRUE(again.status.ok());
  EXPECT_EQ(again.admitted, 0u);
  EXPECT_EQ(again.fibers, first.fibers);
  EXPECT_EQ(again.visibility, first.visibility);
  // Another seed, another level of detail, another length: other fibers.
  for (const api::YarnJob& other : {job(2, 0, 0.2), job(1, 0.01, 0.2), job(1, 0, 0.25)}) {
    const Built b = build(other, &cache, true);
    ASSERT_TRUE(b.status.ok());
    EXPECT_GT(b.admitted, 0u);
    EXPECT_NE(b.fibers, first.fibers);
  }
  EXPECT_EQ(cache.entries(), 4u);
  // Kept without its visibility (CreateBtf's way), then asked with it: built again, replacing the entry.
  EXPECT_GT(build(job(3, 0, 0.2), &cache, false).admitted, 0u);
  EXPECT_EQ(build(job(3, 0, 0.2), &cache, false).admitted, 0u);
  const Built with = build(job(3, 0, 0.2), &cache, true);
  EXPECT_GT(with.admitted, 0u);
  ASSERT_TRUE(with.visibility);
  EXPECT_EQ(cache.entries(), 5u);
  EXPECT_EQ(build(job(3, 0, 0.2), &cache, false).admitted, 0u);  // the entry with visibility serves both

  // Bounded: room for one scene keeps the last; a scene over the bound is not kept.
  const size_t one = cache.bytes() / cache.entries();
  yarn::FiberSceneCache small(one + one / 2);
  ASSERT_TRUE(build(job(1, 0, 0.2), &small, true).status.ok());
  ASSERT_TRUE(build(job(2, 0, 0.2), &small, true).status.ok());
  EXPECT_EQ(small.entries(), 1u);
  EXPECT_LE(small.bytes(), one + one / 2);
  EXPECT_EQ(build(job(2, 0, 0.2), &small, true).admitted, 0u);
  EXPECT_GT(build(job(1, 0, 0.2), &small, true).admitted, 0u);
  yarn::FiberSceneCache tiny(16);
  ASSERT_TRUE(build(job(1, 0, 0.2), &tiny, true).status.ok());
  EXPECT_EQ(tiny.entries(), 0u);
}

class YarnRpcTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    api::ServerOptions options;
    options.metrics_address = "127.0.0.1:0";  // tests wait for calls to end (testing::WaitForCallsEnded)
    server_ = testing::StartInProcessServer(options).release();
  }
  static void TearDownTestSuite() { delete server_; }
  static std::unique_ptr<v1::Loomlight::Stub> Stub() { return testing::Connect(server_->port()); }
  static api::LoomlightServer* server_;
};
api::LoomlightServer* YarnRpcTest::server_ = nullptr;

// SPEC.md section 6's table, typed in here: K, fibers per ply, yarn radius, ellipse long/short, alpha,
// alpha_yarn, eps, beta, s, rho_min, hair density, loop density.
TEST_F(YarnRpcTest, ListModelsListsTheFivePresetsOfTheSpec) {
  const std::map<std::string, std::vector<double>> spec = {
      {"cotton1", {3, 75, .0378, .0257, .0200, .366, .453, 0, .201, 1.0, .85, 30.36, 19.10}},
      {"cotton2", {3, 36, .0330, .0247, .0180, .435, .336, .0109, .417, 1.9, .95, 20.53, 15.39}},
      {"polyester1", {2, 60, .0287, .0285, .0211, .380, .370, .339, .423, 1.1, .70, 31.49, 34.11}},
      {"rayon2", {2, 79, .0287, .0283, .0209, .378, .372, .242, .389, 1.5, .80, 47.31, 36.51}},
      {"silk1", {3, 33, .0376, .0253, .0216, .460, .526, 0, .485, 0.1, .95, 24.87, 20.67}}};
  const char* names[] = {"plies", "fibers_per_ply", "yarn_radius", "ellipse_b", "ellipse_n", "alpha", "alpha_yarn",
                         "eps", "beta", "s", "rho_min", "hair_density", "loop_density"};
  grpc::ClientContext ctx;
  v1::ListModelsResponse models;
  ASSERT_TRUE(Stub()->ListModels(&ctx, v1::ListModelsRequest(), &models).ok());
  const v1::YarnModelInfo& yarn = models.yarn();
  ASSERT_EQ(yarn.presets_size(), 5);
  EXPECT_GT(yarn.max_fibers(), 0u);
  std::map<std::string, const v1::ParamSchema*> schema;
  for (const v1::ParamSchema& s : yarn.params()) schema[s.name()] = &s;
  for (const v1::Preset& preset : yarn.presets()) {
    SCOPED_TRACE(preset.name());
    ASSERT_TRUE(spec.count(preset.name()));
    std::map<std::string, double> values;
    for (const v1::Param& p : preset.params()) {
      ASSERT_EQ(p.values_size(), 1);
      values[p.name()] = p.values(0);
      ASSERT_TRUE(schema.count(p.name())) << p.name();
      EXPECT_GE(p.values(0), schema[p.name()]->min()) << p.name();
      EXPECT_LE(p.values(0), schema[p.name()]->max()) << p.name();
    }
    EXPECT_EQ(values.size(), schema.size());
    for (size_t k = 0; k < std::size(names); ++k) EXPECT_DOUBLE_EQ(values[names[k]], spec.at(preset.name())[k]) << names[k];
    EXPECT_EQ(values["rho_max"], 1.0);
  }
}

TEST_F(YarnRpcTest, StreamedCurvesMatchTheirSummary) {
  v1::YarnGeometryRequest request = Straight("cotton2", 15.0);
  request.mutable_detail()->set_core(false);  // every fiber explicit: more than one chunk
  const Streamed s = Fetch(*Stub(), request);
  ASSERT_TRUE(s.status.ok()) << s.status.error_message();
  ASSERT_GT(s.chunks.size(), 1u);
  EXPECT_TRUE(s.chunks.front().has_summary());
  for (size_t k = 1; k < s.chunks.size(); ++k) EXPECT_FALSE(s.chunks[k].has_summary());
  const v1::FiberCurves& c = s.curves;
  ASSERT_EQ(uint64_t(c.point_counts_size()), s.summary.fibers());
  EXPECT_EQ(s.chunks.back().fibers_sent(), s.summary.fibers());
  for (const auto& chunk : s.chunks)
    EXPECT_LE(chunk.curves().ByteSizeLong(), api::kYarnChunkBytes + 4096);  // whole curves up to ~1 MiB
  uint64_t points = 0;
  for (uint32_t n : c.point_counts()) {
    EXPECT_GE(n, 2u);
    points += n;
  }
  EXPECT_EQ(points, s.summary.control_points());
  ASSERT_EQ(uint64_t(c.points_size()), 3 * points);
  for (int k = 0; k < c.points_size(); ++k) {
    ASSERT_TRUE(std::isfinite(c.points(k)));
    // Inside the summary's bounds (as float), and along z within the yarn's length (widened by a fiber).
    EXPECT_GE(c.points(k), float(s.summary.bounds_min(k % 3)) - 1e-6f);
    EXPECT_LE(c.points(k), float(s.summary.bounds_max(k % 3)) + 1e-6f);
  }
  EXPECT_NEAR(s.summary.bounds_min(2), 0, 0.05);
  EXPECT_NEAR(s.summary.bounds_max(2), 15.0, 0.05);
  // cotton2: 3 plies of 36 fibers, no core: every regular fiber is there (as pieces), plus flyaways.
  std::map<std::pair<uint32_t, int>, int> fibers;
  int hairs = 0, loops = 0;
  for (int i = 0; i < c.point_counts_size(); ++i) {
    EXPECT_NE(c.types(i), v1::FIBER_CORE);
    EXPECT_GT(c.widths(i), 0);
    EXPECT_LT(c.plies(i), 3u);
    fibers[{c.plies(i), c.fibers(i)}]++;
    hairs += c.types(i) == v1::FIBER_HAIR;
    loops += c.types(i) == v1::FIBER_LOOP;
  }
  EXPECT_EQ(fibers.size(), 3u * 36u);
  // Expected flyaways: plies * density * (L - alpha) (yarn.h), each a Poisson-like count: within 5 sigma.
  const double expect_hair = 3 * 20.53 * (15.0 - 0.435), expect_loop = 3 * 15.39 * (15.0 - 0.435);
  EXPECT_NEAR(hairs, expect_hair, 5 * std::sqrt(expect_hair));
  EXPECT_NEAR(loops, expect_loop, 5 * std::sqrt(expect_loop));
}

TEST_F(YarnRpcTest, SameSeedSameBytesOtherSeedOtherCurves) {
  v1::YarnGeometryRequest request = Straight("silk1");
  request.mutable_yarn()->set_seed(7);
  const Streamed a = Fetch(*Stub(), request), b = Fetch(*Stub(), request);
  ASSERT_TRUE(a.status.ok() && b.status.ok());
  EXPECT_EQ(a.curves.SerializeAsString(), b.curves.SerializeAsString());
  request.mutable_yarn()->set_seed(8);
  const Streamed c = Fetch(*Stub(), request);
  ASSERT_TRUE(c.status.ok());
  EXPECT_NE(a.curves.SerializeAsString(), c.curves.SerializeAsString());
}

TEST_F(YarnRpcTest, LevelOfDetailThinsTheFibers) {
  v1::YarnGeometryRequest request = Straight("cotton1");
  const Streamed full = Fetch(*Stub(), request);
  request.mutable_detail()->set_footprint(0.01);
  const Streamed lod = Fetch(*Stub(), request);
  request.mutable_detail()->set_footprint(1.0);  // wider than a ply: cores alone
  const Streamed cores = Fetch(*Stub(), request);
  ASSERT_TRUE(full.status.ok() && lod.status.ok() && cores.status.ok());
  EXPECT_EQ(full.summary.lambda(), 1.0);
  EXPECT_GT(lod.summary.lambda(), 0.0);
  EXPECT_LT(lod.summary.lambda(), 1.0);
  EXPECT_LT(lod.summary.fibers(), full.summary.fibers());
  EXPECT_EQ(cores.summary.lambda(), 0.0);
  ASSERT_EQ(cores.summary.fibers(), 3u);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(cores.curves.types(i), v1::FIBER_CORE);
}

TEST_F(YarnRpcTest, BadRequestsNameTheirField) {
  struct Case {
    std::function<void(v1::YarnGeometryRequest*)> edit;
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](auto* r) { r->mutable_yarn()->set_preset("wool9"); }, "yarn.preset"},
      {[](auto* r) { SetParam(r, "twist", 1); }, "yarn.params"},
      {[](auto* r) { SetParam(r, "plies", 2.5); }, "yarn.plies"},
      {[](auto* r) { SetParam(r, "alpha", NAN); }, "yarn.alpha"},
      {[](auto* r) { SetParam(r, "eps", -0.1); }, "yarn.eps"},
      {[](auto* r) { SetParam(r, "beta", 1), SetParam(r, "beta", 2); }, "yarn.params[1]"},
      {[](auto* r) { SetParam(r, "rho_min", 0.9), SetParam(r, "rho_max", 0.5); }, "yarn.rho_min"},
      {[](auto* r) { r->mutable_yarn()->add_params()->set_name("s"); }, "yarn.params[0]"},
      {[](auto* r) { r->mutable_straight()->set_length(-1); }, "straight.length"},
      {[](auto* r) { r->mutable_straight()->set_length(INFINITY); }, "straight.length"},
      {[](auto* r) { r->mutable_detail()->set_core_radius(2); }, "detail.core_radius"},
      {[](auto* r) { r->mutable_detail()->set_points_per_twist(100000); }, "detail.points_per_twist"},
      {[](auto* r) { r->mutable_detail()->set_footprint(-1); }, "detail.footprint"},
      {[](auto* r) { r->set_max_fibers(api::kMaxYarnFibers + 1); }, "max_fibers"},
      {[](auto* r) { r->set_max_control_points(api::kMaxYarnControlPoints + 1); }, "max_control_points"},
      {[](auto* r) { r->set_max_fibers(10); }, "max_fibers"},          // 3 plies x 75 fibers
      {[](auto* r) { r->set_max_control_points(100); }, "max_control_points"},
  };
  auto stub = Stub();
  for (const Case& c : cases) {
    v1::YarnGeometryRequest request = Straight("cotton1");
    c.edit(&request);
    const Streamed s = Fetch(*stub, request);
    EXPECT_EQ(s.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field;
    EXPECT_EQ(s.status.error_message().rfind(c.field, 0), 0u) << s.status.error_message();
    EXPECT_TRUE(s.chunks.empty());
  }
}

// A yarn near the limits (150,000 fibers, 6.7 million points) under a 50 ms deadline: DEADLINE_EXCEEDED,
// while Evaluate calls made meanwhile are answered, and the server stays healthy.
TEST_F(YarnRpcTest, DeadlineStopsAHugeYarnAndEvaluateIsStillServed) {
  v1::YarnGeometryRequest request = Straight("cotton1");
  SetParam(&request, "plies", 10);
  SetParam(&request, "fibers_per_ply", 15000);
  request.mutable_detail()->set_core(false);
  std::thread evaluator([&] {
    auto stub = Stub();
    for (int k = 0; k < 20; ++k) {
      v1::EvaluateRequest e;
      e.mutable_material()->set_preset("linen_plain");
      for (float v : {0.f, 0.f, 1.f}) e.add_wi(v), e.add_wo(v);
      v1::EvaluateResponse r;
      grpc::ClientContext ctx;
      ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
      EXPECT_TRUE(stub->Evaluate(&ctx, e, &r).ok());
    }
  });
  const double ended = testing::CallsEnded(server_->metrics_port(), "YarnGeometry", "DEADLINE_EXCEEDED");
  for (int k = 0; k < 3; ++k) {
    const Streamed s = Fetch(*Stub(), request, 0.05);
    EXPECT_EQ(s.status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  evaluator.join();
  // The client sees its deadline before the server has stopped the generation and given back its memory (this
  // client's share): the next call waits for the server to end all three.
  ASSERT_TRUE(testing::WaitForCallsEnded(server_->metrics_port(), "YarnGeometry", "DEADLINE_EXCEEDED", ended + 3));
  const Streamed small = Fetch(*Stub(), Straight("rayon2", 0.5));
  EXPECT_TRUE(small.status.ok()) << small.status.error_message();
}

// `loomlight yarn` writes one pbrt-v4 cubic B-spline curve per fiber, its end points tripled.
TEST_F(YarnRpcTest, ClientWritesPbrtCurves) {
  const std::string path = ::testing::TempDir() + "/yarn_rpc_test.pbrt";
  std::string output;
  ASSERT_EQ(testing::RunClient(server_->port(), "yarn --yarn polyester1 --length 0.5 --seed 3 --out " + path, &output),
            0)
      << output;
  v1::YarnGeometryRequest request = Straight("polyester1", 0.5);
  request.mutable_yarn()->set_seed(3);
  const Streamed s = Fetch(*Stub(), request);
  ASSERT_TRUE(s.status.ok());
  std::ifstream in(path);
  std::string line;
  int shapes = 0;
  uint64_t points = 0;
  while (std::getline(in, line)) {
    if (line.rfind("Shape \"curve\"", 0) == 0) {
      ++shapes;
      EXPECT_NE(line.find("\"bspline\""), std::string::npos);
      EXPECT_NE(line.find("\"cylinder\""), std::string::npos);
    }
    const size_t p = line.find("\"point3 P\" [");
    if (p == std::string::npos) continue;
    std::istringstream values(line.substr(p + 12));
    std::vector<double> xyz;
    double v;
    while (values >> v) xyz.push_back(v);
    ASSERT_EQ(xyz.size() % 3, 0u);
    const size_t n = xyz.size() / 3;
    ASSERT_GE(n, 6u);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(xyz[k], xyz[3 + k]);
      EXPECT_EQ(xyz[3 * (n - 1) + k], xyz[3 * (n - 3) + k]);
    }
    points += n - 4;
  }
  EXPECT_EQ(uint64_t(shapes), s.summary.fibers());
  EXPECT_EQ(points, s.summary.control_points());
}

// A woven patch: cotton_twill (3/1, 4 x 4) at 2 x 1 repeats is 8 warp yarns along +y and 4 weft yarns along
// +x, every curve names one of them, and the fibers stay near the patch (the default spacing is 4.5 yarn
// radii, crimp heights one yarn radius).
TEST_F(YarnRpcTest, WovenLayoutLaysWarpAndWeft) {
  v1::YarnGeometryRequest request;
  request.mutable_yarn()->set_preset("cotton1");
  v1::WovenYarnLayout& woven = *request.mutable_woven();
  woven.mutable_weave()->set_preset("cotton_twill");
  woven.set_repeats_u(2);
  woven.set_repeats_v(1);
  request.mutable_detail()->set_footprint(0.02);  // level of detail keeps the patch small
  const Streamed s = Fetch(*Stub(), request);
  ASSERT_TRUE(s.status.ok()) << s.status.error_message();
  ASSERT_EQ(s.summary.yarns_size(), 12);
  const double radius = 0.0378, spacing = 4.5 * radius;
  int warps = 0;
  for (int k = 0; k < s.summary.yarns_size(); ++k) {
    const v1::LaidYarn& y = s.summary.yarns(k);
    warps += y.warp();
    EXPECT_EQ(y.thread(), uint32_t(y.warp() ? k % 4 : (k - 8) % 4));
    // Longer than the straight span it crosses (crimp), by less than half again.
    const double span = (y.warp() ? 4 : 8) * spacing;
    EXPECT_GT(y.length(), span);
    EXPECT_LT(y.length(), 1.5 * span);
  }
  EXPECT_EQ(warps, 8);
  std::vector<int> per_yarn(12, 0);
  for (int i = 0; i < s.curves.point_counts_size(); ++i) {
    ASSERT_LT(s.curves.yarns(i), 12u);
    per_yarn[s.curves.yarns(i)]++;
  }
  for (int k = 0; k < 12; ++k) EXPECT_GE(per_yarn[k], 2) << k;  // at least the cores of its plies
  EXPECT_GT(s.summary.bounds_min(0), -3 * radius);
  EXPECT_LT(s.summary.bounds_max(0), 8 * spacing + 3 * radius);
  EXPECT_LT(s.summary.bounds_max(1), 4 * spacing + 3 * radius);
  EXPECT_LT(s.summary.bounds_max(2), 5 * radius);
  EXPECT_GT(s.summary.bounds_min(2), -5 * radius);
}

TEST_F(YarnRpcTest, BadWovenLayoutsNameTheirField) {
  struct Case {
    std::function<void(v1::WovenYarnLayout*)> edit;
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](auto* w) { w->mutable_weave()->set_preset("silk_shot"); }, "woven.weave"},
      {[](auto* w) { w->mutable_weave()->set_preset("no_such_weave"); }, "woven.weave"},
      {[](auto* w) { w->set_crimp(1.5); }, "woven.crimp"},
      {[](auto* w) { w->set_yarn_spacing(0.01); }, "woven.yarn_spacing"},
      {[](auto* w) { w->set_yarn_spacing(-1); }, "woven.yarn_spacing"},
      {[](auto* w) { w->set_repeats_u(100000); }, "woven.repeats_u"},
  };
  auto stub = Stub();
  for (const Case& c : cases) {
    v1::YarnGeometryRequest request;
    request.mutable_woven()->mutable_weave()->set_preset("cotton_plain");
    c.edit(request.mutable_woven());
    const Streamed s = Fetch(*stub, request);
    EXPECT_EQ(s.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field;
    EXPECT_EQ(s.status.error_message().rfind(c.field, 0), 0u) << s.status.error_message();
  }
}
}  // namespace
}  // namespace loomlight
