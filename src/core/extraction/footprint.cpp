// Occupied-cell footprint of a submap and the overlap of two aligned footprints.
#include "dtif/core/extraction/footprint.h"

#include <pcl/common/point_tests.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

#include "dtif/core/cells.h"
#include "dtif/core/extraction/extraction_stages.h"

namespace dtif {

namespace {

// DATASET.md's trunk-height band: the local ground of each 2 m tile is the 5th percentile of z
// in the 6 m window around it; points 0.3-3.0 m above it count.
constexpr double kTileM = 2.0;       // local-ground tile
constexpr int kWindowTiles = 1;      // 6 m window = the tile and one tile on each side
constexpr double kGroundPct = 0.05;  // 5th percentile
constexpr double kMinAboveM = 0.3;   // counted band above the local ground
constexpr double kMaxAboveM = 3.0;

// cellIndex without libm's floor call (not inlined on baseline x86-64; this runs several times
// per point): the same value for every argument.
inline int64_t fastCellIndex(double v) {
  constexpr double kMax = static_cast<double>(kMaxCellIndex);
  if (!(v > -kMax && v < kMax)) return cellIndex(v);
  const int64_t i = static_cast<int64_t>(v);  // truncates towards zero
  return i - (v < static_cast<double>(i));
}

int64_t tileOf(float v) { return fastCellIndex(v / kTileM); }

// The local-ground tiles of a cloud, by a dense index over its extent; a cloud spread over
// kilometres (stray points) falls back to a hash map, so the result never depends on the
// extent.
class Tiles {
 public:
  // Tiles over the extent of the finite points. tileOf is monotonic, so the tiles of the extreme
  // coordinates are the extreme tiles.
  bool init(float minx, float maxx, float miny, float maxy) {
    tx0_ = tileOf(minx), tx1_ = tileOf(maxx), ty0_ = tileOf(miny), ty1_ = tileOf(maxy);
    tw_ = static_cast<double>(tx1_ - tx0_) + 1.0, th_ = static_cast<double>(ty1_ - ty0_) + 1.0;
    dense_ = tw_ * th_ <= 4e6;
    width_ = dense_ ? static_cast<int64_t>(tw_) : 0;
    return true;
  }
  bool dense() const { return dense_; }
  // Tiles the dense index holds (0 when sparse: indices are made on insertion).
  size_t denseSize() const { return dense_ ? static_cast<size_t>(tw_ * th_) : 0; }
  // Dense index of the tile of a point of the cloud (inside the extent by construction).
  int denseIndex(float x, float y) const {
    return static_cast<int>((tileOf(y) - ty0_) * width_ + (tileOf(x) - tx0_));
  }
  // Index of tile (tx, ty); -1 when outside or (sparse, !insert) unknown.
  int index(int64_t tx, int64_t ty, bool insert) {
    if (dense_) {
      if (tx < tx0_ || tx > tx1_ || ty < ty0_ || ty > ty1_) return -1;
      return static_cast<int>((ty - ty0_) * width_ + (tx - tx0_));
    }
    const auto it = sparse_.find(packCell(tx, ty));
    if (it != sparse_.end()) return it->second;
    if (!insert) return -1;
    const int id = static_cast<int>(sparse_.size());
    sparse_.emplace(packCell(tx, ty), id);
    return id;
  }
  // Index of the tile of a point of the cloud; -1 when (sparse) unknown.
  int pointIndex(float x, float y) {
    return dense_ ? denseIndex(x, y) : index(tileOf(x), tileOf(y), false);
  }
  // Tile of index id; sparse indices need their coordinates in `made` (in insertion order).
  std::pair<int64_t, int64_t> coords(size_t id,
                                     const std::vector<std::pair<int64_t, int64_t>>& made) const {
    if (!dense_) return made[id];
    return {tx0_ + static_cast<int64_t>(id % static_cast<size_t>(tw_)),
            ty0_ + static_cast<int64_t>(id / static_cast<size_t>(tw_))};
  }

 private:
  int64_t tx0_ = 0, ty0_ = 0, tx1_ = 0, ty1_ = 0, width_ = 0;
  double tw_ = 0.0, th_ = 0.0;
  bool dense_ = false;
  std::unordered_map<int64_t, int> sparse_;
};

// What trunkHeightCells reads in its first passes over a cloud.
struct HeightCellsPrepass {
  size_t finite = 0;               // finite points of the cloud
  float minx = 0.0f, maxx = 0.0f;  // extent of the finite points [m]
  float miny = 0.0f, maxy = 0.0f;  // [m]
  size_t stride = 0;               // samples: every stride-th finite point, from the first
  std::vector<float> sx, sy, sz;   // the samples' coordinates [m]
};

std::vector<std::pair<int64_t, int64_t>> heightCells(const Cloud& cloud_S, const Pose& T_F_S,
                                                     double cell_m, size_t max_ground_samples,
                                                     const HeightCellsPrepass& given);

// Ground samples by tile: tile id's z values, ascending, are z[start[id]] .. z[start[id + 1] - 1].
struct TileSamples {
  std::vector<uint32_t> start;
  std::vector<float> z;
  std::vector<std::pair<int64_t, int64_t>> made;  // coordinates of each index (sparse case)
};

// Every stride-th finite point's coordinates.
void takeSamples(const Cloud& cloud, size_t stride, HeightCellsPrepass* pre) {
  pre->stride = stride;
  size_t skip = 0;
  for (const auto& p : cloud) {
    if (!pcl::isFinite(p)) continue;
    if (skip != 0) {
      --skip;
      continue;
    }
    skip = stride - 1;
    pre->sx.push_back(p.x), pre->sy.push_back(p.y), pre->sz.push_back(p.z);
  }
}

// A float's order as an unsigned integer: a < b implies key(a) < key(b), and equal keys are equal
// floats (-0 sorts before +0, which compare equal: either is the same ground).
uint32_t orderKey(float v) {
  uint32_t u;
  std::memcpy(&u, &v, sizeof(u));
  return u ^ ((u >> 31) ? 0xffffffffu : 0x80000000u);
}

float fromOrderKey(uint32_t key) {
  const uint32_t u = key ^ ((key >> 31) ? 0x80000000u : 0xffffffffu);
  float v;
  std::memcpy(&v, &u, sizeof(v));
  return v;
}

// Counts of the records' three 11-bit digits of z's order key (from bits 0, 11 and 22), for
// radixPass: taken as the records are made, not in a read of them per pass.
struct DigitCounts {
  uint32_t at[3][2049] = {};
  void add(uint32_t key) {
    ++at[0][(key & 2047u) + 1], ++at[1][((key >> 11) & 2047u) + 1], ++at[2][(key >> 22) + 1];
  }
};

// One stable counting-sort pass of records by their key's digit d (11 bits from 11 d on; the
// tile id above the key plays no part), its counts `at` (turned into places here).
void radixPass(const std::vector<uint64_t>& in, int d, uint32_t* at, std::vector<uint64_t>* out) {
  const int shift = 11 * d;
  for (size_t v = 0; v < 2048; ++v) at[v + 1] += at[v];
  uint64_t* o = out->data();
  for (const uint64_t r : in) o[at[(static_cast<uint32_t>(r) >> shift) & 2047u]++] = r;
}

// Sample coordinates, read in place (HeightCellMarks' are the caller's, not copied).
struct SampleArrays {
  const float *x, *y, *z;
  size_t n;
  explicit SampleArrays(const HeightCellsPrepass& pre)
      : x(pre.sx.data()), y(pre.sy.data()), z(pre.sz.data()), n(pre.sz.size()) {}
  SampleArrays(const std::vector<float>& sx, const std::vector<float>& sy,
               const std::vector<float>& sz)
      : x(sx.data()), y(sy.data()), z(sz.data()), n(sz.size()) {}
};

// The samples bucketed by tile, each tile's z sorted: an LSD radix sort of (tile, z) records by
// z's order key (three passes), then a stable counting sort by tile. Bucketing, then selecting
// and sorting by comparisons the part of each tile its windows' percentiles read cost ~3x more
// (6.1 against 1.9 ms for a 1.25 M-point submap's 208k samples; a branch mispredicted per
// comparison).
TileSamples sortedTileSamples(const SampleArrays& pre, Tiles* tiles) {
  TileSamples s;
  const size_t n = pre.n;
  // The records' buffers kept between submaps: each is written whole before it is read.
  thread_local std::vector<uint64_t> a_of_thread, b_of_thread;
  std::vector<uint64_t>&a = a_of_thread, &b = b_of_thread;
  a.resize(n), b.resize(n);
  DigitCounts digits;
  for (size_t k = 0; k < n; ++k) {
    const float x = pre.x[k], y = pre.y[k];
    int id;
    if (tiles->dense()) {
      id = tiles->denseIndex(x, y);
    } else {
      id = tiles->index(tileOf(x), tileOf(y), true);
      if (static_cast<size_t>(id) == s.made.size()) s.made.emplace_back(tileOf(x), tileOf(y));
    }
    const uint32_t key = orderKey(pre.z[k]);
    a[k] = static_cast<uint64_t>(id) << 32 | key;
    digits.add(key);
  }
  radixPass(a, 0, digits.at[0], &b), radixPass(b, 1, digits.at[1], &a);
  radixPass(a, 2, digits.at[2], &b);
  const size_t ntiles = tiles->dense() ? tiles->denseSize() : s.made.size();
  s.start.assign(ntiles + 1, 0);
  for (const uint64_t r : b) ++s.start[(r >> 32) + 1];
  for (size_t t = 0; t < ntiles; ++t) s.start[t + 1] += s.start[t];
  s.z.resize(n);
  std::vector<uint32_t> fill(s.start.begin(), s.start.end() - 1);
  for (const uint64_t r : b) s.z[fill[r >> 32]++] = fromOrderKey(static_cast<uint32_t>(r));
  return s;
}

// The k-th smallest (0-based) of the union of m >= 1 sorted runs. Each round drops a prefix that
// ranks wholly below k: with s = max(1, (k + 1) / m), that of the run whose s-th value (or last,
// if shorter) is the smallest such value v. Below v lie at most s - 1 values of each run, so with
// the prefix at most k + 1 - (m - 1) values (s = 1: the smallest head, k >= 1): those of rank < k
// in some order of the ties. About m ln(k / m) rounds of m comparisons instead of a merge's k + 1
// steps of m (k is 5 % of the window, ~60).
float kthOfSortedRuns(std::vector<std::pair<const float*, const float*>>* runs, size_t k) {
  while (runs->size() > 1) {
    const size_t m = runs->size();
    const size_t s = std::max<size_t>(1, (k + 1) / m);
    size_t best = 0, take = 0;
    float lowest = std::numeric_limits<float>::infinity();
    for (size_t r = 0; r < m; ++r) {
      const auto& [b, e] = (*runs)[r];
      const size_t t = std::min<size_t>(s, static_cast<size_t>(e - b));
      if (b[t - 1] < lowest || r == 0) lowest = b[t - 1], best = r, take = t;
    }
    if (k == 0) return lowest;  // s = 1: the smallest head
    (*runs)[best].first += take;
    k -= take;
    if ((*runs)[best].first == (*runs)[best].second) {
      (*runs)[best] = runs->back();
      runs->pop_back();
    }
  }
  return (*runs)[0].first[k];
}

// Local ground per tile (in S): 5th percentile of z inside the window around it, on every
// stride-th finite point. NaN where the window holds no sample.
std::vector<float> tileGround(const SampleArrays& pre, Tiles* tiles) {
  const TileSamples s = sortedTileSamples(pre, tiles);
  const size_t ntiles = s.start.size() - 1;
  std::vector<float> ground(ntiles, std::numeric_limits<float>::quiet_NaN());
  std::vector<std::pair<const float*, const float*>> runs;
  for (size_t id = 0; id < ntiles; ++id) {
    const auto [tx, ty] = tiles->coords(id, s.made);
    size_t total = 0;
    runs.clear();
    for (int64_t dx = -kWindowTiles; dx <= kWindowTiles; ++dx) {
      for (int64_t dy = -kWindowTiles; dy <= kWindowTiles; ++dy) {
        const int o = tiles->index(tx + dx, ty + dy, false);
        if (o < 0 || s.start[o] == s.start[o + 1]) continue;
        total += s.start[o + 1] - s.start[o];
        runs.emplace_back(s.z.data() + s.start[o], s.z.data() + s.start[o + 1]);
      }
    }
    if (total == 0) continue;
    ground[id] =
        kthOfSortedRuns(&runs, static_cast<size_t>(kGroundPct * static_cast<double>(total - 1)));
  }
  return ground;
}

}  // namespace

std::vector<std::pair<int64_t, int64_t>> trunkHeightCells(const Cloud& cloud_S, const Pose& T_F_S,
                                                          double cell_m,
                                                          size_t max_ground_samples) {
  HeightCellsPrepass pre;
  for (const auto& p : cloud_S) {
    if (!pcl::isFinite(p)) continue;
    if (pre.finite++ == 0) pre.minx = pre.maxx = p.x, pre.miny = pre.maxy = p.y;
    pre.minx = std::min(pre.minx, p.x), pre.maxx = std::max(pre.maxx, p.x);
    pre.miny = std::min(pre.miny, p.y), pre.maxy = std::max(pre.maxy, p.y);
  }
  return heightCells(cloud_S, T_F_S, cell_m, max_ground_samples, pre);
}

namespace {

std::vector<std::pair<int64_t, int64_t>> heightCells(const Cloud& cloud_S, const Pose& T_F_S,
                                                     double cell_m, size_t max_ground_samples,
                                                     const HeightCellsPrepass& given) {
  std::vector<std::pair<int64_t, int64_t>> out;
  Tiles tiles;
  const size_t n = given.finite;
  if (n == 0 || !tiles.init(given.minx, given.maxx, given.miny, given.maxy) || !(cell_m > 0.0))
    return out;
  const size_t stride = max_ground_samples > 0 ? std::max<size_t>(1, n / max_ground_samples) : 1;
  HeightCellsPrepass own;
  if (given.stride != stride) takeSamples(cloud_S, stride, &own);
  const std::vector<float> ground =
      tileGround(SampleArrays(given.stride == stride ? given : own), &tiles);
  const Eigen::Isometry3f T = T_F_S.cast<float>();
  // The descriptor's own footprint is in S: no transform (an identity one changes no value).
  const bool identity = T_F_S.matrix() == Eigen::Matrix4d::Identity();
  const Divisor by_cell(cell_m);
  for (const auto& p : cloud_S) {
    if (!pcl::isFinite(p)) continue;
    const int id = tiles.pointIndex(p.x, p.y);
    // No samples in the window (only when subsampling): no ground to measure from.
    if (id < 0 || !std::isfinite(ground[id])) continue;
    const float h = p.z - ground[id];
    if (h < kMinAboveM || h > kMaxAboveM) continue;
    const Eigen::Vector3f w =
        identity ? Eigen::Vector3f(p.x, p.y, p.z) : T * Eigen::Vector3f(p.x, p.y, p.z);
    const std::pair<int64_t, int64_t> cell(fastCellIndex(by_cell(w.x())),
                                           fastCellIndex(by_cell(w.y())));
    if (out.empty() || out.back() != cell) out.push_back(cell);  // neighbours share cells
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

}  // namespace

bool HeightCellMarks::init(const std::vector<float>& sx, const std::vector<float>& sy,
                           const std::vector<float>& sz, double cell_m, const Eigen::Vector2d& lo,
                           const Eigen::Vector2d& hi) {
  // Far from any origin (|coordinate| >= 1e6 m) the float margins below lose metres, and the
  // cell indices must stay where floorOf is fastCellIndex.
  const double far = std::max(lo.cwiseAbs().maxCoeff(), hi.cwiseAbs().maxCoeff());
  if (sx.empty() || !(cell_m > 0.0) || !(far < 1e6) ||
      !(far / cell_m < static_cast<double>(kMaxCellIndex) / 4.0)) {
    return false;
  }
  // Tiles over the samples' extent and one tile more on each side: beyond, no window holds a
  // sample. Their ground as trunkHeightCells computes it.
  HeightCellsPrepass pre;
  pre.finite = sx.size();
  pre.minx = *std::min_element(sx.begin(), sx.end()) - 2.5f;
  pre.maxx = *std::max_element(sx.begin(), sx.end()) + 2.5f;
  pre.miny = *std::min_element(sy.begin(), sy.end()) - 2.5f;
  pre.maxy = *std::max_element(sy.begin(), sy.end()) + 2.5f;
  Tiles tiles;
  tiles.init(pre.minx, pre.maxx, pre.miny, pre.maxy);
  if (!tiles.dense()) return false;
  ground_ = tileGround(SampleArrays(sx, sy, sz), &tiles);
  Pass& g = grid_;
  g = Pass();
  g.tx0_ = tileOf(pre.minx), g.ty0_ = tileOf(pre.miny);
  g.tw_ = tileOf(pre.maxx) - g.tx0_ + 1, g.th_ = tileOf(pre.maxy) - g.ty0_ + 1;
  g.cell_m_ = cell_m;
  int e = 0;
  g.pow2_ = std::frexp(cell_m, &e) == 0.5 && e > -1000 && e < 1000;  // as Divisor
  g.inv_cell_ = g.pow2_ ? 1.0 / cell_m : 0.0;
  g.shift_ = g.pow2_ && e >= 1 && e <= 40 ? e - 1 : -1;
  g.cx0_ = fastCellIndex(lo.x() / cell_m), g.cy0_ = fastCellIndex(lo.y() / cell_m);
  g.cw_ = fastCellIndex(hi.x() / cell_m) - g.cx0_ + 1;
  g.ch_ = fastCellIndex(hi.y() / cell_m) - g.cy0_ + 1;
  if (!(static_cast<double>(g.cw_) * static_cast<double>(g.ch_) <= 16e6)) return false;
  marks_.assign(static_cast<size_t>(g.cw_ * g.ch_) + 1, 0);  // the cells and Pass's sink
  return true;
}

std::vector<std::pair<int64_t, int64_t>> HeightCellMarks::cells() const {
  std::vector<std::pair<int64_t, int64_t>> out;
  const Pass& g = grid_;
  for (int64_t cx = 0; cx < g.cw_; ++cx) {
    for (int64_t cy = 0; cy < g.ch_; ++cy) {
      if (marks_[static_cast<size_t>(cx * g.ch_ + cy)]) out.emplace_back(g.cx0_ + cx, g.cy0_ + cy);
    }
  }
  return out;
}

size_t Footprint::count() const {
  size_t n = 0;
  for (uint8_t b : bits) n += static_cast<size_t>(__builtin_popcount(b));
  return n;
}

bool Footprint::wellFormed() const {
  return cell_m > 0.0 && std::isfinite(cell_m) && width > 0 && height > 0 &&
         width <= kMaxFootprintSide && height <= kMaxFootprintSide &&
         bits.size() == (static_cast<size_t>(width) * height + 7) / 8;
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
      const int64_t ix = cellIndex(p_c.x() / c.cell_m), iy = cellIndex(p_c.y() / c.cell_m);
      shared += c.occupied(ix, iy);
    }
  }
  // Footprints coarsened to different cell sizes make this approximate; the usual case is one
  // cell size on both sides, where it is the protocol's count.
  return static_cast<double>(shared) / static_cast<double>(std::min(nq, nc));
}

}  // namespace dtif
