// Drawing of an upper-half-disc polar plot to a PNG with OpenImageIO (used by `loomlight plot`).
#pragma once

#include <string>
#include <vector>

#include "client/canvas.h"

namespace loomlight::client {

// A curve r(theta): theta in degrees from the vertical, positive to the right. Non-finite values break it.
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
  int size = 800;      // image width in pixels; the height follows from the half disc
};

// Writes the plot as a PNG. Text is drawn only if OpenImageIO finds a font; otherwise the plot has no labels.
// Throws std::runtime_error if the file cannot be written.
void write_polar_plot(const PolarPlot& plot, const std::string& path);

}  // namespace loomlight::client
