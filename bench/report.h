// Markdown output for the benchmark report: tables, number formatting and the machine description.
#pragma once

#include <string>
#include <vector>

namespace loomlight::bench {

// A markdown table: a header row, then rows of the same width; the first `text_columns` columns are
// left-aligned, the others right-aligned (numbers).
class Table {
 public:
  explicit Table(std::vector<std::string> header, size_t text_columns = 1)
      : header_(std::move(header)), text_columns_(text_columns) {}
  void Add(std::vector<std::string> row) { rows_.push_back(std::move(row)); }
  std::string Markdown() const;

 private:
  std::vector<std::string> header_;
  std::vector<std::vector<std::string>> rows_;
  size_t text_columns_;
};

// A section: "## title", a paragraph on the method, then the body.
std::string Section(const std::string& title, const std::string& method, const std::string& body);
// A table preceded by its one-line "How to read".
std::string TableBlock(const std::string& how_to_read, const Table& table);

std::string Fixed(double v, int decimals);  // 1.23
std::string Sci(double v);                  // 1.2e-05 (0 as "0")
std::string Rate(double per_second);        // queries/s as "12.3 M" / "456 k"
std::string Millis(double seconds);         // latency in ms, 3 significant digits
std::string Count(size_t n);                // 1,048,576

// Machine, OpenCL device, compiler, source revision and date, as a markdown bullet list.
// The fixed CPU calibration loop every report starts with, in milliseconds (best of 3).
double CalibrationMilliseconds();

std::string MachineDescription(const std::string& cl_platform, const std::string& cl_device, bool quick);

}  // namespace loomlight::bench
