// Importance sampling of any material: draws wi given wo with a density that is known exactly, so a renderer
// (or a client, through the Sample RPC) can weigh f |cos| / pdf and combine it with light sampling (MIS).
//
// The density is a tabulated one built from the material itself: at a grid of wo nodes (24 x 24), f(wi, wo) |cos theta_i|
// (averaged over the pattern's tile for spatially varying models) at the centres of equal-area cells of wi
// (uniform in cos theta and phi); between nodes the node densities are blended bilinearly (a mixture, so its
// density is the same blend). Surfaces: each node's density is first moved to wo's elevation, its cos theta
// mapped by the piecewise linear map of [0, 1] taking the node's cos theta_o to wo's (odd over the sphere), so a
// narrow lobe that follows wo's elevation (a highlight, most of all at grazing angles) lies where wo's does
// rather than split between its neighbours'; the map's slope makes the moved density exact. (Turning nodes
// about the normal by phi_o - phi_node too, everywhere or only near the horizon, was tried: it helps one grazing
// azimuth of the satin and hurts others, as a microcylinder's highlight is a cone about the thread, not a lobe
// that turns with wo.)
// A fraction kCosineFraction (kMisCosineFraction under MIS) of a cosine density is mixed in, so every
// direction where f may be non-zero has a non-zero density even where the table's cell centres missed it.
// Piecewise constant within a cell, so pdf() is the density Draw() samples (to float rounding), whatever the table's error;
// the table only decides how much variance is left. Surface models: wo and wi about the normal (z), wi over the
// hemisphere of wo or, for materials that let light through, the whole sphere; the cloth is two-sided, so a wo
// below the surface is mirrored, sampled and mirrored back. Fiber models: about the material's own axis
// (SPEC.md section 5's cos theta_i), wo and wi over the sphere.
#pragma once

#include <array>
#include <cstddef>
#include <string>
#include <vector>

namespace loomlight::models {

struct PreparedMaterial;
class Model;

class DirectionSampler {
 public:
  using Dir = std::array<double, 3>;
  static constexpr double kCosineFraction = 0.1;
  // The floor where the draws are weighed against the environment's by MIS (the renderer): a direction the table
  // misses is found by the map's draws anyway, so less of the cosine density is spent on it (0.03 against 0.1 left
  // 3% less variance on the satin cylinders, 7% on the satin sphere, 2% on the twill, at 10 samples per pixel).
  static constexpr double kMisCosineFraction = 0.03;

  static bool Fiber(const Model& model);
  static bool Sphere(const Model& model, bool layered);  // wi over the whole sphere

  // Threads that build a table (on the caller's thread and kBuildThreads - 1 more).
  static constexpr int kBuildThreads = 2;
  static constexpr int kMaxPhiCells = 256;

  // Resolution, measured on the cylinders at 16 samples per pixel (uniform), PSNR against 512-1024 spp (satin,
  // twill, the satin sphere): 12 x 12 wo nodes with 24 x 48 wi cells 41.5, 39.0, 38.4 dB; 24 x 24 nodes with
  // 16 x 32 cells 42.7, 41.5, 40.2 dB at the same time per sample, for 1.8 times the bytes (1.3 MiB a surface
  // table) and queries (the satin's table 0.19 -> 0.26 s, a woven's 0.06 -> 0.09 s on the first call). Finer wo
  // nodes matter most (24 x 48 cells at 24 x 24 nodes: 43.0 dB on the satin, 2.8 MiB, and the soak test's mix
  // was still filling the material cache with them in its last third; 12 x 24 nodes: 42.5); 2 x 2 tile points
  // lose 5 dB on the twill. Built through the batcher's OpenCL kernels instead (~5x faster), a table was not the
  // same bytes twice (f from a launch is not bitwise the native build's, and a second PreparedMaterial of the
  // same material built its own), so the same request rendered two images: kept on the native build.
  // A surface table now holds 1.2 MB (the cells' densities and row sums; drawing a cell from the densities
  // dropped the per-row sums that doubled it).
  struct Resolution {
    int wo_z = 24, wo_phi = 24;     // wo nodes (cos theta_o, phi_o)
    int fiber_wo_z = 32;           // fibers: wo nodes in cos theta_o over the sphere (f depends on phi_i - phi_o)
    int wi_z = 16, wi_phi = 32;    // wi cells per hemisphere in cos theta; phi cells (at most kMaxPhiCells)
    int uv = 3;                    // uv points per axis averaged over the tile (spatially varying models)
  };

  // The table for `material`, from its native (float, -O3) host build of the kernel source (the same
  // source as the kernels; ~80,000 evaluations per texel point). Never fails: a material that is zero
  // everywhere samples the cosine density alone.
  explicit DirectionSampler(const PreparedMaterial& material);
  DirectionSampler(const PreparedMaterial& material, Resolution resolution);

  struct Sample {
    Dir wi{0, 0, 0};
    double pdf = 0;  // per steradian
  };
  // The density for one wo (its table nodes found once), for a draw and the densities MIS asks for.
  class Conditional {
   public:
    // u0 chooses the mixture component, (u1, u2) the direction within it (keep them one stratified pair).
    // (Choosing the component from u1 rescaled instead, as pbrt reuses a dimension, left 18% more variance on the
    // satin cylinders at 4 spp: the four nodes' densities are nearly alike, and split among them a pixel's draws
    // are four small stratified sets instead of one.)
    Sample Draw(double u0, double u1, double u2) const;
    // Draw in two steps, for a caller with several draws: Start chooses the component and its row of wi cells
    // and starts reading that row; Finish, after the other draws' Starts, completes the draw (Draw's result), so
    // the draws' cache misses overlap.
    struct Started {
      int component = -1;  // Choose's
      int row = 0;
      double fz = 0, u1 = 0, u2 = 0;
    };
    Started Start(double u0, double u1, double u2) const;
    Sample Finish(const Started& started) const;
    double Pdf(const Dir& wi) const;

   private:
    friend class DirectionSampler;
    double TablePdf(const Dir& wi_table) const;  // wi in the table frame, mirrored with wo
    double TablePdf(double z, double phi) const;  // wi in wo's frame by cos theta and azimuth in [0, 2 pi)
    // The mixture component u0 falls in: -1, the cosine density, else k of the four nodes.
    int Choose(double u0) const;
    // The monotone map of cos theta in [-1, 1], odd, linear on [0, from] and on [from, 1], taking from to `to`
    // (its two slopes computed once per wo, not per density asked for).
    struct ZMap {
      double from = 0.5, to = 0.5, slope_below = 1, slope_above = 1;
      ZMap() = default;
      ZMap(double from, double to);
      double operator()(double z, double* slope) const;  // *slope: the map's at z
    };
    // Surfaces: node k's density moved to wo's elevation (cos theta mapped from the node's to wo's), and back.
    struct Move {
      ZMap to_wo, to_node;
    };
    double cosine_fraction_ = kCosineFraction;
    bool moved_ = false;
    Move move_[4];
    // Fibers: the table frame rotated about its axis so that wo's azimuth is 0 (identity for surfaces).
    Dir ToWoFrame(const Dir& w) const;
    Dir FromWoFrame(const Dir& w) const;
    double cos_o_ = 1, sin_o_ = 0;
    const DirectionSampler* sampler_ = nullptr;
    double mirror_ = 1;
    int index_[4] = {0, 0, 0, 0};
    double weight_[4] = {1, 0, 0, 0};
  };
  Conditional At(const Dir& wo, double cosine_fraction = kCosineFraction) const;
  Sample Draw(const Dir& wo, double u0, double u1, double u2) const { return At(wo).Draw(u0, u1, u2); }
  double Pdf(const Dir& wo, const Dir& wi) const { return At(wo).Pdf(wi); }

  // The cosine weight of wi that f is multiplied by: |wi.z| for surfaces, sin(angle to the axis) for fibers.
  double Cosine(const Dir& wi) const;
  bool sphere() const { return sphere_; }  // wi over the whole sphere (else wo's hemisphere)
  size_t bytes() const;

 private:
  // The frame wi and wo are tabulated in: the surface's (z = normal) or the fiber's (z = axis).
  Dir ToTable(const Dir& w) const;
  Dir FromTable(const Dir& w) const;
  // The four wo nodes around wo (table frame, sign already mirrored) and their bilinear weights.
  void Nodes(const Dir& wo, int index[4], double weight[4]) const;
  double CosinePdf(double z) const;  // z: wi's cos theta (the table frame)
  int PhiCell(double phi) const;  // the wi cell column of phi in [0, 2 pi), the same in every node
  double NodePdf(int node, double z, int phi_cell) const;
  // The density in the table frame (wo mirrored to its side), given wo's nodes.
  double Pdf(const Dir& wo_table, const Dir& wi_table, const int index[4], const double weight[4]) const;  // < 0: the node is empty (use the cosine density)
  // A node's draw: the row from u1 (its remainder in *fz), then the cell within the row from u2.
  int DrawRow(int node, double u1, double* fz) const;
  void DrawCell(int node, int row, double fz, double u2, double* z, double* phi) const;
  const float* CellRow(int node, int row) const { return &cell_pdf_[(size_t(node) * wi_rows_ + row) * res_.wi_phi]; }
  void DrawCosine(double u1, double u2, double* z, double* phi) const;

  Resolution res_;
  bool fiber_ = false, sphere_ = false, wo_sphere_ = false;
  int wi_rows_ = 0;  // wi_z, or 2 wi_z over the sphere
  double z_min_ = 0;  // -1 over the sphere
  Dir axis_{0, 0, 1}, t_{1, 0, 0}, b_{0, 1, 0};  // fibers: the material's axis and a frame about it
  int node_count_ = 0;
  // Per node, its rows' sums (wi_rows + 1 each, unnormalised; summed in double, stored as float: half the bytes
  // and cache lines; cell_pdf_ is computed from the stored values, so it stays what Draw samples), and per row
  // the sum of its cells' densities (clamped at 0) added in order, in double: DrawCell walks the row's cells to
  // a fraction of it. One array each, so a node's sums are one address away, not behind a pointer.
  std::vector<float> row_cdf_;
  std::vector<double> row_total_;
  const float* RowCdf(int node) const { return &row_cdf_[size_t(node) * (wi_rows_ + 1)]; }
  bool NodeEmpty(int node) const { return !(RowCdf(node)[wi_rows_] > 0); }
  // Per node, each wi cell's density (rows x phi cells; -1 throughout an empty node), in float: within float rounding
  // (6e-8 relative) of what DrawCell samples from the float sums, the table's own precision.
  std::vector<float> cell_pdf_;
};

}  // namespace loomlight::models
