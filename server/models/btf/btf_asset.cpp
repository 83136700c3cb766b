#include "server/models/btf/btf_asset.h"

#include <Eigen/Dense>

#include <algorithm>
#include <chrono>
#include <cctype>
#include <cmath>
#include <thread>

namespace loomlight::models::btf {
namespace {
namespace bt_layout {
typedef double real;
#include "common/shim.h"
#include "models/btf.h"
}  // namespace bt_layout

constexpr double kDeg = M_PI / 180.0;

// The packed layout's offsets (kernels/models/btf.h) for a grid, tile and K.
struct Layout {
  size_t rings, weights, texels, means, size;
  Layout(const DirectionGrid& grid, int width, int height, int k) {
    const size_t n = grid.size(), stride = 3 * size_t(1 + k);
    rings = BT_HEADER_SIZE;
    weights = rings + BT_RING_STRIDE * grid.rings.size();
    texels = weights + n * n * k;
    means = texels + n * size_t(width) * height * stride;
    size = means + n * stride;
  }
};

}  // namespace

DirectionGrid DirectionGrid::Preset(const std::string& name, bool* found) {
  static const int counts[6] = {1, 6, 12, 18, 20, 24};
  DirectionGrid g;
  *found = name == "h1" || name == "h2";
  if (!*found) return g;
  const double step = name == "h1" ? 17 : 15;
  for (int r = 0; r < 6; ++r) g.rings.push_back({step * r, counts[r]});
  return g;
}

std::string DirectionGrid::Validate() const {
  if (rings.empty()) return "rings: at least one ring";
  size_t n = 0;
  for (size_t r = 0; r < rings.size(); ++r) {
    const std::string f = "rings[" + std::to_string(r) + "]";
    const Ring& ring = rings[r];
    if (!(ring.theta_deg >= 0 && ring.theta_deg <= 89)) return f + ".theta: must be in [0, 89] degrees";
    if (r > 0 && !(ring.theta_deg > rings[r - 1].theta_deg)) return f + ".theta: rings must ascend in theta";
    if (ring.count < 1 || ring.count > int(kMaxGridDirections)) return f + ".count: must be in [1, 256]";
    if (ring.theta_deg == 0 && ring.count != 1) return f + ".count: the ring at theta 0 is one direction";
    n += size_t(ring.count);
  }
  if (rings.size() > BT_MAX_RINGS) return "rings: at most " + std::to_string(BT_MAX_RINGS);
  if (n > kMaxGridDirections) return "rings: at most " + std::to_string(kMaxGridDirections) + " directions in all";
  return "";
}

size_t DirectionGrid::size() const {
  size_t n = 0;
  for (const Ring& r : rings) n += size_t(r.count);
  return n;
}

void DirectionGrid::Direction(size_t i, double xyz[3]) const {
  for (const Ring& r : rings) {
    if (i < size_t(r.count)) {
      const double theta = r.theta_deg * kDeg, phi = 2 * M_PI * double(i) / r.count;
      xyz[0] = std::sin(theta) * std::cos(phi);
      xyz[1] = std::sin(theta) * std::sin(phi);
      xyz[2] = std::cos(theta);
      return;
    }
    i -= size_t(r.count);
  }
  xyz[0] = xyz[1] = 0, xyz[2] = 1;
}

ViewQueries::ViewQueries(const DirectionGrid& grid, int width, int height) {
  const size_t n = grid.size(), texels = size_t(width) * height;
  wi.resize(3 * n * texels);
  wo.resize(3 * n * texels);
  uv.resize(2 * n * texels);
  for (size_t l = 0; l < n; ++l) {
    double w[3];
    grid.Direction(l, w);
    for (size_t t = 0; t < texels; ++t) {
      const size_t q = l * texels + t;
      for (int c = 0; c < 3; ++c) wi[3 * q + c] = float(w[c]);
      uv[2 * q] = float((double(t % width) + 0.5) / width);
      uv[2 * q + 1] = float((double(t / width) + 0.5) / height);
    }
  }
}

void ViewQueries::SetView(const DirectionGrid& grid, size_t view) {
  double w[3];
  grid.Direction(view, w);
  for (size_t q = 0; q < size(); ++q)
    for (int c = 0; c < 3; ++c) wo[3 * q + c] = float(w[c]);
}

int DirectionGrid::Find(const double w[3], double tolerance_deg) const {
  const double min_cos = std::cos(tolerance_deg * kDeg);
  int best = -1;
  double best_cos = min_cos;
  for (size_t i = 0; i < size(); ++i) {
    double d[3];
    Direction(i, d);
    const double c = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
    if (c >= best_cos) best = int(i), best_cos = c;
  }
  return best;
}

uint64_t BtfAsset::BytesAt(int c) const {
  return Layout(grid, width, height, c).size * sizeof(float);
}

std::string AssembleAsset(std::vector<float> tables, BtfAsset* a) {
  if (std::string e = a->grid.Validate(); !e.empty()) return "grid." + e;
  if (a->width < 1 || a->height < 1 || a->width > kMaxTexels || a->height > kMaxTexels) return "texels out of range";
  if (a->components < 0 || a->components > kMaxComponents) return "components out of range";
  const Layout layout(a->grid, a->width, a->height, a->components);
  if (tables.size() != layout.size)
    return "tables hold " + std::to_string(tables.size()) + " values, the layout " + std::to_string(layout.size);
  for (float v : tables)
    if (!std::isfinite(v)) return "tables hold a value that is not finite";
  // The header and rings are rewritten from the grid, so stored tables cannot point the kernel elsewhere.
  const size_t n = a->grid.size();
  const double header[BT_HEADER_SIZE] = {double(a->components), double(a->width), double(a->height),
                                         double(a->grid.rings.size()), double(n), double(layout.weights),
                                         double(layout.texels), double(layout.means)};
  std::copy(header, header + BT_HEADER_SIZE, tables.begin());
  size_t first = 0;
  for (size_t r = 0; r < a->grid.rings.size(); ++r) {
    float* ring = tables.data() + layout.rings + BT_RING_STRIDE * r;
    ring[0] = float(a->grid.rings[r].theta_deg * kDeg);
    ring[1] = float(a->grid.rings[r].count);
    ring[2] = float(first);
    first += size_t(a->grid.rings[r].count);
  }
  a->tables = std::make_shared<PackedTables>(std::move(tables));
  return "";
}

std::shared_ptr<BtfAsset> Compress(const BtfImages& images, const CompressionOptions& options,
                                   const std::function<void(size_t)>& progress,
                                   const std::function<bool()>& cancelled, int threads) {
  const auto start = std::chrono::steady_clock::now();
  const size_t n = images.grid.size(), d = images.image_values();
  // Mean-centred: at most n - 1 components carry anything.
  const int kmax = std::max(0, std::min({options.max_components, kMaxComponents, int(n) - 1}));

  // Per view: the mean, the first kmax eigen-images (unit length) and each light's coefficients, and every
  // eigenvalue (their tail sums are the squared errors).
  struct ViewPca {
    Eigen::VectorXd mean;
    Eigen::MatrixXd basis;    // d x kmax
    Eigen::MatrixXd weights;  // n x kmax
    Eigen::VectorXd eigenvalues;  // descending, n
  };
  std::vector<ViewPca> pca(n);
  std::atomic<size_t> next{0}, done{0};
  std::atomic<bool> stop{false};
  std::mutex progress_mutex;
  auto work = [&] {
    for (size_t v; !stop && (v = next++) < n;) {
      if (cancelled && cancelled()) {
        stop = true;
        return;
      }
      Eigen::MatrixXd x(n, d);
      for (size_t l = 0; l < n; ++l)
        x.row(Eigen::Index(l)) = Eigen::Map<const Eigen::VectorXf>(images.image(v, l), Eigen::Index(d)).cast<double>();
      ViewPca& p = pca[v];
      p.mean = x.colwise().mean().transpose();
      x.rowwise() -= p.mean.transpose();
      // The n x n Gram matrix instead of the d x d covariance: the same non-zero eigenvalues.
      const Eigen::MatrixXd gram = x * x.transpose();
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(gram);
      const Eigen::VectorXd values = eig.eigenvalues().reverse().cwiseMax(0.0);
      const Eigen::MatrixXd u = eig.eigenvectors().rowwise().reverse();
      p.eigenvalues = values;
      p.basis = Eigen::MatrixXd::Zero(Eigen::Index(d), kmax);
      p.weights = Eigen::MatrixXd::Zero(Eigen::Index(n), kmax);
      for (int k = 0; k < kmax; ++k) {
        // Below this the eigenvector is rounding noise: the component is dropped (it carries nothing).
        if (values(k) <= 1e-12 * std::max(1.0, values(0))) break;
        const double s = std::sqrt(values(k));
        p.basis.col(k) = x.transpose() * u.col(k) / s;  // unit eigen-image B_k
        p.weights.col(k) = u.col(k) * s;                // p_lk = X_l . B_k
      }
      const size_t finished = ++done;
      if (progress) {
        std::lock_guard<std::mutex> lock(progress_mutex);
        progress(finished);
      }
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < std::max(1, threads); ++t) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
  if (stop) return nullptr;

  auto asset = std::make_shared<BtfAsset>();
  asset->grid = images.grid;
  asset->width = images.width;
  asset->height = images.height;
  double peak = 0, sum_squares = 0;
  for (float value : images.f) peak = std::max(peak, double(value)), sum_squares += double(value) * value;
  const double count = double(images.f.size());
  asset->peak = peak;
  asset->rms = std::sqrt(sum_squares / count);
  // Squared error with c components: the eigenvalues beyond c, over every view.
  auto row = [&](int c) {
    double sse = 0;
    for (const ViewPca& p : pca) sse += p.eigenvalues.tail(Eigen::Index(n) - c).sum();
    ErrorRow r;
    r.components = c;
    r.rmse = std::sqrt(sse / count);
    r.psnr_db = r.rmse > 0 && peak > 0 ? 20 * std::log10(peak / r.rmse) : 999;
    return r;
  };
  int keep = kmax;
  if (options.target_psnr_db > 0)
    for (int c = 0; c <= kmax; ++c)
      if (row(c).psnr_db >= options.target_psnr_db) {
        keep = c;
        break;
      }
  asset->components = keep;
  for (int c = 0; c <= keep; ++c) {
    asset->errors.push_back(row(c));
    asset->errors.back().bytes = asset->BytesAt(c);
  }

  const Layout layout(images.grid, images.width, images.height, keep);
  std::vector<float> tables(layout.size, 0.0f);
  const size_t texels = images.texels(), stride = size_t(1 + keep);
  for (size_t v = 0; v < n; ++v) {
    const ViewPca& p = pca[v];
    for (size_t l = 0; l < n; ++l)
      for (int k = 0; k < keep; ++k) tables[layout.weights + (v * n + l) * keep + k] = float(p.weights(Eigen::Index(l), k));
    float* means = tables.data() + layout.means + v * 3 * stride;
    for (size_t t = 0; t < texels; ++t)
      for (size_t ch = 0; ch < 3; ++ch) {
        const Eigen::Index i = Eigen::Index(3 * t + ch);
        float* e = tables.data() + layout.texels + ((v * texels + t) * 3 + ch) * stride;
        e[0] = float(p.mean(i));
        means[ch * stride] += float(p.mean(i) / double(texels));
        for (int k = 0; k < keep; ++k) {
          e[1 + k] = float(p.basis(i, k));
          means[ch * stride + 1 + k] += float(p.basis(i, k) / double(texels));
        }
      }
  }
  asset->compression_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (std::string e = AssembleAsset(std::move(tables), asset.get()); !e.empty()) return nullptr;  // cannot: ours
  return asset;
}

Assets& Assets::Global() {
  static Assets* assets = new Assets;
  return *assets;
}

Assets::Assets() {
  // The built-in demonstration asset (id 0, the model's default and its preset): 15 directions, a 4 x 4 grey
  // checker whose contrast follows the light's azimuth and the view's elevation, compressed as any asset.
  BtfImages im;
  im.grid.rings = {{0, 1}, {30, 6}, {60, 8}};
  im.width = im.height = 4;
  const size_t n = im.grid.size();
  im.f.resize(n * n * im.image_values());
  for (size_t v = 0; v < n; ++v)
    for (size_t l = 0; l < n; ++l) {
      double wv[3], wl[3];
      im.grid.Direction(v, wv);
      im.grid.Direction(l, wl);
      for (size_t t = 0; t < im.texels(); ++t) {
        const double checker = ((t % 4) / 2 + (t / 4) / 2) % 2 ? 1 : -1;
        const double contrast = 0.4 * wl[0] + 0.2 * wv[2];
        for (int c = 0; c < 3; ++c) im.image(v, l)[3 * t + c] = float((0.5 + 0.1 * c) / M_PI * (1 + contrast * checker));
      }
    }
  std::shared_ptr<BtfAsset> demo = Compress(im, {.max_components = 4}, nullptr, nullptr, 1);
  demo->name = "";
  demo->source = "built-in demonstration asset: a grey checker whose contrast follows the light";
  by_id_[0] = demo;
}

uint64_t Assets::Add(const std::shared_ptr<BtfAsset>& asset) {
  std::lock_guard<std::mutex> lock(mutex_);
  asset->id = next_id_++;
  by_id_[asset->id] = asset;
  return asset->id;
}

void Assets::Remove(uint64_t id) {
  if (id == 0) return;
  std::lock_guard<std::mutex> lock(mutex_);
  by_id_.erase(id);
}

std::shared_ptr<const BtfAsset> Assets::Find(uint64_t id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = by_id_.find(id);
  return it == by_id_.end() ? nullptr : it->second;
}

std::shared_ptr<const BtfAsset> Assets::FindName(const std::string& name) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [id, asset] : by_id_)  // names differing only in case are one name
    if (id != 0 && asset->name.size() == name.size() &&
        std::equal(name.begin(), name.end(), asset->name.begin(),
                   [](char a, char b) { return std::tolower(static_cast<unsigned char>(a)) ==
                                               std::tolower(static_cast<unsigned char>(b)); }))
      return asset;
  return nullptr;
}

std::vector<std::shared_ptr<const BtfAsset>> Assets::List() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::shared_ptr<const BtfAsset>> out;
  for (const auto& [id, asset] : by_id_)
    if (id != 0) out.push_back(asset);
  return out;
}

}  // namespace loomlight::models::btf
