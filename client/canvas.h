// A drawing surface for the client's plots (polar lobes, line charts, image views): lines, dashed lines,
// text, pixel images, a title block, a legend and line-chart axes, written as PNG through OpenImageIO (in the
// image module, client/image_module.h, loaded by the first canvas).
// Lengths are in "units" of 1/800 of the image width, so a plot looks the same at any size.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

namespace loomlight::client {

using Color = std::array<float, 3>;  // display RGB in [0, 1]

struct Point {
  double x, y;  // supersampled canvas pixels
};

struct LegendEntry {
  Color color;
  std::string text;
};

// Drawn at this multiple of the output size, then filtered down: OpenImageIO's render_line has no anti-aliasing.
constexpr int kSupersample = 2;
constexpr double kUnitsPerWidth = 800.0;
constexpr double kCurveWidth = 2.5, kMarkerWidth = 1.5, kGridWidth = 1.0;
constexpr int kTitleFont = 20, kLabelFont = 13;

inline constexpr Color kWhite = {1, 1, 1};
inline constexpr Color kGrid = {0.86f, 0.86f, 0.86f};
inline constexpr Color kRim = {0.6f, 0.6f, 0.6f};
inline constexpr Color kText = {0.1f, 0.1f, 0.1f};
inline constexpr Color kFaintText = {0.45f, 0.45f, 0.45f};
inline constexpr Color kChannelColors[3] = {{0.85f, 0.10f, 0.10f}, {0.10f, 0.60f, 0.10f}, {0.10f, 0.25f, 0.90f}};

enum class Align { kStart, kCenter, kEnd };

class CanvasPixels;  // client/image_module.h

class Canvas {
 public:
  // An image of width x height output pixels, white. Throws std::runtime_error if the image module is missing.
  Canvas(int width, int height);
  ~Canvas();
  int width() const { return width_; }    // supersampled pixels
  int height() const { return height_; }
  double unit() const { return unit_; }   // supersampled pixels per unit
  bool has_font() const;                  // text is drawn (a font is installed)

  // render_line draws one pixel wide; a wider line is the union of offset copies within the pen radius.
  void line(Point a, Point b, const Color& color, double width_units);
  void dashed_line(Point a, Point b, const Color& color, double width_units);
  // Silently does nothing without a font: labels are a nicety, the curves are the plot.
  void text(Point p, const std::string& text, int font_units, const Color& color, Align align_x = Align::kCenter,
            Align align_y = Align::kCenter);
  // Paints a w x h image of display RGB (row-major, top row first, values in [0, 1]) into the rectangle
  // from top_left to bottom_right, each image pixel a block (nearest neighbour).
  void image(Point top_left, Point bottom_right, int w, int h, const std::vector<float>& rgb);
  // Filters the supersampled canvas down to the output size and writes it as 8-bit. Throws
  // std::runtime_error if the file cannot be written.
  void write(const std::string& path) const;

 private:
  int width_, height_;
  double unit_;
  std::unique_ptr<CanvasPixels> pixels_;
};

// Title and notes in the top-left corner of a panel whose top edge is `top_units` below the canvas's top.
void draw_title(Canvas& canvas, const std::string& title, const std::vector<std::string>& notes,
                double top_units = 0);
// Colour swatches with their text in the top-right corner of that panel (nothing without a font).
void draw_legend(Canvas& canvas, const std::vector<LegendEntry>& legend, double top_units = 0);
// A line chart's plot rectangle: x from 0 at the left edge to x_max, y from 0 at the bottom to y_max.
struct Axes {
  Point top_left, bottom_right;
  double x_max, y_max;
  Point at(double x, double y) const {
    return {top_left.x + (bottom_right.x - top_left.x) * x / x_max,
            bottom_right.y - (bottom_right.y - top_left.y) * y / y_max};
  }
};
// A frame around the axes' rectangle, ticks every x_step and y_step with their labels, optional grid lines,
// and the axis titles (x below, y above the rectangle's top-left corner).
void draw_axes(Canvas& canvas, const Axes& axes, double x_step, double y_step, const std::string& x_title,
               const std::string& y_title, bool grid_lines);
// A round tick step (1, 2 or 5 times a power of ten) giving about four to eight ticks up to `top`.
double nice_step(double top);
// printf-style formatting of one number, e.g. format_value("%.3g", v).
std::string format_value(const char* format, double v);

}  // namespace loomlight::client
