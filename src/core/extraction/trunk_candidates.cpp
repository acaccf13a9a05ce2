// Trunk candidates (paper Sec. 3.B): vertical-continuity voxel columns in the low slab above
// the local ground, merged into candidates by connectivity. An open-addressing hash and
// counting sorts instead of kd-trees: the descriptor is timed (DESIGN.md).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>

#include "dtif/core/extraction/avx2.h"
#include "dtif/core/extraction/extraction_stages.h"

#if DTIF_AVX2_PATHS
#include <immintrin.h>
#endif

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

// Each slab point's column cell (floor of x, y / cs) and layer (of the slab's nlayers), and the
// cells' extent.
struct SlabCells {
  std::vector<int64_t> cx, cy;
  std::vector<int32_t> layer;
  int64_t x0 = std::numeric_limits<int64_t>::max(), y0 = x0;
  int64_t x1 = std::numeric_limits<int64_t>::min(), y1 = x1;

  // Slab point k at (x, y) of height hv.
  void set(size_t k, float x, float y, float hv, double cs, const TrunkExtractorParams& p,
           int nlayers) {
    const int64_t ix = floorIndex(x / cs), iy = floorIndex(y / cs);
    cx[k] = ix, cy[k] = iy;
    x0 = std::min(x0, ix), x1 = std::max(x1, ix);
    y0 = std::min(y0, iy), y1 = std::max(y1, iy);
    layer[k] = std::min(nlayers - 1, static_cast<int>((hv - p.slab_min_h_m) / p.layer_h_m));
  }
};

#if DTIF_AVX2_PATHS
// SlabCells::set of slab points 0.. four at a time where their cells fit in int32 (always for
// local points, below 1e8 m, at a sane cs): the same division, its floor as floorIndex's (both
// exact), the extent in lanes. Returns the count of points done (the rest: fewer than four).
DTIF_TARGET_AVX2 size_t slabCellsAvx2(const LocalPoints& pts, const float* h, const uint32_t* slab,
                                      size_t ns, double cs, const TrunkExtractorParams& p,
                                      int nlayers, SlabCells* out) {
  const __m256d vcs = _mm256_set1_pd(cs), h0 = _mm256_set1_pd(p.slab_min_h_m);
  const __m256d lh = _mm256_set1_pd(p.layer_h_m), big = _mm256_set1_pd(2147483648.0);
  const __m128i last = _mm_set1_epi32(nlayers - 1);
  __m128i x0 = _mm_set1_epi32(INT32_MAX), y0 = x0, x1 = _mm_set1_epi32(INT32_MIN), y1 = x1;
  size_t k = 0;
  for (; k + 4 <= ns; k += 4) {
    prefetchGather(pts.x.data(), slab, k, ns), prefetchGather(pts.y.data(), slab, k, ns);
    prefetchGather(h, slab, k, ns);
    const __m128i at = _mm_loadu_si128(reinterpret_cast<const __m128i*>(slab + k));
    const __m256d fx =
        _mm256_floor_pd(_mm256_div_pd(_mm256_cvtps_pd(_mm_i32gather_ps(pts.x.data(), at, 4)), vcs));
    const __m256d fy =
        _mm256_floor_pd(_mm256_div_pd(_mm256_cvtps_pd(_mm_i32gather_ps(pts.y.data(), at, 4)), vcs));
    const __m256d hv = _mm256_cvtps_pd(_mm_i32gather_ps(h, at, 4));
    // In [-2^31, 2^31) (no NaN): else the four one by one.
    const __m256d in = _mm256_and_pd(
        _mm256_and_pd(_mm256_cmp_pd(fx, big, _CMP_LT_OQ), _mm256_cmp_pd(fx, -big, _CMP_GE_OQ)),
        _mm256_and_pd(_mm256_cmp_pd(fy, big, _CMP_LT_OQ), _mm256_cmp_pd(fy, -big, _CMP_GE_OQ)));
    if (_mm256_movemask_pd(in) != 15) {
      for (size_t j = k; j < k + 4; ++j) {
        const uint32_t i = slab[j];
        out->set(j, pts.x[i], pts.y[i], h[i], cs, p, nlayers);
      }
      continue;
    }
    const __m128i ix = _mm256_cvttpd_epi32(fx), iy = _mm256_cvttpd_epi32(fy);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(&out->cx[k]), _mm256_cvtepi32_epi64(ix));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(&out->cy[k]), _mm256_cvtepi32_epi64(iy));
    x0 = _mm_min_epi32(x0, ix), x1 = _mm_max_epi32(x1, ix);
    y0 = _mm_min_epi32(y0, iy), y1 = _mm_max_epi32(y1, iy);
    const __m128i layer =
        _mm256_cvttpd_epi32(_mm256_div_pd(_mm256_sub_pd(hv, h0), lh));  // as static_cast<int>
    _mm_storeu_si128(reinterpret_cast<__m128i*>(&out->layer[k]), _mm_min_epi32(layer, last));
  }
  alignas(16) int32_t e[4][4];
  _mm_store_si128(reinterpret_cast<__m128i*>(e[0]), x0);
  _mm_store_si128(reinterpret_cast<__m128i*>(e[1]), y0);
  _mm_store_si128(reinterpret_cast<__m128i*>(e[2]), x1);
  _mm_store_si128(reinterpret_cast<__m128i*>(e[3]), y1);
  for (int j = 0; j < 4; ++j) {
    out->x0 = std::min<int64_t>(out->x0, e[0][j]), out->y0 = std::min<int64_t>(out->y0, e[1][j]);
    out->x1 = std::max<int64_t>(out->x1, e[2][j]), out->y1 = std::max<int64_t>(out->y1, e[3][j]);
  }
  return k;
}
#endif

// The slab points' cells and layers (*cells), and the index of their columns made (a dense grid
// over the cells' extent or a hash).
void slabCells(const LocalPoints& pts, const std::vector<float>& h, VoxelColumns* cols, double cs,
               const TrunkExtractorParams& p, int nlayers, SlabCells* cells) {
  const uint32_t* slab = cols->slab.data();
  const size_t ns = cols->slab.size();
  SlabCells& c = *cells;
  c.cx.resize(ns), c.cy.resize(ns), c.layer.resize(ns);
  c.x0 = c.y0 = std::numeric_limits<int64_t>::max();
  c.x1 = c.y1 = std::numeric_limits<int64_t>::min();
  size_t k = 0;
#if DTIF_AVX2_PATHS
  if (useAvx2()) k = slabCellsAvx2(pts, h.data(), slab, ns, cs, p, nlayers, &c);
#endif
  for (; k < ns; ++k) {
    prefetchGather(pts.x.data(), slab, k, ns), prefetchGather(pts.y.data(), slab, k, ns);
    const uint32_t i = slab[k];
    c.set(k, pts.x[i], pts.y[i], h[i], cs, p, nlayers);
  }
  // Dense when the grid is small next to the slab (always for survey data; a few far points
  // would make it huge).
  const double area =
      (static_cast<double>(c.x1) - c.x0 + 1.0) * (static_cast<double>(c.y1) - c.y0 + 1.0);
  if (area <= std::max(65536.0, 8.0 * static_cast<double>(ns))) {
    cols->gx0 = c.x0, cols->gy0 = c.y0, cols->gw = c.x1 - c.x0 + 1, cols->gh = c.y1 - c.y0 + 1;
    cols->grid.assign(static_cast<size_t>(cols->gw * cols->gh), -1);
  } else {
    cols->index = CellHash(ns);
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
  thread_local SlabCells cells_of_thread;  // kept between submaps
  SlabCells& cells = cells_of_thread;
  slabCells(pts, h, &cols, cs, p, nlayers, &cells);
  const int64_t *CX = cells.cx.data(), *CY = cells.cy.data();
  const int32_t* L = cells.layer.data();
  cols.slab_col.resize(cols.slab.size());
  // Columns are numbered in order of their first slab point, whichever index holds them.
  for (size_t k = 0; k < cols.slab.size(); ++k) {
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
    cols.mask[id] |= uint64_t{1} << L[k];
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
