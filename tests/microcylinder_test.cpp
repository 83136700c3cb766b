// The microcylinder model itself (double reference, SPEC.md section 2): presets against the paper's
// tables, tangent-curve sampling, hard cases and energy.
#include <gtest/gtest.h>

#include <array>
#include <cmath>

#include "server/models/registry.h"
#include "tests/testing.h"

namespace loomlight {
namespace {
// The material layout (mc_material_stride) of the shared source.
namespace mc_source {
typedef double real;
#include "common/shim.h"
#include "models/microcylinder.h"
}  // namespace mc_source

using models::Model;
using models::ParamValues;

const Model& Microcylinder() { return *models::Registry::Global().FindModel("microcylinder"); }

ParamValues Preset(const std::string& name) {
  const models::PresetSpec* preset = nullptr;
  const Model* m = models::Registry::Global().FindPreset(name, &preset);
  EXPECT_NE(m, nullptr) << name;
  return m->PresetValues(*preset);
}

// Table 2 (eta, A = colour x factor, kd, gamma_s, gamma_v) and Table 3 (a, offsets, lengths) of Sadeghi et al.,
// transcribed by hand. Thread 1 is the flat / "Dir 1" thread.
struct ThreadRow {
  double a, r, g, b, factor, kd, gs, gv;
  std::vector<double> offsets, lengths;
};
struct PresetRow {
  const char* name;
  double eta;
  ThreadRow t1, t2;
};
const PresetRow kPaper[] = {
    {"linen_plain", 1.46, {0.33, .2, .8, 1, .3, .3, 12, 24, {25, 25}, {1}}, {0.33, .2, .8, 1, .3, .3, 12, 24, {25, 25}, {1}}},
    {"silk_crepe_de_chine", 1.345, {0.75, 1, .95, .05, .12, .2, 5, 10, {-35, -35, 35, 35}, {1, 1, 1}},
     {0.25, 1, .95, .05, .16, .3, 18, 32, {0, 0}, {1}}},
    {"polyester_satin_charmeuse_front", 1.539,
     {0.9, 1, .37, .3, .035, .1, 2.5, 5, {-32, -32, -18, 0, 0, 18, 32, 32}, {1.33, .66, 2, 2, 2, .66, 1.33}},
     {0.1, 1, .37, .3, .2, .7, 30, 60, {0, 0}, {1}}},
    {"polyester_satin_charmeuse_back", 1.539,
     // Table 3d gives six lengths for eight points; the two pieces are joined by a jump (length 0).
     {0.67, 1, .37, .3, .035, .1, 2.5, 5, {-30, -30, 30, 30, -5, -5, 5, 5}, {1.33, 1.33, 1.33, 0, .67, .67, .67}},
     {0.33, 1, .37, .3, .2, .7, 30, 60, {0, 0}, {3}}},
    {"silk_shot", 1.345, {0.86, .1, 1, .4, .2, .1, 4, 8, {-25, -25, 25, 25}, {1.33, 2.67, 1.33}},
     {0.14, 1, 0, .1, .6, .1, 5, 10, {0, 0}, {1}}},
    {"velvet", 1.46, {0.5, .05, .02, 0, .3, .1, 6, 12, {-90, -50}, {1}},
     {0.5, .05, .02, 0, .3, .1, 6, 12, {-90, -55, 55, 90}, {.5, 0, .5}}},
};

TEST(MicrocylinderPresets, MatchThePapersTables) {
  ASSERT_EQ(Microcylinder().presets().size(), std::size(kPaper));
  for (const PresetRow& row : kPaper) {
    SCOPED_TRACE(row.name);
    const ParamValues v = Preset(row.name);
    EXPECT_DOUBLE_EQ(v.at("eta")[0], row.eta);
    EXPECT_EQ(v.at("tangent_samples")[0], 32);
    for (const auto& [t, r] : {std::pair{"thread1.", &row.t1}, std::pair{"thread2.", &row.t2}}) {
      const std::string p = t;
      EXPECT_DOUBLE_EQ(v.at(p + "coverage")[0], r->a);
      const auto& A = v.at(p + "albedo");
      EXPECT_NEAR(A[0], r->r * r->factor, 1e-15);
      EXPECT_NEAR(A[1], r->g * r->factor, 1e-15);
      EXPECT_NEAR(A[2], r->b * r->factor, 1e-15);
      EXPECT_DOUBLE_EQ(v.at(p + "kd")[0], r->kd);
      EXPECT_DOUBLE_EQ(v.at(p + "gamma_s")[0], r->gs);
      EXPECT_DOUBLE_EQ(v.at(p + "gamma_v")[0], r->gv);
      EXPECT_EQ(v.at(p + "tangent_offsets"), r->offsets);
      EXPECT_EQ(v.at(p + "tangent_lengths"), r->lengths);
    }
    EXPECT_EQ(Microcylinder().Validate(v), "");
  }
}

// Distinct tangent k of thread j (0 or 1) in a packed material: (cos, sin), and the samples it stands for.
struct PackedTangent {
  double c, s, count;
};
size_t ThreadStart(const models::PackedMaterial& m, int j) {
  return j == 0 ? 1 : 1 + size_t(mc_source::mc_thread_size(int(m.data[MC_THREAD_HEADER])));
}
int DistinctTangents(const models::PackedMaterial& m, int j) { return int(m.data[ThreadStart(m, j) + MC_THREAD_HEADER - 1]); }
PackedTangent Tangent(const models::PackedMaterial& m, int j, int k) {
  const double* t = &m.data[ThreadStart(m, j) + MC_THREAD_HEADER + 2 * k];
  const double count = std::round(std::hypot(t[0], t[1]));
  return {t[0] / count, t[1] / count, count};
}

TEST(MicrocylinderCurve, SamplesArcLengthMidpointsAndJumps) {
  ParamValues v = Preset("velvet");
  v["tangent_samples"] = {4};
  const models::PackedMaterial m = Microcylinder().Pack(v);
  ASSERT_EQ(m.data.size(), 1 + size_t(mc_source::mc_thread_size(DistinctTangents(m, 0)) +
                                      mc_source::mc_thread_size(DistinctTangents(m, 1))));
  // Thread 2: -90 -> -55 over [0, 0.5], jump, 55 -> 90 over [0.5, 1]; midpoints 1/8, 3/8, 5/8, 7/8.
  const double expected[4] = {-81.25, -63.75, 63.75, 81.25};
  ASSERT_EQ(DistinctTangents(m, 1), 4);
  for (int k = 0; k < 4; ++k) {
    const auto [c, s, count] = Tangent(m, 1, k);
    EXPECT_NEAR(c, std::cos(expected[k] * M_PI / 180), 1e-14) << k;
    EXPECT_NEAR(s, std::sin(expected[k] * M_PI / 180), 1e-14) << k;
    EXPECT_EQ(count, 1) << k;
  }
  // A constant -90 degree offset gives an exactly vertical tangent (cos exactly 0): one distinct tangent for
  // all 4 samples.
  v["thread1.tangent_offsets"] = {-90, -90};
  const models::PackedMaterial flat = Microcylinder().Pack(v);
  ASSERT_EQ(DistinctTangents(flat, 0), 1);
  const auto [c0, s0, n0] = Tangent(flat, 0, 0);
  EXPECT_EQ(c0, 0.0);
  EXPECT_EQ(s0, -1.0);
  EXPECT_EQ(n0, 4);
}

void Push(std::vector<float>& v, double x, double y, double z);

// Equal samples merged (a flat stretch of the curve) give the f of every sample evaluated on its own: the satin's
// thread 1 (flat at -32, 0 and 32 degrees) and its wholly flat thread 2, against the same curves nudged off flat
// by 1e-9 degrees (every sample distinct, f changed by ~1e-11 relative).
TEST(MicrocylinderCurve, EqualSamplesMergedGiveTheSameF) {
  ParamValues v = Preset("polyester_satin_charmeuse_front");
  v["tangent_samples"] = {32};
  const models::PackedMaterial merged = Microcylinder().Pack(v);
  EXPECT_LT(DistinctTangents(merged, 0), 24);
  EXPECT_EQ(DistinctTangents(merged, 1), 1);
  for (int j = 0; j < 2; ++j) {
    double samples = 0;
    for (int k = 0; k < DistinctTangents(merged, j); ++k) samples += Tangent(merged, j, k).count;
    EXPECT_EQ(samples, 32) << "thread " << j + 1;
  }
  ParamValues nudged = v;
  for (const char* t : {"thread1.tangent_offsets", "thread2.tangent_offsets"}) {
    std::vector<double>& o = nudged[t];
    for (size_t k = 0; k < o.size(); ++k) o[k] += 1e-9 * double(k);
  }
  const models::PackedMaterial distinct = Microcylinder().Pack(nudged);
  EXPECT_EQ(DistinctTangents(distinct, 0), 32);
  EXPECT_EQ(DistinctTangents(distinct, 1), 32);
  std::vector<float> wi, wo;
  for (int i = 0; i < 200; ++i) {
    const double a = 0.37 * i, b = 0.71 * i;
    Push(wi, std::cos(a), std::sin(a), 0.05 + 0.9 * std::fabs(std::sin(1.3 * i)));
    Push(wo, std::cos(b), std::sin(b), 0.05 + 0.9 * std::fabs(std::cos(0.7 * i)));
  }
  std::vector<double> f_merged(wi.size()), f_distinct(wi.size());
  Microcylinder().ReferenceEval(merged, wi.data(), wo.data(), nullptr, wi.size() / 3, f_merged.data());
  Microcylinder().ReferenceEval(distinct, wi.data(), wo.data(), nullptr, wi.size() / 3, f_distinct.data());
  double largest = 0;
  for (double x : f_distinct) largest = std::max(largest, x);
  ASSERT_GT(largest, 0);
  for (size_t q = 0; q < f_merged.size(); ++q) EXPECT_NEAR(f_merged[q], f_distinct[q], 1e-8 * largest + 1e-8 * f_distinct[q]) << q;
}

std::vector<double> Reference(const ParamValues& v, const std::vector<float>& wi, const std::vector<float>& wo) {
  std::vector<double> f(wi.size());
  Microcylinder().ReferenceEval(Microcylinder().Pack(v), wi.data(), wo.data(), nullptr, wi.size() / 3, f.data());
  return f;
}

void Push(std::vector<float>& v, double x, double y, double z) {
  const double l = std::sqrt(x * x + y * y + z * z);
  v.insert(v.end(), {float(x / l), float(y / l), float(z / l)});
}

TEST(MicrocylinderModel, ReflectionOnlyAndZeroBelowHorizon) {
  std::vector<float> wi, wo;
  Push(wi, 0.3, 0.2, -0.5); Push(wo, 0, 0, 1);
  Push(wi, 0, 0, 1);        Push(wo, 0.1, 0.3, -0.2);
  Push(wi, 1, 0, 0);        Push(wo, 0, 0, 1);
  for (const auto& row : kPaper) {
    const auto f = Reference(Preset(row.name), wi, wo);
    for (double x : f) EXPECT_EQ(x, 0.0) << row.name;
  }
}

TEST(MicrocylinderModel, SpecularPeakSitsAtTheMirrorDirectionForFlatThreads) {
  // Linen's tangents are tilted 25 degrees; a curve of 0-degree tangents with narrow gamma_s peaks at the
  // mirror direction in the thread's incidence plane: f(mirror) is the maximum over theta_o in that plane.
  ParamValues v = Preset("linen_plain");
  for (const char* t : {"thread1.", "thread2."}) {
    v[std::string(t) + "tangent_offsets"] = {0, 0};
    v[std::string(t) + "gamma_s"] = {2};
    v[std::string(t) + "albedo"] = {0, 0, 0};
  }
  const double ti = 40 * M_PI / 180;
  std::vector<float> wi, wo;
  for (int k = -80; k <= 80; ++k) {
    Push(wi, -std::sin(ti), 0, std::cos(ti));
    const double to = k * M_PI / 180;
    Push(wo, std::sin(to), 0, std::cos(to));
  }
  const auto f = Reference(v, wi, wo);
  int best = 0;
  for (int k = 0; k < 161; ++k)
    if (f[3 * k] > f[3 * best]) best = k;
  EXPECT_EQ(best - 80, 40);
}

// Hard cases of SPEC.md section 2 for one preset (double reference): finite and non-negative.
std::pair<std::vector<float>, std::vector<float>> HardCases(const models::PackedMaterial& m) {
  std::vector<float> wi, wo;
  std::mt19937 rng(7);
  for (int k = 0; k < 200; ++k) {
    float a[3], b[3];
    accuracy::RandomHemisphere(rng, a);
    accuracy::RandomHemisphere(rng, b);
    Push(wi, a[0], a[1], a[2]); Push(wo, a[0], a[1], a[2]);       // wi = wo
    Push(wi, -a[0], -a[1], a[2]); Push(wo, a[0], a[1], a[2]);     // wi = -reflect(wo): the mirror pair
    Push(wi, a[0], a[1], 1e-6); Push(wo, b[0], b[1], b[2]);       // grazing light
    Push(wi, b[0], b[1], b[2]); Push(wo, a[0], a[1], 1e-6);       // grazing view
    Push(wi, a[0], a[1], 1e-6); Push(wo, -a[0], -a[1], 1e-6);     // both grazing, theta_d -> 90
  }
  // Directions parallel to every sampled tangent (flipped into the upper hemisphere; horizontal ones
  // lifted by 1e-6), against random and opposite views.
  for (int j = 0; j < 2; ++j)
    for (int k = 0; k < DistinctTangents(m, j); ++k) {
      const auto [c, s, count] = Tangent(m, j, k);
      double t[3] = {j == 0 ? c : 0, j == 1 ? c : 0, s};
      if (t[2] < 0) for (double& x : t) x = -x;
      if (t[2] == 0) t[2] = 1e-6;
      float b[3];
      accuracy::RandomHemisphere(rng, b);
      Push(wi, t[0], t[1], t[2]); Push(wo, b[0], b[1], b[2]);
      Push(wi, b[0], b[1], b[2]); Push(wo, t[0], t[1], t[2]);
      Push(wi, t[0], t[1], t[2]); Push(wo, -t[0], -t[1], t[2]);
      Push(wi, t[0], t[1], t[2]); Push(wo, t[0], t[1], t[2]);
    }
  return {wi, wo};
}

TEST(MicrocylinderModel, HardCasesAreFiniteAndNonNegative) {
  for (const auto& row : kPaper) {
    for (double gamma_s : {-1.0, 0.5}) {
      ParamValues v = Preset(row.name);
      if (gamma_s > 0) v["thread1.gamma_s"] = v["thread2.gamma_s"] = {gamma_s};
      const auto [wi, wo] = HardCases(Microcylinder().Pack(v));
      const auto f = Reference(v, wi, wo);
      for (size_t i = 0; i < f.size(); ++i) {
        ASSERT_TRUE(std::isfinite(f[i]) && f[i] >= 0) << row.name << " gamma_s " << gamma_s << " query " << i / 3
                                                      << " f " << f[i];
      }
    }
  }
}

// Directional albedo rho(wo) = integral f(wi, wo) cos(theta_i) dwi (RGB), by midpoint quadrature on the
// projected disk (uniform in sin^2 theta and phi), with the fp32 kernel (its error, ~1e-5, is far below
// the quadrature's). swap: integrate over wo for a fixed light instead.
std::array<double, 3> Albedo(const ParamValues& v, double theta_deg, double phi_deg, bool swap) {
  const int nr = 128, nphi = 256;
  std::vector<float> wi, wo;
  const double to = theta_deg * M_PI / 180, po = phi_deg * M_PI / 180;
  for (int a = 0; a < nr; ++a)
    for (int b = 0; b < nphi; ++b) {
      const double s2 = (a + 0.5) / nr, phi = 2 * M_PI * (b + 0.5) / nphi, s = std::sqrt(s2);
      Push(wi, s * std::cos(phi), s * std::sin(phi), std::sqrt(1 - s2));
      Push(wo, std::sin(to) * std::cos(po), std::sin(to) * std::sin(po), std::cos(to));
    }
  if (swap) std::swap(wi, wo);
  const auto f = testing::RunKernel(Microcylinder(), Microcylinder().Pack(v), false, wi, wo);
  std::array<double, 3> rho{0, 0, 0};
  for (size_t q = 0; q < f.size() / 3; ++q)
    for (int c = 0; c < 3; ++c) rho[c] += f[3 * q + c] * M_PI / (nr * nphi);
  return rho;
}

TEST(MicrocylinderModel, DirectionalAlbedoAtMostOne) {
  for (const auto& row : kPaper) {
    const ParamValues v = Preset(row.name);
    for (double theta : {0.0, 30.0, 60.0, 80.0})
      for (double phi : {0.0, 90.0}) {
        const auto rho = Albedo(v, theta, phi, false);
        for (int c = 0; c < 3; ++c) {
          EXPECT_LE(rho[c], 1.0) << row.name << " view theta " << theta << " phi " << phi << " channel " << c;
          EXPECT_GE(rho[c], 0.0);
        }
      }
  }
}

TEST(MicrocylinderModel, WhiteLosslessThreadsStayBelowOneForEveryLightDirection) {
  // The harshest setting the schema allows: albedo 1, kd 1, so every bit of volume scattering is kept;
  // energy leaving for any light direction (integral of f cos(theta_o) over wo) must still be <= 1.
  ParamValues v = Preset("linen_plain");
  for (const char* t : {"thread1.", "thread2."}) {
    v[std::string(t) + "albedo"] = {1, 1, 1};
    v[std::string(t) + "kd"] = {1};
  }
  for (double theta : {0.0, 45.0, 75.0}) {
    const double rho = Albedo(v, theta, 0, true)[0];
    EXPECT_LE(rho, 1.0) << "light theta " << theta;
    EXPECT_GT(rho, 0.05);
  }
}

}  // namespace
}  // namespace loomlight
