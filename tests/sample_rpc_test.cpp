// The Sample RPC in process: for materials of every kind of model (microcylinder, woven with uv, thin layer,
// fiber, a curtain) the samples carry f |cos| / pdf with the f Evaluate returns and the pdf of the server's
// sampler, and their mean weight is the directional albedo Evaluate integrates on a fine grid; the same request
// gives the same bytes, a seed is the same as its explicit random numbers; bad input is refused naming the
// field.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "server/models/direction_sampler.h"
#include "server/models/material_cache.h"
#include "server/models/registry.h"
#include "server/models/rng.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using Dir = std::array<double, 3>;
constexpr double kPi = std::numbers::pi;

Dir Normalized(Dir w) {
  const double l = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  return {w[0] / l, w[1] / l, w[2] / l};
}

v1::Material Preset(const std::string& name, const std::string& layer = "") {
  v1::Material m;
  m.set_preset(name);
  if (!layer.empty()) m.mutable_transmission()->set_preset(layer);
  return m;
}

grpc::Status CallSample(v1::Loomlight::Stub& stub, const v1::SampleRequest& request, v1::SampleResponse* response,
                        double timeout_s = 120) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::microseconds(int64_t(timeout_s * 1e6)));
  return stub.Sample(&context, request, response);
}

grpc::Status CallEvaluate(v1::Loomlight::Stub& stub, const v1::EvaluateRequest& request, v1::EvaluateResponse* response) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  return stub.Evaluate(&context, request, response);
}

// `count` samples at each of `wo` (each with `uv` when given), random numbers from `seed`.
v1::SampleRequest SampleRequest(const v1::Material& material, const std::vector<Dir>& wo, int count, uint64_t seed,
                                const std::vector<float>& uv = {}) {
  v1::SampleRequest r;
  *r.mutable_material() = material;
  r.set_seed(seed);
  for (const Dir& w : wo)
    for (int k = 0; k < count; ++k) {
      for (double c : w) r.add_wo(float(c));
      for (float c : uv) r.add_uv(c);
    }
  return r;
}

// The sampler the server builds for `material` (the same code and table, built here again).
std::shared_ptr<const models::PreparedMaterial> Prepared(const v1::Material& material) {
  static models::MaterialCache cache(size_t{256} << 20);
  std::shared_ptr<const models::PreparedMaterial> out;
  EXPECT_EQ(cache.Get(material, models::Registry::Global(), &out), "");
  return out;
}

class SampleRpcTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = testing::StartInProcessServer().release(); }
  static void TearDownTestSuite() { delete server_; }
  static api::LoomlightServer* server_;
};
api::LoomlightServer* SampleRpcTest::server_ = nullptr;

// The directional albedo integral of f(wi, wo) Cosine(wi) over the sampler's domain of wi, by Evaluate on a
// midpoint grid of nz x nphi cells equal in solid angle, in the sampler's frame (z the normal, or the fiber axis).
std::array<double, 3> Albedo(v1::Loomlight::Stub& stub, const v1::Material& material,
                             const models::DirectionSampler& sampler, bool fiber, const Dir& axis, const Dir& wo,
                             const std::vector<float>& uv, int nz, int nphi) {
  // A frame with `axis` as z.
  const Dir helper = std::fabs(axis[0]) < 0.9 ? Dir{1, 0, 0} : Dir{0, 1, 0};
  const double d = helper[0] * axis[0] + helper[1] * axis[1] + helper[2] * axis[2];
  const Dir t = Normalized({helper[0] - d * axis[0], helper[1] - d * axis[1], helper[2] - d * axis[2]});
  const Dir b = {axis[1] * t[2] - axis[2] * t[1], axis[2] * t[0] - axis[0] * t[2], axis[0] * t[1] - axis[1] * t[0]};
  double z_min = 0, z_max = 1;
  if (fiber || sampler.sphere()) z_min = -1;
  else if (wo[2] < 0) z_min = -1, z_max = 0;  // wo's hemisphere (two-sided cloth)
  const double dz = (z_max - z_min) / nz, dphi = 2 * kPi / nphi;
  v1::EvaluateRequest request;
  *request.mutable_material() = material;
  std::vector<double> weights;
  for (int i = 0; i < nz; ++i)
    for (int j = 0; j < nphi; ++j) {
      const double z = z_min + (i + 0.5) * dz, phi = (j + 0.5) * dphi, r = std::sqrt(1 - z * z);
      const double x = r * std::cos(phi), y = r * std::sin(phi);
      const Dir wi = {x * t[0] + y * b[0] + z * axis[0], x * t[1] + y * b[1] + z * axis[1],
                      x * t[2] + y * b[2] + z * axis[2]};
      for (double c : wi) request.add_wi(float(c));
      for (double c : wo) request.add_wo(float(c));
      for (float c : uv) request.add_uv(c);
      weights.push_back(sampler.Cosine(wi) * dz * dphi);
    }
  v1::EvaluateResponse response;
  EXPECT_TRUE(CallEvaluate(stub, request, &response).ok());
  std::array<double, 3> sum = {0, 0, 0};
  if (response.f_size() != 3 * int(weights.size())) return sum;
  for (size_t q = 0; q < weights.size(); ++q)
    for (int c = 0; c < 3; ++c) sum[c] += response.f(3 * q + c) * weights[q];
  return sum;
}

struct Case {
  std::string label;
  v1::Material material;
  std::vector<float> uv;  // every query's (u, v), or none
};

TEST_F(SampleRpcTest, WeightsCarryEvaluatesFAndAverageToTheAlbedo) {
  auto stub = testing::Connect(server_->port());
  const std::vector<Case> cases = {
      {"microcylinder satin", Preset("polyester_satin_charmeuse_front"), {}},
      {"woven twill at uv", Preset("cotton_twill"), {0.3f, 0.7f}},
      {"thin layer", Preset("sheer_voile"), {}},
      {"fiber", Preset("cotton"), {}},
      {"curtain", Preset("cotton_twill", "cotton_curtain"), {}},
  };
  const std::vector<Dir> wos = {Normalized({0.2, 0.1, 0.95}), Normalized({0.6, -0.45, 0.55}),
                                Normalized({-0.3, 0.5, -0.7})};  // the last below the surface
  constexpr int kCount = 200000;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.label);
    const auto prepared = Prepared(c.material);
    ASSERT_NE(prepared, nullptr);
    const models::DirectionSampler& sampler = prepared->Sampler();
    const bool fiber = models::DirectionSampler::Fiber(*prepared->model);
    Dir axis = {0, 0, 1};
    if (fiber) {
      const auto& a = prepared->values.at(prepared->model->fiber_axis_param());
      axis = Normalized({a[0], a[1], a[2]});
    }

    const v1::SampleRequest request = SampleRequest(c.material, wos, kCount, 7, c.uv);
    v1::SampleResponse response;
    const grpc::Status status = CallSample(*stub, request, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
    const int n = request.wo_size() / 3;
    ASSERT_EQ(response.wi_size(), 3 * n);
    ASSERT_EQ(response.pdf_size(), n);
    ASSERT_EQ(response.weight_size(), 3 * n);
    ASSERT_EQ(response.f_size(), 3 * n);
    EXPECT_EQ(response.model(), prepared->model->name());

    // f is what Evaluate returns for the same pairs.
    v1::EvaluateRequest eval;
    *eval.mutable_material() = c.material;
    *eval.mutable_wi() = response.wi();
    *eval.mutable_wo() = request.wo();
    *eval.mutable_uv() = request.uv();
    v1::EvaluateResponse evaluated;
    ASSERT_TRUE(CallEvaluate(*stub, eval, &evaluated).ok());
    ASSERT_EQ(evaluated.f_size(), 3 * n);

    int f_mismatch = 0, weight_mismatch = 0, pdf_mismatch = 0, side_mismatch = 0, not_finite = 0;
    for (int q = 0; q < n; ++q) {
      const Dir wi = {response.wi(3 * q), response.wi(3 * q + 1), response.wi(3 * q + 2)};
      const Dir wo = {request.wo(3 * q), request.wo(3 * q + 1), request.wo(3 * q + 2)};
      const double pdf = response.pdf(q);
      if (!std::isfinite(pdf) || !(pdf > 0)) ++not_finite;
      if (std::fabs(std::sqrt(wi[0] * wi[0] + wi[1] * wi[1] + wi[2] * wi[2]) - 1) > 1e-6) ++not_finite;
      if (!fiber && !sampler.sphere() && wi[2] * wo[2] < 0) ++side_mismatch;  // wo's hemisphere
      // The server's sampler density at the returned pair (a float-rounded wi may cross a cell edge: rare).
      const double expected_pdf = sampler.Pdf(wo, wi);
      if (std::fabs(pdf - expected_pdf) > 1e-5 * expected_pdf) ++pdf_mismatch;
      const double cosine = sampler.Cosine(wi);
      for (int ch = 0; ch < 3; ++ch) {
        const double f = response.f(3 * q + ch), w = response.weight(3 * q + ch);
        if (!std::isfinite(f) || !std::isfinite(w) || w < 0) ++not_finite;
        if (std::fabs(f - evaluated.f(3 * q + ch)) > 1e-6 * std::fabs(f) + 1e-30) ++f_mismatch;
        // weight * pdf / cos is f (float rounding of weight and pdf).
        if (std::fabs(w * pdf - f * cosine) > 1e-5 * f * cosine + 1e-30) ++weight_mismatch;
      }
    }
    EXPECT_EQ(not_finite, 0);
    EXPECT_EQ(side_mismatch, 0);
    EXPECT_EQ(f_mismatch, 0);
    EXPECT_EQ(weight_mismatch, 0);
    EXPECT_LE(pdf_mismatch, n / 10000) << "of " << n;

    // The mean weight per wo is the directional albedo (Evaluate on a fine grid), within 4 standard errors
    // and the grid's own error (estimated from a grid half as fine in each direction).
    for (size_t k = 0; k < wos.size(); ++k) {
      const Dir wo = {request.wo(3 * k * kCount), request.wo(3 * k * kCount + 1), request.wo(3 * k * kCount + 2)};
      const auto fine = Albedo(*stub, c.material, sampler, fiber, axis, wo, c.uv, 1024, 1024);
      const auto coarse = Albedo(*stub, c.material, sampler, fiber, axis, wo, c.uv, 512, 512);
      for (int ch = 0; ch < 3; ++ch) {
        double sum = 0, squares = 0;
        for (size_t q = k * kCount; q < (k + 1) * kCount; ++q) {
          const double w = response.weight(3 * q + ch);
          sum += w;
          squares += w * w;
        }
        const double mean = sum / kCount;
        const double se = std::sqrt(std::max(0.0, squares / kCount - mean * mean) / (kCount - 1));
        const double grid_error = std::fabs(fine[ch] - coarse[ch]);
        std::printf("  %-20s wo %zu ch %d: mean weight %.5f +- %.5f, albedo %.5f (grid %.5f), diff %.2f se\n",
                    c.label.c_str(), k, ch, mean, se, fine[ch], coarse[ch], (mean - fine[ch]) / std::max(se, 1e-12));
        EXPECT_NEAR(mean, fine[ch], 4 * se + grid_error + 1e-3 * fine[ch]) << "wo " << k << " channel " << ch;
      }
    }
  }
}

TEST_F(SampleRpcTest, SameRequestSameBytesAndSeedEqualsItsRandomNumbers) {
  auto stub = testing::Connect(server_->port());
  const std::vector<Dir> wos = {Normalized({0.1, 0.2, 0.9}), Normalized({0.7, 0.0, 0.3})};
  for (const v1::Material& material : {Preset("velvet"), Preset("cotton_plain")}) {
    const v1::SampleRequest request = SampleRequest(material, wos, 500, 12345);
    v1::SampleResponse a, b;
    ASSERT_TRUE(CallSample(*stub, request, &a).ok());
    ASSERT_TRUE(CallSample(*stub, request, &b).ok());
    const auto bytes = [](const v1::SampleResponse& r) {
      v1::SampleResponse samples;
      *samples.mutable_wi() = r.wi();
      *samples.mutable_pdf() = r.pdf();
      *samples.mutable_weight() = r.weight();
      *samples.mutable_f() = r.f();
      return samples.SerializeAsString();
    };
    EXPECT_EQ(bytes(a), bytes(b));

    // The seed's numbers (CounterRng rounded to float below 1), sent explicitly: the same bytes.
    v1::SampleRequest explicit_random = request;
    explicit_random.set_seed(99);  // ignored when random numbers are given
    const int n = request.wo_size() / 3;
    for (int q = 0; q < n; ++q) {
      const models::CounterRng rng(request.seed(), uint64_t(q));
      for (int d = 0; d < 3; ++d) explicit_random.add_random(std::min(float(rng.Uniform(d)), 0x1.fffffep-1f));
    }
    v1::SampleResponse c;
    ASSERT_TRUE(CallSample(*stub, explicit_random, &c).ok());
    EXPECT_EQ(bytes(a), bytes(c)) << material.preset();

    v1::SampleRequest other_seed = request;
    other_seed.set_seed(request.seed() + 1);
    v1::SampleResponse e;
    ASSERT_TRUE(CallSample(*stub, other_seed, &e).ok());
    EXPECT_NE(bytes(a), bytes(e));
  }
}

TEST_F(SampleRpcTest, ExplicitRandomNumbersPickTheDirection) {
  // u0 < 0.1 picks the cosine component: (u1, u2) = (0.25, 0) is cos theta = sqrt(0.25), phi = 0 for a surface.
  auto stub = testing::Connect(server_->port());
  v1::SampleRequest request = SampleRequest(Preset("linen_plain"), {Normalized({0.3, 0.1, 0.9})}, 1, 0);
  request.add_random(0.05f);
  request.add_random(0.25f);
  request.add_random(0.0f);
  v1::SampleResponse response;
  ASSERT_TRUE(CallSample(*stub, request, &response).ok());
  EXPECT_NEAR(response.wi(0), std::sqrt(0.75), 1e-6);
  EXPECT_NEAR(response.wi(1), 0.0, 1e-6);
  EXPECT_NEAR(response.wi(2), 0.5, 1e-6);
  // Below the surface the same numbers give the mirrored direction, with the same pdf.
  const float pdf = response.pdf(0);
  request.set_wo(2, -request.wo(2));
  ASSERT_TRUE(CallSample(*stub, request, &response).ok());
  EXPECT_NEAR(response.wi(0), std::sqrt(0.75), 1e-6);
  EXPECT_NEAR(response.wi(2), -0.5, 1e-6);
  EXPECT_FLOAT_EQ(response.pdf(0), pdf);
}

TEST_F(SampleRpcTest, BadInputIsRefusedNamingTheField) {
  auto stub = testing::Connect(server_->port());
  const auto base = [] { return SampleRequest(Preset("velvet"), {{0, 0, 1}, {0.6, 0, 0.8}}, 2, 1); };
  struct Bad {
    std::function<void(v1::SampleRequest&)> change;
    std::string message;  // the status message starts with this
  };
  const std::vector<Bad> bad = {
      {[](auto& r) { r.clear_wo(); }, "wo: no directions"},
      {[](auto& r) { r.add_wo(0.5f); }, "wo: length 13 is not a multiple of 3"},
      {[](auto& r) { r.set_wo(4, 0.9f); }, "wo[1]: direction has length"},
      {[](auto& r) { r.set_wo(0, std::nanf("")); }, "wo[0]: direction is not finite"},
      {[](auto& r) {
         for (int i = 0; i < 11; ++i) r.add_random(0.5f);
       },
       "random: length 11 is not 3 per query (12 for 4 queries)"},
      {[](auto& r) {
         for (int i = 0; i < 12; ++i) r.add_random(i == 7 ? 1.5f : 0.5f);
       },
       "random[7]: 1.5 is outside [0, 1)"},
      {[](auto& r) {
         for (int i = 0; i < 12; ++i) r.add_random(i == 0 ? -0.25f : 0.5f);
       },
       "random[0]: -0.25 is outside [0, 1)"},
      {[](auto& r) {
         for (int i = 0; i < 12; ++i) r.add_random(i == 11 ? 1.0f : 0.5f);
       },
       "random[11]: 1 is outside [0, 1)"},
      {[](auto& r) {
         for (int i = 0; i < 12; ++i) r.add_random(i == 3 ? std::nanf("") : 0.5f);
       },
       "random[3]: nan is outside [0, 1)"},
      {[](auto& r) {
         for (int i = 0; i < 8; ++i) r.add_uv(0.5f);
       },
       "uv: model 'microcylinder' is not spatially varying; send no uv"},
      {[](auto& r) {
         r.mutable_material()->set_preset("cotton_twill");
         for (int i = 0; i < 6; ++i) r.add_uv(0.5f);
       },
       "uv: length 6 is not 2 per query"},
      {[](auto& r) {
         r.mutable_material()->set_preset("cotton_twill");
         for (int i = 0; i < 8; ++i) r.add_uv(i == 3 ? 5000.0f : 0.5f);
       },
       "uv[3]:"},
      {[](auto& r) { r.mutable_material()->set_preset("burlap"); }, "material"},
      {[](auto& r) { r.set_precision(static_cast<v1::Precision>(7)); }, "precision: unknown value 7"},
      {[](auto& r) { r.set_error_target(-1); }, "error_target:"},
      {[](auto& r) { r.set_error_target(std::nan("")); }, "error_target:"},
      {[](auto& r) {
         r.clear_wo();
         for (size_t q = 0; q <= api::kMaxQueriesPerCall; ++q) {
           r.add_wo(0);
           r.add_wo(0);
           r.add_wo(1);
         }
       },
       "wo: 1048577 queries exceed the limit of 1048576 per call"},
  };
  for (const Bad& b : bad) {
    v1::SampleRequest request = base();
    b.change(request);
    v1::SampleResponse response;
    const grpc::Status status = CallSample(*stub, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << b.message << ": " << status.error_message();
    EXPECT_EQ(status.error_message().rfind(b.message, 0), 0u) << status.error_message();
    EXPECT_EQ(response.pdf_size(), 0);
  }
  // uv on a woven material is fine, and error_target too.
  v1::SampleRequest woven = SampleRequest(Preset("cotton_twill"), {{0, 0, 1}}, 3, 1, {0.25f, 0.5f});
  woven.set_error_target(0.05);
  v1::SampleResponse response;
  const grpc::Status status = CallSample(*stub, woven, &response);
  EXPECT_TRUE(status.ok()) << status.error_message();
}

TEST_F(SampleRpcTest, DeadlineStopsTheCallAndTheServerCarriesOn) {
  auto stub = testing::Connect(server_->port());
  // A material not seen before (its table takes tens of milliseconds) and many queries, with 5 ms to run.
  v1::Material material = Preset("silk_shot");
  auto* p = material.add_params();
  p->set_name("eta");
  p->add_values(1.41);
  const v1::SampleRequest request = SampleRequest(material, {{0, 0.6, 0.8}}, 1 << 19, 3);
  v1::SampleResponse response;
  EXPECT_EQ(CallSample(*stub, request, &response, 0.005).error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  const v1::SampleRequest small = SampleRequest(material, {{0, 0.6, 0.8}}, 10, 3);
  EXPECT_TRUE(CallSample(*stub, small, &response).ok());
  EXPECT_EQ(response.pdf_size(), 10);
}

TEST_F(SampleRpcTest, ClientPrintsSamplesAndMeans) {
  std::string output;
  ASSERT_EQ(testing::RunClient(server_->port(),
                               "sample --preset cotton_twill --wo 0,0.5,0.866 --count 50 --seed 1 --uv 0.2,0.4",
                               &output),
            0)
      << output;
  EXPECT_EQ(output.rfind("wox,woy,woz,wix,wiy,wiz,pdf,weight_r,weight_g,weight_b,f_r,f_g,f_b\n", 0), 0u) << output;
  EXPECT_EQ(std::count(output.begin(), output.end(), '\n'), 51);
  const std::string path = ::testing::TempDir() + "/sample_rpc_test.csv";
  ASSERT_EQ(testing::RunClient(server_->port(),
                               "sample --preset velvet --wo-deg 30,0 --wo-deg 60,90 --count 200 --out " + path, &output),
            0)
      << output;
  EXPECT_NE(output.find("200 samples, mean weight"), std::string::npos) << output;
  EXPECT_EQ(std::count(output.begin(), output.end(), '\n'), 2) << output;
  EXPECT_NE(testing::RunClient(server_->port(), "sample --preset velvet --count 3", &output), 0);
}

TEST(SampleMetrics, CallsAndQueriesAreCounted) {
  api::ServerOptions options;
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  v1::SampleResponse response;
  ASSERT_TRUE(CallSample(*stub, SampleRequest(Preset("velvet"), {{0, 0, 1}}, 37, 1), &response).ok());
  EXPECT_GT(response.sampling_seconds(), 0);
  EXPECT_GE(response.total_seconds(), response.sampling_seconds());
  EXPECT_GE(response.batch_queries(), 37u);
  EXPECT_EQ(CallSample(*stub, SampleRequest(Preset("burlap"), {{0, 0, 1}}, 1, 1), &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
  EXPECT_NE(text.find("loomlight_calls_total{code=\"OK\",rpc=\"Sample\"} 1"), std::string::npos) << text;
  EXPECT_NE(text.find("loomlight_calls_total{code=\"INVALID_ARGUMENT\",rpc=\"Sample\"} 1"), std::string::npos);
  EXPECT_NE(text.find("loomlight_queries_total{model=\"microcylinder\",precision=\"fp32\"} 37"), std::string::npos);
}

}  // namespace
}  // namespace loomlight
