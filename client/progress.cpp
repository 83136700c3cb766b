#include "client/progress.h"

#include <unistd.h>

#include <cstdio>

namespace loomlight::client {

ProgressBar::ProgressBar(std::string unit) : unit_(std::move(unit)), terminal_(isatty(STDERR_FILENO) == 1) {}

void ProgressBar::update(uint64_t done, uint64_t total) {
  if (total == 0) return;
  const int percent = static_cast<int>(100 * done / total);
  if (terminal_) {
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(kWidth * done / total);
    std::fprintf(stderr, "\r[%s%s] %3d%%  %s / %s %s", std::string(filled, '#').c_str(),
                 std::string(kWidth - filled, '.').c_str(), percent, grouped(done).c_str(), grouped(total).c_str(),
                 unit_.c_str());
    drawn_ = true;
  } else if (percent != last_percent_) {  // one line per change, not per message
    std::fprintf(stderr, "progress: %3d%%  %s / %s %s\n", percent, grouped(done).c_str(), grouped(total).c_str(),
                 unit_.c_str());
  }
  last_percent_ = percent;
  std::fflush(stderr);
}

void ProgressBar::end() {
  if (drawn_) std::fputc('\n', stderr);
  drawn_ = false;
}

std::string ProgressBar::grouped(uint64_t n) {
  const std::string digits = std::to_string(n);
  std::string out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

}  // namespace loomlight::client
