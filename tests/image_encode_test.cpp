// Catalogue output (issue 46): a rendered product encoded on a white or transparent background as PNG, JPEG,
// WebP and EXR, decoded back with OpenImageIO (and WebP's colour with libwebp, whose straight RGBA OpenImageIO
// 2.4 premultiplies on reading): white is 255 exactly where the product is absent, edges blend over white in
// display space, alpha is the coverage, JPEG refuses a transparent background, 4096-pixel images encode, and
// the automatic exposure looks at the product only.
#include <gtest/gtest.h>
#include <webp/decode.h>

#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "server/imaging/image_encode.h"
#include "server/render/renderer.h"
#include "server/render/tone_map.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace loomlight {
namespace {

using imaging::Background;
using imaging::ImageFormat;

// A rendered product: per pixel its radiance averaged over all samples (misses adding 0) and its coverage.
struct Product {
  imaging::LinearRgbImage image;
  std::vector<float> coverage;
};

Product Empty(int width, int height) {
  return {{width, height, std::vector<float>(size_t(width) * height * 3, 0.0f)},
          std::vector<float>(size_t(width) * height, 0.0f)};
}

// Pixel (x, y) covered by `coverage` of a product whose own radiance is `radiance` (grey).
void Put(Product* product, int x, int y, float radiance, float coverage) {
  const size_t p = size_t(y) * product->image.width + x;
  product->coverage[p] = coverage;
  for (int c = 0; c < 3; ++c) product->image.rgb[3 * p + c] = radiance * coverage;
}

struct Decoded {
  int width = 0, height = 0, channels = 0;
  std::vector<unsigned char> pixels;
  unsigned char at(int x, int y, int c) const { return pixels[(size_t(y) * width + x) * channels + c]; }
};

// 8-bit pixels as stored: alpha unassociated (PNG's convention), not premultiplied on reading.
Decoded Decode8(const std::string& bytes, const char* name) {
  Decoded d;
  OIIO::Filesystem::IOMemReader reader(bytes.data(), bytes.size());
  OIIO::Filesystem::IOProxy* proxy = &reader;
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &proxy);  // with a config, the proxy is read from it
  auto in = OIIO::ImageInput::open(name, &config);
  EXPECT_TRUE(in) << OIIO::geterror();
  if (!in) return d;
  d.width = in->spec().width;
  d.height = in->spec().height;
  d.channels = in->spec().nchannels;
  d.pixels.resize(size_t(d.width) * d.height * d.channels);
  EXPECT_TRUE(in->read_image(0, 0, 0, d.channels, OIIO::TypeDesc::UINT8, d.pixels.data())) << in->geterror();
  return d;
}

std::vector<float> DecodeExr(const std::string& bytes, int* channels) {
  OIIO::Filesystem::IOMemReader reader(bytes.data(), bytes.size());
  auto in = OIIO::ImageInput::open("x.exr", nullptr, &reader);
  EXPECT_TRUE(in) << OIIO::geterror();
  if (!in) return {};
  *channels = in->spec().nchannels;
  EXPECT_EQ(in->spec().alpha_channel, *channels == 4 ? 3 : -1);
  std::vector<float> pixels(size_t(in->spec().width) * in->spec().height * *channels);
  EXPECT_TRUE(in->read_image(0, 0, 0, *channels, OIIO::TypeDesc::FLOAT, pixels.data())) << in->geterror();
  return pixels;
}

std::string Encode(const Product& product, Background background, ImageFormat format, double exposure = 1.0,
                   double* used_exposure = nullptr) {
  std::string bytes;
  double used = 0;
  const std::string error =
      render::EncodeRendered(product.image, &product.coverage, background, format, exposure, &bytes, &used);
  EXPECT_EQ(error, "");
  if (used_exposure) *used_exposure = used;
  return bytes;
}

// 32 x 16: the left half empty; a bright (display white) product in columns 16..23 and a black one in 24..31,
// each fully covered except row 0, half covered.
Product WhiteAndBlack() {
  Product product = Empty(32, 16);
  for (int y = 0; y < 16; ++y)
    for (int x = 16; x < 32; ++x) Put(&product, x, y, x < 24 ? 1000.0f : 0.0f, y == 0 ? 0.5f : 1.0f);
  return product;
}

TEST(ImageEncode, WhiteBackgroundIs255WhereEmptyAndEdgesBlendInDisplaySpace) {
  const Product product = WhiteAndBlack();
  const Decoded png = Decode8(Encode(product, Background::kWhite, ImageFormat::kPng), "x.png");
  ASSERT_EQ(png.channels, 3);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (int c = 0; c < 3; ++c) ASSERT_EQ(png.at(x, y, c), 255) << x << "," << y;
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(png.at(20, 5, c), 255);  // the white product
    EXPECT_EQ(png.at(28, 5, c), 0);    // the black one
    EXPECT_EQ(png.at(20, 0, c), 255);  // half covered: white over white does not darken
    EXPECT_NEAR(png.at(28, 0, c), 127.5, 0.5);  // black over white, half: half way in sRGB codes
  }
  // Lossy formats: white exactly where whole blocks are empty, the edge pixels within their loss.
  for (const auto& [format, name] : {std::pair{ImageFormat::kJpeg, "x.jpg"}, std::pair{ImageFormat::kWebp, "x.webp"}}) {
    const Decoded lossy = Decode8(Encode(product, Background::kWhite, format), name);
    ASSERT_EQ(lossy.width, 32);
    ASSERT_EQ(lossy.height, 16);
    ASSERT_EQ(lossy.channels, 3);
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 8; ++x)
        for (int c = 0; c < 3; ++c) ASSERT_EQ(lossy.at(x, y, c), 255) << name << " " << x << "," << y;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(lossy.at(28, 0, c), 127.5, 24) << name;
  }
}

TEST(ImageEncode, TransparentPngAndWebpCarryCoverageAsAlphaAndTheUnblendedColour) {
  Product product = Empty(16, 16);
  for (int y = 0; y < 16; ++y)
    for (int x = 8; x < 16; ++x) Put(&product, x, y, 0.05f + 0.01f * y, (x - 7) / 8.0f);  // coverage 1/8 .. 1
  product.coverage[3] = 0.3f;  // a pixel of coverage but no light: black at alpha 77
  for (const auto& [format, name] : {std::pair{ImageFormat::kPng, "x.png"}, std::pair{ImageFormat::kWebp, "x.webp"}}) {
    const std::string bytes = Encode(product, Background::kTransparent, format);
    const Decoded decoded = Decode8(bytes, name);
    ASSERT_EQ(decoded.width, 16) << name;
    ASSERT_EQ(decoded.channels, 4) << name;
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x)
        ASSERT_EQ(decoded.at(x, y, 3), std::lround(255.0 * product.coverage[size_t(y) * 16 + x]))
            << name << " " << x << "," << y;
    if (format == ImageFormat::kPng) {
      // Unassociated: a row's partly covered pixels have the colour of its fully covered one.
      for (int y = 0; y < 16; ++y)
        for (int x = 8; x < 15; ++x)
          for (int c = 0; c < 3; ++c) ASSERT_EQ(decoded.at(x, y, c), decoded.at(15, y, c)) << x << "," << y;
    } else {
      // libwebp's own decoder gives the straight colour (OpenImageIO's premultiplies it): the PNG's, within
      // the loss of quality 90.
      const Decoded png = Decode8(Encode(product, Background::kTransparent, ImageFormat::kPng), "x.png");
      int width = 0, height = 0;
      uint8_t* rgba = WebPDecodeRGBA(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), &width, &height);
      ASSERT_NE(rgba, nullptr);
      ASSERT_EQ(width, 16);
      for (int y = 0; y < 16; ++y)
        for (int x = 12; x < 16; ++x)  // covered by half or more
          for (int c = 0; c < 3; ++c) EXPECT_NEAR(rgba[(y * 16 + x) * 4 + c], png.at(x, y, c), 8) << x << "," << y;
      WebPFree(rgba);
    }
  }
}

TEST(ImageEncode, WebpIsQuality90LossyAndDeterministic) {
  // A smooth product on white: the WebP decodes to the PNG's colours within a few codes.
  Product product = Empty(64, 48);
  for (int y = 4; y < 44; ++y)
    for (int x = 8; x < 56; ++x) Put(&product, x, y, 0.02f + 0.01f * x, 1.0f);
  const std::string webp = Encode(product, Background::kWhite, ImageFormat::kWebp);
  ASSERT_GE(webp.size(), 12u);
  EXPECT_EQ(webp.substr(0, 4), "RIFF");
  EXPECT_EQ(webp.substr(8, 4), "WEBP");
  EXPECT_EQ(Encode(product, Background::kWhite, ImageFormat::kWebp), webp);
  const Decoded decoded = Decode8(webp, "x.webp");
  const Decoded png = Decode8(Encode(product, Background::kWhite, ImageFormat::kPng), "x.png");
  ASSERT_EQ(decoded.width, 64);
  ASSERT_EQ(decoded.height, 48);
  double error = 0;
  for (size_t i = 0; i < png.pixels.size(); ++i) error += std::abs(int(decoded.pixels[i]) - int(png.pixels[i]));
  EXPECT_LT(error / png.pixels.size(), 3.0);
  EXPECT_GT(error, 0.0) << "lossy at quality 90, not lossless";
}

TEST(ImageEncode, ExrIsLinearWithPremultipliedAlphaOrOverWhite) {
  const Product product = WhiteAndBlack();
  int channels = 0;
  const std::vector<float> transparent = DecodeExr(Encode(product, Background::kTransparent, ImageFormat::kExr),
                                                   &channels);
  ASSERT_EQ(channels, 4);
  for (size_t p = 0; p < product.coverage.size(); ++p) {
    ASSERT_EQ(transparent[4 * p + 3], product.coverage[p]) << p;
    for (int c = 0; c < 3; ++c) ASSERT_FLOAT_EQ(transparent[4 * p + c], product.image.rgb[3 * p + c]) << p;
  }
  const std::vector<float> white = DecodeExr(Encode(product, Background::kWhite, ImageFormat::kExr), &channels);
  ASSERT_EQ(channels, 3);
  for (size_t p = 0; p < product.coverage.size(); ++p)
    for (int c = 0; c < 3; ++c)
      ASSERT_FLOAT_EQ(white[3 * p + c], product.image.rgb[3 * p + c] + 1.0f - product.coverage[p]) << p;
  EXPECT_EQ(white[0], 1.0f);
}

TEST(ImageEncode, JpegWithATransparentBackgroundIsRefused) {
  const Product product = WhiteAndBlack();
  std::string bytes;
  double used = 0;
  const std::string error = render::EncodeRendered(product.image, &product.coverage, Background::kTransparent,
                                                   ImageFormat::kJpeg, 0, &bytes, &used);
  EXPECT_NE(error.find("JPEG"), std::string::npos) << error;
  EXPECT_NE(error.find("transparent"), std::string::npos) << error;
  EXPECT_TRUE(bytes.empty());
  EXPECT_EQ(imaging::CheckBackground(ImageFormat::kJpeg, Background::kTransparent), error);
  for (ImageFormat ok : {ImageFormat::kPng, ImageFormat::kWebp, ImageFormat::kExr})
    EXPECT_EQ(imaging::CheckBackground(ok, Background::kTransparent), "");
  EXPECT_EQ(imaging::CheckBackground(ImageFormat::kJpeg, Background::kWhite), "");
  // A white or transparent background without a coverage of the image's size is an error, not a crash.
  std::vector<float> short_coverage(3, 1.0f);
  EXPECT_NE(render::EncodeRendered(product.image, &short_coverage, Background::kWhite, ImageFormat::kPng, 0, &bytes,
                                   &used),
            "");
  EXPECT_NE(render::EncodeRendered(product.image, nullptr, Background::kWhite, ImageFormat::kPng, 0, &bytes, &used),
            "");
}

// The automatic exposure of a mid-grey product (radiance 0.3, its edges half covered) is Reinhard's key for it,
// 0.18 / 0.3, whatever the empty area around it.
TEST(ImageEncode, AutomaticExposureLooksAtTheProductOnly) {
  for (int size : {16, 64, 256}) {
    Product product = Empty(size, size);
    for (int y = 2; y < 10; ++y)
      for (int x = 2; x < 10; ++x) Put(&product, x, y, 0.3f, x == 2 || y == 9 ? 0.5f : 1.0f);
    for (Background background : {Background::kWhite, Background::kTransparent}) {
      double exposure = 0;
      Encode(product, background, ImageFormat::kPng, 0, &exposure);
      EXPECT_NEAR(exposure, 0.18 / 0.3, 1e-5) << size;
    }
  }
}

TEST(ImageEncode, FillIsTheMeanCoverage) {
  EXPECT_DOUBLE_EQ(render::Fill({0.0f, 0.5f, 1.0f, 1.0f}), 0.625);
  EXPECT_DOUBLE_EQ(render::Fill({2.0f, -1.0f, NAN, 0.5f}), 0.375);  // clamped; not finite counts as 0
  EXPECT_EQ(render::Fill({}), 0.0);
}

// Catalogue size: 4096 on the long side encodes in every format, to the right size (no cap at 2048).
TEST(ImageEncode, A4096By2304ImageEncodesInEveryFormat) {
  const int width = 4096, height = 2304;
  Product product = Empty(width, height);
  for (int y = height / 4; y < 3 * height / 4; ++y)
    for (int x = width / 4; x < 3 * width / 4; ++x) Put(&product, x, y, 0.18f, 1.0f);  // flat: encodes fast
  const std::vector<std::tuple<ImageFormat, Background, const char*>> cases = {
      {ImageFormat::kPng, Background::kTransparent, "x.png"},
      {ImageFormat::kJpeg, Background::kWhite, "x.jpg"},
      {ImageFormat::kWebp, Background::kTransparent, "x.webp"},
      {ImageFormat::kExr, Background::kTransparent, "x.exr"}};
  for (const auto& [format, background, name] : cases) {
    const std::string bytes = Encode(product, background, format);
    OIIO::Filesystem::IOMemReader reader(bytes.data(), bytes.size());
    auto in = OIIO::ImageInput::open(name, nullptr, &reader);
    ASSERT_TRUE(in) << name << ": " << OIIO::geterror();
    EXPECT_EQ(in->spec().width, width) << name;
    EXPECT_EQ(in->spec().height, height) << name;
    EXPECT_EQ(in->spec().nchannels, background == Background::kTransparent ? 4 : 3) << name;
  }
}

}  // namespace
}  // namespace loomlight
