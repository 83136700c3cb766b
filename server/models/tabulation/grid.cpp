#include "server/models/tabulation/grid.h"

#include <utility>

namespace loomlight::tabulation {

void Grid::Axis::Add(double deg, double direction_deg) {
  this->deg.push_back(deg);
  trig.push_back(CosSin::Degrees(direction_deg));
}

Grid::Grid(GridKind kind, std::vector<uint32_t> dims, uint32_t queries_per_cell)
    : kind_(kind), dims_(std::move(dims)), queries_per_cell_(queries_per_cell) {
  cells_ = 1;
  for (uint32_t d : dims_) cells_ *= d;
  row_cells_ = kind_ == GridKind::kAnisotropic ? uint64_t{dims_[2]} * dims_[3] : dims_.back();
}

Grid Grid::InPlaneBins(uint32_t theta_i_count, uint32_t theta_o_count, bool full_circle, double phi_plane_deg) {
  std::vector<double> theta_i;
  for (uint32_t k = 0; k < theta_i_count; ++k) theta_i.push_back(BinCentreDeg(k, theta_i_count, 90.0));
  return InPlane(std::move(theta_i), theta_o_count, full_circle, phi_plane_deg);
}

Grid Grid::InPlane(std::vector<double> theta_i_deg, uint32_t theta_o_count, bool full_circle,
                   double phi_plane_deg) {
  Grid g(GridKind::kInPlane, {static_cast<uint32_t>(theta_i_deg.size()), theta_o_count}, 1);
  g.axes_.resize(2);
  for (double theta_i : theta_i_deg) g.axes_[0].Add(theta_i, -theta_i);  // the light at -theta_i
  const double range = full_circle ? 360.0 : 180.0;
  for (uint32_t k = 0; k < theta_o_count; ++k) {
    const double theta_o = -range / 2 + BinCentreDeg(k, theta_o_count, range);
    g.axes_[1].Add(theta_o, theta_o);
  }
  g.phi_plane_ = CosSin::Degrees(phi_plane_deg);
  return g;
}

Grid Grid::Anisotropic(uint32_t theta_i_count, uint32_t phi_i_count, uint32_t theta_o_count, uint32_t phi_o_count) {
  Grid g(GridKind::kAnisotropic, {theta_i_count, phi_i_count, theta_o_count, phi_o_count}, 1);
  g.axes_.resize(4);
  for (int d = 0; d < 4; ++d) {
    const double range = d % 2 == 0 ? 90.0 : 360.0;  // theta, phi, theta, phi
    for (uint32_t k = 0; k < g.dims_[d]; ++k) {
      const double angle = BinCentreDeg(k, g.dims_[d], range);
      g.axes_[d].Add(angle, angle);
    }
  }
  return g;
}

Grid Grid::Merl(uint32_t phi_h_samples) {
  Grid g(GridKind::kMerl, {kMerlThetaH, kMerlThetaD, kMerlPhiD}, phi_h_samples);
  g.axes_.resize(4);
  for (int i = 0; i < kMerlThetaH; ++i) g.axes_[0].Add(MerlThetaHDeg(i), MerlThetaHDeg(i));
  for (int j = 0; j < kMerlThetaD; ++j) g.axes_[1].Add(MerlThetaDDeg(j), MerlThetaDDeg(j));
  for (int k = 0; k < kMerlPhiD; ++k) g.axes_[2].Add(MerlPhiDDeg(k), MerlPhiDDeg(k));
  for (uint32_t s = 0; s < phi_h_samples; ++s) g.axes_[3].Add(s * 360.0 / phi_h_samples, s * 360.0 / phi_h_samples);
  return g;
}

uint32_t Grid::Index(uint64_t cell, size_t dim) const {
  for (size_t d = dims_.size() - 1; d > dim; --d) cell /= dims_[d];
  return static_cast<uint32_t>(cell % dims_[dim]);
}

void Grid::Directions(uint64_t query, float* wi, float* wo) const {
  const uint64_t cell = query / queries_per_cell_;
  Direction i, o;
  switch (kind_) {
    case GridKind::kInPlane:
      i = tabulation::InPlane(axes_[0].trig[Index(cell, 0)], phi_plane_);
      o = tabulation::InPlane(axes_[1].trig[Index(cell, 1)], phi_plane_);
      break;
    case GridKind::kAnisotropic:
      i = Spherical(axes_[0].trig[Index(cell, 0)], axes_[1].trig[Index(cell, 1)]);
      o = Spherical(axes_[2].trig[Index(cell, 2)], axes_[3].trig[Index(cell, 3)]);
      break;
    case GridKind::kMerl:
      HalfDiffDirections(axes_[0].trig[Index(cell, 0)], axes_[3].trig[query % queries_per_cell_],
                         axes_[1].trig[Index(cell, 1)], axes_[2].trig[Index(cell, 2)], &i, &o);
      break;
  }
  for (int c = 0; c < 3; ++c) {
    wi[c] = static_cast<float>(i[c]);
    wo[c] = static_cast<float>(o[c]);
  }
}

void Grid::FillDirections(uint64_t first, size_t count, float* wi, float* wo) const {
  for (size_t i = 0; i < count; ++i) Directions(first + i, wi + 3 * i, wo + 3 * i);
}

std::vector<double> Grid::CellAngles(uint64_t cell) const {
  std::vector<double> angles;
  for (size_t d = 0; d < dims_.size(); ++d) angles.push_back(axes_[d].deg[Index(cell, d)]);
  return angles;
}

std::vector<std::string> Grid::angle_names() const {
  switch (kind_) {
    case GridKind::kInPlane: return {"theta_i_deg", "theta_o_deg"};
    case GridKind::kAnisotropic: return {"theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"};
    case GridKind::kMerl: return {"theta_h_deg", "theta_d_deg", "phi_d_deg"};
  }
  return {};
}

}  // namespace loomlight::tabulation
