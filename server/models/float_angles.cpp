#include "server/models/float_angles.h"

#include <cmath>

namespace loomlight::models::float_angles {
namespace {
typedef float real;
#include "common/shim.h"
}  // namespace

float Atan2(float y, float x) { return ll_atan2_poly(y, x); }

float Acos(float c) {
  // As fmin(fmax(c, -1), 1), NaN to -1 included, but compares: GCC leaves fminf and fmaxf as library calls.
  c = c > -1.0f ? (c < 1.0f ? c : 1.0f) : -1.0f;
  return ll_atan2_poly(std::sqrt((1.0f - c) * (1.0f + c)), c);  // (1 - c)(1 + c): no cancellation near |c| = 1
}

}  // namespace loomlight::models::float_angles
