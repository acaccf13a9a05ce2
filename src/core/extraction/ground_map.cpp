#include "dtif/core/extraction/ground_map.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "core/byte_io.h"
#include "dtif/core/extraction/extraction_stages.h"

namespace dtif {

namespace {

constexpr int8_t kEmptyCode = -128;
constexpr int8_t kEscapeCode = -127;
constexpr size_t kHeaderBytes = 4 + 4 + 8 + 4 + 4 + 2 + 2;
/// Histogram of elevation differences: 5 cm bins over +-kMaxDz.
constexpr double kBin = 0.05, kMaxDz = 30.0;

/// Value the encoder predicts for cell k: the left neighbour, else the one above, else `last`.
int predict(const GroundMap& m, size_t k, int last) {
  const size_t col = k % static_cast<size_t>(m.width);
  if (col > 0 && m.z[k - 1] != GroundMap::kUnknown) return m.z[k - 1];
  if (k >= static_cast<size_t>(m.width) && m.z[k - m.width] != GroundMap::kUnknown)
    return m.z[k - m.width];
  return last;
}

}  // namespace

bool GroundMap::wellFormed() const {
  return cell_m > 0.0 && std::isfinite(cell_m) && z_step_m > 0.0 && std::isfinite(z_step_m) &&
         std::isfinite(z0_m) && width > 0 && height > 0 && width <= kMaxGroundMapSide &&
         height <= kMaxGroundMapSide &&
         z.size() == static_cast<size_t>(width) * static_cast<size_t>(height);
}

size_t GroundMap::count() const {
  return static_cast<size_t>(
      std::count_if(z.begin(), z.end(), [](int16_t v) { return v != kUnknown; }));
}

bool GroundMap::at(double x, double y, double* z_m) const {
  if (empty()) return false;
  const double fx = std::floor(x / cell_m) - x0, fy = std::floor(y / cell_m) - y0;
  if (!(fx >= 0.0 && fy >= 0.0 && fx < width && fy < height)) return false;
  const int16_t v = z[static_cast<size_t>(fy) * width + static_cast<size_t>(fx)];
  if (v == kUnknown) return false;
  *z_m = z0_m + v * z_step_m;
  return true;
}

namespace {

// The lowest point (z + origin) and the point count of every cell of the box lo..hi, binned in
// the same pass that bounds the points (the box's cells at the map's first cell size).
struct BoxCells {
  bool used = false;
  int64_t x0 = 0, y0 = 0, width = 0, height = 0;
  std::vector<double> low;
  std::vector<uint32_t> hits;

  BoxCells(const Eigen::Vector2d& lo, const Eigen::Vector2d& hi, double cell_m) {
    const double w = std::floor(hi.x() / cell_m) - std::floor(lo.x() / cell_m) + 1.0;
    const double h = std::floor(hi.y() / cell_m) - std::floor(lo.y() / cell_m) + 1.0;
    if (!(w >= 1.0 && h >= 1.0 && w * h <= 4e6)) return;  // a stray box: two passes
    used = true;
    x0 = floorIndex(lo.x() / cell_m), y0 = floorIndex(lo.y() / cell_m);
    width = static_cast<int64_t>(w), height = static_cast<int64_t>(h);
    low.assign(static_cast<size_t>(width * height), std::numeric_limits<double>::infinity());
    hits.assign(low.size(), 0);
  }
  // A point inside the box lies in one of its cells: floor and division are monotonic.
  void add(double px, double py, double pz, const Divisor& by_cell) {
    const size_t k = static_cast<size_t>((floorIndex(by_cell(py)) - y0) * width +
                                         (floorIndex(by_cell(px)) - x0));
    low[k] = std::min(low[k], pz);
    ++hits[k];
  }
};

// The map's values: each cell's lowest point in z steps, unknown under min_points points.
void quantise(const std::vector<float>& low, const std::vector<uint32_t>& hits, uint32_t min_points,
              GroundMap* m) {
  m->z.resize(low.size());
  for (size_t k = 0; k < low.size(); ++k) {
    m->z[k] = std::isfinite(low[k]) && hits[k] >= min_points
                  ? static_cast<int16_t>(std::lround(low[k] / m->z_step_m))
                  : GroundMap::kUnknown;
  }
}

}  // namespace

GroundMap makeGroundMap(const float* x, const float* y, const float* z, size_t n,
                        const Eigen::Vector3d& origin, const Eigen::Vector2d& lo,
                        const Eigen::Vector2d& hi, double cell_m, double z_step_m,
                        uint32_t min_points) {
  GroundMap m;
  if (!(cell_m > 0.0) || !(z_step_m > 0.0)) return m;
  double minx = std::numeric_limits<double>::infinity(), miny = minx, minz = minx;
  double maxx = -minx, maxy = -minx, maxz = -minx;
  const auto inside = [&](size_t i) {
    if (!std::isfinite(x[i]) || !std::isfinite(y[i]) || !std::isfinite(z[i])) return false;
    const double px = x[i] + origin.x(), py = y[i] + origin.y();
    return px >= lo.x() && py >= lo.y() && px <= hi.x() && py <= hi.y();
  };
  BoxCells box(lo, hi, cell_m);
  const Divisor by_cell(cell_m);
  for (size_t i = 0; i < n; ++i) {
    if (!inside(i)) continue;
    const double px = x[i] + origin.x(), py = y[i] + origin.y(), pz = z[i] + origin.z();
    minx = std::min(minx, px), maxx = std::max(maxx, px);
    miny = std::min(miny, py), maxy = std::max(maxy, py);
    minz = std::min(minz, pz), maxz = std::max(maxz, pz);
    if (box.used) box.add(px, py, pz, by_cell);
  }
  if (!(minx <= maxx)) return m;
  // A tall extent in z would overflow the 16-bit values: coarser steps keep it in range.
  while ((maxz - minz) / z_step_m > 60000.0) z_step_m *= 2.0;
  for (;;) {
    m.x0 = static_cast<int32_t>(std::floor(minx / cell_m));
    m.y0 = static_cast<int32_t>(std::floor(miny / cell_m));
    m.width = static_cast<int32_t>(std::floor(maxx / cell_m)) - m.x0 + 1;
    m.height = static_cast<int32_t>(std::floor(maxy / cell_m)) - m.y0 + 1;
    if (m.width <= kMaxGroundMapSide && m.height <= kMaxGroundMapSide) break;
    cell_m *= 2.0;
    box.used = false;  // binned at the finer size: bin again
  }
  m.cell_m = cell_m;
  m.z_step_m = z_step_m;
  m.z0_m = std::floor(minz);
  std::vector<float> low(static_cast<size_t>(m.width) * m.height,
                         std::numeric_limits<float>::infinity());
  std::vector<uint32_t> hits(low.size(), 0);
  if (box.used) {
    // The map's cells within the box's (the points' extent lies inside the box). The float of
    // (z - z0) is monotonic in z: that of the lowest z is the lowest of them.
    for (int32_t r = 0; r < m.height; ++r) {
      for (int32_t c = 0; c < m.width; ++c) {
        const size_t b = static_cast<size_t>((m.y0 + r - box.y0) * box.width + (m.x0 + c - box.x0));
        const size_t k = static_cast<size_t>(r) * m.width + c;
        hits[k] = box.hits[b];
        if (hits[k] > 0) low[k] = static_cast<float>(box.low[b] - m.z0_m);
      }
    }
  } else {
    for (size_t i = 0; i < n; ++i) {
      if (!inside(i)) continue;
      const int64_t ix = static_cast<int64_t>(std::floor((x[i] + origin.x()) / cell_m)) - m.x0;
      const int64_t iy = static_cast<int64_t>(std::floor((y[i] + origin.y()) / cell_m)) - m.y0;
      if (ix < 0 || iy < 0 || ix >= m.width || iy >= m.height) continue;  // rounding at the edge
      const size_t k = static_cast<size_t>(iy) * m.width + static_cast<size_t>(ix);
      low[k] = std::min(low[k], static_cast<float>(z[i] + origin.z() - m.z0_m));
      ++hits[k];
    }
  }
  quantise(low, hits, min_points, &m);
  return m;
}

namespace {

// The cells of the box lo..hi: its column and row index range in S, clipped to the gathered
// cells', and which columns / rows the box's edges cut (cl, ch, rl, rh; their points are
// tested one by one).
struct BoxRange {
  int64_t cl, ch, rl, rh;  // the cells of lo and hi
  int64_t c0, c1, r0, r1;  // clipped to the gathered cells
  bool edge(int64_t c, int64_t r) const { return c == cl || c == ch || r == rl || r == rh; }
};

// Marks the grid cells that may hold points of map columns [c_lo, c_hi] x rows [r_lo, r_hi]
// (one grid cell of margin for the rounding of local coordinates).
void markGridCells(const GroundGrid& grid, const GroundMapCells& mc, int64_t c_lo, int64_t c_hi,
                   int64_t r_lo, int64_t r_hi, std::vector<char>* mark) {
  const auto gridIndex = [&](double local, double grid_min, int n) {
    const double g = std::floor((local - grid_min) / grid.cell_m);
    return static_cast<int>(std::clamp(g, -1.0, static_cast<double>(n)));
  };
  const int gx0 = std::max(0, gridIndex(c_lo * mc.cell_m - mc.ox, grid.minx, grid.nx) - 1);
  const int gx1 =
      std::min(grid.nx - 1, gridIndex((c_hi + 1) * mc.cell_m - mc.ox, grid.minx, grid.nx) + 1);
  const int gy0 = std::max(0, gridIndex(r_lo * mc.cell_m - mc.oy, grid.miny, grid.ny) - 1);
  const int gy1 =
      std::min(grid.ny - 1, gridIndex((r_hi + 1) * mc.cell_m - mc.oy, grid.miny, grid.ny) + 1);
  for (int gy = gy0; gy <= gy1; ++gy)
    for (int gx = gx0; gx <= gx1; ++gx) (*mark)[static_cast<size_t>(gy) * grid.nx + gx] = 1;
}

// The lowest point (z + oz) and the count of the box's edge cells, from the points of the grid
// cells that hold them, each point tested against the box as makeGroundMap tests it.
void edgeCells(const GroundMapCells& mc, const GroundGrid& grid, const BoxRange& b,
               const Eigen::Vector2d& lo, const Eigen::Vector2d& hi, std::vector<double>* low,
               std::vector<uint32_t>* hits) {
  std::vector<char> mark(grid.cells(), 0);
  for (const int64_t c : {b.cl, b.ch})
    if (c >= b.c0 && c <= b.c1) markGridCells(grid, mc, c, c, b.r0, b.r1, &mark);
  for (const int64_t r : {b.rl, b.rh})
    if (r >= b.r0 && r <= b.r1) markGridCells(grid, mc, b.c0, b.c1, r, r, &mark);
  const Divisor by_cell(mc.cell_m);
  const int64_t w = b.c1 - b.c0 + 1;
  for (size_t g = 0; g < mark.size(); ++g) {
    if (!mark[g]) continue;
    for (uint32_t k = grid.start[g]; k < grid.start[g + 1]; ++k) {
      const GroundGrid::SortedPoint& q = grid.sorted[k];
      const double px = q.x + mc.ox, py = q.y + mc.oy;
      const int64_t c = floorIndex(by_cell(px)), r = floorIndex(by_cell(py));
      if (c < b.c0 || c > b.c1 || r < b.r0 || r > b.r1 || !b.edge(c, r)) continue;
      if (!(px >= lo.x() && py >= lo.y() && px <= hi.x() && py <= hi.y())) continue;
      const size_t i = static_cast<size_t>((r - b.r0) * w + (c - b.c0));
      (*low)[i] = std::min((*low)[i], q.z + mc.oz);
      ++(*hits)[i];
    }
  }
}

}  // namespace

bool groundMapOfCells(const GroundMapCells& mc, const GroundGrid& grid, const Eigen::Vector2d& lo,
                      const Eigen::Vector2d& hi, const TrunkExtractorParams& p, GroundMap* map) {
  const double z_step_m = p.ground_map_z_step_m;
  if (!mc.used || mc.cell_m != p.ground_map_cell_m || !(z_step_m > 0.0)) return false;
  const Divisor by_cell(mc.cell_m);
  BoxRange b;
  b.cl = floorIndex(by_cell(lo.x())), b.ch = floorIndex(by_cell(hi.x()));
  b.rl = floorIndex(by_cell(lo.y())), b.rh = floorIndex(by_cell(hi.y()));
  b.c0 = std::max(b.cl, mc.x0), b.c1 = std::min(b.ch, mc.x0 + mc.width - 1);
  b.r0 = std::max(b.rl, mc.y0), b.r1 = std::min(b.rh, mc.y0 + mc.height - 1);
  if (b.c0 > b.c1 || b.r0 > b.r1) {  // no point inside the box
    *map = GroundMap();
    return true;
  }
  const int64_t w = b.c1 - b.c0 + 1, h = b.r1 - b.r0 + 1;
  // Inner cells hold only points inside the box: a point left of lo lies in lo's column or
  // further left (floor and division are monotonic), and so on. Edge cells: point by point.
  std::vector<double> low(static_cast<size_t>(w * h), std::numeric_limits<double>::infinity());
  std::vector<uint32_t> hits(low.size(), 0);
  for (int64_t r = b.r0; r <= b.r1; ++r) {
    for (int64_t c = b.c0; c <= b.c1; ++c) {
      if (b.edge(c, r)) continue;
      const size_t s = static_cast<size_t>((r - mc.y0) * mc.width + (c - mc.x0));
      const size_t i = static_cast<size_t>((r - b.r0) * w + (c - b.c0));
      hits[i] = mc.hits[s];
      if (hits[i] > 0) low[i] = mc.low[s] + mc.oz;
    }
  }
  edgeCells(mc, grid, b, lo, hi, &low, &hits);
  // The extent of the points inside: the first and last cells holding any (makeGroundMap's
  // floor(min x / cell) is the cell of the lowest x).
  int64_t cmin = b.c1 + 1, cmax = b.c0 - 1, rmin = b.r1 + 1, rmax = b.r0 - 1;
  double minz = std::numeric_limits<double>::infinity();
  for (int64_t r = b.r0; r <= b.r1; ++r) {
    for (int64_t c = b.c0; c <= b.c1; ++c) {
      const size_t i = static_cast<size_t>((r - b.r0) * w + (c - b.c0));
      if (hits[i] == 0) continue;
      cmin = std::min(cmin, c), cmax = std::max(cmax, c);
      rmin = std::min(rmin, r), rmax = std::max(rmax, r);
      minz = std::min(minz, low[i]);
    }
  }
  if (cmin > cmax) {
    *map = GroundMap();
    return true;
  }
  // A coarser z step (a tall extent; the bound on all points bounds the box's) or cell (a wide
  // one): makeGroundMap's own pass.
  if (!((mc.max_z - minz) / z_step_m <= 60000.0)) return false;
  if (cmax - cmin + 1 > kMaxGroundMapSide || rmax - rmin + 1 > kMaxGroundMapSide) return false;
  GroundMap m;
  m.x0 = static_cast<int32_t>(cmin), m.y0 = static_cast<int32_t>(rmin);
  m.width = static_cast<int32_t>(cmax - cmin + 1), m.height = static_cast<int32_t>(rmax - rmin + 1);
  m.cell_m = mc.cell_m;
  m.z_step_m = z_step_m;
  m.z0_m = std::floor(minz);
  std::vector<float> mlow(static_cast<size_t>(m.width) * m.height,
                          std::numeric_limits<float>::infinity());
  std::vector<uint32_t> mhits(mlow.size(), 0);
  for (int32_t r = 0; r < m.height; ++r) {
    for (int32_t c = 0; c < m.width; ++c) {
      const size_t i = static_cast<size_t>((rmin + r - b.r0) * w + (cmin + c - b.c0));
      const size_t k = static_cast<size_t>(r) * m.width + c;
      mhits[k] = hits[i];
      if (mhits[k] > 0) mlow[k] = static_cast<float>(low[i] - m.z0_m);
    }
  }
  quantise(mlow, mhits, static_cast<uint32_t>(p.ground_map_min_points), &m);
  *map = std::move(m);
  return true;
}

namespace {

// The w x h cells of m from column c0, row r0 (inside m).
GroundMap cropCells(const GroundMap& m, int32_t c0, int32_t r0, int32_t w, int32_t h) {
  GroundMap out = m;
  out.x0 = m.x0 + c0;
  out.y0 = m.y0 + r0;
  out.width = w;
  out.height = h;
  out.z.resize(static_cast<size_t>(w) * h);
  for (int32_t r = 0; r < h; ++r) {
    const auto row = m.z.begin() + static_cast<std::ptrdiff_t>(r0 + r) * m.width + c0;
    std::copy(row, row + w, out.z.begin() + static_cast<std::ptrdiff_t>(r) * w);
  }
  return out;
}

// m with twice its z step. Values 2k and 2k + 1 both become k, with z0 raised by a quarter of
// the new step, so the rounding errors (-+ step / 4) cancel over a map (no bias in dz).
GroundMap coarserSteps(const GroundMap& m) {
  GroundMap out = m;
  out.z_step_m = 2.0 * m.z_step_m;
  out.z0_m = m.z0_m + 0.25 * out.z_step_m;
  for (int16_t& v : out.z) {
    if (v != GroundMap::kUnknown) v = static_cast<int16_t>(v >= 0 ? v / 2 : -((1 - v) / 2));
  }
  return out;
}

}  // namespace

GroundMap fitGroundMapBytes(GroundMap m, size_t max_bytes) {
  if (max_bytes == 0 || m.empty()) return m;
  size_t bytes = encodeGroundMap(m).size();
  if (bytes <= max_bytes) return m;
  // Coarser heights first (a map's differences are averaged over hundreds of cells, where
  // half-step errors cancel), then fewer cells: a crop loses whole stretches of ground that a
  // loop's partner may share only at the edge.
  m = coarserSteps(m);
  bytes = encodeGroundMap(m).size();
  for (int attempt = 0; attempt < 12 && bytes > max_bytes; ++attempt) {
    // Bytes grow about with the area: shrink both sides by the square root of the excess, a
    // little more so that one or two crops usually do.
    const double side = 0.97 * std::sqrt(static_cast<double>(max_bytes) / bytes);
    const int32_t w = std::max(1, static_cast<int32_t>(m.width * side));
    const int32_t h = std::max(1, static_cast<int32_t>(m.height * side));
    if (w == m.width && h == m.height) break;
    m = cropCells(m, (m.width - w) / 2, (m.height - h) / 2, w, h);
    bytes = encodeGroundMap(m).size();
  }
  return bytes <= max_bytes ? m : GroundMap();
}

std::vector<uint8_t> encodeGroundMap(const GroundMap& m) {
  if (m.empty()) return {};
  if (!m.wellFormed()) throw std::runtime_error("ground map is not well formed");
  detail::ByteWriter raw;
  raw.bytes.reserve(m.z.size());
  int last = 0;
  for (size_t k = 0; k < m.z.size(); ++k) {
    const int v = m.z[k];
    if (v == GroundMap::kUnknown) {
      raw.put<int8_t>(kEmptyCode);
      continue;
    }
    const int d = v - predict(m, k, last);
    last = v;
    if (d > kEscapeCode && d <= 127) {
      raw.put<int8_t>(static_cast<int8_t>(d));
    } else {
      raw.put<int8_t>(kEscapeCode);
      raw.put<int16_t>(static_cast<int16_t>(v));
    }
  }
  detail::ByteWriter out;
  out.put<float>(static_cast<float>(m.cell_m));
  out.put<float>(static_cast<float>(m.z_step_m));
  out.put<double>(m.z0_m);
  out.put<int32_t>(m.x0);
  out.put<int32_t>(m.y0);
  out.put<uint16_t>(static_cast<uint16_t>(m.width));
  out.put<uint16_t>(static_cast<uint16_t>(m.height));
  const size_t header = out.bytes.size();
  uLongf packed = compressBound(raw.bytes.size());
  out.bytes.resize(header + packed);
  // Run-length matches only (Z_RLE): the cell differences are short symbols with runs of
  // empty cells and no long repeats, so a full match search (compress2 at level 9) made the
  // stream ~1 % smaller at 3x the time, and describe encodes a map up to four times to fit it
  // to the descriptor's budget. Any inflate reads either.
  z_stream zs{};
  if (deflateInit2(&zs, Z_BEST_COMPRESSION, Z_DEFLATED, 15, 8, Z_RLE) != Z_OK) {
    throw std::runtime_error("ground map compression failed");
  }
  zs.next_in = const_cast<Bytef*>(raw.bytes.data());
  zs.avail_in = static_cast<uInt>(raw.bytes.size());
  zs.next_out = out.bytes.data() + header;
  zs.avail_out = static_cast<uInt>(packed);
  const int status = deflate(&zs, Z_FINISH);
  packed = zs.total_out;
  deflateEnd(&zs);
  if (status != Z_STREAM_END) throw std::runtime_error("ground map compression failed");
  out.bytes.resize(header + packed);
  return out.bytes;
}

GroundMap decodeGroundMap(const uint8_t* data, size_t size) {
  GroundMap m;
  if (size == 0) return m;
  if (size <= kHeaderBytes) throw std::runtime_error("ground map shorter than its header");
  detail::ByteReader head(data, kHeaderBytes, "ground map header");
  m.cell_m = head.get<float>();
  m.z_step_m = head.get<float>();
  m.z0_m = head.get<double>();
  m.x0 = head.get<int32_t>();
  m.y0 = head.get<int32_t>();
  m.width = head.get<uint16_t>();
  m.height = head.get<uint16_t>();
  // Bounded before anything is allocated: a header of 20000 x 20000 cells in an 800-byte
  // message asked for 1.28 GB. zlib inflates at most ~1032:1, so the stream must be long enough.
  if (m.width > kMaxGroundMapSide || m.height > kMaxGroundMapSide) {
    throw std::runtime_error("ground map of " + std::to_string(m.width) + " x " +
                             std::to_string(m.height) + " cells exceeds kMaxGroundMapSide (" +
                             std::to_string(kMaxGroundMapSide) + ")");
  }
  const size_t cells = static_cast<size_t>(m.width) * m.height;
  if (cells > 1100 * (size - kHeaderBytes)) {
    throw std::runtime_error("ground map stream too short for its cells");
  }
  if (!(m.cell_m > 0.0) || !std::isfinite(m.cell_m) || !(m.z_step_m > 0.0) ||
      !std::isfinite(m.z_step_m) || !std::isfinite(m.z0_m) || cells == 0) {
    throw std::runtime_error("ground map header is invalid");
  }
  // Every cell takes one byte, an escaped one three.
  std::vector<uint8_t> raw(3 * cells + 1);
  uLongf unpacked = raw.size();
  if (uncompress(raw.data(), &unpacked, data + kHeaderBytes, size - kHeaderBytes) != Z_OK) {
    throw std::runtime_error("ground map stream is corrupt");
  }
  m.z.resize(cells);
  detail::ByteReader r(raw.data(), unpacked, "ground map stream");
  int last = 0;
  for (size_t k = 0; k < cells; ++k) {
    const int8_t code = r.get<int8_t>();
    if (code == kEmptyCode) {
      m.z[k] = GroundMap::kUnknown;
      continue;
    }
    int v;
    if (code == kEscapeCode) {
      v = r.get<int16_t>();
    } else {
      v = predict(m, k, last) + code;
    }
    if (v == GroundMap::kUnknown || v > std::numeric_limits<int16_t>::max() ||
        v < std::numeric_limits<int16_t>::min()) {
      throw std::runtime_error("ground map value out of range");
    }
    m.z[k] = static_cast<int16_t>(v);
    last = v;
  }
  if (r.remaining() != 0) throw std::runtime_error("ground map stream has trailing bytes");
  return m;
}

GroundDifferences groundDifferences(const GroundMap& q, const GroundMap& c, const Pose& T_c_q) {
  GroundDifferences out;
  if (q.empty() || c.empty()) return out;
  for (int32_t iy = 0; iy < q.height; ++iy) {
    for (int32_t ix = 0; ix < q.width; ++ix) {
      const int16_t v = q.z[static_cast<size_t>(iy) * q.width + ix];
      if (v == GroundMap::kUnknown) continue;
      const Eigen::Vector3d p =
          T_c_q * Eigen::Vector3d((q.x0 + ix + 0.5) * q.cell_m, (q.y0 + iy + 0.5) * q.cell_m,
                                  q.z0_m + v * q.z_step_m);
      double zc;
      if (!c.at(p.x(), p.y(), &zc)) continue;
      out.xy.push_back(p.head<2>());
      out.dz.push_back(zc - p.z());
    }
  }
  return out;
}

GroundElevation groundElevation(const GroundMap& q, const GroundMap& c, const Pose& T_c_q,
                                double window_m) {
  if (q.empty() || c.empty()) return GroundElevation();
  return groundElevationOf(groundDifferences(q, c, T_c_q).dz, window_m);
}

GroundElevation groundElevationOf(const std::vector<double>& differences, double window_m) {
  GroundElevation out;
  const int nb = static_cast<int>(std::lround(kMaxDz / kBin));
  std::vector<double> hist(2 * nb + 1, 0.0);
  std::vector<double> dz;
  out.compared = static_cast<int>(differences.size());
  for (double d : differences) {
    const long b = std::lround(d / kBin);
    if (std::abs(b) > nb) continue;
    hist[static_cast<size_t>(b + nb)] += 1.0;
    dz.push_back(d);
  }
  if (dz.empty()) return out;
  // Smoothed [1 2 1]: the true difference straddles bins.
  std::vector<double> s(hist.size(), 0.0);
  for (size_t i = 1; i + 1 < hist.size(); ++i) s[i] = hist[i - 1] + 2.0 * hist[i] + hist[i + 1];
  const size_t peak = static_cast<size_t>(std::max_element(s.begin(), s.end()) - s.begin());
  const double mode = (static_cast<double>(peak) - nb) * kBin;
  double sum = 0.0, sum2 = 0.0;
  for (double d : dz) {
    if (std::abs(d - mode) > window_m) continue;
    ++out.support;
    sum += d;
    sum2 += d * d;
  }
  if (out.support == 0) return out;
  out.dz_m = sum / out.support;
  out.spread_m = std::sqrt(std::max(0.0, sum2 / out.support - out.dz_m * out.dz_m));
  double second = 0.0;
  const double exclude = 2.0 * window_m + kBin;
  for (size_t i = 0; i < s.size(); ++i) {
    if (std::abs((static_cast<double>(i) - nb) * kBin - mode) > exclude)
      second = std::max(second, s[i]);
  }
  out.ambiguity = s[peak] > 0.0 ? second / s[peak] : 1.0;
  out.ok = true;
  return out;
}

}  // namespace dtif
