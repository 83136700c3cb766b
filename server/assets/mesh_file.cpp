#include "server/assets/mesh_file.h"

#include <tiny_gltf.h>
#include <tiny_obj_loader.h>

#include <algorithm>
#include <charconv>
#include <cfloat>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <istream>
#include <map>
#include <streambuf>
#include <unordered_map>
#include <utility>

#include "server/models/quote.h"

namespace loomlight::assets {
namespace {

using models::Quote;
using Vec3d = std::array<double, 3>;

constexpr char kStopped[] = "stopped";
constexpr uint64_t kStopInterval = uint64_t{1} << 16;
// glTF node hierarchies are a few levels deep; a deeper one is hostile or broken.
constexpr int kMaxNodeDepth = 64;
// tinygltf turns `extras` and `extensions` into its Value tree recursively: deep JSON nesting would overflow the
// stack there (nlohmann's parser itself is iterative). glTF's own structure is under 10 levels.
constexpr int kMaxJsonDepth = 64;
// tinyobjloader's ear clipping costs O(n^2) to O(n^3) per polygon of n vertices: the bound keeps a parse linear
// in the file's size. Exporters write triangles and quads, and n-gons of a few dozen vertices at most.
constexpr size_t kMaxObjFaceVertices = 64;
constexpr size_t kMaxMaterialNameBytes = 256;

std::string Str(uint64_t v) { return std::to_string(v); }

std::string OverLimit(const char* what, uint64_t count, uint64_t limit, const std::string& detail = "") {
  return std::string(what) + ": " + Str(count) + ", more than the limit of " + Str(limit) + detail;
}

// Asks the caller's stop function once per kStopInterval elements counted.
class StopCheck {
 public:
  explicit StopCheck(const std::function<bool()>& stop) : stop_(stop) {}
  bool Tick(uint64_t elements = 1) {
    counted_ += elements;
    if (counted_ < kStopInterval) return false;
    counted_ = 0;
    return Now();
  }
  bool Now() const { return stop_ && stop_(); }

 private:
  const std::function<bool()>& stop_;
  uint64_t counted_ = 0;
};

Vec3d Sub(const Vec3d& a, const Vec3d& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Vec3d Cross(const Vec3d& a, const Vec3d& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double Dot(const Vec3d& a, const Vec3d& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
double Length(const Vec3d& a) { return std::sqrt(Dot(a, a)); }
Vec3d ToDouble(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }
bool IsZero(const std::array<float, 3>& a) { return a[0] == 0 && a[1] == 0 && a[2] == 0; }

// `v` scaled to unit length, or zero when it has none.
std::array<float, 3> UnitOrZero(const Vec3d& v) {
  const double length = Length(v);
  if (!(length > 0) || !std::isfinite(length)) return {0, 0, 0};
  return {float(v[0] / length), float(v[1] / length), float(v[2] / length)};
}

// Any unit vector perpendicular to unit `n`.
Vec3d Perpendicular(const Vec3d& n) {
  const Vec3d axis = std::fabs(n[0]) < 0.6 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
  const Vec3d t = Cross(axis, n);
  const double length = Length(t);
  return {t[0] / length, t[1] / length, t[2] / length};
}

// Why `name` cannot be a material name (MeshInfo.materials is a proto string: UTF-8), or "".
std::string MaterialNameDefect(std::string_view name) {
  if (name.size() > kMaxMaterialNameBytes) {
    return Quote(name) + " is longer than " + Str(kMaxMaterialNameBytes) + " bytes";
  }
  for (size_t i = 0; i < name.size();) {
    uint32_t cp = 0;
    const size_t n = models::quote_detail::Utf8Sequence(name.substr(i), &cp);
    if (n == 0 || models::quote_detail::Unprintable(cp)) return Quote(name) + " is not printable UTF-8 text";
    i += n;
  }
  return "";
}

// The mesh being assembled from a file: every vertex array as long as positions. A normal or tangent of (0, 0, 0)
// is one the file did not give (computed in Finish); uv_given says which texture coordinates it gave.
struct Assembly {
  explicit Assembly(const MeshLimits& l) : limits(l) {}
  const MeshLimits& limits;
  TriangleMesh mesh;
  std::vector<uint8_t> uv_given;
  std::map<std::string, uint32_t, std::less<>> material_index;

  // Appends n vertices (zeroed), or says why not.
  std::string AddVertices(uint64_t n) {
    const uint64_t total = mesh.positions.size() + n;
    if (total > limits.max_vertices) {
      return "vertices: at least " + Str(total) + ", more than the limit of " + Str(limits.max_vertices);
    }
    mesh.positions.resize(total);
    mesh.normals.resize(total);
    mesh.uvs.resize(total);
    mesh.tangents.resize(total);
    uv_given.resize(total);
    return "";
  }

  // The index of material `name` in mesh.material_names (added at its first use), or why not.
  std::string Material(std::string_view name, uint32_t* index) {
    const auto found = material_index.find(name);
    if (found != material_index.end()) return *index = found->second, "";
    if (mesh.material_names.size() >= limits.max_materials) {
      return "materials: more than the limit of " + Str(limits.max_materials) + " (at " + Quote(name) + ")";
    }
    *index = uint32_t(mesh.material_names.size());
    mesh.material_names.emplace_back(name);
    material_index.emplace(std::string(name), *index);
    return "";
  }
};

// ---- Checks, normals, tangents and measures, for both formats ----

// Drops degenerate triangles and unused vertices; computes missing normals (area-weighted) and tangents
// (Lengyel's, from the UV derivatives); fills bounds, area and metres_per_uv.
std::string Finish(Assembly* a, uint64_t* dropped, StopCheck* stop) {
  TriangleMesh& m = a->mesh;
  const uint64_t file_triangles = m.triangles.size();
  if (file_triangles == 0) return "no triangles (a mesh needs at least one)";

  // Zero area: the cross product of the edges vanishes against their lengths (exactly, for repeated or collinear
  // float positions, whose differences and products double holds exactly).
  size_t kept = 0;
  for (size_t t = 0; t < m.triangles.size(); ++t) {
    if (stop->Tick()) return kStopped;
    const auto& tri = m.triangles[t];
    const Vec3d p0 = ToDouble(m.positions[tri[0]]);
    const Vec3d e1 = Sub(ToDouble(m.positions[tri[1]]), p0), e2 = Sub(ToDouble(m.positions[tri[2]]), p0);
    if (Length(Cross(e1, e2)) <= 1e-12 * Length(e1) * Length(e2)) continue;
    m.triangles[kept] = tri;
    m.triangle_material[kept] = m.triangle_material[t];
    ++kept;
  }
  if (kept == 0) return "every triangle is degenerate (zero area): " + Str(file_triangles) + " of them";
  if (dropped) *dropped = file_triangles - kept;
  m.triangles.resize(kept);
  m.triangles.shrink_to_fit();
  m.triangle_material.resize(kept);
  m.triangle_material.shrink_to_fit();

  // Only the materials and vertices the triangles use, in their order.
  constexpr uint32_t kUnused = ~uint32_t{0};
  std::vector<uint32_t> material_remap(m.material_names.size(), kUnused);
  std::vector<std::string> material_names;
  for (uint32_t& material : m.triangle_material) {
    if (material_remap[material] == kUnused) {
      material_remap[material] = uint32_t(material_names.size());
      material_names.push_back(std::move(m.material_names[material]));
    }
    material = material_remap[material];
  }
  m.material_names.swap(material_names);
  std::vector<uint32_t> remap(m.positions.size(), kUnused);
  uint32_t used = 0;
  for (auto& tri : m.triangles) {
    for (uint32_t& v : tri) {
      if (remap[v] == kUnused) remap[v] = used++;
      v = remap[v];
    }
  }
  if (stop->Now()) return kStopped;
  const auto compact = [&](auto& values) {
    std::remove_reference_t<decltype(values)> out(used);
    for (size_t i = 0; i < remap.size(); ++i) {
      if (remap[i] != kUnused) out[remap[i]] = values[i];
    }
    values.swap(out);
  };
  compact(m.positions);
  compact(m.normals);
  compact(m.uvs);
  compact(m.tangents);
  compact(a->uv_given);
  remap = {};

  // Face sums: twice the area times the unit normal, per vertex; and a face normal for each vertex, in case the
  // sum cancels (a vertex shared by faces facing opposite ways).
  const size_t vertices = m.positions.size();
  std::vector<Vec3d> area_normal(vertices, Vec3d{0, 0, 0}), face_normal(vertices, Vec3d{0, 0, 0});
  double area2 = 0, uv_area2 = 0;
  for (const auto& tri : m.triangles) {
    if (stop->Tick()) return kStopped;
    const Vec3d p0 = ToDouble(m.positions[tri[0]]);
    const Vec3d n = Cross(Sub(ToDouble(m.positions[tri[1]]), p0), Sub(ToDouble(m.positions[tri[2]]), p0));
    area2 += Length(n);
    for (uint32_t v : tri) {
      for (int c = 0; c < 3; ++c) area_normal[v][c] += n[c];
      if (face_normal[v] == Vec3d{0, 0, 0}) face_normal[v] = n;
    }
  }
  m.file_normals = true;
  for (size_t v = 0; v < vertices; ++v) {
    if (!IsZero(m.normals[v])) continue;
    m.file_normals = false;
    m.normals[v] = UnitOrZero(area_normal[v]);
    if (IsZero(m.normals[v])) m.normals[v] = UnitOrZero(face_normal[v]);
  }
  area_normal = {};
  face_normal = {};

  m.file_uvs = std::all_of(a->uv_given.begin(), a->uv_given.end(), [](uint8_t g) { return g != 0; });
  m.file_tangents = false;
  if (!m.file_uvs) {
    m.uvs = {};
    m.tangents = {};
  } else {
    // Lengyel's tangents: per triangle, dP/du and dP/dv from the UV differences, summed per vertex; a triangle
    // whose UVs span no area has no derivatives and adds nothing.
    std::vector<Vec3d> sdir(vertices, Vec3d{0, 0, 0}), tdir(vertices, Vec3d{0, 0, 0});
    for (const auto& tri : m.triangles) {
      if (stop->Tick()) return kStopped;
      const Vec3d p0 = ToDouble(m.positions[tri[0]]);
      const Vec3d e1 = Sub(ToDouble(m.positions[tri[1]]), p0), e2 = Sub(ToDouble(m.positions[tri[2]]), p0);
      const auto& uv0 = m.uvs[tri[0]];
      const double du1 = double(m.uvs[tri[1]][0]) - uv0[0], dv1 = double(m.uvs[tri[1]][1]) - uv0[1];
      const double du2 = double(m.uvs[tri[2]][0]) - uv0[0], dv2 = double(m.uvs[tri[2]][1]) - uv0[1];
      const double r = du1 * dv2 - du2 * dv1;
      uv_area2 += std::fabs(r);
      if (std::fabs(r) <= 1e-12 * (std::fabs(du1) + std::fabs(du2)) * (std::fabs(dv1) + std::fabs(dv2))) continue;
      Vec3d s, t;
      for (int c = 0; c < 3; ++c) {
        s[c] = (e1[c] * dv2 - e2[c] * dv1) / r;
        t[c] = (e2[c] * du1 - e1[c] * du2) / r;
      }
      for (uint32_t v : tri) {
        for (int c = 0; c < 3; ++c) sdir[v][c] += s[c], tdir[v][c] += t[c];
      }
    }
    m.file_tangents = true;
    for (size_t v = 0; v < vertices; ++v) {
      const Vec3d n = ToDouble(m.normals[v]);
      auto& out = m.tangents[v];
      // The file's tangent (unit or zero), else dP/du, made perpendicular to the normal: unless it lies within
      // a thousandth of a radian of the normal, where what is left of it is mostly rounding.
      const auto perpendicular = [&](const Vec3d& t) {
        return Sub(t, {n[0] * Dot(n, t), n[1] * Dot(n, t), n[2] * Dot(n, t)});
      };
      Vec3d t = perpendicular({out[0], out[1], out[2]});
      double w = out[3] < 0 ? -1 : 1;
      if (!(Length(t) > 1e-3)) {
        m.file_tangents = false;
        const Vec3d& s = sdir[v];
        t = perpendicular(s);
        w = Dot(Cross(n, s), tdir[v]) < 0 ? -1 : 1;
        if (!(Length(t) > 1e-3 * Length(s))) t = Perpendicular(n), w = 1;
      }
      const auto unit = UnitOrZero(perpendicular(t));  // again: the normal itself is rounded to float
      out = {unit[0], unit[1], unit[2], float(w)};
    }
  }
  a->uv_given = {};

  m.bounds_min = {DBL_MAX, DBL_MAX, DBL_MAX};
  m.bounds_max = {-DBL_MAX, -DBL_MAX, -DBL_MAX};
  for (const auto& p : m.positions) {
    for (int c = 0; c < 3; ++c) {
      m.bounds_min[c] = std::min(m.bounds_min[c], double(p[c]));
      m.bounds_max[c] = std::max(m.bounds_max[c], double(p[c]));
    }
  }
  m.surface_area = area2 / 2;
  m.metres_per_uv = uv_area2 > 0 ? std::sqrt(area2 / uv_area2) : 0;
  return "";
}

// ---- glTF ----

// tinygltf's file callbacks: every path is refused, and the first one asked for is kept for the error message
// (tinygltf asks through ExpandFilePath before anything else).
struct RefusedFiles {
  std::string first;
  bool asked = false;
};

std::string RefuseExpandFilePath(const std::string& path, void* user) {
  auto* refused = static_cast<RefusedFiles*>(user);
  if (!refused->asked) refused->first = path, refused->asked = true;
  return "";
}
bool RefuseFileExists(const std::string&, void*) { return false; }
bool RefuseReadWholeFile(std::vector<unsigned char>*, std::string* err, const std::string&, void*) {
  if (err) *err = "external files are refused";
  return false;
}
bool RefuseWriteWholeFile(std::string* err, const std::string&, const std::vector<unsigned char>&, void*) {
  if (err) *err = "writing files is refused";
  return false;
}
// Textures are not used: images stay undecoded.
bool IgnoreImage(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int,
                 void*) {
  return true;
}

uint32_t ReadU32LE(const char* p) {
  const auto* b = reinterpret_cast<const uint8_t*>(p);
  return uint32_t(b[0]) | uint32_t(b[1]) << 8 | uint32_t(b[2]) << 16 | uint32_t(b[3]) << 24;
}

// The GLB container checked (tinygltf 2.7 lets a BIN chunk's length run 8 bytes past the file); *json and
// *length: its JSON chunk and its declared length.
std::string CheckGlb(std::string_view bytes, std::string_view* json, uint32_t* length) {
  if (bytes.size() < 20 || bytes.substr(0, 4) != "glTF") return "not a GLB file (no glTF header)";
  if (ReadU32LE(&bytes[4]) != 2) return "GLB version " + Str(ReadU32LE(&bytes[4])) + ": only glTF 2 is read";
  *length = ReadU32LE(&bytes[8]);
  if (*length > bytes.size()) return "GLB truncated: " + Str(bytes.size()) + " of " + Str(*length) + " bytes";
  const uint64_t json_length = ReadU32LE(&bytes[12]);
  if (ReadU32LE(&bytes[16]) != 0x4E4F534A) return "GLB: the first chunk is not JSON";
  if (20 + json_length > *length) return "GLB: the JSON chunk runs past the file";
  const uint64_t bin_start = 20 + json_length;
  if (bin_start < *length) {
    if (bin_start + 8 > *length) return "GLB: a chunk header runs past the file";
    if (bin_start + 8 + ReadU32LE(&bytes[bin_start]) > *length) return "GLB: the BIN chunk runs past the file";
  }
  *json = bytes.substr(20, json_length);
  return "";
}

std::string CheckJsonDepth(std::string_view json) {
  int depth = 0;
  bool in_string = false;
  for (size_t i = 0; i < json.size(); ++i) {
    const char c = json[i];
    if (in_string) {
      if (c == '\\') ++i;
      else if (c == '"') in_string = false;
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > kMaxJsonDepth) return "glTF JSON nested more than " + Str(kMaxJsonDepth) + " levels deep";
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return "";
}

// y = linear x + translation, rows of [linear | translation].
struct Affine {
  double m[3][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}};

  Affine operator*(const Affine& b) const {
    Affine r;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 4; ++j) {
        r.m[i][j] = (j == 3 ? m[i][3] : 0);
        for (int k = 0; k < 3; ++k) r.m[i][j] += m[i][k] * b.m[k][j];
      }
    }
    return r;
  }
  Vec3d Point(const Vec3d& p) const {
    Vec3d r;
    for (int i = 0; i < 3; ++i) r[i] = m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3];
    return r;
  }
  Vec3d Vector(const Vec3d& v) const {
    Vec3d r;
    for (int i = 0; i < 3; ++i) r[i] = m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2];
    return r;
  }
  double Determinant() const {
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  }
  // Normals transform by the inverse transpose: the cofactor matrix (det times it) with det's sign taken out,
  // which needs no division and stays defined for a singular transform.
  Affine NormalMatrix() const {
    Affine r;
    const double sign = Determinant() < 0 ? -1 : 1;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
        r.m[i][j] = sign * (m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]);
      }
      r.m[i][3] = 0;
    }
    return r;
  }
  bool Finite() const {
    for (const auto& row : m) {
      for (double v : row) {
        if (!std::isfinite(v)) return false;
      }
    }
    return true;
  }
};

std::string NodeName(size_t i) { return "nodes[" + Str(i) + "]"; }

std::string NodeTransform(const tinygltf::Node& node, size_t index, Affine* out) {
  const std::string where = NodeName(index);
  const auto finite = [](const std::vector<double>& v) {
    return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
  };
  *out = Affine{};
  if (!node.matrix.empty()) {
    const auto& a = node.matrix;  // column-major
    if (a.size() != 16) return where + ".matrix: " + Str(a.size()) + " numbers, not 16";
    if (!finite(a)) return where + ".matrix is not finite";
    if (a[3] != 0 || a[7] != 0 || a[11] != 0 || a[15] != 1) return where + ".matrix is not affine";
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) out->m[r][c] = a[c * 4 + r];
    }
    return "";
  }
  const auto check = [&](const std::vector<double>& v, size_t n, const char* name) -> std::string {
    if (!v.empty() && v.size() != n) return where + "." + name + ": " + Str(v.size()) + " numbers, not " + Str(n);
    if (!finite(v)) return where + "." + name + " is not finite";
    return "";
  };
  std::string error = check(node.translation, 3, "translation");
  if (error.empty()) error = check(node.rotation, 4, "rotation");
  if (error.empty()) error = check(node.scale, 3, "scale");
  if (!error.empty()) return error;
  double x = 0, y = 0, z = 0, w = 1;
  if (!node.rotation.empty()) {
    const auto& q = node.rotation;
    const double length = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(length > 0) || !std::isfinite(length)) return where + ".rotation is not a rotation quaternion";
    x = q[0] / length, y = q[1] / length, z = q[2] / length, w = q[3] / length;
  }
  const double r[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)},
                          {2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)},
                          {2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)}};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out->m[i][j] = r[i][j] * (node.scale.empty() ? 1.0 : node.scale[j]);
    out->m[i][3] = node.translation.empty() ? 0.0 : node.translation[i];
  }
  return "";
}

// An accessor's elements, checked against its buffer view and buffer.
struct AccessorView {
  const uint8_t* data = nullptr;
  uint64_t count = 0;
  uint64_t stride = 0;
  int component_type = 0;
  bool normalized = false;

  double Component(uint64_t i, int c) const {
    const uint8_t* p = data + i * stride;
    switch (component_type) {
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return p[c] / (normalized ? 255.0 : 1.0);
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
        uint16_t v;
        std::memcpy(&v, p + 2 * c, 2);
        return v / (normalized ? 65535.0 : 1.0);
      }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
        uint32_t v;
        std::memcpy(&v, p + 4 * c, 4);
        return v;
      }
      default: {
        float v;
        std::memcpy(&v, p + 4 * c, 4);
        return v;
      }
    }
  }
  uint32_t Index(uint64_t i) const { return uint32_t(Component(i, 0)); }
};

uint64_t ComponentBytes(int component_type) {
  switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return 1;
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      return 2;
    default:
      return 4;
  }
}

const char* TypeName(int type) {
  switch (type) {
    case TINYGLTF_TYPE_SCALAR:
      return "SCALAR";
    case TINYGLTF_TYPE_VEC2:
      return "VEC2";
    case TINYGLTF_TYPE_VEC3:
      return "VEC3";
    case TINYGLTF_TYPE_VEC4:
      return "VEC4";
    default:
      return "a matrix";
  }
}

// Which component types an attribute takes (glTF 2.0 section 3.7.2.1), and whether they must be normalized.
struct AttributeRule {
  int type;
  std::vector<int> component_types;
  bool normalized_integers;
};

std::string ViewAccessor(const tinygltf::Model& model, int index, const std::string& what, const AttributeRule& rule,
                         AccessorView* out) {
  if (index < 0 || size_t(index) >= model.accessors.size()) {
    return what + ": accessor " + std::to_string(index) + " does not exist";
  }
  const tinygltf::Accessor& a = model.accessors[index];
  const std::string where = what + " (accessors[" + Str(index) + "])";
  if (a.sparse.isSparse) return where + ": sparse accessors are not supported";
  if (a.type != rule.type) return where + ": " + TypeName(a.type) + ", not " + TypeName(rule.type);
  if (std::find(rule.component_types.begin(), rule.component_types.end(), a.componentType) ==
      rule.component_types.end()) {
    return where + ": component type " + std::to_string(a.componentType) + " is not allowed here";
  }
  const bool integer = a.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT;
  if (integer && a.normalized != rule.normalized_integers) {
    return where + (rule.normalized_integers ? ": integers must be normalized" : ": indices cannot be normalized");
  }
  if (a.bufferView < 0 || size_t(a.bufferView) >= model.bufferViews.size()) {
    return where + ": no buffer view (bufferView " + std::to_string(a.bufferView) + ")";
  }
  const tinygltf::BufferView& view = model.bufferViews[a.bufferView];
  if (view.buffer < 0 || size_t(view.buffer) >= model.buffers.size()) {
    return where + ": bufferViews[" + Str(a.bufferView) + "].buffer " + std::to_string(view.buffer) +
           " does not exist";
  }
  const uint64_t buffer_bytes = model.buffers[view.buffer].data.size();
  if (view.byteOffset > buffer_bytes || view.byteLength > buffer_bytes - view.byteOffset) {
    return where + ": bufferViews[" + Str(a.bufferView) + "] runs past its buffer";
  }
  const uint64_t element_bytes = ComponentBytes(a.componentType) * uint64_t(rule.type == TINYGLTF_TYPE_SCALAR ? 1
                                                                                                            : rule.type);
  const uint64_t stride = view.byteStride ? view.byteStride : element_bytes;
  if (stride < element_bytes || stride % ComponentBytes(a.componentType) != 0) {
    return where + ": byteStride " + Str(view.byteStride) + " does not fit its elements";
  }
  // byteOffset + (count - 1) * stride + element_bytes <= byteLength, without overflow.
  if (a.count > 0) {
    const uint64_t room = view.byteLength;
    if (a.byteOffset > room || element_bytes > room - a.byteOffset ||
        (a.count - 1) > (room - a.byteOffset - element_bytes) / stride) {
      return where + ": " + Str(a.count) + " elements run past bufferViews[" + Str(a.bufferView) + "]";
    }
  }
  out->data = model.buffers[view.buffer].data.data() + view.byteOffset + a.byteOffset;
  out->count = a.count;
  out->stride = stride;
  out->component_type = a.componentType;
  out->normalized = a.normalized;
  return "";
}

const AttributeRule kPositionRule{TINYGLTF_TYPE_VEC3, {TINYGLTF_COMPONENT_TYPE_FLOAT}, false};
const AttributeRule kNormalRule{TINYGLTF_TYPE_VEC3, {TINYGLTF_COMPONENT_TYPE_FLOAT}, false};
const AttributeRule kTangentRule{TINYGLTF_TYPE_VEC4, {TINYGLTF_COMPONENT_TYPE_FLOAT}, false};
const AttributeRule kTexcoordRule{TINYGLTF_TYPE_VEC2,
                                  {TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE,
                                   TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT},
                                  true};
const AttributeRule kIndexRule{TINYGLTF_TYPE_SCALAR,
                               {TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE, TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT,
                                TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT},
                               false};

bool IsTriangleMode(int mode) {
  return mode == TINYGLTF_MODE_TRIANGLES || mode == TINYGLTF_MODE_TRIANGLE_STRIP ||
         mode == TINYGLTF_MODE_TRIANGLE_FAN;
}

uint64_t TrianglesOf(int mode, uint64_t elements) {
  if (mode == TINYGLTF_MODE_TRIANGLES) return elements / 3;
  if (IsTriangleMode(mode)) return elements >= 3 ? elements - 2 : 0;
  return 0;
}

uint64_t SaturatingAdd(uint64_t a, uint64_t b) { return a > UINT64_MAX - b ? UINT64_MAX : a + b; }

// A primitive's vertex indices mapped to the assembled mesh's, for the vertices its triangles use: an array when
// the accessor is not much longer than the index list, else a hash map, so the cost follows the indices either way.
class VertexRemap {
 public:
  VertexRemap(uint64_t vertices, uint64_t elements) {
    if (vertices <= 4 * elements + 1024) dense_.assign(vertices, kNone);
  }
  // The new index of old vertex v, or kNone.
  uint32_t Find(uint32_t v) const {
    if (!dense_.empty()) return dense_[v];
    const auto found = sparse_.find(v);
    return found == sparse_.end() ? kNone : found->second;
  }
  void Set(uint32_t v, uint32_t index) {
    if (!dense_.empty()) dense_[v] = index;
    else sparse_[v] = index;
  }
  static constexpr uint32_t kNone = ~uint32_t{0};

 private:
  std::vector<uint32_t> dense_;
  std::unordered_map<uint32_t, uint32_t> sparse_;
};

class GltfReader {
 public:
  GltfReader(const tinygltf::Model& model, Assembly* out, StopCheck* stop) : model_(model), a_(*out), stop_(*stop) {}

  std::string Read() {
    std::string error = CollectInstances();
    if (error.empty()) error = CountTriangles();
    if (!error.empty()) return error;
    for (const Instance& instance : instances_) {
      const auto& mesh = model_.meshes[instance.mesh];
      for (size_t p = 0; p < mesh.primitives.size(); ++p) {
        error = ReadPrimitive(instance, size_t(instance.mesh), p);
        if (!error.empty()) return error;
      }
    }
    return "";
  }

 private:
  struct Instance {
    size_t node;
    int mesh;
    Affine world;
  };

  // The default scene's nodes (or the first scene's, or every root node when there are no scenes), depth first
  // with their world transforms.
  std::string CollectInstances() {
    const auto& nodes = model_.nodes;
    std::vector<int> roots;
    if (!model_.scenes.empty()) {
      int scene = model_.defaultScene;
      if (scene < -1 || scene >= int(model_.scenes.size())) return "scene " + std::to_string(scene) + " does not exist";
      roots = model_.scenes[scene < 0 ? 0 : scene].nodes;
    } else {
      std::vector<uint8_t> has_parent(nodes.size());
      for (size_t i = 0; i < nodes.size(); ++i) {
        for (int child : nodes[i].children) {
          if (child < 0 || size_t(child) >= nodes.size()) {
            return NodeName(i) + ".children: node " + std::to_string(child) + " does not exist";
          }
          has_parent[child] = 1;
        }
      }
      for (size_t i = 0; i < nodes.size(); ++i) {
        if (!has_parent[i]) roots.push_back(int(i));
      }
    }
    struct Pending {
      int node;
      int depth;
      Affine parent;
    };
    std::vector<Pending> stack;
    for (auto r = roots.rbegin(); r != roots.rend(); ++r) {
      if (*r < 0 || size_t(*r) >= nodes.size()) return "scene node " + std::to_string(*r) + " does not exist";
      stack.push_back({*r, 1, Affine{}});
    }
    std::vector<uint8_t> visited(nodes.size());
    while (!stack.empty()) {
      if (stop_.Tick()) return kStopped;
      const Pending at = std::move(stack.back());
      stack.pop_back();
      const auto& node = nodes[at.node];
      if (visited[at.node]) return NodeName(at.node) + " is reached twice (a cycle, or a node with two parents)";
      visited[at.node] = 1;
      if (at.depth > kMaxNodeDepth) return NodeName(at.node) + " is deeper than " + Str(kMaxNodeDepth) + " levels";
      Affine local;
      std::string error = NodeTransform(node, at.node, &local);
      if (!error.empty()) return error;
      const Affine world = at.parent * local;
      if (!world.Finite()) return NodeName(at.node) + ": its world transform is not finite";
      if (node.mesh >= 0 || node.mesh < -1) {
        if (size_t(node.mesh) >= model_.meshes.size()) {
          return NodeName(at.node) + ".mesh " + std::to_string(node.mesh) + " does not exist";
        }
        instances_.push_back({size_t(at.node), node.mesh, world});
      }
      for (auto c = node.children.rbegin(); c != node.children.rend(); ++c) {
        if (*c < 0 || size_t(*c) >= nodes.size()) {
          return NodeName(at.node) + ".children: node " + std::to_string(*c) + " does not exist";
        }
        stack.push_back({*c, at.depth + 1, world});
      }
    }
    return "";
  }

  // Each mesh's triangles once, times the nodes that show it: the limit holds before any instance is expanded.
  std::string CountTriangles() {
    std::vector<uint64_t> per_mesh(model_.meshes.size(), UINT64_MAX);
    uint64_t total = 0;
    for (const Instance& instance : instances_) {
      uint64_t& count = per_mesh[instance.mesh];
      if (count == UINT64_MAX) {
        count = 0;
        for (const auto& primitive : model_.meshes[instance.mesh].primitives) {
          int accessor = primitive.indices;
          if (accessor < 0) {
            const auto position = primitive.attributes.find("POSITION");
            accessor = position == primitive.attributes.end() ? -1 : position->second;
          }
          const uint64_t elements =
              accessor >= 0 && size_t(accessor) < model_.accessors.size() ? model_.accessors[accessor].count : 0;
          count = SaturatingAdd(count, TrianglesOf(primitive.mode, elements));
        }
      }
      total = SaturatingAdd(total, count);
    }
    if (total > a_.limits.max_triangles) {
      return OverLimit("triangles", total, a_.limits.max_triangles,
                       " (" + Str(instances_.size()) + " mesh instances)");
    }
    return "";
  }

  std::string MaterialName(const tinygltf::Primitive& primitive, const std::string& where, std::string* name) {
    if (primitive.material == -1) return *name = "", "";
    if (primitive.material < 0 || size_t(primitive.material) >= model_.materials.size()) {
      return where + ".material " + std::to_string(primitive.material) + " does not exist";
    }
    const std::string& given = model_.materials[primitive.material].name;
    // An unnamed material is named by its index, so that the request can still bind it.
    *name = given.empty() ? "materials[" + Str(primitive.material) + "]" : given;
    const std::string defect = MaterialNameDefect(*name);
    if (!defect.empty()) return "materials[" + Str(primitive.material) + "].name " + defect;
    return "";
  }

  std::string ReadPrimitive(const Instance& instance, size_t mesh_index, size_t primitive_index) {
    const tinygltf::Primitive& primitive = model_.meshes[mesh_index].primitives[primitive_index];
    const std::string where = "meshes[" + Str(mesh_index) + "].primitives[" + Str(primitive_index) + "]";
    if (primitive.mode < 0 || primitive.mode > TINYGLTF_MODE_TRIANGLE_FAN) {
      return where + ".mode " + std::to_string(primitive.mode) + " is not a glTF mode";
    }
    if (!IsTriangleMode(primitive.mode)) return "";  // points and lines have no surface
    uint64_t uv_sets = 0;
    for (const auto& [name, accessor] : primitive.attributes) uv_sets += name.rfind("TEXCOORD_", 0) == 0;
    if (uv_sets > a_.limits.max_uv_sets) return OverLimit((where + " UV sets").c_str(), uv_sets, a_.limits.max_uv_sets);

    const auto attribute = [&](const char* name) {
      const auto found = primitive.attributes.find(name);
      return found == primitive.attributes.end() ? -1 : found->second;
    };
    AccessorView positions, normals, tangents, uvs, indices;
    const int position_accessor = attribute("POSITION");
    if (position_accessor < 0) return where + ": no POSITION attribute";
    std::string error = ViewAccessor(model_, position_accessor, where + ".POSITION", kPositionRule, &positions);
    const auto optional = [&](const char* name, const AttributeRule& rule, AccessorView* view) {
      if (!error.empty() || attribute(name) < 0) return;
      error = ViewAccessor(model_, attribute(name), where + "." + name, rule, view);
      if (error.empty() && view->count < positions.count) {
        error = where + "." + name + ": " + Str(view->count) + " elements for " + Str(positions.count) + " positions";
      }
    };
    optional("NORMAL", kNormalRule, &normals);
    optional("TANGENT", kTangentRule, &tangents);
    optional("TEXCOORD_0", kTexcoordRule, &uvs);
    if (error.empty() && primitive.indices >= 0) {
      error = ViewAccessor(model_, primitive.indices, where + ".indices", kIndexRule, &indices);
    } else if (error.empty() && primitive.indices != -1) {
      error = where + ".indices " + std::to_string(primitive.indices) + " does not exist";
    }
    if (!error.empty()) return error;
    const bool indexed = primitive.indices >= 0;
    const uint64_t elements = indexed ? indices.count : positions.count;
    if (positions.count > UINT32_MAX) return where + ".POSITION: more than 2^32 elements";

    // The vertices the primitive's elements use, in order of first use.
    VertexRemap remap(positions.count, elements);
    std::vector<uint32_t> used;
    std::vector<uint32_t> element_vertex(elements);
    const uint32_t first = uint32_t(a_.mesh.positions.size());
    for (uint64_t k = 0; k < elements; ++k) {
      if (stop_.Tick()) return kStopped;
      const uint64_t v = indexed ? indices.Index(k) : k;
      if (v >= positions.count) {
        return where + ": index " + Str(v) + " (indices[" + Str(k) + "]) is out of range: " + Str(positions.count) +
               " vertices";
      }
      uint32_t mapped = remap.Find(uint32_t(v));
      if (mapped == VertexRemap::kNone) {
        mapped = first + uint32_t(used.size());
        remap.Set(uint32_t(v), mapped);
        used.push_back(uint32_t(v));
      }
      element_vertex[k] = mapped;
    }
    error = a_.AddVertices(used.size());
    if (!error.empty()) return error;

    const Affine& world = instance.world;
    const Affine normal_matrix = world.NormalMatrix();
    const bool mirrored = world.Determinant() < 0;
    const auto not_finite = [&](const char* name, uint64_t v) {
      return where + "." + name + "[" + Str(v) + "] is not finite";
    };
    for (size_t i = 0; i < used.size(); ++i) {
      if (stop_.Tick()) return kStopped;
      const uint64_t v = used[i];
      const size_t out = first + i;
      Vec3d p{positions.Component(v, 0), positions.Component(v, 1), positions.Component(v, 2)};
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) return not_finite("POSITION", v);
      p = world.Point(p);
      if (!(std::fabs(p[0]) <= FLT_MAX && std::fabs(p[1]) <= FLT_MAX && std::fabs(p[2]) <= FLT_MAX)) {
        return where + ".POSITION[" + Str(v) + "] under " + NodeName(instance.node) + " leaves float range";
      }
      a_.mesh.positions[out] = {float(p[0]), float(p[1]), float(p[2])};
      if (normals.data) {
        const Vec3d n{normals.Component(v, 0), normals.Component(v, 1), normals.Component(v, 2)};
        if (!std::isfinite(n[0]) || !std::isfinite(n[1]) || !std::isfinite(n[2])) return not_finite("NORMAL", v);
        a_.mesh.normals[out] = UnitOrZero(normal_matrix.Vector(n));
      }
      if (tangents.data) {
        const Vec3d t{tangents.Component(v, 0), tangents.Component(v, 1), tangents.Component(v, 2)};
        const double w = tangents.Component(v, 3);
        if (!std::isfinite(t[0]) || !std::isfinite(t[1]) || !std::isfinite(t[2]) || !std::isfinite(w)) {
          return not_finite("TANGENT", v);
        }
        const auto unit = UnitOrZero(world.Vector(t));
        // A mirroring transform flips the tangent frame's handedness.
        a_.mesh.tangents[out] = {unit[0], unit[1], unit[2], float((w < 0) != mirrored ? -1 : 1)};
      }
      if (uvs.data) {
        const double s = uvs.Component(v, 0), t = uvs.Component(v, 1);
        if (!std::isfinite(s) || !std::isfinite(t)) return not_finite("TEXCOORD_0", v);
        // glTF's v runs down the image; TriangleMesh's runs up (OBJ's and OpenGL's).
        a_.mesh.uvs[out] = {float(s), float(1 - t)};
        a_.uv_given[out] = 1;
      }
    }

    std::string material_name;
    error = MaterialName(primitive, where, &material_name);
    uint32_t material = 0;
    if (error.empty()) error = a_.Material(material_name, &material);
    if (!error.empty()) return error;
    const uint64_t triangles = TrianglesOf(primitive.mode, elements);
    for (uint64_t t = 0; t < triangles; ++t) {
      if (stop_.Tick()) return kStopped;
      std::array<uint64_t, 3> e;
      if (primitive.mode == TINYGLTF_MODE_TRIANGLES) {
        e = {3 * t, 3 * t + 1, 3 * t + 2};
      } else if (primitive.mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
        e = {t, t + 1 + t % 2, t + 2 - t % 2};  // glTF 2.0 section 3.7.2.1: every other triangle reversed
      } else {
        e = {t + 1, t + 2, 0};
      }
      std::array<uint32_t, 3> tri{element_vertex[e[0]], element_vertex[e[1]], element_vertex[e[2]]};
      if (mirrored) std::swap(tri[1], tri[2]);  // counter-clockwise in world space again
      a_.mesh.triangles.push_back(tri);
      a_.mesh.triangle_material.push_back(material);
    }
    return "";
  }

  const tinygltf::Model& model_;
  Assembly& a_;
  StopCheck& stop_;
  std::vector<Instance> instances_;
};

std::string FirstLine(const std::string& text) {
  const size_t end = text.find('\n');
  return end == std::string::npos ? text : text.substr(0, end);
}

// Required extensions change what the data means; only those about looks (ignored here) are accepted.
std::string CheckRequiredExtensions(const tinygltf::Model& model) {
  for (const std::string& name : model.extensionsRequired) {
    if (name.rfind("KHR_materials_", 0) == 0 || name == "KHR_texture_transform" || name == "KHR_lights_punctual") {
      continue;
    }
    return "extensionsRequired: " + Quote(name) + " is not supported";
  }
  return "";
}

std::string ReadGltf(std::string_view bytes, bool binary, Assembly* out, StopCheck* stop) {
  std::string_view json = bytes;
  uint32_t glb_length = 0;
  if (binary) {
    const std::string error = CheckGlb(bytes, &json, &glb_length);
    if (!error.empty()) return error;
  } else if (bytes.size() > UINT32_MAX) {
    return "glTF: files of 4 GiB or more are not read";
  }
  std::string error = CheckJsonDepth(json);
  if (!error.empty()) return error;

  tinygltf::TinyGLTF loader;
  RefusedFiles refused;
  loader.SetFsCallbacks(
      {&RefuseFileExists, &RefuseExpandFilePath, &RefuseReadWholeFile, &RefuseWriteWholeFile, &refused});
  loader.SetImageLoader(&IgnoreImage, nullptr);
  tinygltf::Model model;
  std::string err, warn;
  bool loaded = false;
  try {
    loaded = binary ? loader.LoadBinaryFromMemory(&model, &err, &warn,
                                                  reinterpret_cast<const unsigned char*>(bytes.data()), glb_length, "")
                    : loader.LoadASCIIFromString(&model, &err, &warn, bytes.data(), unsigned(bytes.size()), "");
  } catch (const std::exception& e) {
    err = e.what();
  }
  if (stop->Now()) return kStopped;
  // Buffers load first and an external one fails the load at once, so the buffers loaded so far number the one
  // refused; an external image only warns (and keeps its uri).
  if (!loaded && refused.asked && model.images.empty()) {
    if (refused.first.empty()) {
      return "buffers[" + Str(model.buffers.size()) + "]: no uri (a .gltf file's buffers are embedded as data: URIs)";
    }
    return "buffers[" + Str(model.buffers.size()) + "].uri: external files are refused (" + Quote(refused.first) +
           ")";
  }
  if (!loaded) return "not a glTF 2.0 file: " + Quote(FirstLine(err.empty() ? "tinygltf failed" : err));
  for (size_t i = 0; i < model.images.size(); ++i) {
    const std::string& uri = model.images[i].uri;
    if (!uri.empty() && !tinygltf::IsDataURI(uri)) {
      return "images[" + Str(i) + "].uri: external files are refused (" + Quote(uri) + ")";
    }
  }
  error = CheckRequiredExtensions(model);
  if (!error.empty()) return error;
  return GltfReader(model, out, stop).Read();
}

// ---- OBJ ----

// A read-only stream over two pieces of text without copying them: tinyobjloader reads the file through it, after
// a line that makes it ask UsemtlMaterials for its materials.
class ChainedBuffer : public std::streambuf {
 public:
  ChainedBuffer(std::string_view first, std::string_view second) : parts_{first, second} {}

 protected:
  int_type underflow() override {
    while (gptr() == egptr()) {
      if (next_ == 2) return traits_type::eof();
      char* begin = const_cast<char*>(parts_[next_].data());  // only ever read
      setg(begin, begin, begin + parts_[next_].size());
      ++next_;
    }
    return traits_type::to_int_type(*gptr());
  }

 private:
  std::string_view parts_[2];
  int next_ = 0;
};

constexpr std::string_view kMaterialLine = "mtllib (usemtl names)\n";

// tinyobjloader's material library reader: nothing is read from disk; the first `mtllib` (kMaterialLine) gets one
// material per usemtl name the file uses, so faces' material ids name them. The file's own mtllib lines get none.
class UsemtlMaterials : public tinyobj::MaterialReader {
 public:
  explicit UsemtlMaterials(const std::vector<std::string>& names) : names_(names) {}
  bool operator()(const std::string&, std::vector<tinyobj::material_t>* materials,
                  std::map<std::string, int>* ids, std::string*, std::string*) override {
    if (given_) return true;
    given_ = true;
    for (const std::string& name : names_) {
      tinyobj::material_t material{};
      material.name = name;
      (*ids)[name] = int(materials->size());
      materials->push_back(std::move(material));
    }
    return true;
  }

 private:
  const std::vector<std::string>& names_;
  bool given_ = false;
};

bool ObjSpace(char c) { return c == ' ' || c == '\t'; }
bool ObjLineEnd(char c) { return c == '\r' || c == '\n' || c == '\0'; }
// atoi, as tinyobjloader parses indices (0 is never an index: OBJ counts from 1, negatives from the end).
int ObjIndex(const char* s) { return int(std::strtol(s, nullptr, 10)); }

// One face vertex (v, v/vt, v//vn or v/vt/vn) as tinyobjloader's parseTriple reads it: false where it fails.
bool ParseObjTriple(const char** p) {
  const auto index = [&]() {
    if (ObjIndex(*p) == 0) return false;
    *p += std::strcspn(*p, "/ \t\r");
    return true;
  };
  if (!index()) return false;
  if (**p != '/') return true;
  ++*p;
  if (**p == '/') return ++*p, index();
  if (!index()) return false;
  if (**p != '/') return true;
  ++*p;
  return index();
}

// What a first pass over the OBJ text finds before tinyobjloader reads it: the triangles its faces make, and the
// usemtl names faces use, in order of first use. Lines split as tinyobjloader splits them (\n, \r\n or \r).
struct ObjScan {
  uint64_t triangles = 0;
  std::vector<std::string> materials;
};

std::string ScanObj(std::string_view text, const MeshLimits& limits, StopCheck* stop, ObjScan* scan) {
  std::string line, pending_material;
  std::map<std::string, int, std::less<>> seen;
  uint64_t line_number = 0;
  for (size_t start = 0; start < text.size();) {
    if (stop->Tick()) return kStopped;
    size_t end = start;
    while (end < text.size() && text[end] != '\n' && text[end] != '\r') ++end;
    ++line_number;
    line.assign(text.substr(start, end - start));
    start = end + (end < text.size() && text[end] == '\r' && end + 1 < text.size() && text[end + 1] == '\n' ? 2 : 1);
    stop->Tick(line.size());
    const char* token = line.c_str();  // up to a NUL, as tinyobjloader's C-string parsing sees the line
    token += std::strspn(token, " \t");
    const std::string where = "line " + Str(line_number);
    if (std::strncmp(token, "usemtl", 6) == 0) {
      token += 6;
      token += std::strspn(token, " \t");
      pending_material.assign(token, std::strcspn(token, " \t\r"));
      continue;
    }
    if (token[0] == 't' && ObjSpace(token[1])) {
      // tinyobjloader sizes a tag's arrays from the counts the line states (up to 8192 values of each kind, some
      // 330 KB for a line of 20 bytes): a file of them would take thousands of times its size.
      return where + ": 't' lines (subdivision surface tags) are not read";
    }
    if (token[0] == 'v' && (ObjSpace(token[1]) || ((token[1] == 't' || token[1] == 'n') && ObjSpace(token[2])))) {
      // tinyobjloader reads a value it cannot parse ("nan", "1,5", "x") as 0: a vertex silently moved. Every
      // value must be a finite decimal number (std::from_chars would take "nan" and "inf": refused after it).
      const char* what = token[1] == 't' ? "vt" : token[1] == 'n' ? "vn" : "v";
      token += std::strlen(what);
      for (token += std::strspn(token, " \t"); !ObjLineEnd(*token); token += std::strspn(token, " \t\r")) {
        const size_t length = std::strcspn(token, " \t\r");
        double value = 0;
        const char* number = token + (length > 1 && token[0] == '+');  // from_chars takes no '+'; strtod does
        const auto [rest, code] = std::from_chars(number, token + length, value);
        if (code != std::errc() || rest != token + length || !std::isfinite(value))
          return where + ": " + what + " value " + Quote(std::string_view(token, length)) +
                 " is not a finite number";
        token += length;
      }
      continue;
    }
    const bool face = token[0] == 'f' && ObjSpace(token[1]);
    if (!face && !((token[0] == 'l' || token[0] == 'p') && ObjSpace(token[1]))) continue;
    token += 2;
    token += std::strspn(token, " \t");
    uint64_t vertices = 0;
    while (!ObjLineEnd(*token)) {
      const char* vertex = token;
      if (!ParseObjTriple(&token)) {
        return where + ": " + Quote(std::string_view(vertex, std::strcspn(vertex, " \t"))) +
               " is not a vertex reference (v, v/vt, v//vn or v/vt/vn; indices count from 1)";
      }
      if (face && ++vertices > kMaxObjFaceVertices) {
        return where + ": a face of more than " + Str(kMaxObjFaceVertices) + " vertices";
      }
      token += std::strspn(token, " \t\r");
    }
    if (!face || vertices < 3) continue;
    scan->triangles += vertices - 2;
    if (!pending_material.empty() && seen.find(pending_material) == seen.end()) {
      const std::string defect = MaterialNameDefect(pending_material);
      if (!defect.empty()) return where + ": usemtl " + defect;
      if (scan->materials.size() >= limits.max_materials) {
        return "materials: more than the limit of " + Str(limits.max_materials) + " (" + where + ": usemtl " +
               Quote(pending_material) + ")";
      }
      seen.emplace(pending_material, 0);
      scan->materials.push_back(pending_material);
    }
  }
  if (scan->triangles > limits.max_triangles) return OverLimit("triangles", scan->triangles, limits.max_triangles);
  return "";
}

struct ObjCorner {
  int v, vt, vn;
  bool operator==(const ObjCorner& o) const { return v == o.v && vt == o.vt && vn == o.vn; }
};
struct ObjCornerHash {
  size_t operator()(const ObjCorner& c) const {
    uint64_t h = uint64_t(uint32_t(c.v)) * 0x9E3779B97F4A7C15ull;
    h ^= (uint64_t(uint32_t(c.vt)) + 0x632BE59BD9B4E019ull) * 0xBF58476D1CE4E5B9ull;
    h ^= (uint64_t(uint32_t(c.vn)) + 0x85EBCA77C2B2AE63ull) * 0x94D049BB133111EBull;
    return size_t(h ^ (h >> 31));
  }
};

std::string ReadObj(std::string_view text, Assembly* out, StopCheck* stop) {
  ObjScan scan;
  std::string error = ScanObj(text, out->limits, stop, &scan);
  if (!error.empty()) return error;
  if (stop->Now()) return kStopped;

  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> materials;
  std::string warn, err;
  ChainedBuffer buffer(scan.materials.empty() ? std::string_view() : kMaterialLine, text);
  std::istream stream(&buffer);
  UsemtlMaterials reader(scan.materials);
  bool loaded = false;
  try {
    loaded = tinyobj::LoadObj(&attrib, &shapes, &materials, &warn, &err, &stream, &reader, /*triangulate=*/true,
                              /*default_vcols_fallback=*/false);
  } catch (const std::exception& e) {
    err = e.what();
  }
  if (stop->Now()) return kStopped;
  if (!loaded) return "not an OBJ file: " + Quote(FirstLine(err.empty() ? "tinyobjloader failed" : err));

  const uint64_t positions = attrib.vertices.size() / 3, normals = attrib.normals.size() / 3,
                 uvs = attrib.texcoords.size() / 2;
  std::unordered_map<ObjCorner, uint32_t, ObjCornerHash> vertex_of;
  std::vector<uint32_t> material_of(materials.size() + 1, VertexRemap::kNone);  // [0]: no material
  TriangleMesh& mesh = out->mesh;
  uint64_t triangle = 0;
  for (const tinyobj::shape_t& shape : shapes) {
    const auto& indices = shape.mesh.indices;
    for (size_t f = 0; f < shape.mesh.material_ids.size() && 3 * f + 2 < indices.size(); ++f, ++triangle) {
      if (stop->Tick()) return kStopped;
      std::array<uint32_t, 3> tri;
      for (int k = 0; k < 3; ++k) {
        const tinyobj::index_t& index = indices[3 * f + k];
        const ObjCorner corner{index.vertex_index, index.texcoord_index, index.normal_index};
        const auto out_of_range = [&](const char* what, int i, uint64_t count) {
          return "OBJ triangle " + Str(triangle) + ": " + what + " index " + std::to_string(int64_t(i) + 1) +
                 " is out of range: " + Str(count) + " in the file";
        };
        if (corner.v < 0 || uint64_t(corner.v) >= positions) return out_of_range("vertex", corner.v, positions);
        if (corner.vt < -1 || (corner.vt >= 0 && uint64_t(corner.vt) >= uvs)) {
          return out_of_range("texture coordinate", corner.vt, uvs);
        }
        if (corner.vn < -1 || (corner.vn >= 0 && uint64_t(corner.vn) >= normals)) {
          return out_of_range("normal", corner.vn, normals);
        }
        const auto found = vertex_of.find(corner);
        if (found != vertex_of.end()) {
          tri[k] = found->second;
          continue;
        }
        const uint32_t v = uint32_t(mesh.positions.size());
        error = out->AddVertices(1);
        if (!error.empty()) return error;
        const auto not_finite = [](const char* what, int i) {
          return std::string(what) + " " + std::to_string(int64_t(i) + 1) + " is not finite";
        };
        const float* p = &attrib.vertices[3 * size_t(corner.v)];
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) return not_finite("v", corner.v);
        mesh.positions[v] = {p[0], p[1], p[2]};
        if (corner.vn >= 0) {
          const float* n = &attrib.normals[3 * size_t(corner.vn)];
          if (!std::isfinite(n[0]) || !std::isfinite(n[1]) || !std::isfinite(n[2])) {
            return not_finite("vn", corner.vn);
          }
          mesh.normals[v] = UnitOrZero({n[0], n[1], n[2]});
        }
        if (corner.vt >= 0) {
          const float* t = &attrib.texcoords[2 * size_t(corner.vt)];
          if (!std::isfinite(t[0]) || !std::isfinite(t[1])) return not_finite("vt", corner.vt);
          mesh.uvs[v] = {t[0], t[1]};
          out->uv_given[v] = 1;
        }
        vertex_of.emplace(corner, v);
        tri[k] = v;
      }
      const int id = shape.mesh.material_ids[f];
      const size_t slot = id >= 0 && size_t(id) < materials.size() ? size_t(id) + 1 : 0;
      if (material_of[slot] == VertexRemap::kNone) {
        error = out->Material(slot == 0 ? std::string() : materials[slot - 1].name, &material_of[slot]);
        if (!error.empty()) return error;
      }
      mesh.triangles.push_back(tri);
      mesh.triangle_material.push_back(material_of[slot]);
    }
  }
  return "";
}

}  // namespace

uint64_t TriangleMesh::memory_bytes() const {
  uint64_t bytes = sizeof(*this) + positions.capacity() * sizeof(positions[0]) +
                   normals.capacity() * sizeof(normals[0]) + uvs.capacity() * sizeof(uvs[0]) +
                   tangents.capacity() * sizeof(tangents[0]) + triangles.capacity() * sizeof(triangles[0]) +
                   triangle_material.capacity() * sizeof(triangle_material[0]) +
                   material_names.capacity() * sizeof(material_names[0]);
  for (const std::string& name : material_names) bytes += name.capacity();
  return bytes;
}

v1::MeshFormat DetectMeshFormat(std::string_view bytes, v1::MeshFormat declared) {
  if (declared != v1::MESH_FORMAT_AUTO) return declared;
  if (bytes.substr(0, 4) == "glTF") return v1::MESH_FORMAT_GLB;
  const size_t first = bytes.find_first_not_of(" \t\r\n");
  if (first != std::string_view::npos && bytes[first] == '{') return v1::MESH_FORMAT_GLTF;
  return v1::MESH_FORMAT_OBJ;
}

std::string ParseMesh(std::string_view bytes, v1::MeshFormat format, const MeshLimits& limits, TriangleMesh* out,
                      uint64_t* dropped, const std::function<bool()>& stop) {
  if (bytes.size() > limits.max_bytes) return OverLimit("file bytes", bytes.size(), limits.max_bytes);
  StopCheck check(stop);
  if (check.Now()) return kStopped;
  Assembly assembly(limits);
  std::string error;
  try {
    switch (DetectMeshFormat(bytes, format)) {
      case v1::MESH_FORMAT_GLB:
        error = ReadGltf(bytes, true, &assembly, &check);
        break;
      case v1::MESH_FORMAT_GLTF:
        error = ReadGltf(bytes, false, &assembly, &check);
        break;
      case v1::MESH_FORMAT_OBJ:
        error = ReadObj(bytes, &assembly, &check);
        break;
      default:
        return "unknown mesh format " + std::to_string(int(format));
    }
    uint64_t dropped_triangles = 0;
    if (error.empty()) error = Finish(&assembly, &dropped_triangles, &check);
    if (!error.empty()) return error;
    *out = std::move(assembly.mesh);
    if (dropped) *dropped = dropped_triangles;
  } catch (const std::bad_alloc&) {
    return "the mesh does not fit in memory";
  }
  return "";
}

void DescribeMesh(const TriangleMesh& mesh, v1::MeshInfo* info) {
  info->set_triangles(mesh.triangles.size());
  info->set_vertices(mesh.positions.size());
  info->clear_materials();
  for (const std::string& name : mesh.material_names) info->add_materials(name);
  info->set_has_normals(mesh.file_normals);
  info->set_has_uvs(mesh.file_uvs);
  info->set_has_tangents(mesh.file_tangents);
  info->clear_bounds_min();
  info->clear_bounds_max();
  for (int c = 0; c < 3; ++c) {
    info->add_bounds_min(mesh.bounds_min[c]);
    info->add_bounds_max(mesh.bounds_max[c]);
  }
  info->set_surface_area(mesh.surface_area);
  info->set_metres_per_uv(mesh.metres_per_uv);
}

}  // namespace loomlight::assets
