#include "client/polar_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <optional>
#include <stdexcept>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>

namespace loomlight::client {
namespace {

namespace algo = OIIO::ImageBufAlgo;

// Drawn at this multiple of the output size, then filtered down: render_line has no anti-aliasing.
constexpr int kSupersample = 2;
// Every length below is in "units" of 1/800 of the image width, so the plot looks the same at any --size.
constexpr double kUnitsPerWidth = 800.0;
constexpr double kSideMargin = 50, kTopMargin = 100, kBottomMargin = 40;
constexpr double kCurveWidth = 2.5, kMarkerWidth = 1.5, kGridWidth = 1.0;
constexpr double kDash = 10, kGap = 7;
constexpr int kTitleFont = 20, kLabelFont = 13;

const Color kWhite = {1, 1, 1};
const Color kGrid = {0.86f, 0.86f, 0.86f};
const Color kRim = {0.6f, 0.6f, 0.6f};
const Color kText = {0.1f, 0.1f, 0.1f};
const Color kFaintText = {0.45f, 0.45f, 0.45f};

struct Point {
  double x, y;
};

// Pixel geometry of the supersampled canvas.
struct Layout {
  double unit;    // pixels per unit
  double cx, cy;  // disc centre
  double radius;  // rim radius in pixels
  int width, height;

  Point at(double theta_deg, double r) const {  // r in pixels from the centre
    const double t = theta_deg * std::numbers::pi / 180.0;
    return {cx + r * std::sin(t), cy - r * std::cos(t)};
  }
};

Layout make_layout(int size) {
  Layout l;
  l.width = size * kSupersample;
  l.unit = l.width / kUnitsPerWidth;
  l.radius = l.width / 2.0 - kSideMargin * l.unit;
  l.cx = l.width / 2.0;
  l.cy = kTopMargin * l.unit + l.radius;
  l.height = static_cast<int>(std::lround(l.cy + kBottomMargin * l.unit)) / kSupersample * kSupersample;
  return l;
}

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

class Canvas {
 public:
  explicit Canvas(const Layout& layout)
      : layout_(layout), image_(OIIO::ImageSpec(layout.width, layout.height, 3, OIIO::TypeDesc::FLOAT)) {
    algo::fill(image_, kWhite);
  }

  // render_line draws one pixel wide; a wider line is the union of offset copies within the pen radius.
  void line(Point a, Point b, const Color& color, double width_units) {
    const double pen = std::max(0.5, 0.5 * width_units * layout_.unit);
    const int reach = static_cast<int>(std::floor(pen));
    for (int dy = -reach; dy <= reach; ++dy)
      for (int dx = -reach; dx <= reach; ++dx)
        if (dx * dx + dy * dy <= pen * pen)
          algo::render_line(image_, px(a.x) + dx, px(a.y) + dy, px(b.x) + dx, px(b.y) + dy, color);
  }

  void dashed_line(Point a, Point b, const Color& color, double width_units) {
    const double length = std::hypot(b.x - a.x, b.y - a.y);
    const double dash = kDash * layout_.unit, period = (kDash + kGap) * layout_.unit;
    for (double s = 0; s < length; s += period) {
      const double e = std::min(s + dash, length);
      line(lerp(a, b, s / length), lerp(a, b, e / length), color, width_units);
    }
  }

  // Silently does nothing without a font: labels are a nicety, the curves are the plot.
  void text(Point p, const std::string& text, int font_units, const Color& color,
            algo::TextAlignX align_x = algo::TextAlignX::Center, algo::TextAlignY align_y = algo::TextAlignY::Center) {
    const auto& font = text_font();
    if (!font || text.empty()) return;
    const int size = static_cast<int>(std::lround(font_units * layout_.unit));
    if (!algo::render_text(image_, px(p.x), px(p.y), text, size, *font, color, align_x, align_y)) image_.geterror();
  }

  // Filters the supersampled canvas down to the output size and writes it as 8-bit.
  void write(const std::string& path) const {
    const OIIO::ROI out(0, layout_.width / kSupersample, 0, layout_.height / kSupersample, 0, 1, 0, 3);
    const OIIO::ImageBuf small = algo::resize(image_, "", 0.0f, out);
    if (small.has_error() || !small.write(path, OIIO::TypeDesc::UINT8))
      throw std::runtime_error("cannot write " + path + ": " + small.geterror());
  }

 private:
  static int px(double v) { return static_cast<int>(std::lround(v)); }
  static Point lerp(Point a, Point b, double t) { return {a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t}; }

  Layout layout_;
  OIIO::ImageBuf image_;
};

std::string format_value(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

void draw_half_circle(Canvas& canvas, const Layout& l, double r, const Color& color) {
  Point prev = l.at(-90, r);
  for (int deg = -89; deg <= 90; ++deg) {
    const Point next = l.at(deg, r);
    canvas.line(prev, next, color, kGridWidth);
    prev = next;
  }
}

// Rings at quarters of the scale, radial lines every 30 degrees, the baseline, and their labels.
void draw_grid(Canvas& canvas, const Layout& l, double scale) {
  for (int quarter = 1; quarter <= 4; ++quarter)
    draw_half_circle(canvas, l, l.radius * quarter / 4.0, quarter == 4 ? kRim : kGrid);
  for (int deg = -60; deg <= 60; deg += 30) canvas.line(l.at(0, 0), l.at(deg, l.radius), kGrid, kGridWidth);
  canvas.line(l.at(-90, l.radius), l.at(90, l.radius), kRim, kGridWidth);

  for (int deg = -90; deg <= 90; deg += 30)
    canvas.text(l.at(deg, l.radius + 22 * l.unit), std::to_string(deg), kLabelFont, kFaintText);
  for (int quarter = 1; quarter <= 4; ++quarter)
    canvas.text({l.cx + l.radius * quarter / 4.0, l.cy + 16 * l.unit}, format_value("%.3g", scale * quarter / 4.0),
                kLabelFont, kFaintText);
}

void draw_curve(Canvas& canvas, const Layout& l, const PolarCurve& curve, double scale) {
  std::optional<Point> prev;
  for (std::size_t i = 0; i < curve.value.size(); ++i) {
    const double v = curve.value[i];
    if (!std::isfinite(v)) {
      prev.reset();
      continue;
    }
    const Point p = l.at(curve.theta_deg[i], l.radius * std::max(0.0, v) / scale);
    if (prev) canvas.line(*prev, p, curve.color, kCurveWidth);
    prev = p;
  }
}

// Title and notes in the top-left corner, the legend in the top-right one: the half disc leaves both free.
void draw_header(Canvas& canvas, const Layout& l, const PolarPlot& plot) {
  const double x = 16 * l.unit;
  canvas.text({x, 28 * l.unit}, plot.title, kTitleFont, kText, algo::TextAlignX::Left);
  for (std::size_t i = 0; i < plot.notes.size(); ++i)
    canvas.text({x, (52 + 18 * i) * l.unit}, plot.notes[i], kLabelFont, kFaintText, algo::TextAlignX::Left);
}

void draw_legend(Canvas& canvas, const Layout& l, const std::vector<LegendEntry>& legend) {
  if (!text_font()) return;  // swatches without their text would say nothing
  const double x = l.width - 180 * l.unit;
  for (std::size_t i = 0; i < legend.size(); ++i) {
    const double y = (20 + 20 * i) * l.unit;
    canvas.line({x, y}, {x + 24 * l.unit, y}, legend[i].color, kCurveWidth);
    canvas.text({x + 32 * l.unit, y}, legend[i].text, kLabelFont, kText, algo::TextAlignX::Left);
  }
}

}  // namespace

void write_polar_plot(const PolarPlot& plot, const std::string& path) {
  if (!(plot.scale > 0.0)) throw std::invalid_argument("polar plot scale must be positive");
  const Layout layout = make_layout(plot.size);
  Canvas canvas(layout);
  draw_grid(canvas, layout, plot.scale);
  for (const PolarMarker& m : plot.markers)
    canvas.dashed_line(layout.at(0, 0), layout.at(m.theta_deg, layout.radius), m.color, kMarkerWidth);
  for (const PolarCurve& curve : plot.curves) draw_curve(canvas, layout, curve, plot.scale);
  draw_header(canvas, layout, plot);
  draw_legend(canvas, layout, plot.legend);
  canvas.write(path);
}

}  // namespace loomlight::client
