#include "client/polar_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <optional>
#include <stdexcept>

namespace loomlight::client {
namespace {

// Lengths in units of 1/800 of the image width (client/canvas.h).
constexpr double kSideMargin = 50, kTopMargin = 100, kBottomMargin = 40;

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

}  // namespace

void write_polar_plot(const PolarPlot& plot, const std::string& path) {
  if (!(plot.scale > 0.0)) throw std::invalid_argument("polar plot scale must be positive");
  const Layout layout = make_layout(plot.size);
  Canvas canvas(plot.size, layout.height / kSupersample);
  draw_grid(canvas, layout, plot.scale);
  for (const PolarMarker& m : plot.markers)
    canvas.dashed_line(layout.at(0, 0), layout.at(m.theta_deg, layout.radius), m.color, kMarkerWidth);
  for (const PolarCurve& curve : plot.curves) draw_curve(canvas, layout, curve, plot.scale);
  draw_title(canvas, plot.title, plot.notes);  // the half disc leaves the top corners free
  draw_legend(canvas, plot.legend);
  canvas.write(path);
}

}  // namespace loomlight::client
