// End to end: the real loomlight-server binary on a loopback port, concurrent clients with different
// materials, every answer checked against direct evaluation; and the loomlight client's commands.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
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

TEST_F(Integration, ClientEvalPrintsCsvEqualToDirectEvaluation) {
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->address(), "eval --preset velvet --wi 0,0,1 --wo 0.6,0,0.8 --wi-deg 60,30 --wo-deg 45,200", &out), 0) << out;
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
  EXPECT_EQ(testing::RunClient(server_->address(), "eval --preset burlap --wi 0,0,1 --wo 0,0,1", &out), 1);
  EXPECT_NE(out.find("INVALID_ARGUMENT"), std::string::npos) << out;
  EXPECT_NE(out.find("material.preset"), std::string::npos) << out;
  EXPECT_EQ(testing::RunClient(server_->address(), "eval --preset velvet --wi 0,0,2 --wo 0,0,1", &out), 1);
  EXPECT_NE(out.find("wi[0]"), std::string::npos) << out;
}

// A PNG the client wrote: its size and how many pixels are not the white background.
struct PlotImage {
  int width = 0, height = 0;
  size_t coloured = 0;
};

::testing::AssertionResult ReadPlot(const std::string& path, PlotImage* image) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) return ::testing::AssertionFailure() << "cannot open " << path << ": " << OIIO::geterror();
  const OIIO::ImageSpec& spec = in->spec();
  std::vector<unsigned char> pixels(size_t(spec.width) * spec.height * spec.nchannels);
  if (spec.nchannels < 3 || !in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::UINT8, pixels.data()))
    return ::testing::AssertionFailure() << "cannot read " << path << ": " << in->geterror();
  *image = {spec.width, spec.height, 0};
  for (size_t p = 0; p < pixels.size(); p += spec.nchannels)
    if (pixels[p] < 200 || pixels[p + 1] < 200 || pixels[p + 2] < 200) ++image->coloured;
  return ::testing::AssertionSuccess();
}

// Curves were drawn: a good share of pixels is not the white background.
void ExpectCurvesDrawn(const PlotImage& image) {
  EXPECT_GT(image.coloured, size_t(image.width) * image.height / 200);
}

TEST_F(Integration, ClientPlotWritesAPolarLobePng) {
  const std::string path = ::testing::TempDir() + "/lobe.png";
  std::remove(path.c_str());
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->address(), "plot --preset polyester_satin_charmeuse_front --incidence 0,30,60 --size 640 --out " + path, &out), 0) << out;
  PlotImage image;
  ASSERT_TRUE(ReadPlot(path, &image));
  EXPECT_EQ(image.width, 640);
  EXPECT_GT(image.height, 200);
  ExpectCurvesDrawn(image);
}

// A shell command's exit status and output (stdout and stderr).
int RunShell(const std::string& command, std::string* output) {
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  output->clear();
  char buffer[4096];
  while (pipe && std::fgets(buffer, sizeof buffer, pipe)) *output += buffer;
  const int status = pipe ? pclose(pipe) : -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// OpenImageIO (some 300 shared libraries, ~0.5 s of loading) is not loaded when the CLI starts: only its image
// module links it (client/image_module.h). LD_TRACE_LOADED_OBJECTS makes the dynamic loader list what it loads.
TEST(Client, StartsWithoutLoadingOpenImageIO) {
  std::string out;
  ASSERT_EQ(RunShell(std::string("LD_TRACE_LOADED_OBJECTS=1 ") + LOOMLIGHT_CLIENT_BINARY, &out), 0) << out;
  EXPECT_NE(out.find("libgrpc++"), std::string::npos) << out;  // the listing is the client's
  EXPECT_EQ(out.find("OpenImageIO"), std::string::npos) << out;
}

// A client copied without its image module still runs commands that need no image, and a plot fails with an
// error naming the module it looked for; beside a module of another interface version, likewise.
TEST_F(Integration, ClientWithoutItsImageModuleSaysWhichFileAPlotNeeds) {
  const std::string dir = ::testing::TempDir() + "/client_alone";
  std::string out;
  ASSERT_EQ(RunShell("rm -rf " + dir + " && mkdir -p " + dir + " && cp " + LOOMLIGHT_CLIENT_BINARY + " " + dir, &out), 0)
      << out;
  const std::string client = dir + "/loomlight --server " + server_->address() + " ";
  EXPECT_EQ(RunShell(client + "health", &out), 0) << out;
  EXPECT_EQ(RunShell(client + "plot --preset velvet --size 200 --out " + dir + "/lobe.png", &out), 1) << out;
  EXPECT_NE(out.find("client_alone/libloomlight_images.so"), std::string::npos) << out;
  EXPECT_NE(out.find("cannot be loaded"), std::string::npos) << out;
  EXPECT_FALSE(std::ifstream(dir + "/lobe.png").good());
  // A module of another interface version beside it is refused by its entry's name, not called.
  ASSERT_EQ(RunShell(std::string("cp ") + STALE_IMAGE_MODULE + " " + dir + "/libloomlight_images.so", &out), 0) << out;
  EXPECT_EQ(RunShell(client + "plot --preset velvet --size 200 --out " + dir + "/lobe.png", &out), 1) << out;
  EXPECT_NE(out.find("is not this client's image module (no loomlight_image_module_v1)"), std::string::npos) << out;
  EXPECT_FALSE(std::ifstream(dir + "/lobe.png").good());
}

// `models` lists the procedural yarn's parameters after the models, and `render --yarn-param` sends them: a
// bad value comes back naming its field, a good one renders.
TEST_F(Integration, ClientListsAndSetsYarnParameters) {
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->address(), "models", &out), 0) << out;
  const size_t yarn = out.find("\nyarn (fiber scenes");
  ASSERT_NE(yarn, std::string::npos) << out;
  EXPECT_NE(out.find("fibers_per_ply", yarn), std::string::npos) << out;
  EXPECT_NE(out.find("cotton1", yarn), std::string::npos) << out;
  const std::string path = ::testing::TempDir() + "/yarn_param.exr";
  const std::string render = "render --preset cotton --scene yarn --size 32x16 --spp 1 --out " + path;
  EXPECT_EQ(testing::RunClient(server_->address(), render + " --yarn-param fibers_per_ply=0", &out), 1) << out;
  EXPECT_NE(out.find("yarn.fibers_per_ply"), std::string::npos) << out;
  EXPECT_EQ(testing::RunClient(server_->address(), render + " --yarn cotton2 --yarn-param fibers_per_ply=40", &out), 0)
      << out;
  EXPECT_NE(out.find("fiber curves"), std::string::npos) << out;
}

// The "LOBE,THETA_I,ANGLE,VALUE" lines of `plot` (full circle, fiber), by lobe name.
struct Peak {
  double theta_i, angle, value;
};
std::map<std::string, std::vector<Peak>> ParsePeaks(const std::string& out) {
  std::map<std::string, std::vector<Peak>> peaks;
  std::istringstream lines(out);
  for (std::string line; std::getline(lines, line);) {
    std::vector<std::string> cells;
    std::istringstream row(line);
    for (std::string cell; std::getline(row, cell, ',');) cells.push_back(cell);
    if (cells.size() == 4) peaks[cells[0]].push_back({std::stod(cells[1]), std::stod(cells[2]), std::stod(cells[3])});
  }
  return peaks;
}

constexpr double kRadiansPerDegree = M_PI / 180.0;

// Luminance of f(wi, wo) from the fp32 kernel, as the client plots it (before its cosine factor).
double DirectLuminance(const models::Model& model, const models::ParamValues& values, const std::vector<float>& wi,
                       const std::vector<float>& wo) {
  const std::vector<double> f = testing::RunKernel(model, model.Pack(values), false, wi, wo);
  return 0.2126 * f[0] + 0.7152 * f[1] + 0.0722 * f[2];
}

const models::Model& PresetModel(const std::string& name, models::ParamValues* values) {
  const models::PresetSpec* preset = nullptr;
  const models::Model* model = models::Registry::Global().FindPreset(name, &preset);
  EXPECT_NE(model, nullptr) << name;
  *values = model->PresetValues(*preset);
  return *model;
}

// A thin layer plots over the full circle by itself: reflection above, transmission below; each printed peak
// is f |cos theta_o| (luminance) of the plane direction it names, light at -theta_i in the x-z plane.
TEST_F(Integration, ClientPlotOfAThinLayerIsAFullCircleWithTransmissionBelow) {
  const std::string path = ::testing::TempDir() + "/voile.png";
  std::remove(path.c_str());
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->address(), "plot --preset sheer_voile --incidence 0,40 --size 500 --out " + path, &out), 0) << out;
  PlotImage image;
  ASSERT_TRUE(ReadPlot(path, &image));
  EXPECT_EQ(image.width, 500);
  EXPECT_GT(image.height, image.width);  // the whole disc, not the upper half
  ExpectCurvesDrawn(image);

  auto peaks = ParsePeaks(out);
  ASSERT_EQ(peaks["reflection"].size(), 2u) << out;
  ASSERT_EQ(peaks["transmission"].size(), 2u) << out;
  models::ParamValues values;
  const models::Model& model = PresetModel("sheer_voile", &values);
  for (const char* lobe : {"reflection", "transmission"})
    for (const Peak& p : peaks[lobe]) {
      EXPECT_GT(p.value, 0.0) << lobe << " at theta_i " << p.theta_i;
      EXPECT_EQ(std::abs(p.angle) > 90.0, std::string(lobe) == "transmission") << p.angle;
      const double ti = -p.theta_i * kRadiansPerDegree, to = p.angle * kRadiansPerDegree;
      const std::vector<float> wi = {float(std::sin(ti)), 0.0f, float(std::cos(ti))};
      const std::vector<float> wo = {float(std::sin(to)), 0.0f, float(std::cos(to))};
      const double expected = DirectLuminance(model, values, wi, wo) * std::abs(std::cos(to));
      EXPECT_NEAR(p.value, expected, 1e-5 * expected) << lobe << " at theta_i " << p.theta_i << ", theta_o " << p.angle;
    }
}

// A curtain (--layer) also plots the full circle: its transmitted half is the layer's, point for point; the
// reflection material alone, forced onto the full circle, transmits nothing.
TEST_F(Integration, ClientPlotOfACurtainShowsTheLayersTransmission) {
  const std::string dir = ::testing::TempDir();
  std::string curtain, layer, alone;
  ASSERT_EQ(testing::RunClient(server_->address(), "plot --preset linen_plain --layer cotton_curtain --incidence 0,30,60 --size 400 --out " + dir + "/curtain.png", &curtain), 0) << curtain;
  ASSERT_EQ(testing::RunClient(server_->address(), "plot --preset cotton_curtain --incidence 0,30,60 --size 400 --out " + dir + "/layer.png", &layer), 0) << layer;
  ASSERT_EQ(testing::RunClient(server_->address(), "plot --preset linen_plain --full-circle --incidence 0,30,60 --size 400 --out " + dir + "/linen.png", &alone), 0) << alone;
  PlotImage image;
  ASSERT_TRUE(ReadPlot(dir + "/curtain.png", &image));
  EXPECT_EQ(image.width, 400);
  EXPECT_GT(image.height, image.width);
  ExpectCurvesDrawn(image);

  auto with_layer = ParsePeaks(curtain), of_layer = ParsePeaks(layer), without = ParsePeaks(alone);
  ASSERT_EQ(with_layer["transmission"].size(), 3u) << curtain;
  ASSERT_EQ(of_layer["transmission"].size(), 3u) << layer;
  ASSERT_EQ(without["transmission"].size(), 3u) << alone;
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_GT(with_layer["transmission"][i].value, 0.0);
    EXPECT_EQ(with_layer["transmission"][i].value, of_layer["transmission"][i].value) << i;
    EXPECT_EQ(with_layer["transmission"][i].angle, of_layer["transmission"][i].angle) << i;
    EXPECT_EQ(without["transmission"][i].value, 0.0) << i;
    // The layer's direct transmission leaves less light to reflect (docs/models.md "Curtains").
    EXPECT_GT(without["reflection"][i].value, with_layer["reflection"][i].value) << i;
    EXPECT_GT(with_layer["reflection"][i].value, 0.0) << i;
  }
}

// The fiber view: two full-circle panels in one PNG, and each printed peak is f cos^2(theta_o) (luminance) of the
// direction it names in the fiber frame t = axis = +y, u = +z, v = t x u = +x.
TEST_F(Integration, ClientPlotOfAFiberShowsLongitudinalAndAzimuthalLobes) {
  const std::string path = ::testing::TempDir() + "/fleece.png";
  std::remove(path.c_str());
  std::string out;
  ASSERT_EQ(testing::RunClient(server_->address(), "plot --preset fleece --param axis=0,1,0 --incidence 10,30 --size 600 --out " + path, &out), 0) << out;
  PlotImage image;
  ASSERT_TRUE(ReadPlot(path, &image));
  EXPECT_EQ(image.width, 600);
  EXPECT_GT(image.height, 2 * image.width);  // two discs, one above the other
  ExpectCurvesDrawn(image);

  auto peaks = ParsePeaks(out);
  ASSERT_EQ(peaks["longitudinal"].size(), 2u) << out;
  ASSERT_EQ(peaks["azimuthal"].size(), 2u) << out;
  models::ParamValues values;
  const models::Model& model = PresetModel("fleece", &values);
  values["axis"] = {0.0, 1.0, 0.0};
  for (size_t i = 0; i < 2; ++i) {
    const Peak& lon = peaks["longitudinal"][i];
    const Peak& az = peaks["azimuthal"][i];
    const double ti = lon.theta_i * kRadiansPerDegree;
    const std::vector<float> wi = {0.0f, float(std::sin(ti)), float(std::cos(ti))};
    // Longitudinal: wo = sin(a) t + cos(a) u. Fleece's TT outweighs R, so the peak is forward (phi_o = 180),
    // near the straight-through direction a = theta_i - 180 (pulled a few degrees toward the axis by cos^2).
    const double a = lon.angle * kRadiansPerDegree;
    const double lon_expected = DirectLuminance(model, values, wi, {0.0f, float(std::sin(a)), float(std::cos(a))}) *
                                std::cos(a) * std::cos(a);
    EXPECT_NEAR(lon.value, lon_expected, 1e-5 * lon_expected) << "theta_i " << lon.theta_i << ", a " << lon.angle;
    EXPECT_NEAR(lon.angle, lon.theta_i - 180.0, 5.0);
    // Azimuthal: wo = sin(-theta_i) t + cos(theta_i) (cos(phi) u + sin(phi) v); TT peaks forward at phi = 180.
    const double phi = az.angle * kRadiansPerDegree;
    const std::vector<float> wo = {float(std::cos(ti) * std::sin(phi)), float(-std::sin(ti)),
                                   float(std::cos(ti) * std::cos(phi))};
    const double az_expected = DirectLuminance(model, values, wi, wo) * std::cos(ti) * std::cos(ti);
    EXPECT_NEAR(az.value, az_expected, 1e-5 * az_expected) << "theta_i " << az.theta_i << ", phi " << az.angle;
    EXPECT_GT(std::abs(az.angle), 179.0);
    EXPECT_GT(az.value, 0.0);
  }
}

TEST_F(Integration, ClientHealthPrintsServingAndFailsWhereNobodyListens) {
  std::string out;
  EXPECT_EQ(testing::RunClient(server_->address(), "health", &out), 0) << out;
  EXPECT_EQ(out, "SERVING\n");
  EXPECT_EQ(testing::RunClient(server_->address(), "health --service loomlight.v1.Loomlight", &out), 0) << out;
  EXPECT_EQ(out, "SERVING\n");
  EXPECT_EQ(testing::RunClient(server_->address(), "health --service no.such.Service", &out), 1) << out;
  EXPECT_NE(out.find("NOT_FOUND"), std::string::npos) << out;
  const int closed_port = testing::ClosedLoopbackPort();
  ASSERT_GT(closed_port, 0);
  EXPECT_EQ(testing::RunClient(closed_port, "health --timeout 10", &out), 1) << out;
  EXPECT_NE(out.find("error: UNAVAILABLE"), std::string::npos) << out;
  EXPECT_EQ(out.find("SERVING"), std::string::npos) << out;
}

}  // namespace
}  // namespace loomlight
