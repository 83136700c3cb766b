#include "client/canvas.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "client/image_module.h"

namespace loomlight::client {
namespace {

constexpr double kDash = 10, kGap = 7;

int px(double v) { return static_cast<int>(std::lround(v)); }
Point lerp(Point a, Point b, double t) { return {a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t}; }

}  // namespace

Canvas::Canvas(int width, int height)
    : width_(width * kSupersample),
      height_(height * kSupersample),
      unit_(width_ / kUnitsPerWidth),
      pixels_(image_module().new_canvas(width_, height_)) {}

Canvas::~Canvas() = default;

bool Canvas::has_font() const { return pixels_->has_font(); }

void Canvas::line(Point a, Point b, const Color& color, double width_units) {
  const double pen = std::max(0.5, 0.5 * width_units * unit_);
  const int reach = static_cast<int>(std::floor(pen));
  for (int dy = -reach; dy <= reach; ++dy)
    for (int dx = -reach; dx <= reach; ++dx)
      if (dx * dx + dy * dy <= pen * pen) pixels_->line(px(a.x) + dx, px(a.y) + dy, px(b.x) + dx, px(b.y) + dy, color);
}

void Canvas::dashed_line(Point a, Point b, const Color& color, double width_units) {
  const double length = std::hypot(b.x - a.x, b.y - a.y);
  const double dash = kDash * unit_, period = (kDash + kGap) * unit_;
  for (double s = 0; s < length; s += period) {
    const double e = std::min(s + dash, length);
    line(lerp(a, b, s / length), lerp(a, b, e / length), color, width_units);
  }
}

void Canvas::text(Point p, const std::string& text, int font_units, const Color& color, Align align_x, Align align_y) {
  if (text.empty()) return;
  pixels_->text(px(p.x), px(p.y), text, static_cast<int>(std::lround(font_units * unit_)), color, align_x, align_y);
}

void Canvas::image(Point top_left, Point bottom_right, int w, int h, const std::vector<float>& rgb) {
  const int x0 = std::max(0, px(top_left.x)), x1 = std::min(width_, px(bottom_right.x));
  const int y0 = std::max(0, px(top_left.y)), y1 = std::min(height_, px(bottom_right.y));
  if (x1 <= x0 || y1 <= y0 || rgb.size() != size_t(3) * w * h) return;
  for (int y = y0; y < y1; ++y) {
    const int row = std::min(h - 1, (y - px(top_left.y)) * h / std::max(1, px(bottom_right.y) - px(top_left.y)));
    for (int x = x0; x < x1; ++x) {
      const int col = std::min(w - 1, (x - px(top_left.x)) * w / std::max(1, px(bottom_right.x) - px(top_left.x)));
      pixels_->set_pixel(x, y, &rgb[3 * (size_t(row) * w + col)]);
    }
  }
}

void Canvas::write(const std::string& path) const {
  if (std::string error = pixels_->write(path, width_ / kSupersample, height_ / kSupersample); !error.empty())
    throw std::runtime_error(error);
}

void draw_title(Canvas& canvas, const std::string& title, const std::vector<std::string>& notes, double top_units) {
  const double u = canvas.unit(), x = 16 * u;
  canvas.text({x, (top_units + 28) * u}, title, kTitleFont, kText, Align::kStart);
  for (std::size_t i = 0; i < notes.size(); ++i)
    canvas.text({x, (top_units + 52 + 18 * i) * u}, notes[i], kLabelFont, kFaintText, Align::kStart);
}

void draw_legend(Canvas& canvas, const std::vector<LegendEntry>& legend, double top_units) {
  if (!canvas.has_font()) return;  // swatches without their text would say nothing
  const double u = canvas.unit(), x = canvas.width() - 180 * u;
  for (std::size_t i = 0; i < legend.size(); ++i) {
    const double y = (top_units + 20 + 20 * i) * u;
    canvas.line({x, y}, {x + 24 * u, y}, legend[i].color, kCurveWidth);
    canvas.text({x + 32 * u, y}, legend[i].text, kLabelFont, kText, Align::kStart);
  }
}

void draw_axes(Canvas& canvas, const Axes& a, double x_step, double y_step, const std::string& x_title,
               const std::string& y_title, bool grid_lines) {
  const double u = canvas.unit();
  for (double x = 0; x <= a.x_max + 1e-9; x += x_step) {
    if (grid_lines) canvas.line(a.at(x, 0), a.at(x, a.y_max), kGrid, kGridWidth);
    canvas.text({a.at(x, 0).x, a.bottom_right.y + 14 * u}, format_value("%g", x), kLabelFont, kFaintText);
  }
  for (double y = 0; y <= a.y_max + 1e-9; y += y_step) {
    if (grid_lines) canvas.line(a.at(0, y), a.at(a.x_max, y), kGrid, kGridWidth);
    canvas.text({a.top_left.x - 8 * u, a.at(0, y).y}, format_value("%.3g", y), kLabelFont, kFaintText, Align::kEnd);
  }
  const Point corners[4] = {a.top_left, {a.bottom_right.x, a.top_left.y}, a.bottom_right, {a.top_left.x, a.bottom_right.y}};
  for (int i = 0; i < 4; ++i) canvas.line(corners[i], corners[(i + 1) % 4], kRim, kGridWidth);
  canvas.text({(a.top_left.x + a.bottom_right.x) / 2, a.bottom_right.y + 36 * u}, x_title, kLabelFont, kText);
  canvas.text({a.top_left.x, a.top_left.y - 12 * u}, y_title, kLabelFont, kText, Align::kStart);
}

double nice_step(double top) {
  const double raw = top / 5, power = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0})
    if (m * power >= raw) return m * power;
  return 10 * power;
}

std::string format_value(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

}  // namespace loomlight::client
