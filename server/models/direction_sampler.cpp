#include "server/models/direction_sampler.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <numbers>
#include <thread>

#include "server/models/cdf.h"
#include "server/models/float_angles.h"
#include "server/models/material_plan.h"

namespace loomlight::models {
namespace {

constexpr double kPi = std::numbers::pi;
using Dir = DirectionSampler::Dir;

double Dot(const Dir& a, const Dir& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// The azimuth's cosine and sine in float (double sincos was 2% of a render's time; the table's cells need ~1e-7
// rad), the pair scaled back to unit length in double so wi stays a unit vector to double rounding.
Dir FromZPhi(double z, double phi) {
  float s, c;
  sincosf(float(phi), &s, &c);
  const double r = std::sqrt(std::max(0.0, 1 - z * z) / (double(c) * c + double(s) * s));
  return {r * c, r * s, z};
}

// phi in [0, 2 pi). In float: it only finds a table cell or node (to ~1e-7 rad), and library atan2 was the
// largest single cost of MIS's density lookups.
double PhiOf(const Dir& w) {
  const double phi = float_angles::Atan2(float(w[1]), float(w[0]));
  return phi < 0 ? phi + 2 * kPi : phi;
}

// How far moved densities reach toward the pole and the horizon: a wo beyond it moves them as far as this.
constexpr double kMoveZMargin = 1e-3;

// A drawn azimuth this close to a cell's edge (in cells) has its density found from its direction's atan2.
constexpr double kCellEdgeMargin = 1e-4;

}  // namespace

bool DirectionSampler::Fiber(const Model& model) { return !model.fiber_axis_param().empty(); }

bool DirectionSampler::Sphere(const Model& model, bool layered) {
  return Fiber(model) || model.transmission() || layered;
}

DirectionSampler::DirectionSampler(const PreparedMaterial& material) : DirectionSampler(material, Resolution()) {}

namespace {
// The material at its model's shape setting (AccuracyKnob::shape_setting) when that is cheaper than its own,
// else null: the table needs the lobes' shape, e.g. 8 tangent samples instead of 32-256 for the microcylinder.
std::unique_ptr<PreparedMaterial> AtShapeSetting(const PreparedMaterial& material) {
  const AccuracyKnob knob = material.model->accuracy_knob();
  if (knob.param.empty() || std::isnan(knob.shape_setting)) return nullptr;
  const auto own = material.values.find(knob.param);
  if (own == material.values.end() || own->second.empty() || own->second[0] <= knob.shape_setting) return nullptr;
  auto shape = std::make_unique<PreparedMaterial>();
  shape->model = material.model;
  shape->values = material.values;
  shape->values[knob.param] = {knob.shape_setting};
  shape->packed = material.model->Pack(shape->values);
  shape->transmission = material.transmission;
  return shape;
}
}  // namespace

DirectionSampler::DirectionSampler(const PreparedMaterial& own, Resolution resolution) : res_(resolution) {
  res_.wi_phi = std::clamp(res_.wi_phi, 1, kMaxPhiCells);
  const std::unique_ptr<PreparedMaterial> shape = AtShapeSetting(own);
  const PreparedMaterial& material = shape ? *shape : own;
  const Model& model = *material.model;
  fiber_ = Fiber(model);
  sphere_ = Sphere(model, material.transmission != nullptr);
  if (fiber_) {
    // A fiber's f depends on the azimuths only through their difference: the table is kept in wo's azimuthal
    // frame (nodes at phi_o = 0, one per wo elevation), and finer in elevation, where its narrow R cone moves
    // with wo (theta_i = -theta_o).
    res_.wo_z = res_.fiber_wo_z;
    res_.wo_phi = 1;
  }
  wo_sphere_ = fiber_;
  wi_rows_ = sphere_ ? 2 * res_.wi_z : res_.wi_z;
  z_min_ = sphere_ ? -1 : 0;
  if (fiber_) {
    const std::vector<double>& a = material.values.at(model.fiber_axis_param());
    const double length = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    if (length > 0) axis_ = {a[0] / length, a[1] / length, a[2] / length};
    // Any frame about the axis: f is tabulated in it, and only the density depends on the choice.
    const Dir helper = std::fabs(axis_[0]) < 0.9 ? Dir{1, 0, 0} : Dir{0, 1, 0};
    const double d = Dot(helper, axis_);
    t_ = {helper[0] - d * axis_[0], helper[1] - d * axis_[1], helper[2] - d * axis_[2]};
    const double tl = std::sqrt(Dot(t_, t_));
    for (double& c : t_) c /= tl;
    b_ = {axis_[1] * t_[2] - axis_[2] * t_[1], axis_[2] * t_[0] - axis_[0] * t_[2], axis_[0] * t_[1] - axis_[1] * t_[0]};
  }
  const bool with_uv = model.spatially_varying() || (material.transmission && material.transmission->model->spatially_varying());
  const int uv_points = with_uv ? res_.uv * res_.uv : 1;
  const int cells = wi_rows_ * res_.wi_phi;
  const double dz = (1 - z_min_) / wi_rows_, dphi = 2 * kPi / res_.wi_phi;
  const double wo_z_min = wo_sphere_ ? -1 : 0, wo_dz = (1 - wo_z_min) / res_.wo_z;

  // One node's queries at a time: its cells' centres x the tile's points.
  const size_t n = size_t(cells) * uv_points;
  std::vector<float> wi(3 * n), uv(with_uv ? 2 * n : 0);
  std::vector<double> cosine(cells);
  for (int r = 0; r < wi_rows_; ++r)
    for (int c = 0; c < res_.wi_phi; ++c) {
      const Dir w = FromTable(FromZPhi(z_min_ + (r + 0.5) * dz, (c + 0.5) * dphi));
      cosine[r * res_.wi_phi + c] = Cosine(w);
      for (int k = 0; k < uv_points; ++k) {
        const size_t q = size_t(r * res_.wi_phi + c) * uv_points + k;
        for (int i = 0; i < 3; ++i) wi[3 * q + i] = float(w[i]);
        if (with_uv) {
          uv[2 * q] = float((k % res_.uv + 0.5) / res_.uv);
          uv[2 * q + 1] = float((k / res_.uv + 0.5) / res_.uv);
        }
      }
    }
  node_count_ = res_.wo_z * res_.wo_phi;
  cell_pdf_.assign(size_t(node_count_) * cells, 0.0f);
  row_cdf_.assign(size_t(node_count_) * (wi_rows_ + 1), 0.0f);
  row_total_.assign(size_t(node_count_) * wi_rows_, 0.0);
  // Nodes are independent: kBuildThreads threads take every kBuildThreads-th node, each with its own wo and f.
  const auto build_nodes = [&](int first) {
    std::vector<float> wo(3 * n), column_cdf;  // a node's cells' sums per row (unnormalised), while it is built
    std::vector<double> f(3 * n);
    for (int index = first; index < node_count_; index += kBuildThreads) {
      const int i = index / res_.wo_phi, j = index % res_.wo_phi;
      const double phi_o = fiber_ ? 0.0 : (j + 0.5) * 2 * kPi / res_.wo_phi;
      const Dir o = FromTable(FromZPhi(wo_z_min + (i + 0.5) * wo_dz, phi_o));
      for (size_t q = 0; q < n; ++q)
        for (int k = 0; k < 3; ++k) wo[3 * q + k] = float(o[k]);
      EvaluateNative(EvaluationPlan(material, wi.data(), wo.data(), with_uv ? uv.data() : nullptr, n), f.data());
      float* row_cdf = &row_cdf_[size_t(index) * (wi_rows_ + 1)];
      column_cdf.assign(size_t(wi_rows_) * (res_.wi_phi + 1), 0.0f);
      double row_sum = 0;
      for (int r = 0; r < wi_rows_; ++r) {
        float* column = &column_cdf[size_t(r) * (res_.wi_phi + 1)];
        double column_sum = 0;
        for (int c = 0; c < res_.wi_phi; ++c) {
          double sum = 0;
          for (int k = 0; k < uv_points; ++k)
            for (int ch = 0; ch < 3; ++ch) {
              const double v = f[3 * (size_t(r * res_.wi_phi + c) * uv_points + k) + ch];
              if (std::isfinite(v) && v > 0) sum += v;
            }
          column_sum += sum * cosine[r * res_.wi_phi + c];
          column[c + 1] = float(column_sum);  // rounding is monotone: the sums stay non-decreasing
        }
        row_sum += column_sum;
        row_cdf[r + 1] = float(row_sum);
      }
      // Each cell's density (the row's probability from the stored row sums, then the cell's within the row,
      // over its solid angle dz dphi): one read per node where MIS asks for densities, and a row of them is
      // what DrawCell picks the cell from.
      float* cell_pdf = &cell_pdf_[size_t(index) * cells];
      const double total = row_cdf[wi_rows_];
      for (int r = 0; r < wi_rows_; ++r) {
        const float* column = &column_cdf[size_t(r) * (res_.wi_phi + 1)];
        const double row = double(row_cdf[r + 1]) - double(row_cdf[r]), row_total = column[res_.wi_phi];
        for (int c = 0; c < res_.wi_phi; ++c)
          cell_pdf[r * res_.wi_phi + c] =
              !(total > 0)                 ? -1.0f  // an empty node: TablePdf uses the cosine density instead
              : row > 0 && row_total > 0 ? float(row / total * ((double(column[c + 1]) - double(column[c])) / row_total) /
                                                 (dz * dphi))
                                         : 0.0f;
      }
      double* row_total = &row_total_[size_t(index) * wi_rows_];
      for (int r = 0; r < wi_rows_; ++r)
        for (int c = 0; c < res_.wi_phi; ++c) row_total[r] += std::max(0.0f, cell_pdf[r * res_.wi_phi + c]);
    }
  };
  std::vector<std::thread> helpers;
  for (int t = 1; t < kBuildThreads; ++t) helpers.emplace_back(build_nodes, t);
  build_nodes(0);
  for (std::thread& t : helpers) t.join();
}

size_t DirectionSampler::bytes() const {
  size_t total = sizeof(*this);
  return total + (cell_pdf_.size() + row_cdf_.size()) * sizeof(float) + row_total_.size() * sizeof(double);
}

Dir DirectionSampler::ToTable(const Dir& w) const {
  if (!fiber_) return w;
  return {Dot(w, t_), Dot(w, b_), Dot(w, axis_)};
}

Dir DirectionSampler::FromTable(const Dir& w) const {
  if (!fiber_) return w;
  Dir out;
  for (int i = 0; i < 3; ++i) out[i] = w[0] * t_[i] + w[1] * b_[i] + w[2] * axis_[i];
  return out;
}

double DirectionSampler::Cosine(const Dir& wi) const {
  if (!fiber_) return std::fabs(wi[2]);
  const double along = Dot(wi, axis_);
  return std::sqrt(std::max(0.0, 1 - along * along));
}

void DirectionSampler::Nodes(const Dir& wo, int index[4], double weight[4]) const {
  const double wo_z_min = wo_sphere_ ? -1 : 0;
  const double fz = std::clamp((wo[2] - wo_z_min) / (1 - wo_z_min) * res_.wo_z - 0.5, 0.0, res_.wo_z - 1.0);
  const int i0 = std::min(int(fz), res_.wo_z - 1), i1 = std::min(i0 + 1, res_.wo_z - 1);
  const double tz = fz - i0;
  const double fp = PhiOf(wo) / (2 * kPi) * res_.wo_phi - 0.5;  // nodes at cell centres; phi wraps around
  const double floor_p = std::floor(fp);
  const int j0 = (int(floor_p) % res_.wo_phi + res_.wo_phi) % res_.wo_phi, j1 = (j0 + 1) % res_.wo_phi;
  const double tp = fp - floor_p;
  index[0] = i0 * res_.wo_phi + j0;
  index[1] = i0 * res_.wo_phi + j1;
  index[2] = i1 * res_.wo_phi + j0;
  index[3] = i1 * res_.wo_phi + j1;
  weight[0] = (1 - tz) * (1 - tp);
  weight[1] = (1 - tz) * tp;
  weight[2] = tz * (1 - tp);
  weight[3] = tz * tp;
}

// Surfaces: cos theta / pi over the hemisphere (|cos| / 2 pi over the sphere); fibers: uniform on the sphere
// (the density of sin(angle to the axis) has no closed-form inverse).
double DirectionSampler::CosinePdf(double z) const {
  if (fiber_) return 1 / (4 * kPi);
  if (!sphere_ && z < 0) return 0;
  return std::fabs(z) / (sphere_ ? 2 * kPi : kPi);
}

void DirectionSampler::DrawCosine(double u1, double u2, double* z, double* phi) const {
  *phi = 2 * kPi * u2;
  if (fiber_) {
    *z = 1 - 2 * u1;
    return;
  }
  double sign = 1;
  if (sphere_) {  // the side from u1's top bit, keeping the remainder uniform
    sign = u1 < 0.5 ? 1 : -1;
    u1 = u1 < 0.5 ? 2 * u1 : 2 * u1 - 1;
  }
  *z = sign * std::sqrt(u1);  // z^2 uniform: density z / pi
}

int DirectionSampler::PhiCell(double phi) const {
  return std::clamp(int(phi * (res_.wi_phi / (2 * kPi))), 0, res_.wi_phi - 1);
}

double DirectionSampler::NodePdf(int node, double z, int phi_cell) const {
  if (z < z_min_) return NodeEmpty(node) ? -1 : 0;
  const int r = std::clamp(int((z - z_min_) * (wi_rows_ / (1 - z_min_))), 0, wi_rows_ - 1);
  return cell_pdf_[(size_t(node) * wi_rows_ + r) * res_.wi_phi + phi_cell];
}

int DirectionSampler::DrawRow(int node, double u1, double* fz) const {
  const float* row_cdf = RowCdf(node);
  return SearchShortCdf(row_cdf, wi_rows_, u1 * row_cdf[wi_rows_], fz);
}

void DirectionSampler::DrawCell(int node, int r, double fz, double u2, double* z, double* phi) const {
  const double dz = (1 - z_min_) / wi_rows_, dphi = 2 * kPi / res_.wi_phi;
  // The cell within the row in proportion to its density, from the row of cell_pdf_ (so the density drawn is
  // cell_pdf_ to float rounding, with no second table of sums): the cells' sums walked, in the order
  // row_total_ added them, to the first that passes the target (SearchCdf's cell for those sums).
  const float* row = CellRow(node, r);
  const double target = u2 * row_total_[size_t(node) * wi_rows_ + r];
  double below = 0;
  int c = 0;
  for (; c < res_.wi_phi - 1; ++c) {
    const double next = below + std::max(0.0f, row[c]);
    if (target < next) break;
    below = next;
  }
  const double width = std::max(0.0f, row[c]);
  const double fp = width > 0 ? std::clamp((target - below) / width, 0.0, kBelowOne) : 0.5;
  *z = z_min_ + (r + fz) * dz;
  *phi = (c + fp) * dphi;
}

DirectionSampler::Conditional::ZMap::ZMap(double from_z, double to_z)
    : from(from_z), to(to_z), slope_below(to_z / from_z), slope_above((1 - to_z) / (1 - from_z)) {}

double DirectionSampler::Conditional::ZMap::operator()(double z, double* slope) const {
  const double a = std::fabs(z);
  *slope = a <= from ? slope_below : slope_above;
  return std::copysign(a <= from ? a * *slope : to + (a - from) * *slope, z);
}

DirectionSampler::Conditional DirectionSampler::At(const Dir& wo_in, double cosine_fraction) const {
  Conditional c;
  c.sampler_ = this;
  c.cosine_fraction_ = std::clamp(cosine_fraction, 1e-3, 1.0);  // some floor stays: every direction has a density
  Dir wo = ToTable(wo_in);
  c.mirror_ = !wo_sphere_ && wo[2] < 0 ? -1 : 1;  // two-sided cloth: sample for the mirrored wo
  wo[2] *= c.mirror_;
  Nodes(wo, c.index_, c.weight_);
  // The draws' first reads, the nodes' row sums (two cache lines each), started while the caller goes on.
  for (int k = 0; k < 4; ++k) {
    const float* row_cdf = RowCdf(c.index_[k]);
    const double* row_total = &row_total_[size_t(c.index_[k]) * wi_rows_];
    __builtin_prefetch(row_cdf);
    __builtin_prefetch(row_cdf + wi_rows_);
    __builtin_prefetch(row_total);
    __builtin_prefetch(row_total + wi_rows_ - 1);
  }
  if (!fiber_) {
    c.moved_ = true;
    const double z_wo = std::clamp(wo[2], kMoveZMargin, 1 - kMoveZMargin);
    for (int k = 0; k < 4; ++k) {
      const double z_node = (c.index_[k] / res_.wo_phi + 0.5) / res_.wo_z;
      c.move_[k] = {Conditional::ZMap(z_node, z_wo), Conditional::ZMap(z_wo, z_node)};
    }
  } else {
    const double r = std::hypot(wo[0], wo[1]);
    if (r > 0) {
      c.cos_o_ = wo[0] / r;
      c.sin_o_ = wo[1] / r;
    }
  }
  return c;
}

DirectionSampler::Dir DirectionSampler::Conditional::ToWoFrame(const Dir& w) const {
  return {cos_o_ * w[0] + sin_o_ * w[1], -sin_o_ * w[0] + cos_o_ * w[1], w[2]};
}

DirectionSampler::Dir DirectionSampler::Conditional::FromWoFrame(const Dir& w) const {
  return {cos_o_ * w[0] - sin_o_ * w[1], sin_o_ * w[0] + cos_o_ * w[1], w[2]};
}

int DirectionSampler::Conditional::Choose(double u0) const {
  if (u0 < cosine_fraction_) return -1;
  // The node by its bilinear weight (u0's remainder).
  const double target = cosine_fraction_ < 1 ? (u0 - cosine_fraction_) / (1 - cosine_fraction_) : 0.0;
  double sum = 0;
  for (int k = 0; k < 4; ++k) {
    sum += weight_[k];
    if (target < sum) return k;
  }
  return 3;
}

DirectionSampler::Sample DirectionSampler::Conditional::Draw(double u0, double u1, double u2) const {
  return Finish(Start(u0, u1, u2));
}

DirectionSampler::Conditional::Started DirectionSampler::Conditional::Start(double u0, double u1, double u2) const {
  const DirectionSampler& s = *sampler_;
  Started started;
  started.component = Choose(u0);
  if (started.component >= 0 && s.NodeEmpty(index_[started.component])) started.component = -1;  // cosine instead
  started.u1 = u1;
  started.u2 = u2;
  if (started.component >= 0) {
    const int node = index_[started.component];
    started.row = s.DrawRow(node, u1, &started.fz);
    const float* row = s.CellRow(node, started.row);
    __builtin_prefetch(row);
    __builtin_prefetch(row + s.res_.wi_phi - 1);
  }
  return started;
}

DirectionSampler::Sample DirectionSampler::Conditional::Finish(const Started& started) const {
  const DirectionSampler& s = *sampler_;
  double z, phi;  // wi in wo's frame
  if (started.component >= 0) {
    double slope;
    s.DrawCell(index_[started.component], started.row, started.fz, started.u2, &z, &phi);
    if (moved_) z = move_[started.component].to_wo(z, &slope);
  } else {
    s.DrawCosine(started.u1, started.u2, &z, &phi);  // the cosine component, or an empty node's stand-in
  }
  Dir wi = FromWoFrame(FromZPhi(z, phi));
  Sample sample;
  // The density from wi itself, as Pdf finds it: the drawn phi is wi's azimuth to float rounding (~1e-6 rad),
  // which can only put it in another cell when it lies that close to a cell's edge (then its atan2 is taken).
  const double cells = phi * (s.res_.wi_phi / (2 * kPi)), from_edge = cells - std::floor(cells);
  sample.pdf = from_edge > kCellEdgeMargin && from_edge < 1 - kCellEdgeMargin ? TablePdf(z, phi) : TablePdf(wi);
  wi[2] *= mirror_;
  sample.wi = s.FromTable(wi);
  return sample;
}

double DirectionSampler::Conditional::Pdf(const Dir& wi_in) const {
  Dir wi = sampler_->ToTable(wi_in);
  wi[2] *= mirror_;
  return TablePdf(wi);
}

double DirectionSampler::Conditional::TablePdf(const Dir& wi_table) const {
  if (wi_table[2] < sampler_->z_min_) return 0;  // below a reflecting surface (no azimuth needed)
  const Dir wi = ToWoFrame(wi_table);
  return TablePdf(wi[2], PhiOf(wi));
}

double DirectionSampler::Conditional::TablePdf(double z, double phi) const {
  const DirectionSampler& s = *sampler_;
  const double cosine = s.CosinePdf(z);
  const int phi_cell = s.PhiCell(phi);
  double table = 0;
  for (int i = 0; i < 4; ++i) {
    if (weight_[i] <= 0) continue;
    double p;
    if (moved_) {  // the node's density where the move came from, divided by the move's slope
      double slope;
      const double z_node = move_[i].to_node(z, &slope);  // the inverse map; slope = 1 / its
      p = s.NodePdf(index_[i], z_node, phi_cell) * slope;
    } else {
      p = s.NodePdf(index_[i], z, phi_cell);
    }
    table += weight_[i] * (p < 0 ? cosine : p);
  }
  return cosine_fraction_ * cosine + (1 - cosine_fraction_) * table;
}

}  // namespace loomlight::models
