#include "server/yarn/curve.h"

#include <algorithm>
#include <cstdio>

#include "server/models/quote.h"

namespace loomlight::yarn {
namespace {

constexpr double kMaxCoordinate = 1e6;
const double kCos60 = 0.5;

using models::Number;

bool Finite(Vec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

Vec3 Normalized(Vec3 v) { return (1 / Norm(v)) * v; }

// Any unit vector perpendicular to unit t, chosen the same way every time (only for frames that
// interpolation made degenerate, which the validation rules out; this keeps At() finite regardless).
Vec3 AnyPerpendicular(Vec3 t) {
  const Vec3 axis = std::abs(t.x) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  return Normalized(Cross(Cross(t, axis), t));
}

}  // namespace

std::string PolylineYarnCurve::Make(std::vector<Vec3> vertices, std::vector<Vec3> normals, PolylineYarnCurve* out) {
  const size_t n = vertices.size();
  if (n < 2 || n > kMaxCurveVertices)
    return "vertices: has " + std::to_string(n) + " vertices, must have 2.." + std::to_string(kMaxCurveVertices);
  if (normals.size() != n)
    return "normals: has " + std::to_string(normals.size()) + " normals for " + std::to_string(n) + " vertices";
  for (size_t i = 0; i < n; ++i) {
    if (!Finite(vertices[i]) || std::abs(vertices[i].x) > kMaxCoordinate || std::abs(vertices[i].y) > kMaxCoordinate ||
        std::abs(vertices[i].z) > kMaxCoordinate)
      return "vertices: vertex " + std::to_string(i) + " is not finite or farther than " + Number(kMaxCoordinate) +
             " from the origin";
    if (!Finite(normals[i])) return "normals: normal " + std::to_string(i) + " is not finite";
  }
  std::vector<Vec3> directions(n - 1);
  std::vector<double> arc(n, 0.0);
  for (size_t i = 0; i + 1 < n; ++i) {
    const double length = Norm(vertices[i + 1] - vertices[i]);
    if (!(length > 0)) return "vertices: vertices " + std::to_string(i) + " and " + std::to_string(i + 1) + " coincide";
    directions[i] = (1 / length) * (vertices[i + 1] - vertices[i]);
    arc[i + 1] = arc[i] + length;
    if (i > 0 && Dot(directions[i - 1], directions[i]) <= kCos60)
      return "vertices: the polyline turns 60 degrees or more at vertex " + std::to_string(i);
  }
  std::vector<Vec3> tangents(n);
  for (size_t i = 0; i < n; ++i) tangents[i] = VertexTangent(vertices, i);
  for (size_t i = 0; i < n; ++i) {
    const double length = Norm(normals[i]);
    if (std::abs(length - 1) > 1e-6)
      return "normals: normal " + std::to_string(i) + " has length " + Number(length) + ", must be 1";
    if (std::abs(Dot(normals[i], tangents[i])) >= 1e-3)
      return "normals: normal " + std::to_string(i) + " is not perpendicular to the polyline there";
    if (i > 0 && Dot(normals[i - 1], normals[i]) <= kCos60)
      return "normals: normals " + std::to_string(i - 1) + " and " + std::to_string(i) + " differ by 60 degrees or more";
  }
  out->vertices_ = std::move(vertices);
  out->normals_ = std::move(normals);
  out->tangents_ = std::move(tangents);
  out->arc_ = std::move(arc);
  out->keys_.clear();
  const Vec3 chord = out->vertices_.back() - out->vertices_.front();
  out->chord_ = Norm(chord) > 0 ? Normalized(chord) : directions[0];
  bool advancing = true;
  for (const Vec3& d : directions) advancing = advancing && Dot(d, out->chord_) > 0;
  out->boxes_.clear();
  if (advancing)
    for (const Vec3& v : out->vertices_) out->keys_.push_back(Dot(v, out->chord_));
  else
    out->BuildBoxes(0, uint32_t(n - 1));
  return "";
}

Vec3 PolylineYarnCurve::VertexTangent(const std::vector<Vec3>& vertices, size_t i) {
  const auto direction = [&](size_t k) {
    const Vec3 d = vertices[k + 1] - vertices[k];
    return (1 / Norm(d)) * d;  // as Make's segment directions, bit for bit
  };
  if (i == 0) return direction(0);
  if (i + 1 == vertices.size()) return direction(i - 1);
  return Normalized(direction(i - 1) + direction(i));
}

int32_t PolylineYarnCurve::BuildBoxes(uint32_t first, uint32_t count) {
  const int32_t index = int32_t(boxes_.size());
  boxes_.push_back({});
  SegmentBox box;
  box.first = first;
  box.count = count;
  if (count <= kLeafSegments) {
    box.lower = box.upper = vertices_[first];
    for (uint32_t i = first + 1; i <= first + count; ++i) {
      const Vec3& v = vertices_[i];
      box.lower = {std::min(box.lower.x, v.x), std::min(box.lower.y, v.y), std::min(box.lower.z, v.z)};
      box.upper = {std::max(box.upper.x, v.x), std::max(box.upper.y, v.y), std::max(box.upper.z, v.z)};
    }
  } else {
    box.left = BuildBoxes(first, count / 2);
    box.right = BuildBoxes(first + count / 2, count - count / 2);
    const SegmentBox &l = boxes_[size_t(box.left)], &r = boxes_[size_t(box.right)];
    box.lower = {std::min(l.lower.x, r.lower.x), std::min(l.lower.y, r.lower.y), std::min(l.lower.z, r.lower.z)};
    box.upper = {std::max(l.upper.x, r.upper.x), std::max(l.upper.y, r.upper.y), std::max(l.upper.z, r.upper.z)};
  }
  boxes_[size_t(index)] = box;
  return index;
}

void PolylineYarnCurve::ClosestSegment(Vec3 p, size_t* segment, double* u) const {
  *segment = 0;
  *u = 0;
  if (vertices_.size() < 2 || !Finite(p)) return;
  double best = INFINITY;
  // The lowest-numbered of the nearest segments, whatever order they are tested in.
  const auto test = [&](size_t i) {
    const Vec3 d = vertices_[i + 1] - vertices_[i];
    const double along = std::clamp(Dot(p - vertices_[i], d) / Dot(d, d), 0.0, 1.0);
    const Vec3 off = p - (vertices_[i] + along * d);
    const double d2 = Dot(off, off);
    if (d2 < best || (d2 == best && i < *segment)) best = d2, *segment = i, *u = along;
  };
  if (!keys_.empty()) {
    // Within a yarn radius of the curve, the nearest point lies on the segment over p's chord coordinate or
    // close to it (segments turn less than 60 degrees): two on either side are searched.
    const size_t segments = vertices_.size() - 1;
    const size_t k = std::upper_bound(keys_.begin(), keys_.end(), Dot(p, chord_)) - keys_.begin();
    for (size_t i = k > 3 ? k - 3 : 0; i < std::min(segments, k + 2); ++i) test(i);
    return;
  }
  const auto box_distance2 = [&](const SegmentBox& b) {
    const double x = std::max({b.lower.x - p.x, 0.0, p.x - b.upper.x});
    const double y = std::max({b.lower.y - p.y, 0.0, p.y - b.upper.y});
    const double z = std::max({b.lower.z - p.z, 0.0, p.z - b.upper.z});
    return x * x + y * y + z * z;
  };
  // Depth first, the nearer child first; a box farther than the best segment so far cannot hold a nearer one.
  // Depth is at most log2(kMaxCurveVertices / kLeafSegments) + 1 = 18, and each level leaves one box waiting.
  int32_t stack[64];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const SegmentBox& b = boxes_[size_t(stack[--top])];
    if (box_distance2(b) > best) continue;
    if (b.left < 0) {
      for (uint32_t i = b.first; i < b.first + b.count; ++i) test(i);
      continue;
    }
    const bool left_first = box_distance2(boxes_[size_t(b.left)]) <= box_distance2(boxes_[size_t(b.right)]);
    stack[top++] = left_first ? b.right : b.left;
    stack[top++] = left_first ? b.left : b.right;
  }
}

double PolylineYarnCurve::ClosestArc(Vec3 p) const {
  size_t i;
  double u;
  ClosestSegment(p, &i, &u);
  return ArcOnSegment(i, u);
}

CurveFrame PolylineYarnCurve::ClosestFrame(Vec3 p, double* arc) const {
  *arc = 0;
  if (vertices_.size() < 2) return {};  // not made
  size_t i;
  double u;
  ClosestSegment(p, &i, &u);
  *arc = ArcOnSegment(i, u);
  return FrameOnSegment(i, u);
}

double PolylineYarnCurve::ArcOnSegment(size_t i, double u) const {
  return arc_.size() < 2 ? 0 : arc_[i] + u * (arc_[i + 1] - arc_[i]);
}

CurveFrame PolylineYarnCurve::At(double arc) const {
  const double a = std::clamp(arc, 0.0, Length());
  // The segment holding `a`: the last vertex whose arc length is <= a, short of the final vertex.
  const size_t i = std::min<size_t>(std::upper_bound(arc_.begin(), arc_.end(), a) - arc_.begin(), arc_.size() - 1) - 1;
  return FrameOnSegment(i, (a - arc_[i]) / (arc_[i + 1] - arc_[i]));
}

CurveFrame PolylineYarnCurve::FrameOnSegment(size_t i, double u) const {
  CurveFrame f;
  f.position = vertices_[i] + u * (vertices_[i + 1] - vertices_[i]);
  f.tangent = Normalized((1 - u) * tangents_[i] + u * tangents_[i + 1]);
  const Vec3 n = (1 - u) * normals_[i] + u * normals_[i + 1];
  const Vec3 perpendicular = n - Dot(n, f.tangent) * f.tangent;
  f.normal = Norm(perpendicular) > 1e-9 ? Normalized(perpendicular) : AnyPerpendicular(f.tangent);
  return f;
}

}  // namespace loomlight::yarn
