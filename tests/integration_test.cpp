// End to end: the real loomlight-server binary on a loopback port, concurrent clients with different
// materials, every answer checked against direct evaluation; and the loomlight client's commands.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cstdio>
#include <fstream>
#include <sstream>
#include <thread>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "server/models/material.h"
#include "tests/testing.h"

// After the protobuf headers: OpenImageIO's byte-swap macros clash with protobuf's port.h.
#include <OpenImageIO/imageio.h>

namespace loomlight {
namespace {

class Integration : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = new testing::ServerProcess(); }
  static void TearDownTestSuite() { delete server_; }
  static testing::ServerProcess* server_;
};
testing::ServerProcess* Integration::server_ = nullptr;

TEST_F(Integration, ServerStartsWarmAndReportsServing) {
  ASSERT_GT(server_->port(), 0);
  ASSERT_TRUE(server_->running());
  auto health = grpc::health::v1::Health::NewStub(grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  grpc::health::v1::HealthCheckRequest req;
  grpc::health::v1::HealthCheckResponse resp;
  ASSERT_TRUE(health->Check(&ctx, req, &resp).ok());
  EXPECT_EQ(resp.status(), grpc::health::v1::HealthCheckResponse::SERVING);
}

// A material per client: presets, overrides and another tangent sample count (its own launches).
v1::Material ClientMaterial(int client) {
  v1::Material m;
  const auto& presets = models::Registry::Global().FindModel("microcylinder")->presets();
  m.set_preset(presets[client % presets.size()].name);
  if (client % 3 == 1) {
    auto* p = m.add_params();
    p->set_name("thread1.albedo");
    p->add_values(0.05 * (client % 7));
    p->add_values(0.5);
    p->add_values(0.9);
  }
  if (client % 4 == 3) {
    auto* p = m.add_params();
    p->set_name("tangent_samples");
    p->add_values(16);
  }
  return m;
}

TEST_F(Integration, ConcurrentClientsGetExactlyTheDirectEvaluation) {
  constexpr int kClients = 12, kCalls = 5;
  std::vector<std::vector<v1::EvaluateRequest>> requests(kClients);
  std::vector<std::vector<v1::EvaluateResponse>> responses(kClients, std::vector<v1::EvaluateResponse>(kCalls));
  std::vector<std::vector<grpc::Status>> status(kClients, std::vector<grpc::Status>(kCalls));
  for (int c = 0; c < kClients; ++c) {
    for (int k = 0; k < kCalls; ++k) {
      v1::EvaluateRequest r;
      *r.mutable_material() = ClientMaterial(c);
      const accuracy::Pairs p = accuracy::RandomPairs(1 + (c * 977 + k * 313) % 4000, c * kCalls + k);
      r.mutable_wi()->Add(p.wi.begin(), p.wi.end());
      r.mutable_wo()->Add(p.wo.begin(), p.wo.end());
      requests[c].push_back(r);
    }
  }
  std::vector<std::thread> threads;
  for (int c = 0; c < kClients; ++c)
    threads.emplace_back([&, c] {
      auto stub = v1::Loomlight::NewStub(grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
      for (int k = 0; k < kCalls; ++k) {
        grpc::ClientContext ctx;
        status[c][k] = stub->Evaluate(&ctx, requests[c][k], &responses[c][k]);
      }
    });
  for (auto& t : threads) t.join();

  int coalesced = 0;
  for (int c = 0; c < kClients; ++c)
    for (int k = 0; k < kCalls; ++k) {
      ASSERT_TRUE(status[c][k].ok()) << status[c][k].error_message();
      const v1::EvaluateRequest& r = requests[c][k];
      models::ResolvedMaterial m;
      ASSERT_EQ(models::ResolveMaterial(r.material(), models::Registry::Global(), &m), "");
      const std::vector<float> wi(r.wi().begin(), r.wi().end()), wo(r.wo().begin(), r.wo().end());
      const std::vector<double> direct = testing::RunKernel(*m.model, m.model->Pack(m.values), false, wi, wo);
      ASSERT_EQ(responses[c][k].f_size(), int(direct.size()));
      for (size_t i = 0; i < direct.size(); ++i)
        ASSERT_EQ(responses[c][k].f(int(i)), static_cast<float>(direct[i])) << "client " << c << " call " << k << " value " << i;
      if (responses[c][k].batch_requests() > 1) ++coalesced;
    }
  std::printf("%d of %d calls shared a launch with other requests\n", coalesced, kClients * kCalls);
  EXPECT_TRUE(server_->running());
}

// Runs the client binary against the test server; returns its exit code, with stdout and stderr in *output.
int RunClient(const std::string& address, const std::string& args, std::string* output) {
  const std::string cmd = std::string(LOOMLIGHT_CLIENT_BINARY) + " --server " + address + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  char buf[4096];
  output->clear();
  while (p && std::fgets(buf, sizeof buf, p)) *output += buf;
  const int status = p ? pclose(p) : -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST_F(Integration, ClientEvalPrintsCsvEqualToDirectEvaluation) {
  std::string out;
  ASSERT_EQ(RunClient(server_->address(), "eval --preset velvet --wi 0,0,1 --wo 0.6,0,0.8 --wi-deg 60,30 --wo-deg 45,200", &out), 0) << out;
  std::istringstream lines(out);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "wix,wiy,wiz,wox,woy,woz,r,g,b");
  std::vector<float> wi, wo;
  std::vector<double> rgb;
  while (std::getline(lines, line)) {
    std::vector<double> v;
    std::istringstream cells(line);
    for (std::string cell; std::getline(cells, cell, ',');) v.push_back(std::stod(cell));
    ASSERT_EQ(v.size(), 9u) << line;
    wi.insert(wi.end(), {float(v[0]), float(v[1]), float(v[2])});
    wo.insert(wo.end(), {float(v[3]), float(v[4]), float(v[5])});
    rgb.insert(rgb.end(), {v[6], v[7], v[8]});
  }
  ASSERT_EQ(rgb.size(), 6u);
  const models::PresetSpec* preset = nullptr;
  const models::Model* model = models::Registry::Global().FindPreset("velvet", &preset);
  const std::vector<double> direct = testing::RunKernel(*model, model->Pack(model->PresetValues(*preset)), false, wi, wo);
  for (size_t i = 0; i < rgb.size(); ++i) EXPECT_NEAR(rgb[i], direct[i], 1e-6 * direct[i]) << i;
  EXPECT_GT(rgb[0], 0.0);
}

TEST_F(Integration, ClientReportsServerErrorsWithNonZeroExit) {
  std::string out;
  EXPECT_EQ(RunClient(server_->address(), "eval --preset burlap --wi 0,0,1 --wo 0,0,1", &out), 1);
  EXPECT_NE(out.find("INVALID_ARGUMENT"), std::string::npos) << out;
  EXPECT_NE(out.find("material.preset"), std::string::npos) << out;
  EXPECT_EQ(RunClient(server_->address(), "eval --preset velvet --wi 0,0,2 --wo 0,0,1", &out), 1);
  EXPECT_NE(out.find("wi[0]"), std::string::npos) << out;
}

TEST_F(Integration, ClientPlotWritesAPolarLobePng) {
  const std::string path = ::testing::TempDir() + "/lobe.png";
  std::remove(path.c_str());
  std::string out;
  ASSERT_EQ(RunClient(server_->address(), "plot --preset polyester_satin_charmeuse_front --incidence 0,30,60 --size 640 --out " + path, &out), 0) << out;
  auto in = OIIO::ImageInput::open(path);
  ASSERT_TRUE(in) << OIIO::geterror();
  const OIIO::ImageSpec& spec = in->spec();
  EXPECT_EQ(spec.width, 640);
  EXPECT_GT(spec.height, 200);
  std::vector<unsigned char> pixels(size_t(spec.width) * spec.height * spec.nchannels);
  ASSERT_TRUE(in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::UINT8, pixels.data()));
  // Curves were drawn: a good share of pixels is not the white background.
  size_t coloured = 0;
  for (size_t p = 0; p < pixels.size(); p += spec.nchannels)
    if (pixels[p] < 200 || pixels[p + 1] < 200 || pixels[p + 2] < 200) ++coloured;
  EXPECT_GT(coloured, pixels.size() / spec.nchannels / 200);
}

}  // namespace
}  // namespace loomlight
