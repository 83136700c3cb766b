#include "server/models/weave/wif.h"

#include <algorithm>
#include <bitset>
#include <cctype>
#include <map>
#include <optional>
#include <string_view>
#include <vector>

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

// The sections this importer interprets; only these are checked line by line.
bool IsRead(const std::string& name) {
  static const char* const kRead[] = {"WIF",     "CONTENTS",  "WEAVING", "WARP",    "WEFT",
                                      "THREADING", "TREADLING", "TIEUP", "LIFTPLAN"};
  return std::find(std::begin(kRead), std::end(kRead), name) != std::end(kRead);
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

std::string Lex(std::string_view text, Sections* sections) {
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
      if (!inserted && IsRead(name)) return Repeated(n, "section [" + name + "]", it->second.line);
      if (sections->size() > kMaxSections)
        return LineError(n, "more than " + std::to_string(kMaxSections) + " sections");
      in_section = true;
      current = IsRead(name) ? &it->second : nullptr;
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
    if (std::string err = ParseIndex(e.key, keys, e.line, &key); !err.empty()) return err;
    if (first_line[key - 1])
      return Repeated(e.line, "[" + name + "] " + keys.what + " " + std::to_string(key), first_line[key - 1]);
    first_line[key - 1] = e.line;
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

}  // namespace

std::string ParseWif(const std::string& text, WeavePattern* out) {
  if (text.size() > kMaxWifBytes)
    return LineError(0, "WIF text of " + std::to_string(text.size()) + " bytes is over the limit of " +
                            std::to_string(kMaxWifBytes));
  Sections sections;
  Draft d;
  if (std::string err = Lex(text, &sections); !err.empty()) return err;
  if (std::string err = CheckHeader(sections); !err.empty()) return err;
  if (std::string err = ReadCounts(sections, &d); !err.empty()) return err;
  if (std::string err = ReadTables(sections, &d); !err.empty()) return err;
  // Undeclared counts: the largest index used (by the section that drives the drawdown, for picks).
  const int warps = d.warps.value_or(d.threading->max_key);
  const int picks = d.picks.value_or((d.liftplan ? d.liftplan : d.treadling)->max_key);
  if (warps == 0) return LineError(0, "no warp threads: no WARP Threads= and no [THREADING] entries");
  if (picks == 0) return LineError(0, "no picks: no WEFT Threads= and no treadling or liftplan entries");
  *out = Drawdown(d, warps, picks);
  return "";
}

}  // namespace loomlight::models::weave

namespace loomlight::models::weave {
// Placeholder until the colour sections are read (being written now).
std::string ParseWif(const std::string& text, WeavePattern* out, WifColors* colors) {
  std::string e = ParseWif(text, out);
  if (e.empty()) *colors = WifColors();
  return e;
}
}  // namespace loomlight::models::weave
