// Fuzz target: WIF weaving drafts (server/models/weave/wif.h), the one file format clients send in the clear
// (Param.text of the woven model's pattern.wif). Input: the draft's bytes, parsed with and without its colours.
// Checks ParseWif's contract: an error is "line N: reason", bounded and on one line, and leaves the outputs
// untouched; a success is a pattern that passes ValidatePattern and whose floats and area fractions add up, and
// colours that are none at all or one index per warp thread and pick, each -1 or in the table, the table's values
// finite in [0, 1]. Reading colours only ever refuses more: where it succeeds, the weave alone succeeds with the
// same pattern.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"
#include "server/models/weave/wif.h"
#include "tests/fuzz/fuzz_check.h"

namespace loomlight::fuzz {
namespace {

using models::weave::WeavePattern;
using models::weave::WifColors;

bool StartsWithLineNumber(const std::string& message) {
  if (message.rfind("line ", 0) != 0) return false;
  size_t i = 5;
  while (i < message.size() && message[i] >= '0' && message[i] <= '9') ++i;
  return i > 5 && message.compare(i, 2, ": ") == 0;
}

void CheckPattern(const WeavePattern& pattern) {
  FUZZ_CHECK(models::weave::ValidatePattern(pattern).empty(), models::weave::ValidatePattern(pattern));
  size_t ones = 0;
  for (uint8_t cell : pattern.cells) ones += cell;
  const size_t zeros = pattern.cells.size() - ones;
  size_t warp_length = 0, weft_length = 0;
  for (const models::weave::Float& f : models::weave::ExtractFloats(pattern)) {
    FUZZ_CHECK(f.length >= 1, models::weave::ToString(f));
    (f.warp ? warp_length : weft_length) += f.length;
  }
  FUZZ_CHECK(warp_length == ones && weft_length == zeros,
             "floats cover " + std::to_string(warp_length) + " + " + std::to_string(weft_length) + " cells of " +
                 std::to_string(ones) + " + " + std::to_string(zeros) + "\n" + models::weave::ToString(pattern));
  const models::weave::AreaFractions area = models::weave::ComputeAreaFractions(pattern);
  FUZZ_CHECK(std::fabs(area.warp + area.weft - 1) < 1e-12 && std::fabs(area.warp * pattern.cells.size() - ones) < 1e-6,
             "area fractions " + std::to_string(area.warp) + " + " + std::to_string(area.weft));
}

void CheckColors(const WifColors& colors, const WeavePattern& pattern) {
  if (colors.table.empty()) {
    FUZZ_CHECK(colors.warp.empty() && colors.weft.empty(), "thread colours without a table");
    return;
  }
  FUZZ_CHECK(colors.table.size() <= size_t(models::weave::kMaxRepeat),
             std::to_string(colors.table.size()) + " colours");
  FUZZ_CHECK(colors.warp.size() == size_t(pattern.warps) && colors.weft.size() == size_t(pattern.picks),
             std::to_string(colors.warp.size()) + " x " + std::to_string(colors.weft.size()) + " thread colours for " +
                 std::to_string(pattern.warps) + " x " + std::to_string(pattern.picks) + " threads");
  bool colored = false;
  for (const std::vector<int>* threads : {&colors.warp, &colors.weft})
    for (int index : *threads) {
      FUZZ_CHECK(index >= -1 && index < int(colors.table.size()),
                 "colour index " + std::to_string(index) + " of " + std::to_string(colors.table.size()));
      colored |= index >= 0;
    }
  FUZZ_CHECK(colored, "a table but no coloured thread: the colours should be empty");
  for (const auto& rgb : colors.table)
    for (double v : rgb) FUZZ_CHECK(std::isfinite(v) && v >= 0 && v <= 1, "colour value " + std::to_string(v));
}

void CheckError(const std::string& error) {
  FUZZ_CHECK(MessageDefect(error).empty(), MessageDefect(error) + ": " + error);
  FUZZ_CHECK(StartsWithLineNumber(error), error);
}

}  // namespace
}  // namespace loomlight::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace loomlight::fuzz;
  const std::string text(reinterpret_cast<const char*>(data), size);
  const WeavePattern untouched{-1, -1, {7}};
  const WifColors untouched_colors{{{-1, -1, -1}}, {7}, {7}};
  WeavePattern weave = untouched, pattern = untouched;
  WifColors colors = untouched_colors;
  const std::string weave_error = loomlight::models::weave::ParseWif(text, &weave);
  const std::string error = loomlight::models::weave::ParseWif(text, &pattern, &colors);
  if (weave_error.empty()) {
    CheckPattern(weave);
  } else {
    CheckError(weave_error);
    FUZZ_CHECK(weave == untouched, "a failed parse changed the output: " + weave_error);
  }
  if (error.empty()) {
    FUZZ_CHECK(weave_error.empty() && weave == pattern, "reading colours changed the weave: " + weave_error);
    CheckColors(colors, pattern);
    return 0;
  }
  CheckError(error);
  FUZZ_CHECK(pattern == untouched && colors == untouched_colors, "a failed parse changed the output: " + error);
  return 0;
}
