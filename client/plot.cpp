// `loomlight plot`: polar plots of a material's lobes as PNG, one curve per incidence angle: the in-plane lobe
// (the upper half disc, or the full circle with transmission below the surface for materials that transmit)
// and the fiber model's longitudinal and azimuthal lobes. The other views are in client/plot_views.cpp.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <iostream>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "client/canvas.h"
#include "client/commands.h"
#include "client/directions.h"
#include "client/material.h"
#include "client/plot_views.h"
#include "client/polar_plot.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

// Half-circle outgoing angles stop short of 90 degrees: f is zero at grazing by definition (SPEC.md section 1).
constexpr double kMaxThetaO = 89.5;
constexpr int kHalfCircleSamples = 721, kFullCircleSamples = 1440;

struct PlotSettings {
  std::vector<double> incidence_deg;
  double plane_phi_deg = 0.0;
  std::optional<int> samples;  // the default depends on half or full circle
  bool full_circle = false;    // asked for; materials with transmission get it anyway
  bool rgb = false;            // one curve per channel instead of the luminance
  bool cosine = true;          // plot f times the cosine factor of the view (the radiance lobe), rather than f
  int size = 800;
  std::string out;
};

PlotSettings read_settings(const ParsedOptions& options) {
  PlotSettings s;
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("plot needs --out FILE.png");
  s.out = *out;
  s.incidence_deg = parse_numbers(options.last("incidence").value_or("0,30,60"), "--incidence");
  // The light stays above the surface (off a fiber's axis): the materials that transmit are symmetric about
  // their surface (a curtain's reflection is mirrored to the front), so a light from below shows nothing new.
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
  s.full_circle = options.has("full-circle");
  return s;
}

// ---- What the server says about the material ----

// The material's model and preset from ListModels; left empty when the server knows neither, so that
// Evaluate reports the error in its usual words.
struct MaterialModel {
  v1::ModelInfo info;
  std::optional<v1::Preset> preset;
};

MaterialModel find_material_model(Client& client, const v1::Material& material) {
  const v1::ListModelsResponse models = client.list_models();
  for (const v1::ModelInfo& model : models.models()) {
    if (!material.model().empty() && model.name() != material.model()) continue;
    if (material.preset().empty()) return {model, std::nullopt};
    for (const v1::Preset& preset : model.presets())
      if (preset.name() == material.preset()) return {model, preset};
  }
  return {};
}

// A parameter's values as the server will use them: the material's override, else its preset's, else the
// schema's default (empty if the model has no such parameter).
std::vector<double> parameter_values(const MaterialModel& model, const v1::Material& material, std::string_view name) {
  for (const v1::Param& p : material.params())
    if (p.name() == name) return {p.values().begin(), p.values().end()};
  if (model.preset)
    for (const v1::Param& p : model.preset->params())
      if (p.name() == name) return {p.values().begin(), p.values().end()};
  for (const v1::ParamSchema& p : model.info.params())
    if (p.name() == name) return {p.default_values().begin(), p.default_values().end()};
  return {};
}

// ---- Sweeps: the queries behind one polar panel ----

// Plot angles: the half circle from -89.5 to 89.5 degrees, or the full circle at Tabulate's full_circle bin
// centres -180 + (k + 1/2) 360 / n (for even n none falls on the horizon, where a layer's mu is 0).
std::vector<double> sweep_angles(const PlotSettings& s, bool full_circle) {
  const int n = s.samples.value_or(full_circle ? kFullCircleSamples : kHalfCircleSamples);
  std::vector<double> angles(n);
  for (int k = 0; k < n; ++k)
    angles[k] = full_circle ? -180.0 + 360.0 * (k + 0.5) / n : -kMaxThetaO + 2.0 * kMaxThetaO * k / (n - 1);
  return angles;
}

// For each incidence a light direction, and for each plot angle an outgoing direction and the factor that
// turns f into the plotted value. Samples are incidence-major: sample i * angles + k.
struct Sweep {
  bool full_circle;
  std::vector<double> angle_deg;
  std::vector<Vec3> wi;        // per incidence
  std::vector<Vec3> wo;        // per sample
  std::vector<double> weight;  // per sample
  int first_query = 0;         // the sweep's first query in the Evaluate request

  Sweep(const PlotSettings& s, bool full) : full_circle(full), angle_deg(sweep_angles(s, full)) {}
  void add(const Vec3& light) { wi.push_back(light); }
  void add_sample(const Vec3& out, double factor) {
    wo.push_back(out);
    weight.push_back(factor);
  }
};

void add_queries(Sweep& sweep, v1::EvaluateRequest& request) {
  sweep.first_query = request.wi_size() / 3;
  const std::size_t n = sweep.angle_deg.size();
  for (std::size_t i = 0; i < sweep.wi.size(); ++i)
    for (std::size_t k = 0; k < n; ++k) add_query(request, sweep.wi[i], sweep.wo[i * n + k]);
}

double cos_degrees(double deg) { return std::cos(deg * std::numbers::pi / 180.0); }

// The light at -theta_i in the plane of azimuth phi, so the mirror direction is at +theta_i; theta_o sweeps the
// plane (|theta_o| > 90 is below the surface). Plotted: f |cos(theta_o)|, the radiance lobe on either side.
Sweep in_plane_sweep(const PlotSettings& s, bool full_circle) {
  Sweep sweep(s, full_circle);
  for (double ti : s.incidence_deg) {
    sweep.add(direction_from_degrees(-ti, s.plane_phi_deg));
    for (double to : sweep.angle_deg)
      sweep.add_sample(direction_from_degrees(to, s.plane_phi_deg), s.cosine ? std::abs(cos_degrees(to)) : 1.0);
  }
  return sweep;
}

// The fiber's frame as the server builds it (server/models/plugins/fiber.cpp): t the normalised axis, u = +z
// made perpendicular to t (+x when t is along z), v = t x u.
struct FiberFrame {
  Vec3 t, u, v;
  Vec3 combine(double along_t, double along_u, double along_v) const {
    Vec3 w;
    for (int c = 0; c < 3; ++c) w[c] = along_t * t[c] + along_u * u[c] + along_v * v[c];
    return w;
  }
  // The direction at theta from the fiber's normal plane (sin theta = w.t) and azimuth phi from u toward v.
  Vec3 at(double theta_deg, double phi_deg) const {
    const Vec3 d = direction_from_degrees(90.0 - theta_deg, phi_deg);  // (cos th cos ph, cos th sin ph, sin th)
    return combine(d[2], d[0], d[1]);
  }
};

FiberFrame fiber_frame(std::vector<double> axis) {
  if (axis.size() != 3) axis = {1.0, 0.0, 0.0};  // not a fiber material: the fiber's default
  const Vec3 t = normalized({axis[0], axis[1], axis[2]});
  Vec3 u = {-t[2] * t[0], -t[2] * t[1], 1.0 - t[2] * t[2]};             // z - (z.t) t
  if (std::sqrt(dot(u, u)) < 1e-6) u = {1.0 - t[0] * t[0], -t[0] * t[1], -t[0] * t[2]};  // x - (x.t) t
  u = normalized(u);
  return {t, u, cross(t, u)};
}

// The light at theta_i from the fiber's normal plane, azimuth 0 (along u). Longitudinal lobe: wo sweeps the
// plane of t and u, plot angle a from u toward t, so the upper half is phi_o = 0 (back, where R goes) and the
// lower half phi_o = 180 (forward through the fiber, where TT goes), theta_o = asin(sin a) either way.
// Plotted: f cos^2(theta_o), the density in (theta_o, phi_o) of the scattered energy (SPEC.md section 5).
Sweep fiber_longitudinal_sweep(const PlotSettings& s, const FiberFrame& frame) {
  Sweep sweep(s, true);
  for (double ti : s.incidence_deg) {
    sweep.add(frame.at(ti, 0.0));
    for (double a : sweep.angle_deg) {
      const Vec3 d = direction_from_degrees(a, 0.0);  // (sin a, 0, cos a)
      sweep.add_sample(frame.combine(d[0], d[2], 0.0), s.cosine ? d[2] * d[2] : 1.0);
    }
  }
  return sweep;
}

// Azimuthal lobe: wo at theta_o = -theta_i (both lobes' longitudinal centre) and phi_o around the fiber.
Sweep fiber_azimuthal_sweep(const PlotSettings& s, const FiberFrame& frame) {
  Sweep sweep(s, true);
  for (double ti : s.incidence_deg) {
    sweep.add(frame.at(ti, 0.0));
    const double cos_theta_o = cos_degrees(ti);
    for (double phi : sweep.angle_deg)
      sweep.add_sample(frame.at(-ti, phi), s.cosine ? cos_theta_o * cos_theta_o : 1.0);
  }
  return sweep;
}

// ---- Curves, legend, peaks ----

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

// Plotted value of one channel (0..2) or the luminance (-1) of incidence i, angle k.
double sample_value(const Sweep& sweep, const v1::EvaluateResponse& response, std::size_t i, std::size_t k,
                    int channel) {
  const std::size_t sample = i * sweep.angle_deg.size() + k;
  const int q = sweep.first_query + static_cast<int>(sample);
  const double f = channel < 0 ? luminance(response.f(3 * q), response.f(3 * q + 1), response.f(3 * q + 2))
                               : response.f(3 * q + channel);
  return f * sweep.weight[sample];
}

PolarCurve make_curve(const Sweep& sweep, const v1::EvaluateResponse& response, std::size_t i, int channel,
                      const Color& color) {
  PolarCurve curve{sweep.angle_deg, {}, color};
  for (std::size_t k = 0; k < sweep.angle_deg.size(); ++k) curve.value.push_back(sample_value(sweep, response, i, k, channel));
  return curve;
}

// Labels are ASCII: OpenImageIO 2.4's render_text drops the high bits of non-ASCII characters.
std::string degrees(double v) { return format_value("%g deg", v); }

double max_value(const std::vector<PolarCurve>& curves) {
  double max = 0.0;
  for (const PolarCurve& c : curves)
    for (double v : c.value)
      if (std::isfinite(v)) max = std::max(max, v);
  return max;
}

// A plot of the sweep's curves (one per incidence, or per incidence and channel), a light marker per incidence
// at the plot angle `light_deg(theta_i)`, and the legend; autoscaled to the largest value.
PolarPlot make_plot(const PlotSettings& s, const Sweep& sweep, const v1::EvaluateResponse& response,
                    const std::function<double(double)>& light_deg) {
  PolarPlot plot;
  plot.size = s.size;
  plot.full_circle = sweep.full_circle;
  const std::size_t n = s.incidence_deg.size();
  for (std::size_t i = 0; i < n; ++i) {
    const Color marker = s.rgb ? lighten(kMarkerGray, i, n) : incidence_color(i);
    if (s.rgb)
      for (int c = 0; c < 3; ++c)
        plot.curves.push_back(make_curve(sweep, response, i, c, lighten(kChannelColors[c], i, n)));
    else
      plot.curves.push_back(make_curve(sweep, response, i, -1, marker));
    plot.markers.push_back({light_deg(s.incidence_deg[i]), marker});
    plot.legend.push_back({marker, "theta_i = " + degrees(s.incidence_deg[i])});
  }
  if (s.rgb)
    for (int c = 0; c < 3; ++c) plot.legend.push_back({kChannelColors[c], std::string(1, "RGB"[c])});
  const double max = max_value(plot.curves);
  plot.scale = max > 0.0 ? max : 1.0;  // an all-zero lobe still gets a drawable grid
  return plot;
}

std::string quantity_note(const PlotSettings& s, const v1::EvaluateResponse& response, const std::string& weighted) {
  return response.model() + ", " + precision_name(response.precision()) + ": " +
         (s.rgb ? "R, G, B of " : "luminance of ") + (s.cosine ? weighted : "f") + " (1/sr)";
}

// Prints "LOBE,THETA_I,ANGLE,VALUE" for incidence i: the largest luminance of the plotted value over the plot
// angles that `keep` accepts, and its plot angle (the first on ties; 0 with value 0 when none is positive).
void print_peak(const char* lobe, const PlotSettings& s, const Sweep& sweep, const v1::EvaluateResponse& response,
                std::size_t i, const std::function<bool(double)>& keep) {
  double best_angle = 0.0, best = 0.0;
  for (std::size_t k = 0; k < sweep.angle_deg.size(); ++k) {
    const double v = sample_value(sweep, response, i, k, -1);
    if (keep(sweep.angle_deg[k]) && std::isfinite(v) && v > best) {
      best = v;
      best_angle = sweep.angle_deg[k];
    }
  }
  std::printf("%s,%g,%.9g,%.9g\n", lobe, s.incidence_deg[i], best_angle, best);
}

v1::EvaluateResponse evaluate(Client& client, const ParsedOptions& options, const v1::EvaluateRequest& request) {
  v1::EvaluateResponse response = client.evaluate(request);
  if (options.has("verbose")) print_timing(std::cerr, response, request.wi_size() / 3);
  return response;
}

// ---- The views ----

int run_polar(const PlotSettings& s, const ParsedOptions& options, Client& client, v1::EvaluateRequest request,
              bool full_circle) {
  Sweep sweep = in_plane_sweep(s, full_circle);
  add_queries(sweep, request);
  const v1::EvaluateResponse response = evaluate(client, options, request);

  PolarPlot plot = make_plot(s, sweep, response, [](double ti) { return -ti; });
  plot.title = material_label(request.material());
  plot.notes = {quantity_note(s, response, full_circle ? "f |cos(theta_o)|" : "f cos(theta_o)"),
                "plane of incidence phi = " + degrees(s.plane_phi_deg)};
  if (full_circle) {
    plot.upper_label = "reflection";
    plot.lower_label = "transmission";
  }
  write_polar_plot(plot, s.out);
  std::printf("%.9g\n", max_value(plot.curves));
  if (full_circle)
    for (std::size_t i = 0; i < s.incidence_deg.size(); ++i) {
      print_peak("reflection", s, sweep, response, i, [](double to) { return std::abs(to) < 90.0; });
      print_peak("transmission", s, sweep, response, i, [](double to) { return std::abs(to) > 90.0; });
    }
  return 0;
}

std::string vector_text(const Vec3& v) {
  char text[96];
  std::snprintf(text, sizeof text, "(%.3g, %.3g, %.3g)", v[0] + 0.0, v[1] + 0.0, v[2] + 0.0);  // + 0.0: no "-0"
  return text;
}

// Two panels in one PNG: the longitudinal lobe above, the azimuthal lobe below.
int run_fiber(const PlotSettings& s, const ParsedOptions& options, Client& client, v1::EvaluateRequest request,
              const MaterialModel& model) {
  const std::string& axis_param = model.info.fiber_axis_param();
  const FiberFrame frame = fiber_frame(axis_param.empty() ? std::vector<double>{}
                                                          : parameter_values(model, request.material(), axis_param));
  Sweep longitudinal = fiber_longitudinal_sweep(s, frame), azimuthal = fiber_azimuthal_sweep(s, frame);
  add_queries(longitudinal, request);
  add_queries(azimuthal, request);
  const v1::EvaluateResponse response = evaluate(client, options, request);

  PolarPlot top = make_plot(s, longitudinal, response, [](double ti) { return ti; });
  top.title = material_label(request.material()) + ": longitudinal lobe";
  top.notes = {quantity_note(s, response, "f cos^2(theta_o)"),
               "axis t = " + vector_text(frame.t) + " (to the right), normal u = " + vector_text(frame.u) + " (up)",
               "light at theta_i = asin(wi.t), phi_i = 0; up: phi_o = 0 (R),",
               "down: phi_o = 180 (forward, R + TT)"};
  top.upper_label = "back (phi_o = 0)";
  top.lower_label = "forward (phi_o = 180)";
  PolarPlot bottom = make_plot(s, azimuthal, response, [](double) { return 0.0; });
  bottom.title = "azimuthal lobe at theta_o = -theta_i";
  bottom.notes = {"phi_o around the axis seen end-on, from u (up) toward v = t x u",
                  "R at the back (up), TT forward (down, phi_o = 180)"};

  const double top_height = polar_plot_height_units(top);
  Canvas canvas(s.size, static_cast<int>(std::lround(s.size * (top_height + polar_plot_height_units(bottom)) /
                                                     kUnitsPerWidth)));
  draw_polar_plot(canvas, top, 0.0);
  draw_polar_plot(canvas, bottom, top_height);
  canvas.write(s.out);
  const auto everywhere = [](double) { return true; };
  for (std::size_t i = 0; i < s.incidence_deg.size(); ++i) {
    print_peak("longitudinal", s, longitudinal, response, i, everywhere);
    print_peak("azimuthal", s, azimuthal, response, i, everywhere);
  }
  return 0;
}

int run_plot(const ParsedOptions& options) {
  const std::optional<std::string> view = options.last("view");
  if (view && *view != "polar" && *view != "fiber") return run_plot_view(*view, options);
  const PlotSettings settings = read_settings(options);
  v1::EvaluateRequest request = material_request(options);
  Client client(options);
  const MaterialModel model = find_material_model(client, request.material());
  const bool fiber_model = !model.info.fiber_axis_param().empty();
  if (view.value_or(fiber_model ? "fiber" : "polar") == "fiber")
    return run_fiber(settings, options, client, request, model);
  const bool transmits = request.material().has_transmission() || model.info.transmission();
  return run_polar(settings, options, client, request, settings.full_circle || transmits);
}

OptionList plot_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"out", "FILE.png", "output image (required)"},
      {"incidence", "DEG,...", "incidence angles theta_i in degrees (default 0,30,60)"},
      {"plane-phi", "DEG", "azimuth of the plane of incidence: 0 = x-z plane (default), 90 = y-z plane"},
      {"full-circle", "", "polar: theta_o over the whole circle, transmission below (default when the material transmits)"},
      {"channels", "lum|rgb", "plot the luminance (default) or each RGB channel"},
      {"no-cos", "", "plot f instead of f |cos(theta_o)| (fiber: f cos^2(theta_o))"},
      {"samples", "N", "outgoing directions per curve (default 721 over the half circle, 1440 over the full one)"},
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
      "  With --full-circle (automatic for materials with transmission: thin_layer, fiber, --layer curtains)\n"
      "  theta_o sweeps the whole circle at -180 + (k + 1/2) 360 / N, reflection above the surface line and\n"
      "  transmission below, f |cos(theta_o)|. After the maximum it prints one line per incidence and side:\n"
      "  reflection|transmission,THETA_I,THETA_O,PEAK, the largest luminance of the plotted value and where.\n"
      "--view fiber (default for the fiber model): in the fiber frame (t the axis parameter, u = +z made\n"
      "  perpendicular to t, v = t x u), the light at theta_i from the normal plane (sin theta = w.t), phi_i = 0.\n"
      "  Top panel, longitudinal lobe: wo in the t-u plane, upper half phi_o = 0 (R), lower half phi_o = 180\n"
      "  (forward: R + TT), theta_o = asin(wo.t); bottom panel, azimuthal lobe: phi_o around the axis at\n"
      "  theta_o = -theta_i. Both plot f cos^2(theta_o) (the density whose integral over theta_o, phi_o is the\n"
      "  scattered fraction). Prints longitudinal|azimuthal,THETA_I,PLOT_ANGLE,PEAK (luminance) per incidence.\n"
      "  One PNG: the longitudinal panel above the azimuthal one.\n"
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
