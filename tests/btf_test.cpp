// BTF assets (Sattler et al.; SPEC.md section 7): the per-view PCA against images of known rank, the
// reconstruction kernels against their double reference, grid directions reproduced within the error the
// asset reports, the BRDF as the BTF's tile mean, and the RPCs end to end on a real server: a woven twill
// synthesised and compressed, evaluated, kept across a restart, deleted; bad names and materials rejected.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <thread>
#include <tuple>

#include "server/assets/btf_store.h"
#include "server/models/btf/btf_asset.h"
#include "tests/testing.h"

#include <OpenImageIO/imageio.h>  // after protobuf's headers (its byte-swap macros clash with OpenImageIO's)

namespace loomlight {
namespace {
using models::btf::BtfImages;
using models::btf::DirectionGrid;

const models::Model& BtfModel() { return *models::Registry::Global().FindModel("btf"); }

// Images of rank `rank` about a positive mean per view: exactly representable with `rank` components.
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
      for (float& x : a) x = 0.4f * (unit(rng) - 0.5f) / float(rank);
      float* out = im.image(v, l);
      for (size_t i = 0; i < d; ++i) {
        float value = mean[i];
        for (int k = 0; k < rank; ++k) value += a[k] * basis[k][i];
        out[i] = value;
      }
    }
  }
  return im;
}

std::shared_ptr<models::btf::BtfAsset> Register(std::shared_ptr<models::btf::BtfAsset> asset, const std::string& name) {
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

// Every (view, light) grid pair at every texel centre: wi, wo, uv, in the images' order.
void GridQueries(const BtfImages& im, std::vector<float>* wi, std::vector<float>* wo, std::vector<float>* uv) {
  const size_t n = im.grid.size();
  for (size_t v = 0; v < n; ++v)
    for (size_t l = 0; l < n; ++l)
      for (int t = 0; t < im.width * im.height; ++t) {
        double dv[3], dl[3];
        im.grid.Direction(v, dv);
        im.grid.Direction(l, dl);
        for (int c = 0; c < 3; ++c) wi->push_back(float(dl[c])), wo->push_back(float(dv[c]));
        uv->push_back(float((t % im.width + 0.5) / im.width));
        uv->push_back(float((t / im.width + 0.5) / im.height));
      }
}

double Rms(const std::vector<double>& a, const std::vector<float>& b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(s / double(a.size()));
}

DirectionGrid SmallGrid() {
  DirectionGrid g;
  g.rings = {{0, 1}, {30, 6}, {60, 8}};
  return g;
}

TEST(BtfCompression, ErrorFallsWithComponentsAndVanishesAtTheImagesRank) {
  const BtfImages im = LowRankImages(SmallGrid(), 8, 3, 7);
  auto asset = models::btf::Compress(im, {.max_components = 6}, nullptr, nullptr);
  ASSERT_TRUE(asset);
  ASSERT_EQ(asset->components, 6);
  ASSERT_EQ(asset->errors.size(), 7u);
  for (size_t c = 1; c < asset->errors.size(); ++c)
    EXPECT_LE(asset->errors[c].rmse, asset->errors[c - 1].rmse * (1 + 1e-12)) << c;
  EXPECT_GT(asset->errors[2].rmse, 1e-3);  // two components miss the third
  EXPECT_LT(asset->errors[3].rmse, 1e-5);  // rank 3 about the mean: exact
  EXPECT_LT(asset->errors[3].bytes, asset->errors[6].bytes);
}

TEST(BtfCompression, TargetPsnrKeepsTheFewestComponentsReachingIt) {
  const BtfImages im = LowRankImages(SmallGrid(), 8, 4, 11);
  auto all = models::btf::Compress(im, {.max_components = 8}, nullptr, nullptr);
  ASSERT_TRUE(all);
  const double target = 0.5 * (all->errors[1].psnr_db + all->errors[2].psnr_db);
  auto asset = models::btf::Compress(im, {.max_components = 8, .target_psnr_db = target}, nullptr, nullptr);
  ASSERT_TRUE(asset);
  EXPECT_EQ(asset->components, 2);
}

// The reconstruction at grid directions and texel centres is the PCA's: its RMS error against the images is
// what the asset reports (from its eigenvalues), at each of these component counts.
void ExpectGridDirectionsReproduceTheImages(const BtfImages& im, const models::btf::BtfAsset& asset,
                                            std::initializer_list<int> components) {
  std::vector<float> wi, wo, uv;
  GridQueries(im, &wi, &wo, &uv);
  const size_t n = wi.size() / 3;
  for (int c : components) {
    const models::PackedMaterial m = Pack(asset, c);
    std::vector<double> f(3 * n);
    BtfModel().ReferenceEval(m, wi.data(), wo.data(), uv.data(), n, f.data());
    // The tables are float32: 1e-6 of the values on top of the PCA's own error.
    EXPECT_NEAR(Rms(f, im.f), asset.errors[c].rmse, 1e-5 + 1e-3 * asset.errors[c].rmse) << "c = " << c;
  }
}

TEST(BtfKernels, GridDirectionsReproduceTheImagesWithinTheReportedError) {
  const BtfImages im = LowRankImages(SmallGrid(), 6, 5, 3);
  auto asset = Register(models::btf::Compress(im, {.max_components = 5}, nullptr, nullptr), "test_grid");
  ExpectGridDirectionsReproduceTheImages(im, *asset, {0, 1, 2, 5});
}

// The same on Table 1's H1 grid with 24 components kept: c = 16 and 21 sum the components in the kernel's
// blocks of 16 (and five more one by one), c = 24 is exact. Only the asset's error, from its eigenvalues, is
// the expectation: the double reference shares the kernel's source.
TEST(BtfKernels, GridDirectionsReproduceTheImagesInBlocksOfComponents) {
  bool found = false;
  const BtfImages im = LowRankImages(DirectionGrid::Preset("h1", &found), 4, 24, 7);
  ASSERT_TRUE(found);
  auto asset = Register(models::btf::Compress(im, {.max_components = 24}, nullptr, nullptr), "test_grid_blocks");
  ASSERT_EQ(asset->components, 24);
  ExpectGridDirectionsReproduceTheImages(im, *asset, {15, 16, 21, 24});
  EXPECT_GT(asset->errors[21].rmse, 10 * asset->errors[24].rmse + 1e-4);  // c = 21 is not already exact
}

// c = 6: the components one by one; on Table 1's H1 grid, c = 16 and 21 of 24 kept: the kernel's blocks of 16
// (explicit vectors), a block and five more, and components kept beyond those used.
class BtfKernelsAtComponents : public ::testing::TestWithParam<std::tuple<bool, int, int>> {};

TEST_P(BtfKernelsAtComponents, OpenClFloatAndDoubleAgreeWithTheDoubleReference) {
  const auto [h1, kept, c] = GetParam();
  bool found = false;
  const DirectionGrid grid = h1 ? DirectionGrid::Preset("h1", &found) : SmallGrid();
  const BtfImages im = LowRankImages(grid, h1 ? 4 : 8, kept, 5);
  auto asset = Register(models::btf::Compress(im, {.max_components = kept}, nullptr, nullptr),
                        "test_kernels_" + std::to_string(c));
  ASSERT_EQ(asset->components, kept);
  const models::PackedMaterial m = Pack(*asset, c);
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::vector<float> wi, wo, uv;
  const size_t n = 4000;
  for (size_t q = 0; q < n; ++q) {
    for (auto* w : {&wi, &wo}) {  // the upper hemisphere, pole and horizon included
      const float z = q % 97 == 0 ? 1.0f : q % 89 == 0 ? 0.0f : unit(rng), phi = 6.2831853f * unit(rng);
      const float s = std::sqrt(std::max(0.0f, 1 - z * z));
      w->insert(w->end(), {s * std::cos(phi), s * std::sin(phi), z});
    }
    uv.insert(uv.end(), {8 * unit(rng) - 4, 8 * unit(rng) - 4});  // several tiles, negative too
  }
  std::vector<double> ref(3 * n);
  BtfModel().ReferenceEval(m, wi.data(), wo.data(), uv.data(), n, ref.data());
  double peak = 0;
  for (double x : ref) {
    ASSERT_TRUE(std::isfinite(x));
    ASSERT_GE(x, 0);
    peak = std::max(peak, x);
  }
  ASSERT_GT(peak, 0.5);
  auto& rt = testing::SharedRuntime();
  for (bool fp64 : {false, true}) {
    if (fp64 && !rt.has_fp64()) continue;
    for (bool textured : {true, false}) {
      std::vector<double> expect(3 * n);
      BtfModel().ReferenceEval(m, wi.data(), wo.data(), textured ? uv.data() : nullptr, n, expect.data());
      const std::vector<double> got = testing::RunKernel(BtfModel(), m, fp64, wi, wo, textured ? uv : std::vector<float>{});
      double worst = 0;
      for (size_t i = 0; i < got.size(); ++i) worst = std::max(worst, std::abs(got[i] - expect[i]) / peak);
      EXPECT_LT(worst, fp64 ? 1e-12 : 2e-5) << (fp64 ? "fp64" : "fp32") << (textured ? " BTF" : " BRDF");
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Components, BtfKernelsAtComponents,
                         ::testing::Values(std::make_tuple(false, 6, 6), std::make_tuple(true, 24, 16),
                                           std::make_tuple(true, 24, 21)));

// Random queries wait on memory, so the runtime lays out a launch of the BTF model's random queries grouped by
// view and texel row (Model::LocalityOrder) and each result still goes to its own query: through Evaluate,
// every query of a random request must get its own f (the double reference's, in the request's order). A
// texture slice's queries (one wo, uv in rows) keep their order.
TEST(BtfKernels, RandomQueriesRunGroupedByViewAndAnswerInRequestOrder) {
  auto asset = Register(models::btf::Compress(LowRankImages(SmallGrid(), 8, 6, 11), {.max_components = 6}, nullptr,
                                              nullptr),
                        "test_locality_order");
  const size_t n = 40000;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  v1::EvaluateRequest request;
  request.mutable_material()->set_model("btf");
  v1::Param* p = request.mutable_material()->add_params();
  p->set_name("asset");
  p->set_text(asset->name);
  for (size_t q = 0; q < n; ++q) {
    for (int w = 0; w < 2; ++w) {
      const float z = unit(rng), phi = 6.2831853f * unit(rng), s = std::sqrt(1 - z * z);
      for (float x : {s * std::cos(phi), s * std::sin(phi), z}) (w ? request.add_wo(x) : request.add_wi(x));
    }
    request.add_uv(8 * unit(rng) - 4);
    request.add_uv(8 * unit(rng) - 4);
  }
  std::vector<size_t> position(n);
  ASSERT_TRUE(BtfModel().LocalityOrder(request.wo().data(), request.uv().data(), n, position.data()));
  std::vector<size_t> sorted = position;
  std::sort(sorted.begin(), sorted.end());
  for (size_t q = 0; q < n; ++q) ASSERT_EQ(sorted[q], q);  // a permutation
  std::vector<float> one_wo(3 * n), rows(2 * n);
  for (size_t q = 0; q < n; ++q) {
    std::copy_n(request.wo().data(), 3, &one_wo[3 * q]);
    rows[2 * q] = (float(q % 200) + 0.5f) / 200;
    rows[2 * q + 1] = (float(q / 200) + 0.5f) / 200;
  }
  EXPECT_FALSE(BtfModel().LocalityOrder(one_wo.data(), rows.data(), n, position.data()));

  const models::PackedMaterial m = Pack(*asset, 6);
  std::vector<double> expect(3 * n);
  BtfModel().ReferenceEval(m, request.wi().data(), request.wo().data(), request.uv().data(), n, expect.data());
  const double peak = *std::max_element(expect.begin(), expect.end());
  ASSERT_GT(peak, 0.5);
  auto server = testing::StartInProcessServer();
  ASSERT_TRUE(server);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  v1::EvaluateResponse response;
  const grpc::Status status = testing::Connect(server->port())->Evaluate(&context, request, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_EQ(size_t(response.f_size()), 3 * n);
  double worst = 0;
  for (size_t i = 0; i < 3 * n; ++i) worst = std::max(worst, std::abs(double(response.f(int(i))) - expect[i]) / peak);
  EXPECT_LT(worst, 2e-5);
}

// An asset larger than 2^24 values, whose tile-mean block starts at an offset a float32 table cannot hold (the
// packed material is kept as float32): read from the header, the tile means came one value off, in the kernels
// and the double reference alike (its table is made from the float one). The tile mean, the BRDF, must still
// be the mean of the BTF over the texel centres (as in BrdfIsTheMeanOfTheBtfOverTheTile), in both.
TEST(BtfKernels, OffsetsBeyondWhatAFloatHoldsAreExact) {
  const BtfImages im = LowRankImages(SmallGrid(), 232, 6, 11);
  auto asset = Register(models::btf::Compress(im, {.max_components = 6}, nullptr, nullptr), "test_large");
  ASSERT_TRUE(asset);
  const models::PackedMaterial m = Pack(*asset, 6);
  // The tile means' offset by the layout (kernels/models/btf.h), from the header's small integers.
  const double* header = m.values64();
  const double n_dirs = header[4], kept = header[0];
  const double means_offset =
      8 + 3 * header[3] + n_dirs * n_dirs * kept + n_dirs * header[1] * header[2] * 3 * (1 + kept);
  ASSERT_NE(double(float(means_offset)), means_offset) << "the test needs an offset a float cannot hold";
  const size_t texels = size_t(im.width) * im.height;
  std::vector<float> wi, wo, uv;
  for (int t = 0; t < im.width * im.height; ++t)
    uv.insert(uv.end(), {float((t % im.width + 0.5) / im.width), float((t / im.width + 0.5) / im.height)});
  const float pairs[3][6] = {{0, 0, 1, 0, 0, 1}, {0.6f, 0, 0.8f, 0, 0.6f, 0.8f}, {-0.28f, 0.48f, 0.83f, 0.5f, 0.1f, 0.86f}};
  for (const auto& pair : pairs) {
    wi.assign(3 * texels, 0.0f);
    wo.assign(3 * texels, 0.0f);
    for (size_t t = 0; t < texels; ++t)
      for (int c = 0; c < 3; ++c) wi[3 * t + c] = pair[c], wo[3 * t + c] = pair[3 + c];
    std::vector<double> btf(3 * texels);
    BtfModel().ReferenceEval(m, wi.data(), wo.data(), uv.data(), texels, btf.data());
    double mean[3] = {0, 0, 0};
    for (size_t t = 0; t < texels; ++t)
      for (int c = 0; c < 3; ++c) mean[c] += btf[3 * t + c] / double(texels);
    double reference[3];
    BtfModel().ReferenceEval(m, pair, pair + 3, nullptr, 1, reference);
    const std::vector<double> kernel =
        testing::RunKernel(BtfModel(), m, false, {pair, pair + 3}, {pair + 3, pair + 6}, {});
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(reference[c], mean[c], 1e-4 * mean[c]) << "double reference, channel " << c;
      EXPECT_NEAR(kernel[c], mean[c], 1e-4 * mean[c]) << "OpenCL fp32, channel " << c;
    }
  }
}

// Without uv the model is the BTF's mean over the tile (DESIGN.md: BRDF = average of BTF): at texel centres
// the bilinear filter returns texels, so the mean over centres is the tile mean exactly.
TEST(BtfKernels, BrdfIsTheMeanOfTheBtfOverTheTile) {
  const BtfImages im = LowRankImages(SmallGrid(), 4, 3, 9);
  auto asset = Register(models::btf::Compress(im, {.max_components = 3}, nullptr, nullptr), "test_mean");
  const models::PackedMaterial m = Pack(*asset, 3);
  const float wi[3] = {0.3f, -0.2f, 0.93273791f}, wo[3] = {-0.5f, 0.1f, 0.86023253f};
  std::vector<float> wis, wos, uv;
  for (int t = 0; t < 16; ++t) {
    wis.insert(wis.end(), wi, wi + 3), wos.insert(wos.end(), wo, wo + 3);
    uv.insert(uv.end(), {float((t % 4 + 0.5) / 4), float((t / 4 + 0.5) / 4)});
  }
  std::vector<double> btf(48), brdf(3);
  BtfModel().ReferenceEval(m, wis.data(), wos.data(), uv.data(), 16, btf.data());
  BtfModel().ReferenceEval(m, wi, wo, nullptr, 1, brdf.data());
  for (int c = 0; c < 3; ++c) {
    double mean = 0;
    for (int t = 0; t < 16; ++t) mean += btf[3 * t + c] / 16;
    EXPECT_NEAR(brdf[c], mean, 1e-6 * mean);
  }
}

TEST(BtfKernels, BelowTheSurfaceIsBlack) {
  const models::PackedMaterial m = BtfModel().Pack(BtfModel().DefaultValues());  // the built-in asset
  const float up[3] = {0, 0, 1}, down[3] = {0, 0.6f, -0.8f}, horizon[3] = {1, 0, 0};
  double f[3];
  for (const float* below : {down, horizon}) {
    BtfModel().ReferenceEval(m, up, below, nullptr, 1, f);
    EXPECT_EQ(f[0] + f[1] + f[2], 0);
    BtfModel().ReferenceEval(m, below, up, nullptr, 1, f);
    EXPECT_EQ(f[0] + f[1] + f[2], 0);
  }
  // Head-on, the checker's mean over the tile: (0.5 + 0.1 c) / pi, the contrast averaging out.
  BtfModel().ReferenceEval(m, up, up, nullptr, 1, f);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(f[c], (0.5 + 0.1 * c) / M_PI, 1e-6) << c;
}

TEST(BtfStore, NamesThatCouldEscapeTheDirectoryAreRefused) {
  for (const char* bad : {"", "../x", "a/b", ".hidden", "..", "x\\y", "a b", "name\n"})
    EXPECT_NE(assets::ValidateAssetName(bad), "") << bad;
  EXPECT_EQ(assets::ValidateAssetName("twill_64.v2-a"), "");
  EXPECT_NE(assets::ValidateAssetName(std::string(65, 'a')), "");
}

// ---- The store on disk (two stores on one directory are two replicas sharing a volume) ----

class BtfStoreOnDisk : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("loomlight-btf-store-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
  }
  void TearDown() override {
    for (const auto& a : models::btf::Assets::Global().List())
      if (a->name.rfind("disk_", 0) == 0) models::btf::Assets::Global().Remove(a->id);
    std::filesystem::remove_all(dir_);
  }
  std::unique_ptr<assets::BtfStore> Open() {
    std::string error;
    auto store = assets::BtfStore::Open(dir_.string(), uint64_t{1} << 30, &error);
    EXPECT_TRUE(store) << error;
    return store;
  }
  // A small asset; `source` tells whose it is.
  static std::shared_ptr<models::btf::BtfAsset> Small(const std::string& name, const std::string& source) {
    auto asset = models::btf::Compress(LowRankImages(SmallGrid(), 4, 2, 5), {.max_components = 2}, nullptr, nullptr);
    asset->name = name;
    asset->source = source;
    return asset;
  }
  // The source in the manifest the directory holds under `name` ("" when none can be read).
  std::string SourceOnDisk(const std::string& name) const {
    std::ifstream in(dir_ / "btf" / name / "manifest.pb", std::ios::binary);
    v1::BtfAssetInfo info;
    return in && info.ParseFromIstream(&in) ? info.source() : "";
  }
  std::filesystem::path dir_;
};

// Store B checks the name, writes, and before it publishes, store A (another replica) stores the same name:
// B gets ALREADY_EXISTS and A's asset stays (B used to move A's directory away and put its own in place).
TEST_F(BtfStoreOnDisk, ACreateThatLosesTheRaceIsAlreadyExistsAndKeepsTheWinnersAsset) {
  auto a = Open(), b = Open();
  ASSERT_TRUE(a && b);
  std::string error_a, error_b;
  assets::BtfStore::Outcome won = assets::BtfStore::Outcome::kFailed;
  b->set_before_publish_for_test([&] { won = a->Put(Small("disk_race", "a"), false, &error_a); });
  EXPECT_EQ(b->Put(Small("disk_race", "b"), false, &error_b), assets::BtfStore::Outcome::kExists) << error_b;
  EXPECT_EQ(won, assets::BtfStore::Outcome::kOk) << error_a;
  EXPECT_EQ(SourceOnDisk("disk_race"), "a");
  ASSERT_TRUE(models::btf::Assets::Global().FindName("disk_race"));
  EXPECT_EQ(models::btf::Assets::Global().FindName("disk_race")->source, "a");
  // Nothing of B's write is left behind.
  for (const auto& entry : std::filesystem::directory_iterator(dir_ / "btf"))
    if (entry.is_symlink()) {
      EXPECT_EQ(entry.path().filename(), "disk_race");
    }
  size_t versions = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir_ / "btf"))
    versions += entry.path().filename().string().rfind(".v-", 0) == 0;
  EXPECT_EQ(versions, 1u);
}

// Two stores on one directory create the same names at once: each name is stored once, by the store that says
// so, and holds that store's bytes.
TEST_F(BtfStoreOnDisk, TwoStoresCreatingTheSameNamesAtOnceStoreEachOnce) {
  auto a = Open(), b = Open();
  ASSERT_TRUE(a && b);
  constexpr int kNames = 20;
  std::vector<assets::BtfStore::Outcome> outcome[2];
  std::vector<std::shared_ptr<models::btf::BtfAsset>> made[2];
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kNames; ++i) made[k].push_back(Small("disk_" + std::to_string(i), k == 0 ? "a" : "b"));
  std::thread threads[2];
  for (int k = 0; k < 2; ++k)
    threads[k] = std::thread([&, k] {
      for (int i = 0; i < kNames; ++i) {
        std::string error;
        outcome[k].push_back((k == 0 ? *a : *b).Put(made[k][i], false, &error));
      }
    });
  for (auto& t : threads) t.join();
  for (int i = 0; i < kNames; ++i) {
    const bool a_won = outcome[0][i] == assets::BtfStore::Outcome::kOk;
    const bool b_won = outcome[1][i] == assets::BtfStore::Outcome::kOk;
    EXPECT_NE(a_won, b_won) << i;
    EXPECT_EQ(outcome[a_won ? 1 : 0][i], assets::BtfStore::Outcome::kExists) << i;
    EXPECT_EQ(SourceOnDisk("disk_" + std::to_string(i)), a_won ? "a" : "b") << i;
  }
}

// Replacing an asset over and over while another thread reads the directory as a replica's Sync does: the name
// always holds a whole asset, the old or the new (the old store renamed the old directory away and then the
// new one into place: between the two, nothing).
TEST_F(BtfStoreOnDisk, ReplaceLeavesTheOldOrTheNewAssetNeverNothing) {
  auto a = Open();
  ASSERT_TRUE(a);
  std::string error;
  ASSERT_EQ(a->Put(Small("disk_replaced", "0"), false, &error), assets::BtfStore::Outcome::kOk) << error;
  std::atomic<bool> done{false};
  std::atomic<int> reads{0}, missing{0};
  // The store's own reader (what another server's Sync loads): a version removed after its replacement was
  // published sent it back to the link (it failed 6 of 82,647 reads under load before it did).
  std::thread reader([&] {
    while (!done) {
      std::shared_ptr<models::btf::BtfAsset> asset;
      if (!a->Load("disk_replaced", &asset).empty() || asset->source.empty()) ++missing;
      ++reads;
    }
  });
  // At the moment of publishing, the old asset is still whole.
  std::string at_publish;
  a->set_before_publish_for_test([&] { at_publish = SourceOnDisk("disk_replaced"); });
  for (int i = 1; i <= 200; ++i) {
    ASSERT_EQ(a->Put(Small("disk_replaced", std::to_string(i)), true, &error), assets::BtfStore::Outcome::kOk) << error;
    ASSERT_EQ(at_publish, std::to_string(i - 1));
  }
  while (reads < 100) std::this_thread::yield();  // the reader looked often enough to be a check at all
  done = true;
  reader.join();
  EXPECT_EQ(missing, 0) << "of " << reads << " reads";
  EXPECT_EQ(SourceOnDisk("disk_replaced"), "200");
  // Each replacement removed the version it replaced.
  size_t entries = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir_ / "btf")) ++entries, (void)entry;
  EXPECT_EQ(entries, 2u);  // the link and its version
}

// A write that fails (the file size limit here: permissions do not stop root) is reported with the system's
// reason, and nothing is published or left behind.
TEST_F(BtfStoreOnDisk, AWriteErrorIsReportedAndPublishesNothing) {
  auto a = Open();
  ASSERT_TRUE(a);
  struct rlimit saved {};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved), 0);
  const auto previous = ::signal(SIGXFSZ, SIG_IGN);  // write(2) fails with EFBIG instead of killing the process
  struct rlimit small = saved;
  small.rlim_cur = 1000;  // the tables are larger
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  std::string error;
  const auto outcome = a->Put(Small("disk_unwritten", "a"), false, &error);
  ::setrlimit(RLIMIT_FSIZE, &saved);
  ::signal(SIGXFSZ, previous);
  EXPECT_EQ(outcome, assets::BtfStore::Outcome::kFailed);
  EXPECT_NE(error.find("tables.f32"), std::string::npos) << error;
  EXPECT_NE(error.find(std::strerror(EFBIG)), std::string::npos) << error;
  EXPECT_FALSE(a->Exists("disk_unwritten"));
  EXPECT_TRUE(std::filesystem::is_empty(dir_ / "btf"));
}

// An asset another server is still writing (a plain directory whose tables are half there) does not load, and
// Sync loads it once it is whole (it used to try each manifest once, and the manifest did not change).
TEST_F(BtfStoreOnDisk, SyncRetriesAnAssetThatWasHalfWrittenAndLoadsItWhole) {
  auto a = Open();
  ASSERT_TRUE(a);
  // The asset's files, as a store elsewhere writes them.
  const auto elsewhere = dir_ / "elsewhere";
  std::string error;
  auto other = assets::BtfStore::Open(elsewhere.string(), uint64_t{1} << 30, &error);
  ASSERT_TRUE(other) << error;
  auto asset = Small("disk_half", "other");
  ASSERT_EQ(other->Put(asset, false, &error), assets::BtfStore::Outcome::kOk) << error;
  models::btf::Assets::Global().Remove(asset->id);  // registered by the other store only
  std::string tables;
  {
    std::ifstream in(elsewhere / "btf" / "disk_half" / "tables.f32", std::ios::binary);
    tables.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_GT(tables.size(), 100u);
  const auto half = dir_ / "btf" / "disk_half";
  std::filesystem::create_directory(half);
  std::filesystem::copy_file(elsewhere / "btf" / "disk_half" / "manifest.pb", half / "manifest.pb");
  {
    std::ofstream out(half / "tables.f32", std::ios::binary);
    out.write(tables.data(), std::streamsize(tables.size() / 2));
  }
  std::vector<std::string> log;
  const auto say = [&log](const std::string& line) { log.push_back(line); };
  EXPECT_EQ(a->Sync(say), 0);
  EXPECT_FALSE(models::btf::Assets::Global().FindName("disk_half"));
  ASSERT_EQ(log.size(), 1u);
  EXPECT_NE(log[0].find("not loaded"), std::string::npos) << log[0];
  EXPECT_EQ(a->Sync(say), 0);  // unchanged: not logged again
  EXPECT_EQ(log.size(), 1u);
  {
    std::ofstream out(half / "tables.f32", std::ios::binary | std::ios::app);
    out.write(tables.data() + tables.size() / 2, std::streamsize(tables.size() - tables.size() / 2));
  }
  EXPECT_EQ(a->Sync(say), 1);
  auto loaded = models::btf::Assets::Global().FindName("disk_half");
  ASSERT_TRUE(loaded);
  EXPECT_EQ(loaded->source, "other");
  EXPECT_EQ(loaded->tables->data32(), asset->tables->data32());
}

// An asset belongs to the client that stored it: another client can neither replace nor delete it, whether the
// store has loaded it or only finds it on disk (another replica's); a token with the admin right can, and the
// asset stays its owner's.
TEST_F(BtfStoreOnDisk, OnlyTheOwnerOrAnAdminReplacesOrDeletesAnAsset) {
  auto a = Open(), b = Open();
  ASSERT_TRUE(a && b);
  using Outcome = assets::BtfStore::Outcome;
  using Removal = assets::BtfStore::Removal;
  const auto by = [](const std::string& owner, const std::string& source) {
    auto asset = Small("disk_owned", source);
    asset->owner = owner;
    return asset;
  };
  std::string error;
  ASSERT_EQ(a->Put(by("host:alice", "alice"), false, &error), Outcome::kOk) << error;
  EXPECT_EQ(b->Put(by("host:bob", "bob"), true, &error), Outcome::kDenied);
  // On disk only (B has not loaded it): the owner is read from the directory.
  auto loaded = models::btf::Assets::Global().FindName("disk_owned");
  ASSERT_TRUE(loaded);
  models::btf::Assets::Global().Remove(loaded->id);
  EXPECT_EQ(b->Put(by("host:bob", "bob"), true, &error), Outcome::kDenied);
  EXPECT_EQ(b->Delete("disk_owned", "host:bob", false), Removal::kDenied);
  EXPECT_EQ(SourceOnDisk("disk_owned"), "alice");
  // An admin replaces it; it is still Alice's.
  ASSERT_EQ(b->Put(by("client:operator", "admin"), true, &error, true), Outcome::kOk) << error;
  EXPECT_EQ(SourceOnDisk("disk_owned"), "admin");
  ASSERT_TRUE(models::btf::Assets::Global().FindName("disk_owned"));
  EXPECT_EQ(models::btf::Assets::Global().FindName("disk_owned")->owner, "host:alice");
  EXPECT_EQ(a->Delete("disk_owned", "host:bob", false), Removal::kDenied);
  EXPECT_EQ(a->Delete("disk_owned", "host:alice", false), Removal::kRemoved);
  EXPECT_FALSE(a->Exists("disk_owned"));
  EXPECT_EQ(a->Delete("disk_owned", "host:alice", false), Removal::kNotFound);
}

// One client's assets together are bounded by its quota; another client's are not counted against it, and a
// replacement counts once.
TEST_F(BtfStoreOnDisk, AClientsAssetsAreBoundedByItsQuota) {
  auto a = Open();
  ASSERT_TRUE(a);
  const uint64_t one = Small("x", "x")->bytes();
  a->set_client_quota(2 * one + one / 2);
  using Outcome = assets::BtfStore::Outcome;
  std::string error;
  const auto by = [](const std::string& owner, const std::string& name) {
    auto asset = Small(name, owner);
    asset->owner = owner;
    return asset;
  };
  EXPECT_EQ(a->Put(by("host:alice", "disk_1"), false, &error), Outcome::kOk) << error;
  EXPECT_EQ(a->Put(by("host:alice", "disk_2"), false, &error), Outcome::kOk) << error;
  EXPECT_EQ(a->Put(by("host:alice", "disk_3"), false, &error), Outcome::kFull);
  EXPECT_NE(error.find("--btf-client-quota-mb"), std::string::npos) << error;
  EXPECT_EQ(a->Put(by("host:bob", "disk_3"), false, &error), Outcome::kOk) << error;
  EXPECT_EQ(a->Put(by("host:alice", "disk_2"), true, &error), Outcome::kOk) << error;
}

// Names that differ only in case are one name: one link (the name in lower case) however a client spells it, so
// two spellings cannot be two assets (on a case-insensitive volume they would be one file), nor can a second
// replica create the other spelling; the asset keeps the spelling it was created with.
TEST_F(BtfStoreOnDisk, NamesThatDifferOnlyInCaseAreOneName) {
  auto a = Open(), b = Open();
  ASSERT_TRUE(a && b);
  using Outcome = assets::BtfStore::Outcome;
  std::string error;
  ASSERT_EQ(a->Put(Small("disk_Case", "first"), false, &error), Outcome::kOk) << error;
  EXPECT_TRUE(std::filesystem::is_symlink(dir_ / "btf" / "disk_case"));
  EXPECT_EQ(a->Put(Small("DISK_CASE", "second"), false, &error), Outcome::kExists);
  // B's check before writing passes (the name unregistered), its publishing does not.
  auto loaded = models::btf::Assets::Global().FindName("DISK_case");
  ASSERT_TRUE(loaded);
  EXPECT_EQ(loaded->name, "disk_Case");
  models::btf::Assets::Global().Remove(loaded->id);
  EXPECT_TRUE(b->Exists("disk_CASE"));
  EXPECT_EQ(b->Put(Small("Disk_Case", "second"), false, &error), Outcome::kExists);
  EXPECT_EQ(b->Sync(), 1);
  ASSERT_TRUE(models::btf::Assets::Global().FindName("disk_case"));
  EXPECT_EQ(models::btf::Assets::Global().FindName("disk_case")->name, "disk_Case");  // from the manifest
  EXPECT_EQ(b->Put(Small("DISK_case", "replaced"), true, &error), Outcome::kOk) << error;
  EXPECT_EQ(SourceOnDisk("disk_case"), "replaced");
  EXPECT_EQ(b->Delete("disk_CASE", "", false), assets::BtfStore::Removal::kRemoved);
  EXPECT_TRUE(std::filesystem::is_empty(dir_ / "btf"));
  // An older server's plain directory spelled otherwise is the same name.
  std::filesystem::create_directories(dir_ / "btf" / "disk_Legacy");
  EXPECT_TRUE(a->Exists("DISK_LEGACY"));
  EXPECT_EQ(a->Put(Small("disk_legacy", "new"), false, &error), Outcome::kExists);
}

// ---- End to end ----

class BtfRpcTest : public ::testing::Test {
 protected:
  static std::string DataDir() {
    static const std::string dir = [] {
      auto d = std::filesystem::temp_directory_path() / ("loomlight-btf-test-" + std::to_string(::getpid()));
      std::filesystem::remove_all(d);
      return d.string();
    }();
    return dir;
  }
  static std::unique_ptr<api::LoomlightServer> Start() {
    api::ServerOptions options;
    options.data_dir = DataDir();
    return testing::StartInProcessServer(options);
  }
  static void TearDownTestSuite() { std::filesystem::remove_all(DataDir()); }
};

v1::CreateBtfRequest TwillRequest(const std::string& name) {
  v1::CreateBtfRequest r;
  r.set_name(name);
  r.mutable_material()->set_preset("cotton_twill");
  r.set_resolution(16);
  for (auto [theta, count] : {std::pair{0.0, 1u}, {20.0, 6u}, {40.0, 8u}, {60.0, 12u}}) {
    v1::BtfRing* ring = r.mutable_grid()->add_rings();
    ring->set_theta(theta);
    ring->set_count(count);
  }
  r.mutable_compression()->set_max_components(12);
  return r;
}

grpc::Status Create(v1::Loomlight::Stub& stub, const v1::CreateBtfRequest& r, v1::BtfAssetInfo* info,
                    int* progress_messages = nullptr) {
  grpc::ClientContext ctx;
  auto reader = stub.CreateBtf(&ctx, r);
  v1::CreateBtfProgress p;
  int messages = 0;
  while (reader->Read(&p)) {
    ++messages;
    if (p.has_asset()) *info = p.asset();
  }
  if (progress_messages) *progress_messages = messages;
  return reader->Finish();
}

v1::EvaluateRequest BtfEvaluate(const std::string& asset, int components) {
  v1::EvaluateRequest r;
  r.mutable_material()->set_model("btf");
  v1::Param* p = r.mutable_material()->add_params();
  p->set_name("asset");
  p->set_text(asset);
  if (components > 0) {
    p = r.mutable_material()->add_params();
    p->set_name("components");
    p->add_values(components);
  }
  return r;
}

TEST_F(BtfRpcTest, SynthesisedTwillReproducesTheWovenBtfAtGridDirectionsAndSurvivesRestart) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::BtfAssetInfo info;
  int messages = 0;
  grpc::Status s = Create(*stub, TwillRequest("twill16"), &info, &messages);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_GT(messages, 3);  // progress, then the asset
  ASSERT_EQ(info.name(), "twill16");
  ASSERT_EQ(info.components(), 12u);
  EXPECT_EQ(info.threads_per_tile(), 4);  // the 3/1 twill's repeat: what the fidelity chooser compares with a pixel
  ASSERT_EQ(info.errors_size(), 13);
  for (int c = 1; c < info.errors_size(); ++c) EXPECT_LE(info.errors(c).rmse(), info.errors(c - 1).rmse() * (1 + 1e-12));
  EXPECT_LT(info.errors(12).rmse(), info.errors(1).rmse());

  // The woven model and the asset at every grid pair and texel centre.
  DirectionGrid grid;
  ASSERT_EQ(assets::GridOf(TwillRequest("x").grid(), "grid", &grid), "");
  BtfImages shape;
  shape.grid = grid;
  shape.width = shape.height = 16;
  std::vector<float> wi, wo, uv;
  GridQueries(shape, &wi, &wo, &uv);
  v1::EvaluateRequest woven;
  woven.mutable_material()->set_preset("cotton_twill");
  for (auto* r : {&woven}) {
    *r->mutable_wi() = {wi.begin(), wi.end()};
    *r->mutable_wo() = {wo.begin(), wo.end()};
    *r->mutable_uv() = {uv.begin(), uv.end()};
  }
  v1::EvaluateResponse truth;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub->Evaluate(&ctx, woven, &truth).ok());
  }
  const std::vector<float> images(truth.f().begin(), truth.f().end());
  std::vector<double> restarted_f;
  for (int c : {2, 6, 12}) {
    v1::EvaluateRequest r = BtfEvaluate("twill16", c);
    *r.mutable_wi() = woven.wi();
    *r.mutable_wo() = woven.wo();
    *r.mutable_uv() = woven.uv();
    v1::EvaluateResponse got;
    grpc::ClientContext ctx;
    s = stub->Evaluate(&ctx, r, &got);
    ASSERT_TRUE(s.ok()) << s.error_message();
    const std::vector<double> f(got.f().begin(), got.f().end());
    // fp32 kernels and float tables: 1e-5 of the peak on top of the reported error.
    EXPECT_LE(Rms(f, images), info.errors(c).rmse() * 1.001 + 1e-5 * info.peak()) << "c = " << c;
    if (c == 12) restarted_f = f;
  }

  // Listed, and the same after a restart of the server on the same data directory.
  server.reset();
  server = Start();
  ASSERT_TRUE(server);
  stub = testing::Connect(server->port());
  v1::ListBtfsResponse list;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub->ListBtfs(&ctx, {}, &list).ok());
  }
  // (This process's other tests registered assets of their own, outside the store.)
  const v1::BtfAssetInfo* listed = nullptr;
  for (const v1::BtfAssetInfo& a : list.assets())
    if (a.name() == "twill16") listed = &a;
  ASSERT_TRUE(listed);
  EXPECT_EQ(listed->bytes(), info.bytes());
  EXPECT_EQ(listed->errors_size(), info.errors_size());
  v1::EvaluateRequest again = BtfEvaluate("twill16", 12);
  *again.mutable_wi() = woven.wi();
  *again.mutable_wo() = woven.wo();
  *again.mutable_uv() = woven.uv();
  v1::EvaluateResponse after;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub->Evaluate(&ctx, again, &after).ok());
  }
  ASSERT_EQ(after.f_size(), int(restarted_f.size()));
  for (int i = 0; i < after.f_size(); ++i) ASSERT_EQ(after.f(i), float(restarted_f[i])) << i;

  // Between grid directions: the interpolation error of the BRDF against the woven model's own, reported.
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  v1::EvaluateRequest between = BtfEvaluate("twill16", 12), woven_between;
  woven_between.mutable_material()->set_preset("cotton_twill");
  for (int q = 0; q < 2000; ++q)
    for (auto* w : {between.mutable_wi(), between.mutable_wo()}) {
      const float z = 0.55f + 0.45f * unit(rng), phi = 6.2831853f * unit(rng), sn = std::sqrt(1 - z * z);
      w->Add(sn * std::cos(phi)), w->Add(sn * std::sin(phi)), w->Add(z);
    }
  *woven_between.mutable_wi() = between.wi();
  *woven_between.mutable_wo() = between.wo();
  v1::EvaluateResponse a, b;
  {
    grpc::ClientContext c1, c2;
    ASSERT_TRUE(stub->Evaluate(&c1, between, &a).ok());
    ASSERT_TRUE(stub->Evaluate(&c2, woven_between, &b).ok());
  }
  double num = 0, den = 0;
  for (int i = 0; i < a.f_size(); ++i) num += std::pow(a.f(i) - b.f(i), 2), den += std::pow(b.f(i), 2);
  const double relative = std::sqrt(num / den);
  std::printf("BRDF between grid directions (theta < 57 deg): relative RMS error %.3f against the woven model\n",
              relative);
  EXPECT_LT(relative, 0.1);  // measured 0.03

  // Deleted: gone from the list and from materials.
  {
    grpc::ClientContext ctx;
    v1::DeleteBtfRequest del;
    del.set_name("twill16");
    v1::DeleteBtfResponse out;
    ASSERT_TRUE(stub->DeleteBtf(&ctx, del, &out).ok());
  }
  {
    grpc::ClientContext ctx;
    v1::EvaluateResponse out;
    s = stub->Evaluate(&ctx, again, &out);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("twill16"), std::string::npos) << s.error_message();
  }
}

TEST_F(BtfRpcTest, BadRequestsAreRefusedNamingTheField) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  struct Case {
    v1::CreateBtfRequest request;
    grpc::StatusCode code;
    std::string field;
  };
  std::vector<Case> cases;
  for (const char* name : {"../escape", "a/b", ".hidden", "", "/etc/passwd"}) cases.push_back({TwillRequest(name), grpc::StatusCode::INVALID_ARGUMENT, "name"});
  Case c{TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "material"};
  c.request.mutable_material()->set_preset("cotton_microcylinder_does_not_exist");
  cases.push_back(c);
  c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "resolution"};
  c.request.set_resolution(100000);
  cases.push_back(c);
  c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "grid.rings[1].theta"};
  c.request.mutable_grid()->mutable_rings(1)->set_theta(95);
  cases.push_back(c);
  c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "grid.preset"};
  c.request.mutable_grid()->Clear();
  c.request.mutable_grid()->set_preset("/etc/passwd");
  cases.push_back(c);
  c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "compression.max_components"};
  c.request.mutable_compression()->set_max_components(1000);
  cases.push_back(c);
  for (double psnr : {-1.0, std::nan(""), 1e9}) {
    c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "compression.target_psnr_db"};
    c.request.mutable_compression()->set_target_psnr_db(psnr);
    cases.push_back(c);
  }
  c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "grid.rings[0].count"};
  c.request.mutable_grid()->mutable_rings(0)->set_count(6);  // theta 0 is one direction
  cases.push_back(c);
  c = {TwillRequest("ok"), grpc::StatusCode::INVALID_ARGUMENT, "grid.rings[2].count"};
  c.request.mutable_grid()->mutable_rings(2)->set_count(0);
  cases.push_back(c);
  for (const Case& k : cases) {
    v1::BtfAssetInfo info;
    grpc::Status s = Create(*stub, k.request, &info);
    EXPECT_EQ(s.error_code(), k.code) << k.field << ": " << s.error_message();
    EXPECT_EQ(s.error_message().rfind(k.field, 0), 0u) << s.error_message();
  }
  // A material that does not vary over the surface has no BTF.
  v1::CreateBtfRequest flat = TwillRequest("flat");
  flat.mutable_material()->Clear();
  flat.mutable_material()->set_model("microcylinder");
  v1::BtfAssetInfo info;
  grpc::Status s = Create(*stub, flat, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  // Deleting what is not there, or a path.
  for (const char* name : {"missing", "../../etc"}) {
    grpc::ClientContext ctx;
    v1::DeleteBtfRequest del;
    del.set_name(name);
    v1::DeleteBtfResponse out;
    s = stub->DeleteBtf(&ctx, del, &out);
    EXPECT_TRUE(s.error_code() == grpc::StatusCode::NOT_FOUND || s.error_code() == grpc::StatusCode::INVALID_ARGUMENT)
        << name;
  }
  // A material naming an asset that does not exist, or a path: assets are found by name only.
  for (const char* name : {"nothing_here", "../../etc/passwd", "/etc/passwd"}) {
    v1::EvaluateRequest r = BtfEvaluate(name, 0);
    r.add_wi(0), r.add_wi(0), r.add_wi(1), r.add_wo(0), r.add_wo(0), r.add_wo(1);
    grpc::ClientContext ctx;
    v1::EvaluateResponse out;
    s = stub->Evaluate(&ctx, r, &out);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << name;
    EXPECT_NE(s.error_message().find("no BTF asset named"), std::string::npos) << s.error_message();
  }
}

// The images a client would upload: TextureSlice of the woven twill at every grid pair, as EXR (exact floats).
std::vector<v1::BtfImage> SliceImages(v1::Loomlight::Stub& stub, const DirectionGrid& grid, int texels) {
  std::vector<v1::BtfImage> images;
  for (size_t v = 0; v < grid.size(); ++v)
    for (size_t l = 0; l < grid.size(); ++l) {
      double dv[3], dl[3];
      grid.Direction(v, dv);
      grid.Direction(l, dl);
      v1::TextureSliceRequest r;
      r.mutable_material()->set_preset("cotton_twill");
      for (int c = 0; c < 3; ++c) r.add_wi(float(dl[c])), r.add_wo(float(dv[c]));
      r.set_width(texels);
      r.set_height(texels);
      r.set_format(v1::IMAGE_FORMAT_EXR);
      v1::TextureSliceResponse out;
      grpc::ClientContext ctx;
      EXPECT_TRUE(stub.TextureSlice(&ctx, r, &out).ok());
      v1::BtfImage& image = images.emplace_back();
      for (int c = 0; c < 3; ++c) image.add_view(float(dv[c])), image.add_light(float(dl[c]));
      image.set_data(out.image());
    }
  return images;
}

v1::UploadBtfHeader UploadHeader(const std::string& name, int texels) {
  v1::UploadBtfHeader h;
  h.set_name(name);
  *h.mutable_grid() = TwillRequest("x").grid();
  h.set_width(texels);
  h.set_height(texels);
  h.mutable_compression()->set_max_components(12);
  return h;
}

grpc::Status Upload(v1::Loomlight::Stub& stub, const v1::UploadBtfHeader* header, const std::vector<v1::BtfImage>& images,
                    v1::BtfAssetInfo* info) {
  grpc::ClientContext ctx;
  auto writer = stub.UploadBtf(&ctx, info);
  v1::UploadBtfMessage m;
  if (header) {
    *m.mutable_header() = *header;
    writer->Write(m);
  }
  for (const v1::BtfImage& image : images) {
    *m.mutable_image() = image;
    if (!writer->Write(m)) break;  // the server ended the call
  }
  writer->WritesDone();
  return writer->Finish();
}

// The fiber source: a cotton twill's fibers, one weave repeat captured (server/render/btf_capture.h), stored and
// served like any asset; its bad requests refused naming the field; a deadline stops it and the server goes on.
v1::CreateBtfRequest FiberRequest(const std::string& name) {
  v1::CreateBtfRequest r = TwillRequest(name);
  r.mutable_material()->Clear();
  r.mutable_material()->set_preset("cotton");  // the fiber model
  r.set_resolution(8);
  r.mutable_fibers()->set_samples_per_texel(2);
  return r;
}

TEST_F(BtfRpcTest, FiberSourceCapturesAWovenPatchOfFibers) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::BtfAssetInfo info;
  grpc::Status s = Create(*stub, FiberRequest("fibers8"), &info);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(info.source().rfind("fibers: 4 x 4 weave", 0), 0u) << info.source();  // cotton_twill's repeat
  EXPECT_NE(info.source().find("2 rays per texel"), std::string::npos) << info.source();
  EXPECT_EQ(info.threads_per_tile(), 4);
  EXPECT_EQ(info.width(), 8u);
  ASSERT_EQ(info.errors_size(), 13);
  for (int c = 1; c < info.errors_size(); ++c) EXPECT_LE(info.errors(c).rmse(), info.errors(c - 1).rmse() * (1 + 1e-12));
  EXPECT_GT(info.peak(), 0.0);
  // Served through Evaluate: finite, non-negative, and lit wherever a texel sees fibers lit from above.
  v1::EvaluateRequest r = BtfEvaluate("fibers8", 0);
  double sum = 0;
  for (int i = 0; i < 64; ++i) {
    r.add_wi(0.3f), r.add_wi(0.0f), r.add_wi(std::sqrt(1 - 0.09f));
    r.add_wo(0.0f), r.add_wo(-0.4f), r.add_wo(std::sqrt(1 - 0.16f));
    r.add_uv((i % 8 + 0.5f) / 8), r.add_uv((i / 8 + 0.5f) / 8);
  }
  grpc::ClientContext ctx;
  v1::EvaluateResponse out;
  s = stub->Evaluate(&ctx, r, &out);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(out.f_size(), 3 * 64);
  for (float f : out.f()) {
    EXPECT_TRUE(std::isfinite(f));
    EXPECT_GE(f, 0.0f);
    sum += f;
  }
  // Cotton fibers under a light 17 degrees off the normal: between a dark 0.005 and an implausible 1 per sr.
  EXPECT_GT(sum / out.f_size(), 0.005);
  EXPECT_LT(sum / out.f_size(), 1.0);

  struct Case {
    v1::CreateBtfRequest request;
    std::string field;
  };
  std::vector<Case> cases;
  Case c{FiberRequest("bad"), "fibers.samples_per_texel"};
  c.request.mutable_fibers()->set_samples_per_texel(65);
  cases.push_back(c);
  c = {FiberRequest("bad"), "fibers.woven.repeats_u"};
  c.request.mutable_fibers()->mutable_woven()->set_repeats_u(2);
  cases.push_back(c);
  c = {FiberRequest("bad"), "fibers.yarn"};
  c.request.mutable_fibers()->mutable_yarn()->set_preset("../cotton1");
  cases.push_back(c);
  c = {FiberRequest("bad"), "fibers.woven.crimp"};
  c.request.mutable_fibers()->mutable_woven()->set_crimp(2);
  cases.push_back(c);
  c = {FiberRequest("bad"), "fibers.woven.weave"};
  c.request.mutable_fibers()->mutable_woven()->mutable_weave()->set_preset("cotton");  // a fiber model: no pattern
  cases.push_back(c);
  c = {FiberRequest("bad"), "fibers.yarn"};  // 24 yarns x 3 plies x 20,000 fibers: over the fiber limit
  v1::Param* many = c.request.mutable_fibers()->mutable_yarn()->add_params();
  many->set_name("fibers_per_ply");
  many->add_values(20000);
  cases.push_back(c);
  c = {FiberRequest("bad"), "material"};  // the woven model shades no fibers
  c.request.mutable_material()->set_preset("cotton_twill");
  cases.push_back(c);
  for (const Case& k : cases) {
    grpc::Status bad = Create(*stub, k.request, &info);
    EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << k.field << ": " << bad.error_message();
    EXPECT_EQ(bad.error_message().rfind(k.field, 0), 0u) << bad.error_message();
  }
  // A fiber model without the fiber source does not vary over the surface.
  v1::CreateBtfRequest plain = FiberRequest("plain");
  plain.clear_fibers();
  EXPECT_EQ(Create(*stub, plain, &info).error_code(), grpc::StatusCode::INVALID_ARGUMENT);

  // A deadline stops a large capture (h1 at 64 x 64 texels, 64 rays each: minutes) mid-way; nothing is stored and
  // the server serves the next call.
  v1::CreateBtfRequest big = FiberRequest("big");
  big.mutable_grid()->Clear();
  big.mutable_grid()->set_preset("h1");
  big.set_resolution(64);
  big.mutable_fibers()->set_samples_per_texel(64);
  {
    grpc::ClientContext deadline;
    deadline.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(1500));
    auto reader = stub->CreateBtf(&deadline, big);
    v1::CreateBtfProgress p;
    while (reader->Read(&p)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  }
  grpc::ClientContext list_ctx;
  v1::ListBtfsResponse listed;
  ASSERT_TRUE(stub->ListBtfs(&list_ctx, v1::ListBtfsRequest(), &listed).ok());
  for (const v1::BtfAssetInfo& a : listed.assets()) EXPECT_NE(a.name(), "big");
  s = Create(*stub, FiberRequest("after"), &info);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

// The fiber source with a knit: its tile one repeat of the stitch (jersey one wale, rib two, by one course), in
// the middle of a patch the server lays out around it; every texel of the tile sees the knit (a tile off the
// patch would see black), and its bad requests are refused naming the field.
TEST_F(BtfRpcTest, FiberSourceCapturesOneRepeatOfAKnit) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  for (const auto& [stitch, name, wales] :
       {std::tuple{v1::KNIT_JERSEY, "jersey", 1}, std::tuple{v1::KNIT_RIB_1X1, "1 x 1 rib", 2}}) {
    v1::CreateBtfRequest request = FiberRequest(std::string("knit_") + (wales == 1 ? "jersey" : "rib"));
    request.mutable_fibers()->mutable_knit()->set_stitch(stitch);
    v1::BtfAssetInfo info;
    grpc::Status s = Create(*stub, request, &info);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(info.source().rfind(std::string("fibers: ") + name + " knit", 0), 0u) << info.source();
    EXPECT_EQ(info.threads_per_tile(), wales);
    EXPECT_GT(info.peak(), 0.0);
    // Seen from the normal, lit 17 degrees off it: every texel's value finite, most texels see a fiber (black is
    // a miss; a fiber in shadow still gets some light through the others at 2 rays a texel), and the mean is
    // that of the woven source's cotton: between a dark 0.005 and an implausible 1 per sr.
    v1::EvaluateRequest r = BtfEvaluate(request.name(), 0);
    for (int i = 0; i < 64; ++i) {
      r.add_wi(0.3f), r.add_wi(0.0f), r.add_wi(std::sqrt(1 - 0.09f));
      r.add_wo(0.0f), r.add_wo(0.0f), r.add_wo(1.0f);
      r.add_uv((i % 8 + 0.5f) / 8), r.add_uv((i / 8 + 0.5f) / 8);
    }
    grpc::ClientContext ctx;
    v1::EvaluateResponse out;
    s = stub->Evaluate(&ctx, r, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
    ASSERT_EQ(out.f_size(), 3 * 64);
    int seen = 0;
    double sum = 0;
    for (int t = 0; t < 64; ++t) {
      for (int c = 0; c < 3; ++c) EXPECT_TRUE(std::isfinite(out.f(3 * t + c)) && out.f(3 * t + c) >= 0);
      seen += out.f(3 * t) > 0;
      sum += out.f(3 * t);
    }
    EXPECT_GT(seen, 32) << name;
    EXPECT_GT(sum / 64, 0.005) << name;
    EXPECT_LT(sum / 64, 1.0) << name;
  }

  struct Case {
    std::function<void(v1::FiberBtfSource*)> edit;
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](auto* f) { f->mutable_knit()->set_wales(4); }, "fibers.knit.wales"},
      {[](auto* f) { f->mutable_knit()->set_course_spacing(0.01); }, "fibers.knit.course_spacing"},
      {[](auto* f) { f->mutable_knit()->set_stitch(static_cast<v1::KnitStitch>(9)); }, "fibers.knit.stitch"},
      {[](auto* f) { f->mutable_knit(), f->mutable_woven()->set_crimp(0.5); }, "fibers.knit"},
  };
  for (const Case& c : cases) {
    v1::CreateBtfRequest bad = FiberRequest("bad");
    c.edit(bad.mutable_fibers());
    v1::BtfAssetInfo info;
    const grpc::Status s = Create(*stub, bad, &info);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.field << ": " << s.error_message();
    EXPECT_EQ(s.error_message().rfind(c.field, 0), 0u) << s.error_message();
  }
}

// Replicas sharing one data directory (a volume): each sees the assets another creates, replaces and deletes,
// within its sync period or at once on SIGHUP, and none overwrites another's asset without `replace`.
TEST(BtfSharedDirectory, ReplicasSeeEachOthersAssets) {
  const auto dir = std::filesystem::temp_directory_path() / ("loomlight-btf-shared-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  testing::ServerProcess a({"--data-dir", dir.string(), "--btf-sync-seconds", "1"});
  testing::ServerProcess b({"--data-dir", dir.string(), "--btf-sync-seconds", "0"});  // syncs on SIGHUP only
  testing::ServerProcess c({"--data-dir", dir.string(), "--btf-sync-seconds", "1"});
  auto on_a = testing::Connect(a.port()), on_b = testing::Connect(b.port()), on_c = testing::Connect(c.port());
  const auto listed = [](v1::Loomlight::Stub& stub, const std::string& name) {
    grpc::ClientContext ctx;
    v1::ListBtfsResponse out;
    if (!stub.ListBtfs(&ctx, v1::ListBtfsRequest(), &out).ok()) return std::string("(list failed)");
    for (const v1::BtfAssetInfo& asset : out.assets())
      if (asset.name() == name) return asset.source() + " c=" + std::to_string(asset.components());
    return std::string();
  };
  const auto wait_until = [](const std::function<bool()>& ok) {
    for (int i = 0; i < 100; ++i) {
      if (ok()) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return false;
  };
  // f at a few (wi, wo, uv), or the error.
  const auto evaluate = [](v1::Loomlight::Stub& stub) {
    v1::EvaluateRequest r = BtfEvaluate("shared", 0);
    for (int i = 0; i < 8; ++i) {
      r.add_wi(0.3f), r.add_wi(0.1f * i), r.add_wi(std::sqrt(1 - 0.09f - 0.01f * i * i));
      r.add_wo(0), r.add_wo(0), r.add_wo(1);
      r.add_uv(0.1f * i), r.add_uv(0.05f * i);
    }
    grpc::ClientContext ctx;
    v1::EvaluateResponse out;
    const grpc::Status s = stub.Evaluate(&ctx, r, &out);
    return s.ok() ? std::vector<float>(out.f().begin(), out.f().end()) : std::vector<float>{};
  };

  v1::BtfAssetInfo info;
  grpc::Status s = Create(*on_a, TwillRequest("shared"), &info);
  ASSERT_TRUE(s.ok()) << s.error_message();
  // B has not looked at the directory since it started, yet does not overwrite A's asset without `replace`.
  EXPECT_EQ(listed(*on_b, "shared"), "");
  s = Create(*on_b, TwillRequest("shared"), &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS) << s.error_message();
  // C finds it within its period and reconstructs exactly what A does.
  ASSERT_TRUE(wait_until([&] { return !listed(*on_c, "shared").empty(); }));
  const std::vector<float> first = evaluate(*on_a);
  ASSERT_EQ(first.size(), 24u);
  EXPECT_EQ(evaluate(*on_c), first);
  // B on SIGHUP.
  ASSERT_EQ(::kill(b.pid(), SIGHUP), 0);
  ASSERT_TRUE(wait_until([&] { return !listed(*on_b, "shared").empty(); }));
  EXPECT_EQ(evaluate(*on_b), first);
  // Replaced on A with fewer components: C serves the new tables (its cached material dropped with them).
  v1::CreateBtfRequest fewer = TwillRequest("shared");
  fewer.mutable_compression()->set_max_components(2);
  fewer.set_replace(true);
  s = Create(*on_a, fewer, &info);
  ASSERT_TRUE(s.ok()) << s.error_message();
  const std::vector<float> second = evaluate(*on_a);
  ASSERT_EQ(second.size(), 24u);
  EXPECT_NE(second, first);
  EXPECT_TRUE(wait_until([&] { return evaluate(*on_c) == second; }));
  EXPECT_NE(listed(*on_c, "shared").find("c=2"), std::string::npos) << listed(*on_c, "shared");
  // Deleted on A: gone from C.
  {
    grpc::ClientContext ctx;
    v1::DeleteBtfRequest del;
    del.set_name("shared");
    v1::DeleteBtfResponse out;
    ASSERT_TRUE(on_a->DeleteBtf(&ctx, del, &out).ok());
  }
  EXPECT_TRUE(wait_until([&] { return listed(*on_c, "shared").empty() && evaluate(*on_c).empty(); }));
  std::filesystem::remove_all(dir);
}

TEST_F(BtfRpcTest, UploadedImagesGiveTheServerSynthesisedAsset) {
  auto server = Start();
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::BtfAssetInfo made, uploaded;
  v1::CreateBtfRequest create = TwillRequest("twill_made");
  ASSERT_TRUE(Create(*stub, create, &made).ok());
  DirectionGrid grid;
  ASSERT_EQ(assets::GridOf(create.grid(), "grid", &grid), "");
  std::vector<v1::BtfImage> images = SliceImages(*stub, grid, 16);
  std::reverse(images.begin(), images.end());  // any order
  const v1::UploadBtfHeader header = UploadHeader("twill_uploaded", 16);
  grpc::Status s = Upload(*stub, &header, images, &uploaded);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(uploaded.source(), "upload");
  ASSERT_EQ(uploaded.errors_size(), made.errors_size());
  EXPECT_EQ(uploaded.peak(), made.peak());
  for (int c = 0; c < made.errors_size(); ++c)
    EXPECT_NEAR(uploaded.errors(c).rmse(), made.errors(c).rmse(), 1e-9 * made.peak()) << c;
  // Evaluated alike at random directions and positions.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  v1::EvaluateRequest a = BtfEvaluate("twill_made", 0);
  for (int q = 0; q < 500; ++q) {
    for (auto* w : {a.mutable_wi(), a.mutable_wo()}) {
      const float z = 0.2f + 0.8f * unit(rng), phi = 6.2831853f * unit(rng), sn = std::sqrt(1 - z * z);
      w->Add(sn * std::cos(phi)), w->Add(sn * std::sin(phi)), w->Add(z);
    }
    a.add_uv(unit(rng)), a.add_uv(unit(rng));
  }
  v1::EvaluateRequest b = a;
  b.mutable_material()->mutable_params(0)->set_text("twill_uploaded");
  v1::EvaluateResponse fa, fb;
  grpc::ClientContext c1, c2;
  ASSERT_TRUE(stub->Evaluate(&c1, a, &fa).ok());
  ASSERT_TRUE(stub->Evaluate(&c2, b, &fb).ok());
  for (int i = 0; i < fa.f_size(); ++i) ASSERT_NEAR(fa.f(i), fb.f(i), 1e-5 * made.peak()) << i;

  // Bad uploads, each refused naming the image or the header field.
  const std::string small = SliceImages(*stub, DirectionGrid{{{0, 1}}}, 8)[0].data();  // 8 x 8, not 16 x 16
  struct Bad {
    std::string why, field;
    std::function<void(v1::UploadBtfHeader*, std::vector<v1::BtfImage>*)> spoil;
  };
  const std::vector<Bad> bad = {
      {"image size differs", "images[5].data", [&small](auto*, auto* im) { (*im)[5].set_data(small); }},
      {"not an image", "images[3].data", [](auto*, auto* im) { (*im)[3].set_data("GIF89a this is not a picture"); }},
      {"repeated pair", "images[7]", [](auto*, auto* im) { (*im)[7] = (*im)[2]; }},
      {"missing pair", "images", [](auto*, auto* im) { im->pop_back(); }},
      {"too many", "images[729]", [](auto*, auto* im) { im->push_back(im->front()); }},
      {"direction off the grid", "images[4].light", [](auto*, auto* im) { (*im)[4].set_light(0, 0.1f), (*im)[4].set_light(2, 0.99498744f); }},
      {"not unit", "images[9].view", [](auto*, auto* im) { (*im)[9].set_view(2, 3.0f); }},
      {"bad name", "header.name", [](auto* h, auto*) { h->set_name("../../etc/x"); }},
      {"bad size", "header.width", [](auto* h, auto*) { h->set_width(100000); }},
      {"negative scale", "header.value_scale", [](auto* h, auto*) { h->set_value_scale(-1); }},
      {"threads", "header.threads_per_tile", [](auto* h, auto*) { h->set_threads_per_tile(5000); }},
      {"no size", "header.width", [](auto* h, auto*) { h->set_height(0); }},
  };
  for (const Bad& b : bad) {
    v1::UploadBtfHeader h = UploadHeader("twill_bad", 16);
    std::vector<v1::BtfImage> im = SliceImages(*stub, grid, 16);
    b.spoil(&h, &im);
    v1::BtfAssetInfo out;
    grpc::Status st = Upload(*stub, &h, im, &out);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << b.why << ": " << st.error_message();
    EXPECT_EQ(st.error_message().rfind(b.field, 0), 0u) << b.why << ": " << st.error_message();
  }
  v1::BtfAssetInfo out;
  EXPECT_EQ(Upload(*stub, nullptr, images, &out).error_code(), grpc::StatusCode::INVALID_ARGUMENT);  // no header
  v1::ListBtfsResponse list;
  grpc::ClientContext ctx;
  ASSERT_TRUE(stub->ListBtfs(&ctx, {}, &list).ok());
  for (const v1::BtfAssetInfo& a : list.assets()) EXPECT_NE(a.name(), "twill_bad");
}

// An upload whose client sends its header and then nothing holds only what it sent: two such stalled uploads,
// whose headers promise h1 at 32 x 32 (~136 MB each to compress), do not keep a CreateBtf of that size from a
// 300 MB memory budget.
TEST_F(BtfRpcTest, StalledUploadsHoldOnlyWhatTheySent) {
  api::ServerOptions options;
  options.data_dir = DataDir();
  options.limits.memory_budget_bytes = size_t{300} << 20;
  options.memory_per_client_bytes = options.limits.memory_budget_bytes;  // one client here: the whole budget
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::UploadBtfHeader header;
  header.set_name("stalled");
  header.mutable_grid()->set_preset("h1");
  header.set_width(32);
  header.set_height(32);
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
  std::vector<std::unique_ptr<grpc::ClientWriter<v1::UploadBtfMessage>>> writers;
  v1::BtfAssetInfo unused[2];
  for (int k = 0; k < 2; ++k) {
    contexts.push_back(std::make_unique<grpc::ClientContext>());
    writers.push_back(stub->UploadBtf(contexts.back().get(), &unused[k]));
    v1::UploadBtfMessage m;
    *m.mutable_header() = header;
    ASSERT_TRUE(writers.back()->Write(m));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));  // the server reads both headers
  v1::CreateBtfRequest create = TwillRequest("fits");
  create.mutable_grid()->Clear();
  create.mutable_grid()->set_preset("h1");
  create.set_resolution(32);
  v1::BtfAssetInfo info;
  grpc::Status s = Create(*stub, create, &info);
  EXPECT_TRUE(s.ok()) << s.error_message();
  for (auto& c : contexts) c->TryCancel();
  for (auto& w : writers) EXPECT_FALSE(w->Finish().ok());
}

// A client that sends its header and then nothing is cut off after the idle limit, giving back its long-call
// slot: with one slot in the server, a CreateBtf behind the stalled upload is admitted once the limit passes
// (with the upload holding its slot until its deadline, it is refused RESOURCE_EXHAUSTED throughout).
TEST_F(BtfRpcTest, AnUploadThatStopsSendingIsCancelledAndFreesItsSlot) {
  api::ServerOptions options;
  options.data_dir = DataDir();
  options.limits.max_long_running_calls = 1;
  options.limits.upload_idle_timeout = std::chrono::seconds(5);
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  grpc::ClientContext stalled;
  v1::BtfAssetInfo unused;
  auto writer = stub->UploadBtf(&stalled, &unused);
  v1::UploadBtfMessage header;
  *header.mutable_header() = UploadHeader("stalled", 16);
  ASSERT_TRUE(writer->Write(header));
  // Waits for the server to have admitted the upload (its slot in use), not a time a slow machine may overrun;
  // the idle limit (5 s) runs from the header.
  for (int i = 0; i < 3000 && server->long_calls_in_use() != 1; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const v1::CreateBtfRequest create = TwillRequest("behind");
  v1::BtfAssetInfo info;
  EXPECT_EQ(Create(*stub, create, &info).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);  // the slot is held
  grpc::Status created;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);  // against a hang, not a bound
  while (std::chrono::steady_clock::now() < until) {
    created = Create(*stub, create, &info);
    if (created.error_code() != grpc::StatusCode::RESOURCE_EXHAUSTED) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  EXPECT_TRUE(created.ok()) << created.error_message();
  EXPECT_EQ(writer->Finish().error_code(), grpc::StatusCode::CANCELLED);  // the server cancelled it
}


// An OpenEXR image of `channels` channels, every value `value`, as any client can make one.
std::string ExrOfChannels(int width, int height, int channels, float value = 0) {
  const auto path = std::filesystem::temp_directory_path() / ("loomlight-channels-" + std::to_string(::getpid()) + ".exr");
  auto out = OIIO::ImageOutput::create(path.string());
  EXPECT_TRUE(out);
  if (!out) return "";
  OIIO::ImageSpec spec(width, height, channels, OIIO::TypeDesc::HALF);
  spec.attribute("compression", "zip");
  const std::vector<float> values(size_t(width) * height * channels, value);
  EXPECT_TRUE(out->open(path.string(), spec) && out->write_image(OIIO::TypeDesc::FLOAT, values.data()) &&
              out->close());
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), {});
  std::filesystem::remove(path);
  return bytes;
}

// An uploaded image is bounded by its header before it is decoded: more than 4 channels is refused naming the
// image (64 used to be decoded, every channel a float per pixel, then all but three dropped), and an image
// whose decoding the memory budget cannot hold is refused before it is decoded (the budget was charged only
// for the image kept, after decoding). Hostile uploads are decoded on the asset loader, in their client's turn:
// another client's calls meanwhile complete.
TEST_F(BtfRpcTest, UploadedImagesAreBoundedByTheirHeaderBeforeDecoding) {
  api::ServerOptions options;
  options.data_dir = DataDir();
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  const DirectionGrid one{{{0, 1}}};
  v1::UploadBtfHeader header = UploadHeader("bounded", 16);
  header.mutable_grid()->clear_rings();
  header.mutable_grid()->add_rings()->set_count(1);
  std::vector<v1::BtfImage> images = SliceImages(*stub, one, 16);
  ASSERT_EQ(images.size(), 1u);
  v1::BtfAssetInfo out;
  images[0].set_data(ExrOfChannels(16, 16, 64));
  grpc::Status s = Upload(*stub, &header, images, &out);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_EQ(s.error_message().rfind("images[0].data: 64 channels", 0), 0u) << s.error_message();
  images[0].set_data(ExrOfChannels(16, 16, 4, 0.25f));  // RGBA is read
  s = Upload(*stub, &header, images, &out);
  EXPECT_TRUE(s.ok()) << s.error_message();

  // Hostile clients send 64-channel images over and over while another client's small calls go on.
  std::atomic<bool> stop{false};
  std::atomic<int> refused{0}, wrong{0};
  std::vector<std::thread> hostile;
  images[0].set_data(ExrOfChannels(16, 16, 64));
  header.set_name("bounded_again");
  for (int k = 0; k < 4; ++k)
    hostile.emplace_back([&] {
      auto own = testing::Connect(server->port());
      while (!stop) {
        const grpc::Status st = Upload(*own, &header, images, &out);
        (st.error_code() == grpc::StatusCode::INVALID_ARGUMENT ? refused : wrong)++;
      }
    });
  for (int i = 0; i < 20; ++i) {
    grpc::ClientContext ctx;
    v1::ListBtfsResponse list;
    EXPECT_TRUE(stub->ListBtfs(&ctx, {}, &list).ok());
    v1::EvaluateResponse f;
    grpc::ClientContext ectx;
    v1::EvaluateRequest e = BtfEvaluate("bounded", 0);
    e.add_wi(0), e.add_wi(0), e.add_wi(1), e.add_wo(0), e.add_wo(0), e.add_wo(1), e.add_uv(0.5f), e.add_uv(0.5f);
    EXPECT_TRUE(stub->Evaluate(&ectx, e, &f).ok());
  }
  while (refused < 8) std::this_thread::yield();  // the hostile uploads were running meanwhile
  stop = true;
  for (auto& t : hostile) t.join();
  EXPECT_EQ(wrong, 0);
}

// The bytes decoding takes are charged before decoding: a 128 x 128 RGBA image decodes into 128 x 128 x (4 + 3)
// floats (448 KiB) of which the call keeps 128 x 128 x 3 (192 KiB); a budget of 400 KiB refuses it
// RESOURCE_EXHAUSTED naming the image (it used to decode it and then charge the 192 KiB kept, which fit).
TEST_F(BtfRpcTest, AnImageWhoseDecodingTheBudgetCannotHoldIsRefusedBeforeDecoding) {
  api::ServerOptions options;
  options.data_dir = DataDir();
  options.limits.memory_budget_bytes = size_t{400} << 10;
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::UploadBtfHeader header = UploadHeader("budget", 128);
  header.mutable_grid()->clear_rings();
  header.mutable_grid()->add_rings()->set_count(1);
  v1::BtfImage image;
  for (int c = 0; c < 3; ++c) image.add_view(c == 2 ? 1.0f : 0.0f), image.add_light(c == 2 ? 1.0f : 0.0f);
  image.set_data(ExrOfChannels(128, 128, 4));
  v1::BtfAssetInfo out;
  const grpc::Status s = Upload(*stub, &header, {image}, &out);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_EQ(s.error_message().rfind("images[0].data: ", 0), 0u) << s.error_message();
}

// A client that trickles images just under the idle limit (one every 250 ms, the limit 1 s) is cancelled at the
// upload's whole-duration bound (2 s), and not before it; the server counts it DEADLINE_EXCEEDED.
TEST_F(BtfRpcTest, AnUploadTricklingUnderTheIdleLimitIsCancelledAtItsWholeDurationBound) {
  api::ServerOptions options;
  options.data_dir = DataDir();
  options.metrics_address = "127.0.0.1:0";
  options.limits.upload_idle_timeout = std::chrono::seconds(1);
  options.limits.upload_max_duration = std::chrono::seconds(2);
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  v1::UploadBtfHeader header = UploadHeader("trickled", 8);
  header.mutable_grid()->clear_rings();
  for (auto [theta, count] : {std::pair{0.0, 1u}, {45.0, 6u}}) {
    v1::BtfRing* ring = header.mutable_grid()->add_rings();
    ring->set_theta(theta);
    ring->set_count(count);
  }
  DirectionGrid grid;
  ASSERT_EQ(assets::GridOf(header.grid(), "grid", &grid), "");
  const std::vector<v1::BtfImage> images = SliceImages(*stub, grid, 8);  // 49 pairs: 12 s of trickling
  const auto started = std::chrono::steady_clock::now();
  grpc::ClientContext ctx;
  v1::BtfAssetInfo out;
  auto writer = stub->UploadBtf(&ctx, &out);
  v1::UploadBtfMessage m;
  *m.mutable_header() = header;
  ASSERT_TRUE(writer->Write(m));
  std::chrono::duration<double> refused_at{0};
  size_t sent = 0;
  for (; sent < images.size(); ++sent) {
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
    *m.mutable_image() = images[sent];
    if (!writer->Write(m)) {
      refused_at = std::chrono::steady_clock::now() - started;
      break;
    }
  }
  ASSERT_LT(sent, images.size()) << "the upload was never cut off";
  EXPECT_EQ(writer->Finish().error_code(), grpc::StatusCode::CANCELLED);
  // Not before the bound: the server's call began after `started`, and a write fails only once the client
  // has learnt that the server cancelled it.
  EXPECT_GE(refused_at.count(), 2.0);
  // By the bound, not the idle limit.
  const std::string text = testing::HttpGet(server->metrics_port(), "/metrics");
  bool counted = false;
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);)
    counted |= line.rfind("loomlight_calls_total{", 0) == 0 && line.find("rpc=\"UploadBtf\"") != std::string::npos &&
               line.find("DEADLINE_EXCEEDED") != std::string::npos;
  EXPECT_TRUE(counted) << text;
}

// Through a trusted proxy, two clients (their forwarded addresses): the second can neither replace nor delete the
// first's asset, and the refusal does not name the first; the first deletes it.
TEST_F(BtfRpcTest, AnotherClientCannotReplaceOrDeleteAnAsset) {
  api::ServerOptions options;
  options.data_dir = DataDir();
  ASSERT_EQ(options.access.trusted_proxies.Add("127.0.0.1"), "");
  auto server = testing::StartInProcessServer(options);
  ASSERT_TRUE(server);
  auto stub = testing::Connect(server->port());
  const auto from = [](grpc::ClientContext* ctx, const char* address) { ctx->AddMetadata("x-forwarded-for", address); };
  v1::CreateBtfRequest create = TwillRequest("owned_Twill");
  create.set_resolution(8);
  v1::BtfAssetInfo info;
  grpc::Status s;
  {
    grpc::ClientContext ctx;
    from(&ctx, "10.0.0.1");
    auto reader = stub->CreateBtf(&ctx, create);
    v1::CreateBtfProgress p;
    while (reader->Read(&p)) {
    }
    s = reader->Finish();
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  create.set_replace(true);
  create.set_name("OWNED_twill");  // the same name
  {
    grpc::ClientContext ctx;
    from(&ctx, "10.0.0.2");
    auto reader = stub->CreateBtf(&ctx, create);
    v1::CreateBtfProgress p;
    while (reader->Read(&p)) {
    }
    s = reader->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::PERMISSION_DENIED) << s.error_message();
    EXPECT_EQ(s.error_message().find("10.0.0.1"), std::string::npos) << s.error_message();
  }
  v1::DeleteBtfRequest del;
  del.set_name("owned_twill");
  v1::DeleteBtfResponse out;
  {
    grpc::ClientContext ctx;
    from(&ctx, "10.0.0.2");
    s = stub->DeleteBtf(&ctx, del, &out);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::PERMISSION_DENIED) << s.error_message();
    EXPECT_EQ(s.error_message().find("10.0.0.1"), std::string::npos) << s.error_message();
  }
  {
    grpc::ClientContext ctx;
    from(&ctx, "10.0.0.1");
    s = stub->DeleteBtf(&ctx, del, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
  }
}
}  // namespace
}  // namespace loomlight
