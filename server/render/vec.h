// Small double-precision 3-vectors for the host renderer (scene geometry, frames, lights).
#pragma once

#include <cmath>

namespace loomlight::render {

struct Vec3 {
  double x = 0, y = 0, z = 0;
  double operator[](int i) const { return i == 0 ? x : i == 1 ? y : z; }
};

inline Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator-(Vec3 a) { return {-a.x, -a.y, -a.z}; }
inline Vec3 operator*(double s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
inline Vec3 operator*(Vec3 a, Vec3 b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }  // per channel (RGB)
inline double Dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(Vec3 a, Vec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline double Length(Vec3 a) { return std::sqrt(Dot(a, a)); }
// a / |a|; the zero vector stays zero (callers reject or avoid it).
inline Vec3 Normalize(Vec3 a) {
  const double len = Length(a);
  return len > 0 ? (1.0 / len) * a : Vec3{};
}
// A unit vector perpendicular to the unit a (a's cross product with whichever of +z and +x is not along it).
inline Vec3 AnyPerpendicular(Vec3 a) {
  return Normalize(Cross(a, Length(Cross(a, {0, 0, 1})) > 1e-3 ? Vec3{0, 0, 1} : Vec3{1, 0, 0}));
}
inline bool IsFinite(Vec3 a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }

using Rgb = Vec3;  // linear RGB radiance, irradiance or weights

}  // namespace loomlight::render
