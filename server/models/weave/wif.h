// Import of WIF (Weaving Information File, version 1.x) drafts, the INI-like format weaving programs use
// to exchange patterns: the drawdown of threading, tie-up and treadling (or liftplan) becomes a
// WeavePattern.
#pragma once

#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"

namespace loomlight::models::weave {

// Largest WIF text accepted, in bytes. A 256 x 256 draft with every optional section is well under it.
inline constexpr size_t kMaxWifBytes = size_t(1) << 20;

// The most heap a ParseWif of `text_bytes` bytes holds at once: the text's size (section names are copied)
// plus a fixed part (at most 1024 sections, 1024 entries in each section read, index sets of 256 values,
// the 256 x 256 drawdown). What the server charges to its memory budget for a draft while it parses.
inline constexpr size_t WifParseBytes(size_t text_bytes) { return text_bytes + (size_t(1) << 20); }

// Parses a WIF draft into *out (left untouched on error). Returns "" or "line N: reason", N being the
// 1-based line that failed; a missing section is reported at line 0, a missing key at the line of its
// section header, and a section that [CONTENTS] lists but the file lacks at that [CONTENTS] line.
//
// Syntax (INI): "[Section]" headers and "key=value" lines; section and key names are case-insensitive and
// trimmed; ';' starts a comment that runs to the end of the line; blank lines are allowed; lines end in
// "\n", "\r\n" or "\r"; a UTF-8 byte-order mark is skipped. Only the sections read below are checked
// line by line (each non-blank line must contain '=', keys must not repeat, the section must not
// repeat); any other section (TEXT, NOTES, colours, private sections...) is skipped unread, so free text
// written loosely by some program cannot make a draft unreadable (the colour sections are read by the
// three-argument ParseWif below). Only blank lines and comments may precede the first header.
//
// Sections read:
// - [WIF] Version= (required, major version 1).
// - [CONTENTS] (required) name=bool for each section; every section it lists as present (true/yes/on/1;
//   false/no/off/0 otherwise) must exist.
// - [WEAVING] (required): Shafts= (required, 1..256), Treadles= (0..256; required when [TIEUP] or
//   [TREADLING] is present), Rising Shed= (bool, default true).
// - [WARP] Threads=, [WEFT] Threads= (optional, 1..256): the pattern's warps and picks. Without them the
//   largest thread index in [THREADING], and the largest pick index in [LIFTPLAN] (or [TREADLING]) are used.
// - [THREADING] (required) thread=shaft[,shaft...]; [TIEUP] treadle=shaft[,...]; [TREADLING]
//   pick=treadle[,...]; [LIFTPLAN] pick=shaft[,...]. Every index is a decimal integer from 1 to its
//   bound: the declared count (Shafts=, Treadles=, WARP/WEFT Threads=) or, for undeclared thread and
//   pick counts, 256. An index given twice in a section is an error, and so is a value given twice in one
//   entry ("3=2,2": refused, naming the line, not folded). A thread, pick or treadle with no entry, or an
//   empty value, has no shafts (never lifted).
// - At most 1024 sections, and at most 1024 entries in each section read.
//
// Drawdown: the shafts lifted at pick p are those of the [LIFTPLAN] line for p when the file has a
// liftplan (it is what the loom does, so it wins over any treadling also present), otherwise the union
// of the tie-ups of the treadles pressed at p. Warp thread w is on top at p (cell 1) when any of its
// shafts is lifted. With Rising Shed=false the marked shafts sink instead and every cell is inverted:
// a warp end is under when any of its shafts sinks, so an end on no shaft stays on top. WIF thread i and
// pick j become warp i-1 and pick j-1, without mirroring. The result always passes ValidatePattern.
std::string ParseWif(const std::string& text, WeavePattern* out);

// A draft's thread colours ([COLOR TABLE] with [COLOR PALETTE]'s Range, [WARP COLORS], [WEFT COLORS] and the
// [WARP] / [WEFT] Color= defaults): linear RGB, so a renderer can use them as diffuse albedo.
struct WifColors {
  // Colour WIF index i + 1 at table[i]: the table's values mapped from the palette's range to [0, 1] as sRGB, then
  // to linear. Up to the largest index [COLOR TABLE] lists; an index it skips is black there, and no thread has it.
  // Empty when the draft colours no thread.
  std::vector<std::array<double, 3>> table;
  std::vector<int> warp;  // per warp thread (the pattern's warps): its index into table, -1 when uncoloured
  std::vector<int> weft;  // per pick (the pattern's picks), likewise

  bool operator==(const WifColors&) const = default;
};

// ParseWif, and the draft's colours into *colors (left untouched on error; empty table, warp and weft when the
// draft colours no thread). With a null `colors` it is the two-argument ParseWif. The colour sections are then read
// as strictly as the weave's (checked line by line, keys and sections not repeated, at most 1024 entries each,
// errors "line N: reason"), with the same bounds:
// - [COLOR PALETTE] (optional): Entries= (1..256; the bound of colour indices, 256 when absent), Form= (RGB, the
//   only form WIF 1.1 defines, also when absent; anything else is refused), Range=lo,hi (decimal integers,
//   lo < hi; 0,255 when absent: Fiberworks writes 0,999).
// - [COLOR TABLE]: index=r,g,b, each value from lo to hi. A value v becomes (v - lo) / (hi - lo), read as sRGB and
//   made linear (imaging::SrgbToLinear).
// - [WARP] Color=, [WEFT] Color=: the colour index of every warp thread / pick without an entry of its own. WIF
//   writes "index"; "index,r,g,b" (written by some programs) is accepted, its r,g,b checked like a table entry's
//   and not used: the table defines the colour.
// - [WARP COLORS] thread=index, [WEFT COLORS] pick=index: one colour per thread, over the default; an entry
//   without a value leaves the default. Threads run from 1 to the pattern's warps and picks from 1 to its picks
//   (WARP / WEFT Threads= when declared, else the count found from the weave).
// - Every colour index a thread uses must be listed in [COLOR TABLE]; a Color= key or a thread colour section in a
//   draft without [COLOR TABLE] is an error at its line. A table that no thread uses gives no colours.
// - [CONTENTS] lists these sections like the others: one listed as present must exist.
std::string ParseWif(const std::string& text, WeavePattern* out, WifColors* colors);

}  // namespace loomlight::models::weave
