// The yarn's cross-section seen through its fiber density: the precomputed self-shadow slices of Wu and
// Yuksel Sec. 4.1 and the ambient occlusion texture and distance-based occlusion of Sec. 4.2. They are the cheap
// approximations of shadow and occlusion rays traced through the actual fibers (FiberScene), for a renderer
// that chooses between the two.
//
// Readings (ours; the paper gives the method, not its units):
// - Cross-section frame: the yarn's (N_yarn, B_yarn) plane with the ply twist taken out, i.e. rotated by the
//   ply phase 2 pi arc / alpha_yarn (yarn.cpp's PlyFrame), so ply j's centre sits at angle 2 pi j / K, R_ply / 2
//   from the origin, its ellipse e_N along the radius and e_B across it. A caller maps a point to this frame
//   by its offset from the yarn centre curve and that rotation.
// - Optical depth: the fibers are taken parallel to the yarn (the paper's 2D simplification), a ply holding
//   fibers_per_ply fibers spread by D(R) (normalised over the ellipse) of diameter fiber_width. A ray crossing
//   parallel fibers of number density n (per unit cross-section area) meets n * fiber_width of them per unit
//   of its projection onto the cross-section, whatever its angle to the yarn (the path is longer by 1 / cos and
//   the fibers' projected width shorter by cos), so the depth is fiber_width * integral of n along the 2D
//   projection, exact for parallel fibers, and the transmittance exp(-depth).
// - Slices: the light's 2D direction at angle gamma in [0, 2 pi / K) (rotational symmetry of the plies),
//   `slices` of them; in slice coordinates the light comes from +s, and each texel holds the depth from its
//   centre to the texture's edge toward the light (a running sum along s, two density samples per texel).
//   Lookups are trilinear in (s, t, gamma), gamma wrapping.
// - Ambient occlusion: the mean transmittance over 2D directions, which equals the visibility averaged over
//   the 3D sphere for parallel fibers (a uniform direction's azimuth about the yarn is uniform, and the depth
//   does not depend on the elevation). Directions are the K * slices slice angles, so each texel's value is
//   read from the slices without interpolating in gamma. Sec. 4.2 fits a cubic to the texture's radial mean
//   for its distance-based occlusion; we keep the radial mean itself as a 1D table (the same information,
//   without the fit's error).
// - Own fiber: a shading point on a fiber's axis sits inside the density that fiber contributes; Depth and
//   the occlusion textures are of the density as it is (as the paper's), Shadow subtracts the own fiber's part.
#pragma once

#include <string>
#include <vector>

#include "server/yarn/yarn.h"

namespace loomlight::yarn {

struct CrossSectionOptions {
  int resolution = 192; // texels per side of the square texture, [16, 512]
  int slices = 32;      // light angles per 2 pi / K, [1, 256]

  bool operator==(const CrossSectionOptions&) const = default;
};

std::string ValidateCrossSectionOptions(const CrossSectionOptions& o);

class YarnCrossSection {
 public:
  // Returns "" and fills *out, or "field: reason" (a YarnParams field or an option).
  static std::string Make(const YarnParams& p, const CrossSectionOptions& o, YarnCrossSection* out);

  // Half the side of the square the textures cover, centred on the yarn: every ply's ellipse fits inside.
  double extent() const { return extent_; }

  // Fibers per unit area at (x, y) of the cross-section frame, times fiber_width: the depth per unit length of
  // a ray's 2D projection there (analytic; zero outside every ply).
  double Extinction(double x, double y) const;

  // Optical depth from (x, y) toward the light whose 2D direction (in the same frame) is at angle
  // `light_angle` (radians): the slices, trilinear. Outside the texture, the nearest texel's.
  double Depth(double x, double y, double light_angle) const;
  // The same toward the 2D direction (dx, dy) (any length; zero: along the yarn).
  double DepthToward(double x, double y, double dx, double dy) const;
  // Self-shadow transmittance toward the light, exp(-depth), for a shading point on the axis of a fiber of
  // radius own_radius: the depth less own_radius * Extinction(x, y) (bilinear from the texel centres), the
  // density its own fiber contributes on the way out (measured on traced cotton1 and polyester1 yarns: without it the mean visibility comes out
  // 0.47-0.50 against the traced 0.62, with it 0.59-0.61).
  double Shadow(double x, double y, double light_angle, double own_radius) const;
  double ShadowToward(double x, double y, double dx, double dy, double own_radius) const;
  // The same integral by direct quadrature of Extinction (for tests and error reports): `steps` midpoints.
  double DepthExact(double x, double y, double light_angle, int steps = 4096) const;

  // Visibility averaged over directions, in [0, 1]: the occlusion texture, bilinear (Sec. 4.2's precomputed
  // texture).
  double Occlusion(double x, double y) const;
  // Its radial mean at distance r from the yarn centre, linear between bins (Sec. 4.2's distance-based
  // occlusion); 1 beyond the texture.
  double DistanceOcclusion(double r) const;

  const YarnParams& params() const { return params_; }

 private:
  // Bilinear in texel (s, u) of slice `slice` of a texture whose texels hold `stride` slices each.
  double Texel(const std::vector<float>& t, int stride, int slice, double s, double u) const;

  YarnParams params_;
  CrossSectionOptions options_;
  double extent_ = 0;
  double cell_ = 0;
  double ply_norm_ = 0;             // fiber_width * fibers_per_ply / (e_N e_B integral over the unit disk of D)
  std::vector<float> depth_;        // resolution x resolution x slices, [t][s][slice]
  std::vector<float> occlusion_;    // resolution x resolution, [y][x]
  std::vector<float> extinction_;   // Extinction at the texel centres, [y][x]
  std::vector<float> radial_;       // radial mean of occlusion_, bins of extent / radial_.size()
};

}  // namespace loomlight::yarn
