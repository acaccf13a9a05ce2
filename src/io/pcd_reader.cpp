// dtif's own PCD reader (issue #17). PCL's PCDReader::read reads out of bounds on valid binary
// files whose x y z are float64 (found by fuzz_pcd), and its conversion reads nonsense from
// non-float32 fields, so the three layouts are decoded here from a header checked first (bounds
// of docs/limits.md). Only pcl::lzfDecompress (bounds-checked liblzf) is PCL's.
#include "dtif/io/pcd_reader.h"

#include <pcl/io/lzf.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <vector>

#include "dtif/io/dataset.h"

namespace dtif {
namespace {

// Bounds of docs/limits.md.
constexpr long long kMaxPcdPoints = 100000000;  // trunk_extraction.max_points' upper bound
constexpr long long kMaxFieldCount = 4096;      // COUNT of one field
constexpr size_t kMaxFields = 256;
// An LZF token of 3 bytes expands to at most 264: a block that claims more than 88 bytes per
// compressed byte is malformed, and is refused before its output is allocated.
constexpr uint64_t kMaxLzfRatio = 88;
constexpr long long kChunkBytes = 1 << 20;  // binary data are read ~1 MiB at a time

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw DatasetError(path + ": " + what);
}

struct PcdField {
  std::string name;
  long long size = 4;         ///< bytes of one value
  char type = 'F';            ///< F, I or U
  long long count = 1;        ///< values per point
  long long offset = 0;       ///< bytes before it in a point
  long long value_index = 0;  ///< numbers before it in an ASCII row
};

struct PcdHeader {
  std::vector<PcdField> fields;
  long long point_step = 0;  ///< bytes per point
  long long values = 0;      ///< numbers per ASCII row
  long long points = 0;
  std::string data;          ///< ascii, binary or binary_compressed
  long long lines = 0;       ///< lines up to and including DATA
  long long data_bytes = 0;  ///< bytes of the file after the header
};

using HeaderKeys = std::map<std::string, std::vector<std::string>>;
using XyzFields = std::array<const PcdField*, 3>;

const std::vector<std::string>& valuesOf(const HeaderKeys& keys, const std::string& key) {
  static const std::vector<std::string> kNone;
  const auto it = keys.find(key);
  return it == keys.end() ? kNone : it->second;
}

// A header is ASCII text: control or 8-bit bytes in it (found by fuzz_pcd: PCL then asked for
// a 100 TB string) mean binary junk.
bool hasBinaryBytes(const std::string& line) {
  return std::any_of(line.begin(), line.end(),
                     [](unsigned char c) { return (c < 0x20 && c != '\t') || c >= 0x7f; });
}

// The header's lines up to DATA, each key with its values; DATA's value goes to h.data.
HeaderKeys readHeaderKeys(std::istream& in, const std::string& path, PcdHeader& h) {
  static const std::set<std::string> kKeys = {"VERSION", "FIELDS", "SIZE",      "TYPE",  "COUNT",
                                              "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS"};
  HeaderKeys keys;
  std::string line;
  while (h.data.empty() && std::getline(in, line)) {
    ++h.lines;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    if (hasBinaryBytes(line)) fail(path, "not a PCD file (binary bytes in the header)");
    std::istringstream ss(line);
    std::string key, v;
    ss >> key;
    std::vector<std::string> values;
    while (ss >> v) values.push_back(v);
    if (key == "DATA") {
      h.data = values.empty() ? "?" : values[0];
    } else if (kKeys.count(key)) {
      keys[key] = values;
    } else {
      fail(path, "not a PCD file (unexpected header line '" + line.substr(0, 40) + "')");
    }
  }
  if (h.data.empty()) fail(path, "not a PCD file (no DATA line)");
  return keys;
}

// A header count in [0, max], so that no product of counts overflows.
long long toCount(const std::string& path, const std::string& s, const char* what, long long max) {
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(s.c_str(), &end, 10);
  if (s.empty() || *end != '\0' || v < 0 || errno == ERANGE) {
    fail(path, std::string("malformed PCD ") + what);
  }
  if (v > max) {
    fail(path,
         std::string("PCD ") + what + " " + s + " exceeds the limit of " + std::to_string(max));
  }
  return v;
}

// FIELDS, SIZE, TYPE and COUNT: the fields with their offsets, the point step.
void parseFields(const HeaderKeys& keys, const std::string& path, PcdHeader& h) {
  const auto& names = valuesOf(keys, "FIELDS");
  const auto& sizes = valuesOf(keys, "SIZE");
  const auto& types = valuesOf(keys, "TYPE");
  std::vector<std::string> counts = valuesOf(keys, "COUNT");
  if (counts.empty()) counts.assign(names.size(), "1");
  if (names.empty() || sizes.size() != names.size() || types.size() != names.size() ||
      counts.size() != names.size()) {
    fail(path, "malformed PCD header (FIELDS, SIZE, TYPE and COUNT disagree)");
  }
  if (names.size() > kMaxFields) fail(path, "PCD has more than 256 fields");
  for (size_t i = 0; i < names.size(); ++i) {
    PcdField f;
    f.name = names[i];
    f.size = toCount(path, sizes[i], "SIZE", 8);
    if (f.size != 1 && f.size != 2 && f.size != 4 && f.size != 8) fail(path, "malformed PCD SIZE");
    if (types[i] != "F" && types[i] != "I" && types[i] != "U") fail(path, "malformed PCD TYPE");
    f.type = types[i][0];
    f.count = toCount(path, counts[i], "COUNT", kMaxFieldCount);
    f.offset = h.point_step;
    f.value_index = h.values;
    h.point_step += f.size * f.count;
    h.values += f.count;
    h.fields.push_back(f);
  }
}

// POINTS, or WIDTH x HEIGHT; both must agree when both are given (PCL's rule too).
long long pointCount(const HeaderKeys& keys, const std::string& path) {
  const auto& points = valuesOf(keys, "POINTS");
  const auto& width = valuesOf(keys, "WIDTH");
  const auto& height = valuesOf(keys, "HEIGHT");
  if (points.empty() && width.empty()) fail(path, "malformed PCD header (no POINTS or WIDTH)");
  long long n = -1;
  if (!points.empty()) n = toCount(path, points[0], "POINTS", kMaxPcdPoints);
  if (width.empty()) return n;
  const long long wh = toCount(path, width[0], "WIDTH", kMaxPcdPoints) *
                       (height.empty() ? 1 : toCount(path, height[0], "HEIGHT", kMaxPcdPoints));
  if (wh > kMaxPcdPoints) fail(path, "PCD WIDTH x HEIGHT exceeds the point limit");
  if (n >= 0 && wh != n) fail(path, "malformed PCD header (WIDTH x HEIGHT disagrees with POINTS)");
  return wh;
}

PcdHeader readHeader(std::istream& in, const std::string& path) {
  in.seekg(0, std::ios::end);
  const std::streamoff file_size = in.tellg();
  in.seekg(0);
  PcdHeader h;
  const HeaderKeys keys = readHeaderKeys(in, path, h);
  parseFields(keys, path, h);
  h.points = pointCount(keys, path);
  if (h.data != "ascii" && h.data != "binary" && h.data != "binary_compressed") {
    fail(path, "malformed PCD (DATA must be ascii, binary or binary_compressed)");
  }
  const std::streamoff data_start = in.tellg();
  h.data_bytes = data_start < 0 ? 0 : file_size - data_start;
  return h;
}

// x, y and z: one value each, of any numeric type (float64 from CloudCompare or PDAL, integers).
XyzFields xyzFields(const PcdHeader& h, const std::string& path) {
  XyzFields xyz = {nullptr, nullptr, nullptr};
  for (const PcdField& f : h.fields) {
    for (int k = 0; k < 3; ++k) {
      if (!xyz[k] && f.name == std::string(1, "xyz"[k])) xyz[k] = &f;
    }
  }
  if (!xyz[0] || !xyz[1] || !xyz[2]) fail(path, "PCD has no x y z fields");
  for (const PcdField* f : xyz) {
    if (f->count != 1 || (f->type == 'F' && f->size < 4)) {
      fail(path, "PCD field '" + f->name + "' has an unsupported type or layout");
    }
  }
  return xyz;
}

template <typename T>
float as(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof(v));
  return static_cast<float>(v);
}

// One stored value of field f as a float, whatever its type (PCD data are little-endian).
float binaryValue(const char* p, const PcdField& f) {
  if (f.type == 'F') return f.size == 8 ? as<double>(p) : as<float>(p);
  const bool s = f.type == 'I';
  switch (f.size) {
    case 1:
      return s ? as<int8_t>(p) : as<uint8_t>(p);
    case 2:
      return s ? as<int16_t>(p) : as<uint16_t>(p);
    case 4:
      return s ? as<int32_t>(p) : as<uint32_t>(p);
    default:
      return s ? as<int64_t>(p) : as<uint64_t>(p);
  }
}

// NaN and infinite points are dropped (PCL writes NaN for "no return").
void addPoint(Cloud& cloud, float x, float y, float z) {
  if (std::isfinite(x) && std::isfinite(y) && std::isfinite(z)) cloud.push_back({x, y, z});
}

Cloud::Ptr finish(Cloud::Ptr cloud) {
  cloud->width = static_cast<uint32_t>(cloud->size());
  cloud->height = 1;
  cloud->is_dense = true;
  return cloud;
}

// The numbers of one ASCII row; `where` names its line in errors.
std::vector<double> asciiRow(const std::string& line, const std::string& path,
                             const std::string& where) {
  std::vector<double> row;
  const char* p = line.c_str();
  const char* const e = p + line.size();
  auto blank = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
  while (true) {
    while (p < e && blank(*p)) ++p;
    if (p == e) return row;
    const char* tok = p;
    while (p < e && !blank(*p)) ++p;
    char* end = nullptr;
    const double v = std::strtod(tok, &end);
    if (end != p) {
      fail(path,
           where + ": '" + std::string(tok, std::min<size_t>(p - tok, 20)) + "' is not a number");
    }
    row.push_back(v);
  }
}

// DATA ascii: one row of h.values numbers per point, h.points rows (blank lines skipped).
Cloud::Ptr readAscii(std::istream& in, const std::string& path, const PcdHeader& h,
                     const XyzFields& xyz) {
  Cloud::Ptr cloud(new Cloud);
  std::string line;
  long long rows = 0;
  for (long long n = 1; std::getline(in, line); ++n) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::string where =
        "ASCII data row " + std::to_string(n) + " (line " + std::to_string(h.lines + n) + ")";
    const std::vector<double> row = asciiRow(line, path, where);
    if (static_cast<long long>(row.size()) != h.values) {
      fail(path, where + " has " + std::to_string(row.size()) + " values, the header says " +
                     std::to_string(h.values));
    }
    // Rows beyond POINTS are counted for the error below, not kept.
    if (++rows <= h.points) {
      addPoint(*cloud, static_cast<float>(row[xyz[0]->value_index]),
               static_cast<float>(row[xyz[1]->value_index]),
               static_cast<float>(row[xyz[2]->value_index]));
    }
  }
  if (rows != h.points) {
    fail(path, "ASCII data has " + std::to_string(rows) + " rows, POINTS says " +
                   std::to_string(h.points));
  }
  return finish(cloud);
}

// DATA binary: h.points records of h.point_step bytes, read a chunk at a time.
Cloud::Ptr readBinary(std::istream& in, const std::string& path, const PcdHeader& h,
                      const XyzFields& xyz) {
  if (h.points * h.point_step > h.data_bytes) fail(path, "truncated PCD (binary data too short)");
  Cloud::Ptr cloud(new Cloud);
  cloud->reserve(h.points);
  const long long per_chunk = std::max<long long>(1, kChunkBytes / h.point_step);
  std::vector<char> buf;
  for (long long first = 0; first < h.points; first += per_chunk) {
    const long long n = std::min(per_chunk, h.points - first);
    buf.resize(static_cast<size_t>(n * h.point_step));
    if (!in.read(buf.data(), static_cast<std::streamsize>(buf.size()))) {
      fail(path, "truncated PCD (binary data too short)");
    }
    for (long long i = 0; i < n; ++i) {
      const char* p = buf.data() + i * h.point_step;
      addPoint(*cloud, binaryValue(p + xyz[0]->offset, *xyz[0]),
               binaryValue(p + xyz[1]->offset, *xyz[1]), binaryValue(p + xyz[2]->offset, *xyz[2]));
    }
  }
  return finish(cloud);
}

// The LZF block of DATA binary_compressed (sizes u32 compressed, u32 uncompressed, then the
// data), checked against the file and POINTS before anything is allocated, decoded.
std::vector<char> decompressBlock(std::istream& in, const std::string& path, const PcdHeader& h) {
  uint32_t sizes[2] = {0, 0};
  if (h.data_bytes < 8 || !in.read(reinterpret_cast<char*>(sizes), 8)) {
    fail(path, "truncated PCD (no compressed block)");
  }
  if (sizes[0] > h.data_bytes - 8) fail(path, "truncated PCD (compressed data too short)");
  if (static_cast<long long>(sizes[1]) != h.points * h.point_step) {
    fail(path, "malformed PCD (compressed size disagrees with POINTS)");
  }
  if (sizes[1] > kMaxLzfRatio * sizes[0]) {
    fail(path, "malformed PCD (" + std::to_string(sizes[0]) + " compressed bytes cannot hold " +
                   std::to_string(sizes[1]) + ")");
  }
  std::vector<char> packed(sizes[0]);
  if (!in.read(packed.data(), sizes[0])) fail(path, "truncated PCD (compressed data too short)");
  std::vector<char> raw(sizes[1]);
  if (pcl::lzfDecompress(packed.data(), sizes[0], raw.data(), sizes[1]) != sizes[1]) {
    fail(path, "malformed PCD (the compressed data do not decode)");
  }
  return raw;
}

// DATA binary_compressed: decoded, the fields are stored one after the other (all x, then all
// y, ...), so value i of field f is at points x offset(f) + i x size(f).
Cloud::Ptr readCompressed(std::istream& in, const std::string& path, const PcdHeader& h,
                          const XyzFields& xyz) {
  Cloud::Ptr cloud(new Cloud);
  if (h.points == 0) return finish(cloud);
  const std::vector<char> raw = decompressBlock(in, path, h);
  cloud->reserve(h.points);
  const char* column[3];
  for (int k = 0; k < 3; ++k) column[k] = raw.data() + h.points * xyz[k]->offset;
  for (long long i = 0; i < h.points; ++i) {
    addPoint(*cloud, binaryValue(column[0] + i * xyz[0]->size, *xyz[0]),
             binaryValue(column[1] + i * xyz[1]->size, *xyz[1]),
             binaryValue(column[2] + i * xyz[2]->size, *xyz[2]));
  }
  return finish(cloud);
}

}  // namespace

Cloud::Ptr readPcdFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "cannot open file");
  const PcdHeader h = readHeader(in, path);
  const XyzFields xyz = xyzFields(h, path);
  if (h.data == "ascii") return readAscii(in, path, h, xyz);
  if (h.data == "binary") return readBinary(in, path, h, xyz);
  return readCompressed(in, path, h, xyz);
}

}  // namespace dtif
