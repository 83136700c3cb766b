// Weave patterns and WIF import: hand-written drafts against drawdowns worked out by hand, malformed
// drafts against the line that is wrong, float extraction and the standard-weave builders.
#include <gtest/gtest.h>

#include <malloc.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdlib>
#include <fstream>
#include <new>
#include <ostream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"
#include "server/models/weave/wif.h"

// ---- A counting allocator for this test binary: the heap in use, and its peak since the last reset ----

namespace {
std::atomic<size_t> heap_in_use{0};
std::atomic<size_t> heap_peak{0};

void* CountedAllocate(size_t n) {
  void* p = std::malloc(n ? n : 1);
  if (!p) throw std::bad_alloc();
  const size_t now = heap_in_use.fetch_add(malloc_usable_size(p)) + malloc_usable_size(p);
  for (size_t peak = heap_peak.load(); now > peak && !heap_peak.compare_exchange_weak(peak, now);) {
  }
  return p;
}
void CountedFree(void* p) {
  if (!p) return;
  heap_in_use.fetch_sub(malloc_usable_size(p));
  std::free(p);
}
}  // namespace

void* operator new(size_t n) { return CountedAllocate(n); }
void* operator new[](size_t n) { return CountedAllocate(n); }
void operator delete(void* p) noexcept { CountedFree(p); }
void operator delete[](void* p) noexcept { CountedFree(p); }
void operator delete(void* p, size_t) noexcept { CountedFree(p); }
void operator delete[](void* p, size_t) noexcept { CountedFree(p); }

namespace loomlight::models::weave {

// Readable failures (found by argument-dependent lookup, hence outside the anonymous namespace).
void PrintTo(const WeavePattern& p, std::ostream* os) { *os << "\n" << ToString(p); }
void PrintTo(const Float& f, std::ostream* os) { *os << "{" << ToString(f) << "}"; }

namespace {

// Parses a draft that must be valid.
WeavePattern Wif(const std::string& text) {
  WeavePattern p;
  const std::string err = ParseWif(text, &p);
  EXPECT_EQ(err, "") << text;
  return p;
}

WeavePattern Twill(int up, int down, TwillDirection direction) {
  WeavePattern p;
  EXPECT_EQ(MakeTwill(up, down, direction, &p), "");
  return p;
}

WeavePattern Satin(int ends, int move, SatinFace face) {
  WeavePattern p;
  EXPECT_EQ(MakeSatin(ends, move, face, &p), "");
  return p;
}

// Compares with the expected matrix, printing both in canonical form on failure.
void ExpectPattern(const WeavePattern& got, int warps, int picks, const std::vector<uint8_t>& cells) {
  const WeavePattern want{warps, picks, cells};
  EXPECT_EQ(got, want) << "got\n" << ToString(got) << "want\n" << ToString(want);
}

// Replaces the one occurrence of `from` (it must occur exactly once, so an edit cannot hit the wrong
// section).
std::string Edit(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "'" << from << "' not in the draft";
  EXPECT_EQ(text.find(from, at + 1), std::string::npos) << "'" << from << "' occurs twice";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// 1-based number of the line holding `marker`, counted the plain way (newlines before it).
int LineOf(const std::string& text, const std::string& marker) {
  const size_t at = text.find(marker);
  EXPECT_NE(at, std::string::npos) << "no marker";
  return 1 + int(std::count(text.begin(), text.begin() + std::min(at, text.size()), '\n'));
}

// Standard header sections; `contents` lists the sections the rest of the draft holds.
std::string Header(const std::string& contents) {
  return "[WIF]\nVersion=1.1\nDate=April 20, 1997\nDevelopers=loomlight\nSource Program=hand\n"
         "[CONTENTS]\n" + contents;
}

// ---- WIF drafts that import ----

// Plain weave, 2 shafts and 2 treadles: pick 1 presses treadle 1, which lifts shaft 1 carrying thread 1;
// pick 2 lifts shaft 2 carrying thread 2.
const std::string kPlainWif = Header("WEAVING=yes\nWARP=yes\nWEFT=yes\nTHREADING=yes\nTIEUP=yes\nTREADLING=yes\n") + R"(
[WEAVING]
Shafts=2
Treadles=2
Rising Shed=true
[WARP]
Threads=2
[WEFT]
Threads=2
[THREADING]
1=1
2=2
[TIEUP]
1=1
2=2
[TREADLING]
1=1
2=2
)";

TEST(WifTest, PlainWeave) {
  const WeavePattern p = Wif(kPlainWif);
  ExpectPattern(p, 2, 2,
                {1, 0,
                 0, 1});
  EXPECT_EQ(p, PlainWeave());
}

// 2/2 twill on 4 shafts, straight draw (thread i on shaft i), treadles 1..4 tied to shafts {1,2},
// {2,3}, {3,4}, {4,1} and pressed in order: at pick p threads p and p+1 are up.
const std::string kTwillWif =
    Header("WEAVING=true\nWARP=true\nWEFT=true\nTHREADING=true\nTIEUP=true\nTREADLING=true\n") + R"(
[WEAVING]
Shafts=4
Treadles=4
Rising Shed=true
[WARP]
Threads=4
[WEFT]
Threads=4
[THREADING]
1=1
2=2
3=3
4=4
[TIEUP]
1=1,2
2=2,3
3=3,4
4=4,1
[TREADLING]
1=1
2=2
3=3
4=4
)";

TEST(WifTest, TwillStraightDraw) {
  const WeavePattern p = Wif(kTwillWif);
  ExpectPattern(p, 4, 4,
                {1, 1, 0, 0,
                 0, 1, 1, 0,
                 0, 0, 1, 1,
                 1, 0, 0, 1});
  EXPECT_EQ(p, Twill(2, 2, TwillDirection::kRightward));
}

// Warp-faced 5-end satin, move 2: 5 shafts in straight draw; treadle t lifts every shaft but one, and
// the one left down steps by 2: treadle 1 leaves shaft 1, then 3, 5, 2, 4.
TEST(WifTest, FiveEndSatin) {
  const WeavePattern p = Wif(Header("WEAVING=1\nTHREADING=1\nTIEUP=1\nTREADLING=1\n") + R"(
[WEAVING]
Shafts=5
Treadles=5
[THREADING]
1=1
2=2
3=3
4=4
5=5
[TIEUP]
1=2,3,4,5
2=1,2,4,5
3=1,2,3,4
4=1,3,4,5
5=1,2,3,5
[TREADLING]
1=1
2=2
3=3
4=4
5=5
)");
  ExpectPattern(p, 5, 5,
                {0, 1, 1, 1, 1,
                 1, 1, 0, 1, 1,
                 1, 1, 1, 1, 0,
                 1, 0, 1, 1, 1,
                 1, 1, 1, 0, 1});
  EXPECT_EQ(p, Satin(5, 2, SatinFace::kWarpFaced));
}

// 2/1 twill from a liftplan (no treadles): 3 shafts in straight draw, picks lift {1,2}, {2,3}, {3,1}.
TEST(WifTest, Liftplan) {
  const WeavePattern p = Wif(Header("WEAVING=on\nTHREADING=on\nLIFTPLAN=on\n") + R"(
[WEAVING]
Shafts=3
[THREADING]
1=1
2=2
3=3
[LIFTPLAN]
1=1,2
2=2,3
3=3,1
)");
  ExpectPattern(p, 3, 3,
                {1, 1, 0,
                 0, 1, 1,
                 1, 0, 1});
  EXPECT_EQ(p, Twill(2, 1, TwillDirection::kRightward));
}

// When a draft has both, the liftplan (what the loom does) decides; here the treadling would give the
// 2/2 twill, the liftplan lifts shaft 1 only at pick 1, nothing at the other picks.
TEST(WifTest, LiftplanWinsOverTreadling) {
  const std::string text =
      Edit(kTwillWif, "TREADLING=true\n", "TREADLING=true\nLIFTPLAN=true\n") + "[LIFTPLAN]\n1=1\n";
  ExpectPattern(Wif(text), 4, 4,
                {1, 0, 0, 0,
                 0, 0, 0, 0,
                 0, 0, 0, 0,
                 0, 0, 0, 0});
}

// Sinking shed: the tie-up marks the shaft that goes down. Pick p presses treadle p, which sinks one
// shaft: 4, 1, 2, 3. The thread on that shaft goes under, the other three stay on top: a 3/1 twill.
const std::string kSinkingWif = Header("WEAVING=yes\nTHREADING=yes\nTIEUP=yes\nTREADLING=yes\n") + R"(
[WEAVING]
Shafts=4
Treadles=4
Rising Shed=no
[THREADING]
1=1
2=2
3=3
4=4
[TIEUP]
1=4
2=1
3=2
4=3
[TREADLING]
1=1
2=2
3=3
4=4
)";

TEST(WifTest, SinkingShed) {
  const WeavePattern p = Wif(kSinkingWif);
  ExpectPattern(p, 4, 4,
                {1, 1, 1, 0,
                 0, 1, 1, 1,
                 1, 0, 1, 1,
                 1, 1, 0, 1});
  EXPECT_EQ(p, Twill(3, 1, TwillDirection::kRightward));
  // The same draft woven with a rising shed is the exact inverse (a 1/3 twill).
  ExpectPattern(Wif(Edit(kSinkingWif, "Rising Shed=no", "Rising Shed=yes")), 4, 4,
                {0, 0, 0, 1,
                 1, 0, 0, 0,
                 0, 1, 0, 0,
                 0, 0, 1, 0});
}

// A thread on two shafts rises with either; a thread and a pick with no entry (within the declared
// counts) never lift; an entry with an empty value is the same as none.
TEST(WifTest, MultiShaftThreadsAndEmptyEntries) {
  const WeavePattern p = Wif(Header("WEAVING=yes\nWARP=yes\nWEFT=yes\nTHREADING=yes\nLIFTPLAN=yes\n") + R"(
[WEAVING]
Shafts=2
[WARP]
Threads=4
[WEFT]
Threads=3
[THREADING]
1=1
2=2
3=1,2
4=
[LIFTPLAN]
1=1
2=2
)");
  ExpectPattern(p, 4, 3,
                {1, 0, 1, 0,
                 0, 1, 1, 0,
                 0, 0, 0, 0});
}

// Without WARP/WEFT Threads= the counts are the largest thread and pick indices used.
TEST(WifTest, CountsFromLargestIndexWhenUndeclared) {
  std::string text = kTwillWif;
  text = Edit(text, "WARP=true\nWEFT=true\n", "");
  text = Edit(text, "[WARP]\nThreads=4\n[WEFT]\nThreads=4\n", "");
  text = Edit(text, "[TREADLING]\n1=1\n", "[TREADLING]\n6=1\n1=1\n");  // pick 5 has no entry
  ExpectPattern(Wif(text), 4, 6,
                {1, 1, 0, 0,
                 0, 1, 1, 0,
                 0, 0, 1, 1,
                 1, 0, 0, 1,
                 0, 0, 0, 0,
                 1, 1, 0, 0});
}

// The limits themselves are accepted: 256 threads declared, 256 shafts.
TEST(WifTest, CountsAtTheLimit) {
  std::string text = Edit(kPlainWif, "[WARP]\nThreads=2", "[WARP]\nThreads=256");
  text = Edit(text, "Shafts=2", "Shafts=256");
  const WeavePattern p = Wif(text);
  EXPECT_EQ(p.warps, 256);
  EXPECT_EQ(p.picks, 2);
  EXPECT_EQ(ValidatePattern(p), "");
}

// Case-insensitive names, comments, blank lines, spaces, CRLF line ends, a byte-order mark, sections
// that are not read (with free text, even lines without '='), and two treadles pressed at one pick.
TEST(WifTest, ForgivingSyntax) {
  std::string text = "\xEF\xBB\xBF; drafted by hand\n" +
                     Header("Weaving = True\nthreading=YES\ntieup=yes\nTreadling=yes\nText=yes\nNotes=yes\n") + R"(

[Text]
Title=Two treadles ; with a comment
[notes]
this line has no equals sign and is free text
[ weaving ]
  shafts = 2   ; two shafts
TREADLES=2
rising shed=On
[Threading]
1 = 1
2= 2
[TieUp]
1=1
2=2
[TREADLING]
1 = 1 , 2
2=2
)";
  std::string crlf;
  for (char c : text) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  const std::vector<uint8_t> want = {1, 1,
                                     0, 1};
  ExpectPattern(Wif(text), 2, 2, want);
  ExpectPattern(Wif(crlf), 2, 2, want);
}

// ---- Malformed drafts: each case edits the twill draft; the line that must be reported carries the
// comment "; <-- bad" (the parser ignores it as a comment), or the error is at line 0. ----

struct BadDraft {
  const char* name;
  std::vector<std::pair<std::string, std::string>> edits;  // applied in order
  bool at_marker;                                          // else line 0
  const char* reason;                                      // substring of the error
};

TEST(WifTest, MalformedDraftsReportTheLine) {
  const std::vector<BadDraft> cases = {
      {"unknown shaft in threading", {{"[THREADING]\n1=1\n", "[THREADING]\n1=5 ; <-- bad\n"}}, true,
       "shaft 5 out of range 1..4"},
      {"treadle beyond Treadles= in treadling", {{"[TREADLING]\n1=1\n", "[TREADLING]\n1=5 ; <-- bad\n"}}, true,
       "treadle 5 out of range 1..4"},
      {"treadle beyond Treadles= in tie-up", {{"4=4,1\n", "4=4,1\n5=1 ; <-- bad\n"}}, true,
       "treadle 5 out of range 1..4"},
      {"thread beyond WARP Threads=", {{"4=4\n[TIEUP]", "4=4\n5=1 ; <-- bad\n[TIEUP]"}}, true,
       "thread 5 out of range 1..4 (WARP Threads=4)"},
      {"pick beyond WEFT Threads=", {{"[TREADLING]\n", "[TREADLING]\n9=1 ; <-- bad\n"}}, true,
       "pick 9 out of range 1..4 (WEFT Threads=4)"},
      {"shaft 0", {{"[THREADING]\n1=1\n", "[THREADING]\n1=0 ; <-- bad\n"}}, true, "shaft 0 out of range"},
      {"non-numeric value", {{"[THREADING]\n1=1\n2=2\n", "[THREADING]\n1=1\n2=two ; <-- bad\n"}}, true,
       "'two' is not a number"},
      {"non-numeric item in a list", {{"2=2,3\n", "2=2,x3 ; <-- bad\n"}}, true, "'x3' is not a number"},
      {"empty item in a list", {{"1=1,2\n", "1=1,,2 ; <-- bad\n"}}, true, "'' is not a number"},
      {"negative index", {{"[THREADING]\n1=1\n", "[THREADING]\n-1=1 ; <-- bad\n"}}, true,
       "'-1' is not a number"},
      {"line without '='", {{"[THREADING]\n1=1\n", "[THREADING]\n1 1 ; <-- bad\n"}}, true, "no '='"},
      {"index given twice", {{"[THREADING]\n1=1\n", "[THREADING]\n1=1\n1=2 ; <-- bad\n"}}, true,
       "thread 1 repeated"},
      {"shaft listed twice in a tie-up", {{"2=2,3\n", "2=2,3,2 ; <-- bad\n"}}, true, "treadle 2 lists shaft 2 twice"},
      {"treadle pressed twice at a pick", {{"[TREADLING]\n1=1\n", "[TREADLING]\n1=1, 1 ; <-- bad\n"}}, true,
       "pick 1 lists treadle 1 twice"},
      {"[THREADING] listed but missing",
       {{"THREADING=true\n", "THREADING=true ; <-- bad\n"}, {"[THREADING]\n1=1\n2=2\n3=3\n4=4\n", ""}}, true,
       "no [THREADING] section"},
      {"[THREADING] missing, not listed",
       {{"THREADING=true\n", ""}, {"[THREADING]\n1=1\n2=2\n3=3\n4=4\n", ""}}, false,
       "missing section [THREADING]"},
      {"[TIEUP] missing, not listed", {{"TIEUP=true\n", ""}, {"[TIEUP]\n1=1,2\n2=2,3\n3=3,4\n4=4,1\n", ""}},
       false, "missing section [TIEUP]"},
      {"[WIF] missing", {{"[WIF]\nVersion=1.1\nDate=April 20, 1997\nDevelopers=loomlight\nSource Program=hand\n", ""}},
       false, "missing section [WIF]"},
      {"Shafts= missing", {{"[WEAVING]\n", "[WEAVING] ; <-- bad\n"}, {"Shafts=4\n", ""}}, true, "no Shafts= key"},
      {"Treadles= missing with a tie-up", {{"[WEAVING]\n", "[WEAVING] ; <-- bad\n"}, {"Treadles=4\n", ""}}, true,
       "no Treadles= key"},
      {"Shafts= over the limit", {{"Shafts=4", "Shafts=300 ; <-- bad"}}, true, "Shafts=300 is not a number in 1..256"},
      {"Treadles= over the limit", {{"Treadles=4", "Treadles=257 ; <-- bad"}}, true, "Treadles=257"},
      {"WARP Threads= over the limit", {{"[WARP]\nThreads=4", "[WARP]\nThreads=257 ; <-- bad"}}, true,
       "Threads=257 is not a number in 1..256"},
      {"undeclared thread count over the limit",
       {{"WARP=true\n", ""}, {"[WARP]\nThreads=4\n", ""}, {"4=4\n[TIEUP]", "4=4\n300=1 ; <-- bad\n[TIEUP]"}}, true,
       "thread 300 out of range 1..256"},
      {"Rising Shed= not a boolean", {{"Rising Shed=true", "Rising Shed=maybe ; <-- bad"}}, true,
       "not a boolean"},
      {"[CONTENTS] value not a boolean", {{"WEFT=true", "WEFT=perhaps ; <-- bad"}}, true, "not a boolean"},
      {"unsupported version", {{"Version=1.1", "Version=2.0 ; <-- bad"}}, true, "version 2.0"},
      {"section repeated", {{"[TIEUP]\n", "[THREADING] ; <-- bad\n1=1\n[TIEUP]\n"}}, true, "repeated"},
      {"entry before any section", {{"[WIF]\n", "Shafts=4 ; <-- bad\n[WIF]\n"}}, true, "before the first"},
      {"header without ']'", {{"[WEAVING]", "[WEAVING ; <-- bad"}}, true, "must end with ']'"},
  };
  for (const BadDraft& c : cases) {
    SCOPED_TRACE(c.name);
    std::string text = kTwillWif;
    for (const auto& [from, to] : c.edits) text = Edit(text, from, to);
    const int line = c.at_marker ? LineOf(text, "<-- bad") : 0;
    WeavePattern p{1, 1, {1}};
    const std::string err = ParseWif(text, &p);
    EXPECT_EQ(err.rfind("line " + std::to_string(line) + ": ", 0), 0u) << err;
    EXPECT_NE(err.find(c.reason), std::string::npos) << err;
    EXPECT_EQ(p, (WeavePattern{1, 1, {1}})) << "output touched on error";
  }
}

TEST(WifTest, TextOverOneMebibyteIsRejected) {
  std::string text = kTwillWif;
  text += ";" + std::string(kMaxWifBytes - text.size() - 2, 'x') + "\n";  // exactly at the limit: fine
  ASSERT_EQ(text.size(), kMaxWifBytes);
  Wif(text);
  WeavePattern p;
  const std::string err = ParseWif(text + " ", &p);
  EXPECT_EQ(err.rfind("line 0: ", 0), 0u) << err;
}

// ---- Patterns and floats ----

TEST(PatternTest, Validation) {
  EXPECT_EQ(ValidatePattern(PlainWeave()), "");
  EXPECT_EQ(ValidatePattern({1, 1, {1}}), "");                      // never interlaces: allowed
  EXPECT_EQ(ValidatePattern({2, 3, {1, 0, 1, 0, 1, 0}}), "");        // likewise, both threads
  EXPECT_EQ(ValidatePattern({256, 256, std::vector<uint8_t>(65536)}), "");
  EXPECT_NE(ValidatePattern({}), "");
  EXPECT_NE(ValidatePattern({0, 2, {}}), "");
  EXPECT_NE(ValidatePattern({257, 1, std::vector<uint8_t>(257)}), "");
  EXPECT_NE(ValidatePattern({1, 257, std::vector<uint8_t>(257)}), "");
  EXPECT_NE(ValidatePattern({2, 2, {1, 0, 0}}), "");
  EXPECT_NE(ValidatePattern({2, 2, {1, 0, 2, 1}}).find("cell (warp 0, pick 1) is 2"), std::string::npos);
}

TEST(PatternTest, CanonicalString) {
  EXPECT_EQ(ToString(Twill(3, 1, TwillDirection::kRightward)), "warps=4 picks=4\n1110\n0111\n1011\n1101\n");
  EXPECT_EQ(ToString(Float{true, 0, 2, 3}), "warp float at warp 0, pick 2, length 3");
  EXPECT_EQ(ToString(Float{false, 3, 1, 1}), "weft float at warp 3, pick 1, length 1");
}

TEST(FloatTest, PlainWeaveHasFourUnitFloats) {
  const std::vector<Float> want = {
      {true, 0, 0, 1}, {true, 1, 1, 1},    // warp 0 up at pick 0, warp 1 at pick 1
      {false, 1, 0, 1}, {false, 0, 1, 1},  // weft 0 over warp 1, weft 1 over warp 0
  };
  EXPECT_EQ(ExtractFloats(PlainWeave()), want);
}

TEST(FloatTest, Twill31) {
  // Rows 1110 / 0111 / 1011 / 1101 (see CanonicalString): warp 0 is 1,0,1,1 down its column, so its float
  // starts at pick 2 and wraps over the edge to pick 0.
  const std::vector<Float> want = {
      {true, 0, 2, 3},  {true, 1, 3, 3},  {true, 2, 0, 3},  {true, 3, 1, 3},
      {false, 3, 0, 1}, {false, 0, 1, 1}, {false, 1, 2, 1}, {false, 2, 3, 1},
  };
  EXPECT_EQ(ExtractFloats(Twill(3, 1, TwillDirection::kRightward)), want);
}

TEST(FloatTest, WrapAroundRunsCountedOnce) {
  // Every thread has one float of 2 cells; warp 0's crosses the top/bottom edge, pick 2's the left/right.
  const WeavePattern p{4, 4,
                       {1, 0, 0, 1,
                        0, 0, 1, 1,
                        0, 1, 1, 0,
                        1, 1, 0, 0}};
  const std::vector<Float> want = {
      {true, 0, 3, 2},  {true, 1, 2, 2},  {true, 2, 1, 2},  {true, 3, 0, 2},
      {false, 1, 0, 2}, {false, 0, 1, 2}, {false, 3, 2, 2}, {false, 2, 3, 2},
  };
  EXPECT_EQ(ExtractFloats(p), want);
}

TEST(FloatTest, ThreadOnTopThroughoutIsOneClosedFloat) {
  // Warp 0 is always up, warp 1 always down: one warp float of the full 3 picks starting at pick 0, and
  // one unit weft float per pick over warp 1.
  const std::vector<Float> columns = {
      {true, 0, 0, 3}, {false, 1, 0, 1}, {false, 1, 1, 1}, {false, 1, 2, 1}};
  EXPECT_EQ(ExtractFloats({2, 3, {1, 0,
                                  1, 0,
                                  1, 0}}),
            columns);
  // Pick 0 is all weft: one weft float of the full 3 warps starting at warp 0.
  const std::vector<Float> rows = {{true, 0, 1, 1}, {true, 2, 1, 1}, {false, 0, 0, 3}, {false, 1, 1, 1}};
  EXPECT_EQ(ExtractFloats({3, 2, {0, 0, 0,
                                  1, 0, 1}}),
            rows);
  EXPECT_EQ(ExtractFloats({1, 1, {1}}), (std::vector<Float>{{true, 0, 0, 1}}));
}

// Float lengths of every float, warp then weft, sorted within each kind.
std::pair<std::vector<int>, std::vector<int>> Lengths(const WeavePattern& p) {
  std::pair<std::vector<int>, std::vector<int>> l;
  for (const Float& f : ExtractFloats(p)) (f.warp ? l.first : l.second).push_back(f.length);
  std::sort(l.first.begin(), l.first.end());
  std::sort(l.second.begin(), l.second.end());
  return l;
}

TEST(FloatTest, SatinFloatLengths) {
  using V = std::vector<int>;
  EXPECT_EQ(Lengths(Satin(5, 2, SatinFace::kWarpFaced)), std::make_pair(V{4, 4, 4, 4, 4}, V{1, 1, 1, 1, 1}));
  EXPECT_EQ(Lengths(Satin(5, 3, SatinFace::kWeftFaced)), std::make_pair(V{1, 1, 1, 1, 1}, V{4, 4, 4, 4, 4}));
  EXPECT_EQ(Lengths(Satin(8, 3, SatinFace::kWarpFaced)), std::make_pair(V(8, 7), V(8, 1)));
  EXPECT_EQ(Lengths(Twill(2, 2, TwillDirection::kLeftward)), std::make_pair(V(4, 2), V(4, 2)));
}

TEST(FloatTest, LengthsCoverTheRepeat) {
  for (const WeavePattern& p : {PlainWeave(), Twill(3, 1, TwillDirection::kLeftward),
                                Satin(7, 3, SatinFace::kWeftFaced), Wif(kSinkingWif)}) {
    int warp = 0, weft = 0;
    for (const Float& f : ExtractFloats(p)) (f.warp ? warp : weft) += f.length;
    const AreaFractions a = ComputeAreaFractions(p);
    EXPECT_DOUBLE_EQ(a.warp, double(warp) / (p.warps * p.picks)) << ToString(p);
    EXPECT_DOUBLE_EQ(a.weft, double(weft) / (p.warps * p.picks)) << ToString(p);
  }
}

TEST(PatternTest, AreaFractions) {
  const auto expect = [](const WeavePattern& p, double warp) {
    const AreaFractions a = ComputeAreaFractions(p);
    EXPECT_DOUBLE_EQ(a.warp, warp) << ToString(p);
    EXPECT_DOUBLE_EQ(a.weft, 1 - warp) << ToString(p);
  };
  expect(PlainWeave(), 0.5);
  expect(Twill(2, 2, TwillDirection::kRightward), 0.5);
  expect(Twill(3, 1, TwillDirection::kRightward), 0.75);
  expect(Twill(1, 3, TwillDirection::kLeftward), 0.25);
  expect(Satin(5, 2, SatinFace::kWarpFaced), 0.8);
  expect(Satin(5, 2, SatinFace::kWeftFaced), 0.2);
  expect({2, 3, {1, 0, 1, 0, 1, 0}}, 0.5);
}

// ---- Builders ----

TEST(BuilderTest, Twills) {
  ExpectPattern(PlainWeave(), 2, 2,
                {1, 0,
                 0, 1});
  // 3/1 moving right: warps 0-2 up at pick 0, then 1-3, 2-0, 3-1.
  ExpectPattern(Twill(3, 1, TwillDirection::kRightward), 4, 4,
                {1, 1, 1, 0,
                 0, 1, 1, 1,
                 1, 0, 1, 1,
                 1, 1, 0, 1});
  // 1/3 moving left: warp 0 up at pick 0, then warp 3, 2, 1.
  ExpectPattern(Twill(1, 3, TwillDirection::kLeftward), 4, 4,
                {1, 0, 0, 0,
                 0, 0, 0, 1,
                 0, 0, 1, 0,
                 0, 1, 0, 0});
  EXPECT_EQ(Twill(1, 1, TwillDirection::kLeftward), PlainWeave());
}

TEST(BuilderTest, Satins) {
  // Weft-faced 5-end satin, move 3: the warp on top at pick p is 3p mod 5: 0, 3, 1, 4, 2.
  ExpectPattern(Satin(5, 3, SatinFace::kWeftFaced), 5, 5,
                {1, 0, 0, 0, 0,
                 0, 0, 0, 1, 0,
                 0, 1, 0, 0, 0,
                 0, 0, 0, 0, 1,
                 0, 0, 1, 0, 0});
  // Every satin has exactly one interlacing per row and per column.
  const WeavePattern s = Satin(8, 3, SatinFace::kWeftFaced);
  for (int i = 0; i < 8; ++i) {
    int row = 0, column = 0;
    for (int j = 0; j < 8; ++j) row += s.at(j, i), column += s.at(i, j);
    EXPECT_EQ(row, 1);
    EXPECT_EQ(column, 1);
  }
}

TEST(BuilderTest, RejectsBadArguments) {
  WeavePattern p{1, 1, {1}};
  EXPECT_NE(MakeTwill(0, 1, TwillDirection::kRightward, &p), "");
  EXPECT_NE(MakeTwill(2, 0, TwillDirection::kRightward, &p), "");
  EXPECT_NE(MakeTwill(200, 57, TwillDirection::kRightward, &p), "");
  EXPECT_EQ(MakeTwill(200, 56, TwillDirection::kRightward, &p), "");
  p = {1, 1, {1}};
  EXPECT_NE(MakeSatin(4, 1, SatinFace::kWarpFaced, &p), "");   // too few ends
  EXPECT_NE(MakeSatin(5, 1, SatinFace::kWarpFaced, &p), "");   // move 1: a twill
  EXPECT_NE(MakeSatin(5, 4, SatinFace::kWarpFaced, &p), "");   // move ends - 1: a twill
  EXPECT_NE(MakeSatin(6, 2, SatinFace::kWarpFaced, &p), "");   // shares a factor
  EXPECT_NE(MakeSatin(10, 5, SatinFace::kWarpFaced, &p), "");  // shares a factor
  EXPECT_NE(MakeSatin(257, 2, SatinFace::kWarpFaced, &p), "");
  EXPECT_EQ(p, (WeavePattern{1, 1, {1}})) << "output touched on error";
}

// ---- Client text echoed only truncated: 100 KB in every value, key or name a message shows ----

TEST(WifTest, LongValuesAreEchoedCutWithTheirSize) {
  const std::string junk = std::string(100000, 'x') + "\x01";
  const std::string size = "(" + std::to_string(junk.size()) + " bytes)";
  const std::vector<BadDraft> cases = {
      {"Shafts=", {{"Shafts=4", "Shafts=" + junk + " ; <-- bad"}}, true, "[WEAVING] Shafts='xxx"},
      {"WARP Threads=", {{"[WARP]\nThreads=4", "[WARP]\nThreads=" + junk + " ; <-- bad"}}, true, "[WARP] Threads='xxx"},
      {"Rising Shed=", {{"Rising Shed=true", "Rising Shed=" + junk + " ; <-- bad"}}, true, "Rising Shed='xxx"},
      {"Version=", {{"Version=1.1", "Version=" + junk + " ; <-- bad"}}, true, "WIF version 'xxx"},
      {"[CONTENTS] value", {{"WEFT=true", "WEFT=" + junk + " ; <-- bad"}}, true, "'xxx"},
      {"[CONTENTS] key", {{"WEFT=true", "WEFT=true\n" + junk + "=true ; <-- bad"}}, true, "the file has no ['xxx"},
      {"index key", {{"[THREADING]\n1=1\n", "[THREADING]\n" + junk + "=1 ; <-- bad\n"}}, true, "thread 'xxx"},
      {"index value", {{"[THREADING]\n1=1\n", "[THREADING]\n1=1," + junk + " ; <-- bad\n"}}, true, "shaft 'xxx"},
  };
  for (const BadDraft& c : cases) {
    SCOPED_TRACE(c.name);
    std::string text = kTwillWif;
    for (const auto& [from, to] : c.edits) text = Edit(text, from, to);
    WeavePattern p;
    const std::string err = ParseWif(text, &p);
    const std::string prefix = "line " + std::to_string(LineOf(text, "<-- bad")) + ": ";
    EXPECT_EQ(err.rfind(prefix, 0), 0u) << err.substr(0, 300);
    EXPECT_NE(err.find(c.reason), std::string::npos) << err.substr(0, 300);
    EXPECT_NE(err.find(size), std::string::npos) << err.substr(0, 300);
    EXPECT_LT(err.size(), 400u) << err.substr(0, 300);
    EXPECT_EQ(err.find('\x01'), std::string::npos) << "control byte echoed raw";
  }
}

// ---- What a parse may cost (issue 44): drafts built to multiply memory ----

// A draft with `treadles` treadles on `shafts` shafts: tie-up row t lists `tieup_list`, every one of `picks`
// picks presses `pressed_list`.
std::string TreadlingDraft(int shafts, int treadles, int picks, const std::string& tieup_list,
                           const std::string& pressed_list) {
  std::string text = Header("WEAVING=yes\nTHREADING=yes\nTIEUP=yes\nTREADLING=yes\n") + "[WEAVING]\nShafts=" +
                     std::to_string(shafts) + "\nTreadles=" + std::to_string(treadles) + "\n[THREADING]\n";
  for (int w = 1; w <= kMaxRepeat; ++w) text += std::to_string(w) + "=" + std::to_string(1 + (w - 1) % shafts) + "\n";
  text += "[TIEUP]\n";
  for (int t = 1; t <= treadles; ++t) text += std::to_string(t) + "=" + tieup_list + "\n";
  text += "[TREADLING]\n";
  for (int p = 1; p <= picks; ++p) text += std::to_string(p) + "=" + pressed_list + "\n";
  return text;
}

// "1,2,...,n" or "k,k,...,k" (n times).
std::string Sequence(int n) {
  std::string s;
  for (int i = 1; i <= n; ++i) {
    if (i > 1) s += ',';
    s += std::to_string(i);
  }
  return s;
}
std::string Repeat(const std::string& item, size_t n) {
  std::string s;
  for (size_t i = 0; i < n; ++i) {
    if (i) s += ',';
    s += item;
  }
  return s;
}

// The heap ParseWif holds at its peak, from the counting allocator at the top of this file.
size_t PeakHeapOfParse(const std::string& text, std::string* error) {
  WeavePattern pattern;
  const size_t before = ::heap_in_use.load();
  ::heap_peak = before;
  *error = ParseWif(text, &pattern);
  return ::heap_peak.load() - before;
}

// The attack: a tie-up row repeating one shaft tens of thousands of times and picks pressing one treadle as
// often made each pick append every pressed treadle's whole row (gigabytes from a draft under the 1 MiB
// limit). Repeats are refused at the first repeated value, and the parse holds at most WifParseBytes.
TEST(WifCostTest, RepeatedIndicesAreRefusedAndCannotMultiplyMemory) {
  const std::string tieup = Repeat("1", 100000), pressed = Repeat("1", 1400);
  const std::string text = TreadlingDraft(4, 1, 256, tieup, pressed);
  ASSERT_LE(text.size(), kMaxWifBytes);
  ASSERT_GT(text.size(), kMaxWifBytes * 3 / 4);
  std::string error;
  const size_t peak = PeakHeapOfParse(text, &error);
  const int tieup_line = LineOf(text, "[TIEUP]") + 1;
  EXPECT_EQ(error.rfind("line " + std::to_string(tieup_line) + ": [TIEUP] treadle 1 lists shaft 1 twice", 0), 0u)
      << error.substr(0, 300);
  EXPECT_LE(peak, WifParseBytes(text.size())) << "bytes held at the peak of a " << text.size() << "-byte parse";

  // The treadling's repeats alone, with a tie-up that is fine.
  const std::string treadling_only = TreadlingDraft(4, 1, 256, "1", pressed);
  const size_t peak2 = PeakHeapOfParse(treadling_only, &error);
  EXPECT_NE(error.find("[TREADLING] pick 1 lists treadle 1 twice"), std::string::npos) << error.substr(0, 300);
  EXPECT_LE(peak2, WifParseBytes(treadling_only.size()));
}

// The largest draft the format allows without repeats: 256 treadles each tied to all 256 shafts and 256
// picks each pressing all 256 treadles. Lifted shafts are a set (256 at most), so this is cheap, and every
// warp end is up at every pick.
TEST(WifCostTest, EveryTreadlePressedAtEveryPickIsASetUnion) {
  const std::string text = TreadlingDraft(kMaxRepeat, kMaxRepeat, kMaxRepeat, Sequence(kMaxRepeat), Sequence(kMaxRepeat));
  std::string error;
  const size_t peak = PeakHeapOfParse(text, &error);
  EXPECT_EQ(error, "");
  EXPECT_LE(peak, WifParseBytes(text.size()));
  const WeavePattern p = Wif(text);
  EXPECT_EQ(p.warps, kMaxRepeat);
  EXPECT_EQ(p.picks, kMaxRepeat);
  EXPECT_EQ(std::count(p.cells.begin(), p.cells.end(), 1), kMaxRepeat * kMaxRepeat);
}

// Sections and entries are counted as they are read, so neither a flood of section headers nor of entries
// in one section is held.
TEST(WifCostTest, SectionAndEntryFloodsAreRefusedWhereTheyPassTheLimit) {
  std::string sections = kTwillWif;
  for (int i = 0; i < 5000; ++i) sections += "[Private" + std::to_string(i) + "]\n";
  std::string error;
  const size_t peak = PeakHeapOfParse(sections, &error);
  EXPECT_NE(error.find("more than 1024 sections"), std::string::npos) << error;
  EXPECT_LE(peak, WifParseBytes(sections.size()));

  std::string entries = Edit(kTwillWif, "[WIF]\n", "[WIF]\n; flood below\n");
  std::string flood;
  for (int i = 0; i < 200000; ++i) flood += "k=\n";
  entries = Edit(entries, "; flood below\n", flood);
  ASSERT_LE(entries.size(), kMaxWifBytes);
  const size_t peak2 = PeakHeapOfParse(entries, &error);
  const int line = LineOf(entries, "[WIF]") + 1025;  // the 1025th entry of [WIF] (Version= is after the flood)
  EXPECT_EQ(error.rfind("line " + std::to_string(line) + ": more than 1024 entries in one section", 0), 0u) << error;
  EXPECT_LE(peak2, WifParseBytes(entries.size()));
  // Unread sections hold no entries: free text of any length is skipped.
  std::string notes = kTwillWif + "[NOTES]\n";
  for (int i = 0; i < 200000; ++i) notes += "n=\n";
  EXPECT_LE(PeakHeapOfParse(notes, &error), WifParseBytes(notes.size()));
  EXPECT_EQ(error, "");
}

// ---- WIF colours (issue 47): expected values worked out apart from the parser (the sRGB curve in Python) ----

void PrintTo(const WifColors& c, std::ostream* os) {
  *os << "\n  table:";
  for (const auto& rgb : c.table) *os << " (" << rgb[0] << ", " << rgb[1] << ", " << rgb[2] << ")";
  *os << "\n  warp:";
  for (int i : c.warp) *os << " " << i;
  *os << "\n  weft:";
  for (int i : c.weft) *os << " " << i;
}

// Parses a draft that must be valid, with its colours.
WifColors Colors(const std::string& text, WeavePattern* pattern = nullptr) {
  WeavePattern p;
  WifColors colors;
  EXPECT_EQ(ParseWif(text, &p, &colors), "") << text;
  if (pattern) *pattern = p;
  return colors;
}

void ExpectRgb(const std::array<double, 3>& got, const std::array<double, 3>& want) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], want[c], 1e-12) << "channel " << c;
}

std::string Fixture(const std::string& name) {
  std::ifstream in(std::string(LOOMLIGHT_SOURCE_DIR) + "/tests/data/wif/" + name, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_FALSE(text.str().empty()) << name;
  return text.str();
}

// The twill draft coloured: white the warp's default, warp thread 3 dark red, picks 2 and 4 blue; the weft has no
// default, so picks 1 and 3 are uncoloured. Values chosen for the sRGB curve: 0, 255, 128 and 10 (below the
// curve's linear segment, which ends at 0.04045 * 255 = 10.3).
const std::string kColorWif =
    Edit(kTwillWif, "[WARP]\nThreads=4\n", "[WARP]\nThreads=4\nColor=1\n") + R"([COLOR PALETTE]
Entries=3
Form=RGB
Range=0,255
[COLOR TABLE]
1=255,255,255
2=128,0,0
3=0,10,255
[WARP COLORS]
3=2
[WEFT COLORS]
2=3
4=3
)";

// sRGB 128/255 -> ((128/255 + 0.055) / 1.055)^2.4, 10/255 -> 10/255 / 12.92.
constexpr double kLinear128 = 0.21586050011389926, kLinear10 = 0.003035269835488375;

TEST(WifColorTest, TableIsLinearAndPerThreadColorsOverrideTheDefault) {
  WeavePattern p;
  const WifColors c = Colors(kColorWif, &p);
  EXPECT_EQ(p, Twill(2, 2, TwillDirection::kRightward)) << "colours change nothing in the weave";
  ASSERT_EQ(c.table.size(), 3u);
  ExpectRgb(c.table[0], {1, 1, 1});
  ExpectRgb(c.table[1], {kLinear128, 0, 0});
  ExpectRgb(c.table[2], {0, kLinear10, 1});
  EXPECT_EQ(c.warp, (std::vector<int>{0, 0, 1, 0}));
  EXPECT_EQ(c.weft, (std::vector<int>{-1, 2, -1, 2}));
}

TEST(WifColorTest, WithoutAPaletteTheRangeIs0To255) {
  std::string text = kColorWif;
  text = Edit(text, "[COLOR PALETTE]\nEntries=3\nForm=RGB\nRange=0,255\n", "");
  const WifColors c = Colors(text);
  EXPECT_EQ(c, Colors(kColorWif));
  ASSERT_EQ(c.table.size(), 3u);
  ExpectRgb(c.table[1], {kLinear128, 0, 0});
  // A palette without Range= and Form= (Form=RGB is the only one): the same.
  EXPECT_EQ(Colors(Edit(kColorWif, "Form=RGB\nRange=0,255\n", "")), c);
}

TEST(WifColorTest, PaletteRangeScalesTheValues) {
  // 0..999 (Fiberworks): 500 -> 500/999 as sRGB -> 0.21450468786256824 linear.
  std::string text = Edit(kColorWif, "Range=0,255", "Range=0,999");
  text = Edit(text, "1=255,255,255\n2=128,0,0\n3=0,10,255\n", "1=999,999,999\n2=500,0,0\n3=0,0,999\n");
  const WifColors c = Colors(text);
  ASSERT_EQ(c.table.size(), 3u);
  ExpectRgb(c.table[0], {1, 1, 1});
  ExpectRgb(c.table[1], {0.21450468786256824, 0, 0});
  ExpectRgb(c.table[2], {0, 0, 1});
  // A range that does not start at 0: 100..355 is 0..255 moved up by 100, so 228 reads as 128 did.
  text = Edit(kColorWif, "Range=0,255", "Range=100,355");
  text = Edit(text, "1=255,255,255\n2=128,0,0\n3=0,10,255\n", "1=355,355,355\n2=228,100,100\n3=100,110,355\n");
  EXPECT_EQ(Colors(text), Colors(kColorWif));
}

TEST(WifColorTest, DefaultsEmptyEntriesAndTheIndexRgbForm) {
  // "index,r,g,b" in Color=: the table's colour, the r,g,b only checked.
  EXPECT_EQ(Colors(Edit(kColorWif, "Color=1\n", "Color=1,0,0,0\n")), Colors(kColorWif));
  // An entry without a value keeps the default; a default for the weft colours the picks without an entry.
  std::string text = Edit(kColorWif, "[WARP COLORS]\n3=2\n", "[WARP COLORS]\n3=\n");
  text = Edit(text, "[WEFT]\nThreads=4\n", "[WEFT]\nThreads=4\nColor=2\n");
  const WifColors c = Colors(text);
  EXPECT_EQ(c.warp, (std::vector<int>{0, 0, 0, 0}));
  EXPECT_EQ(c.weft, (std::vector<int>{1, 2, 1, 2}));
  // Only the weft coloured: the warp is all -1, not empty.
  text = Edit(kColorWif, "Color=1\n", "");
  text = Edit(text, "[WARP COLORS]\n3=2\n", "");
  const WifColors weft_only = Colors(text);
  EXPECT_EQ(weft_only.warp, (std::vector<int>{-1, -1, -1, -1}));
  EXPECT_EQ(weft_only.weft, (std::vector<int>{-1, 2, -1, 2}));
}

TEST(WifColorTest, AnIndexTheTableSkipsIsBlackAndNoThreadMayUseIt) {
  const std::string text = Edit(kColorWif, "2=128,0,0\n", "");
  const std::string used = Edit(text, "[WARP COLORS]\n3=2\n", "[WARP COLORS]\n3=3\n");
  const WifColors c = Colors(used);
  ASSERT_EQ(c.table.size(), 3u);
  ExpectRgb(c.table[1], {0, 0, 0});
  EXPECT_EQ(c.warp, (std::vector<int>{0, 0, 2, 0}));
  WeavePattern p;
  WifColors untouched{{{0.5, 0.5, 0.5}}, {0}, {0}};
  WifColors colors = untouched;
  const std::string err = ParseWif(text, &p, &colors);
  EXPECT_EQ(err, "line " + std::to_string(LineOf(text, "[WARP COLORS]") + 1) + ": colour 2 is not in [COLOR TABLE]");
  EXPECT_EQ(colors, untouched);
}

TEST(WifColorTest, DraftsWithoutThreadColoursHaveNone) {
  EXPECT_EQ(Colors(kTwillWif), WifColors());
  // A table that no thread uses.
  EXPECT_EQ(Colors(kTwillWif + "[COLOR TABLE]\n1=255,0,0\n2=0,255,0\n"), WifColors());
  // A failed parse leaves the colours as they were.
  WeavePattern p;
  WifColors colors{{{1, 1, 1}}, {0}, {0}};
  EXPECT_NE(ParseWif("[WIF]\nVersion=2\n", &p, &colors), "");
  EXPECT_EQ(colors, (WifColors{{{1, 1, 1}}, {0}, {0}}));
}

// The two-argument ParseWif still skips the colour sections unread: loose free text there cannot break it.
TEST(WifColorTest, TheWeaveAloneIgnoresColourSections) {
  const std::string text = Edit(kColorWif, "Form=RGB", "Form=HSV\nthis line has no equals sign");
  EXPECT_EQ(Wif(text), Twill(2, 2, TwillDirection::kRightward));
  WeavePattern p;
  WifColors colors;
  EXPECT_EQ(ParseWif(text, &p, &colors),
            "line " + std::to_string(LineOf(text, "this line")) + ": expected key=value, found no '='");
  EXPECT_EQ(ParseWif(text, &p, nullptr), "") << "a null colors is the two-argument ParseWif";
}

TEST(WifColorTest, GinghamFixture) {
  WeavePattern p;
  const WifColors c = Colors(Fixture("gingham.wif"), &p);
  ASSERT_EQ(p.warps, 8);
  ASSERT_EQ(p.picks, 8);
  for (int pick = 0; pick < 8; ++pick)
    for (int warp = 0; warp < 8; ++warp)
      EXPECT_EQ(p.cells[pick * 8 + warp], (warp + pick + 1) % 2) << warp << "," << pick;
  ASSERT_EQ(c.table.size(), 2u);
  ExpectRgb(c.table[0], {1, 1, 1});
  ExpectRgb(c.table[1], {0.014443843596092545, 0.05126945837404324, 0.35153259950043936});  // sRGB 32, 64, 160
  const std::vector<int> four_and_four = {0, 0, 0, 0, 1, 1, 1, 1};
  EXPECT_EQ(c.warp, four_and_four);
  EXPECT_EQ(c.weft, four_and_four);
}

TEST(WifColorTest, PlaidWithRange999Fixture) {
  WeavePattern p;
  const WifColors c = Colors(Fixture("plaid_range999.wif"), &p);
  ASSERT_EQ(p.warps, 16);
  ASSERT_EQ(p.picks, 16);
  ASSERT_EQ(c.table.size(), 2u);
  ExpectRgb(c.table[0], {0, 0.12759883955702317, 0.03193194979304206});     // 0, 392, 196 of 999
  ExpectRgb(c.table[1], {0.5783587378161046, 0, 0.013068211383941786});     // 784, 0, 118 of 999
  const std::vector<int> stripes = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 1, 1};  // 8 green 2 red 4 green 2 red
  EXPECT_EQ(c.warp, stripes);
  EXPECT_EQ(c.weft, stripes);
}

// The threadcount the fixture's comment gives, expanded here: colour codes in the table's order.
std::vector<int> ExpandSett(const std::string& threadcount, const std::vector<std::string>& codes) {
  std::vector<int> threads;
  std::istringstream in(threadcount);
  for (std::string stripe; in >> stripe;) {
    const size_t digits = stripe.find_first_of("0123456789");
    const int color = int(std::find(codes.begin(), codes.end(), stripe.substr(0, digits)) - codes.begin());
    threads.insert(threads.end(), std::stoi(stripe.substr(digits)), color);
  }
  return threads;
}

TEST(WifColorTest, TartanFixture) {
  WeavePattern p;
  const WifColors c = Colors(Fixture("tartan.wif"), &p);
  ASSERT_EQ(p.warps, 64);
  ASSERT_EQ(p.picks, 64);
  // 2/2 twill throughout: the 4 x 4 twill tiled.
  const WeavePattern twill = Twill(2, 2, TwillDirection::kRightward);
  for (int pick = 0; pick < 64; ++pick)
    for (int warp = 0; warp < 64; ++warp)
      ASSERT_EQ(p.cells[pick * 64 + warp], twill.cells[(pick % 4) * 4 + warp % 4]) << warp << "," << pick;
  const std::vector<int> sett = ExpandSett("R26 DB2 K3 LY1 K1 W1 K1 G5 R2 K1 R1 W2 R1 K1 R2 G5 K1 W1 K1 LY1 K3 DB2",
                                           {"R", "DB", "K", "LY", "W", "G"});
  ASSERT_EQ(sett.size(), 64u);
  EXPECT_EQ(c.warp, sett);
  EXPECT_EQ(c.weft, c.warp) << "a tartan: the same sett in warp and weft";
  EXPECT_GE(std::set<int>(c.warp.begin(), c.warp.end()).size(), 6u);
  ASSERT_EQ(c.table.size(), 6u);
  ExpectRgb(c.table[0], {0.5775804404296506, 0.005181516702338386, 0.027320891639074894});  // scarlet 200, 16, 46
}

TEST(WifColorTest, DraftWithoutColoursFixture) {
  WeavePattern p;
  EXPECT_EQ(Colors(Fixture("no_colors.wif"), &p), WifColors());
  EXPECT_EQ(p, Twill(2, 2, TwillDirection::kRightward));
}

// Each case edits kColorWif; the line to report carries "; <-- bad".
TEST(WifColorTest, MalformedColourSectionsReportTheLine) {
  const std::string no_table = "[COLOR TABLE]\n1=255,255,255\n2=128,0,0\n3=0,10,255\n";
  const std::vector<BadDraft> cases = {
      {"two values", {{"2=128,0,0", "2=128,0 ; <-- bad"}}, true,
       "[COLOR TABLE] colour 2 has 2 value(s), expected 3 (r,g,b)"},
      {"four values", {{"2=128,0,0", "2=128,0,0,0 ; <-- bad"}}, true, "[COLOR TABLE] colour 2 has more than 3 values"},
      {"no value", {{"2=128,0,0", "2= ; <-- bad"}}, true, "[COLOR TABLE] colour 2 value '' is not a number"},
      {"not a number", {{"2=128,0,0", "2=128,0x10,0 ; <-- bad"}}, true, "value '0x10' is not a number"},
      {"negative value", {{"2=128,0,0", "2=128,-1,0 ; <-- bad"}}, true, "value '-1' is not a number"},
      {"value over the range", {{"2=128,0,0", "2=128,256,0 ; <-- bad"}}, true,
       "[COLOR TABLE] colour 2 value 256 out of range 0..255 (COLOR PALETTE Range=0,255)"},
      {"value under a range's low end", {{"Range=0,255", "Range=100,355"}, {"1=255,255,255", "1=355,99,355 ; <-- bad"}},
       true, "value 99 out of range 100..355"},
      {"over the default range", {{"Range=0,255\n", ""}, {"3=0,10,255", "3=0,10,999 ; <-- bad"}}, true,
       "value 999 out of range 0..255 (the default Range=0,255)"},
      {"Form=HSV", {{"Form=RGB", "Form=HSV ; <-- bad"}}, true, "[COLOR PALETTE] Form=HSV is not supported (only RGB)"},
      {"index beyond Entries=", {{"3=0,10,255\n", "3=0,10,255\n4=0,0,0 ; <-- bad\n"}}, true,
       "colour 4 out of range 1..3 (COLOR PALETTE Entries=3)"},
      {"index 0", {{"1=255,255,255", "0=255,255,255 ; <-- bad"}}, true, "colour 0 out of range 1..3"},
      {"index over 256 without Entries=", {{"Entries=3\n", ""}, {"3=0,10,255\n", "3=0,10,255\n257=0,0,0 ; <-- bad\n"}},
       true, "colour 257 out of range 1..256 (the limit of 256)"},
      {"index given twice", {{"3=0,10,255\n", "3=0,10,255\n1=0,0,0 ; <-- bad\n"}}, true,
       "[COLOR TABLE] colour 1 repeated"},
      {"Entries= over 256", {{"Entries=3", "Entries=257 ; <-- bad"}}, true, "Entries=257 is not a number in 1..256"},
      {"Entries=0", {{"Entries=3", "Entries=0 ; <-- bad"}}, true, "Entries=0 is not a number in 1..256"},
      {"Range= reversed", {{"Range=0,255", "Range=255,0 ; <-- bad"}}, true,
       "Range='255,0' is not two numbers lo,hi with lo < hi"},
      {"Range= of one number", {{"Range=0,255", "Range=255 ; <-- bad"}}, true, "is not two numbers"},
      {"Range= negative", {{"Range=0,255", "Range=-1,255 ; <-- bad"}}, true, "is not two numbers"},
      {"Range= of three numbers", {{"Range=0,255", "Range=0,1,255 ; <-- bad"}}, true, "is not two numbers"},
      {"Form= given twice", {{"Form=RGB\n", "Form=RGB\nForm=RGB ; <-- bad\n"}}, true, "[COLOR PALETTE] Form= repeated"},
      {"warp thread beyond WARP Threads=", {{"[WARP COLORS]\n3=2\n", "[WARP COLORS]\n3=2\n5=2 ; <-- bad\n"}}, true,
       "thread 5 out of range 1..4 (WARP Threads=4)"},
      {"pick beyond WEFT Threads=", {{"[WEFT COLORS]\n", "[WEFT COLORS]\n9=3 ; <-- bad\n"}}, true,
       "pick 9 out of range 1..4 (WEFT Threads=4)"},
      {"warp thread beyond the threaded ones",
       {{"[WARP]\nThreads=4\n", "[WARP]\n"}, {"3=2\n[WEFT", "3=2\n5=2 ; <-- bad\n[WEFT"}}, true,
       "thread 5 out of range 1..4 (the threads of [THREADING])"},
      {"pick beyond the treadled ones",
       {{"[WEFT]\nThreads=4\n", "[WEFT]\n"}, {"[WEFT COLORS]\n", "[WEFT COLORS]\n5=3 ; <-- bad\n"}}, true,
       "pick 5 out of range 1..4 (the picks of [TREADLING])"},
      {"thread given twice", {{"[WARP COLORS]\n3=2\n", "[WARP COLORS]\n3=2\n3=1 ; <-- bad\n"}}, true,
       "[WARP COLORS] thread 3 repeated"},
      {"two colours for one thread", {{"[WARP COLORS]\n3=2\n", "[WARP COLORS]\n3=1,2 ; <-- bad\n"}}, true,
       "colour '1,2' is not a number"},
      {"thread colour beyond Entries=", {{"[WARP COLORS]\n3=2\n", "[WARP COLORS]\n3=4 ; <-- bad\n"}}, true,
       "colour 4 out of range 1..3 (COLOR PALETTE Entries=3)"},
      {"Color= beyond Entries=", {{"Color=1", "Color=9 ; <-- bad"}}, true, "colour 9 out of range 1..3"},
      {"Color= not a number", {{"Color=1", "Color=white ; <-- bad"}}, true, "colour 'white' is not a number"},
      {"Color= with two values", {{"Color=1", "Color=1,255,255 ; <-- bad"}}, true, "[WARP] Color= has 2 value(s)"},
      {"Color= with an r,g,b out of range", {{"Color=1", "Color=1,255,255,256 ; <-- bad"}}, true,
       "[WARP] Color= value 256 out of range"},
      {"Color= given twice", {{"Color=1\n", "Color=1\nColor=2 ; <-- bad\n"}}, true, "[WARP] Color= repeated"},
      {"Color= without a table", {{no_table, ""}, {"Color=1", "Color=1 ; <-- bad"}}, true,
       "[WARP] Color= names a colour, but the draft has no [COLOR TABLE]"},
      {"[WARP COLORS] without a table",
       {{no_table, ""}, {"Color=1\n", ""}, {"[WARP COLORS]\n", "[WARP COLORS] ; <-- bad\n"}}, true,
       "[WARP COLORS] gives colours, but the draft has no [COLOR TABLE]"},
      {"[WEFT COLORS] without a table",
       {{no_table, ""},
        {"Color=1\n", ""},
        {"[WARP COLORS]\n3=2\n", ""},
        {"[WEFT COLORS]\n", "[WEFT COLORS] ; <-- bad\n"}},
       true, "[WEFT COLORS] gives colours, but the draft has no [COLOR TABLE]"},
      {"[COLOR TABLE] listed but missing",
       {{no_table, ""},
        {"Color=1\n", ""},
        {"[WARP COLORS]\n3=2\n", ""},
        {"[WEFT COLORS]\n2=3\n4=3\n", ""},
        {"WEFT=true\n", "WEFT=true\nCOLOR TABLE=yes ; <-- bad\n"}},
       true, "listed in [CONTENTS], but the file has no [COLOR TABLE] section"},
      {"[COLOR TABLE] repeated", {{"[WARP COLORS]\n", "[COLOR TABLE] ; <-- bad\n[WARP COLORS]\n"}}, true,
       "section [COLOR TABLE] repeated"},
      {"line without '=' in [COLOR TABLE]", {{"2=128,0,0", "2 128,0,0 ; <-- bad"}}, true, "no '='"},
  };
  for (const BadDraft& c : cases) {
    SCOPED_TRACE(c.name);
    std::string text = kColorWif;
    for (const auto& [from, to] : c.edits) text = Edit(text, from, to);
    const int line = c.at_marker ? LineOf(text, "<-- bad") : 0;
    WeavePattern p{1, 1, {1}};
    const WifColors untouched{{{0.5, 0.5, 0.5}}, {0}, {0}};
    WifColors colors = untouched;
    const std::string err = ParseWif(text, &p, &colors);
    EXPECT_EQ(err.rfind("line " + std::to_string(line) + ": ", 0), 0u) << err;
    EXPECT_NE(err.find(c.reason), std::string::npos) << err;
    EXPECT_EQ(p, (WeavePattern{1, 1, {1}})) << "output touched on error";
    EXPECT_EQ(colors, untouched) << "colours touched on error";
  }
}

// Every section the colour-reading parse reads, flooded to its limit of 1024 entries: what it holds stays within
// WifParseBytes. And the largest coloured draft: 256 colours, 256 warp threads and 256 picks each coloured.
TEST(WifCostTest, ColourSectionsStayWithinTheParseBound) {
  std::string flood;
  for (const char* name : {"WIF", "CONTENTS", "WEAVING", "WARP", "WEFT", "THREADING", "TREADLING", "TIEUP", "LIFTPLAN",
                           "COLOR PALETTE", "COLOR TABLE", "WARP COLORS", "WEFT COLORS"}) {
    flood.append("[").append(name).append("]\n");
    for (int i = 0; i < 1024; ++i) flood += "k" + std::to_string(i) + "=" + std::string(20, 'v') + "\n";
  }
  ASSERT_LE(flood.size(), kMaxWifBytes);
  const auto peak_of = [](const std::string& text, std::string* error) {
    WeavePattern pattern;
    WifColors colors;
    const size_t before = ::heap_in_use.load();
    ::heap_peak = before;
    *error = ParseWif(text, &pattern, &colors);
    return ::heap_peak.load() - before;
  };
  std::string error;
  EXPECT_LE(peak_of(flood, &error), WifParseBytes(flood.size()));
  EXPECT_NE(error, "");

  std::string full = TreadlingDraft(4, 4, kMaxRepeat, "1,2", "1");
  full += "[COLOR PALETTE]\nEntries=256\nRange=0,65535\n[COLOR TABLE]\n";
  for (int i = 1; i <= kMaxRepeat; ++i) full += std::to_string(i) + "=" + std::to_string(i * 255) + ",0,65535\n";
  full += "[WARP COLORS]\n";
  for (int i = 1; i <= kMaxRepeat; ++i) full += std::to_string(i) + "=" + std::to_string(i) + "\n";
  full += "[WEFT COLORS]\n";
  for (int i = 1; i <= kMaxRepeat; ++i) full += std::to_string(i) + "=" + std::to_string(kMaxRepeat + 1 - i) + "\n";
  EXPECT_LE(peak_of(full, &error), WifParseBytes(full.size()));
  EXPECT_EQ(error, "");
  const WifColors c = Colors(full);
  ASSERT_EQ(c.table.size(), size_t(kMaxRepeat));
  ASSERT_EQ(c.warp.size(), size_t(kMaxRepeat));
  ASSERT_EQ(c.weft.size(), size_t(kMaxRepeat));
  EXPECT_EQ(c.warp[0], 0);
  EXPECT_EQ(c.weft[0], kMaxRepeat - 1);
  ExpectRgb(c.table[kMaxRepeat - 1], {0.9911711624342799, 0, 1});  // red 256 * 255 = 65280 of 65535
}

}  // namespace
}  // namespace loomlight::models::weave
