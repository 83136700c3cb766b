#include "server/models/tabulation/angles.h"

#include <cmath>
#include <numbers>

namespace loomlight::tabulation {

double BinCentreDeg(uint32_t k, uint32_t count, double range_deg) { return (k + 0.5) * range_deg / count; }

double MerlThetaHDeg(int i) {
  const double x = (i + 0.5) / kMerlThetaH;
  return x * x * 90.0;
}
double MerlThetaDDeg(int j) { return BinCentreDeg(j, kMerlThetaD, 90.0); }
double MerlPhiDDeg(int k) { return BinCentreDeg(k, kMerlPhiD, 180.0); }

CosSin CosSin::Degrees(double deg) {
  const double r = deg * (std::numbers::pi / 180.0);
  return {std::cos(r), std::sin(r)};
}

Direction Spherical(CosSin theta, CosSin phi) { return {theta.s * phi.c, theta.s * phi.s, theta.c}; }

void HalfDiffDirections(CosSin theta_h, CosSin phi_h, CosSin theta_d, CosSin phi_d, Direction* wi, Direction* wo) {
  const double dx = theta_d.s * phi_d.c, dy = theta_d.s * phi_d.s, dz = theta_d.c;
  // Ry(theta_h) then Rz(phi_h) of (x, y, z).
  auto to_local = [&](double x, double y, double z) -> Direction {
    const double rx = x * theta_h.c + z * theta_h.s, rz = -x * theta_h.s + z * theta_h.c;
    return {rx * phi_h.c - y * phi_h.s, rx * phi_h.s + y * phi_h.c, rz};
  };
  *wi = to_local(dx, dy, dz);
  *wo = to_local(-dx, -dy, dz);
}

}  // namespace loomlight::tabulation
