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
constexpr double kSideMargin = 50, kTopMargin = 100, kBottomMargin = 40, kNoteLine = 18;
constexpr double kRadiusUnits = kUnitsPerWidth / 2 - kSideMargin;
constexpr double kSurfaceWidth = 2.0;
const Color kSurface = {0.2f, 0.2f, 0.2f};

// Pixel geometry of one plot on the supersampled canvas.
struct Layout {
  double unit;    // pixels per unit
  double cx, cy;  // disc centre
  double radius;  // rim radius in pixels
  bool full_circle;

  Point at(double theta_deg, double r) const {  // r in pixels from the centre
    const double t = theta_deg * std::numbers::pi / 180.0;
    return {cx + r * std::sin(t), cy - r * std::cos(t)};
  }
  // The angular range drawn: [-90, 90] for the half disc, [-180, 180] for the full circle.
  double half_span() const { return full_circle ? 180.0 : 90.0; }
};

// The title block has room for two notes above the disc's top label; each further note moves the disc down.
double top_margin(const PolarPlot& plot) {
  return kTopMargin + kNoteLine * static_cast<double>(std::max<std::size_t>(plot.notes.size(), 2) - 2);
}

Layout make_layout(const Canvas& canvas, const PolarPlot& plot, double top_units) {
  Layout l;
  l.unit = canvas.unit();
  l.radius = kRadiusUnits * l.unit;
  l.cx = canvas.width() / 2.0;
  l.cy = (top_units + top_margin(plot)) * l.unit + l.radius;
  l.full_circle = plot.full_circle;
  return l;
}

void draw_arc(Canvas& canvas, const Layout& l, double r, const Color& color) {
  const int span = static_cast<int>(l.half_span());
  Point prev = l.at(-span, r);
  for (int deg = -span + 1; deg <= span; ++deg) {
    const Point next = l.at(deg, r);
    canvas.line(prev, next, color, kGridWidth);
    prev = next;
  }
}

// Rings at quarters of the scale, radial lines every 30 degrees, the baseline (half disc) or the surface line
// (full circle, when labelled), and their labels.
void draw_grid(Canvas& canvas, const Layout& l, const PolarPlot& plot) {
  const bool surface = l.full_circle && !(plot.upper_label.empty() && plot.lower_label.empty());
  const int span = static_cast<int>(l.half_span());
  for (int quarter = 1; quarter <= 4; ++quarter)
    draw_arc(canvas, l, l.radius * quarter / 4.0, quarter == 4 ? kRim : kGrid);
  for (int deg = -span + 30; deg <= span; deg += 30)
    if (std::abs(deg) != 90) canvas.line(l.at(0, 0), l.at(deg, l.radius), kGrid, kGridWidth);
  if (surface) {
    canvas.line(l.at(-90, l.radius), l.at(90, l.radius), kSurface, kSurfaceWidth);
    const double x = l.cx - l.radius + 8 * l.unit;
    canvas.text({x, l.cy - 12 * l.unit}, plot.upper_label, kLabelFont, kText, Align::kStart);
    canvas.text({x, l.cy + 14 * l.unit}, plot.lower_label, kLabelFont, kText, Align::kStart);
  } else {
    canvas.line(l.at(-90, l.radius), l.at(90, l.radius), l.full_circle ? kGrid : kRim, kGridWidth);
  }

  for (int deg = l.full_circle ? -span + 30 : -span; deg <= span; deg += 30)
    canvas.text(l.at(deg, l.radius + 22 * l.unit), std::to_string(deg), kLabelFont, kFaintText);
  for (int quarter = 1; quarter <= 4; ++quarter)
    canvas.text({l.cx + l.radius * quarter / 4.0, l.cy + 16 * l.unit},
                format_value("%.3g", plot.scale * quarter / 4.0), kLabelFont, kFaintText);
}

void draw_curve(Canvas& canvas, const Layout& l, const PolarCurve& curve, double scale) {
  const auto point = [&](std::size_t i) -> std::optional<Point> {
    const double v = curve.value[i];
    if (!std::isfinite(v)) return std::nullopt;
    return l.at(curve.theta_deg[i], l.radius * std::max(0.0, v) / scale);
  };
  std::optional<Point> prev;
  for (std::size_t i = 0; i < curve.value.size(); ++i) {
    const std::optional<Point> p = point(i);
    if (prev && p) canvas.line(*prev, *p, curve.color, kCurveWidth);
    prev = p;
  }
  if (l.full_circle && !curve.value.empty())
    if (const auto first = point(0); first && prev) canvas.line(*prev, *first, curve.color, kCurveWidth);
}

}  // namespace

double polar_plot_height_units(const PolarPlot& plot) {
  return top_margin(plot) + kRadiusUnits * (plot.full_circle ? 2 : 1) + kBottomMargin;
}

void draw_polar_plot(Canvas& canvas, const PolarPlot& plot, double top_units) {
  if (!(plot.scale > 0.0)) throw std::invalid_argument("polar plot scale must be positive");
  const Layout layout = make_layout(canvas, plot, top_units);
  draw_grid(canvas, layout, plot);
  for (const PolarMarker& m : plot.markers)
    canvas.dashed_line(layout.at(0, 0), layout.at(m.theta_deg, layout.radius), m.color, kMarkerWidth);
  for (const PolarCurve& curve : plot.curves) draw_curve(canvas, layout, curve, plot.scale);
  // The disc leaves the top corners free.
  draw_title(canvas, plot.title, plot.notes, top_units);
  draw_legend(canvas, plot.legend, top_units);
}

void write_polar_plot(const PolarPlot& plot, const std::string& path) {
  Canvas canvas(plot.size, static_cast<int>(std::lround(plot.size * polar_plot_height_units(plot) / kUnitsPerWidth)));
  draw_polar_plot(canvas, plot, 0.0);
  canvas.write(path);
}

}  // namespace loomlight::client
