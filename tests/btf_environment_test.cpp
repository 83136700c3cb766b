// Environment lighting folded into a BTF (Sattler et al. 2003 Sec. 5.3, Eq. 10; server/models/btf/
// environment_fold.h, server/render/folded_environment.h). Every expected value comes from the btf model's own
// double reference (ReferenceEval: f per direction, clamped and interpolated as the kernels do) summed over the
// map by the test, never from the fold:
// (a) a constant map: the fold equals the same directions' sum of f cos L exactly (float tables), and L times the
//     directional albedo by fine quadrature within a bound taken from f's variation over each map cell;
// (b) the built-in sky with its sun, discretised as the renderer does (64 x 32 cells and the sun's pixels):
//     within the cells' bound of the brute-force sum over every pixel of the map; and exact for the pixels as
//     given;
// (c) renders of a twill BTF sphere: FOLDED's mean over the sphere within 2% of SAMPLED at 512 spp, and at 2 spp
//     its error against that reference far below SAMPLED's; the choice in the fidelity report;
// (d) the fold's error estimate: reported, bounding the folded render's bias against SAMPLED at 512 spp; AUTO
//     folds only where it is within the target; a fold kept across calls renders the same bytes;
// (e) bad btf_environment values refused naming the field.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <random>

#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/models/btf/btf_asset.h"
#include "server/models/btf/environment_fold.h"
#include "server/render/environment.h"
#include "server/render/scene.h"
#include "server/render/shading.h"
#include "tests/testing.h"

namespace loomlight {
namespace {
using models::btf::BtfImages;
using models::btf::DirectionGrid;
using models::btf::EnvironmentDirection;
using models::btf::EnvironmentFold;
using models::btf::FoldFrame;
using render::Vec3;

const models::Model& BtfModel() { return *models::Registry::Global().FindModel("btf"); }

DirectionGrid FourRings() {
  DirectionGrid g;
  g.rings = {{0, 1}, {20, 6}, {40, 8}, {60, 12}};
  return g;
}

// Images of rank `rank` about a positive mean per view (as btf_test's): exactly representable with `rank`
// components and positive, so the kernel's clamp at 0 never acts and the fold's linear sum is f's.
BtfImages LowRankImages(const DirectionGrid& grid, int texels, int rank, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  BtfImages im;
  im.grid = grid;
  im.width = im.height = texels;
  const size_t n = grid.size(), d = im.image_values();
  im.f.resize(n * n * d);
  for (size_t v = 0; v < n; ++v) {
    std::vector<std::vector<float>> basis(rank, std::vector<float>(d));
    std::vector<float> mean(d);
    for (float& x : mean) x = 0.5f + unit(rng);
    for (auto& b : basis)
      for (float& x : b) x = unit(rng) - 0.5f;
    for (size_t l = 0; l < n; ++l) {
      std::vector<float> a(rank);
      double light[3];
      grid.Direction(l, light);
      for (float& x : a) x = 0.8f * (unit(rng) - 0.5f) / float(rank);
      float* out = im.image(v, l);
      for (size_t i = 0; i < d; ++i) {
        float value = mean[i] * float(0.5 + light[0] * light[0]);  // varies with the light, smoothly
        for (int k = 0; k < rank; ++k) value += a[k] * basis[k][i];
        out[i] = value;
      }
    }
  }
  return im;
}

std::shared_ptr<const models::btf::BtfAsset> Register(std::shared_ptr<models::btf::BtfAsset> asset, const std::string& name) {
  asset->name = name;
  models::btf::Assets::Global().Add(asset);
  return asset;
}

models::PackedMaterial Pack(const models::btf::BtfAsset& asset, int components) {
  models::ParamValues v = BtfModel().DefaultValues();
  v["asset_id"] = {double(asset.id)};
  v["components"] = {double(components)};
  return BtfModel().Pack(v);
}

Vec3 V(const double a[3]) { return {a[0], a[1], a[2]}; }

FoldFrame FrameAround(Vec3 normal, Vec3 toward_u) {
  const Vec3 n = render::Normalize(normal);
  const Vec3 x = render::Normalize(toward_u - render::Dot(toward_u, n) * n);
  const Vec3 y = render::Cross(n, x);
  FoldFrame f;
  for (int c = 0; c < 3; ++c) f.x[c] = x[c], f.y[c] = y[c], f.n[c] = n[c];
  return f;
}

// f(R^T d, wo, uv) cos(theta) (cos > 0, else 0) for world directions d, by the model's double reference.
std::vector<double> FCos(const models::PackedMaterial& m, const FoldFrame& frame, const std::vector<Vec3>& dirs,
                         Vec3 wo, float u, float v) {
  std::vector<float> wi, wos, uv;
  for (const Vec3& d : dirs) {
    wi.insert(wi.end(), {float(render::Dot(d, V(frame.x))), float(render::Dot(d, V(frame.y))), float(render::Dot(d, V(frame.n)))});
    wos.insert(wos.end(), {float(wo.x), float(wo.y), float(wo.z)});
    uv.insert(uv.end(), {u, v});
  }
  std::vector<double> f(3 * dirs.size());
  BtfModel().ReferenceEval(m, wi.data(), wos.data(), uv.data(), dirs.size(), f.data());
  for (size_t i = 0; i < dirs.size(); ++i) {
    const double c = std::max(0.0, render::Dot(dirs[i], V(frame.n)));
    for (int ch = 0; ch < 3; ++ch) f[3 * i + ch] *= c;
  }
  return f;
}

Vec3 Folded(const EnvironmentFold& fold, Vec3 wo, float u, float v) {
  const int frame[4] = {0, -1, -1, -1};
  const double weight[4] = {1, 0, 0, 0}, w[3] = {wo.x, wo.y, wo.z};
  double out[3];
  fold.Radiance(frame, weight, w, true, u, v, out);
  return {out[0], out[1], out[2]};
}

Vec3 Spherical(double theta, double phi) {
  return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
}

struct ViewAndTexel {
  Vec3 wo;
  float u, v;
};
const ViewAndTexel kQueries[] = {
    {Spherical(0.1, 0.3), 0.125f, 0.125f}, {Spherical(0.6, 2.0), 0.4f, 0.7f}, {Spherical(1.2, 4.0), 0.93f, 0.05f}};

// (a) A constant map: a world latitude-longitude grid of cells, each at its centre with its exact solid angle.
TEST(BtfEnvironmentFold, ConstantMapGivesTheAlbedoTimesTheRadiance) {
  const BtfImages im = LowRankImages(FourRings(), 4, 3, 21);
  auto asset = Register(models::btf::Compress(im, {.max_components = 3}, nullptr, nullptr), "fold_constant");
  ASSERT_TRUE(asset);
  const models::PackedMaterial m = Pack(*asset, 3);
  const Vec3 radiance{1.0, 0.5, 0.25};
  constexpr int kW = 128, kH = 64;
  std::vector<EnvironmentDirection> env;
  std::vector<Vec3> centres, corners;
  std::vector<double> solid_angle;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      EnvironmentDirection e;
      const Vec3 d = Spherical(M_PI * (y + 0.5) / kH, 2 * M_PI * (x + 0.5) / kW);
      for (int c = 0; c < 3; ++c) e.direction[c] = d[c], e.radiance[c] = radiance[c];
      e.solid_angle = 2 * M_PI / kW * (std::cos(M_PI * y / kH) - std::cos(M_PI * (y + 1) / kH));
      env.push_back(e);
      centres.push_back(d);
      solid_angle.push_back(e.solid_angle);
    }
  for (int y = 0; y <= kH; ++y)
    for (int x = 0; x <= kW; ++x) corners.push_back(Spherical(M_PI * y / kH, 2 * M_PI * x / kW));
  const FoldFrame frame = FrameAround({0.3, 0.5, 0.8}, {1, 0, 0});
  auto fold = EnvironmentFold::Make(asset->tables, 3, env, {frame}, {}, 2, {});
  ASSERT_TRUE(fold);
  EXPECT_EQ(fold->bytes(), EnvironmentFold::TableBytes(*asset->tables, 3, 1));

  for (const ViewAndTexel& q : kQueries) {
    // The same cells summed through f: the fold's algebra (Eq. 10), exact but for the float tables.
    const std::vector<double> at_centres = FCos(m, frame, centres, q.wo, q.u, q.v);
    const std::vector<double> at_corners = FCos(m, frame, corners, q.wo, q.u, q.v);
    // Each cell's midpoint value lies within its f cos's range, as does the cell's mean: their difference is
    // at most the range (max - min over its corners and centre) times its solid angle.
    Vec3 sum, bound;
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        const size_t cell = size_t(y) * kW + x;
        for (int ch = 0; ch < 3; ++ch) {
          double lo = at_centres[3 * cell + ch], hi = lo;
          for (int k : {y * (kW + 1) + x, y * (kW + 1) + x + 1, (y + 1) * (kW + 1) + x, (y + 1) * (kW + 1) + x + 1})
            lo = std::min(lo, at_corners[3 * k + ch]), hi = std::max(hi, at_corners[3 * k + ch]);
          (ch == 0 ? sum.x : ch == 1 ? sum.y : sum.z) += solid_angle[cell] * at_centres[3 * cell + ch];
          (ch == 0 ? bound.x : ch == 1 ? bound.y : bound.z) += solid_angle[cell] * (hi - lo);
        }
      }
    // The directional albedo by a fine midpoint rule in the frame's own (theta, phi), and its own error
    // estimated from half the resolution.
    const auto albedo = [&](int n_theta) {
      std::vector<Vec3> dirs;
      std::vector<double> weights;
      for (int i = 0; i < n_theta; ++i)
        for (int j = 0; j < 2 * n_theta; ++j) {
          const double theta = 0.5 * M_PI * (i + 0.5) / n_theta, phi = M_PI * (j + 0.5) / n_theta;
          const Vec3 l = Spherical(theta, phi);
          dirs.push_back(l.x * V(frame.x) + l.y * V(frame.y) + l.z * V(frame.n));
          weights.push_back(std::sin(theta) * (0.5 * M_PI / n_theta) * (M_PI / n_theta));
        }
      const std::vector<double> f = FCos(m, frame, dirs, q.wo, q.u, q.v);
      Vec3 a;
      for (size_t i = 0; i < dirs.size(); ++i) a = a + weights[i] * Vec3{f[3 * i], f[3 * i + 1], f[3 * i + 2]};
      return a;
    };
    const Vec3 fine = albedo(256), coarse = albedo(128);
    const Vec3 got = Folded(*fold, q.wo, q.u, q.v);
    std::printf("constant map, wo.z %.2f: folded %.5g, L x albedo %.5g (relative %.2g; bound %.2g)\n", q.wo.z, got.x,
                radiance.x * fine.x, std::fabs(got.x / (radiance.x * fine.x) - 1), bound.x / fine.x);
    for (int ch = 0; ch < 3; ++ch) {
      const double exact = radiance[ch] * sum[ch];
      EXPECT_NEAR(got[ch], exact, 1e-5 * exact) << "ch " << ch;
      const double allowed = radiance[ch] * (bound[ch] + std::fabs(fine[ch] - coarse[ch]));
      EXPECT_NEAR(got[ch], radiance[ch] * fine[ch], allowed) << "ch " << ch;
      EXPECT_LT(allowed, 0.15 * radiance[ch] * fine[ch]) << "the bound says something";
      EXPECT_GT(fine[ch], 0.3);
    }
  }
}

// (b) The built-in sky (a sun of 2 degrees radius, 780 times brighter than the sky), as the renderer discretises
// it, against the brute-force sum over its 512 x 256 pixels.
TEST(BtfEnvironmentFold, SkyWithSunMatchesTheSumOverEveryPixel) {
  const BtfImages im = LowRankImages(FourRings(), 4, 4, 5);
  auto asset = Register(models::btf::Compress(im, {.max_components = 4}, nullptr, nullptr), "fold_sky");
  ASSERT_TRUE(asset);
  const models::PackedMaterial m = Pack(*asset, 4);
  const render::Environment sky = render::Environment::Builtin();
  constexpr int kW = 512, kH = 256, kCellsW = 64, kCellsH = 32;
  // Every pixel at its centre (environment.h's convention: column 0.5 W looks along -z, +x at 0.75 W, row 0 up).
  std::vector<Vec3> dirs, radiance;
  std::vector<double> solid_angle;
  std::vector<bool> bright;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const double phi = ((x + 0.5) / kW - 0.5) * 2 * M_PI, theta = (y + 0.5) / kH * M_PI;
      const Vec3 d{std::sin(theta) * std::sin(phi), std::cos(theta), -std::sin(theta) * std::cos(phi)};
      dirs.push_back(d);
      radiance.push_back(sky.Radiance(d));
      solid_angle.push_back(2 * M_PI / kW * (std::cos(M_PI * y / kH) - std::cos(M_PI * (y + 1) / kH)));
      bright.push_back(sky.Lookup(d).component == render::Environment::kBright);
    }
  size_t bright_pixels = 0;
  for (bool b : bright) bright_pixels += b;
  ASSERT_GT(bright_pixels, 10u);  // the sun is its own cells
  ASSERT_LT(bright_pixels, 200u);

  // The renderer's discretisation.
  std::vector<EnvironmentDirection> cells;
  for (const render::Environment::Cell& c : sky.Cells(kCellsW, kCellsH, 4096)) {
    EnvironmentDirection e;
    for (int i = 0; i < 3; ++i) e.direction[i] = c.direction[i], e.radiance[i] = c.radiance[i];
    e.solid_angle = c.solid_angle;
    cells.push_back(e);
  }
  EXPECT_EQ(cells.size(), size_t(kCellsW * kCellsH) + bright_pixels);
  // Every pixel as given.
  std::vector<EnvironmentDirection> pixels(dirs.size());
  for (size_t p = 0; p < dirs.size(); ++p) {
    for (int i = 0; i < 3; ++i) pixels[p].direction[i] = dirs[p][i], pixels[p].radiance[i] = radiance[p][i];
    pixels[p].solid_angle = solid_angle[p];
  }
  const FoldFrame frame = FrameAround({-0.3, 0.8, 0.5}, {0, 0.2, 1});  // the sun 22 degrees from the normal
  auto by_cells = EnvironmentFold::Make(asset->tables, 4, cells, {frame}, {}, 2, {});
  auto by_pixels = EnvironmentFold::Make(asset->tables, 4, pixels, {frame}, {}, 2, {});
  ASSERT_TRUE(by_cells && by_pixels);
  for (const ViewAndTexel& q : kQueries) {
    const std::vector<double> g = FCos(m, frame, dirs, q.wo, q.u, q.v);
    // The brute force, and the bound on grouping the sky's pixels into cells: each cell's power times the range
    // of f cos over its pixels (the cell's direction lies among them).
    Vec3 brute, sun, bound;
    std::vector<Vec3> lo(kCellsW * kCellsH, Vec3{1e300, 1e300, 1e300}), hi(kCellsW * kCellsH, Vec3{-1e300, -1e300, -1e300}),
        power(kCellsW * kCellsH);
    for (size_t p = 0; p < dirs.size(); ++p) {
      const Vec3 gp{g[3 * p], g[3 * p + 1], g[3 * p + 2]};
      const Vec3 term = solid_angle[p] * (radiance[p] * gp);
      brute = brute + term;
      if (bright[p]) {
        sun = sun + term;
        continue;
      }
      const size_t cell = (p / kW) * kCellsH / kH * kCellsW + (p % kW) * kCellsW / kW;
      for (int ch = 0; ch < 3; ++ch) {
        double& l = ch == 0 ? lo[cell].x : ch == 1 ? lo[cell].y : lo[cell].z;
        double& h = ch == 0 ? hi[cell].x : ch == 1 ? hi[cell].y : hi[cell].z;
        l = std::min(l, gp[ch]), h = std::max(h, gp[ch]);
      }
      power[cell] = power[cell] + solid_angle[p] * radiance[p];
    }
    for (size_t c = 0; c < power.size(); ++c) bound = bound + power[c] * (hi[c] - lo[c]);
    const Vec3 cells_got = Folded(*by_cells, q.wo, q.u, q.v), pixels_got = Folded(*by_pixels, q.wo, q.u, q.v);
    std::printf("sky, wo.z %.2f: cells %.5g, pixels %.5g, brute force %.5g (cells relative %.2g; bound %.2g)\n", q.wo.z,
                cells_got.y, pixels_got.y, brute.y, std::fabs(cells_got.y / brute.y - 1), bound.y / brute.y);
    for (int ch = 0; ch < 3; ++ch) {
      EXPECT_NEAR(pixels_got[ch], brute[ch], 1e-5 * brute[ch]) << "ch " << ch;
      EXPECT_NEAR(cells_got[ch], brute[ch], bound[ch] + 1e-5 * brute[ch]) << "ch " << ch;
      EXPECT_LT(bound[ch], 0.1 * brute[ch]) << "the bound says something";
      EXPECT_GT(sun[ch], 0.2 * brute[ch]) << "the sun matters here";
    }
  }
}

// The vertices' frames: PointOnShape is where a ray finds the same (s, t) and frame.
TEST(BtfEnvironmentFold, PointOnShapeIsWhereRaysHitTheSameSurfaceCoordinates) {
  for (render::SceneKind kind : {render::SceneKind::kSphere, render::SceneKind::kCylinders, render::SceneKind::kSwatch}) {
    const render::Scene scene = render::MakeScene(kind);
    const render::Shape& shape = scene.objects[0].shape;
    for (double s : {-0.7, 0.1, 0.9})
      for (double t : {-0.3, 0.05, 0.4}) {
        const render::Hit p = render::PointOnShape(shape, s * (shape.kind == render::Shape::Kind::kQuad ? 0.5 : 1.0), t);
        render::Hit hit;
        const Vec3 origin = p.position + 2.0 * p.normal;
        ASSERT_TRUE(scene.Intersect(origin, -1.0 * p.normal, 0, INFINITY, &hit));
        EXPECT_NEAR(hit.s, p.s, 1e-9);
        EXPECT_NEAR(hit.t, p.t, 1e-9);
        EXPECT_NEAR(render::Length(hit.position - p.position), 0, 1e-9);
        EXPECT_NEAR(render::Dot(hit.tangent_s, p.tangent_s), 1, 1e-9);
        EXPECT_NEAR(render::Dot(hit.normal, p.normal), 1, 1e-9);
      }
  }
}

// ---- Renders on an in-process server ----

// A woven twill BTF on a 27-direction grid, 8 x 8 texels, 4 components, synthesised through the woven model's
// double reference and registered in this process (where the in-process server finds it by name).
std::shared_ptr<const models::btf::BtfAsset> TwillAsset() {
  static std::shared_ptr<const models::btf::BtfAsset> asset = [] {
    const models::PresetSpec* preset = nullptr;
    const models::Model* woven = models::Registry::Global().FindPreset("cotton_twill", &preset);
    const models::ParamValues values = woven->PresetValues(*preset);
    const models::PackedMaterial m = woven->Pack(values);
    BtfImages im;
    im.grid = FourRings();
    im.width = im.height = 8;
    const size_t n = im.grid.size(), texels = im.texels();
    im.f.resize(n * n * im.image_values());
    std::vector<float> wi, wo, uv;
    for (size_t v = 0; v < n; ++v)
      for (size_t l = 0; l < n; ++l)
        for (size_t t = 0; t < texels; ++t) {
          double dv[3], dl[3];
          im.grid.Direction(v, dv);
          im.grid.Direction(l, dl);
          for (int c = 0; c < 3; ++c) wi.push_back(float(dl[c])), wo.push_back(float(dv[c]));
          uv.push_back(float((t % 8 + 0.5) / 8));
          uv.push_back(float((t / 8 + 0.5) / 8));
        }
    std::vector<double> f(im.f.size());
    woven->ReferenceEval(m, wi.data(), wo.data(), uv.data(), wi.size() / 3, f.data());
    for (size_t i = 0; i < f.size(); ++i) im.f[i] = float(f[i]);
    auto a = models::btf::Compress(im, {.max_components = 4}, nullptr, nullptr);
    a->threads_per_tile = woven->ThreadsPerRepeat(values);
    return Register(a, "fold_twill");
  }();
  return asset;
}

class BtfEnvironmentRender : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    ASSERT_TRUE(TwillAsset());
    server_ = testing::StartInProcessServer().release();
    ASSERT_NE(server_, nullptr);
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  static api::LoomlightServer* server_;
  std::unique_ptr<v1::Loomlight::Stub> stub_ = testing::Connect(server_->port());
};
api::LoomlightServer* BtfEnvironmentRender::server_ = nullptr;

v1::RenderRequest SphereRequest(v1::BtfEnvironment mode, uint32_t spp, uint64_t seed, int side = 64) {
  v1::RenderRequest r;
  r.mutable_material()->set_model("btf");
  v1::Param* p = r.mutable_material()->add_params();
  p->set_name("asset");
  p->set_text("fold_twill");
  r.set_scene(v1::SCENE_SPHERE);
  r.set_width(side);
  r.set_height(side);
  r.set_samples_per_pixel(spp);
  r.set_format(v1::RENDER_FORMAT_EXR);
  r.set_seed(seed);
  r.set_error_target(1e-6);  // the BTF at all 4 components, in both modes
  r.set_texture_scale(1);     // threads ~8 pixels wide: little of a pixel's variance is its texture
  r.set_btf_environment(mode);
  return r;
}

struct Rendered {
  grpc::Status status;
  v1::RenderUpdate last;
  std::vector<float> rgb;
};

Rendered Render(v1::Loomlight::Stub& stub, const v1::RenderRequest& request) {
  Rendered out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(600));
  auto reader = stub.Render(&ctx, request);
  v1::RenderUpdate update;
  while (reader->Read(&update)) out.last = update;
  out.status = reader->Finish();
  if (out.status.ok()) out.rgb = testing::DecodeImage(out.last.image(), "r.exr").pixels;
  return out;
}

// Pixels wholly on the sphere (all four corners hit it): the object's interior, no background mixed in.
std::vector<size_t> SpherePixels(int side) {
  const render::Scene scene = render::MakeScene(render::SceneKind::kSphere);
  const render::PinholeCamera camera(scene.default_camera, side, side);
  std::vector<size_t> out;
  for (int y = 0; y < side; ++y)
    for (int x = 0; x < side; ++x) {
      bool inside = true;
      for (int c = 0; c < 4; ++c) {
        render::Hit hit;
        inside = inside && scene.Intersect(camera.position(), camera.Direction(x + c % 2, y + c / 2), 0, INFINITY, &hit);
      }
      if (inside) out.push_back(size_t(y) * side + x);
    }
  return out;
}

double Mean(const std::vector<float>& rgb, const std::vector<size_t>& pixels) {
  double sum = 0;
  for (size_t p : pixels) sum += rgb[3 * p] + rgb[3 * p + 1] + rgb[3 * p + 2];
  return sum / (3.0 * double(pixels.size()));
}

double RelativeMse(const std::vector<float>& rgb, const std::vector<float>& reference, const std::vector<size_t>& pixels) {
  double diff = 0, total = 0;
  for (size_t p : pixels)
    for (int c = 0; c < 3; ++c) {
      diff += (rgb[3 * p + c] - reference[3 * p + c]) * double(rgb[3 * p + c] - reference[3 * p + c]);
      total += reference[3 * p + c] * double(reference[3 * p + c]);
    }
  return diff / total;
}

const v1::FidelityChoice* Choice(const v1::RenderUpdate& u, const std::string& aspect) {
  if (u.fidelity_size() == 0) return nullptr;
  for (const v1::FidelityChoice& c : u.fidelity(0).choices())
    if (c.aspect() == aspect) return &c;
  return nullptr;
}

TEST_F(BtfEnvironmentRender, FoldedAgreesWithSampledAndHasFarLessNoise) {
  constexpr int kSide = 64;
  const std::vector<size_t> pixels = SpherePixels(kSide);
  ASSERT_GT(pixels.size(), 500u);
  const Rendered reference = Render(*stub_, SphereRequest(v1::BTF_ENVIRONMENT_SAMPLED, 512, 1, kSide));
  ASSERT_TRUE(reference.status.ok()) << reference.status.error_message();
  const Rendered folded = Render(*stub_, SphereRequest(v1::BTF_ENVIRONMENT_FOLDED, 16, 2, kSide));
  ASSERT_TRUE(folded.status.ok()) << folded.status.error_message();
  const double mean_ref = Mean(reference.rgb, pixels), mean_folded = Mean(folded.rgb, pixels);
  const double mean_error = std::fabs(mean_folded - mean_ref) / mean_ref;
  const double folded_rmse = std::sqrt(RelativeMse(folded.rgb, reference.rgb, pixels));
  std::printf("sphere mean: sampled 512 spp %.5g, folded 16 spp %.5g (%.2g relative); folded relative RMSE %.3g\n",
              mean_ref, mean_folded, mean_error, folded_rmse);
  EXPECT_LT(mean_error, 0.02);

  const v1::FidelityChoice* chosen = Choice(folded.last, "btf_environment");
  ASSERT_NE(chosen, nullptr);
  EXPECT_EQ(chosen->chosen(), "folded");
  EXPECT_EQ(chosen->full(), "sampled");
  EXPECT_NE(chosen->reason().find("vertices"), std::string::npos) << chosen->reason();
  const v1::FidelityChoice* sampled_choice = Choice(reference.last, "btf_environment");
  ASSERT_NE(sampled_choice, nullptr);
  EXPECT_EQ(sampled_choice->chosen(), "sampled");
  // With the sky the only light, a folded sphere needs no kernel query at all.
  EXPECT_EQ(folded.last.queries(), 0u);

  // At 2 samples per pixel: FOLDED's noise is only the pixel footprint's texture; SAMPLED's is the map's too.
  const Rendered folded2 = Render(*stub_, SphereRequest(v1::BTF_ENVIRONMENT_FOLDED, 2, 3, kSide));
  const Rendered sampled2 = Render(*stub_, SphereRequest(v1::BTF_ENVIRONMENT_SAMPLED, 2, 3, kSide));
  ASSERT_TRUE(folded2.status.ok() && sampled2.status.ok());
  const double folded_mse = RelativeMse(folded2.rgb, reference.rgb, pixels);
  const double sampled_mse = RelativeMse(sampled2.rgb, reference.rgb, pixels);
  std::printf("2 spp relative MSE against sampled 512 spp: folded %.3g, sampled %.3g\n", folded_mse, sampled_mse);
  EXPECT_LT(folded_mse, 0.2 * sampled_mse);
}

// The estimate is what AUTO decides by: over the target, sampled (saying so); within it, folded, counted in
// the object's estimated error. And it is honest: the folded image's bias over the sphere against SAMPLED at
// 512 spp is within it (the mean's bias is at most the mean absolute error the estimate measures), up to the
// reference's own noise.
TEST_F(BtfEnvironmentRender, AutoFoldsWhereTheEstimatedErrorIsWithinTheTarget) {
  constexpr int kSide = 64;
  const std::vector<size_t> pixels = SpherePixels(kSide);
  const Rendered folded = Render(*stub_, SphereRequest(v1::BTF_ENVIRONMENT_FOLDED, 16, 2, kSide));
  ASSERT_TRUE(folded.status.ok()) << folded.status.error_message();
  const v1::FidelityChoice* requested = Choice(folded.last, "btf_environment");
  ASSERT_NE(requested, nullptr);
  const double estimate = requested->estimated_error();
  EXPECT_GT(estimate, 0.0) << requested->reason();
  EXPECT_NE(requested->reason().find("estimated error"), std::string::npos) << requested->reason();

  const Rendered reference = Render(*stub_, SphereRequest(v1::BTF_ENVIRONMENT_SAMPLED, 512, 11, kSide));
  ASSERT_TRUE(reference.status.ok()) << reference.status.error_message();
  double noise = 0;  // the reference mean's standard error, from its pixels' spread about the folded image
  const double mean_ref = Mean(reference.rgb, pixels), mean_folded = Mean(folded.rgb, pixels);
  for (size_t p : pixels)
    for (int c = 0; c < 3; ++c) noise += std::pow(reference.rgb[3 * p + c] - folded.rgb[3 * p + c], 2);
  noise = std::sqrt(noise / (3.0 * pixels.size())) / std::sqrt(3.0 * pixels.size()) / mean_ref;
  const double bias = std::fabs(mean_folded - mean_ref) / mean_ref;
  std::printf("fold's estimated error %.3g; folded 16 spp against sampled 512 spp: mean bias %.3g (reference noise "
              "%.2g)\n", estimate, bias, noise);
  EXPECT_LE(bias, estimate + 3 * noise);

  v1::RenderRequest strict = SphereRequest(v1::BTF_ENVIRONMENT_AUTO, 1, 1, kSide);  // target 1e-6
  const Rendered sampled = Render(*stub_, strict);
  ASSERT_TRUE(sampled.status.ok()) << sampled.status.error_message();
  const v1::FidelityChoice* over = Choice(sampled.last, "btf_environment");
  ASSERT_NE(over, nullptr);
  EXPECT_EQ(over->chosen(), "sampled");
  EXPECT_NE(over->reason().find("over the target"), std::string::npos) << over->reason();
  EXPECT_GT(sampled.last.queries(), 0u);

  v1::RenderRequest loose = strict;
  loose.set_error_target(0.05);
  const Rendered chosen = Render(*stub_, loose);
  ASSERT_TRUE(chosen.status.ok()) << chosen.status.error_message();
  const v1::FidelityChoice* within = Choice(chosen.last, "btf_environment");
  ASSERT_NE(within, nullptr);
  EXPECT_EQ(within->chosen(), "folded") << within->reason();
  EXPECT_GT(within->estimated_error(), 0.0);
  EXPECT_LE(within->estimated_error(), 0.05);
  EXPECT_GE(chosen.last.fidelity(0).estimated_error(), within->estimated_error());
  EXPECT_EQ(chosen.last.queries(), 0u);  // the sky is the only light: nothing left to sample
}

// A second call with the same asset, map, scene and camera reuses the first call's fold, and renders the same
// bytes as the call that made it.
TEST_F(BtfEnvironmentRender, AFoldKeptAcrossCallsRendersTheSameImage) {
  v1::RenderRequest r = SphereRequest(v1::BTF_ENVIRONMENT_FOLDED, 2, 5, 32);
  r.set_texture_rotation_deg(33);  // a fold of its own: no other test's call made it
  const Rendered first = Render(*stub_, r);
  const Rendered second = Render(*stub_, r);
  ASSERT_TRUE(first.status.ok() && second.status.ok());
  const v1::FidelityChoice* made = Choice(first.last, "btf_environment");
  const v1::FidelityChoice* kept = Choice(second.last, "btf_environment");
  ASSERT_TRUE(made && kept);
  EXPECT_EQ(made->reason().find("kept from an earlier call"), std::string::npos) << made->reason();
  EXPECT_NE(kept->reason().find("kept from an earlier call"), std::string::npos) << kept->reason();
  EXPECT_EQ(first.last.image(), second.last.image());
  EXPECT_EQ(made->estimated_error(), kept->estimated_error());
}

TEST_F(BtfEnvironmentRender, BadValuesAreRefusedNamingTheField) {
  struct Case {
    const char* what;
    std::function<void(v1::RenderRequest&)> change;
  };
  const Case cases[] = {
      {"unknown value", [](v1::RenderRequest& r) { r.set_btf_environment(static_cast<v1::BtfEnvironment>(9)); }},
      {"not a btf material",
       [](v1::RenderRequest& r) {
         r.mutable_material()->Clear();
         r.mutable_material()->set_preset("cotton_twill");
       }},
      {"no environment",
       [](v1::RenderRequest& r) {
         v1::RenderLight* l = r.add_lights();
         l->set_type(v1::RenderLight::TYPE_DIRECTIONAL);
         for (double x : {0.0, 1.0, 1.0}) l->add_direction(x);
         for (double x : {1.0, 1.0, 1.0}) l->add_rgb(x);
       }},
      {"fiber scene", [](v1::RenderRequest& r) { r.set_scene(v1::SCENE_YARN); }},
  };
  for (const Case& c : cases) {
    v1::RenderRequest r = SphereRequest(v1::BTF_ENVIRONMENT_FOLDED, 1, 1, 8);
    c.change(r);
    const Rendered out = Render(*stub_, r);
    EXPECT_EQ(out.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.what;
    EXPECT_EQ(out.status.error_message().rfind("btf_environment", 0), 0u) << c.what << ": " << out.status.error_message();
  }
  // SAMPLED and AUTO are fine on any material.
  v1::RenderRequest r = SphereRequest(v1::BTF_ENVIRONMENT_SAMPLED, 1, 1, 8);
  r.mutable_material()->Clear();
  r.mutable_material()->set_preset("cotton_twill");
  EXPECT_TRUE(Render(*stub_, r).status.ok());
}

}  // namespace
}  // namespace loomlight
