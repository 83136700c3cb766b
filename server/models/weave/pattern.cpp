#include "server/models/weave/pattern.h"

#include <numeric>
#include <utility>

namespace loomlight::models::weave {
namespace {

// Non-negative remainder, so that shifts to lower indices wrap around the repeat.
int Mod(int a, int n) { return ((a % n) + n) % n; }

// Maximal cyclic runs of `on_top(i)` over i in [0, n): each run as (start, length), by start. A run is
// reported from the cell whose predecessor (cyclically) is off, so a run crossing the edge is found once,
// at its true start; when every cell is on there is no such cell, hence the single closed run (0, n).
template <typename OnTop>
std::vector<std::pair<int, int>> CyclicRuns(int n, OnTop on_top) {
  std::vector<std::pair<int, int>> runs;
  for (int i = 0; i < n; ++i) {
    if (!on_top(i) || on_top(Mod(i - 1, n))) continue;
    int length = 1;
    while (length < n && on_top(Mod(i + length, n))) ++length;
    runs.push_back({i, length});
  }
  if (runs.empty() && n > 0 && on_top(0)) runs.push_back({0, n});
  return runs;
}

// Fills a square n x n repeat where the warp at (warp, pick) is on top when up(warp, pick).
template <typename Up>
WeavePattern Square(int n, Up up) {
  WeavePattern p{n, n, std::vector<uint8_t>(size_t(n) * n)};
  for (int pick = 0; pick < n; ++pick)
    for (int warp = 0; warp < n; ++warp) p.cells[size_t(pick) * n + warp] = up(warp, pick) ? 1 : 0;
  return p;
}

}  // namespace

std::string ValidatePattern(const WeavePattern& p) {
  const std::string limit = std::to_string(kMaxRepeat);
  if (p.warps < 1 || p.warps > kMaxRepeat)
    return "warps is " + std::to_string(p.warps) + ", must be in 1.." + limit;
  if (p.picks < 1 || p.picks > kMaxRepeat)
    return "picks is " + std::to_string(p.picks) + ", must be in 1.." + limit;
  if (p.cells.size() != size_t(p.warps) * p.picks)
    return "cells has " + std::to_string(p.cells.size()) + " entries, warps * picks is " +
           std::to_string(p.warps * p.picks);
  for (size_t i = 0; i < p.cells.size(); ++i)
    if (p.cells[i] > 1)
      return "cell (warp " + std::to_string(i % p.warps) + ", pick " + std::to_string(i / p.warps) + ") is " +
             std::to_string(p.cells[i]) + ", must be 0 or 1";
  return "";
}

std::vector<Float> ExtractFloats(const WeavePattern& p) {
  std::vector<Float> floats;
  for (int warp = 0; warp < p.warps; ++warp)
    for (auto [start, length] : CyclicRuns(p.picks, [&](int pick) { return p.at(warp, pick) == 1; }))
      floats.push_back({true, warp, start, length});
  for (int pick = 0; pick < p.picks; ++pick)
    for (auto [start, length] : CyclicRuns(p.warps, [&](int warp) { return p.at(warp, pick) == 0; }))
      floats.push_back({false, start, pick, length});
  return floats;
}

AreaFractions ComputeAreaFractions(const WeavePattern& p) {
  if (p.cells.empty()) return {};
  const double warp = double(std::accumulate(p.cells.begin(), p.cells.end(), size_t(0))) / p.cells.size();
  return {warp, 1.0 - warp};
}

std::string ToString(const WeavePattern& p) {
  std::string s = "warps=" + std::to_string(p.warps) + " picks=" + std::to_string(p.picks) + "\n";
  for (int pick = 0; pick < p.picks; ++pick) {
    for (int warp = 0; warp < p.warps; ++warp) s += p.at(warp, pick) ? '1' : '0';
    s += '\n';
  }
  return s;
}

std::string ToString(const Float& f) {
  return std::string(f.warp ? "warp" : "weft") + " float at warp " + std::to_string(f.start_warp) + ", pick " +
         std::to_string(f.start_pick) + ", length " + std::to_string(f.length);
}

WeavePattern PlainWeave() {
  WeavePattern p;
  MakeTwill(1, 1, TwillDirection::kRightward, &p);  // a 1/1 twill is the plain weave
  return p;
}

std::string MakeTwill(int up, int down, TwillDirection direction, WeavePattern* out) {
  const std::string name = "twill " + std::to_string(up) + "/" + std::to_string(down);
  if (up < 1 || down < 1) return name + ": up and down must be >= 1";
  if (up > kMaxRepeat - down) return name + ": repeat over " + std::to_string(kMaxRepeat);  // cannot overflow
  const int n = up + down;
  // The raised block starts at warp 0 on pick 0 and moves one warp per pick; shifting the warp index
  // back by the pick (or forward, for kLeftward) brings every pick to the pick-0 case.
  const int step = direction == TwillDirection::kRightward ? -1 : 1;
  *out = Square(n, [&](int warp, int pick) { return Mod(warp + step * pick, n) < up; });
  return "";
}

std::string MakeSatin(int ends, int move, SatinFace face, WeavePattern* out) {
  const std::string name = std::to_string(ends) + "-end satin move " + std::to_string(move);
  if (ends < 5 || ends > kMaxRepeat) return name + ": ends must be in 5.." + std::to_string(kMaxRepeat);
  if (move < 2 || move > ends - 2) return name + ": move must be in 2.." + std::to_string(ends - 2);
  if (std::gcd(ends, move) != 1) return name + ": move and ends share a factor";
  const bool warp_faced = face == SatinFace::kWarpFaced;
  // At the interlacing the face thread goes under: the warp for warp-faced, the weft for weft-faced.
  *out = Square(ends, [&](int warp, int pick) { return (warp == pick * move % ends) != warp_faced; });
  return "";
}

}  // namespace loomlight::models::weave
