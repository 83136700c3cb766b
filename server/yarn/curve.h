// Yarn centre curves: where a yarn runs and how its cross-section is oriented, by arc length. The fiber
// generator (yarn.h) only asks a curve for a position and a frame, so the straight yarn of Wu and Yuksel's
// Fig. 7 and a woven layout's warp and weft (over and under, as polylines) go through the same code.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace loomlight::yarn {

// Lengths are in the unit of SPEC.md section 6's presets (Zhao et al.'s fitted values, which SPEC gives
// without a unit); nothing in this library depends on which unit that is.
struct Vec3 {
  double x = 0;
  double y = 0;
  double z = 0;

  bool operator==(const Vec3&) const = default;
};

inline Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator*(double s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
inline double Dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(Vec3 a, Vec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline double Norm(Vec3 a) { return std::sqrt(Dot(a, a)); }

// The yarn's cross-section frame at one point: `tangent` along the yarn (the paper's T_yarn), `normal`
// perpendicular to it (N_yarn, where ply 0 starts); both unit length. B_yarn = tangent x normal.
struct CurveFrame {
  Vec3 position;
  Vec3 tangent;
  Vec3 normal;
};

// A yarn centre parameterised by arc length. At(arc) is defined for arc in [0, Length()], returns a finite
// orthonormal frame there, and is a pure function (the generator calls it from several threads).
class YarnCurve {
 public:
  virtual ~YarnCurve() = default;
  virtual double Length() const = 0;
  virtual CurveFrame At(double arc) const = 0;
  // The arc length of the curve point nearest to p (for a point within the yarn: where its cross-section is).
  virtual double ClosestArc(Vec3 p) const = 0;
  // At(ClosestArc(p)), with that arc in *arc: curves that find the frame on the way override it.
  virtual CurveFrame ClosestFrame(Vec3 p, double* arc) const {
    *arc = ClosestArc(p);
    return At(*arc);
  }
  // The centre as a polyline (a straight yarn: its two ends), e.g. for a thick tube standing for the yarn.
  virtual std::vector<Vec3> CentrePolyline() const = 0;
};

// The straight yarn of Fig. 7: from the origin along +z, N_yarn = +x (so B_yarn = +y).
class StraightYarnCurve final : public YarnCurve {
 public:
  explicit StraightYarnCurve(double length) : length_(length) {}
  double Length() const override { return length_; }
  CurveFrame At(double arc) const override { return {{0, 0, arc}, {0, 0, 1}, {1, 0, 0}}; }
  double ClosestArc(Vec3 p) const override { return std::isfinite(p.z) ? std::clamp(p.z, 0.0, length_) : 0.0; }
  std::vector<Vec3> CentrePolyline() const override { return {{0, 0, 0}, {0, 0, length_}}; }

 private:
  double length_;
};

// Most vertices a polyline curve accepts (a woven repeat needs a few per crossing).
inline constexpr size_t kMaxCurveVertices = 1'000'000;

// A polyline with a normal per vertex (e.g. a warp thread going over and under wefts). Positions are linear
// along each segment; the tangent at a vertex is the bisector of its two segments (the segment's direction
// at the ends), and tangents and normals are interpolated linearly by arc length and re-orthonormalised, so
// the frame turns smoothly through a vertex instead of jumping.
class PolylineYarnCurve final : public YarnCurve {
 public:
  // Returns "" or "field: reason" ("vertices: ..." or "normals: ..."). Rules: 2 to kMaxCurveVertices
  // vertices, one normal each; every coordinate finite and within 1e6 of the origin; consecutive vertices
  // distinct; the polyline turns less than 60 degrees at a vertex; each normal unit length (within 1e-6),
  // perpendicular to its vertex tangent (|cos| < 1e-3), and within 60 degrees of the next vertex's normal.
  // The turning bounds keep the interpolated frame far from degenerate.
  static std::string Make(std::vector<Vec3> vertices, std::vector<Vec3> normals, PolylineYarnCurve* out);
  // The unit tangent Make gives vertex i of `vertices` (the bisector of its two segments, a segment's direction
  // at either end), for normals made perpendicular to it; the vertices must be distinct where they meet.
  static Vec3 VertexTangent(const std::vector<Vec3>& vertices, size_t i);

  double Length() const override { return arc_.empty() ? 0 : arc_.back(); }
  CurveFrame At(double arc) const override;
  // Polylines that advance along their chord (every segment does: a woven layout's yarns) are searched by
  // binary search on the chord and the neighbouring segments; others (loops: a knit's courses, a client's
  // curves) through a tree of boxes over runs of consecutive segments, nearer boxes first, so a query near the
  // curve tests a few runs instead of every segment.
  double ClosestArc(Vec3 p) const override;
  // The frame on the closest segment found, without At's search for the segment again (once per shading point
  // of a fiber render).
  CurveFrame ClosestFrame(Vec3 p, double* arc) const override;
  std::vector<Vec3> CentrePolyline() const override { return vertices_; }

 private:
  // The segment nearest to p and the position along it, u in [0, 1] (segment 0, u 0 for a degenerate input).
  void ClosestSegment(Vec3 p, size_t* segment, double* u) const;
  CurveFrame FrameOnSegment(size_t i, double u) const;
  double ArcOnSegment(size_t i, double u) const;

  std::vector<Vec3> vertices_;
  std::vector<Vec3> normals_;
  std::vector<Vec3> tangents_;  // per vertex
  std::vector<double> arc_;     // arc length at each vertex, arc_[0] = 0
  Vec3 chord_;                  // unit, first vertex to last
  std::vector<double> keys_;    // Dot(vertex, chord_) per vertex when increasing, else empty
  // The box tree (when keys_ is empty): boxes_[0] is the root, a box holds segments [first, first + count) and
  // either has two children (halves of its run) or is a leaf of at most kLeafSegments.
  struct SegmentBox {
    Vec3 lower, upper;
    uint32_t first = 0, count = 0;
    int32_t left = -1, right = -1;
  };
  static constexpr uint32_t kLeafSegments = 8;
  int32_t BuildBoxes(uint32_t first, uint32_t count);
  std::vector<SegmentBox> boxes_;
};

}  // namespace loomlight::yarn
