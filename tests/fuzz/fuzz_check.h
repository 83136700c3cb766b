// Checks for the fuzz targets: a failed check prints what failed and aborts, which libFuzzer reports as a crash
// (and saves the input) and the corpus replay turns into a failed test. Not assert(): Release builds drop it.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "server/models/quote.h"

namespace loomlight::fuzz {

[[noreturn]] inline void Fail(const char* file, int line, const char* condition, const std::string& detail) {
  std::fprintf(stderr, "%s:%d: fuzz check failed: %s\n  %s\n", file, line, condition, detail.c_str());
  std::abort();
}

// The longest error message a client may get: a status message travels in HTTP/2 trailers, so an unbounded one
// (client text echoed whole) would turn the error into another (server/models/quote.h).
inline constexpr size_t kMaxErrorMessageBytes = 1024;

// Why `message` is not a readable one-line error message of bounded length, or "".
inline std::string MessageDefect(std::string_view message) {
  if (message.empty()) return "empty message";
  if (message.size() >= kMaxErrorMessageBytes) return std::to_string(message.size()) + " bytes";
  for (size_t i = 0; i < message.size();) {
    uint32_t cp = 0;
    const size_t n = models::quote_detail::Utf8Sequence(message.substr(i), &cp);
    if (n == 0) return "not UTF-8 at byte " + std::to_string(i);
    if (models::quote_detail::Unprintable(cp)) return "unprintable code point at byte " + std::to_string(i);
    i += n;
  }
  return "";
}

}  // namespace loomlight::fuzz

// Aborts with `detail` (a std::string, built only on failure) when `condition` is false.
#define FUZZ_CHECK(condition, detail) \
  ((condition) ? void() : ::loomlight::fuzz::Fail(__FILE__, __LINE__, #condition, (detail)))
