// The geometry of Tabulate's grids: bin centres and the directions of a cell, in one place for the server
// (which tabulates) and the client (whose plot views evaluate the same half/difference directions). Pure
// math, no protobuf: angles in the API are degrees, inside radians (SPEC.md section 1).
#pragma once

#include <array>
#include <cstdint>

namespace loomlight::tabulation {

using Direction = std::array<double, 3>;

// MERL's half/difference grid (Matusik et al. 2003, BRDFRead.cpp): 90 theta_h x 90 theta_d x 180 phi_d.
constexpr int kMerlThetaH = 90, kMerlThetaD = 90, kMerlPhiD = 180;
constexpr uint64_t kMerlCells = uint64_t{kMerlThetaH} * kMerlThetaD * kMerlPhiD;
// A MERL reader multiplies the stored R, G, B values by these, so the file stores f / scale.
constexpr double kMerlScale[3] = {1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0};

// The centre of bin k of `count` equal bins over [0, range_deg): (k + 1/2) range / count.
double BinCentreDeg(uint32_t k, uint32_t count, double range_deg);
// MERL bin centres in degrees: theta_h = ((i + 1/2) / 90)^2 90 (the bins are square-root spaced: MERL's
// index of theta_h is floor(sqrt(theta_h / 90deg) 90)), theta_d = j + 1/2, phi_d = k + 1/2.
double MerlThetaHDeg(int i);
double MerlThetaDDeg(int j);
double MerlPhiDDeg(int k);

// cos and sin of an angle, computed once per grid axis.
struct CosSin {
  double c = 1, s = 0;
  static CosSin Degrees(double deg);
};

// The direction at polar angle theta from +z and azimuth phi from +x.
Direction Spherical(CosSin theta, CosSin phi);
// The direction at signed angle t in the plane through +z at azimuth phi: (sin t cos phi, sin t sin phi,
// cos t); negative t is the other side of the normal, |t| > 90 degrees below the surface.
inline Direction InPlane(CosSin t, CosSin phi) { return Spherical(t, phi); }

// wi and wo of the Rusinkiewicz half/difference angles, MERL's convention: the half vector h is at
// (theta_h, phi_h); the difference vector d = (sin td cos pd, sin td sin pd, cos td) is wi in the frame
// where h is +z, reached from the local frame by rotating by -phi_h about z, then -theta_h about y.
// So wi = Rz(phi_h) Ry(theta_h) d, and wo = Rz(phi_h) Ry(theta_h) (-dx, -dy, dz).
void HalfDiffDirections(CosSin theta_h, CosSin phi_h, CosSin theta_d, CosSin phi_d, Direction* wi, Direction* wo);

}  // namespace loomlight::tabulation
