// TextureSlice end to end against a real server: image formats decode to the requested size, pixels are the
// BTF at their centres (Evaluate with uv), the slice mean over a repeat converges to the BRDF, bytes are
// deterministic, every bad field is named, deadlines and shutdown with a slice in flight; and `loomlight slice`.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <future>
#include <numbers>
#include <thread>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/api/texture_slice.h"
#include "server/imaging/image_encode.h"
#include "server/models/texture_slice.h"
#include "tests/testing.h"

// After the protobuf headers: OpenImageIO's byte-swap macros clash with protobuf's port.h.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace loomlight {
namespace {

using v1::TextureSliceRequest;
using v1::TextureSliceResponse;

constexpr const char* kPreset = "cotton_twill";

std::array<float, 3> Direction(double theta_deg, double phi_deg) {
  const double t = theta_deg * std::numbers::pi / 180, p = phi_deg * std::numbers::pi / 180;
  return {float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(std::cos(t))};
}

// A generic light and view: the specular lobe is well inside both thread types' ellipses, so the image
// has structure at ellipse edges as well as at cell edges.
const std::array<float, 3> kWi = Direction(25, 30), kWo = Direction(35, 200);

TextureSliceRequest Slice(uint32_t width, uint32_t height, uint32_t spp, v1::ImageFormat format) {
  TextureSliceRequest r;
  r.mutable_material()->set_preset(kPreset);
  r.mutable_wi()->Add(kWi.begin(), kWi.end());
  r.mutable_wo()->Add(kWo.begin(), kWo.end());
  r.set_width(width);
  r.set_height(height);
  r.set_samples_per_pixel(spp);
  r.set_format(format);
  return r;
}

void SetRegion(TextureSliceRequest& r, double u_min, double v_min, double u_max, double v_max) {
  r.mutable_region()->set_u_min(u_min);
  r.mutable_region()->set_v_min(v_min);
  r.mutable_region()->set_u_max(u_max);
  r.mutable_region()->set_v_max(v_max);
}

grpc::Status CallSlice(v1::Loomlight::Stub& stub, const TextureSliceRequest& request, TextureSliceResponse* response,
                       std::chrono::milliseconds timeout = std::chrono::seconds(120)) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + timeout);
  return stub.TextureSlice(&ctx, request, response);
}

// f of the preset at the given (wi, wo), and at each uv pair when uv is not empty (Evaluate with uv).
std::vector<float> Evaluate(v1::Loomlight::Stub& stub, const std::vector<float>& uv, size_t n) {
  v1::EvaluateRequest r;
  r.mutable_material()->set_preset(kPreset);
  for (size_t q = 0; q < n; ++q) {
    r.mutable_wi()->Add(kWi.begin(), kWi.end());
    r.mutable_wo()->Add(kWo.begin(), kWo.end());
  }
  r.mutable_uv()->Add(uv.begin(), uv.end());
  grpc::ClientContext ctx;
  v1::EvaluateResponse response;
  const grpc::Status status = stub.Evaluate(&ctx, r, &response);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return {response.f().begin(), response.f().end()};
}

std::vector<float> RawFloats(const std::string& bytes) {
  std::vector<float> v(bytes.size() / 4);
  std::memcpy(v.data(), bytes.data(), 4 * v.size());  // the test machine is little-endian, like the format
  return v;
}

class SliceTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = new testing::ServerProcess(); }
  static void TearDownTestSuite() { delete server_; }
  static testing::ServerProcess* server_;
  std::unique_ptr<v1::Loomlight::Stub> stub_ = testing::Connect(server_->address());
};
testing::ServerProcess* SliceTest::server_ = nullptr;

TEST_F(SliceTest, ExrPixelsAreTheBtfAtPixelCentresWithTopRowAtVMax) {
  // Region and sizes chosen so every pixel centre is exact in binary: the comparison with Evaluate then
  // cannot fall on the other side of a discontinuity through rounding of u or v.
  constexpr int kWidth = 64, kHeight = 32;
  TextureSliceRequest request = Slice(kWidth, kHeight, 1, v1::IMAGE_FORMAT_EXR);
  SetRegion(request, -0.5, 0.25, 1.5, 1.25);
  TextureSliceResponse response;
  const grpc::Status status = CallSlice(*stub_, request, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.format(), v1::IMAGE_FORMAT_EXR);
  EXPECT_EQ(response.queries(), uint64_t(kWidth * kHeight));
  EXPECT_EQ(response.exposure(), 1.0);
  const testing::DecodedImage image = testing::DecodeImage(response.image(), "slice.exr");
  ASSERT_EQ(image.width, kWidth);
  ASSERT_EQ(image.height, kHeight);
  ASSERT_EQ(image.channels, 3);

  std::vector<float> centres, flipped;  // flipped: v growing downwards, which must NOT match
  for (int y = 0; y < kHeight; ++y)
    for (int x = 0; x < kWidth; ++x) {
      const double u = -0.5 + (x + 0.5) / kWidth * 2.0;
      centres.insert(centres.end(), {float(u), float(1.25 - (y + 0.5) / kHeight * 1.0)});
      flipped.insert(flipped.end(), {float(u), float(0.25 + (y + 0.5) / kHeight * 1.0)});
    }
  const std::vector<float> expected = Evaluate(*stub_, centres, kWidth * kHeight);
  const std::vector<float> wrong = Evaluate(*stub_, flipped, kWidth * kHeight);
  ASSERT_EQ(expected.size(), image.pixels.size());
  size_t differs_from_flipped = 0;
  double mean[3] = {0, 0, 0};
  for (size_t i = 0; i < expected.size(); ++i) {
    ASSERT_FLOAT_EQ(image.pixels[i], expected[i]) << "pixel " << i / 3 << " channel " << i % 3;
    if (wrong[i] != expected[i]) ++differs_from_flipped;
    mean[i % 3] += image.pixels[i] / double(kWidth * kHeight);
  }
  EXPECT_GT(differs_from_flipped, expected.size() / 10) << "the test could not tell the orientation apart";
  const auto [lo, hi] = std::minmax_element(image.pixels.begin(), image.pixels.end());
  EXPECT_GT(*hi, 2 * *lo) << "the image has no structure";
  ASSERT_EQ(response.mean_size(), 3);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(response.mean(c), mean[c], 1e-6 * mean[c]);
}

TEST_F(SliceTest, RawIsTheExrPixelsAsLittleEndianFloats) {
  TextureSliceRequest request = Slice(40, 24, 2, v1::IMAGE_FORMAT_RAW);
  TextureSliceResponse raw, exr;
  ASSERT_TRUE(CallSlice(*stub_, request, &raw).ok());
  request.set_format(v1::IMAGE_FORMAT_EXR);
  ASSERT_TRUE(CallSlice(*stub_, request, &exr).ok());
  ASSERT_EQ(raw.image().size(), size_t(40 * 24 * 3 * 4));
  EXPECT_EQ(raw.format(), v1::IMAGE_FORMAT_RAW);
  EXPECT_EQ(raw.queries(), uint64_t(40 * 24 * 2));
  const testing::DecodedImage decoded = testing::DecodeImage(exr.image(), "slice.exr");
  EXPECT_EQ(RawFloats(raw.image()), decoded.pixels);
}

TEST_F(SliceTest, PngIsSrgbOfTheLinearImageTimesTheExposure) {
  TextureSliceRequest request = Slice(48, 36, 1, v1::IMAGE_FORMAT_RAW);
  SetRegion(request, 0.1, 0.2, 1.3, 1.1);
  TextureSliceResponse raw, automatic, manual;
  ASSERT_TRUE(CallSlice(*stub_, request, &raw).ok());
  request.set_format(v1::IMAGE_FORMAT_PNG);
  ASSERT_TRUE(CallSlice(*stub_, request, &automatic).ok());
  request.set_exposure(3.5);
  ASSERT_TRUE(CallSlice(*stub_, request, &manual).ok());
  const std::vector<float> linear = RawFloats(raw.image());

  // Automatic exposure: 1 / the 99th percentile (rank floor(0.99 (N - 1))) of max(r, g, b).
  std::vector<float> brightest;
  for (size_t p = 0; p < linear.size(); p += 3) brightest.push_back(std::max({linear[p], linear[p + 1], linear[p + 2]}));
  std::sort(brightest.begin(), brightest.end());
  const double p99 = brightest[size_t(0.99 * (brightest.size() - 1))];
  ASSERT_GT(p99, 0);
  EXPECT_NEAR(automatic.exposure(), 1 / p99, 1e-9 / p99);
  EXPECT_EQ(manual.exposure(), 3.5);

  for (const TextureSliceResponse* png : {&automatic, &manual}) {
    const testing::DecodedImage decoded = testing::DecodeImage(png->image(), "slice.png");
    ASSERT_EQ(decoded.width, 48);
    ASSERT_EQ(decoded.height, 36);
    ASSERT_EQ(decoded.channels, 3);
    for (size_t i = 0; i < linear.size(); ++i) {
      const double scaled = std::min(1.0, linear[i] * png->exposure());
      const double expected = 255 * (scaled <= 0.0031308 ? 12.92 * scaled : 1.055 * std::pow(scaled, 1 / 2.4) - 0.055);
      ASSERT_NEAR(decoded.pixels[i] * 255, expected, 0.5 + 1e-3) << "value " << i;
    }
  }
}

TEST_F(SliceTest, SameRequestGivesIdenticalBytesAndSamplesChangeThem) {
  const TextureSliceRequest request = Slice(96, 64, 4, v1::IMAGE_FORMAT_PNG);
  TextureSliceResponse first, second, one_sample;
  ASSERT_TRUE(CallSlice(*stub_, request, &first).ok());
  ASSERT_TRUE(CallSlice(*stub_, request, &second).ok());
  EXPECT_EQ(first.image(), second.image());
  TextureSliceRequest centres = request;
  centres.set_samples_per_pixel(1);
  ASSERT_TRUE(CallSlice(*stub_, centres, &one_sample).ok());
  EXPECT_NE(first.image(), one_sample.image());
  EXPECT_EQ(first.queries(), uint64_t(96 * 64 * 4));
}

// Low discrepancy, checked by spacing: N R2 points (rotated or not, on the torus) stay >= 0.62 / sqrt(N)
// apart, where N uniform random points come closer than 0.41 / sqrt(N) (N = 16) in 99% of draws.
double MinTorusDistanceTimesSqrtN(uint64_t pixel, uint32_t samples) {
  std::vector<std::array<double, 2>> points;
  for (uint32_t s = 0; s < samples; ++s) points.push_back(api::PixelSampleOffset(pixel, s, samples));
  double nearest = 1;
  for (size_t i = 0; i < points.size(); ++i)
    for (size_t j = i + 1; j < points.size(); ++j) {
      const double dx = std::fabs(points[i][0] - points[j][0]), dy = std::fabs(points[i][1] - points[j][1]);
      nearest = std::min(nearest, std::hypot(std::min(dx, 1 - dx), std::min(dy, 1 - dy)));
    }
  return nearest * std::sqrt(double(samples));
}

TEST(SliceSamples, OffsetsAreWellSpacedInsideThePixelAndRotatedPerPixel) {
  EXPECT_EQ(api::PixelSampleOffset(7, 0, 1), (std::array<double, 2>{0.5, 0.5}));
  for (uint64_t pixel : {0ull, 1ull, 12345ull, 1ull << 40}) {
    for (uint32_t samples : {2u, 16u, 64u, 256u}) {
      for (uint32_t s = 0; s < samples; ++s) {
        const auto o = api::PixelSampleOffset(pixel, s, samples);
        ASSERT_TRUE(o[0] >= 0 && o[0] < 1 && o[1] >= 0 && o[1] < 1) << pixel << " " << s;
      }
      if (samples >= 16) {
        EXPECT_GT(MinTorusDistanceTimesSqrtN(pixel, samples), 0.6) << pixel << " " << samples;
      }
    }
  }
  // Neighbouring pixels get different rotations of the point set.
  EXPECT_NE(api::PixelSampleOffset(0, 0, 4), api::PixelSampleOffset(1, 0, 4));
  EXPECT_NE(api::PixelSampleOffset(1, 0, 4), api::PixelSampleOffset(2, 0, 4));
}

// A chunk of whole pixels may start anywhere in a row (the server's chunks hold a multiple of the samples, not of
// the width): each query's position is its pixel's corner plus its sample's offset, scaled into the region,
// row 0 at v_max.
TEST(SliceSamples, PositionsOfAChunkStartingMidRowAreEachPixelsSampleOffsetsInTheRegion) {
  const models::SliceSampling slice{.u_min = -0.5, .v_min = 2, .u_max = 1.5, .v_max = 3, .width = 7, .height = 5,
                                    .samples = 3};
  const uint64_t first = 3 * 11;  // pixel 11: x 4 of row 1
  const size_t count = 3 * 9;     // to pixel 19, across the row's end
  std::vector<float> uv(2 * count);
  models::SliceTexturePositions(slice, first, count, uv.data());
  for (size_t i = 0; i < count; ++i) {
    const uint64_t q = first + i, pixel = q / 3;
    const auto o = api::PixelSampleOffset(pixel, q % 3, 3);
    const double x = double(pixel % 7), y = double(pixel / 7);
    EXPECT_EQ(uv[2 * i], float(-0.5 + (x + o[0]) / 7 * 2.0)) << q;
    EXPECT_EQ(uv[2 * i + 1], float(3.0 - (y + o[1]) / 5 * 1.0)) << q;
  }
}

// Each pixel of a chunk is the mean of its samples, in its own place in the image, and adds to the sums; other
// pixels are untouched; a non-finite sample fails the chunk.
TEST(SliceSamples, PixelMeansFillTheirPixelsAndSumsAndANonFiniteSampleIsAnError) {
  imaging::LinearRgbImage image;
  image.width = 4;
  image.height = 1;
  image.rgb.assign(12, -1.0f);
  std::vector<double> f;  // pixels 1 and 2, two samples each: p + s + c / 4
  for (int p : {1, 2})
    for (int s = 0; s < 2; ++s)
      for (int c = 0; c < 3; ++c) f.push_back(p + s + c / 4.0);
  std::array<double, 3> sum{0, 0, 0};
  EXPECT_EQ(models::AddPixelMeans(2, 2, 4, f.data(), &image, &sum), "");
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(image.rgb[c], -1.0f);
    EXPECT_EQ(image.rgb[3 + c], float(1.5 + c / 4.0));
    EXPECT_EQ(image.rgb[6 + c], float(2.5 + c / 4.0));
    EXPECT_EQ(image.rgb[9 + c], -1.0f);
    EXPECT_DOUBLE_EQ(sum[c], 4.0 + c / 2.0);
  }
  std::vector<double> bad(12, 1.0);
  bad[7] = std::nan("");
  EXPECT_NE(models::AddPixelMeans(2, 2, 4, bad.data(), &image, &sum), "");
}

// Largest relative error over the channels of the slice mean over one repeat against the BRDF.
double MeanError(v1::Loomlight::Stub& stub, uint32_t side, uint32_t spp, const std::vector<float>& brdf) {
  TextureSliceResponse response;
  const grpc::Status status = CallSlice(stub, Slice(side, side, spp, v1::IMAGE_FORMAT_RAW), &response);
  EXPECT_TRUE(status.ok()) << status.error_message();
  double error = 0;
  for (int c = 0; c < 3; ++c) error = std::max(error, std::fabs(response.mean(c) - brdf[c]) / brdf[c]);
  return error;
}

TEST_F(SliceTest, MeanOverOneRepeatConvergesToTheBrdf) {
  const std::vector<float> brdf = Evaluate(*stub_, {}, 1);
  ASSERT_EQ(brdf.size(), 3u);
  const uint32_t sides[] = {16, 64, 256};
  double errors[3];
  for (int i = 0; i < 3; ++i) {
    errors[i] = MeanError(*stub_, sides[i], 4, brdf);
    std::printf("%ux%u x 4 samples: relative error of the mean %.3g\n", sides[i], sides[i], errors[i]);
  }
  EXPECT_LT(errors[1], errors[0]);
  EXPECT_LT(errors[2], errors[1]);
  // The BTF jumps (by about f itself) across cell and ellipse edges of total length L ~ 4 per repeat. Only
  // the ~L/h pixels on an edge (pixel size h) are in error, each by ~h^2 / sqrt(spp) of the area (rotated
  // samples: the errors are independent), so the mean is off by ~sqrt(L / h) h^2 / sqrt(spp) = sqrt(L / spp)
  // h^1.5: 1.6e-2 at h = 1/16, 2e-3 at 1/64, 2.4e-4 at 1/256 (measured 4.9e-3, 3.7e-4, 1.1e-4). Bound at
  // 2.5x the estimate for h = 1/256; the float kernels' own error (~1e-6) is far below.
  EXPECT_LT(errors[2], 6e-4);
}

TEST_F(SliceTest, EveryInvalidFieldIsNamed) {
  struct Case {
    const char* field;
    std::function<void(TextureSliceRequest&)> change;
  };
  const Case cases[] = {
      {"material.preset", [](auto& r) { r.mutable_material()->set_preset("no_such_cloth"); }},
      {"material.transmission", [](auto& r) { r.mutable_material()->mutable_transmission()->set_model("thin_layer"); }},
      {"wi", [](auto& r) { r.clear_wi(); }},
      {"wi", [](auto& r) { r.mutable_wi()->Add(kWi.begin(), kWi.end()); }},
      {"wi[0]", [](auto& r) { r.set_wi(2, 2.0f); }},
      {"wi[0]", [](auto& r) { r.set_wi(0, NAN); }},
      {"wo", [](auto& r) { r.mutable_wo()->RemoveLast(); }},
      {"wo[0]", [](auto& r) { r.set_wo(1, INFINITY); }},
      {"region.u_min", [](auto& r) { SetRegion(r, NAN, 0, 1, 1); }},
      {"region.u_min", [](auto& r) { SetRegion(r, -2000, 0, 1, 1); }},
      {"region.v_max", [](auto& r) { SetRegion(r, 0, 0, 1, INFINITY); }},
      {"region.u_max", [](auto& r) { SetRegion(r, 1, 0, 1, 1); }},
      {"region.v_max", [](auto& r) { SetRegion(r, 0, 2, 1, 1); }},
      {"region.u_max", [](auto& r) { r.mutable_region(); }},  // set but all zero: an empty region
      {"width", [](auto& r) { r.set_width(0); }},
      {"width", [](auto& r) { r.set_width(api::kMaxSliceSide + 1); }},
      {"height", [](auto& r) { r.set_height(0); }},
      {"height", [](auto& r) { r.set_height(100000); }},
      {"samples_per_pixel", [](auto& r) { r.set_samples_per_pixel(api::kMaxSamplesPerPixel + 1); }},
      {"samples_per_pixel", [](auto& r) {  // each within its limit, the product not
         r.set_width(2048);
         r.set_height(2048);
         r.set_samples_per_pixel(8);
       }},
      {"format", [](auto& r) { r.set_format(static_cast<v1::ImageFormat>(7)); }},
      {"precision", [](auto& r) { r.set_precision(static_cast<v1::Precision>(5)); }},
      {"exposure", [](auto& r) { r.set_exposure(-1); }},
      {"exposure", [](auto& r) { r.set_exposure(NAN); }},
      {"exposure", [](auto& r) { r.set_exposure(INFINITY); }},
  };
  for (const Case& c : cases) {
    TextureSliceRequest request = Slice(8, 8, 1, v1::IMAGE_FORMAT_PNG);
    c.change(request);
    TextureSliceResponse response;
    const grpc::Status status = CallSlice(*stub_, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field << ": " << status.error_message();
    // The message starts with exactly the field: "wi: ..." for the count, "wi[0]: ..." for one direction.
    EXPECT_EQ(status.error_message().rfind(std::string(c.field) + ":", 0), 0u)
        << "expected the message to start with '" << c.field << ":', got: " << status.error_message();
  }
  // The limits themselves are accepted: 1 x 1 pixel and the most samples per pixel.
  TextureSliceResponse response;
  TextureSliceRequest smallest = Slice(1, 1, api::kMaxSamplesPerPixel, v1::IMAGE_FORMAT_RAW);
  ASSERT_TRUE(CallSlice(*stub_, smallest, &response).ok());
  EXPECT_EQ(response.image().size(), 12u);
}

TEST_F(SliceTest, MaterialsWithoutABtfAreRejectedOnMaterial) {
  int checked = 0;
  for (const auto& model : models::Registry::Global().models()) {
    if (model->spatially_varying() || model->presets().empty()) continue;
    TextureSliceRequest request = Slice(8, 8, 1, v1::IMAGE_FORMAT_PNG);
    request.mutable_material()->set_preset(model->presets().front().name);
    TextureSliceResponse response;
    const grpc::Status status = CallSlice(*stub_, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << model->name();
    EXPECT_EQ(status.error_message().rfind("material:", 0), 0u) << status.error_message();
    ++checked;
  }
  EXPECT_GE(checked, 1);  // the microcylinder model at least
}

TEST_F(SliceTest, ShortDeadlineIsExceededAndTheServerKeepsServing) {
  // 2^24 queries (seconds of work) against a 20 ms deadline.
  const TextureSliceRequest big = Slice(2048, 2048, 4, v1::IMAGE_FORMAT_PNG);
  TextureSliceResponse response;
  const grpc::Status status = CallSlice(*stub_, big, &response, std::chrono::milliseconds(20));
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  const grpc::Status after = CallSlice(*stub_, Slice(16, 16, 1, v1::IMAGE_FORMAT_PNG), &response);
  EXPECT_TRUE(after.ok()) << after.error_message();
  EXPECT_TRUE(server_->running());
}

TEST_F(SliceTest, ClientWritesAnImageThatDecodes) {
  for (const char* extension : {"png", "exr"}) {
    const std::string path = ::testing::TempDir() + "/slice_client." + extension;
    std::remove(path.c_str());
    std::string out;
    ASSERT_EQ(testing::RunClient(server_->address(),
                        std::string("slice --preset cotton_twill --wi 0,0,1 --wo-deg 30,0 --size 80x60 "
                                    "--region 0,0,2,2 --spp 4 --out ") + path, &out), 0) << out;
    EXPECT_NE(out.find("80x60"), std::string::npos) << out;
    EXPECT_NE(out.find("mean RGB"), std::string::npos) << out;
    auto in = OIIO::ImageInput::open(path);
    ASSERT_TRUE(in) << OIIO::geterror();
    EXPECT_EQ(in->spec().width, 80);
    EXPECT_EQ(in->spec().height, 60);
    EXPECT_EQ(in->spec().nchannels, 3);
    EXPECT_EQ(in->spec().format == OIIO::TypeDesc::UINT8, std::string(extension) == "png");
  }
  std::string out;
  EXPECT_EQ(testing::RunClient(server_->address(), "slice --preset velvet --wi 0,0,1 --wo 0,0,1 --out /dev/null --format raw", &out), 1);
  EXPECT_NE(out.find("INVALID_ARGUMENT: material:"), std::string::npos) << out;
  EXPECT_EQ(testing::RunClient(server_->address(), "slice --preset cotton_twill --wi 0,0,1 --wo 0,0,1 --out x.tiff", &out), 2);
}

// In process: shutting the server down with slices in flight (several seconds of work, more than the
// one second gRPC gives calls to finish) ends every call and returns.
TEST(SliceShutdown, ServerShutsDownWithSlicesInFlight) {
  api::ServerOptions options;
  options.address = "127.0.0.1:0";
  std::string error;
  auto server = api::LoomlightServer::Start(options, &error);
  ASSERT_NE(server, nullptr) << error;
  auto stub = testing::Connect("127.0.0.1:" + std::to_string(server->port()));
  std::vector<std::future<grpc::StatusCode>> calls;
  for (int i = 0; i < 4; ++i)
    calls.push_back(std::async(std::launch::async, [&] {
      TextureSliceResponse response;
      return CallSlice(*stub, Slice(2048, 2048, 4, v1::IMAGE_FORMAT_PNG), &response).error_code();
    }));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // let the first chunks reach the device
  auto shutdown = std::async(std::launch::async, [&] { server->Shutdown(); });
  ASSERT_EQ(shutdown.wait_for(std::chrono::seconds(60)), std::future_status::ready) << "shutdown hangs";
  int interrupted = 0;
  for (auto& call : calls) {
    ASSERT_EQ(call.wait_for(std::chrono::seconds(60)), std::future_status::ready) << "a call never ended";
    const grpc::StatusCode code = call.get();
    EXPECT_TRUE(code == grpc::StatusCode::OK || code == grpc::StatusCode::CANCELLED ||
                code == grpc::StatusCode::UNAVAILABLE) << code;
    interrupted += code != grpc::StatusCode::OK;
  }
  std::printf("%d of %zu slices were interrupted by the shutdown\n", interrupted, calls.size());
  server.reset();
}

// Identical images give identical bytes whenever they are encoded: no wall-clock date in any format's header
// (OpenImageIO's EXR writer adds one unless told otherwise), so encodings a second apart are equal, and the
// EXR still decodes to its pixels.
TEST(ImageEncode, SameImageGivesIdenticalBytesASecondApartInEveryFormat) {
  imaging::LinearRgbImage image{24, 16, {}};
  for (int i = 0; i < 24 * 16 * 3; ++i) image.rgb.push_back(0.01f * float(i % 97));
  const std::vector<std::pair<imaging::ImageFormat, const char*>> formats = {
      {imaging::ImageFormat::kExr, "x.exr"}, {imaging::ImageFormat::kPng, "x.png"},
      {imaging::ImageFormat::kJpeg, "x.jpg"}, {imaging::ImageFormat::kRaw, "x.raw"}};
  std::vector<std::string> first;
  for (const auto& [format, name] : formats) {
    ASSERT_EQ(imaging::EncodeImage(image, format, 1.0, &first.emplace_back()), "") << name;
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  for (size_t i = 0; i < formats.size(); ++i) {
    std::string again;
    ASSERT_EQ(imaging::EncodeImage(image, formats[i].first, 1.0, &again), "") << formats[i].second;
    EXPECT_EQ(again, first[i]) << formats[i].second << " bytes depend on when they were encoded";
  }
  const testing::DecodedImage exr = testing::DecodeImage(first[0], "x.exr");
  ASSERT_EQ(exr.width, 24);
  ASSERT_EQ(exr.channels, 3);
  EXPECT_EQ(exr.pixels, image.rgb);
}

// End to end: two identical EXR slices a second apart are the same bytes (and PNG, for good measure).
TEST_F(SliceTest, IdenticalRequestsASecondApartGiveIdenticalBytes) {
  for (v1::ImageFormat format : {v1::IMAGE_FORMAT_EXR, v1::IMAGE_FORMAT_PNG}) {
    const TextureSliceRequest request = Slice(32, 24, 2, format);
    TextureSliceResponse first, second;
    ASSERT_TRUE(CallSlice(*stub_, request, &first).ok());
    std::this_thread::sleep_for(std::chrono::milliseconds(1100));
    ASSERT_TRUE(CallSlice(*stub_, request, &second).ok());
    EXPECT_FALSE(first.image().empty());
    EXPECT_EQ(first.image(), second.image()) << v1::ImageFormat_Name(format);
  }
}

}  // namespace
}  // namespace loomlight
