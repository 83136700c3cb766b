#include "server/render/folded_environment.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>

namespace loomlight::render {
namespace {

constexpr double kPi = std::numbers::pi;

// The sides of a shape the camera can see (front: the normal's side). A ray from the camera meets each surface
// point from one side, which for these shapes follows from where the camera is.
void SidesSeen(const Shape& shape, Vec3 camera, bool side[2]) {
  const Vec3 d = camera - shape.centre;
  bool front = true, back = false;
  switch (shape.kind) {
    case Shape::Kind::kSphere:
      front = Length(d) > shape.radius;
      back = !front;
      break;
    case Shape::Kind::kCylinder:
      front = d.x * d.x + d.z * d.z > shape.radius * shape.radius;
      back = !front;
      if (std::fabs(d.y) > shape.half_height) front = back = true;  // beyond an open end: the inside shows too
      break;
    case Shape::Kind::kQuad:
      front = Dot(d, Cross(shape.axis_s, shape.axis_t)) >= 0;
      back = !front;
      break;
  }
  side[0] = front;
  side[1] = back;
}

// Where a surface coordinate falls between vertices (vertex i at coordinate i): the two around it and the
// weight of the second; past the first or last vertex of an open axis, that vertex alone.
void Between(double x, int n, bool periodic, int* i0, int* i1, double* a) {
  if (!std::isfinite(x)) x = 0;
  if (periodic) {
    const double f = std::floor(x);
    *a = x - f;
    *i0 = int(std::fmod(f, double(n)));
    if (*i0 < 0) *i0 += n;
    *i1 = *i0 + 1 == n ? 0 : *i0 + 1;
  } else if (x <= 0 || n == 1) {
    *i0 = *i1 = 0, *a = 0;
  } else if (x >= n - 1) {
    *i0 = *i1 = n - 1, *a = 0;
  } else {
    *i0 = int(std::floor(x));
    *i1 = *i0 + 1;
    *a = x - *i0;
  }
}

// The map as the fold's quadrature: width x height cells and up to max_bright bright pixels.
std::vector<models::btf::EnvironmentDirection> MapCells(const Environment& environment, int width, int height,
                                                        size_t max_bright) {
  std::vector<models::btf::EnvironmentDirection> cells;
  for (const Environment::Cell& c : environment.Cells(width, height, max_bright)) {
    models::btf::EnvironmentDirection e;
    for (int i = 0; i < 3; ++i) e.direction[i] = c.direction[i], e.radiance[i] = c.radiance[i];
    e.solid_angle = c.solid_angle;
    cells.push_back(e);
  }
  return cells;
}

// The environment folded at surface points (s, t) of one object seen from one side: each point's shading frame
// as a hit there has it (mirrored on the back, as TraceSample does), its shadow rays started there. Null when
// stopped.
std::shared_ptr<const models::btf::EnvironmentFold> FoldAtPoints(
    const RenderSetup& setup, int object, int side, const FoldedEnvironment::Material& m,
    const std::vector<std::array<double, 2>>& st, const std::vector<models::btf::EnvironmentDirection>& cells,
    int threads, const std::function<bool()>& stop) {
  const double sign = side == 0 ? 1.0 : -1.0;
  std::vector<models::btf::FoldFrame> frames;
  std::vector<Vec3> origins;
  for (const auto& [s, t] : st) {
    const Hit hit = PointOnShape(setup.scene.objects[object].shape, s, t);
    const Frame f = ShadingFrame(setup, object, hit);
    const Vec3 n = sign * f.n;
    models::btf::FoldFrame frame;
    for (int c = 0; c < 3; ++c) frame.x[c] = f.x[c], frame.y[c] = f.y[c], frame.n[c] = n[c];
    frames.push_back(frame);
    origins.push_back(hit.position + (sign * kRayOffset) * hit.normal);
  }
  const Scene& scene = setup.scene;
  const models::btf::FoldVisibility visible = [&scene, &origins](size_t f, const double d[3]) {
    return !scene.Occluded(origins[f], {d[0], d[1], d[2]}, INFINITY);
  };
  return models::btf::EnvironmentFold::Make(m.tables, m.components, cells, frames, visible, threads, stop);
}

std::string Bytes(uint64_t bytes) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f MiB", double(bytes) / (1 << 20));
  return text;
}

}  // namespace

std::string FoldedEnvironment::Build(const RenderSetup& setup, const std::vector<Material>& materials, int threads,
                                     const std::function<bool()>& stop, const std::function<bool(uint64_t)>& admit,
                                     bool* refused, std::shared_ptr<const FoldedEnvironment>* out) {
  const auto start = std::chrono::steady_clock::now();
  *refused = false;
  if (!setup.environment) return "no environment to fold";
  auto folded = std::make_shared<FoldedEnvironment>();
  const size_t objects = std::min(materials.size(), setup.scene.objects.size());
  folded->objects_.resize(setup.scene.objects.size());

  // The vertex grids, halved until every object's tables fit the limit together.
  std::vector<std::array<bool, 2>> seen(objects);
  for (size_t o = 0; o < objects; ++o) SidesSeen(setup.scene.objects[o].shape, setup.camera.position(), seen[o].data());
  const auto grid_of = [](const Shape& shape, int halvings) {
    Grid g;
    const double r = shape.radius;
    switch (shape.kind) {
      case Shape::Kind::kSphere: g = {64, 32, true, -kPi * r, kPi * r, -0.5 * kPi * r, 0.5 * kPi * r}; break;
      case Shape::Kind::kCylinder: g = {64, 16, true, -kPi * r, kPi * r, -shape.half_height, shape.half_height}; break;
      case Shape::Kind::kQuad: g = {8, 8, false, -shape.half_width, shape.half_width, -shape.half_height, shape.half_height}; break;
    }
    g.ns = std::max(g.ns >> halvings, g.periodic_s ? 4 : 2);
    g.nt = std::max(g.nt >> halvings, 2);
    return g;
  };
  uint64_t total = 0;
  for (int halvings = 0; halvings <= 4; ++halvings) {
    total = 0;
    for (size_t o = 0; o < objects; ++o) {
      const Material& m = materials[o];
      if (!m.tables || setup.scene.objects[o].fibers) continue;
      Object& object = folded->objects_[o];
      object.grid = grid_of(setup.scene.objects[o].shape, halvings);
      object.textured = m.textured;
      const size_t vertices = size_t(object.grid.ns) * object.grid.nt;
      for (int side = 0; side < 2; ++side)
        if (seen[o][side]) total += models::btf::EnvironmentFold::TableBytes(*m.tables, m.components, vertices);
    }
    if (total <= kMaxTableBytes) break;
  }
  if (total > kMaxTableBytes)
    return "the fold's tables need " + Bytes(total) + " at the coarsest vertices, over the limit of " + Bytes(kMaxTableBytes);
  if (admit && !admit(total)) {
    *refused = true;
    return "the server's memory budget cannot take the fold's " + Bytes(total) + " of tables now; retry later";
  }

  // The map's quadrature: the same cells for every object.
  const std::vector<models::btf::EnvironmentDirection> cells =
      MapCells(*setup.environment, kCellsAround, kCellsDown, kMaxBrightCells);
  folded->cells_ = cells.size();

  for (size_t o = 0; o < objects; ++o) {
    const Material& m = materials[o];
    Object& object = folded->objects_[o];
    if (!m.tables || setup.scene.objects[o].fibers) continue;
    const Grid& g = object.grid;
    std::vector<std::array<double, 2>> vertices;
    for (int j = 0; j < g.nt; ++j)
      for (int i = 0; i < g.ns; ++i)
        vertices.push_back({g.s_lo + (i + 0.5) * (g.s_hi - g.s_lo) / g.ns, g.t_lo + (j + 0.5) * (g.t_hi - g.t_lo) / g.nt});
    for (int side = 0; side < 2; ++side) {
      if (!seen[o][side]) continue;
      object.side[side] = FoldAtPoints(setup, int(o), side, m, vertices, cells, threads, stop);
      if (!object.side[side]) return "stopped while folding the environment";
    }
  }
  folded->seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  *out = std::move(folded);
  return "";
}

std::vector<double> FoldedEnvironment::EstimateError(const RenderSetup& setup, const std::vector<Material>& materials,
                                                     const std::vector<ShadingPoint>& points, int threads,
                                                     const std::function<bool()>& stop) const {
  std::vector<double> error(objects_.size(), -1.0);
  if (!setup.environment) return error;
  const std::vector<models::btf::EnvironmentDirection> cells =
      MapCells(*setup.environment, kReferenceCellsAround, kReferenceCellsDown, kMaxBrightCells);
  for (size_t o = 0; o < objects_.size() && o < materials.size(); ++o) {
    if (!Covers(int(o))) continue;
    double diff = 0, total = 0;
    for (int side = 0; side < 2; ++side) {
      if (!objects_[o].side[side]) continue;
      // Evenly spaced through the pilot's points on this side (they come in image order), at most kMaxErrorPoints.
      std::vector<const ShadingPoint*> chosen;
      for (const ShadingPoint& p : points)
        if (p.object == int(o) && !p.fiber && p.back == (side == 1)) chosen.push_back(&p);
      if (chosen.empty()) continue;
      const size_t n = std::min(chosen.size(), kMaxErrorPoints);
      std::vector<std::array<double, 2>> st;
      std::vector<Query> queries;
      for (size_t k = 0; k < n; ++k) {
        const ShadingPoint& p = *chosen[k * chosen.size() / n];
        st.push_back({p.s, p.t});
        queries.push_back(QueryOf(p));
      }
      const auto reference = FoldAtPoints(setup, int(o), side, materials[o], st, cells, threads, stop);
      if (!reference) return {};
      std::vector<Rgb> folded;
      Radiance(queries, &folded);
      for (size_t k = 0; k < n; ++k) {
        const int frame[4] = {int(k), -1, -1, -1};
        const double weight[4] = {1, 0, 0, 0};
        const double wo[3] = {queries[k].wo.x, queries[k].wo.y, queries[k].wo.z};
        double exact[3];
        reference->Radiance(frame, weight, wo, objects_[o].textured, queries[k].u, queries[k].v, exact);
        const double r = exact[0] + exact[1] + exact[2];
        diff += std::fabs(folded[k].x + folded[k].y + folded[k].z - r);
        total += r;
      }
    }
    if (total > 0) error[o] = diff / total;
  }
  return error;
}

std::shared_ptr<const FoldedEnvironment> FoldedEnvironment::Keeping(const std::vector<bool>& keep) const {
  auto kept = std::make_shared<FoldedEnvironment>(*this);
  for (size_t o = 0; o < kept->objects_.size(); ++o)
    if (o >= keep.size() || !keep[o]) kept->objects_[o].side[0] = kept->objects_[o].side[1] = nullptr;
  return kept;
}

FoldedEnvironment::Query FoldedEnvironment::QueryOf(const ShadingPoint& point) const {
  return {point.object, point.back, point.s, point.t, point.wo, point.u, point.v};
}

void FoldedEnvironment::Radiance(const std::vector<Query>& queries, std::vector<Rgb>* out) const {
  out->assign(queries.size(), Rgb{});
  for (size_t q = 0; q < queries.size(); ++q) {
    const Query& query = queries[q];
    if (!Covers(query.object)) continue;
    const Object& object = objects_[query.object];
    const models::btf::EnvironmentFold* fold = object.side[query.back ? 1 : 0].get();
    if (!fold) continue;  // a side SidesSeen ruled out: no camera ray reaches it
    // The 4 vertices around (s, t), bilinear (Eq. 12's per-vertex coefficients, interpolated across the surface).
    const Grid& g = object.grid;
    int i0, i1, j0, j1;
    double a, b;
    Between((query.s - g.s_lo) / (g.s_hi - g.s_lo) * g.ns - 0.5, g.ns, g.periodic_s, &i0, &i1, &a);
    Between((query.t - g.t_lo) / (g.t_hi - g.t_lo) * g.nt - 0.5, g.nt, false, &j0, &j1, &b);
    const int frame[4] = {j0 * g.ns + i0, j0 * g.ns + i1, j1 * g.ns + i0, j1 * g.ns + i1};
    const double weight[4] = {(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b};
    const double wo[3] = {query.wo.x, query.wo.y, query.wo.z};
    double radiance[3];
    fold->Radiance(frame, weight, wo, object.textured, query.u, query.v, radiance);
    (*out)[q] = {radiance[0], radiance[1], radiance[2]};
  }
}

std::string FoldedEnvironment::Describe(int object) const {
  if (!Covers(object)) return "not folded";
  const Object& o = objects_[object];
  uint64_t bytes = 0;
  for (const auto& side : o.side)
    if (side) bytes += side->bytes();
  char text[256];
  std::snprintf(text, sizeof text,
                "environment folded into the BTF (Eq. 10) at %d x %d vertices (%s%s), the scene's occlusion traced "
                "per vertex, from %zu map cells (%d x %d and the bright pixels); %s of tables; all objects folded "
                "in %.2f s",
                o.grid.ns, o.grid.nt, o.side[0] ? "front" : "", o.side[0] && o.side[1] ? " and back" : o.side[1] ? "back" : "",
                cells_, kCellsAround, kCellsDown, Bytes(bytes).c_str(), seconds_);
  return text;
}

uint64_t FoldedEnvironment::bytes() const {
  uint64_t total = 0;
  for (const Object& o : objects_)
    for (const auto& side : o.side)
      if (side) total += side->bytes();
  return total;
}

std::string FoldCache::Key(const RenderSetup& setup, const std::vector<FoldedEnvironment::Material>& materials) {
  std::string key = setup.environment ? setup.environment->Identity() : "none";
  char text[96];
  const auto add = [&](double x) {
    std::snprintf(text, sizeof text, " %a", x);
    key += text;
  };
  const auto add_vec = [&](Vec3 v) { add(v.x), add(v.y), add(v.z); };
  add_vec(setup.camera.position());
  add(setup.texture_scale);
  add(setup.texture_rotation_deg);
  for (size_t o = 0; o < setup.scene.objects.size(); ++o) {
    const SceneObject& object = setup.scene.objects[o];
    const Shape& shape = object.shape;
    key += object.fibers ? " |fibers" : " |" + std::to_string(int(shape.kind));
    add_vec(shape.centre);
    add(shape.radius), add(shape.half_height), add(shape.half_width);
    add_vec(shape.axis_s);
    add_vec(shape.axis_t);
    add(object.thread_angle_deg);
    if (o < materials.size() && materials[o].tables) {
      std::snprintf(text, sizeof text, " %p %d %d", static_cast<const void*>(materials[o].tables.get()),
                    materials[o].components, materials[o].textured ? 1 : 0);
      key += text;
    }
  }
  return key;
}

std::shared_ptr<const FoldedEnvironment> FoldCache::Find(const std::string& key) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = map_.find(key);
  if (it == map_.end()) return nullptr;
  order_.splice(order_.begin(), order_, it->second.order);
  return it->second.fold;
}

void FoldCache::Insert(const std::string& key, std::shared_ptr<const FoldedEnvironment> fold, const RenderSetup& setup) {
  if (!fold || fold->bytes() > capacity_bytes_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  if (map_.count(key)) return;  // another call folded the same meanwhile
  while (!order_.empty() && bytes_ + fold->bytes() > capacity_bytes_) {
    const auto last = map_.find(order_.back());
    bytes_ -= last->second.fold->bytes();
    map_.erase(last);
    order_.pop_back();
  }
  order_.push_front(key);
  bytes_ += fold->bytes();
  map_[key] = {std::move(fold), setup.environment, order_.begin(), {}};
}

bool FoldCache::FindErrors(const std::string& key, const std::string& pilot, std::vector<double>* errors) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = map_.find(key);
  if (it == map_.end()) return false;
  for (const auto& [p, e] : it->second.errors)
    if (p == pilot) {
      *errors = e;
      return true;
    }
  return false;
}

void FoldCache::KeepErrors(const std::string& key, const std::string& pilot, const std::vector<double>& errors) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = map_.find(key);
  if (it == map_.end() || errors.empty()) return;
  auto& kept = it->second.errors;
  for (const auto& entry : kept)
    if (entry.first == pilot) return;
  if (kept.size() >= kMaxErrorsPerFold) kept.erase(kept.begin());
  kept.emplace_back(pilot, errors);
}

void FoldCache::Clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  map_.clear();
  order_.clear();
  bytes_ = 0;
}

uint64_t FoldCache::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bytes_;
}

}  // namespace loomlight::render
