// The gRPC API in process: ListModels, Evaluate against the reference, every bad-input case, and the
// batcher's behaviour (coalescing, full queue, deadlines) through real calls on a loopback port.
#include <arpa/inet.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <algorithm>
#include <functional>
#include <random>
#include <thread>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/job_status.h"
#include "server/api/server.h"
#include "server/models/material.h"
#include "server/models/quote.h"
#include "server/models/weave/wif.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using v1::EvaluateRequest;
using v1::EvaluateResponse;

std::unique_ptr<api::LoomlightServer> StartServer(batching::BatcherOptions batcher = {}) {
  api::ServerOptions options;
  options.batcher = batcher;
  return testing::StartInProcessServer(options);
}

EvaluateRequest Request(const std::string& preset, size_t n, unsigned seed) {
  EvaluateRequest r;
  r.mutable_material()->set_preset(preset);
  const accuracy::Pairs p = accuracy::RandomPairs(n, seed);
  r.mutable_wi()->Add(p.wi.begin(), p.wi.end());
  r.mutable_wo()->Add(p.wo.begin(), p.wo.end());
  return r;
}

grpc::Status Call(v1::Loomlight::Stub& stub, const EvaluateRequest& req, EvaluateResponse* resp,
                  double timeout_s = 60) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::microseconds(int64_t(timeout_s * 1e6)));
  return stub.Evaluate(&ctx, req, resp);
}

// A call that keeps the device busy for about a second (the most queries per call, the most tangent
// samples), so that calls made meanwhile queue.
EvaluateRequest BlockingRequest() {
  EvaluateRequest r = Request("velvet", api::kMaxQueriesPerCall, 1);
  auto* p = r.mutable_material()->add_params();
  p->set_name("tangent_samples");
  p->add_values(256);
  return r;
}

class ApiTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = StartServer().release(); }
  static void TearDownTestSuite() { delete server_; }
  static api::LoomlightServer* server_;
};
api::LoomlightServer* ApiTest::server_ = nullptr;

TEST_F(ApiTest, HealthIsServing) {
  auto health = grpc::health::v1::Health::NewStub(
      grpc::CreateChannel("127.0.0.1:" + std::to_string(server_->port()), grpc::InsecureChannelCredentials()));
  for (const char* service : {"", "loomlight.v1.Loomlight"}) {
    grpc::ClientContext ctx;
    grpc::health::v1::HealthCheckRequest req;
    req.set_service(service);
    grpc::health::v1::HealthCheckResponse resp;
    ASSERT_TRUE(health->Check(&ctx, req, &resp).ok());
    EXPECT_EQ(resp.status(), grpc::health::v1::HealthCheckResponse::SERVING);
  }
}

TEST_F(ApiTest, ListModelsDescribesSchemaAndPresets) {
  auto stub = testing::Connect(server_->port());
  grpc::ClientContext ctx;
  v1::ListModelsResponse resp;
  ASSERT_TRUE(stub->ListModels(&ctx, {}, &resp).ok());
  const auto& registered = models::Registry::Global().models();
  ASSERT_EQ(resp.models_size(), int(registered.size()));
  for (int i = 0; i < resp.models_size(); ++i) {
    EXPECT_EQ(resp.models(i).name(), registered[i]->name());
    EXPECT_EQ(resp.models(i).presets_size(), int(registered[i]->presets().size()));
    EXPECT_EQ(resp.models(i).spatially_varying(), resp.models(i).name() == "woven" || resp.models(i).name() == "btf")
        << resp.models(i).name();
  }
  const v1::ModelInfo& m = resp.models(0);
  EXPECT_EQ(m.name(), "microcylinder");
  EXPECT_EQ(m.presets_size(), 6);
  EXPECT_EQ(m.params_size(), 16);
  for (const auto& p : m.params()) {
    EXPECT_FALSE(p.description().empty()) << p.name();
    EXPECT_LE(p.min(), p.max()) << p.name();
    EXPECT_GE(p.default_values_size(), int(p.min_count())) << p.name();
  }
  for (const auto& preset : m.presets()) EXPECT_EQ(preset.params_size(), 16) << preset.name();
  EXPECT_EQ(resp.max_queries_per_call(), api::kMaxQueriesPerCall);
}

TEST_F(ApiTest, EvaluateMatchesReferenceInBothPrecisions) {
  auto stub = testing::Connect(server_->port());
  EvaluateRequest req = Request("silk_shot", 5000, 3);
  auto* p = req.mutable_material()->add_params();
  p->set_name("thread2.albedo");
  p->add_values(0.1);
  p->add_values(0.5);
  p->add_values(0.9);
  const models::Model& model = *models::Registry::Global().FindModel("microcylinder");
  models::ResolvedMaterial resolved;
  ASSERT_EQ(models::ResolveMaterial(req.material(), models::Registry::Global(), &resolved), "");
  std::vector<double> ref(3 * 5000);
  model.ReferenceEval(model.Pack(resolved.values), req.wi().data(), req.wo().data(), nullptr, 5000, ref.data());
  for (auto precision : {v1::PRECISION_FP32, v1::PRECISION_FP64}) {
    req.set_precision(precision);
    EvaluateResponse resp;
    ASSERT_TRUE(Call(*stub, req, &resp).ok());
    ASSERT_EQ(resp.f_size(), 3 * 5000);
    EXPECT_EQ(resp.model(), "microcylinder");
    EXPECT_EQ(resp.precision(), precision);
    EXPECT_GT(resp.kernel_seconds(), 0);
    std::vector<double> got(resp.f().begin(), resp.f().end());
    // FP64 answers are the double result rounded to float once.
    const auto e = accuracy::Compare(got, ref, 1e-4);
    EXPECT_LE(e.p99, precision == v1::PRECISION_FP64 ? 6e-8 : 1e-4) << e.ToString();
  }
}

// Every bad-input case: the status is INVALID_ARGUMENT and the message names the field.
struct BadCase {
  const char* name;
  std::function<void(EvaluateRequest&)> mutate;
  const char* field;
};

void AddParam(EvaluateRequest& r, const std::string& name, std::vector<double> values) {
  auto* p = r.mutable_material()->add_params();
  p->set_name(name);
  for (double v : values) p->add_values(v);
}

TEST_F(ApiTest, BadInputIsRejectedNamingTheField) {
  const float nan = std::nanf("");
  const std::vector<BadCase> cases = {
      {"no material", [](EvaluateRequest& r) { r.clear_material(); }, "material"},
      {"unknown preset", [](EvaluateRequest& r) { r.mutable_material()->set_preset("burlap"); }, "material.preset"},
      {"unknown model", [](EvaluateRequest& r) { r.mutable_material()->set_preset(""); r.mutable_material()->set_model("tweed"); }, "material.model"},
      {"preset of another model", [](EvaluateRequest& r) { r.mutable_material()->set_model("fiber"); }, "material.model"},
      {"unknown parameter", [](EvaluateRequest& r) { AddParam(r, "thread3.kd", {0.1}); }, "material.params[0].name"},
      {"parameter twice", [](EvaluateRequest& r) { AddParam(r, "eta", {1.3}); AddParam(r, "eta", {1.4}); }, "material.params[1].name"},
      {"wrong value count", [](EvaluateRequest& r) { AddParam(r, "thread1.albedo", {0.1, 0.2}); }, "material.params[0].values"},
      {"value out of range", [](EvaluateRequest& r) { AddParam(r, "eta", {0.5}); }, "material.params[0].values[0]"},
      {"non-finite value", [](EvaluateRequest& r) { AddParam(r, "thread1.kd", {std::nan("")}); }, "material.params[0].values[0]"},
      {"non-integer samples", [](EvaluateRequest& r) { AddParam(r, "tangent_samples", {12.5}); }, "material.params[0].values[0]"},
      {"too many samples", [](EvaluateRequest& r) { AddParam(r, "tangent_samples", {257}); }, "material.params[0].values[0]"},
      {"lengths do not fit offsets", [](EvaluateRequest& r) { AddParam(r, "thread1.tangent_offsets", {0, 10, 20}); }, "material.params: thread1.tangent_lengths"},
      {"zero total length", [](EvaluateRequest& r) { AddParam(r, "thread2.tangent_lengths", {0}); }, "material.params: thread2.tangent_lengths"},
      {"wi and wo lengths differ", [](EvaluateRequest& r) { r.mutable_wo()->RemoveLast(); r.mutable_wo()->RemoveLast(); r.mutable_wo()->RemoveLast(); }, "wo"},
      {"not a multiple of 3", [](EvaluateRequest& r) { r.mutable_wi()->RemoveLast(); r.mutable_wo()->RemoveLast(); }, "wi"},
      {"non-finite direction", [nan](EvaluateRequest& r) { r.mutable_wo()->Set(4, nan); }, "wo[1]"},
      {"infinite direction", [](EvaluateRequest& r) { r.mutable_wi()->Set(7, INFINITY); }, "wi[2]"},
      {"non-unit direction", [](EvaluateRequest& r) { r.mutable_wi()->Set(3, 0.5f); }, "wi[1]"},
      {"zero direction", [](EvaluateRequest& r) { for (int i = 0; i < 3; ++i) r.mutable_wo()->Set(i, 0.0f); }, "wo[0]"},
      {"uv on a uniform model", [](EvaluateRequest& r) { r.add_uv(0.5f); r.add_uv(0.5f); }, "uv"},
      {"unknown precision", [](EvaluateRequest& r) { r.set_precision(static_cast<v1::Precision>(7)); }, "precision"},
      {"negative error target", [](EvaluateRequest& r) { r.set_error_target(-0.01); }, "error_target"},
      {"NaN error target", [](EvaluateRequest& r) { r.set_error_target(std::nan("")); }, "error_target"},
  };
  auto stub = testing::Connect(server_->port());
  for (const BadCase& c : cases) {
    EvaluateRequest req = Request("linen_plain", 4, 1);
    c.mutate(req);
    EvaluateResponse resp;
    const grpc::Status s = Call(*stub, req, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name << ": " << s.error_message();
    // The message starts with the request field (cross-parameter checks add the parameter's name).
    const std::string field = c.field;
    const std::string root = field.substr(0, field.find_first_of(".["));
    EXPECT_EQ(s.error_message().rfind(root, 0), 0u) << c.name << ": " << s.error_message();
    EXPECT_NE(s.error_message().find(field), std::string::npos) << c.name << ": '" << s.error_message()
                                                                 << "' should name '" << field << "'";
  }
}

TEST_F(ApiTest, WovenPatternsAreValidatedAndEvaluated) {
  auto stub = testing::Connect(server_->port());
  auto woven = [](int warps, std::vector<double> cells) {
    EvaluateRequest r = Request("cotton_twill", 50, 9);
    AddParam(r, "pattern.warps", {double(warps)});
    AddParam(r, "pattern.cells", std::move(cells));
    return r;
  };
  EvaluateResponse resp;
  grpc::Status s = Call(*stub, woven(4, {1, 0, 1, 0, 1}), &resp);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("pattern.cells"), std::string::npos) << s.error_message();
  s = Call(*stub, woven(2, {1, 0.5, 0, 1}), &resp);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("0 or 1"), std::string::npos) << s.error_message();
  // A plain weave has half warp, half weft: its BRDF lies between the all-warp and all-weft cloths.
  std::vector<std::vector<float>> f;
  for (const auto& cells : std::vector<std::vector<double>>{{1, 0, 0, 1}, {1, 1, 1, 1}, {0, 0, 0, 0}}) {
    ASSERT_TRUE(Call(*stub, woven(2, cells), &resp).ok());
    f.emplace_back(resp.f().begin(), resp.f().end());
  }
  for (size_t i = 0; i < f[0].size(); ++i) {
    ASSERT_TRUE(std::isfinite(f[0][i]));
    EXPECT_NEAR(f[0][i], 0.5 * (f[1][i] + f[2][i]), 1e-5 * (f[1][i] + f[2][i]) + 1e-6) << i;
  }
}

// A plain weave written by hand as a WIF draft: two shafts threaded straight, tie-up 1-1 and 2-2, treadled
// 1, 2, so warp 1 rises on pick 1 and warp 2 on pick 2.
constexpr char kPlainWif[] =
    "[WIF]\nVersion=1.1\nSource Program=hand\n[CONTENTS]\nWEAVING=yes\nWARP=yes\nWEFT=yes\nTHREADING=yes\n"
    "TIEUP=yes\nTREADLING=yes\n[WEAVING]\nShafts=2\nTreadles=2\nRising Shed=yes\n[WARP]\nThreads=2\n[WEFT]\n"
    "Threads=2\n[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n";

void AddText(EvaluateRequest& r, const std::string& name, const std::string& text) {
  auto* p = r.mutable_material()->add_params();
  p->set_name(name);
  p->set_text(text);
}

TEST_F(ApiTest, WifDraftsSetTheWovenPattern) {
  auto stub = testing::Connect(server_->port());
  EvaluateRequest by_cells = Request("cotton_twill", 200, 21);
  AddParam(by_cells, "pattern.warps", {2});
  AddParam(by_cells, "pattern.cells", {1, 0, 0, 1});
  EvaluateRequest by_wif = Request("cotton_twill", 200, 21);
  AddText(by_wif, "pattern.wif", kPlainWif);
  for (auto* r : {&by_cells, &by_wif}) {  // the BTF depends on the cells themselves, not only their fractions
    for (int q = 0; q < 200; ++q) {
      r->add_uv(0.37f * q);
      r->add_uv(0.11f * q - 3);
    }
  }
  EvaluateResponse a, b;
  ASSERT_TRUE(Call(*stub, by_cells, &a).ok());
  const grpc::Status s = Call(*stub, by_wif, &b);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(a.f_size(), b.f_size());
  for (int i = 0; i < a.f_size(); ++i) ASSERT_EQ(a.f(i), b.f(i)) << i;

  struct BadText {
    const char* name;
    std::function<void(EvaluateRequest&)> mutate;
    std::string expected;  // substring of the message
  };
  std::string bad_shaft = kPlainWif;
  bad_shaft.replace(bad_shaft.find("[THREADING]\n1=1"), 15, "[THREADING]\n1=9");
  const int bad_line = 1 + int(std::count(bad_shaft.begin(), bad_shaft.begin() + bad_shaft.find("1=9"), '\n'));
  const std::vector<BadText> cases = {
      {"malformed WIF", [&](EvaluateRequest& r) { AddText(r, "pattern.wif", bad_shaft); },
       "material.params[0].text: WIF line " + std::to_string(bad_line) + ":"},
      {"not a WIF", [](EvaluateRequest& r) { AddText(r, "pattern.wif", "hello"); }, "material.params[0].text: WIF line"},
      {"empty text", [](EvaluateRequest& r) { AddText(r, "pattern.wif", ""); }, "material.params[0].text"},
      {"values for text", [](EvaluateRequest& r) { AddParam(r, "pattern.wif", {1}); }, "material.params[0].values"},
      {"text for values", [](EvaluateRequest& r) { AddText(r, "eta", "1.5"); }, "material.params[0].text"},
      {"both WIF and cells", [](EvaluateRequest& r) { AddParam(r, "pattern.cells", {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 0, 0, 1}); AddText(r, "pattern.wif", kPlainWif); },
       "material.params[1].name"},
  };
  for (const BadText& c : cases) {
    EvaluateRequest req = Request("cotton_twill", 4, 1);
    c.mutate(req);
    EvaluateResponse resp;
    const grpc::Status st = Call(*stub, req, &resp);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name;
    EXPECT_NE(st.error_message().find(c.expected), std::string::npos)
        << c.name << ": '" << st.error_message() << "' should contain '" << c.expected << "'";
  }
}

// A WIF draft's parse holds up to its size + 1 MiB (models::weave::WifParseBytes): charged to the memory
// budget while it runs (issue 44), so many large drafts at once are refused RESOURCE_EXHAUSTED instead of held.
// Here the budget (1.5 MiB) holds a small draft's parse (1 MiB and its size) and not a 600 KiB draft's.
TEST(MemoryBudget, WifParsesAreChargedWhileTheyRun) {
  api::ServerOptions options;
  options.limits.memory_budget_bytes = size_t{3} << 19;
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  const std::string large = std::string(kPlainWif) + ";" + std::string(size_t{600} << 10, 'x') + "\n";
  ASSERT_GT(models::weave::WifParseBytes(large.size()), options.limits.memory_budget_bytes);

  EvaluateRequest small_draft = Request("cotton_twill", 4, 1);
  AddText(small_draft, "pattern.wif", kPlainWif);
  EvaluateResponse resp;
  const grpc::Status ok = Call(*stub, small_draft, &resp);
  EXPECT_TRUE(ok.ok()) << ok.error_message();

  EvaluateRequest large_draft = Request("cotton_twill", 4, 1);
  AddText(large_draft, "pattern.wif", large);
  const grpc::Status refused = Call(*stub, large_draft, &resp);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << refused.error_message();
  EXPECT_NE(refused.error_message().find("memory budget"), std::string::npos) << refused.error_message();

  // Render checks its material on the gRPC thread, before its own admission: charged there too.
  v1::RenderRequest render;
  *render.mutable_material() = large_draft.material();
  render.set_scene(v1::SCENE_SPHERE);
  render.set_width(8);
  render.set_height(8);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto reader = stub->Render(&ctx, render);
  v1::RenderUpdate chunk;
  while (reader->Read(&chunk)) {
  }
  const grpc::Status rendered = reader->Finish();
  EXPECT_EQ(rendered.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << rendered.error_message();
  EXPECT_NE(rendered.error_message().find("memory budget"), std::string::npos) << rendered.error_message();
  // Each refused or finished parse gave its bytes back: a small draft's parse (over 1 MiB) still fits after them.
  for (int i = 0; i < 3; ++i) EXPECT_EQ(Call(*stub, large_draft, &resp).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  const grpc::Status again = Call(*stub, small_draft, &resp);
  EXPECT_TRUE(again.ok()) << again.error_message();
}

// Evaluate with uv runs the woven BTF kernel: equal to the double reference (fp64 to float rounding; fp32
// except where float rounding moves a sample across a highlight's edge, where the BTF jumps), and uv is
// validated like the directions.
TEST_F(ApiTest, WovenBtfWithUvMatchesReference) {
  auto stub = testing::Connect(server_->port());
  const int n = 20000;
  EvaluateRequest req = Request("cotton_satin", n, 5);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> U(-3, 3);
  for (int q = 0; q < 2 * n; ++q) req.add_uv(U(rng));
  const models::Model& model = *models::Registry::Global().FindModel("woven");
  models::ResolvedMaterial resolved;
  ASSERT_EQ(models::ResolveMaterial(req.material(), models::Registry::Global(), &resolved), "");
  std::vector<double> ref(3 * n);
  model.ReferenceEval(model.Pack(resolved.values), req.wi().data(), req.wo().data(), req.uv().data(), n, ref.data());
  for (auto precision : {v1::PRECISION_FP32, v1::PRECISION_FP64}) {
    req.set_precision(precision);
    EvaluateResponse resp;
    const grpc::Status s = Call(*stub, req, &resp);
    ASSERT_TRUE(s.ok()) << s.error_message();
    ASSERT_EQ(resp.f_size(), 3 * n);
    int off = 0;
    for (int i = 0; i < 3 * n; ++i) {
      ASSERT_TRUE(std::isfinite(resp.f(i)) && resp.f(i) >= 0) << i;
      const double tol = precision == v1::PRECISION_FP64 ? 6e-8 : 1e-5;
      off += std::fabs(resp.f(i) - ref[i]) > tol * std::max(ref[i], 1e-3);
    }
    // fp32: edge flips only, a few per 10^4 samples (the satin's long highlight edges); fp64: none.
    EXPECT_LE(off, precision == v1::PRECISION_FP64 ? 0 : 3 * n / 1000) << v1::Precision_Name(precision);
  }
  struct BadUv {
    const char* name;
    std::function<void(EvaluateRequest&)> mutate;
    const char* field;
  };
  const std::vector<BadUv> cases = {
      {"odd count", [](EvaluateRequest& r) { r.mutable_uv()->RemoveLast(); }, "uv: length"},
      {"NaN", [](EvaluateRequest& r) { r.mutable_uv()->Set(5, std::nanf("")); }, "uv[5]"},
      {"too far", [](EvaluateRequest& r) { r.mutable_uv()->Set(2, 1e6f); }, "uv[2]"},
  };
  for (const auto& c : cases) {
    EvaluateRequest bad = Request("cotton_twill", 4, 1);
    for (int q = 0; q < 8; ++q) bad.add_uv(0.25f);
    c.mutate(bad);
    EvaluateResponse resp;
    const grpc::Status st = Call(*stub, bad, &resp);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name;
    EXPECT_EQ(st.error_message().rfind(c.field, 0), 0u) << c.name << ": " << st.error_message();
  }
}

// Unit directions on a theta x phi midpoint grid of one hemisphere (z >= 0, or z <= 0 when below), each
// with its solid angle: sum of f cos weights is the directional albedo's quadrature.
struct HemisphereGrid {
  std::vector<float> w;
  std::vector<double> weight;  // solid angle x |cos|
};
HemisphereGrid Hemisphere(int n_theta, int n_phi, bool below) {
  HemisphereGrid g;
  const double dt = M_PI / 2 / n_theta, dp = 2 * M_PI / n_phi;
  for (int i = 0; i < n_theta; ++i)
    for (int j = 0; j < n_phi; ++j) {
      const double t = (i + 0.5) * dt, p = (j + 0.5) * dp;
      const double z = below ? -std::cos(t) : std::cos(t);
      g.w.insert(g.w.end(), {float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(z)});
      g.weight.push_back(std::sin(t) * dt * dp * std::cos(t));
    }
  return g;
}

v1::Material Curtain(const std::string& reflection, const std::string& layer) {
  v1::Material m;
  m.set_preset(reflection);
  m.mutable_transmission()->set_preset(layer);
  return m;
}

// A thin layer alone reports its direct transmittance exp(-tau / |n.wo|) per query.
TEST_F(ApiTest, ThinLayerReportsDirectTransmittance) {
  auto stub = testing::Connect(server_->port());
  EvaluateRequest req = Request("cotton_curtain", 1000, 31);
  for (int q = 0; q < 1000; q += 2) req.mutable_wo()->Set(3 * q + 2, -req.wo(3 * q + 2));  // half transmitted
  EvaluateResponse resp;
  ASSERT_TRUE(Call(*stub, req, &resp).ok());
  ASSERT_EQ(resp.transmittance_size(), 1000);
  const double tau = 0.8;  // the preset's (its description, server/models/plugins/thin_layer.cpp)
  for (int q = 0; q < 1000; ++q)
    EXPECT_NEAR(resp.transmittance(q), std::exp(-tau / std::fabs(req.wo(3 * q + 2))), 1e-6) << q;
  EvaluateResponse reflective;
  ASSERT_TRUE(Call(*stub, Request("velvet", 10, 1), &reflective).ok());
  EXPECT_EQ(reflective.transmittance_size(), 0);
}

// A curtain: same-side pairs give the reflection model scaled by sqrt((1 - T(wi)) (1 - T(wo))), opposite
// sides the layer's transmission, pairs below the cloth the mirrored front; reciprocal; energy below 1.
TEST_F(ApiTest, CurtainsCombineReflectionAndLayerTransmission) {
  auto stub = testing::Connect(server_->port());
  const int n = 4000;
  EvaluateRequest req = Request("linen_plain", n, 41);
  *req.mutable_material() = Curtain("linen_plain", "sheer_voile");
  std::mt19937 rng(2);
  for (int q = 0; q < n; ++q) {  // quarters: front/front, front/back, back/front, back/back
    if (q % 4 == 1 || q % 4 == 3) req.mutable_wo()->Set(3 * q + 2, -req.wo(3 * q + 2));
    if (q % 4 >= 2) req.mutable_wi()->Set(3 * q + 2, -req.wi(3 * q + 2));
  }
  EvaluateResponse curtain;
  grpc::Status s = Call(*stub, req, &curtain);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(curtain.f_size(), 3 * n);
  ASSERT_EQ(curtain.transmittance_size(), n);

  EvaluateRequest front = req, layer = req;
  front.mutable_material()->clear_transmission();
  for (int q = 0; q < n; ++q)
    if (q % 4 == 3) {  // back/back mirrored to the front
      front.mutable_wi()->Set(3 * q + 2, -req.wi(3 * q + 2));
      front.mutable_wo()->Set(3 * q + 2, -req.wo(3 * q + 2));
    }
  layer.mutable_material()->Clear();
  layer.mutable_material()->set_preset("sheer_voile");
  EvaluateResponse reflection, transmission;
  ASSERT_TRUE(Call(*stub, front, &reflection).ok());
  ASSERT_TRUE(Call(*stub, layer, &transmission).ok());
  const double tau = 0.15;
  for (int q = 0; q < n; ++q) {
    const bool same = q % 4 == 0 || q % 4 == 3;
    const double ti = std::exp(-tau / std::fabs(req.wi(3 * q + 2))), to = std::exp(-tau / std::fabs(req.wo(3 * q + 2)));
    EXPECT_NEAR(curtain.transmittance(q), to, 1e-6);
    for (int c = 0; c < 3; ++c) {
      const double want = same ? reflection.f(3 * q + c) * std::sqrt((1 - ti) * (1 - to)) : transmission.f(3 * q + c);
      ASSERT_NEAR(curtain.f(3 * q + c), want, 2e-6 * want + 1e-12) << "query " << q << " channel " << c;
    }
  }
  // Swapping wi and wo: the transmission is reciprocal, and the curtain's scale is symmetric, so the curtain
  // changes exactly as its reflection model does (the microcylinder model itself is not reciprocal).
  EvaluateRequest swapped = req, swapped_front = front;
  swapped.mutable_wi()->Swap(swapped.mutable_wo());
  swapped_front.mutable_wi()->Swap(swapped_front.mutable_wo());
  EvaluateResponse back, back_reflection;
  ASSERT_TRUE(Call(*stub, swapped, &back).ok());
  ASSERT_TRUE(Call(*stub, swapped_front, &back_reflection).ok());
  for (int i = 0; i < 3 * n; ++i) {
    const bool same = (i / 3) % 4 == 0 || (i / 3) % 4 == 3;
    const double want = same ? curtain.f(i) * back_reflection.f(i) / std::max(reflection.f(i), 1e-30f) : curtain.f(i);
    if (same && reflection.f(i) < 1e-20f) continue;
    ASSERT_NEAR(back.f(i), want, 1e-5 * want + 1e-12) << i;
  }

  // Energy: reflected + diffusely transmitted + directly transmitted light <= 1 for every reflection preset
  // with every layer preset, at three incidence angles (midpoint quadrature over both hemispheres; the
  // reflection models' own albedo is below 1, and the curtain only removes light from it).
  const HemisphereGrid up = Hemisphere(48, 96, false), down = Hemisphere(48, 96, true);
  for (const std::string reflection_preset : {"linen_plain", "polyester_satin_charmeuse_front", "velvet", "cotton_twill"})
    for (const std::string layer_preset : {"sheer_voile", "cotton_curtain", "linen_blind"})
      for (double theta_i : {10.0, 45.0, 75.0}) {
        EvaluateRequest e;
        *e.mutable_material() = Curtain(reflection_preset, layer_preset);
        const float wi[3] = {float(std::sin(theta_i * M_PI / 180)), 0.0f, float(std::cos(theta_i * M_PI / 180))};
        for (const HemisphereGrid* g : {&up, &down})
          for (size_t k = 0; k < g->weight.size(); ++k) {
            e.mutable_wi()->Add(wi, wi + 3);
            e.mutable_wo()->Add(&g->w[3 * k], &g->w[3 * k] + 3);
          }
        EvaluateResponse r;
        ASSERT_TRUE(Call(*stub, e, &r).ok());
        double reflected = 0, transmitted = 0;
        for (int i = 0; i < 2; ++i) {
          const HemisphereGrid& g = i == 0 ? up : down;
          const size_t base = i == 0 ? 0 : up.weight.size();
          for (size_t k = 0; k < g.weight.size(); ++k) {
            const double lum = (r.f(3 * (base + k)) + r.f(3 * (base + k) + 1) + r.f(3 * (base + k) + 2)) / 3;
            (i == 0 ? reflected : transmitted) += lum * g.weight[k];
          }
        }
        // Direct transmittance toward the light's own direction (the unscattered beam).
        EvaluateRequest direct;
        *direct.mutable_material() = e.material();
        direct.mutable_wi()->Add(wi, wi + 3);
        const float through[3] = {-wi[0], -wi[1], -wi[2]};
        direct.mutable_wo()->Add(through, through + 3);
        EvaluateResponse d;
        ASSERT_TRUE(Call(*stub, direct, &d).ok());
        const double total = reflected + transmitted + d.transmittance(0);
        std::printf("curtain %s + %s at %.0f deg: reflected %.3f, diffuse transmitted %.3f, direct %.3f, sum %.3f\n",
                    reflection_preset.c_str(), layer_preset.c_str(), theta_i, reflected, transmitted,
                    d.transmittance(0), total);
        EXPECT_LT(total, 1.0) << reflection_preset << " + " << layer_preset << " at " << theta_i;
      }

  // Invalid curtains name the field.
  struct BadCurtain {
    const char* name;
    v1::Material material;
    const char* field;
  };
  v1::Material nested = Curtain("velvet", "sheer_voile");
  nested.mutable_transmission()->mutable_transmission()->set_preset("sheer_voile");
  const std::vector<BadCurtain> cases = {
      {"reflective layer", Curtain("velvet", "linen_plain"), "material.transmission: model 'microcylinder'"},
      {"layer on a layer", Curtain("sheer_voile", "cotton_curtain"), "material.transmission: model 'thin_layer'"},
      {"nested", nested, "material.transmission.transmission"},
      {"bad layer parameter", [] { v1::Material m = Curtain("velvet", "sheer_voile"); auto* p = m.mutable_transmission()->add_params(); p->set_name("tau"); p->add_values(-1); return m; }(),
       "material.transmission.params[0].values[0]"},
  };
  for (const BadCurtain& c : cases) {
    EvaluateRequest bad = Request("velvet", 4, 1);
    *bad.mutable_material() = c.material;
    EvaluateResponse resp;
    const grpc::Status st = Call(*stub, bad, &resp);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name;
    EXPECT_EQ(st.error_message().rfind(c.field, 0), 0u) << c.name << ": " << st.error_message();
  }
}

// error_target picks the thin layer's accuracy knob (`scattering`): a loose target keeps single scattering,
// a tight one switches to all orders (more light: multiple scattering only adds), and the response says which;
// without a target the material's own `scattering` parameter decides.
TEST_F(ApiTest, ErrorTargetChoosesTheThinLayersScatteringMode) {
  auto stub = testing::Connect(server_->port());
  EvaluateRequest req = Request("cotton_curtain", 200, 17);
  EvaluateResponse none, loose, tight;
  ASSERT_TRUE(Call(*stub, req, &none).ok());
  req.set_error_target(1.0);
  ASSERT_TRUE(Call(*stub, req, &loose).ok());
  req.set_error_target(1e-3);
  ASSERT_TRUE(Call(*stub, req, &tight).ok());
  EXPECT_NE(none.approximation().find("thin_layer: scattering 0 (the material's own"), std::string::npos)
      << none.approximation();
  EXPECT_NE(loose.approximation().find("thin_layer: scattering 0 (estimated error"), std::string::npos)
      << loose.approximation();
  EXPECT_EQ(tight.approximation(), "thin_layer: scattering 1 (exact)");
  double single = 0, all = 0;
  for (int i = 0; i < none.f_size(); ++i) {
    EXPECT_EQ(loose.f(i), none.f(i)) << i;
    EXPECT_GE(tight.f(i), none.f(i)) << i;
    single += none.f(i);
    all += tight.f(i);
  }
  EXPECT_GT(all, 1.05 * single);  // tau 0.8, albedo ~0.8: multiple scattering is far from negligible
}

// The same mechanism for the microcylinder's knob (tangent_samples): the chosen setting's estimated error is
// within the target, and the f it gives is within about that of the exact setting's on other pairs.
TEST_F(ApiTest, ErrorTargetChoosesTangentSamples) {
  auto stub = testing::Connect(server_->port());
  EvaluateRequest req = Request("velvet", 400, 23);
  EvaluateResponse own, chosen, exact;
  ASSERT_TRUE(Call(*stub, req, &own).ok());
  EXPECT_NE(own.approximation().find("microcylinder: tangent_samples 32 (the material's own; exact: 256)"),
            std::string::npos) << own.approximation();
  req.set_error_target(0.03);
  ASSERT_TRUE(Call(*stub, req, &chosen).ok());
  EXPECT_NE(chosen.approximation().find("microcylinder: tangent_samples "), std::string::npos);
  const size_t at = chosen.approximation().find("estimated error ");
  ASSERT_NE(at, std::string::npos) << chosen.approximation();
  const double estimate = std::stod(chosen.approximation().substr(at + 16)) / 100;
  EXPECT_LE(estimate, 0.03);
  EvaluateRequest full = Request("velvet", 400, 23);
  v1::Param* t = full.mutable_material()->add_params();
  t->set_name("tangent_samples");
  t->add_values(256);
  ASSERT_TRUE(Call(*stub, full, &exact).ok());
  EXPECT_EQ(exact.approximation(), "");
  double diff = 0, total = 0;
  for (int i = 0; i < exact.f_size(); ++i) {
    diff += std::fabs(chosen.f(i) - exact.f(i));
    total += exact.f(i);
  }
  std::printf("error target 0.03: %s; measured relative L1 against 256 samples %.3g\n",
              chosen.approximation().c_str(), diff / total);
  EXPECT_LE(diff / total, 2 * 0.03);  // other pairs than the estimate's (and some near the horizon)
}

TEST_F(ApiTest, MoreQueriesThanTheLimitAreRejected) {
  EvaluateRequest req;
  req.mutable_material()->set_preset("velvet");
  const size_t n = api::kMaxQueriesPerCall + 1;
  req.mutable_wi()->Resize(int(3 * n), 0.0f);
  req.mutable_wo()->Resize(int(3 * n), 0.0f);
  auto stub = testing::Connect(server_->port());
  EvaluateResponse resp;
  const grpc::Status s = Call(*stub, req, &resp);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("limit"), std::string::npos) << s.error_message();
}

TEST_F(ApiTest, BadRequestsNeverDisturbOtherClients) {
  std::atomic<int> good_ok{0}, bad_rejected{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t)
    threads.emplace_back([&, t] {
      auto stub = testing::Connect(server_->port());
      for (int k = 0; k < 10; ++k) {
        EvaluateRequest req = Request(t % 2 ? "velvet" : "silk_shot", 2000, t * 100 + k);
        if (t % 2 == 0) req.mutable_wi()->Set(5 * 3, 3.0f);  // one non-unit direction
        EvaluateResponse resp;
        const grpc::Status s = Call(*stub, req, &resp);
        if (t % 2 == 0 && s.error_code() == grpc::StatusCode::INVALID_ARGUMENT) ++bad_rejected;
        if (t % 2 == 1 && s.ok() && resp.f_size() == 6000) ++good_ok;
      }
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(good_ok, 40);
  EXPECT_EQ(bad_rejected, 40);
}

// Random, mostly malformed requests: every answer is OK (with finite, non-negative f of the right size) or
// INVALID_ARGUMENT, and the server keeps serving.
TEST_F(ApiTest, RandomRequestsGetAnAnswerAndNeverHurtTheServer) {
  auto stub = testing::Connect(server_->port());
  std::mt19937 rng(2026);
  std::uniform_real_distribution<double> u(0, 1);
  const char* names[] = {"eta", "tangent_samples", "thread1.coverage", "thread2.albedo", "thread1.gamma_s",
                         "thread2.tangent_offsets", "thread1.tangent_lengths", "nonsense", ""};
  const char* presets[] = {"velvet", "linen_plain", "", "silk"};
  const double specials[] = {0.0, -1.0, 1e308, -1e-308, std::nan(""), INFINITY, 1.0, 256.0, 90.0, -90.0};
  int ok = 0, invalid = 0;
  for (int k = 0; k < 400; ++k) {
    EvaluateRequest req;
    req.mutable_material()->set_preset(presets[rng() % 4]);
    if (rng() % 4 == 0) req.mutable_material()->set_model(rng() % 2 ? "microcylinder" : "woolly");
    for (int p = 0, np = rng() % 3; p < np; ++p) {
      auto* param = req.mutable_material()->add_params();
      param->set_name(names[rng() % std::size(names)]);
      for (int v = 0, nv = rng() % 5; v < nv; ++v)
        param->add_values(rng() % 2 ? specials[rng() % std::size(specials)] : 4 * u(rng) - 1);
    }
    const int n = rng() % 20;
    for (int i = 0; i < 3 * n + (rng() % 8 == 0 ? 1 : 0); ++i) req.add_wi(float(2 * u(rng) - 1));
    for (int i = 0; i < 3 * n; ++i) req.add_wo(float(2 * u(rng) - 1));
    if (rng() % 2) {  // make the directions unit, sometimes with a special value slipped in
      for (auto* w : {req.mutable_wi(), req.mutable_wo()})
        for (int q = 0; q + 2 < w->size(); q += 3) {
          const float l = std::sqrt(w->Get(q) * w->Get(q) + w->Get(q + 1) * w->Get(q + 1) + w->Get(q + 2) * w->Get(q + 2));
          for (int c = 0; c < 3; ++c) w->Set(q + c, l > 0 ? w->Get(q + c) / l : 1.0f);
        }
      if (n > 0 && rng() % 4 == 0) req.mutable_wo()->Set(0, float(specials[rng() % std::size(specials)]));
    }
    if (rng() % 10 == 0) req.add_uv(0.5f);
    if (rng() % 10 == 0) req.set_precision(v1::PRECISION_FP64);
    EvaluateResponse resp;
    const grpc::Status s = Call(*stub, req, &resp);
    if (s.ok()) {
      ++ok;
      ASSERT_EQ(resp.f_size(), req.wi_size());
      for (float f : resp.f()) ASSERT_TRUE(std::isfinite(f) && f >= 0) << f;
    } else {
      ++invalid;
      ASSERT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
      ASSERT_FALSE(s.error_message().empty());
    }
  }
  EXPECT_GT(ok, 10);
  EXPECT_GT(invalid, 100);
  EvaluateResponse resp;
  EXPECT_TRUE(Call(*stub, Request("velvet", 10, 1), &resp).ok());
}

TEST(MaterialCache, ReturnsTheSamePackingAsResolvingAndEvictsLeastRecentlyUsed) {
  const auto& registry = models::Registry::Global();
  auto material = [](const std::string& preset, double eta) {
    v1::Material m;
    m.set_preset(preset);
    if (eta > 0) {
      auto* p = m.add_params();
      p->set_name("eta");
      p->add_values(eta);
    }
    return m;
  };
  // The bytes of one material (its entry and the alias of its request's bytes; these materials are one preset at
  // three refractive indices, so the same size: a packed microcylinder's size depends on its tangent curves),
  // then a cache that holds two of them.
  size_t entry_bytes = 0;
  {
    models::MaterialCache probe(size_t{1} << 20);
    std::shared_ptr<const models::PreparedMaterial> entry;
    ASSERT_EQ(probe.Get(material("velvet", -1.0), registry, &entry), "");
    entry_bytes = probe.bytes();
  }
  ASSERT_GT(entry_bytes, 0u);
  models::MaterialCache cache(2 * entry_bytes + entry_bytes / 4);
  std::vector<std::shared_ptr<const models::PreparedMaterial>> first;
  const std::pair<const char*, double> materials[] = {{"velvet", -1.0}, {"velvet", 1.3}, {"velvet", 1.4}};
  for (int round = 0; round < 2; ++round)
    for (size_t k = 0; k < 3; ++k) {
      const auto [preset, eta] = materials[k];
      const v1::Material m = material(preset, eta);
      std::shared_ptr<const models::PreparedMaterial> entry;
      ASSERT_EQ(cache.Get(m, registry, &entry), "");
      models::ResolvedMaterial resolved;
      ASSERT_EQ(models::ResolveMaterial(m, registry, &resolved), "");
      EXPECT_EQ(entry->model, resolved.model);
      EXPECT_EQ(entry->packed.data, resolved.model->Pack(resolved.values).data) << preset << " eta " << eta;
      if (round == 0) first.push_back(entry);
      if (round == 1) {
        EXPECT_NE(entry.get(), first[k].get()) << "round two should have missed: " << preset;
      }
      EXPECT_LE(cache.entries(), 2u);
    }
  // Capacity 2 with three materials cycling: every lookup of round two missed (above); a repeat hits.
  std::shared_ptr<const models::PreparedMaterial> again;
  ASSERT_EQ(cache.Get(material("velvet", 1.4), registry, &again), "");
  std::shared_ptr<const models::PreparedMaterial> hit;
  ASSERT_EQ(cache.Get(material("velvet", 1.4), registry, &hit), "");
  EXPECT_EQ(hit.get(), again.get());  // a hit shares the entry
  std::shared_ptr<const models::PreparedMaterial> bad;
  EXPECT_NE(cache.Get(material("velvet", 7.0), registry, &bad), "");  // out of range: an error, not cached
  EXPECT_EQ(bad, nullptr);
}

TEST(Batching, ConcurrentRequestsAreCoalescedIntoOneLaunch) {
  auto server = StartServer();
  std::vector<std::thread> threads;
  std::atomic<int> max_requests{0}, ok{0};
  const char* presets[] = {"linen_plain", "velvet", "silk_shot", "silk_crepe_de_chine"};
  for (int t = 0; t < 16; ++t)
    threads.emplace_back([&, t] {
      auto stub = testing::Connect(server->port());
      for (int k = 0; k < 4; ++k) {
        EvaluateResponse resp;
        if (Call(*stub, Request(presets[t % 4], 3000, t * 10 + k), &resp).ok()) {
          ++ok;
          int seen = max_requests.load();
          while (int(resp.batch_requests()) > seen && !max_requests.compare_exchange_weak(seen, resp.batch_requests())) {}
        }
      }
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(ok, 64);
  EXPECT_GT(max_requests, 1) << "different materials should share launches";
}

TEST(Batching, NoCoalescingRunsOneRequestPerLaunch) {
  batching::BatcherOptions options;
  options.coalesce = false;
  auto server = StartServer(options);
  std::vector<std::thread> threads;
  std::atomic<int> max_requests{0};
  for (int t = 0; t < 8; ++t)
    threads.emplace_back([&, t] {
      auto stub = testing::Connect(server->port());
      EvaluateResponse resp;
      ASSERT_TRUE(Call(*stub, Request("velvet", 3000, t), &resp).ok());
      if (int(resp.batch_requests()) > max_requests) max_requests = resp.batch_requests();
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(max_requests, 1);
}

TEST(Metrics, PrometheusEndpointCountsCallsAndQueries) {
  api::ServerOptions options;
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  ASSERT_GT(server->metrics_port(), 0);
  auto stub = testing::Connect(server->port());
  EvaluateResponse resp;
  ASSERT_TRUE(Call(*stub, Request("velvet", 37, 1), &resp).ok());
  ASSERT_TRUE(Call(*stub, Request("velvet", 5, 2), &resp).ok());
  EXPECT_EQ(Call(*stub, Request("burlap", 5, 3), &resp).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
  EXPECT_NE(text.find("loomlight_calls_total{code=\"OK\",rpc=\"Evaluate\"} 2"), std::string::npos) << text;
  EXPECT_NE(text.find("loomlight_calls_total{code=\"INVALID_ARGUMENT\",rpc=\"Evaluate\"} 1"), std::string::npos);
  EXPECT_NE(text.find("loomlight_queries_total{model=\"microcylinder\",precision=\"fp32\"} 42"), std::string::npos);
  EXPECT_NE(text.find("loomlight_launch_queries_count 2"), std::string::npos);
  EXPECT_NE(text.find("loomlight_kernel_seconds_bucket"), std::string::npos);
}

// Runs BlockingRequest() on another thread; the request is built first so the call starts at once.
// *done (optional) becomes true when the call has returned.
std::thread StartBlockingCall(v1::Loomlight::Stub& stub, std::atomic<bool>* done = nullptr) {
  static const EvaluateRequest blocking = BlockingRequest();
  return std::thread([&stub, done] {
    EvaluateResponse resp;
    EXPECT_TRUE(Call(stub, blocking, &resp).ok());
    if (done) *done = true;
  });
}

TEST(Batching, FullQueueAnswersResourceExhausted) {
  batching::BatcherOptions options;
  options.interactive.max_queued_queries = options.bulk.max_queued_queries = 1000;
  auto server = StartServer(options);
  auto stub = testing::Connect(server->port());
  // While a long request occupies the device, the first small one queues and the rest overflow. Rounds of
  // six small calls are sent until one round overlaps the long call (the first rounds may run before it).
  std::thread big = StartBlockingCall(*stub);
  int exhausted = 0, ok = 0;
  for (int round = 0; round < 200 && exhausted == 0; ++round) {
    std::atomic<int> round_exhausted{0}, round_ok{0};
    std::vector<std::thread> small;
    for (int t = 0; t < 6; ++t)
      small.emplace_back([&, t] {
        EvaluateResponse resp;
        const grpc::Status s = Call(*stub, Request("velvet", 800, 10 + t), &resp);
        if (s.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED) ++round_exhausted;
        if (s.ok()) ++round_ok;
      });
    for (auto& t : small) t.join();
    EXPECT_EQ(round_exhausted + round_ok, 6) << "every call is answered OK or RESOURCE_EXHAUSTED";
    exhausted += round_exhausted;
    ok += round_ok;
  }
  big.join();
  EXPECT_GE(exhausted, 1);
  EXPECT_GE(ok, 1);
}

// A call whose deadline passes while it is queued never rides a launch. The interactive queue holds each launch
// 2 s for company (max_queue_delay), so a call with a 50 ms deadline expires queued on any machine.
TEST(Batching, ExpiredRequestsAreDroppedBeforeLaunch) {
  api::ServerOptions options;
  options.batcher.interactive.max_queue_delay = std::chrono::seconds(2);
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  EvaluateResponse resp;
  EXPECT_EQ(Call(*stub, Request("velvet", 1000, 2), &resp, 0.05).error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  // The server is still healthy afterwards, and the one launch it made was this call's alone.
  EXPECT_TRUE(Call(*stub, Request("velvet", 100, 3), &resp).ok());
  const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
  EXPECT_EQ(testing::MetricValue(text, "loomlight_launch_requests_count"), 1.0) << text;
  EXPECT_EQ(testing::MetricValue(text, "loomlight_launch_requests_sum"), 1.0) << text;
}

// ---- Hostile text in error messages (client input echoed only truncated) and text parameters ----

TEST(Quote, ShortTextIsQuotedWhole) {
  EXPECT_EQ(models::Quote("burlap"), "'burlap'");
  EXPECT_EQ(models::Quote(""), "''");
  EXPECT_EQ(models::Quote("caf\u00e9 \u2713 \U0001F600"), "'caf\u00e9 \u2713 \U0001F600'");  // UTF-8 as it is
}

TEST(Quote, UnprintableBytesAreEscapedOnOneLine) {
  EXPECT_EQ(models::Quote("a\nb\rc\td"), "'a\\nb\\rc\\td'");
  EXPECT_EQ(models::Quote(std::string("\x01\x1b[2J\x7f", 6)), "'\\x01\\x1b[2J\\x7f'");
  EXPECT_EQ(models::Quote(std::string("nul\0here", 8)), "'nul\\x00here'");
  EXPECT_EQ(models::Quote("it's a\\b"), "'it\\'s a\\\\b'");
  // Not well-formed UTF-8: stray bytes, a cut sequence, overlong '/', a surrogate, past U+10FFFF.
  EXPECT_EQ(models::Quote("\xff\x80"), "'\\xff\\x80'");
  EXPECT_EQ(models::Quote("x\xe2\x9c"), "'x\\xe2\\x9c'");
  EXPECT_EQ(models::Quote("\xc0\xaf"), "'\\xc0\\xaf'");
  EXPECT_EQ(models::Quote("\xed\xa0\x80"), "'\\xed\\xa0\\x80'");
  EXPECT_EQ(models::Quote("\xf4\x90\x80\x80"), "'\\xf4\\x90\\x80\\x80'");
  // C1 controls, line separators and bidirectional overrides would break or reorder the line.
  EXPECT_EQ(models::Quote("a\u0085b\u2028c\u202ed"), "'a\\u0085b\\u2028c\\u202ed'");
}

// The body between the quotes of a cut quote, checked to be cut as documented: at most kMaxQuotedBytes,
// followed by the ellipsis and the input's size.
std::string CutBody(const std::string& quoted, size_t input_size) {
  const std::string tail = "\u2026' (" + std::to_string(input_size) + " bytes)";
  EXPECT_EQ(quoted.front(), '\'') << quoted;
  EXPECT_GE(quoted.size(), tail.size() + 1);
  EXPECT_EQ(quoted.substr(quoted.size() - tail.size()), tail) << quoted;
  const std::string body = quoted.substr(1, quoted.size() - 1 - tail.size());
  EXPECT_LE(body.size(), models::kMaxQuotedBytes);
  return body;
}

TEST(Quote, LongTextIsCutOnACharacterBoundaryWithItsSize) {
  const std::string a(1000, 'a');
  EXPECT_EQ(models::Quote(a), "'" + std::string(200, 'a') + "\u2026' (1000 bytes)");
  EXPECT_EQ(models::Quote(std::string(200, 'a')), "'" + std::string(200, 'a') + "'");  // at the limit: whole
  // Four-byte characters after 0 to 3 ASCII bytes: the cut never splits one.
  std::string emoji;
  for (int i = 0; i < 300; ++i) emoji += "\U0001F600";
  for (size_t lead = 0; lead < 4; ++lead) {
    const std::string text = std::string(lead, 'a') + emoji;
    const std::string body = CutBody(models::Quote(text), text.size());
    EXPECT_EQ(text.rfind(body, 0), 0u) << "not a prefix";
    EXPECT_EQ((body.size() - lead) % 4, 0u) << "cut inside a character";
    EXPECT_GT(body.size(), models::kMaxQuotedBytes - 4);
  }
  // Escapes count at their escaped size and are never split: 1 MB of control bytes shows 50 of them.
  const std::string controls(1000000, '\x01');
  std::string want;
  for (int i = 0; i < 50; ++i) want += "\\x01";
  EXPECT_EQ(CutBody(models::Quote(controls), controls.size()), want);
  EXPECT_EQ(CutBody(models::Quote(std::string(199, 'a') + "\n"), 200), std::string(199, 'a'));
}

TEST(Quote, EchoTokenShowsShortPlainTokensBare) {
  EXPECT_EQ(models::EchoToken("300"), "300");
  EXPECT_EQ(models::EchoToken("1.1"), "1.1");
  EXPECT_EQ(models::EchoToken("COLOR PALETTE"), "COLOR PALETTE");
  EXPECT_EQ(models::EchoToken(""), "''");
  EXPECT_EQ(models::EchoToken("a=b"), "'a=b'");
  EXPECT_EQ(models::EchoToken("two\nlines"), "'two\\nlines'");
  EXPECT_EQ(models::EchoToken(std::string(models::kMaxTokenBytes, 'x')), std::string(models::kMaxTokenBytes, 'x'));
  EXPECT_EQ(models::EchoToken(std::string(5000, 'x')), models::Quote(std::string(5000, 'x')));
}

TEST(InvalidStatus, MessagesAreCappedOnACharacterBoundary) {
  const grpc::Status short_status = api::Invalid("material.preset: unknown preset 'burlap'");
  EXPECT_EQ(short_status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(short_status.error_message(), "material.preset: unknown preset 'burlap'");
  const std::string exact(api::kMaxStatusMessageBytes, 'm');
  EXPECT_EQ(api::Invalid(exact).error_message(), exact);
  std::string two_byte;
  for (int i = 0; i < 3000; ++i) two_byte += "\u00e9";
  for (size_t lead = 0; lead < 4; ++lead) {
    const std::string message = "wi: " + std::string(lead, 'a') + two_byte;
    const grpc::Status s = api::Invalid(message);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    const std::string& got = s.error_message();
    EXPECT_LE(got.size(), api::kMaxStatusMessageBytes);
    const std::string mark = " \u2026 (message cut from " + std::to_string(message.size()) + " bytes)";
    ASSERT_GE(got.size(), mark.size());
    EXPECT_EQ(got.substr(got.size() - mark.size()), mark) << got;
    const std::string kept = got.substr(0, got.size() - mark.size());
    EXPECT_EQ(message.rfind(kept, 0), 0u) << "not a prefix";
    EXPECT_EQ((kept.size() - 4 - lead) % 2, 0u) << "cut inside a character";
    EXPECT_GT(kept.size(), api::kMaxStatusMessageBytes - mark.size() - 2);
  }
}

// A request edited into a bad one, and how its error message must start.
struct EchoCase {
  const char* name;
  std::function<void(EvaluateRequest&)> mutate;
  std::string expected;
};

// Client text of 100 KB and 1 MB in every echoing field: INVALID_ARGUMENT (not RESOURCE_EXHAUSTED, which a
// status message over the client's ~8 KB trailer limit becomes), naming the field, quoting the text cut
// with its size, on one line, well under the cap.
TEST_F(ApiTest, HugeClientTextIsEchoedTruncated) {
  auto stub = testing::Connect(server_->port());
  for (size_t size : {size_t{100000}, size_t{1000000}}) {
    std::string junk;  // valid UTF-8 (protobuf strings must be), with a control character and a 2-byte one
    while (junk.size() < size) junk += "x\x01\u00e9" + std::to_string(junk.size());
    junk.resize(size);
    while ((static_cast<unsigned char>(junk.back()) & 0xC0) == 0xC0) junk.pop_back();  // no cut 'é'
    const std::string echoed = "(" + std::to_string(junk.size()) + " bytes)";
    std::string wif_shafts = kPlainWif, wif_index = kPlainWif;
    wif_shafts.replace(wif_shafts.find("Shafts=2"), 8, "Shafts=" + junk);
    wif_index.replace(wif_index.find("[THREADING]\n1=1"), 15, "[THREADING]\n1=" + junk);
    const std::vector<EchoCase> cases = {
        {"preset", [&](EvaluateRequest& r) { r.mutable_material()->set_preset(junk); }, "material.preset: unknown preset '"},
        {"model", [&](EvaluateRequest& r) { r.mutable_material()->set_preset(""); r.mutable_material()->set_model(junk); },
         "material.model: unknown model '"},
        {"model of a preset", [&](EvaluateRequest& r) { r.mutable_material()->set_model(junk); }, "material.model: preset 'cotton_twill'"},
        {"parameter name", [&](EvaluateRequest& r) { AddParam(r, junk, {1}); }, "material.params[0].name: model 'woven' has no parameter '"},
        {"WIF count", [&](EvaluateRequest& r) { AddText(r, "pattern.wif", wif_shafts); }, "material.params[0].text: WIF line 12: [WEAVING] Shafts='"},
        {"WIF index", [&](EvaluateRequest& r) { AddText(r, "pattern.wif", wif_index); }, "material.params[0].text: WIF line 20: shaft '"},
    };
    for (const EchoCase& c : cases) {
      SCOPED_TRACE(std::string(c.name) + ", " + std::to_string(size) + " bytes");
      EvaluateRequest req = Request("cotton_twill", 4, 1);
      c.mutate(req);
      EvaluateResponse resp;
      const grpc::Status s = Call(*stub, req, &resp);
      const std::string& m = s.error_message();
      EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << m.substr(0, 300);
      EXPECT_EQ(m.rfind(c.expected, 0), 0u) << m.substr(0, 300);
      EXPECT_NE(m.find(echoed), std::string::npos) << m.substr(0, 300);
      EXPECT_LT(m.size(), 400u);
      EXPECT_EQ(m.find_first_of(std::string("\n\r\x01", 3)), std::string::npos) << m.substr(0, 300);
    }
  }
}

// A text parameter is never combined with a parameter it sets, even when the values agree (otherwise which
// of the two wins would depend on the values); parameters it does not set combine with it.
TEST_F(ApiTest, TextParametersAreNeverCombinedWithTheParametersTheySet) {
  auto stub = testing::Connect(server_->port());
  const std::vector<EchoCase> cases = {  // kPlainWif sets pattern.warps = 2 and pattern.cells = {1, 0, 0, 1}
      {"WIF, then warps as the WIF sets them",
       [](EvaluateRequest& r) { AddText(r, "pattern.wif", kPlainWif); AddParam(r, "pattern.warps", {2}); },
       "material.params[0].name: parameter 'pattern.wif' sets 'pattern.warps', which is also given"},
      {"warps as the WIF sets them, then the WIF",
       [](EvaluateRequest& r) { AddParam(r, "pattern.warps", {2}); AddText(r, "pattern.wif", kPlainWif); },
       "material.params[1].name: parameter 'pattern.wif' sets 'pattern.warps'"},
      {"cells as the WIF sets them",
       [](EvaluateRequest& r) { AddParam(r, "pattern.cells", {1, 0, 0, 1}); AddText(r, "pattern.wif", kPlainWif); },
       "material.params[1].name: parameter 'pattern.wif' sets 'pattern.cells'"},
  };
  for (const EchoCase& c : cases) {
    EvaluateRequest req = Request("cotton_twill", 4, 1);
    c.mutate(req);
    EvaluateResponse resp;
    const grpc::Status s = Call(*stub, req, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name << ": " << s.error_message();
    EXPECT_EQ(s.error_message().rfind(c.expected, 0), 0u) << c.name << ": " << s.error_message();
  }
  EvaluateRequest other = Request("cotton_twill", 4, 1);
  AddParam(other, "eta", {1.4});
  AddText(other, "pattern.wif", kPlainWif);
  AddParam(other, "warp.alpha", {0.5});
  EvaluateResponse resp;
  const grpc::Status s = Call(*stub, other, &resp);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

// Capabilities are declared as data: the accuracy knob names a parameter of the schema with ascending
// settings inside its range, and a fiber model names its axis parameter (three values); the client's views
// and Render's fidelity chooser read these, never model names.
TEST_F(ApiTest, ListModelsDeclaresKnobsAndFiberAxesAsData) {
  auto stub = testing::Connect(server_->port());
  grpc::ClientContext ctx;
  v1::ListModelsResponse models;
  ASSERT_TRUE(stub->ListModels(&ctx, v1::ListModelsRequest(), &models).ok());
  int knobs = 0, fibers = 0;
  for (const v1::ModelInfo& model : models.models()) {
    SCOPED_TRACE(model.name());
    const auto param = [&](const std::string& name) -> const v1::ParamSchema* {
      for (const v1::ParamSchema& p : model.params())
        if (p.name() == name) return &p;
      return nullptr;
    };
    if (!model.accuracy_knob().param().empty()) {
      ++knobs;
      const v1::ParamSchema* p = param(model.accuracy_knob().param());
      ASSERT_NE(p, nullptr);
      const auto& settings = model.accuracy_knob().settings();
      ASSERT_GE(settings.size(), 2);
      for (int i = 0; i < settings.size(); ++i) {
        EXPECT_GE(settings[i], p->min());
        EXPECT_LE(settings[i], p->max());
        if (i > 0) {
          EXPECT_GT(settings[i], settings[i - 1]);
        }
      }
      EXPECT_FALSE(model.accuracy_knob().error_estimate().empty());
    }
    if (!model.fiber_axis_param().empty()) {
      ++fibers;
      const v1::ParamSchema* p = param(model.fiber_axis_param());
      ASSERT_NE(p, nullptr);
      EXPECT_EQ(p->type(), v1::ParamSchema::TYPE_REAL_LIST);
      EXPECT_EQ(p->min_count(), 3u);
      EXPECT_EQ(p->max_count(), 3u);
    }
  }
  EXPECT_GE(knobs, 1);
  EXPECT_GE(fibers, 1);
}
// A per-query fiber axis gives, for every fiber model's presets, what a material with that axis as its
// parameter gives (random axes, the shading normal's own direction among them: the frame's special case);
// other models, a curtain, a wrong length or a non-unit axis are refused naming fiber_axis.
TEST_F(ApiTest, PerQueryFiberAxisEqualsTheAxisParameter) {
  auto stub = testing::Connect(server_->port());
  grpc::ClientContext list_ctx;
  v1::ListModelsResponse models;
  ASSERT_TRUE(stub->ListModels(&list_ctx, v1::ListModelsRequest(), &models).ok());
  std::mt19937 rng(5);
  std::normal_distribution<float> normal;
  int checked = 0;
  for (const v1::ModelInfo& model : models.models()) {
    if (model.fiber_axis_param().empty()) continue;
    for (const v1::Preset& preset : model.presets()) {
      SCOPED_TRACE(preset.name());
      constexpr int kAxes = 12, kPairs = 16;
      EvaluateRequest per_query = Request(preset.name(), kAxes * kPairs, 3);
      std::vector<std::array<float, 3>> axes = {{0, 0, 1}, {0, 0, -1}, {1, 0, 0}};
      while (axes.size() < kAxes) {
        std::array<float, 3> a = {normal(rng), normal(rng), normal(rng)};
        const float len = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        for (float& x : a) x /= len;
        axes.push_back(a);
      }
      for (int i = 0; i < kAxes * kPairs; ++i) per_query.mutable_fiber_axis()->Add(axes[i / kPairs].begin(), axes[i / kPairs].end());
      EvaluateResponse all;
      ASSERT_TRUE(Call(*stub, per_query, &all).ok());
      for (int a = 0; a < kAxes; ++a) {
        EvaluateRequest one;
        one.mutable_material()->set_preset(preset.name());
        v1::Param* axis = one.mutable_material()->add_params();
        axis->set_name(model.fiber_axis_param());
        axis->mutable_values()->Add(axes[a].begin(), axes[a].end());
        one.mutable_wi()->Add(per_query.wi().begin() + 3 * a * kPairs, per_query.wi().begin() + 3 * (a + 1) * kPairs);
        one.mutable_wo()->Add(per_query.wo().begin() + 3 * a * kPairs, per_query.wo().begin() + 3 * (a + 1) * kPairs);
        EvaluateResponse expected;
        ASSERT_TRUE(Call(*stub, one, &expected).ok());
        for (int i = 0; i < 3 * kPairs; ++i) {
          const float want = expected.f(i), got = all.f(3 * a * kPairs + i);
          EXPECT_NEAR(got, want, 1e-3f * std::fabs(want) + 1e-5f) << "axis " << a << " value " << i;
          ++checked;
        }
      }
    }
  }
  EXPECT_GT(checked, 0);

  const auto refused = [&](EvaluateRequest r) {
    EvaluateResponse resp;
    const grpc::Status s = Call(*stub, r, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_EQ(s.error_message().rfind("fiber_axis", 0), 0u) << s.error_message();
  };
  std::string fiber_preset;
  for (const v1::ModelInfo& model : models.models())
    if (!model.fiber_axis_param().empty()) fiber_preset = model.presets(0).name();
  EvaluateRequest surface = Request("linen_plain", 2, 1);
  for (float v : {0.f, 0.f, 1.f, 0.f, 0.f, 1.f}) surface.add_fiber_axis(v);
  refused(surface);
  EvaluateRequest curtain = Request(fiber_preset, 2, 1);
  curtain.mutable_material()->mutable_transmission()->set_preset("cotton_curtain");
  for (float v : {0.f, 0.f, 1.f, 0.f, 0.f, 1.f}) curtain.add_fiber_axis(v);
  refused(curtain);
  EvaluateRequest short_axis = Request(fiber_preset, 2, 1);
  for (float v : {0.f, 0.f, 1.f}) short_axis.add_fiber_axis(v);
  refused(short_axis);
  EvaluateRequest long_axis = Request(fiber_preset, 1, 1);
  for (float v : {0.f, 0.f, 2.f}) long_axis.add_fiber_axis(v);
  refused(long_axis);
  EvaluateRequest nan_axis = Request(fiber_preset, 1, 1);
  for (float v : {NAN, 0.f, 1.f}) nan_axis.add_fiber_axis(v);
  refused(nan_axis);
}

// Evaluate's ambient quantity (Wu and Yuksel Eqs. 7-10) served through the kernels equals direct quadrature
// of Evaluate's own f: the integral of f(wi, wo) cos(theta_i) dw_i over the sphere, dw = cos(theta) dtheta
// dphi in the fiber frame (t = the axis parameter, +x), for the widest-lobed presets (fleece; the simple mode)
// at several wo; a per-query fiber axis gives the same as the axis parameter; misuse is refused naming the field.
TEST_F(ApiTest, AmbientQuantityEqualsQuadratureOfF) {
  auto stub = testing::Connect(server_->port());
  constexpr int kTheta = 720, kPhi = 180;  // 0.25 and 2 degrees: the narrowest lobe here is 5 degrees wide
  const std::vector<std::array<float, 3>> wos = {{0, 0, 1}, {0.5f, 0, 0.8660254f}, {-0.8f, 0.36f, 0.48f}};
  for (const auto& [name, params] : {std::pair<std::string, std::vector<std::pair<std::string, std::vector<double>>>>{
                                         "fleece", {}},
                                     {"fleece", {{"mode", {0}}, {"kd", {0.3, 0.2, 0.1}}}}}) {
    SCOPED_TRACE(name + (params.empty() ? "" : " simple"));
    EvaluateRequest ambient;
    ambient.mutable_material()->set_preset(name);
    for (const auto& [p, v] : params) {
      v1::Param* param = ambient.mutable_material()->add_params();
      param->set_name(p);
      param->mutable_values()->Add(v.begin(), v.end());
    }
    ambient.set_quantity(v1::QUANTITY_AMBIENT);
    for (const auto& wo : wos) ambient.mutable_wo()->Add(wo.begin(), wo.end());
    EvaluateResponse served;
    ASSERT_TRUE(Call(*stub, ambient, &served).ok());
    ASSERT_EQ(served.f_size(), 3 * static_cast<int>(wos.size()));
    for (size_t o = 0; o < wos.size(); ++o) {
      EvaluateRequest grid;
      *grid.mutable_material() = ambient.material();
      std::vector<double> weight;
      for (int a = 0; a < kTheta; ++a) {
        const double theta = -M_PI / 2 + (a + 0.5) * M_PI / kTheta;  // midpoint rule: smooth periodic-free ends
        for (int b = 0; b < kPhi; ++b) {
          const double phi = (b + 0.5) * 2 * M_PI / kPhi;
          // Fiber frame (t, u, v) = (x, z, -y) for axis +x: u is +z made perpendicular to t.
          const double s = std::sin(theta), c = std::cos(theta);
          grid.add_wi(float(s));
          grid.add_wi(float(-c * std::sin(phi)));
          grid.add_wi(float(c * std::cos(phi)));
          grid.mutable_wo()->Add(wos[o].begin(), wos[o].end());
          weight.push_back(c * c * (M_PI / kTheta) * (2 * M_PI / kPhi));  // cos(theta_i) x dw
        }
      }
      EvaluateResponse f;
      ASSERT_TRUE(Call(*stub, grid, &f).ok());
      for (int ch = 0; ch < 3; ++ch) {
        double sum = 0;
        for (size_t q = 0; q < weight.size(); ++q) sum += weight[q] * f.f(3 * q + ch);
        EXPECT_NEAR(served.f(3 * o + ch), sum, 5e-3 * sum + 1e-6) << "wo " << o << " channel " << ch;
        EXPECT_GT(sum, 0.0);
      }
    }
    // The same factors about a per-query axis: +y in the query's frame, with wo turned to match.
    EvaluateRequest turned = ambient;
    turned.clear_wo();
    for (const auto& wo : wos) {
      for (float v : {-wo[1], wo[0], wo[2]}) turned.add_wo(v);  // rotated 90 degrees about z: +x -> +y
      for (float v : {0.f, 1.f, 0.f}) turned.add_fiber_axis(v);
    }
    EvaluateResponse about_axis;
    ASSERT_TRUE(Call(*stub, turned, &about_axis).ok());
    for (int i = 0; i < served.f_size(); ++i) EXPECT_NEAR(about_axis.f(i), served.f(i), 1e-4f * served.f(i) + 1e-6f);
  }

  const auto refused = [&](EvaluateRequest r, const std::string& field) {
    EvaluateResponse resp;
    const grpc::Status s = Call(*stub, r, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_EQ(s.error_message().rfind(field, 0), 0u) << s.error_message();
  };
  EvaluateRequest with_wi = Request("fleece", 2, 1);
  with_wi.set_quantity(v1::QUANTITY_AMBIENT);
  refused(with_wi, "wi");
  EvaluateRequest surface = Request("linen_plain", 2, 1);
  surface.clear_wi();
  surface.set_quantity(v1::QUANTITY_AMBIENT);
  refused(surface, "quantity");
  EvaluateRequest curtain = surface;
  curtain.mutable_material()->set_preset("fleece");
  curtain.mutable_material()->mutable_transmission()->set_preset("cotton_curtain");
  refused(curtain, "quantity");
  EvaluateRequest unknown = surface;
  unknown.mutable_material()->set_preset("fleece");
  unknown.set_quantity(static_cast<v1::Quantity>(7));
  refused(unknown, "quantity");
}
}  // namespace
}  // namespace loomlight
