// Tabulate's grids of directions (in-plane slice, full 4D, MERL half/diff): their cells, the directions of each
// query and the grid angles of each cell. No protobuf and no limits: the API layer validates a request and builds
// its grid with one of the factories (server/api/tabulate.h).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "server/models/tabulation/angles.h"

namespace loomlight::tabulation {

// The kind of a grid, as the RAW header stores it.
enum class GridKind : uint32_t { kInPlane = 1, kAnisotropic = 2, kMerl = 3 };

class Grid {
 public:
  Grid() = default;  // no cells: a grid to assign to
  // In-plane: rows at incidence theta_i (light at -theta_i: the mirror direction at +theta_i), columns at
  // theta_o, bin centres over [-90, 90) (or [-180, 180) with `full_circle`), in the plane at azimuth
  // phi_plane_deg. InPlane takes the incidences; InPlaneBins uses the bin centres of [0, 90).
  static Grid InPlane(std::vector<double> theta_i_deg, uint32_t theta_o_count, bool full_circle,
                      double phi_plane_deg);
  static Grid InPlaneBins(uint32_t theta_i_count, uint32_t theta_o_count, bool full_circle, double phi_plane_deg);
  // 4D: theta_i x phi_i x theta_o x phi_o, bin centres of [0, 90) for theta and [0, 360) for phi.
  static Grid Anisotropic(uint32_t theta_i_count, uint32_t phi_i_count, uint32_t theta_o_count, uint32_t phi_o_count);
  // MERL's 90 x 90 x 180 half/diff cells, each the mean of `phi_h_samples` queries at phi_h = s 360 / samples.
  static Grid Merl(uint32_t phi_h_samples);

  GridKind kind() const { return kind_; }
  const std::vector<uint32_t>& dims() const { return dims_; }  // slowest first
  uint64_t cells() const { return cells_; }
  uint32_t queries_per_cell() const { return queries_per_cell_; }
  uint64_t queries() const { return cells_ * queries_per_cell_; }
  // Cells per EXR row: the outgoing dimensions (in-plane: theta_o; 4D: theta_o x phi_o; MERL: phi_d).
  uint64_t row_cells() const { return row_cells_; }
  // Query q = cell * queries_per_cell + sample, as float xyz (what the kernels take).
  void Directions(uint64_t query, float* wi, float* wo) const;
  // Queries [first, first + count) into wi and wo (3 floats each per query).
  void FillDirections(uint64_t first, size_t count, float* wi, float* wo) const;
  // The cell's grid angles in degrees, in the order of angle_names().
  std::vector<double> CellAngles(uint64_t cell) const;
  std::vector<std::string> angle_names() const;

 private:
  struct Axis {
    std::vector<double> deg;
    std::vector<CosSin> trig;
    // A grid angle (reported in CSV) and the angle of the direction it stands for.
    void Add(double deg, double direction_deg);
  };
  Grid(GridKind kind, std::vector<uint32_t> dims, uint32_t queries_per_cell);
  // The index of dimension `dim` of a cell.
  uint32_t Index(uint64_t cell, size_t dim) const;

  GridKind kind_ = GridKind::kInPlane;
  std::vector<uint32_t> dims_;
  std::vector<Axis> axes_;  // one per dimension, plus phi_h for MERL
  CosSin phi_plane_;
  uint64_t cells_ = 0, row_cells_ = 0;
  uint32_t queries_per_cell_ = 1;
};

}  // namespace loomlight::tabulation
