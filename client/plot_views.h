// The views of `loomlight plot` besides the polar lobe (client/plot.cpp): the theta_h/theta_d image slice,
// directional albedo against incidence angle, and a lit sphere. Each evaluates on the server (Evaluate)
// and writes a PNG through OpenImageIO (client/canvas.h).
#pragma once

#include <string_view>

#include "client/cli.h"
#include "client/directions.h"

namespace loomlight::client {

// Vector helpers of the views' shading frames (the sphere's here, the fiber's in client/plot.cpp).
Vec3 normalized(const Vec3& v);
double dot(const Vec3& a, const Vec3& b);
Vec3 cross(const Vec3& a, const Vec3& b);

// The options these views add to `plot` (--phi-d, --phi-h, --light, --exposure, --resolution).
OptionList plot_view_options();

// Runs view "thd", "albedo" or "sphere"; throws UsageError for any other name.
int run_plot_view(std::string_view view, const ParsedOptions& options);

}  // namespace loomlight::client
