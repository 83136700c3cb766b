// Tabulate's file formats: RAW with a header, OpenEXR, MERL .binary and CSV, each an encoder that turns a grid's
// cells (in grid order) into file bytes. Bytes that are final are appended as cells arrive, so a table streams
// while it is computed; the rest (MERL's G and B blocks, the whole EXR) at the end.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "server/models/tabulation/grid.h"

namespace loomlight::tabulation {

// RAW format header ("LLTB"), little-endian, kRawHeaderBytes long; then float32 RGB per cell.
constexpr uint32_t kRawVersion = 1;
constexpr uint32_t kRawHeaderBytes = 40;

enum class TableFormat { kRaw, kExr, kMerl, kCsv };

class TableEncoder {
 public:
  virtual ~TableEncoder() = default;
  // The file's first bytes (a header), before any cell.
  virtual void Begin(std::string* out) {}
  // `count` cells from `first`, RGB each (finite).
  virtual void AddCells(uint64_t first, const double* rgb, size_t count, std::string* out) = 0;
  // After the last cell: the rest of the file. Returns "" or the reason it cannot be encoded.
  virtual std::string End(std::string* out) { return ""; }
};

// The encoder of `format` for `grid`, which outlives it (MERL needs the MERL grid; EXR holds the image in memory
// until End); fp64 only sets CSV's printed digits.
std::unique_ptr<TableEncoder> MakeTableEncoder(TableFormat format, const Grid& grid, bool fp64);

}  // namespace loomlight::tabulation
