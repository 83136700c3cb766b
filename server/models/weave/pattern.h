// Weave patterns for the woven-cotton model (SPEC.md section 3): the repeat matrix, its floats (the
// segment windows of Irawan and Marschner's BTF), area fractions, and builders for the standard weaves.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace loomlight::models::weave {

// Largest repeat accepted in either direction. It bounds the per-material data the woven-cotton kernel
// has to carry; real repeats are far smaller (a 24-end satin is already unusual), and WIF import uses
// the same bound for threads, picks, shafts and treadles.
inline constexpr int kMaxRepeat = 256;

// One repeat of a weave. Warp threads run along y (texture v) and are the columns, indexed by `warp`
// along x; picks (weft threads) run along x (texture u) and are the rows, indexed by `pick` along y.
// cells[pick * warps + warp] is 1 when the warp is on top at that crossing, 0 when the weft is.
// The pattern tiles the plane, so every index is taken modulo the repeat.
struct WeavePattern {
  int warps = 0;
  int picks = 0;
  std::vector<uint8_t> cells;

  uint8_t at(int warp, int pick) const { return cells[size_t(pick) * warps + warp]; }
  bool operator==(const WeavePattern&) const = default;
};

// Returns "" or why the pattern is unusable. Rules:
// - 1 <= warps, picks <= kMaxRepeat and cells.size() == warps * picks;
// - every cell is 0 or 1.
// Threads that never interlace (a column of only 1s or only 0s, a row likewise) are accepted: the model
// renders the cloth face, where such a thread is simply one float spanning the whole repeat (see
// ExtractFloats), and WIF drafts legitimately produce them (an end left off every shaft). Whether the
// cloth would hold together is a weaver's question, not an appearance one.
std::string ValidatePattern(const WeavePattern& pattern);

// A float: a maximal run of consecutive cells along one thread where that thread is on top, i.e. one
// segment window of the BTF. Warp floats run along y (a run of 1s down a column, start_warp fixed, the
// run covering picks start_pick .. start_pick + length - 1); weft floats run along x (a run of 0s along
// a row, start_pick fixed, covering warps start_warp .. start_warp + length - 1). Indices past the edge
// wrap around the repeat: a run crossing the edge is one float, reported once from its first cell.
// A thread on top over the whole repeat has no ends: it is one float with length equal to the repeat
// along the thread (picks for a warp float, warps for a weft float) that joins itself, reported as
// starting at index 0.
struct Float {
  bool warp = false;
  int start_warp = 0;
  int start_pick = 0;
  int length = 0;

  bool operator==(const Float&) const = default;
};

// Every float of the repeat: first the warp floats (by warp, then start pick), then the weft floats (by
// pick, then start warp). The pattern must pass ValidatePattern. The lengths of the warp floats sum to
// the number of 1 cells, those of the weft floats to the number of 0 cells.
std::vector<Float> ExtractFloats(const WeavePattern& pattern);

// Fractions of the repeat's area showing warp (1 cells) and weft (0 cells); they sum to 1.
struct AreaFractions {
  double warp = 0;
  double weft = 0;
};
AreaFractions ComputeAreaFractions(const WeavePattern& pattern);

// Canonical text for logs and test failures: "warps=W picks=P" then one line per pick (pick 0 first),
// one '1' or '0' per warp (warp 0 first), each line ending in '\n'.
std::string ToString(const WeavePattern& pattern);
// "warp float at warp 0, pick 2, length 3" (or "weft float ...").
std::string ToString(const Float& f);

// ---- Standard weaves ----
// All builders put the first interlacing at warp 0, pick 0, so equal weaves compare equal cell for cell.

// Plain weave: the 2 x 2 repeat {1 0 / 0 1} (warp 0 on top at pick 0). Equals Twill(1, 1, kRightward).
WeavePattern PlainWeave();

// Which way the twill line moves: at each next pick the block of raised warps shifts one warp
// towards higher (kRightward) or lower (kLeftward) warp indices. With warps along +x and picks along +y
// (SPEC.md section 1), kRightward draws the diagonal lower-left to upper-right, a Z twill; kLeftward an S
// twill.
enum class TwillDirection { kRightward, kLeftward };

// An up/down twill ("3/1" = up 3, down 1): a square repeat of up + down; along every thread the warp is
// on top for `up` consecutive picks then under for `down`. At pick 0 warps 0 .. up-1 are on top.
// Needs up >= 1, down >= 1, up + down <= kMaxRepeat. Returns "" or the reason.
std::string MakeTwill(int up, int down, TwillDirection direction, WeavePattern* out);

// Which thread shows on the face of a satin: kWarpFaced (satin: warp floats over ends - 1 picks) or
// kWeftFaced (sateen: weft floats over ends - 1 warps).
enum class SatinFace { kWarpFaced, kWeftFaced };

// A regular n-end satin with move (counter) m: a square repeat of n, with one interlacing per row and
// per column; at pick p the interlacing warp is (p * m) mod n, where the face thread goes under.
// Needs 5 <= ends <= kMaxRepeat, 2 <= move <= ends - 2 and gcd(ends, move) = 1 (move 1 or ends - 1
// would be a twill, a shared factor would leave warps that never interlace). Returns "" or the reason.
std::string MakeSatin(int ends, int move, SatinFace face, WeavePattern* out);

}  // namespace loomlight::models::weave
