// The YarnGeometry RPC and `loomlight yarn` end to end: the presets ListModels lists against SPEC.md's table,
// streamed curves against their summary, determinism, bad requests naming their field, limits, deadlines
// (with Evaluate still served meanwhile) and the pbrt-v4 file the client writes.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <functional>
#include <map>
#include <numbers>
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
// ---- Yarn curves and knits (docs/fibers.md "Yarn curves", "Knits") ----

v1::YarnCentreCurve* AddCurve(v1::CurveYarnLayout* layout, std::initializer_list<double> points, bool bspline = false) {
  v1::YarnCentreCurve* c = layout->add_yarns();
  c->mutable_points()->Add(points.begin(), points.end());
  c->set_bspline(bspline);
  return c;
}

void ExpectSameCurves(const v1::FiberCurves& a, const v1::FiberCurves& b) {
  ASSERT_GT(a.point_counts_size(), 0);
  EXPECT_TRUE(std::equal(a.point_counts().begin(), a.point_counts().end(), b.point_counts().begin(),
                         b.point_counts().end()));
  EXPECT_TRUE(std::equal(a.widths().begin(), a.widths().end(), b.widths().begin(), b.widths().end()));
  ASSERT_EQ(a.points_size(), b.points_size());
  // The curve's frames are the straight yarn's to rounding (1e-16 in double), here in float.
  int differ = 0;
  for (int i = 0; i < a.points_size(); ++i) differ += std::fabs(a.points(i) - b.points(i)) > 1e-6f;
  EXPECT_EQ(differ, 0) << "of " << a.points_size() << " coordinates";
}

// A curve from the origin to (0, 0, 1) is the straight yarn of length 1: with the same yarn and seed, the same
// fibers (to float rounding). Its radius scales the yarn: the same fibers as the preset with every length doubled by hand.
TEST_F(YarnRpcTest, AStraightCurveGivesTheStraightYarnsFibersAndItsRadiusScalesTheYarn) {
  auto stub = Stub();
  v1::YarnGeometryRequest curve;
  v1::YarnCentreCurve* c = AddCurve(curve.mutable_curves(), {0, 0, 0, 0, 0, 1});
  c->mutable_yarn()->set_preset("cotton1");
  c->mutable_yarn()->set_seed(5);
  curve.mutable_detail()->set_footprint(0.01);
  v1::YarnGeometryRequest straight = Straight("cotton1", 1);
  straight.mutable_yarn()->set_seed(5);
  straight.mutable_detail()->set_footprint(0.01);
  const Streamed along = Fetch(*stub, curve), line = Fetch(*stub, straight);
  ASSERT_TRUE(along.status.ok()) << along.status.error_message();
  ASSERT_TRUE(line.status.ok()) << line.status.error_message();
  ASSERT_EQ(along.summary.yarns_size(), 1);
  EXPECT_EQ(along.summary.yarns(0).length(), 1.0);
  EXPECT_EQ(along.summary.yarns(0).thread(), 0u);
  ExpectSameCurves(along.curves, line.curves);

  // cotton1 (SPEC.md section 6) at twice its radius: lengths doubled, densities per length halved.
  c->set_radius(2 * 0.0378);
  v1::YarnGeometryRequest doubled = straight;
  for (const auto& [name, value] : std::vector<std::pair<std::string, double>>{
           {"yarn_radius", 2 * .0378}, {"ellipse_n", 2 * .0200}, {"ellipse_b", 2 * .0257}, {"alpha", 2 * .366},
           {"alpha_yarn", 2 * .453}, {"fiber_width", 2 * 0.005235774377619163}, {"hair_density", 30.36 / 2},
           {"loop_density", 19.10 / 2}})
    SetParam(&doubled, name, value);
  const Streamed scaled = Fetch(*stub, curve), by_hand = Fetch(*stub, doubled);
  ASSERT_TRUE(scaled.status.ok()) << scaled.status.error_message();
  ASSERT_TRUE(by_hand.status.ok()) << by_hand.status.error_message();
  ExpectSameCurves(scaled.curves, by_hand.curves);
  EXPECT_NEAR(scaled.summary.bounds_max(0), 2 * line.summary.bounds_max(0), 0.2 * line.summary.bounds_max(0));
}

// Curves without a yarn of their own take the request's, each with its own seed: two parallel curves get
// different fibers, and each the same fibers at every call and wherever it is moved.
TEST_F(YarnRpcTest, CurvesOfTheRequestsYarnGetFibersOfTheirOwnAndKeepThemWhenMoved) {
  auto stub = Stub();
  v1::YarnGeometryRequest r;
  r.mutable_yarn()->set_preset("polyester1");
  r.mutable_detail()->set_footprint(0.01);
  AddCurve(r.mutable_curves(), {0, 0, 0, 0, 0, 1});
  AddCurve(r.mutable_curves(), {1, 0, 0, 1, 0, 1});
  const Streamed two = Fetch(*stub, r);
  ASSERT_TRUE(two.status.ok()) << two.status.error_message();
  ASSERT_EQ(two.summary.yarns_size(), 2);
  // Each yarn's fibers relative to its curve's start.
  std::vector<std::vector<float>> relative(2);
  size_t first = 0;
  for (int i = 0; i < two.curves.point_counts_size(); ++i) {
    const uint32_t yarn = two.curves.yarns(i);
    for (size_t k = 0; k < 3 * size_t(two.curves.point_counts(i)); ++k)
      relative[yarn].push_back(two.curves.points(int(3 * first + k)) - (k % 3 == 0 ? float(yarn) : 0.0f));
    first += two.curves.point_counts(i);
  }
  EXPECT_NE(relative[0], relative[1]);
  // The second curve alone at the first one's index is the first curve moved: the same fibers, moved.
  v1::YarnGeometryRequest moved = r;
  moved.mutable_curves()->mutable_yarns()->RemoveLast();
  for (int i = 0; i < 6; i += 3) moved.mutable_curves()->mutable_yarns(0)->set_points(i, 0.5);
  const Streamed one = Fetch(*stub, moved);
  ASSERT_TRUE(one.status.ok()) << one.status.error_message();
  std::vector<float> back;
  for (int i = 0; i < one.curves.points_size(); ++i) back.push_back(one.curves.points(i) - (i % 3 == 0 ? 0.5f : 0.0f));
  ASSERT_EQ(back.size(), relative[0].size());
  for (size_t i = 0; i < back.size(); ++i) ASSERT_NEAR(back[i], relative[0][i], 1e-6) << i;
}

TEST_F(YarnRpcTest, BadCurvesNameTheYarnAndItsField) {
  const double nan = std::nan("");
  struct Case {
    std::function<void(v1::CurveYarnLayout*)> edit;  // on a layout of one good curve
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](auto* l) { AddCurve(l, {0, 0, 0, 0, 0}); }, "curves.yarns[1].points"},
      {[&](auto* l) { AddCurve(l, {0, 0, 0, 0, nan, 1}); }, "curves.yarns[1].points"},
      {[](auto* l) { AddCurve(l, {0, 0, 0, 0, 0, 0.5, 0, 0, 0.5}); }, "curves.yarns[1].points"},  // repeated
      {[](auto* l) { AddCurve(l, {0, 0, 0}); }, "curves.yarns[1].points"},
      {[](auto* l) { AddCurve(l, {0, 0, 0, 0, 0, 1, 0, 0, 2}, true); }, "curves.yarns[1].points"},  // 3 B-spline points
      {[](auto* l) { AddCurve(l, {0, 0, 0, 0, 0, 1})->set_radius(-1); }, "curves.yarns[1].radius"},
      {[&](auto* l) { AddCurve(l, {0, 0, 0, 0, 0, 1})->set_radius(nan); }, "curves.yarns[1].radius"},
      {[](auto* l) { AddCurve(l, {0, 0, 0, 0, 0, 1})->mutable_yarn()->set_preset("no_such_yarn"); },
       "curves.yarns[1].yarn.preset"},
      {[](auto* l) {
         for (int k = 0; k < 4096; ++k) AddCurve(l, {0, 0, 0, 0, 0, 1});
       },
       "curves.yarns"},
      {[](auto* l) {
         v1::YarnCentreCurve* c = l->add_yarns();
         for (int k = 0; k < 1'000'001; ++k) c->add_points(0), c->add_points(0), c->add_points(k);
       },
       "curves.yarns"},
  };
  auto stub = Stub();
  for (const Case& c : cases) {
    v1::YarnGeometryRequest request;
    request.mutable_detail()->set_footprint(0.02);
    AddCurve(request.mutable_curves(), {0, 0, 0, 0, 0, 1});
    c.edit(request.mutable_curves());
    const Streamed s = Fetch(*stub, request);
    EXPECT_EQ(s.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field << ": " << s.status.error_message();
    EXPECT_EQ(s.status.error_message().rfind(c.field + (c.field == "curves.yarns" ? ":" : ""), 0), 0u)
        << s.status.error_message();
  }
  v1::YarnGeometryRequest none;
  none.mutable_curves();
  EXPECT_EQ(Fetch(*stub, none).status.error_message().rfind("curves.yarns: no yarn", 0), 0u);
}

// A jersey of 4 wales x 3 courses at wale spacing 0.4 and course spacing 0.3: one yarn per course, from x = 0 to
// 1.6; course j's legs about y = (j + 1/2) 0.3 and its loops 4/4.5 of a course spacing above and below them; the
// legs and heads a loop depth (1.34 yarn radii) to either side of the fabric plane (server/yarn/knit.h).
TEST_F(YarnRpcTest, KnitLaysOneYarnPerCourse) {
  v1::YarnGeometryRequest r;
  r.mutable_yarn()->set_preset("cotton1");
  v1::KnitYarnLayout& knit = *r.mutable_knit();
  knit.set_wales(4);
  knit.set_courses(3);
  knit.set_wale_spacing(0.4);
  knit.set_course_spacing(0.3);
  r.mutable_detail()->set_footprint(0.02);
  const Streamed s = Fetch(*Stub(), r);
  ASSERT_TRUE(s.status.ok()) << s.status.error_message();
  ASSERT_EQ(s.summary.yarns_size(), 3);
  for (int j = 0; j < 3; ++j) {
    EXPECT_FALSE(s.summary.yarns(j).warp());
    EXPECT_EQ(s.summary.yarns(j).thread(), uint32_t(j));
    EXPECT_GT(s.summary.yarns(j).length(), 2 * 1.6);  // each stitch a loop up and down
  }
  std::vector<int> per_yarn(3, 0);
  for (int i = 0; i < s.curves.point_counts_size(); ++i) {
    ASSERT_LT(s.curves.yarns(i), 3u);
    per_yarn[s.curves.yarns(i)]++;
  }
  for (int j = 0; j < 3; ++j) EXPECT_GE(per_yarn[j], 3) << j;
  const double radius = 0.0378, h = 0.3 * 4 / 4.5, d = 1.34 * radius;
  EXPECT_NEAR(s.summary.bounds_min(0), 0, 3 * radius);
  EXPECT_NEAR(s.summary.bounds_max(0), 1.6, 3 * radius);
  EXPECT_NEAR(s.summary.bounds_min(1), 0.15 - h, 3 * radius);
  EXPECT_NEAR(s.summary.bounds_max(1), 0.75 + h, 3 * radius);
  EXPECT_NEAR(s.summary.bounds_max(2), d, 3 * radius);
  EXPECT_NEAR(s.summary.bounds_min(2), -d, 3 * radius);

  // A rib of the same size: as many yarns.
  knit.set_stitch(v1::KNIT_RIB_1X1);
  const Streamed rib = Fetch(*Stub(), r);
  ASSERT_TRUE(rib.status.ok()) << rib.status.error_message();
  EXPECT_EQ(rib.summary.yarns_size(), 3);
}

TEST_F(YarnRpcTest, BadKnitsNameTheirField) {
  struct Case {
    std::function<void(v1::KnitYarnLayout*)> edit;
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](auto* k) { k->set_stitch(static_cast<v1::KnitStitch>(7)); }, "knit.stitch"},
      {[](auto* k) { k->set_wales(100000); }, "knit.wales"},
      {[](auto* k) { k->set_courses(513); }, "knit.courses"},
      {[](auto* k) { k->set_wale_spacing(-1); }, "knit.wale_spacing"},
      {[](auto* k) { k->set_wale_spacing(std::nan("")); }, "knit.wale_spacing"},
      {[](auto* k) { k->set_course_spacing(0.01); }, "knit.course_spacing"},  // loops would pass through
  };
  auto stub = Stub();
  for (const Case& c : cases) {
    v1::YarnGeometryRequest request;
    c.edit(request.mutable_knit());
    const Streamed s = Fetch(*stub, request);
    EXPECT_EQ(s.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field << ": " << s.status.error_message();
    EXPECT_EQ(s.status.error_message().rfind(c.field, 0), 0u) << s.status.error_message();
  }
}

// ---- The knit and curves scenes (Render) ----

struct RenderResult {
  grpc::Status status;
  v1::RenderUpdate last;
};

RenderResult RenderScene(v1::Loomlight::Stub& stub, const v1::RenderRequest& request) {
  RenderResult out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  auto reader = stub.Render(&ctx, request);
  v1::RenderUpdate update;
  while (reader->Read(&update))
    if (!update.image().empty()) out.last = update;
  out.status = reader->Finish();
  return out;
}

v1::RenderRequest FiberRender(const std::string& scene) {
  v1::RenderRequest r;
  r.mutable_material()->set_preset("cotton");
  r.set_scene_name(scene);
  r.set_width(48);
  r.set_height(32);
  r.set_samples_per_pixel(2);
  r.set_fiber_detail(v1::FIBER_DETAIL_LOD);
  r.set_format(v1::RENDER_FORMAT_EXR);
  return r;
}

// The share of the image's pixels that are not black (the fiber scenes' background without a sky), every
// value finite and >= 0.
double LitShare(const std::string& exr) {
  const testing::DecodedImage image = testing::DecodeImage(exr, "x.exr");
  EXPECT_EQ(image.width, 48);
  EXPECT_EQ(image.height, 32);
  size_t lit = 0, pixels = size_t(image.width) * size_t(image.height);
  for (size_t p = 0; p < pixels; ++p) {
    bool any = false;
    for (int c = 0; c < std::min(image.channels, 3); ++c) {
      const float v = image.pixels[p * size_t(image.channels) + size_t(c)];
      EXPECT_TRUE(std::isfinite(v) && v >= 0) << p;
      any = any || v > 0;
    }
    lit += any;
  }
  return pixels ? double(lit) / double(pixels) : 0;
}

// knit_patch frames the request's knit whole (a default 8 x 8 jersey, and a 3 x 12 rib of another shape), and
// yarn_curves the request's curves; the knit fills much of the frame and the curves some of it, and neither the
// whole frame (the camera sees past them).
TEST_F(YarnRpcTest, KnitAndCurveScenesFrameTheirFibers) {
  auto stub = Stub();
  const RenderResult jersey = RenderScene(*stub, FiberRender("knit_patch"));
  ASSERT_TRUE(jersey.status.ok()) << jersey.status.error_message();
  const double jersey_lit = LitShare(jersey.last.image());
  EXPECT_GT(jersey_lit, 0.2);
  EXPECT_LT(jersey_lit, 1.0);
  v1::RenderRequest rib = FiberRender("knit_patch");
  rib.mutable_knit()->set_stitch(v1::KNIT_RIB_1X1);
  rib.mutable_knit()->set_wales(3);
  rib.mutable_knit()->set_courses(12);
  const RenderResult tall = RenderScene(*stub, rib);
  ASSERT_TRUE(tall.status.ok()) << tall.status.error_message();
  EXPECT_GT(LitShare(tall.last.image()), 0.05);

  v1::RenderRequest curves = FiberRender("yarn_curves");
  // A loop of 8 polyline points about (10, 10, 0), 2 across, far from the scene's default framing.
  for (int k = 0; k < 8; ++k) {
    const double a = 2 * std::numbers::pi * k / 8;
    if (k == 0) curves.mutable_curves()->add_yarns();
    v1::YarnCentreCurve* c = curves.mutable_curves()->mutable_yarns(0);
    c->add_points(10 + std::cos(a)), c->add_points(10 + std::sin(a)), c->add_points(0.1 * k);
  }
  const RenderResult loop = RenderScene(*stub, curves);
  ASSERT_TRUE(loop.status.ok()) << loop.status.error_message();
  const double loop_lit = LitShare(loop.last.image());
  EXPECT_GT(loop_lit, 0.01);
  EXPECT_LT(loop_lit, 1.0);

  // A bad curve is refused naming it; the layouts only on their own scenes.
  curves.mutable_curves()->mutable_yarns(0)->set_points(4, std::nan(""));
  const RenderResult bad = RenderScene(*stub, curves);
  EXPECT_EQ(bad.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(bad.status.error_message().rfind("curves.yarns[0].points", 0), 0u) << bad.status.error_message();
  v1::RenderRequest knit_on_curves = FiberRender("yarn_curves");
  knit_on_curves.mutable_knit()->set_wales(2);
  const RenderResult refused = RenderScene(*stub, knit_on_curves);
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(refused.status.error_message().rfind("knit: only for", 0), 0u) << refused.status.error_message();
  v1::RenderRequest curves_on_patch = FiberRender("woven_patch");
  AddCurve(curves_on_patch.mutable_curves(), {0, 0, 0, 0, 0, 1});
  const RenderResult refused2 = RenderScene(*stub, curves_on_patch);
  EXPECT_EQ(refused2.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(refused2.status.error_message().rfind("curves: only for", 0), 0u) << refused2.status.error_message();
}

// `loomlight yarn --curves` reads the CSV (header, comments, interleaved yarns, per-yarn columns) into the same
// request as built here; `--knit` likewise.
TEST_F(YarnRpcTest, ClientSendsCurvesFromACsvAndKnits) {
  const std::string csv = ::testing::TempDir() + "/yarn_rpc_test_curves.csv";
  {
    std::ofstream out(csv);
    out << "yarn,x,y,z,preset,radius,bspline\n# a comment\n0,0,0,0\n1,1,0,0,silk1,0.05\n0,0,0,0.5\n"
           "1,1,0,0.5\n0,0,0,1\n1,1,0,1,,0.05\n";
  }
  const std::string path = ::testing::TempDir() + "/yarn_rpc_test_curves.pbrt";
  std::string output;
  ASSERT_EQ(testing::RunClient(server_->port(), "yarn --curves " + csv + " --seed 4 --footprint 0.02 --out " + path,
                               &output),
            0)
      << output;
  v1::YarnGeometryRequest request;
  request.mutable_yarn()->set_seed(4);
  request.mutable_detail()->set_footprint(0.02);
  AddCurve(request.mutable_curves(), {0, 0, 0, 0, 0, 0.5, 0, 0, 1});
  v1::YarnCentreCurve* silk = AddCurve(request.mutable_curves(), {1, 0, 0, 1, 0, 0.5, 1, 0, 1});
  silk->mutable_yarn()->set_preset("silk1");
  silk->set_radius(0.05);
  const Streamed s = Fetch(*Stub(), request);
  ASSERT_TRUE(s.status.ok()) << s.status.error_message();
  // The file's first line counts the fibers and points it holds.
  const auto counts_match = [&path](const v1::YarnGeometrySummary& summary) {
    std::ifstream in(path);
    std::string first;
    std::getline(in, first);
    EXPECT_NE(first.find(", " + std::to_string(summary.fibers()) + " fibers, " +
                         std::to_string(summary.control_points()) + " control points"),
              std::string::npos)
        << first << " against " << summary.fibers() << " fibers, " << summary.control_points() << " points";
  };
  counts_match(s.summary);

  // Bad CSV lines are refused naming the file and line.
  for (const auto& [bad, message] : std::vector<std::pair<std::string, std::string>>{
           {"0,0,0\n", ":1: expected yarn,x,y,z"},
           {"0,0,0,0\n2,0,0,1\n", "yarn 1 has no points"},
           {"0,0,0,0,silk1\n0,0,0,1,cotton1\n", ":2: preset differs"},
           {"0,0,0,0,,,2\n", ":1: bspline must be 1"},
           {"0,a,0,0\n", "a"}}) {
    {
      std::ofstream out(csv, std::ios::trunc);
      out << bad;
    }
    std::string refused;
    EXPECT_EQ(testing::RunClient(server_->port(), "yarn --curves " + csv + " --out " + path, &refused), 2) << bad;
    EXPECT_NE(refused.find(message), std::string::npos) << bad << ": " << refused;
  }

  ASSERT_EQ(testing::RunClient(server_->port(),
                               "yarn --knit rib --stitches 3,2 --footprint 0.02 --seed 2 --out " + path, &output),
            0)
      << output;
  v1::YarnGeometryRequest knit;
  knit.mutable_yarn()->set_seed(2);
  knit.mutable_detail()->set_footprint(0.02);
  knit.mutable_knit()->set_stitch(v1::KNIT_RIB_1X1);
  knit.mutable_knit()->set_wales(3);
  knit.mutable_knit()->set_courses(2);
  const Streamed k = Fetch(*Stub(), knit);
  ASSERT_TRUE(k.status.ok()) << k.status.error_message();
  counts_match(k.summary);
}
}  // namespace
}  // namespace loomlight
