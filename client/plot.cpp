// `loomlight plot`: the in-plane lobe of a material as a polar plot (PNG), one curve per incidence angle.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <numbers>
#include <string>
#include <vector>

#include "client/commands.h"
#include "client/directions.h"
#include "client/material.h"
#include "client/plot_views.h"
#include "client/polar_plot.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

// Outgoing angles stop short of 90 degrees: f is zero at grazing by definition (SPEC.md section 1).
constexpr double kMaxThetaO = 89.5;

struct PlotSettings {
  std::vector<double> incidence_deg;
  double plane_phi_deg = 0.0;
  int samples = 721;
  bool rgb = false;     // one curve per channel instead of the luminance
  bool cosine = true;   // plot f cos(theta_o), the radiance lobe, rather than f
  int size = 800;
  std::string out;
};

PlotSettings read_settings(const ParsedOptions& options) {
  PlotSettings s;
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("plot needs --out FILE.png");
  s.out = *out;
  s.incidence_deg = parse_numbers(options.last("incidence").value_or("0,30,60"), "--incidence");
  for (double t : s.incidence_deg)
    if (!(std::abs(t) < 90.0)) throw UsageError("--incidence angles must lie in (-90, 90) degrees");
  if (auto phi = options.last("plane-phi")) s.plane_phi_deg = parse_number(*phi, "--plane-phi");
  if (!std::isfinite(s.plane_phi_deg)) throw UsageError("--plane-phi must be finite");
  if (auto n = options.last("samples")) s.samples = parse_int(*n, "--samples", 2, 100000);
  if (auto px = options.last("size")) s.size = parse_int(*px, "--size", 100, 8000);
  const std::string channels = options.last("channels").value_or("lum");
  if (channels != "lum" && channels != "rgb") throw UsageError("--channels must be lum or rgb");
  s.rgb = channels == "rgb";
  s.cosine = !options.has("no-cos");
  return s;
}

double theta_o_deg(const PlotSettings& s, int k) { return -kMaxThetaO + 2.0 * kMaxThetaO * k / (s.samples - 1); }

// The light sits at -theta_i in the plane, so the mirror direction is at +theta_i. Queries are ordered
// incidence-major: query i * samples + k is incidence i, outgoing sample k.
void add_plane_queries(const PlotSettings& s, v1::EvaluateRequest& request) {
  for (double ti : s.incidence_deg) {
    const Vec3 wi = direction_from_degrees(-ti, s.plane_phi_deg);
    for (int k = 0; k < s.samples; ++k)
      add_query(request, wi, direction_from_degrees(theta_o_deg(s, k), s.plane_phi_deg));
  }
}

// Curve colours: a qualitative palette (matplotlib's tab10) for luminance curves; in rgb mode the channel
// hues, lighter for each later incidence angle.
Color incidence_color(std::size_t i) {
  static const Color palette[] = {{0.12f, 0.47f, 0.71f}, {1.00f, 0.50f, 0.05f}, {0.17f, 0.63f, 0.17f},
                                  {0.84f, 0.15f, 0.16f}, {0.58f, 0.40f, 0.74f}, {0.55f, 0.34f, 0.29f},
                                  {0.89f, 0.47f, 0.76f}, {0.50f, 0.50f, 0.50f}, {0.74f, 0.74f, 0.13f},
                                  {0.09f, 0.75f, 0.81f}};
  return palette[i % std::size(palette)];
}

Color lighten(const Color& c, std::size_t i, std::size_t n) {
  const float t = n > 1 ? 0.6f * static_cast<float>(i) / static_cast<float>(n - 1) : 0.0f;
  return {c[0] + (1 - c[0]) * t, c[1] + (1 - c[1]) * t, c[2] + (1 - c[2]) * t};
}

const Color kMarkerGray = {0.25f, 0.25f, 0.25f};

// Rec. 709 luminance of linear RGB.
double luminance(double r, double g, double b) { return 0.2126 * r + 0.7152 * g + 0.0722 * b; }

// Plotted value of one channel (0..2) or the luminance (-1) of incidence i, sample k.
double sample_value(const PlotSettings& s, const v1::EvaluateResponse& response, std::size_t i, int k, int channel) {
  const int q = static_cast<int>(i) * s.samples + k;
  const double f = channel < 0 ? luminance(response.f(3 * q), response.f(3 * q + 1), response.f(3 * q + 2))
                               : response.f(3 * q + channel);
  return s.cosine ? f * std::cos(theta_o_deg(s, k) * std::numbers::pi / 180.0) : f;
}

PolarCurve make_curve(const PlotSettings& s, const v1::EvaluateResponse& response, std::size_t i, int channel,
                      const Color& color) {
  PolarCurve curve{{}, {}, color};
  for (int k = 0; k < s.samples; ++k) {
    curve.theta_deg.push_back(theta_o_deg(s, k));
    curve.value.push_back(sample_value(s, response, i, k, channel));
  }
  return curve;
}

// Labels are ASCII: OpenImageIO 2.4's render_text drops the high bits of non-ASCII characters.
std::string degrees(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g deg", v);
  return buf;
}

std::vector<std::string> notes(const PlotSettings& s, const v1::EvaluateResponse& response) {
  const std::string quantity =
      std::string(s.rgb ? "R, G, B of " : "luminance of ") + (s.cosine ? "f cos(theta_o)" : "f");
  return {response.model() + ", " + precision_name(response.precision()) + ": " + quantity + " (1/sr)",
          "plane of incidence phi = " + degrees(s.plane_phi_deg)};
}

PolarPlot make_plot(const PlotSettings& s, const v1::EvaluateRequest& request, const v1::EvaluateResponse& response) {
  PolarPlot plot;
  plot.title = material_label(request.material());
  plot.notes = notes(s, response);
  plot.size = s.size;
  const std::size_t n = s.incidence_deg.size();
  for (std::size_t i = 0; i < n; ++i) {
    const Color marker = s.rgb ? lighten(kMarkerGray, i, n) : incidence_color(i);
    if (s.rgb)
      for (int c = 0; c < 3; ++c)
        plot.curves.push_back(make_curve(s, response, i, c, lighten(kChannelColors[c], i, n)));
    else
      plot.curves.push_back(make_curve(s, response, i, -1, marker));
    plot.markers.push_back({-s.incidence_deg[i], marker});
    plot.legend.push_back({marker, "theta_i = " + degrees(s.incidence_deg[i])});
  }
  if (s.rgb)
    for (int c = 0; c < 3; ++c) plot.legend.push_back({kChannelColors[c], std::string(1, "RGB"[c])});
  return plot;
}

double max_value(const std::vector<PolarCurve>& curves) {
  double max = 0.0;
  for (const PolarCurve& c : curves)
    for (double v : c.value)
      if (std::isfinite(v)) max = std::max(max, v);
  return max;
}

int run_plot(const ParsedOptions& options) {
  if (const std::string view = options.last("view").value_or("polar"); view != "polar")
    return run_plot_view(view, options);
  const PlotSettings settings = read_settings(options);
  v1::EvaluateRequest request = material_request(options);
  add_plane_queries(settings, request);

  Client client(options);
  const v1::EvaluateResponse response = client.evaluate(request);
  if (options.has("verbose")) print_timing(std::cerr, response, request.wi_size() / 3);

  PolarPlot plot = make_plot(settings, request, response);
  const double max = max_value(plot.curves);
  plot.scale = max > 0.0 ? max : 1.0;  // an all-zero lobe still gets a drawable grid
  write_polar_plot(plot, settings.out);
  std::printf("%.9g\n", max);
  return 0;
}

OptionList plot_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"out", "FILE.png", "output image (required)"},
      {"incidence", "DEG,...", "incidence angles theta_i in degrees (default 0,30,60)"},
      {"plane-phi", "DEG", "azimuth of the plane of incidence: 0 = x-z plane (default), 90 = y-z plane"},
      {"channels", "lum|rgb", "plot the luminance (default) or each RGB channel"},
      {"no-cos", "", "plot f instead of f cos(theta_o)"},
      {"samples", "N", "outgoing directions per curve, theta_o from -89.5 to 89.5 degrees (default 721)"},
      {"size", "PX", "image width in pixels (default 800)"},
      {"verbose", "", "print the server's timing and batching to stderr"},
  });
  const OptionList views = plot_view_options();
  options.insert(options.end(), views.begin(), views.end());
  return options;
}

}  // namespace

const Command& plot_command() {
  static const Command command = {
      "plot",
      "MATERIAL --out FILE.png [options]\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "write a polar plot of the in-plane lobe, or another view (--view), as a PNG",
      "--view polar (default): for each incidence angle theta_i the light is at -theta_i in the plane (so the mirror direction is at\n"
      "+theta_i) and theta_o sweeps the plane. The radius is proportional to the plotted value, autoscaled\n"
      "to its maximum, which is printed to stdout. All curves come from one Evaluate call.\n"
      "--view thd: f over theta_h (x, 0-90) and theta_d (y, 0 at the bottom) at one phi_d and phi_h\n"
      "  (Rusinkiewicz half/difference angles, as in BRDF Explorer's image slice), tone-mapped.\n"
      "--view albedo: the directional albedo (integral of f cos(theta_o) over the outgoing hemisphere, and\n"
      "  over the lower one when the material transmits) against theta_i, by 32 Gauss-Legendre nodes in\n"
      "  cos(theta_o) x 64 midpoints in phi_o; the values are printed as CSV (theta_i, r, g, b[, transmitted]).\n"
      "--view sphere: the material on a sphere under one directional light, orthographic view from +z;\n"
      "  at each point the shading normal is the sphere's and thread 1 runs along view x projected onto it.\n"
      "Example: loomlight plot --preset silk_shot --incidence 15,45,75 --plane-phi 90 --out silk.png",
      plot_options(),
      run_plot,
  };
  return command;
}

}  // namespace loomlight::client
