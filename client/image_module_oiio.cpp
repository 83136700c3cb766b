// libloomlight_images.so: the client's ImageModule through OpenImageIO (client/image_module.h).
#include <optional>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include "client/image_module.h"

namespace loomlight::client {
namespace {

namespace algo = OIIO::ImageBufAlgo;

// OpenImageIO's default font is often not installed; a few common system fonts are tried after it.
const std::optional<std::string>& text_font() {
  static const std::optional<std::string> font = [] () -> std::optional<std::string> {
    for (const char* name : {"", "DejaVuSans", "LiberationSans-Regular", "FreeSans"}) {
      if (algo::text_size("0", kLabelFont, name).defined()) return name;
      OIIO::geterror();  // discard the failure so it is not reported later
    }
    return std::nullopt;
  }();
  return font;
}

algo::TextAlignX ToOiioX(Align a) {
  return a == Align::kStart ? algo::TextAlignX::Left : a == Align::kEnd ? algo::TextAlignX::Right : algo::TextAlignX::Center;
}
algo::TextAlignY ToOiioY(Align a) {
  return a == Align::kStart ? algo::TextAlignY::Top : a == Align::kEnd ? algo::TextAlignY::Bottom : algo::TextAlignY::Center;
}

class OiioCanvasPixels final : public CanvasPixels {
 public:
  OiioCanvasPixels(int width, int height) : image_(OIIO::ImageSpec(width, height, 3, OIIO::TypeDesc::FLOAT)) {
    algo::fill(image_, kWhite);
  }
  void line(int x0, int y0, int x1, int y1, const Color& color) override {
    algo::render_line(image_, x0, y0, x1, y1, color);
  }
  bool has_font() const override { return text_font().has_value(); }
  void text(int x, int y, const std::string& text, int size, const Color& color, Align align_x,
            Align align_y) override {
    const auto& font = text_font();
    if (!font) return;
    if (!algo::render_text(image_, x, y, text, size, *font, color, ToOiioX(align_x), ToOiioY(align_y)))
      image_.geterror();  // discard: a label that cannot be drawn is left out
  }
  void set_pixel(int x, int y, const float* rgb) override { image_.setpixel(x, y, rgb, 3); }
  std::string write(const std::string& path, int width, int height) const override {
    const OIIO::ROI out(0, width, 0, height, 0, 1, 0, 3);
    const OIIO::ImageBuf small = algo::resize(image_, "", 0.0f, out);
    if (small.has_error() || !small.write(path, OIIO::TypeDesc::UINT8))
      return "cannot write " + path + ": " + small.geterror();
    return "";
  }

 private:
  OIIO::ImageBuf image_;
};

class OiioImageModule final : public ImageModule {
 public:
  std::unique_ptr<CanvasPixels> new_canvas(int width, int height) const override {
    return std::make_unique<OiioCanvasPixels>(width, height);
  }
  std::string image_size(const std::string& path, int* width, int* height) const override {
    const auto input = OIIO::ImageInput::open(path);
    if (!input) return "cannot read the image " + path + ": " + OIIO::geterror();
    *width = input->spec().width;
    *height = input->spec().height;
    return "";
  }
};

}  // namespace
}  // namespace loomlight::client

extern "C" const loomlight::client::ImageModule* loomlight_image_module_v1() {
  static const loomlight::client::OiioImageModule module;
  return &module;
}
