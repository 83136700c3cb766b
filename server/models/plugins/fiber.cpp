// Registry entry of the fiber scattering model (Wu and Yuksel Sec. 4.3, SPEC.md section 5): schema, the
// SPEC's presets, and packing, which computes on the host (in double) everything the kernel must not
// integrate: the fiber frame, i0e(kappa), the truncation tables rho of the longitudinal normalisation G and
// the ambient tables of Eqs. 7-10 (kernels/models/fiber.h describes the layout).
//
// `mode` is the launch-uniform value (PackedMaterial::uniform): the simple and the physically based model
// are different code paths, so the kernel branches once per launch instead of computing both per lane.
#include <algorithm>
#include <cmath>
#include <functional>

#include "server/models/registry.h"

namespace loomlight::models {
namespace {
namespace layout {
typedef double real;
#include "common/shim.h"
#include "models/fiber.h"
}  // namespace layout

constexpr double kDegree = M_PI / 180.0;
constexpr double kHalfPi = M_PI / 2;
// Gaussian lobes are integrated over +-kWindow widths around their centre: exp(-72) is below double's reach
// relative to the peak.
constexpr double kWindow = 12.0;

double Gaussian(double s, double x) {
  const double t = x / s;
  return std::exp(-0.5 * t * t) / (s * std::sqrt(2.0 * M_PI));
}

// Composite Simpson rule on [-pi/2, pi/2] with nodes 1/16 of a lobe width apart (at least 256 intervals):
// integrands here are Gaussians of width >= s times cos^2 and polynomials in cos, smooth on the closed
// interval, so the rule's error is ~(h/s)^4/180 ~ 1e-7 relative or less.
struct Grid {
  explicit Grid(double s) {
    n = std::max(256, 2 * static_cast<int>(std::ceil(M_PI / (s / 16.0) / 2.0)));
    h = M_PI / n;
  }
  double node(int j) const { return -kHalfPi + j * h; }
  double weight(int j) const { return h / 3.0 * (j == 0 || j == n ? 1.0 : (j % 2 ? 4.0 : 2.0)); }
  // Sum of weight(j) * term(j) over the nodes within `half_width` of `centre`.
  double Sum(double centre, double half_width, const std::function<double(int)>& term) const {
    const int lo = std::max(0, static_cast<int>(std::floor((centre - half_width + kHalfPi) / h)));
    const int hi = std::min(n, static_cast<int>(std::ceil((centre + half_width + kHalfPi) / h)));
    double sum = 0.0;
    for (int j = lo; j <= hi; ++j) sum += weight(j) * term(j);
    return sum;
  }
  int n;
  double h;
};

// G(m, s) = int_{-pi/2}^{pi/2} cos^2(theta) g(s, theta - m) dtheta, by quadrature.
double NormalisationG(const Grid& grid, double s, double m) {
  return grid.Sum(m, kWindow * s, [&](int j) {
    const double th = grid.node(j), c = std::cos(th);
    return c * c * Gaussian(s, th - m);
  });
}

// Schlick's Fs(theta) = C_R + (1 - C_R)(1 - cos theta)^5.
double Schlick(double c_r, double theta) { return c_r + (1.0 - c_r) * std::pow(1.0 - std::cos(theta), 5.0); }

// One longitudinal lobe's packed constants: 1/s, A, B, FB_RHO_N / D, and its rho table.
void PackLobe(double s, double* constants, double* rho) {
  const double a = -0.5 * std::expm1(-2.0 * s * s), b = std::exp(-2.0 * s * s);
  const double range = std::min(kHalfPi, kWindow * s);
  constants[0] = 1.0 / s;
  constants[1] = a;
  constants[2] = b;
  constants[3] = FB_RHO_N / range;
  const Grid grid(s);
  for (int k = 0; k <= FB_RHO_N; ++k) {
    const double delta = range * k / FB_RHO_N, c = std::sin(delta);  // c = cos(m), m = pi/2 - delta
    rho[k] = NormalisationG(grid, s, kHalfPi - delta) / (a + b * c * c);
  }
}

// Ambient table entries for |theta_o| = k (pi/2) / FB_AMB_N: sum over lobes of
// int weight(theta_i) g(width, theta_o + theta_i) / norm(theta_i) cos^2(theta_i) dtheta_i (norm 1 when null).
struct AmbientLobe {
  double width;
  std::function<double(double)> weight;  // of theta_i, one channel
  bool normalised;                       // divide by G(theta_i, width)
};
void AmbientTable(const std::vector<AmbientLobe>& lobes, double* table) {
  std::fill(table, table + FB_AMB_N + 1, 0.0);
  for (const AmbientLobe& lobe : lobes) {
    const Grid grid(lobe.width);
    std::vector<double> inv_norm(grid.n + 1, 1.0), weight(grid.n + 1);
    for (int j = 0; j <= grid.n; ++j) {
      const double th = grid.node(j), c = std::cos(th);
      if (lobe.normalised) inv_norm[j] = 1.0 / NormalisationG(grid, lobe.width, th);
      weight[j] = lobe.weight(th) * c * c * inv_norm[j];
    }
    for (int k = 0; k <= FB_AMB_N; ++k) {
      const double theta_o = kHalfPi * k / FB_AMB_N;
      table[k] += grid.Sum(-theta_o, kWindow * lobe.width,
                           [&](int j) { return weight[j] * Gaussian(lobe.width, theta_o + grid.node(j)); });
    }
  }
}

std::vector<ParamSpec> Schema() {
  return {
      {"mode", ParamType::kInt, "1", 0, 1, {1},
       "0: simple model (Eq. 5 + Lambertian); 1: physically based R + TT (Eq. 6) + Lambertian", 1, 1},
      {"axis", ParamType::kRealList, "1", -1.0, 1.0, {1.0, 0.0, 0.0},
       "fiber axis t in the shading frame (normalised on packing)", 3, 3},
      {"kd", ParamType::kRgb, "1", 0.0, 1.0, {0.0, 0.0, 0.0},
       "Lambertian albedo on the fiber's surface normal (+z made perpendicular to the axis), both modes", 3, 3},
      {"ks", ParamType::kRgb, "1", 0.0, 10.0, {0.2, 0.2, 0.2}, "specular colour k_specular (simple model)", 3, 3},
      {"beta", ParamType::kReal, "deg", 0.5, 60.0, {5.0}, "longitudinal width of the specular lobe (simple model)",
       1, 1},
      {"c_r", ParamType::kRgb, "1", 0.0, 1.0, {0.040, 0.087, 0.087},
       "Schlick reflectance at normal incidence C_R (physically based model)", 3, 3},
      {"c_tt", ParamType::kRgb, "1", 0.0, 1.0, {0.452, 0.725, 0.948},
       "transmission colour C_TT (physically based model)", 3, 3},
      {"beta_r", ParamType::kReal, "deg", 0.5, 60.0, {7.238}, "longitudinal width of the R lobe", 1, 1},
      {"beta_tt", ParamType::kReal, "deg", 0.5, 60.0, {10.0}, "longitudinal width of the TT lobe", 1, 1},
      {"gamma_tt", ParamType::kReal, "deg", 0.5, 90.0, {25.989}, "azimuthal width of the TT lobe", 1, 1},
  };
}

PresetSpec Preset(std::string name, std::string description, std::vector<double> c_r, std::vector<double> c_tt,
                  double beta_r, double beta_tt, double gamma_tt) {
  return {std::move(name), std::move(description),
          {{"mode", {1}},
           {"c_r", std::move(c_r)},
           {"c_tt", std::move(c_tt)},
           {"beta_r", {beta_r}},
           {"beta_tt", {beta_tt}},
           {"gamma_tt", {gamma_tt}}}};
}

// SPEC.md section 5 (Khungurn et al.'s fits as listed by Wu and Yuksel); no diffuse term (kd = 0).
std::vector<PresetSpec> Presets() {
  return {
      Preset("fleece", "Fleece fibers, physically based R + TT", {.040, .087, .087}, {.452, .725, .948}, 7.238, 10,
             25.989),
      Preset("gabardine", "Gabardine fibers, physically based R + TT", {.185, .047, .069}, {.999, .330, .354}, 2.141,
             10, 23.548),
      Preset("silk", "Silk fibers, physically based R + TT", {.745, .008, .07}, {.62, .553, .562}, 1, 10, 19.823),
      Preset("cotton", "Cotton fibers, physically based R + TT", {.989, .959, .874}, {.999, .999, .999}, 1, 27.197,
             38.269),
      Preset("polyester", "Polyester fibers, physically based R + TT", {.7, .7, .7}, {.6, 0, .8}, 5.238, 10, 25),
  };
}

double Norm(const std::vector<double>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

template <class A, class B>
double Dot3(const A* a, const B* b) {
  return double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2];
}

// The fiber frame of an axis (any length > 0): t along it, u = +z made perpendicular to t (x instead when t is
// along z), v = t x u. Rounded to float, so that the double reference and the float kernels use the same
// frame (the lobe peaks are sharp enough that a 6e-8 tilt of the axis would show as 1e-5 differences).
struct Frame {
  double t[3], u[3], v[3];
};
Frame FrameOf(const double* axis) {
  const double len = std::sqrt(Dot3(axis, axis));
  const double t[3] = {axis[0] / len, axis[1] / len, axis[2] / len};
  double u[3] = {-t[2] * t[0], -t[2] * t[1], 1.0 - t[2] * t[2]};
  // |u| <= 1 (t is unit), so a plain square root cannot overflow; 3-argument hypot costs several times more,
  // and this runs per query when each query carries its own fiber axis.
  if (Dot3(u, u) < 1e-12) {
    u[0] = 1.0 - t[0] * t[0];
    u[1] = -t[0] * t[1];
    u[2] = -t[0] * t[2];
  }
  const double ul = std::sqrt(Dot3(u, u));
  for (double& x : u) x /= ul;
  const double v[3] = {t[1] * u[2] - t[2] * u[1], t[2] * u[0] - t[0] * u[2], t[0] * u[1] - t[1] * u[0]};
  Frame f;
  for (int k = 0; k < 3; ++k) f.t[k] = float(t[k]), f.u[k] = float(u[k]), f.v[k] = float(v[k]);
  return f;
}

class FiberModel : public Model {
 public:
  std::string name() const override { return "fiber"; }
  std::string description() const override {
    return "Wu and Yuksel fiber scattering (Sec. 4.3): the simple specular + Lambertian model or the physically "
           "based R + TT model with normalised longitudinal lobes and a von Mises TT lobe; scatters through "
           "the fiber (wi, wo anywhere on the sphere)";
  }
  const std::vector<ParamSpec>& params() const override { return schema_; }
  const std::vector<PresetSpec>& presets() const override { return presets_; }
  KernelSpec kernel() const override {
    return {.source = "models/fiber.cl", .function = "fiber_eval", .ambient_function = "fiber_ambient"};
  }

  std::string fiber_axis_param() const override { return "axis"; }

  // Each pair's coordinates in its query's frame (t', u', v') become the same coordinates in the material's
  // frame (t, u, v): f depends on the directions only through them.
  // FrameOf's construction in float, inline: it runs for every query of a render (8% of a fiber close-up's
  // host time in double), and its output is float directions in any case.
  void AlignToAxis(const ParamValues& values, const float* axis, size_t n, float* wi, float* wo) const override {
    const Frame m = FrameOf(values.at("axis").data());
    float mt[3], mu[3], mv[3];
    for (int k = 0; k < 3; ++k) mt[k] = float(m.t[k]), mu[k] = float(m.u[k]), mv[k] = float(m.v[k]);
    for (size_t q = 0; q < n; ++q) {
      const float* a = axis + 3 * q;
      const float inv = 1.0f / std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
      const float t[3] = {a[0] * inv, a[1] * inv, a[2] * inv};
      float u[3] = {-t[2] * t[0], -t[2] * t[1], 1.0f - t[2] * t[2]};
      if (u[0] * u[0] + u[1] * u[1] + u[2] * u[2] < 1e-12f) u[0] = 1.0f - t[0] * t[0], u[1] = -t[0] * t[1], u[2] = -t[0] * t[2];
      const float ul = 1.0f / std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
      for (float& x : u) x *= ul;
      const float v[3] = {t[1] * u[2] - t[2] * u[1], t[2] * u[0] - t[0] * u[2], t[0] * u[1] - t[1] * u[0]};
      for (float* w : {wi + 3 * q, wo + 3 * q}) {
        const float x = t[0] * w[0] + t[1] * w[1] + t[2] * w[2];
        const float y = u[0] * w[0] + u[1] * w[1] + u[2] * w[2];
        const float z = v[0] * w[0] + v[1] * w[1] + v[2] * w[2];
        for (int k = 0; k < 3; ++k) w[k] = x * mt[k] + y * mu[k] + z * mv[k];
      }
    }
  }

  std::string Validate(const ParamValues& v) const override {
    if (Norm(v.at("axis")) < 1e-6) return "axis: must not be the zero vector";
    return "";
  }

  PackedMaterial PackLayout(const ParamValues& v) const override {
    PackedMaterial m;
    m.uniform = static_cast<int>(v.at("mode")[0]);
    m.data.assign(FB_MATERIAL_SIZE, 0.0);
    double* d = m.data.data();
    const Frame frame = FrameOf(v.at("axis").data());
    const double *t = frame.t, *u = frame.u, *w = frame.v;
    for (int k = 0; k < 3; ++k) {
      d[FB_T + k] = t[k];
      d[FB_U + k] = u[k];
      d[FB_V + k] = w[k];
      d[FB_KD + k] = v.at("kd")[k] / M_PI;
      d[FB_KS + k] = v.at("ks")[k];
      d[FB_CR + k] = v.at("c_r")[k];
      d[FB_CTT + k] = v.at("c_tt")[k];
    }
    const double beta = v.at("beta")[0] * kDegree;
    d[FB_INV_2B2] = 1.0 / (2.0 * beta * beta);
    const double gamma_tt = v.at("gamma_tt")[0] * kDegree;
    const double kappa = 1.0 / (gamma_tt * gamma_tt);
    d[FB_KAPPA] = kappa;
    d[FB_VM_NORM] = 1.0 / (2.0 * M_PI * layout::fb_i0e(kappa));
    const double beta_r = v.at("beta_r")[0] * kDegree, beta_tt = v.at("beta_tt")[0] * kDegree;
    PackLobe(beta_r, d + FB_LOBE_R, d + FB_RHO_R);
    PackLobe(beta_tt, d + FB_LOBE_TT, d + FB_RHO_TT);
    d[FB_AMB_SCALE] = FB_AMB_N / kHalfPi;
    for (int c = 0; c < 3; ++c) {
      std::vector<AmbientLobe> lobes;
      if (m.uniform == FB_MODE_SIMPLE) {
        // int cos(phi/2) dphi over [-pi, pi] = 4; theta_h = theta_sum / 2 is a Gaussian of width 2 beta in the sum.
        const double ks = v.at("ks")[c];
        lobes.push_back({2.0 * beta, [=](double) { return 4.0 * ks * 2.0 * beta * std::sqrt(2.0 * M_PI); }, false});
      } else {
        const double c_r = d[FB_CR + c], c_tt = d[FB_CTT + c];
        lobes.push_back({beta_r, [=](double th) { return Schlick(c_r, th); }, true});
        lobes.push_back({beta_tt, [=](double th) { return c_tt * (1.0 - Schlick(c_r, th)); }, true});
      }
      AmbientTable(lobes, d + FB_AMB + c * (FB_AMB_N + 1));
    }
    return m;
  }

 private:
  std::vector<ParamSpec> schema_ = Schema();
  std::vector<PresetSpec> presets_ = Presets();
};

}  // namespace

}  // namespace loomlight::models

LOOMLIGHT_REGISTER_MODEL(fiber, FiberModel)
