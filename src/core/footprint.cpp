// Occupied-cell footprint of a submap and the overlap of two aligned footprints.
#include "dtif/core/footprint.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace dtif {

size_t Footprint::count() const {
  size_t n = 0;
  for (uint8_t b : bits) n += static_cast<size_t>(__builtin_popcount(b));
  return n;
}

bool Footprint::wellFormed() const {
  return cell_m > 0.0 && std::isfinite(cell_m) && width > 0 && height > 0 && width <= 65535 &&
         height <= 65535 && bits.size() == (static_cast<size_t>(width) * height + 7) / 8;
}

bool Footprint::occupied(int64_t ix, int64_t iy) const {
  const int64_t cx = ix - x0, cy = iy - y0;
  if (cx < 0 || cy < 0 || cx >= width || cy >= height) return false;
  const int64_t k = cy * width + cx;
  return (bits[static_cast<size_t>(k / 8)] >> (k % 8)) & 1u;
}

Footprint makeFootprint(const std::vector<std::pair<int64_t, int64_t>>& cells, double cell_m) {
  Footprint f;
  if (cells.empty() || !(cell_m > 0.0) || !std::isfinite(cell_m)) return f;
  int64_t minx = std::numeric_limits<int64_t>::max(), miny = minx;
  int64_t maxx = std::numeric_limits<int64_t>::min(), maxy = maxx;
  for (const auto& [x, y] : cells) {
    minx = std::min(minx, x), maxx = std::max(maxx, x);
    miny = std::min(miny, y), maxy = std::max(maxy, y);
  }
  // Coarsen by powers of two until the bitmap fits (floor division keeps cells nested).
  int shift = 0;
  auto coarse = [&](int64_t v) { return v >= 0 ? v >> shift : -((-v - 1) >> shift) - 1; };
  while (shift < 40 && (coarse(maxx) - coarse(minx) + 1 > kMaxFootprintSide ||
                        coarse(maxy) - coarse(miny) + 1 > kMaxFootprintSide)) {
    ++shift;
  }
  const int64_t x0 = coarse(minx), y0 = coarse(miny);
  if (x0 < std::numeric_limits<int32_t>::min() || x0 > std::numeric_limits<int32_t>::max() ||
      y0 < std::numeric_limits<int32_t>::min() || y0 > std::numeric_limits<int32_t>::max()) {
    return f;  // beyond any survey's coordinates at this cell size
  }
  f.cell_m = std::ldexp(cell_m, shift);
  f.x0 = static_cast<int32_t>(x0);
  f.y0 = static_cast<int32_t>(y0);
  f.width = static_cast<int32_t>(coarse(maxx) - x0 + 1);
  f.height = static_cast<int32_t>(coarse(maxy) - y0 + 1);
  f.bits.assign((static_cast<size_t>(f.width) * f.height + 7) / 8, 0);
  for (const auto& [x, y] : cells) {
    const int64_t k = (coarse(y) - y0) * f.width + (coarse(x) - x0);
    f.bits[static_cast<size_t>(k / 8)] |= static_cast<uint8_t>(1u << (k % 8));
  }
  return f;
}

double footprintOverlap(const Footprint& q, const Footprint& c, const Pose& T_c_q) {
  const size_t nq = q.count(), nc = c.count();
  if (q.cell_m <= 0.0 || c.cell_m <= 0.0 || nq == 0 || nc == 0) return -1.0;
  size_t shared = 0;
  for (int32_t cy = 0; cy < q.height; ++cy) {
    for (int32_t cx = 0; cx < q.width; ++cx) {
      const int64_t k = static_cast<int64_t>(cy) * q.width + cx;
      if (!((q.bits[static_cast<size_t>(k / 8)] >> (k % 8)) & 1u)) continue;
      const Eigen::Vector3d p_q((q.x0 + cx + 0.5) * q.cell_m, (q.y0 + cy + 0.5) * q.cell_m, 0.0);
      const Eigen::Vector3d p_c = T_c_q * p_q;
      const auto ix = static_cast<int64_t>(std::floor(p_c.x() / c.cell_m));
      const auto iy = static_cast<int64_t>(std::floor(p_c.y() / c.cell_m));
      shared += c.occupied(ix, iy);
    }
  }
  // Footprints coarsened to different cell sizes make this approximate; the usual case is one
  // cell size on both sides, where it is the protocol's count.
  return static_cast<double>(shared) / static_cast<double>(std::min(nq, nc));
}

}  // namespace dtif
