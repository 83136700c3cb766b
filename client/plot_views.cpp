#include "client/plot_views.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <numbers>
#include <string>
#include <vector>

#include "client/canvas.h"
#include "client/directions.h"
#include "client/material.h"
#include "client/rpc.h"
#include "server/models/tabulation/angles.h"

namespace loomlight::client {
namespace {

namespace tab = loomlight::tabulation;

constexpr std::size_t kMaxQueriesPerCall = std::size_t{1} << 20;  // the server's documented limit
// Albedo quadrature: Gauss-Legendre in mu = cos(theta_o) on (0, 1), uniform midpoints in phi_o.
constexpr int kAlbedoMuNodes = 32, kAlbedoPhiNodes = 64;
constexpr int kMaxImageResolution = 1024;  // thd cells per side, sphere pixels across
// Layout in units of 1/800 of the width (client/canvas.h).
constexpr double kTop = 110, kBottom = 60, kLeft = 80, kRight = 40;

struct Common {
  std::string out;
  int size = 800;
  v1::EvaluateRequest material;  // the material and precision, no directions
};

Common read_common(const ParsedOptions& options) {
  Common c;
  const auto out = options.last("out");
  if (!out || out->empty()) throw UsageError("plot needs --out FILE.png");
  c.out = *out;
  if (auto px = options.last("size")) c.size = parse_int(*px, "--size", 100, 8000);
  c.material = material_request(options);
  return c;
}

// f for every query of `queries` (its material and precision), in calls within the server's limit.
std::vector<double> evaluate_all(const ParsedOptions& options, const v1::EvaluateRequest& queries) {
  Client client(options);
  std::vector<double> f;
  const int n = queries.wi_size() / 3;
  for (int first = 0; first < n; first += static_cast<int>(kMaxQueriesPerCall)) {
    const int count = std::min<int>(static_cast<int>(kMaxQueriesPerCall), n - first);
    v1::EvaluateRequest part;
    *part.mutable_material() = queries.material();
    part.set_precision(queries.precision());
    part.mutable_wi()->Add(queries.wi().begin() + 3 * first, queries.wi().begin() + 3 * (first + count));
    part.mutable_wo()->Add(queries.wo().begin() + 3 * first, queries.wo().begin() + 3 * (first + count));
    const v1::EvaluateResponse response = client.evaluate(part);
    if (options.has("verbose")) print_timing(std::cerr, response, count);
    f.insert(f.end(), response.f().begin(), response.f().end());
  }
  return f;
}

double srgb(double linear) {
  return linear <= 0.0031308 ? 12.92 * linear : 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
}

// 1 / (99th percentile of the brightest channel), so the brightest 1% clip; 1 when all is black.
double automatic_exposure(const std::vector<double>& rgb) {
  std::vector<double> brightest;
  for (std::size_t p = 0; p + 2 < rgb.size(); p += 3) brightest.push_back(std::max({rgb[p], rgb[p + 1], rgb[p + 2]}));
  if (brightest.empty()) return 1.0;
  const std::size_t rank = static_cast<std::size_t>(0.99 * static_cast<double>(brightest.size() - 1));
  std::nth_element(brightest.begin(), brightest.begin() + rank, brightest.end());
  return brightest[rank] > 0.0 && std::isfinite(1.0 / brightest[rank]) ? 1.0 / brightest[rank] : 1.0;
}

double exposure_option(const ParsedOptions& options, const std::vector<double>& rgb) {
  const auto text = options.last("exposure");
  if (!text) return automatic_exposure(rgb);
  const double e = parse_number(*text, "--exposure");
  if (!(e > 0.0) || !std::isfinite(e)) throw UsageError("--exposure must be a positive number");
  return e;
}

// Linear RGB times the exposure, clamped, through the sRGB transfer function: display values in [0, 1].
std::vector<float> tone_map(const std::vector<double>& rgb, double exposure) {
  std::vector<float> out(rgb.size());
  for (std::size_t i = 0; i < rgb.size(); ++i)
    out[i] = static_cast<float>(srgb(std::clamp(std::isfinite(rgb[i]) ? rgb[i] * exposure : 0.0, 0.0, 1.0)));
  return out;
}

std::string degrees(double v) { return format_value("%g deg", v); }

std::string material_note(const Common& c, const std::string& what) {
  return material_label(c.material.material()) + ", " + precision_name(c.material.precision()) + ": " + what;
}

// ---- theta_h / theta_d image slice (BRDF Explorer's "image slice") ----

int run_thd(const ParsedOptions& options) {
  const Common c = read_common(options);
  const int n = options.last("resolution") ? parse_int(*options.last("resolution"), "--resolution", 2, kMaxImageResolution) : 128;
  const double phi_d = options.last("phi-d") ? parse_number(*options.last("phi-d"), "--phi-d") : 90.0;
  const double phi_h = options.last("phi-h") ? parse_number(*options.last("phi-h"), "--phi-h") : 0.0;
  if (!std::isfinite(phi_d) || !std::isfinite(phi_h)) throw UsageError("--phi-d and --phi-h must be finite");
  // Cell (row r from the top, column k): theta_h = (k + 1/2) 90 / n, theta_d = 90 - (r + 1/2) 90 / n.
  v1::EvaluateRequest request = c.material;
  for (int r = 0; r < n; ++r)
    for (int k = 0; k < n; ++k) {
      tab::Direction wi, wo;
      tab::HalfDiffDirections(tab::CosSin::Degrees(tab::BinCentreDeg(k, n, 90.0)), tab::CosSin::Degrees(phi_h),
                              tab::CosSin::Degrees(90.0 - tab::BinCentreDeg(r, n, 90.0)), tab::CosSin::Degrees(phi_d),
                              &wi, &wo);
      add_query(request, wi, wo);
    }
  const std::vector<double> f = evaluate_all(options, request);
  const double exposure = exposure_option(options, f);

  const double height_units = kTop + (800 - kLeft - kRight) + kBottom;
  Canvas canvas(c.size, static_cast<int>(std::lround(c.size * height_units / 800)));
  const double u = canvas.unit();
  const Axes axes{{kLeft * u, kTop * u}, {(800 - kRight) * u, (height_units - kBottom) * u}, 90, 90};
  canvas.image(axes.top_left, axes.bottom_right, n, n, tone_map(f, exposure));
  draw_axes(canvas, axes, 15, 15, "theta_h (deg)", "theta_d (deg)", false);
  draw_title(canvas, material_label(c.material.material()),
             {material_note(c, "f (1/sr), tone-mapped, exposure " + format_value("%.3g", exposure)),
              "phi_d = " + degrees(phi_d) + ", phi_h = " + degrees(phi_h)});
  canvas.write(c.out);
  std::printf("%.9g\n", exposure);
  return 0;
}

// ---- Directional albedo against incidence angle ----

struct Quadrature {
  std::vector<double> x, w;
};

// Gauss-Legendre nodes and weights on (0, 1) (Newton's iteration on the Legendre polynomial).
Quadrature gauss_legendre_01(int n) {
  Quadrature q;
  for (int i = 0; i < n; ++i) {
    double z = std::cos(std::numbers::pi * (i + 0.75) / (n + 0.5)), derivative = 1;
    for (int iteration = 0; iteration < 100; ++iteration) {
      double p1 = 1, p2 = 0;
      for (int j = 1; j <= n; ++j) {
        const double p3 = p2;
        p2 = p1;
        p1 = ((2.0 * j - 1) * z * p2 - (j - 1.0) * p3) / j;
      }
      derivative = n * (z * p1 - p2) / (z * z - 1);
      const double step = p1 / derivative;
      z -= step;
      if (std::fabs(step) < 1e-15) break;
    }
    q.x.push_back((z + 1) / 2);
    q.w.push_back(1.0 / ((1 - z * z) * derivative * derivative));  // 2 / (...) halved for (0, 1)
  }
  return q;
}

int run_albedo(const ParsedOptions& options) {
  const Common c = read_common(options);
  const int count = options.last("samples") ? parse_int(*options.last("samples"), "--samples", 2, 180) : 45;
  const double phi_i = options.last("plane-phi") ? parse_number(*options.last("plane-phi"), "--plane-phi") : 0.0;
  if (!std::isfinite(phi_i)) throw UsageError("--plane-phi must be finite");
  const Quadrature mu = gauss_legendre_01(kAlbedoMuNodes);
  // Queries: incidence k, side (0 above: reflection, 1 below: transmission), mu node j, phi node m.
  v1::EvaluateRequest request = c.material;
  std::vector<double> theta_i(count);
  for (int k = 0; k < count; ++k) {
    theta_i[k] = tab::BinCentreDeg(k, count, 90.0);
    const Vec3 wi = direction_from_degrees(theta_i[k], phi_i);
    for (int side = 0; side < 2; ++side)
      for (int j = 0; j < kAlbedoMuNodes; ++j)
        for (int m = 0; m < kAlbedoPhiNodes; ++m) {
          const double z = side == 0 ? mu.x[j] : -mu.x[j], s = std::sqrt(1 - z * z);
          const double phi = 2 * std::numbers::pi * (m + 0.5) / kAlbedoPhiNodes;
          add_query(request, wi, {s * std::cos(phi), s * std::sin(phi), z});
        }
  }
  const std::vector<double> f = evaluate_all(options, request);
  // albedo[side][k][channel] = sum over nodes of f mu w_j (2 pi / M).
  std::vector<double> albedo[2] = {std::vector<double>(3 * count, 0.0), std::vector<double>(3 * count, 0.0)};
  std::size_t q = 0;
  for (int k = 0; k < count; ++k)
    for (int side = 0; side < 2; ++side)
      for (int j = 0; j < kAlbedoMuNodes; ++j)
        for (int m = 0; m < kAlbedoPhiNodes; ++m, ++q)
          for (int ch = 0; ch < 3; ++ch)
            albedo[side][3 * k + ch] += f[3 * q + ch] * mu.x[j] * mu.w[j] * 2 * std::numbers::pi / kAlbedoPhiNodes;
  const bool transmits = std::any_of(albedo[1].begin(), albedo[1].end(), [](double a) { return a > 0; });
  double top = 1.0;  // the energy bound stays in view
  for (const auto& side : albedo)
    for (double a : side) top = std::max(top, a);

  const double height_units = 600;
  Canvas canvas(c.size, static_cast<int>(std::lround(c.size * height_units / 800)));
  const double u = canvas.unit();
  const Axes axes{{kLeft * u, kTop * u}, {(800 - kRight) * u, (height_units - kBottom) * u}, 90, top * 1.05};
  draw_axes(canvas, axes, 15, nice_step(axes.y_max), "theta_i (deg)", "directional albedo", true);
  canvas.dashed_line(axes.at(0, 1), axes.at(90, 1), kRim, kMarkerWidth);
  std::vector<LegendEntry> legend;
  for (int side = 0; side < (transmits ? 2 : 1); ++side)
    for (int ch = 0; ch < 3; ++ch) {
      const Color color = kChannelColors[ch];
      for (int k = 0; k + 1 < count; ++k) {
        const Point a = axes.at(theta_i[k], albedo[side][3 * k + ch]), b = axes.at(theta_i[k + 1], albedo[side][3 * (k + 1) + ch]);
        if (side == 0) canvas.line(a, b, color, kCurveWidth);
        else canvas.dashed_line(a, b, color, kCurveWidth);
      }
      legend.push_back({color, std::string(1, "RGB"[ch]) + (side == 0 ? " reflected" : " transmitted (dashed)")});
    }
  draw_title(canvas, material_label(c.material.material()),
             {material_note(c, "integral of f cos(theta_o) over the outgoing hemisphere"),
              "quadrature: " + std::to_string(kAlbedoMuNodes) + " Gauss-Legendre nodes in cos(theta_o) x " +
                  std::to_string(kAlbedoPhiNodes) + " in phi_o; phi_i = " + degrees(phi_i)});
  draw_legend(canvas, legend);
  canvas.write(c.out);
  for (int k = 0; k < count; ++k)
    std::printf("%g,%.6g,%.6g,%.6g%s\n", theta_i[k], albedo[0][3 * k], albedo[0][3 * k + 1], albedo[0][3 * k + 2],
                transmits ? (format_value(",%.6g", albedo[1][3 * k]) + format_value(",%.6g", albedo[1][3 * k + 1]) +
                             format_value(",%.6g", albedo[1][3 * k + 2])).c_str()
                          : "");
  return 0;
}

// ---- A lit sphere ----

// View space: x right, y up, the viewer along +z (orthographic). At a sphere point with normal n the
// shading frame is: local z = n; local x (thread 1) = view +x projected onto the tangent plane, so threads
// 1 run left-right and threads 2 (local y = n x local x) bottom-top across the middle of the image.
struct Frame {
  Vec3 t, b, n;
  Vec3 local(const Vec3& w) const { return {dot(w, t), dot(w, b), dot(w, n)}; }
};
Frame sphere_frame(const Vec3& n) {
  Vec3 x = {1, 0, 0};
  if (std::fabs(n[0]) > 0.999999) x = {0, 1, 0};  // only at the silhouette's two side points
  const Vec3 t = normalized({x[0] - dot(x, n) * n[0], x[1] - dot(x, n) * n[1], x[2] - dot(x, n) * n[2]});
  return {t, cross(n, t), n};
}

int run_sphere(const ParsedOptions& options) {
  const Common c = read_common(options);
  const int n = options.last("resolution") ? parse_int(*options.last("resolution"), "--resolution", 8, kMaxImageResolution)
                                           : std::min(kMaxImageResolution, c.size);
  const auto light_angles = parse_numbers(options.last("light").value_or("40,135"), "--light", 2);
  const Vec3 light = direction_from_degrees(light_angles[0], light_angles[1]);
  const Vec3 view = {0, 0, 1};
  v1::EvaluateRequest request = c.material;
  std::vector<int> pixel_of_query;
  std::vector<double> cosine;
  for (int r = 0; r < n; ++r)
    for (int k = 0; k < n; ++k) {
      const double x = 2 * (k + 0.5) / n - 1, y = 1 - 2 * (r + 0.5) / n;
      const double z2 = 1 - x * x - y * y;
      if (z2 <= 1e-6) continue;  // outside the disc (and the rim, where n.wo is 0)
      const Frame frame = sphere_frame({x, y, std::sqrt(z2)});
      const Vec3 wi = frame.local(light), wo = frame.local(view);
      add_query(request, wi, wo);
      pixel_of_query.push_back(r * n + k);
      cosine.push_back(std::fabs(wi[2]));  // L_o = f E |n.wi| (SPEC.md section 1), E = 1
    }
  const std::vector<double> f = evaluate_all(options, request);
  std::vector<double> radiance(3 * std::size_t(n) * n, 0.0);
  std::vector<double> lit;  // the sphere's pixels only, for the exposure
  for (std::size_t q = 0; q < pixel_of_query.size(); ++q)
    for (int ch = 0; ch < 3; ++ch) {
      radiance[3 * pixel_of_query[q] + ch] = f[3 * q + ch] * cosine[q];
      lit.push_back(radiance[3 * pixel_of_query[q] + ch]);
    }
  const double exposure = exposure_option(options, lit);
  std::vector<float> display = tone_map(radiance, exposure);
  std::vector<bool> on_sphere(std::size_t(n) * n, false);
  for (int p : pixel_of_query) on_sphere[p] = true;
  for (std::size_t p = 0; p < on_sphere.size(); ++p)
    if (!on_sphere[p]) std::fill_n(display.begin() + 3 * p, 3, 0.18f);  // a grey backdrop shows the silhouette

  const double side = 800 - kLeft - kRight, height_units = kTop + side + kBottom / 2;
  Canvas canvas(c.size, static_cast<int>(std::lround(c.size * height_units / 800)));
  const double u = canvas.unit();
  canvas.image({kLeft * u, kTop * u}, {(kLeft + side) * u, (kTop + side) * u}, n, n, display);
  draw_title(canvas, material_label(c.material.material()),
             {material_note(c, "radiance f |n.wi| under one light, exposure " + format_value("%.3g", exposure)),
              "light at theta " + degrees(light_angles[0]) + ", phi " + degrees(light_angles[1]) +
                  " (view space, viewer on +z); thread 1 runs left-right"});
  canvas.write(c.out);
  std::printf("%.9g\n", exposure);
  return 0;
}

}  // namespace

Vec3 normalized(const Vec3& v) {
  const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / len, v[1] / len, v[2] / len};
}
double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

OptionList plot_view_options() {
  return {
      {"view", "polar|fiber|thd|albedo|sphere", "what to draw (default fiber for the fiber model, else polar)"},
      {"resolution", "N", "thd: N x N cells (default 128); sphere: pixels across (default --size, at most 1024)"},
      {"phi-d", "DEG", "thd: the difference azimuth of the slice (default 90)"},
      {"phi-h", "DEG", "thd: the half-vector azimuth (default 0; anisotropic models change with it)"},
      {"light", "THETA,PHI", "sphere: light direction in view space, degrees from the viewer (default 40,135)"},
      {"exposure", "X", "thd, sphere: scale before clamping (default: the 99th percentile maps to 1)"},
  };
}

int run_plot_view(std::string_view view, const ParsedOptions& options) {
  if (view == "thd") return run_thd(options);
  if (view == "albedo") return run_albedo(options);
  if (view == "sphere") return run_sphere(options);
  throw UsageError("--view: expected polar, fiber, thd, albedo or sphere, got '" + std::string(view) + "'");
}

}  // namespace loomlight::client
