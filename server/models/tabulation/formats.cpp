#include "server/models/tabulation/formats.h"

#include <algorithm>
#include <bit>
#include <cstdio>
#include <vector>

#include "server/imaging/image_encode.h"

namespace loomlight::tabulation {
namespace {

// Little-endian whatever the host's byte order.
void AppendLe32(uint32_t v, std::string* out) {
  for (int b = 0; b < 4; ++b) out->push_back(static_cast<char>((v >> (8 * b)) & 0xffu));
}
void AppendLe64(uint64_t v, std::string* out) {
  for (int b = 0; b < 8; ++b) out->push_back(static_cast<char>((v >> (8 * b)) & 0xffu));
}
void AppendFloat(float v, std::string* out) { AppendLe32(std::bit_cast<uint32_t>(v), out); }
void AppendDouble(double v, std::string* out) { AppendLe64(std::bit_cast<uint64_t>(v), out); }

// RAW: the "LLTB" header (docs/tabulation.md "Formats"), then float32 R, G, B per cell in grid order.
class RawEncoder final : public TableEncoder {
 public:
  explicit RawEncoder(const Grid& grid) : grid_(grid) {}
  void Begin(std::string* out) override {
    out->append("LLTB", 4);
    AppendLe32(kRawVersion, out);
    AppendLe32(kRawHeaderBytes, out);
    AppendLe32(static_cast<uint32_t>(grid_.kind()), out);
    AppendLe32(static_cast<uint32_t>(grid_.dims().size()), out);
    for (size_t d = 0; d < 4; ++d) AppendLe32(d < grid_.dims().size() ? grid_.dims()[d] : 1, out);
    AppendLe32(3, out);  // channels
  }
  void AddCells(uint64_t, const double* rgb, size_t count, std::string* out) override {
    out->reserve(out->size() + 12 * count);
    for (size_t i = 0; i < 3 * count; ++i) AppendFloat(static_cast<float>(rgb[i]), out);
  }

 private:
  const Grid& grid_;
};

// MERL .binary: int32 dims (90, 90, 180), then all R, all G, all B as float64 f / scale. R streams as it is
// computed; G and B wait for the last cell.
class MerlEncoder final : public TableEncoder {
 public:
  explicit MerlEncoder(const Grid& grid) : green_(grid.cells()), blue_(grid.cells()) {}
  void Begin(std::string* out) override {
    for (int d : {kMerlThetaH, kMerlThetaD, kMerlPhiD}) AppendLe32(static_cast<uint32_t>(d), out);
  }
  void AddCells(uint64_t first, const double* rgb, size_t count, std::string* out) override {
    out->reserve(out->size() + 8 * count);
    for (size_t i = 0; i < count; ++i) {
      AppendDouble(rgb[3 * i] / kMerlScale[0], out);
      green_[first + i] = rgb[3 * i + 1] / kMerlScale[1];
      blue_[first + i] = rgb[3 * i + 2] / kMerlScale[2];
    }
  }
  std::string End(std::string* out) override {
    out->reserve(out->size() + 16 * green_.size());
    for (const std::vector<double>* block : {&green_, &blue_})
      for (double v : *block) AppendDouble(v, out);
    return "";
  }

 private:
  std::vector<double> green_, blue_;
};

// EXR: the table as an image, one row per incoming cell, one column per outgoing cell, encoded at the end.
class ExrEncoder final : public TableEncoder {
 public:
  explicit ExrEncoder(const Grid& grid) {
    image_.width = static_cast<int>(grid.row_cells());
    image_.height = static_cast<int>(grid.cells() / grid.row_cells());
    image_.rgb.resize(3 * grid.cells());
  }
  void AddCells(uint64_t first, const double* rgb, size_t count, std::string*) override {
    std::transform(rgb, rgb + 3 * count, image_.rgb.begin() + 3 * first, [](double v) { return static_cast<float>(v); });
  }
  std::string End(std::string* out) override {
    std::string bytes;
    if (std::string error = imaging::EncodeImage(image_, imaging::ImageFormat::kExr, 1.0, &bytes); !error.empty())
      return error;
    out->append(bytes);
    return "";
  }

 private:
  imaging::LinearRgbImage image_;
};

// CSV: a header row, then per cell its grid angles (degrees) and r, g, b.
class CsvEncoder final : public TableEncoder {
 public:
  CsvEncoder(const Grid& grid, bool fp64) : grid_(grid), value_format_(fp64 ? "%.17g" : "%.9g") {}
  void Begin(std::string* out) override {
    for (const std::string& name : grid_.angle_names()) out->append(name + ",");
    out->append("r,g,b\n");
  }
  void AddCells(uint64_t first, const double* rgb, size_t count, std::string* out) override {
    char buf[64];
    for (size_t i = 0; i < count; ++i) {
      for (double angle : grid_.CellAngles(first + i)) {
        std::snprintf(buf, sizeof buf, "%.10g,", angle);
        out->append(buf);
      }
      for (int c = 0; c < 3; ++c) {
        std::snprintf(buf, sizeof buf, value_format_, rgb[3 * i + c]);
        out->append(buf);
        out->push_back(c < 2 ? ',' : '\n');
      }
    }
  }

 private:
  const Grid& grid_;
  const char* value_format_;
};

}  // namespace

std::unique_ptr<TableEncoder> MakeTableEncoder(TableFormat format, const Grid& grid, bool fp64) {
  switch (format) {
    case TableFormat::kExr: return std::make_unique<ExrEncoder>(grid);
    case TableFormat::kMerl: return std::make_unique<MerlEncoder>(grid);
    case TableFormat::kCsv: return std::make_unique<CsvEncoder>(grid, fp64);
    case TableFormat::kRaw: break;
  }
  return std::make_unique<RawEncoder>(grid);
}

}  // namespace loomlight::tabulation
