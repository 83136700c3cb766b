// Drawing of polar plots (used by `loomlight plot`): the upper half disc (reflection lobes) or the full circle
// (transmission below the surface, a fiber's lobes), alone in a PNG or as one panel of several on a canvas.
#pragma once

#include <string>
#include <vector>

#include "client/canvas.h"

namespace loomlight::client {

// A curve r(theta): theta in degrees from the vertical, positive to the right (clockwise); 180 is straight
// down. Non-finite values break it; on a full circle the last point joins the first.
struct PolarCurve {
  std::vector<double> theta_deg;
  std::vector<double> value;
  Color color;
};

// A dashed radial line from the centre to the rim, e.g. the incidence direction.
struct PolarMarker {
  double theta_deg;
  Color color;
};

struct PolarPlot {
  std::string title;
  std::vector<std::string> notes;  // smaller lines under the title
  std::vector<PolarCurve> curves;
  std::vector<PolarMarker> markers;
  std::vector<LegendEntry> legend;
  double scale = 1.0;  // the value drawn at the rim; must be > 0
  int size = 800;      // image width in pixels; the height follows from the disc
  bool full_circle = false;  // theta over [-180, 180] rather than the upper half disc [-90, 90]
  // Full circle only: when either is set, a dark horizontal line through the centre (the surface) with these
  // labels just above and below it, e.g. "reflection" and "transmission".
  std::string upper_label, lower_label;
};

// Height of the plot in units of 1/800 of its width (client/canvas.h).
double polar_plot_height_units(const PolarPlot& plot);

// Draws the plot, title and legend included, as a panel whose top edge is `top_units` below the canvas's top;
// the canvas is plot.size pixels wide. Throws std::invalid_argument if plot.scale is not positive.
void draw_polar_plot(Canvas& canvas, const PolarPlot& plot, double top_units);

// Writes the plot alone as a PNG. Text is drawn only if OpenImageIO finds a font; otherwise the plot has no
// labels. Throws std::runtime_error if the file cannot be written.
void write_polar_plot(const PolarPlot& plot, const std::string& path);

}  // namespace loomlight::client
