// Fuzz target: WIF weaving drafts (server/models/weave/wif.h), the one file format clients send in the clear
// (Param.text of the woven model's pattern.wif). Input: the draft's bytes. Checks ParseWif's contract: an error
// is "line N: reason", bounded and on one line, and leaves the output untouched; a success is a pattern that
// passes ValidatePattern and whose floats and area fractions add up.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include "server/models/weave/pattern.h"
#include "server/models/weave/wif.h"
#include "tests/fuzz/fuzz_check.h"

namespace loomlight::fuzz {
namespace {

using models::weave::WeavePattern;

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

}  // namespace
}  // namespace loomlight::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace loomlight::fuzz;
  const std::string text(reinterpret_cast<const char*>(data), size);
  const WeavePattern untouched{-1, -1, {7}};
  WeavePattern pattern = untouched;
  const std::string error = loomlight::models::weave::ParseWif(text, &pattern);
  if (error.empty()) {
    CheckPattern(pattern);
    return 0;
  }
  FUZZ_CHECK(MessageDefect(error).empty(), MessageDefect(error) + ": " + error);
  FUZZ_CHECK(StartsWithLineNumber(error), error);
  FUZZ_CHECK(pattern == untouched, "a failed parse changed the output: " + error);
  return 0;
}
