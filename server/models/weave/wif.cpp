#include "server/models/weave/wif.h"

#include <algorithm>
#include <bitset>
#include <cctype>
#include <map>
#include <optional>
#include <string_view>
#include <vector>

#include "server/imaging/srgb.h"
#include "server/models/quote.h"

namespace loomlight::models::weave {
namespace {

std::string LineError(int line, const std::string& reason) { return "line " + std::to_string(line) + ": " + reason; }

// A section, key or index given a second time at `line`.
std::string Repeated(int line, const std::string& what, int first_line) {
  return LineError(line, what + " repeated (first at line " + std::to_string(first_line) + ")");
}

std::string Upper(std::string_view s) {
  std::string u(s);
  for (char& c : u) c = char(std::toupper(static_cast<unsigned char>(c)));
  return u;
}

std::string_view Trim(std::string_view s) {
  const auto space = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
  while (!s.empty() && space(s.front())) s.remove_prefix(1);
  while (!s.empty() && space(s.back())) s.remove_suffix(1);
  return s;
}

// A plain decimal number: digits only, at most 9 so that it cannot overflow an int.
bool ParseNumber(std::string_view s, int* out) {
  if (s.empty() || s.size() > 9) return false;
  int v = 0;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
    v = v * 10 + (c - '0');
  }
  *out = v;
  return true;
}

// WIF booleans: true/false, yes/no, on/off, 1/0, in any case.
bool ParseBool(std::string_view s, bool* out) {
  const std::string u = Upper(s);
  if (u == "TRUE" || u == "YES" || u == "ON" || u == "1") return *out = true, true;
  if (u == "FALSE" || u == "NO" || u == "OFF" || u == "0") return *out = false, true;
  return false;
}

// ---- Lexing: text -> sections of key=value entries, each with its line ----
//
// What a parse holds is bounded by the text, never multiplied by it: entries are views into the text (no
// copies), a read section holds at most kMaxEntriesPerSection entries and a draft at most kMaxSections
// sections, and every index list is a set of at most kMaxRepeat values (kParseBytesPerTextByte below).

constexpr size_t kMaxSections = 1024;          // real drafts have a few dozen
constexpr size_t kMaxEntriesPerSection = 1024;  // an index section needs at most kMaxRepeat

struct Entry {
  std::string_view key;    // trimmed, as written (compared case-insensitively)
  std::string_view value;  // trimmed
  int line = 0;
};

struct Section {
  int line = 0;  // of the header
  std::vector<Entry> entries;
};

using Sections = std::map<std::string, Section>;  // by upper-case name

bool EqualsIgnoringCase(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::toupper(static_cast<unsigned char>(x)) == std::toupper(static_cast<unsigned char>(y));
         });
}

// The sections this importer interprets; only these are checked line by line. The colour sections only when
// the caller asks for colours, so that the weave alone reads drafts exactly as it did before colours were read.
bool IsRead(const std::string& name, bool colors) {
  static const char* const kRead[] = {"WIF",     "CONTENTS",  "WEAVING", "WARP",    "WEFT",
                                      "THREADING", "TREADLING", "TIEUP", "LIFTPLAN"};
  static const char* const kColors[] = {"COLOR PALETTE", "COLOR TABLE", "WARP COLORS", "WEFT COLORS"};
  return std::find(std::begin(kRead), std::end(kRead), name) != std::end(kRead) ||
         (colors && std::find(std::begin(kColors), std::end(kColors), name) != std::end(kColors));
}

// The next line of `*text` (ending at "\r\n", "\n" or "\r": WIF dates from DOS and classic Mac OS as well as
// Unix), removed from it; false at the end. Walked line by line so that no table of lines is held.
bool NextLine(std::string_view* text, std::string_view* line) {
  if (text->empty()) return false;
  const size_t end = text->find_first_of("\r\n");
  *line = text->substr(0, end);
  if (end == std::string_view::npos) {
    *text = {};
    return true;
  }
  const size_t next = end + ((*text)[end] == '\r' && end + 1 < text->size() && (*text)[end + 1] == '\n' ? 2 : 1);
  text->remove_prefix(next);
  return true;
}

std::string Lex(std::string_view text, bool colors, Sections* sections) {
  if (text.substr(0, 3) == "\xEF\xBB\xBF") text.remove_prefix(3);
  Section* current = nullptr;  // the section being read; null before the first header and in unread sections
  bool in_section = false;
  std::string_view line;
  for (int n = 1; NextLine(&text, &line); ++n) {
    line = Trim(line.substr(0, line.find(';')));
    if (line.empty()) continue;
    if (line.front() == '[') {
      if (line.back() != ']') return LineError(n, "section header must end with ']'");
      const std::string name = Upper(Trim(line.substr(1, line.size() - 2)));
      if (name.empty()) return LineError(n, "empty section name");
      const auto [it, inserted] = sections->insert({name, Section{n, {}}});
      const bool read = IsRead(name, colors);
      if (!inserted && read) return Repeated(n, "section [" + name + "]", it->second.line);
      if (sections->size() > kMaxSections)
        return LineError(n, "more than " + std::to_string(kMaxSections) + " sections");
      in_section = true;
      current = read ? &it->second : nullptr;
      continue;
    }
    if (!in_section) return LineError(n, "entry before the first [section] header");
    if (!current) continue;  // a section this importer does not read: free text allowed
    const size_t eq = line.find('=');
    if (eq == std::string_view::npos) return LineError(n, "expected key=value, found no '='");
    const std::string_view key = Trim(line.substr(0, eq));
    if (key.empty()) return LineError(n, "missing key before '='");
    if (current->entries.size() == kMaxEntriesPerSection)
      return LineError(n, "more than " + std::to_string(kMaxEntriesPerSection) + " entries in one section");
    current->entries.push_back({key, Trim(line.substr(eq + 1)), n});
  }
  return "";
}

// ---- Lookups ----

const Section* Find(const Sections& sections, const std::string& name) {
  const auto it = sections.find(name);
  return it == sections.end() ? nullptr : &it->second;
}

std::string Require(const Sections& sections, const std::string& name, const Section** out) {
  *out = Find(sections, name);
  return *out ? "" : LineError(0, "missing section [" + name + "]");
}

// The entry for `key` (display spelling, e.g. "Rising Shed") in section `name`, or nullptr when absent;
// a key given twice is an error at its second line.
std::string FindKey(const Section& s, const std::string& name, const std::string& key, const Entry** out) {
  *out = nullptr;
  for (const Entry& e : s.entries) {
    if (!EqualsIgnoringCase(e.key, key)) continue;
    if (*out) return Repeated(e.line, "[" + name + "] " + key + "=", (*out)->line);
    *out = &e;
  }
  return "";
}

// An integer key in [min, kMaxRepeat]; *out stays empty when the key is absent and not required.
std::string ReadCount(const Section& s, const std::string& name, const std::string& key, int min, bool required,
                      std::optional<int>* out) {
  const Entry* e = nullptr;
  if (std::string err = FindKey(s, name, key, &e); !err.empty()) return err;
  if (!e) return required ? LineError(s.line, "[" + name + "] has no " + key + "= key") : "";
  int v = 0;
  if (!ParseNumber(e->value, &v) || v < min || v > kMaxRepeat)
    return LineError(e->line, "[" + name + "] " + key + "=" + EchoToken(e->value) + " is not a number in " +
                                  std::to_string(min) + ".." + std::to_string(kMaxRepeat));
  *out = v;
  return "";
}

// ---- Index sections: "index=v1,v2,..." ----

// What an index may be (1..max) and how to name it in messages: "shaft", bound "WEAVING Shafts=4".
struct Range {
  std::string what;
  int max = 0;
  std::string bound;
};

// The range of an index whose count a key may declare (e.g. threads by WARP Threads=); undeclared
// counts are bounded by kMaxRepeat only, and found afterwards from the largest index used.
Range CountRange(const std::string& what, const std::optional<int>& declared, const std::string& key) {
  if (declared) return {what, *declared, key + "=" + std::to_string(*declared)};
  return {what, kMaxRepeat, "the limit of " + std::to_string(kMaxRepeat)};
}

std::string ParseIndex(std::string_view text, const Range& range, int line, int* out) {
  if (!ParseNumber(text, out)) return LineError(line, range.what + " " + Quote(text) + " is not a number");
  if (*out < 1 || *out > range.max)
    return LineError(line, range.what + " " + std::to_string(*out) + " out of range 1.." + std::to_string(range.max) +
                               " (" + range.bound + ")");
  return "";
}

// The index entry `e`'s key names, in `keys`; an index given twice in section `name` is an error at its second
// line (first_line[index - 1]: where it was first given, 0 if not yet).
std::string ParseKey(const Entry& e, const std::string& name, const Range& keys, std::vector<int>* first_line,
                     int* key) {
  if (std::string err = ParseIndex(e.key, keys, e.line, key); !err.empty()) return err;
  int& first = (*first_line)[*key - 1];
  if (first) return Repeated(e.line, "[" + name + "] " + keys.what + " " + std::to_string(*key), first);
  first = e.line;
  return "";
}

// A set of indices 1..kMaxRepeat (bit i for index i): what a thread is threaded on, a treadle ties up, a
// pick presses or lifts. A set, so that a list can never hold more than kMaxRepeat values.
using IndexSet = std::bitset<kMaxRepeat + 1>;

struct IndexTable {
  std::vector<IndexSet> rows;  // rows[index - 1]: the values of that index; empty if no entry
  int max_key = 0;             // largest index with an entry
};

// The one parser shared by [THREADING], [TIEUP], [TREADLING] and [LIFTPLAN]: each entry is a key in
// `keys` and a comma-separated (possibly empty) list of distinct values in `values`. A value listed twice
// in one entry is refused (a thread on shaft 2 "twice" is a broken draft, and a list then stays at most
// kMaxRepeat long).
std::string ParseIndexSection(const Section& s, const std::string& name, const Range& keys, const Range& values,
                              IndexTable* out) {
  out->rows.assign(keys.max, {});
  std::vector<int> first_line(keys.max, 0);
  for (const Entry& e : s.entries) {
    int key = 0;
    if (std::string err = ParseKey(e, name, keys, &first_line, &key); !err.empty()) return err;
    out->max_key = std::max(out->max_key, key);
    if (e.value.empty()) continue;  // listed without shafts: the same as no entry
    IndexSet& row = out->rows[key - 1];
    for (std::string_view rest = e.value;;) {
      const size_t comma = rest.find(',');
      int v = 0;
      if (std::string err = ParseIndex(Trim(rest.substr(0, comma)), values, e.line, &v); !err.empty()) return err;
      if (row.test(v))
        return LineError(e.line, "[" + name + "] " + keys.what + " " + std::to_string(key) + " lists " + values.what +
                                     " " + std::to_string(v) + " twice");
      row.set(v);
      if (comma == std::string_view::npos) break;
      rest.remove_prefix(comma + 1);
    }
  }
  return "";
}

// Parses index section `name` into *out when the file has it (*out stays empty otherwise).
std::string ReadTable(const Sections& sections, const std::string& name, const Range& keys, const Range& values,
                      std::optional<IndexTable>* out) {
  const Section* s = Find(sections, name);
  if (!s) return "";
  return ParseIndexSection(*s, name, keys, values, &out->emplace());
}

// ---- The draft ----

struct Draft {
  int shafts = 0;
  std::optional<int> treadles, warps, picks;  // as declared
  bool rising = true;
  std::optional<IndexTable> threading, tieup, treadling, liftplan;  // the sections present
};

// [WIF] version and the promises of [CONTENTS].
std::string CheckHeader(const Sections& sections) {
  const Section* wif = nullptr;
  const Section* contents = nullptr;
  if (std::string err = Require(sections, "WIF", &wif); !err.empty()) return err;
  const Entry* version = nullptr;
  if (std::string err = FindKey(*wif, "WIF", "Version", &version); !err.empty()) return err;
  if (!version) return LineError(wif->line, "[WIF] has no Version= key");
  if (version->value != "1" && version->value.rfind("1.", 0) != 0)
    return LineError(version->line, "WIF version " + EchoToken(version->value) + " is not supported (only 1.x)");
  if (std::string err = Require(sections, "CONTENTS", &contents); !err.empty()) return err;
  for (const Entry& e : contents->entries) {
    bool present = false;
    if (!ParseBool(e.value, &present)) return LineError(e.line, Quote(e.value) + " is not a boolean");
    if (present && !Find(sections, Upper(e.key)))
      return LineError(e.line, "listed in [CONTENTS], but the file has no [" + EchoToken(e.key) + "] section");
  }
  return "";
}

// [WEAVING], [WARP] and [WEFT]: the counts and the shed.
std::string ReadCounts(const Sections& sections, Draft* d) {
  const Section* weaving = nullptr;
  if (std::string err = Require(sections, "WEAVING", &weaving); !err.empty()) return err;
  std::optional<int> shafts;
  if (std::string err = ReadCount(*weaving, "WEAVING", "Shafts", 1, true, &shafts); !err.empty()) return err;
  d->shafts = *shafts;
  // Treadles matter only to a tie-up or treadling; a liftplan draft may leave them out.
  const bool uses_treadles = Find(sections, "TIEUP") || Find(sections, "TREADLING");
  if (std::string err = ReadCount(*weaving, "WEAVING", "Treadles", 0, uses_treadles, &d->treadles); !err.empty())
    return err;
  const Entry* shed = nullptr;
  if (std::string err = FindKey(*weaving, "WEAVING", "Rising Shed", &shed); !err.empty()) return err;
  if (shed && !ParseBool(shed->value, &d->rising))
    return LineError(shed->line, "Rising Shed=" + EchoToken(shed->value) + " is not a boolean");
  if (const Section* warp = Find(sections, "WARP"))
    if (std::string err = ReadCount(*warp, "WARP", "Threads", 1, false, &d->warps); !err.empty()) return err;
  if (const Section* weft = Find(sections, "WEFT"))
    if (std::string err = ReadCount(*weft, "WEFT", "Threads", 1, false, &d->picks); !err.empty()) return err;
  return "";
}

// The index sections, each bounded by the counts read before, and the check that the draft says which
// shafts rise at each pick.
std::string ReadTables(const Sections& sections, Draft* d) {
  const Range shafts{"shaft", d->shafts, "WEAVING Shafts=" + std::to_string(d->shafts)};
  const Range treadles = CountRange("treadle", d->treadles, "WEAVING Treadles");
  const Range threads = CountRange("thread", d->warps, "WARP Threads");
  const Range picks = CountRange("pick", d->picks, "WEFT Threads");
  if (std::string err = ReadTable(sections, "THREADING", threads, shafts, &d->threading); !err.empty()) return err;
  if (std::string err = ReadTable(sections, "TIEUP", treadles, shafts, &d->tieup); !err.empty()) return err;
  if (std::string err = ReadTable(sections, "TREADLING", picks, treadles, &d->treadling); !err.empty()) return err;
  if (std::string err = ReadTable(sections, "LIFTPLAN", picks, shafts, &d->liftplan); !err.empty()) return err;
  if (!d->threading) return LineError(0, "missing section [THREADING]");
  if (d->liftplan || (d->tieup && d->treadling)) return "";
  return LineError(0, d->tieup       ? "missing section [TREADLING] (or [LIFTPLAN])"
                      : d->treadling ? "missing section [TIEUP] (or [LIFTPLAN])"
                                     : "missing section [LIFTPLAN] (or [TREADLING] and [TIEUP])");
}

// The shafts lifted at each pick, indexed like the pick rows: the liftplan when there is one, else the
// union of the tie-ups of the treadles pressed (a union of sets: at most kMaxRepeat shafts, whatever the
// draft repeats).
std::vector<IndexSet> LiftedShafts(const Draft& d) {
  if (d.liftplan) return d.liftplan->rows;
  std::vector<IndexSet> lifts(d.treadling->rows.size());
  for (size_t p = 0; p < lifts.size(); ++p)
    for (size_t t = 1; t < d.tieup->rows.size() + 1; ++t)
      if (d.treadling->rows[p].test(t)) lifts[p] |= d.tieup->rows[t - 1];
  return lifts;
}

WeavePattern Drawdown(const Draft& d, int warps, int picks) {
  const std::vector<IndexSet> lifts = LiftedShafts(d);
  WeavePattern p{warps, picks, std::vector<uint8_t>(size_t(warps) * picks)};
  for (int pick = 0; pick < picks; ++pick)
    for (int warp = 0; warp < warps; ++warp) {
      const bool up = (d.threading->rows[warp] & lifts[pick]).any();
      p.cells[size_t(pick) * warps + warp] = up == d.rising ? 1 : 0;  // a sinking shed inverts the cell
    }
  return p;
}

// ---- Colours ----

using Rgb = std::array<double, 3>;

// [COLOR PALETTE]: the indices a colour may have (1..Entries) and the range its values are written in.
struct Palette {
  Range colors;
  int lo = 0, hi = 255;
  std::string range_key = "the default Range=0,255";  // how messages name the range
};

std::string ReadPalette(const Sections& sections, Palette* p) {
  std::optional<int> entries;
  if (const Section* s = Find(sections, "COLOR PALETTE")) {
    if (std::string err = ReadCount(*s, "COLOR PALETTE", "Entries", 1, false, &entries); !err.empty()) return err;
    const Entry* form = nullptr;
    if (std::string err = FindKey(*s, "COLOR PALETTE", "Form", &form); !err.empty()) return err;
    if (form && !EqualsIgnoringCase(form->value, "RGB"))
      return LineError(form->line, "[COLOR PALETTE] Form=" + EchoToken(form->value) + " is not supported (only RGB)");
    const Entry* range = nullptr;
    if (std::string err = FindKey(*s, "COLOR PALETTE", "Range", &range); !err.empty()) return err;
    if (range) {
      const size_t comma = range->value.find(',');
      if (comma == std::string_view::npos || !ParseNumber(Trim(range->value.substr(0, comma)), &p->lo) ||
          !ParseNumber(Trim(range->value.substr(comma + 1)), &p->hi) || p->lo >= p->hi)
        return LineError(range->line, "[COLOR PALETTE] Range=" + EchoToken(range->value) +
                                          " is not two numbers lo,hi with lo < hi");
      p->range_key = "COLOR PALETTE Range=" + std::to_string(p->lo) + "," + std::to_string(p->hi);
    }
  }
  p->colors = CountRange("colour", entries, "COLOR PALETTE Entries");
  return "";
}

// "r,g,b", each in the palette's range: mapped to [0, 1], read as sRGB and made linear. `what` names the
// value in messages.
std::string ParseRgb(std::string_view text, const Palette& p, const std::string& what, int line, Rgb* out) {
  Rgb rgb{};
  size_t n = 0;
  for (std::string_view rest = text;;) {
    if (n == rgb.size()) return LineError(line, what + " has more than 3 values (r,g,b)");
    const size_t comma = rest.find(',');
    const std::string_view item = Trim(rest.substr(0, comma));
    int v = 0;
    if (!ParseNumber(item, &v)) return LineError(line, what + " value " + Quote(item) + " is not a number");
    if (v < p.lo || v > p.hi)
      return LineError(line, what + " value " + std::to_string(v) + " out of range " + std::to_string(p.lo) + ".." +
                                 std::to_string(p.hi) + " (" + p.range_key + ")");
    rgb[n++] = imaging::SrgbToLinear(double(v - p.lo) / double(p.hi - p.lo));
    if (comma == std::string_view::npos) break;
    rest.remove_prefix(comma + 1);
  }
  if (n < rgb.size()) return LineError(line, what + " has " + std::to_string(n) + " value(s), expected 3 (r,g,b)");
  *out = rgb;
  return "";
}

struct ColorTable {
  std::vector<Rgb> linear;  // [index - 1], up to the largest index listed; black where an index is not listed
  IndexSet listed;          // the indices [COLOR TABLE] lists
};

std::string ReadColorTable(const Section& s, const Palette& p, ColorTable* out) {
  std::vector<int> first_line(p.colors.max, 0);
  for (const Entry& e : s.entries) {
    int index = 0;
    Rgb rgb;
    if (std::string err = ParseKey(e, "COLOR TABLE", p.colors, &first_line, &index); !err.empty()) return err;
    if (std::string err = ParseRgb(e.value, p, "[COLOR TABLE] colour " + std::to_string(index), e.line, &rgb);
        !err.empty())
      return err;
    if (out->linear.size() < size_t(index)) out->linear.resize(index, Rgb{0, 0, 0});
    out->linear[index - 1] = rgb;
    out->listed.set(index);
  }
  return "";
}

// A thread's colour index: in the palette's range and listed in [COLOR TABLE].
std::string ParseColorIndex(std::string_view text, const Palette& p, const ColorTable& table, int line, int* out) {
  if (std::string err = ParseIndex(text, p.colors, line, out); !err.empty()) return err;
  if (!table.listed.test(*out)) return LineError(line, "colour " + std::to_string(*out) + " is not in [COLOR TABLE]");
  return "";
}

// [WARP] or [WEFT] Color=: the colour of every thread without an entry of its own; 0 when absent. WIF writes an
// index; some programs add the colour's r,g,b after it, which are checked but not used (the table is the colour).
std::string ReadDefaultColor(const Sections& sections, const std::string& name, const Palette& p,
                             const ColorTable* table, int* out) {
  *out = 0;
  const Section* s = Find(sections, name);
  const Entry* color = nullptr;
  if (!s) return "";
  if (std::string err = FindKey(*s, name, "Color", &color); !err.empty()) return err;
  if (!color) return "";
  if (!table) return LineError(color->line, "[" + name + "] Color= names a colour, but the draft has no [COLOR TABLE]");
  const size_t comma = color->value.find(',');
  if (std::string err = ParseColorIndex(Trim(color->value.substr(0, comma)), p, *table, color->line, out); !err.empty())
    return err;
  Rgb unused;
  if (comma == std::string_view::npos) return "";
  return ParseRgb(color->value.substr(comma + 1), p, "[" + name + "] Color=", color->line, &unused);
}

// [WARP COLORS] or [WEFT COLORS]: thread=colour, over the default, into (*colors)[thread - 1] as an index into the
// table (from 0). An entry without a value leaves its thread the default.
std::string ReadThreadColors(const Sections& sections, const std::string& name, const Range& threads,
                             const Palette& p, const ColorTable* table, std::vector<int>* colors) {
  const Section* s = Find(sections, name);
  if (!s) return "";
  if (!table) return LineError(s->line, "[" + name + "] gives colours, but the draft has no [COLOR TABLE]");
  std::vector<int> first_line(threads.max, 0);
  for (const Entry& e : s->entries) {
    int thread = 0, color = 0;
    if (std::string err = ParseKey(e, name, threads, &first_line, &thread); !err.empty()) return err;
    if (e.value.empty()) continue;
    if (std::string err = ParseColorIndex(e.value, p, *table, e.line, &color); !err.empty()) return err;
    (*colors)[thread - 1] = color - 1;
  }
  return "";
}

// The draft's colours, read once its weave is: the thread colour sections are bounded by the pattern's `warps`
// and `picks`, however they were found.
std::string ReadColors(const Sections& sections, const Draft& d, int warps, int picks, WifColors* out) {
  Palette palette;
  if (std::string err = ReadPalette(sections, &palette); !err.empty()) return err;
  std::optional<ColorTable> table;
  if (const Section* s = Find(sections, "COLOR TABLE"))
    if (std::string err = ReadColorTable(*s, palette, &table.emplace()); !err.empty()) return err;
  const ColorTable* listed = table ? &*table : nullptr;
  int warp_default = 0, weft_default = 0;
  if (std::string err = ReadDefaultColor(sections, "WARP", palette, listed, &warp_default); !err.empty()) return err;
  if (std::string err = ReadDefaultColor(sections, "WEFT", palette, listed, &weft_default); !err.empty()) return err;
  std::vector<int> warp(warps, warp_default - 1), weft(picks, weft_default - 1);
  const Range threads = d.warps ? CountRange("thread", d.warps, "WARP Threads")
                                : Range{"thread", warps, "the threads of [THREADING]"};
  const Range pick_range =
      d.picks ? CountRange("pick", d.picks, "WEFT Threads")
              : Range{"pick", picks, d.liftplan ? "the picks of [LIFTPLAN]" : "the picks of [TREADLING]"};
  if (std::string err = ReadThreadColors(sections, "WARP COLORS", threads, palette, listed, &warp); !err.empty())
    return err;
  if (std::string err = ReadThreadColors(sections, "WEFT COLORS", pick_range, palette, listed, &weft); !err.empty())
    return err;
  const auto colored = [](const std::vector<int>& v) {
    return std::any_of(v.begin(), v.end(), [](int c) { return c >= 0; });
  };
  if (!colored(warp) && !colored(weft)) {
    *out = WifColors();
    return "";
  }
  *out = WifColors{std::move(table->linear), std::move(warp), std::move(weft)};
  return "";
}

}  // namespace

std::string ParseWif(const std::string& text, WeavePattern* out) { return ParseWif(text, out, nullptr); }

std::string ParseWif(const std::string& text, WeavePattern* out, WifColors* colors) {
  if (text.size() > kMaxWifBytes)
    return LineError(0, "WIF text of " + std::to_string(text.size()) + " bytes is over the limit of " +
                            std::to_string(kMaxWifBytes));
  Sections sections;
  Draft d;
  if (std::string err = Lex(text, colors != nullptr, &sections); !err.empty()) return err;
  if (std::string err = CheckHeader(sections); !err.empty()) return err;
  if (std::string err = ReadCounts(sections, &d); !err.empty()) return err;
  if (std::string err = ReadTables(sections, &d); !err.empty()) return err;
  // Undeclared counts: the largest index used (by the section that drives the drawdown, for picks).
  const int warps = d.warps.value_or(d.threading->max_key);
  const int picks = d.picks.value_or((d.liftplan ? d.liftplan : d.treadling)->max_key);
  if (warps == 0) return LineError(0, "no warp threads: no WARP Threads= and no [THREADING] entries");
  if (picks == 0) return LineError(0, "no picks: no WEFT Threads= and no treadling or liftplan entries");
  WifColors read;
  if (colors)
    if (std::string err = ReadColors(sections, d, warps, picks, &read); !err.empty()) return err;
  *out = Drawdown(d, warps, picks);
  if (colors) *colors = std::move(read);
  return "";
}

}  // namespace loomlight::models::weave
