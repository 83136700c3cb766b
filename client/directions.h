// Query directions: angle conversion and packing into an EvaluateRequest.
#pragma once

#include <array>

#include "client/cli.h"
#include "loomlight/v1/loomlight.pb.h"

namespace loomlight::client {

using Vec3 = std::array<double, 3>;

// The unit direction at polar angle theta from the normal +z and azimuth phi from +x, both in degrees.
// A negative theta is the direction on the opposite side (phi + 180), which suits in-plane sweeps.
Vec3 direction_from_degrees(double theta_deg, double phi_deg);

// The direction of a "--wi X,Y,Z" or "--wi-deg THETA,PHI" option (any name; a name ending in "-deg" takes angles).
Vec3 direction_option(const ParsedOptions::Entry& entry);

// Appends one (wi, wo) query; the API takes float xyz triples.
void add_query(loomlight::v1::EvaluateRequest& request, const Vec3& wi, const Vec3& wo);

}  // namespace loomlight::client
