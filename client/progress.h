// A progress report on stderr for long calls: a bar redrawn in place on a terminal, otherwise a plain line
// per update (so logs and pipes get readable text, not carriage returns).
#pragma once

#include <cstdint>
#include <string>

namespace loomlight::client {

class ProgressBar {
 public:
  // `unit` names what is counted, e.g. "samples".
  explicit ProgressBar(std::string unit);
  void update(uint64_t done, uint64_t total);
  // Ends the bar's line (terminal only).
  void end();

  // 1234567 as "1,234,567".
  static std::string grouped(uint64_t n);

 private:
  std::string unit_;
  bool terminal_;
  bool drawn_ = false;
  int last_percent_ = -1;
};

}  // namespace loomlight::client
