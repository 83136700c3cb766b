// The client's image work, drawing and writing plot canvases and reading image files' sizes, through
// OpenImageIO in a module (libloomlight_images.so beside the `loomlight` binary) that the CLI loads on first
// use. OpenImageIO pulls in some 300 shared libraries whose loading cost every CLI call ~0.5 s before it did
// anything; only plots and BTF uploads need it.
#pragma once

#include <memory>
#include <string>

#include "client/canvas.h"

namespace loomlight::client {

// A canvas's pixels: RGB float, white when made; coordinates in pixels (outside ones are clipped).
class CanvasPixels {
 public:
  virtual ~CanvasPixels() = default;
  // One pixel wide, from (x0, y0) to (x1, y1) inclusive.
  virtual void line(int x0, int y0, int x1, int y1, const Color& color) = 0;
  // Whether text can be drawn: a font is installed.
  virtual bool has_font() const = 0;
  // Anchored at (x, y) by the alignments; nothing without a font.
  virtual void text(int x, int y, const std::string& text, int size, const Color& color, Align align_x,
                    Align align_y) = 0;
  virtual void set_pixel(int x, int y, const float* rgb) = 0;
  // Filtered down to width x height and written as 8-bit (the format from the extension); "" or the error.
  virtual std::string write(const std::string& path, int width, int height) const = 0;
};

class ImageModule {
 public:
  virtual ~ImageModule() = default;
  virtual std::unique_ptr<CanvasPixels> new_canvas(int width, int height) const = 0;
  // The size of the image in the file at path, from its header: "" or why it cannot be read.
  virtual std::string image_size(const std::string& path, int* width, int* height) const = 0;
};

// Loads the module on first use. Throws std::runtime_error naming the file it looked for when it cannot.
const ImageModule& image_module();

}  // namespace loomlight::client

// The module's one export: its ImageModule, alive as long as the process. The interface's version is in the
// name, so a module built for another layout of these classes (a stale copy beside a newer CLI) is refused by
// name instead of called. Change both together whenever CanvasPixels or ImageModule change.
#define LOOMLIGHT_IMAGE_MODULE_ENTRY "loomlight_image_module_v1"
extern "C" const loomlight::client::ImageModule* loomlight_image_module_v1();
