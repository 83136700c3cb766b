#include "client/directions.h"

#include <cmath>
#include <numbers>

namespace loomlight::client {
namespace {

struct SinCos {
  double sin, cos;
};

// Exact at multiples of 90 degrees, so that e.g. phi = 90 gives x = 0 rather than 6e-17.
SinCos sincos_degrees(double deg) {
  const double r = std::remainder(deg, 360.0);  // in [-180, 180]
  if (r == 0.0) return {0.0, 1.0};
  if (r == 90.0) return {1.0, 0.0};
  if (r == -90.0) return {-1.0, 0.0};
  if (r == 180.0 || r == -180.0) return {0.0, -1.0};
  const double rad = r * std::numbers::pi / 180.0;
  return {std::sin(rad), std::cos(rad)};
}

}  // namespace

Vec3 direction_from_degrees(double theta_deg, double phi_deg) {
  const SinCos theta = sincos_degrees(theta_deg), phi = sincos_degrees(phi_deg);
  // "+ 0.0" turns -0 into 0, which prints more plainly in the CSV.
  return {theta.sin * phi.cos + 0.0, theta.sin * phi.sin + 0.0, theta.cos};
}

Vec3 direction_option(const ParsedOptions::Entry& entry) {
  const std::string what = "--" + entry.name;
  if (entry.name.ends_with("-deg")) {
    const auto angles = parse_numbers(entry.value, what, 2);
    return direction_from_degrees(angles[0], angles[1]);
  }
  const auto xyz = parse_numbers(entry.value, what, 3);
  return {xyz[0], xyz[1], xyz[2]};
}

void add_query(loomlight::v1::EvaluateRequest& request, const Vec3& wi, const Vec3& wo) {
  for (double c : wi) request.add_wi(static_cast<float>(c));
  for (double c : wo) request.add_wo(static_cast<float>(c));
}

}  // namespace loomlight::client
