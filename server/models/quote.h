// Quoting client-given text (preset, model and parameter names, WIF values, ...) in error messages: every
// message that echoes what a client sent goes through Quote, so a hostile request cannot make its error
// message long (a status message travels in HTTP/2 trailers: a long one turns INVALID_ARGUMENT into
// RESOURCE_EXHAUSTED at the client), multi-line or unreadable. Used by the model and the API layers.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>

namespace loomlight::models {

// A number as error messages show it: six significant digits ("0.0378", "1e+06", "nan").
inline std::string Number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

// The most bytes of (escaped) client text a quote shows.
inline constexpr size_t kMaxQuotedBytes = 200;

namespace quote_detail {

// The length of the well-formed UTF-8 sequence at the start of s (1 to 4; code point in *cp), or 0 when
// s does not start with one (a stray continuation byte, an overlong form, a surrogate, past U+10FFFF, or a
// sequence cut short).
inline size_t Utf8Sequence(std::string_view s, uint32_t* cp) {
  const auto byte = [&](size_t i) { return static_cast<uint8_t>(s[i]); };
  const uint8_t b0 = byte(0);
  if (b0 < 0x80) return *cp = b0, 1;
  size_t n = 0;
  uint32_t min = 0;
  if ((b0 & 0xE0) == 0xC0) n = 2, *cp = b0 & 0x1F, min = 0x80;
  else if ((b0 & 0xF0) == 0xE0) n = 3, *cp = b0 & 0x0F, min = 0x800;
  else if ((b0 & 0xF8) == 0xF0) n = 4, *cp = b0 & 0x07, min = 0x10000;
  else return 0;
  if (s.size() < n) return 0;
  for (size_t i = 1; i < n; ++i) {
    if ((byte(i) & 0xC0) != 0x80) return 0;
    *cp = (*cp << 6) | (byte(i) & 0x3F);
  }
  if (*cp < min || *cp > 0x10FFFF || (*cp >= 0xD800 && *cp <= 0xDFFF)) return 0;
  return n;
}

// Code points that would break a message's single readable line or reorder how it displays: C0 and C1
// controls, DEL, line and paragraph separators, and the bidirectional formatting characters.
inline bool Unprintable(uint32_t cp) {
  return cp < 0x20 || (cp >= 0x7F && cp <= 0x9F) || cp == 0x2028 || cp == 0x2029 || cp == 0x200E || cp == 0x200F ||
         (cp >= 0x202A && cp <= 0x202E) || (cp >= 0x2066 && cp <= 0x2069) || cp == 0xFEFF;
}

inline std::string Hex(uint32_t v, int digits) {
  static const char kDigits[] = "0123456789abcdef";
  std::string out(digits, '0');
  for (int i = digits - 1; i >= 0; --i, v >>= 4) out[i] = kDigits[v & 0xF];
  return out;
}

}  // namespace quote_detail

// `text` in single quotes for an error message, on one line: \\ and \' for a backslash and a quote, \n, \r
// and \t, \xNN for any other control byte or a byte that is not part of well-formed UTF-8, \uNNNN for the
// other unprintable code points above. When the escaped text is longer than kMaxQuotedBytes it is cut at a
// whole character (never inside a UTF-8 sequence or an escape), marked with an ellipsis, and followed by the
// input's size: 'abc…' (12345 bytes).
inline std::string Quote(std::string_view text) {
  using namespace quote_detail;
  std::string out = "'";
  size_t shown = 0;  // bytes of `text` represented in `out`
  while (shown < text.size()) {
    const std::string_view rest = text.substr(shown);
    uint32_t cp = 0;
    size_t n = Utf8Sequence(rest, &cp);
    std::string piece;
    if (n == 0) {
      n = 1;
      piece = "\\x" + Hex(static_cast<uint8_t>(rest[0]), 2);
    } else if (cp == '\\' || cp == '\'') {
      piece = std::string("\\") + char(cp);
    } else if (cp == '\n') {
      piece = "\\n";
    } else if (cp == '\r') {
      piece = "\\r";
    } else if (cp == '\t') {
      piece = "\\t";
    } else if (cp < 0x80 && Unprintable(cp)) {
      piece = "\\x" + Hex(cp, 2);
    } else if (Unprintable(cp)) {
      piece = "\\u" + Hex(cp, 4);
    } else {
      piece = std::string(rest.substr(0, n));
    }
    if (out.size() - 1 + piece.size() > kMaxQuotedBytes) break;
    out += piece;
    shown += n;
  }
  if (shown == text.size()) return out + "'";
  return out + "\u2026' (" + std::to_string(text.size()) + " bytes)";
}

// The most bytes of client text EchoToken shows without quotes.
inline constexpr size_t kMaxTokenBytes = 32;

// For values in a key=value syntax (a WIF draft's "Shafts=300"): `text` as it is when it is a short plain
// token (1 to kMaxTokenBytes of ASCII letters, digits, '.', '_', '+', '-', and spaces inside), else Quote(text).
inline std::string EchoToken(std::string_view text) {
  const auto plain = [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
           c == '+' || c == '-' || c == ' ';
  };
  bool token = !text.empty() && text.size() <= kMaxTokenBytes && text.front() != ' ' && text.back() != ' ';
  for (char c : text) token = token && plain(c);
  return token ? std::string(text) : Quote(text);
}

}  // namespace loomlight::models
