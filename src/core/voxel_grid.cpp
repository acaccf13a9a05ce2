#include "dtif/core/voxel_grid.h"

#include <algorithm>
#include <cmath>

#include "dtif/core/cells.h"

namespace dtif {

VoxelCentroidGrid::VoxelCentroidGrid(double voxel_m) : inv_(1.0 / voxel_m) { clear(); }

void VoxelCentroidGrid::add(const Eigen::Vector3f& p) {
  const int64_t x = cellIndex(p.x() * inv_) + (1 << 20);
  const int64_t y = cellIndex(p.y() * inv_) + (1 << 20);
  const int64_t z = cellIndex(p.z() * inv_) + (1 << 20);
  if (x < 0 || y < 0 || z < 0 || x >= (1 << 21) || y >= (1 << 21) || z >= (1 << 21)) return;
  const uint64_t key = (static_cast<uint64_t>(x) << 42) | (static_cast<uint64_t>(y) << 21) |
                       static_cast<uint64_t>(z);
  if (2 * (used_ + 1) > cells_.size()) grow();
  Cell& c = find(key);
  if (c.n == 0) {
    c.key = key;
    ++used_;
  }
  c.sum += p;
  ++c.n;
  ++raw_;
}

std::vector<Eigen::Vector3f> VoxelCentroidGrid::centroids() const {
  std::vector<Cell> v;  // copies, sorted in place: faster than chasing pointers
  v.reserve(used_);
  for (const Cell& c : cells_) {
    if (c.n) v.push_back(c);
  }
  std::sort(v.begin(), v.end(), [](const Cell& a, const Cell& b) { return a.key < b.key; });
  std::vector<Eigen::Vector3f> out;
  out.reserve(v.size());
  for (const Cell& c : v) out.push_back(c.sum / static_cast<float>(c.n));
  return out;
}

void VoxelCentroidGrid::clear() {
  if (cells_.size() < (1 << 16)) {
    cells_.assign(1 << 16, Cell());
  } else {
    std::fill(cells_.begin(), cells_.end(), Cell());
  }
  used_ = 0;
  raw_ = 0;
}

VoxelCentroidGrid::Cell& VoxelCentroidGrid::find(uint64_t key) {
  const size_t mask = cells_.size() - 1;
  size_t i = (key * 0x9E3779B97F4A7C15ULL) >> 20 & mask;
  while (cells_[i].n != 0 && cells_[i].key != key) i = (i + 1) & mask;
  return cells_[i];
}

void VoxelCentroidGrid::grow() {
  std::vector<Cell> old;
  old.swap(cells_);
  cells_.assign(old.size() * 2, Cell());
  for (const Cell& c : old) {
    if (c.n) find(c.key) = c;
  }
}

}  // namespace dtif
