// Trunk candidates (paper Sec. 3.B): vertical-continuity voxel columns in the low slab above
// the local ground, merged into candidates by connectivity. An open-addressing hash and
// counting sorts instead of kd-trees: the descriptor is timed (DESIGN.md).
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "dtif/core/extraction/extraction_stages.h"

namespace dtif {
namespace {

int findRoot(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

// Connected components of the passing columns within cluster_gap_m: a dense label per passing
// column (numbered by first column), -1 elsewhere.
std::vector<int> labelPassingColumns(const VoxelColumns& cols, const TrunkExtractorParams& p,
                                     int* ncand) {
  const size_t ncol = cols.size();
  std::vector<int> parent(ncol);
  std::iota(parent.begin(), parent.end(), 0);
  const int reach = std::max(1, static_cast<int>(std::ceil(p.cluster_gap_m / p.column_cell_m)));
  for (size_t c = 0; c < ncol; ++c) {
    if (!cols.pass[c]) continue;
    for (int dy = -reach; dy <= reach; ++dy) {
      for (int dx = -reach; dx <= reach; ++dx) {
        if (dy < 0 || (dy == 0 && dx <= 0)) continue;  // each pair once
        const int o = cols.find(cols.ix[c] + dx, cols.iy[c] + dy);
        if (o < 0 || !cols.pass[o]) continue;
        const int ra = findRoot(parent, static_cast<int>(c)), rb = findRoot(parent, o);
        if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
      }
    }
  }
  std::vector<int> root_label(ncol, -1), col_label(ncol, -1);
  *ncand = 0;
  for (size_t c = 0; c < ncol; ++c) {
    if (!cols.pass[c]) continue;
    const int r = findRoot(parent, static_cast<int>(c));
    if (root_label[r] < 0) root_label[r] = (*ncand)++;
    col_label[c] = root_label[r];
  }
  return col_label;
}

// Failing columns touching a labelled column join its candidate: that of the first passing
// neighbour in the order (dy, dx) = (-1, -1), (-1, 0), ..., (1, 1). Found from the passing
// columns, which are few, instead of by a search around every failing column (most columns).
void attachFailingColumns(const VoxelColumns& cols, std::vector<int>* col_label) {
  // rank[c]: the order of the first passing neighbour of c found so far; 9: none.
  std::vector<uint8_t> rank(cols.size(), 9);
  for (size_t o = 0; o < cols.size(); ++o) {
    if (!cols.pass[o]) continue;
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        const int c = cols.find(cols.ix[o] - dx, cols.iy[o] - dy);  // o lies at (dx, dy) of c
        const uint8_t r = static_cast<uint8_t>((dy + 1) * 3 + (dx + 1));
        if (c < 0 || cols.pass[c] || r >= rank[c]) continue;
        rank[c] = r;
        (*col_label)[c] = (*col_label)[o];
      }
    }
  }
}

}  // namespace

CellHash::CellHash(size_t expected) {
  size_t cap = 16;
  while (cap < 2 * expected + 1) cap <<= 1;
  keys_.assign(cap, kEmpty);
  vals_.assign(cap, -1);
  mask_ = cap - 1;
}

int CellHash::findOrInsert(uint64_t key, int next_index, bool* inserted) {
  size_t h = hash(key) & mask_;
  while (true) {
    if (keys_[h] == key) {
      *inserted = false;
      return vals_[h];
    }
    if (keys_[h] == kEmpty) {
      keys_[h] = key;
      vals_[h] = next_index;
      *inserted = true;
      return next_index;
    }
    h = (h + 1) & mask_;
  }
}

int CellHash::find(uint64_t key) const {
  size_t h = hash(key) & mask_;
  while (true) {
    if (keys_[h] == key) return vals_[h];
    if (keys_[h] == kEmpty) return -1;
    h = (h + 1) & mask_;
  }
}

size_t CellHash::hash(uint64_t k) {
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdULL;
  k ^= k >> 33;
  return static_cast<size_t>(k);
}

namespace {

// Column cells of the slab points (*cx, *cy) and their extent.
void slabCells(const LocalPoints& pts, VoxelColumns* cols, double cs, std::vector<int64_t>* cxs,
               std::vector<int64_t>* cys) {
  int64_t x0 = std::numeric_limits<int64_t>::max(), y0 = x0;
  int64_t x1 = std::numeric_limits<int64_t>::min(), y1 = x1;
  cxs->resize(cols->slab.size()), cys->resize(cols->slab.size());
  const uint32_t* slab = cols->slab.data();
  const size_t ns = cols->slab.size();
  for (size_t k = 0; k < ns; ++k) {
    prefetchGather(pts.x.data(), slab, k, ns), prefetchGather(pts.y.data(), slab, k, ns);
    const uint32_t i = slab[k];
    const int64_t cx = floorIndex(pts.x[i] / cs), cy = floorIndex(pts.y[i] / cs);
    (*cxs)[k] = cx, (*cys)[k] = cy;
    x0 = std::min(x0, cx), x1 = std::max(x1, cx);
    y0 = std::min(y0, cy), y1 = std::max(y1, cy);
  }
  // Dense when the grid is small next to the slab (always for survey data; a few far points
  // would make it huge).
  const double cells = (static_cast<double>(x1) - x0 + 1.0) * (static_cast<double>(y1) - y0 + 1.0);
  if (cells <= std::max(65536.0, 8.0 * static_cast<double>(cols->slab.size()))) {
    cols->gx0 = x0, cols->gy0 = y0, cols->gw = x1 - x0 + 1, cols->gh = y1 - y0 + 1;
    cols->grid.assign(static_cast<size_t>(cols->gw * cols->gh), -1);
  } else {
    cols->index = CellHash(cols->slab.size());
  }
}

}  // namespace

VoxelColumns slabColumns(const LocalPoints& pts, const std::vector<float>& h,
                         const TrunkExtractorParams& p) {
  VoxelColumns cols;
  slabColumns(pts, h, p, &cols);
  return cols;
}

void slabColumns(const LocalPoints& pts, const std::vector<float>& h, const TrunkExtractorParams& p,
                 VoxelColumns* out) {
  // Branch-free: about a quarter of the points are in the slab, in no predictable pattern.
  out->slab.resize(pts.size());
  size_t ns = 0;
  const double lo = p.slab_min_h_m, hi = p.slab_max_h_m;
  for (size_t i = 0; i < pts.size(); ++i) {
    out->slab[ns] = static_cast<uint32_t>(i);
    ns += static_cast<size_t>((h[i] >= lo) & (h[i] < hi));
  }
  out->slab.resize(ns);
  columnsOfSlab(pts, h, p, out);
}

void columnsOfSlab(const LocalPoints& pts, const std::vector<float>& h,
                   const TrunkExtractorParams& p, VoxelColumns* out) {
  VoxelColumns& cols = *out;
  cols.slab_col.clear(), cols.ix.clear(), cols.iy.clear();
  cols.count.clear(), cols.mask.clear(), cols.pass.clear(), cols.grid.clear();
  cols.passing = 0;
  cols.gx0 = cols.gy0 = cols.gw = cols.gh = 0;
  const double cs = p.column_cell_m;
  const int nlayers =
      std::max(1, static_cast<int>(std::ceil((p.slab_max_h_m - p.slab_min_h_m) / p.layer_h_m)));
  if (cols.slab.empty()) return;
  thread_local std::vector<int64_t> cxs_of_thread, cys_of_thread;  // kept between submaps
  std::vector<int64_t>&cxs = cxs_of_thread, &cys = cys_of_thread;  // each slab point's cell
  slabCells(pts, &cols, cs, &cxs, &cys);
  const int64_t *CX = cxs.data(), *CY = cys.data();
  cols.slab_col.resize(cols.slab.size());
  // Columns are numbered in order of their first slab point, whichever index holds them.
  for (size_t k = 0; k < cols.slab.size(); ++k) {
    prefetchGather(h.data(), cols.slab.data(), k, cols.slab.size());
    const uint32_t i = cols.slab[k];
    const int64_t ix = CX[k], iy = CY[k];
    const int next = static_cast<int>(cols.ix.size());
    int id;
    if (!cols.grid.empty()) {
      int& slot = cols.grid[static_cast<size_t>((iy - cols.gy0) * cols.gw + (ix - cols.gx0))];
      if (slot < 0) slot = next;
      id = slot;
    } else {
      bool inserted;
      id = cols.index.findOrInsert(cellKey(ix, iy), next, &inserted);
    }
    if (id == next) {
      cols.ix.push_back(ix), cols.iy.push_back(iy);
      cols.count.push_back(0), cols.mask.push_back(0);
    }
    cols.slab_col[k] = id;
    ++cols.count[id];
    const int layer =
        std::min(nlayers - 1, static_cast<int>((h[i] - p.slab_min_h_m) / p.layer_h_m));
    cols.mask[id] |= uint64_t{1} << layer;
  }
  cols.pass.assign(cols.size(), 0);
  for (size_t c = 0; c < cols.size(); ++c) {
    const int occupied = __builtin_popcountll(cols.mask[c]);
    cols.pass[c] = cols.count[c] >= static_cast<uint32_t>(p.min_column_points) &&
                   occupied >= p.min_continuity * nlayers;
    cols.passing += cols.pass[c];
  }
}

TrunkCandidates clusterColumns(const VoxelColumns& cols, const TrunkExtractorParams& p) {
  TrunkCandidates cand;
  std::vector<int> col_label = labelPassingColumns(cols, p, &cand.count);
  cand.start.assign(cand.count + 1, 0);
  if (cand.count == 0) return cand;
  attachFailingColumns(cols, &col_label);
  // Bucket slab points by candidate.
  for (size_t k = 0; k < cols.slab.size(); ++k) {
    const int l = col_label[cols.slab_col[k]];
    if (l >= 0) ++cand.start[l + 1];
  }
  for (int l = 0; l < cand.count; ++l) cand.start[l + 1] += cand.start[l];
  cand.points.resize(cand.start[cand.count]);
  std::vector<uint32_t> fill(cand.start.begin(), cand.start.end() - 1);
  for (size_t k = 0; k < cols.slab.size(); ++k) {
    const int l = col_label[cols.slab_col[k]];
    if (l >= 0) cand.points[fill[l]++] = cols.slab[k];
  }
  return cand;
}

}  // namespace dtif
