#include "client/btf_grid.h"

#include <array>
#include <cstdio>

namespace loomlight::client {
namespace {

namespace v1 = loomlight::v1;

struct GridPreset {
  const char* name;
  std::array<double, 6> theta_deg;
};

// Both presets share the ring sizes (delta phi 360, 60, 30, 20, 18, 15 degrees): 81 directions.
constexpr std::array<unsigned, 6> kRingCounts = {1, 6, 12, 18, 20, 24};
constexpr GridPreset kPresets[] = {
    {"h1", {0, 17, 34, 51, 68, 85}},
    {"h2", {0, 15, 30, 45, 60, 75}},
};

const GridPreset* find_preset(const std::string& name) {
  for (const GridPreset& p : kPresets)
    if (name == p.name) return &p;
  return nullptr;
}

bool same_rings(const v1::BtfGrid& a, const v1::BtfGrid& b) {
  if (a.rings_size() != b.rings_size()) return false;
  for (int r = 0; r < a.rings_size(); ++r)
    if (a.rings(r).theta() != b.rings(r).theta() || a.rings(r).count() != b.rings(r).count()) return false;
  return true;
}

}  // namespace

std::string btf_grid_option(const ParsedOptions& options) {
  const std::string name = options.last("grid").value_or("h1");
  if (find_preset(name) == nullptr) throw UsageError("--grid: expected h1 or h2, got '" + name + "'");
  return name;
}

v1::BtfGrid btf_grid_rings(const std::string& preset) {
  const GridPreset* p = find_preset(preset);
  if (p == nullptr) throw UsageError("unknown BTF grid '" + preset + "' (expected h1 or h2)");
  v1::BtfGrid grid;
  for (std::size_t r = 0; r < kRingCounts.size(); ++r) {
    v1::BtfRing* ring = grid.add_rings();
    ring->set_theta(p->theta_deg[r]);
    ring->set_count(kRingCounts[r]);
  }
  return grid;
}

std::vector<Vec3> btf_grid_directions(const v1::BtfGrid& grid) {
  std::vector<Vec3> directions;
  for (const v1::BtfRing& ring : grid.rings())
    for (unsigned j = 0; j < ring.count(); ++j)
      directions.push_back(direction_from_degrees(ring.theta(), 360.0 * j / ring.count()));
  return directions;
}

std::string btf_grid_label(const v1::BtfGrid& grid) {
  std::size_t directions = 0;
  for (const v1::BtfRing& ring : grid.rings()) directions += ring.count();
  std::string name = std::to_string(grid.rings_size()) + " rings";
  for (const GridPreset& p : kPresets)
    if (same_rings(grid, btf_grid_rings(p.name))) name = p.name;
  return name + ", " + std::to_string(directions) + " directions";
}

std::string btf_image_name(std::size_t view, std::size_t light, const std::string& extension) {
  char name[64];
  std::snprintf(name, sizeof name, "view_%03zu_light_%03zu.%s", view, light, extension.c_str());
  return name;
}

}  // namespace loomlight::client
