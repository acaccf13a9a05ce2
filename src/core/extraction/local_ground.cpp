// Local ground of trunk extraction (Zhang et al.; no explicit ground segmentation): per ground
// cell a low z percentile of the open ground points, then per cell a robust plane through the
// cell values of the surrounding window. A plane, not the window minimum, so slopes up to
// ~25 deg do not bias the height. Flat arrays and counting sorts: the whole descriptor must
// take <= 40 ms per submap on one core (DESIGN.md).
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

#include "dtif/core/extraction/avx2.h"
#include "dtif/core/extraction/extraction_stages.h"
#include "dtif/core/robust.h"

#if DTIF_AVX2_PATHS
#include <immintrin.h>
#endif

namespace dtif {
namespace {

// Scratch of the sub-columns of one ground cell, reused across cells.
struct SubColumns {
  int ns = 1;               // sub-columns per cell side
  double sub = 0.0;         // sub-column size [m]
  Divisor by_sub{1.0};      // x / sub
  std::vector<float> smin;  // lowest point per sub-column [m]
  std::vector<char> sopen;  // nothing in the open gap above the lowest point
  std::vector<int> sidx;    // sub-column of each point of the cell
  std::vector<float> zs;    // ground points of the cell [m]
  bool avx2 = false;        // useAvx2()
};

#if DTIF_AVX2_PATHS
// Divisor d of four lanes: x * (1 / d) or x / d, as d computes it.
struct DivisorLanes {
  DTIF_TARGET_AVX2 explicit DivisorLanes(const Divisor& d)
      : mul(d.multiplies()), f(_mm256_set1_pd(d.factor())) {}
  DTIF_TARGET_AVX2 __m256d operator()(__m256d x) const {
    return mul ? _mm256_mul_pd(x, f) : _mm256_div_pd(x, f);
  }
  bool mul;
  __m256d f;
};

static_assert(sizeof(GroundGrid::SortedPoint) == 3 * sizeof(float), "sorted points are xyz");

// openSubColumns' sub-columns of the points b..e-1 (into sidx), and their lowest points in four
// interleaved sets (point k in set (k - b) % 4: one set made a chain through memory from point to
// point), four points at a time.
DTIF_TARGET_AVX2 void subColumnsAvx2(const GroundGrid& grid, uint32_t b, uint32_t e, double x0,
                                     double y0, const SubColumns& s, int* sidx, float (*low)[32]) {
  const GroundGrid::SortedPoint* P = grid.sorted.data();
  const DivisorLanes by_sub(s.by_sub);
  const __m256d vx0 = _mm256_set1_pd(x0), vy0 = _mm256_set1_pd(y0);
  const __m128i last = _mm_set1_epi32(s.ns - 1), zero = _mm_setzero_si128();
  const __m128i ns = _mm_set1_epi32(s.ns);
  uint32_t k = b;
  for (; k + 4 <= e; k += 4) {
    prefetchAhead(P, k, grid.sorted.size());  // the first read since binGroundGrid wrote them
    __m128 x, y, z;
    deinterleave4(&P[k].x, &x, &y, &z);
    // std::clamp(static_cast<int>(by_sub(q.x - x0)), 0, ns - 1), and for y.
    const __m128i sx = _mm_max_epi32(
        _mm_min_epi32(_mm256_cvttpd_epi32(by_sub(_mm256_sub_pd(_mm256_cvtps_pd(x), vx0))), last),
        zero);
    const __m128i sy = _mm_max_epi32(
        _mm_min_epi32(_mm256_cvttpd_epi32(by_sub(_mm256_sub_pd(_mm256_cvtps_pd(y), vy0))), last),
        zero);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(sidx + (k - b)),
                     _mm_add_epi32(_mm_mullo_epi32(sy, ns), sx));
    alignas(16) float zv[4];
    _mm_store_ps(zv, z);
    for (int j = 0; j < 4; ++j) low[j][sidx[k - b + j]] = std::min(low[j][sidx[k - b + j]], zv[j]);
  }
  for (; k < e; ++k) {
    const GroundGrid::SortedPoint& q = P[k];
    const int sx = std::clamp(static_cast<int>(s.by_sub(q.x - x0)), 0, s.ns - 1);
    const int sy = std::clamp(static_cast<int>(s.by_sub(q.y - y0)), 0, s.ns - 1);
    const int sc = sy * s.ns + sx;
    sidx[k - b] = sc;
    float& m = low[(k - b) & 3][sc];
    m = std::min(m, q.z);
  }
}

// A table of at most 16 entries per sub-column in two registers (lo: 0..7, hi: 8..15), zeros
// past its end, for lookup16.
struct Table16 {
  __m256 lo, hi;
};
// The values v[0..n-1], n <= 16.
DTIF_TARGET_AVX2 Table16 table16(const float* v, size_t n) {
  alignas(32) float t[16] = {};
  std::copy(v, v + n, t);
  return {_mm256_load_ps(t), _mm256_load_ps(t + 8)};
}
// The flags f[0..n-1], n <= 16, as lane masks (all bits set where the flag is).
DTIF_TARGET_AVX2 Table16 flagTable16(const char* f, size_t n) {
  alignas(32) int32_t t[16] = {};
  for (size_t i = 0; i < n; ++i) t[i] = f[i] ? -1 : 0;
  return {_mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<const __m256i*>(t))),
          _mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<const __m256i*>(t + 8)))};
}

// Entries sc of a table, eight lanes: two in-register permutes and a blend instead of a gather.
DTIF_TARGET_AVX2 __m256 lookup16(const Table16& t, __m256i sc) {
  const __m256 upper = _mm256_castsi256_ps(_mm256_slli_epi32(sc, 28));  // bit 3 -> sign
  return _mm256_blendv_ps(_mm256_permutevar8x32_ps(t.lo, sc), _mm256_permutevar8x32_ps(t.hi, sc),
                          upper);
}

// The 32-bit lanes of the 64-bit lane masks m0 (points 0..3) and m1 (4..7).
DTIF_TARGET_AVX2 __m256i narrowMasks(__m256d m0, __m256d m1) {
  const __m256i even = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
  return _mm256_permute2x128_si256(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(m0), even),
                                   _mm256_permutevar8x32_epi32(_mm256_castpd_si256(m1), even),
                                   0x20);
}

// Points k..k+7 of the cell whose points start at b: their z (in two halves), their sub-columns,
// and their height above their sub-column's lowest point (low: the lowest points), the float
// difference the one-point loops take.
struct EightAbove {
  __m128 z0, z1;
  __m256i sc;
  __m256 dz;
};
DTIF_TARGET_AVX2 EightAbove eightAbove(const GroundGrid::SortedPoint* P, uint32_t k, uint32_t b,
                                       const int* sidx, const Table16& low) {
  EightAbove a;
  __m128 x, y;
  deinterleave4(&P[k].x, &x, &y, &a.z0);
  deinterleave4(&P[k + 4].x, &x, &y, &a.z1);
  a.sc = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(sidx + (k - b)));
  a.dz = _mm256_sub_ps(_mm256_set_m128(a.z1, a.z0), lookup16(low, a.sc));
  return a;
}

// closedAvx2's points b.. eight at a time for at most 16 sub-columns, the lowest points looked
// up in registers (lookup16) instead of gathered. Returns the bits closed so far, the first
// point not taken in *k.
DTIF_TARGET_AVX2 uint32_t closedEight(const GroundGrid::SortedPoint* P, uint32_t b, uint32_t e,
                                      const int* sidx, const float* smin, size_t nsub, __m256d vgap,
                                      __m256d vtop, uint32_t* k_out) {
  const Table16 low = table16(smin, nsub);
  __m256i closed8 = _mm256_setzero_si256();
  uint32_t k = b;
  for (; k + 8 <= e; k += 8) {
    const EightAbove a = eightAbove(P, k, b, sidx, low);
    const __m256d d0 = _mm256_cvtps_pd(_mm256_castps256_ps128(a.dz));  // compared in double
    const __m256d d1 = _mm256_cvtps_pd(_mm256_extractf128_ps(a.dz, 1));
    const __m256i in = narrowMasks(
        _mm256_and_pd(_mm256_cmp_pd(d0, vgap, _CMP_GT_OQ), _mm256_cmp_pd(d0, vtop, _CMP_LE_OQ)),
        _mm256_and_pd(_mm256_cmp_pd(d1, vgap, _CMP_GT_OQ), _mm256_cmp_pd(d1, vtop, _CMP_LE_OQ)));
    closed8 = _mm256_or_si256(closed8,
                              _mm256_and_si256(in, _mm256_sllv_epi32(_mm256_set1_epi32(1), a.sc)));
  }
  __m128i c = _mm_or_si128(_mm256_castsi256_si128(closed8), _mm256_extracti128_si256(closed8, 1));
  c = _mm_or_si128(c, _mm_shuffle_epi32(c, _MM_SHUFFLE(1, 0, 3, 2)));
  c = _mm_or_si128(c, _mm_shuffle_epi32(c, _MM_SHUFFLE(2, 3, 0, 1)));
  *k_out = k;
  return static_cast<uint32_t>(_mm_cvtsi128_si32(c));
}

// openSubColumns' open tests of the points b..e-1 as bits of the sub-columns closed, four points
// at a time (eight with at most 16 sub-columns).
DTIF_TARGET_AVX2 uint32_t closedAvx2(const GroundGrid& grid, uint32_t b, uint32_t e,
                                     const int* sidx, const float* smin, size_t nsub,
                                     const TrunkExtractorParams& p) {
  const GroundGrid::SortedPoint* P = grid.sorted.data();
  const double gap = p.ground_open_gap_m, top = p.ground_open_top_m;
  const __m256d vgap = _mm256_set1_pd(gap), vtop = _mm256_set1_pd(top);
  const __m128 all = _mm_castsi128_ps(_mm_set1_epi32(-1));
  const __m256i even = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
  __m128i closed4 = _mm_setzero_si128();
  uint32_t k = b;
  if (nsub <= 16)
    closed4 =
        _mm_cvtsi32_si128(static_cast<int>(closedEight(P, b, e, sidx, smin, nsub, vgap, vtop, &k)));
  for (; k + 4 <= e; k += 4) {
    __m128 x, y, z;
    deinterleave4(&P[k].x, &x, &y, &z);
    const __m128i sc = _mm_loadu_si128(reinterpret_cast<const __m128i*>(sidx + (k - b)));
    const __m128 low = _mm_mask_i32gather_ps(_mm_setzero_ps(), smin, sc, all, 4);
    const __m256d dz = _mm256_cvtps_pd(_mm_sub_ps(z, low));  // the float dz, compared in double
    const __m256d in =
        _mm256_and_pd(_mm256_cmp_pd(dz, vgap, _CMP_GT_OQ), _mm256_cmp_pd(dz, vtop, _CMP_LE_OQ));
    const __m128i in4 = _mm256_castsi256_si128(
        _mm256_permutevar8x32_epi32(_mm256_castpd_si256(in), even));  // 64 -> 32-bit lanes
    closed4 = _mm_or_si128(closed4, _mm_and_si128(in4, _mm_sllv_epi32(_mm_set1_epi32(1), sc)));
  }
  closed4 = _mm_or_si128(closed4, _mm_shuffle_epi32(closed4, _MM_SHUFFLE(1, 0, 3, 2)));
  closed4 = _mm_or_si128(closed4, _mm_shuffle_epi32(closed4, _MM_SHUFFLE(2, 3, 0, 1)));
  uint32_t closed = static_cast<uint32_t>(_mm_cvtsi128_si32(closed4));
  for (; k < e; ++k) {
    const int sc = sidx[k - b];
    const float dz = P[k].z - smin[sc];
    closed |= static_cast<uint32_t>((dz > gap) & (dz <= top)) << sc;
  }
  return closed;
}

// openSubColumns with AVX2, for at most 32 sub-columns (the caller checks useAvx2()). The four
// sets' joined minimum has the one chain's bits unless it is a zero (the chain keeps the first
// zero's sign): then the one chain.
DTIF_TARGET_AVX2 void openSubColumnsAvx2(const GroundGrid& grid, uint32_t b, uint32_t e, double x0,
                                         double y0, const TrunkExtractorParams& p, SubColumns* s) {
  const size_t nsub = s->smin.size();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  float low[4][32];
  for (auto& set : low) std::fill(set, set + nsub, kInf);
  s->sidx.resize(e - b);
  int* sidx = s->sidx.data();
  subColumnsAvx2(grid, b, e, x0, y0, *s, sidx, low);
  float* smin = s->smin.data();
  bool zero = false;
  for (size_t sc = 0; sc < nsub; ++sc) {
    smin[sc] = std::min(std::min(low[0][sc], low[1][sc]), std::min(low[2][sc], low[3][sc]));
    zero |= smin[sc] == 0.0f;
  }
  if (zero) {
    const GroundGrid::SortedPoint* P = grid.sorted.data();
    std::fill(smin, smin + nsub, kInf);
    for (uint32_t k = b; k < e; ++k) smin[sidx[k - b]] = std::min(smin[sidx[k - b]], P[k].z);
  }
  const uint32_t closed = closedAvx2(grid, b, e, sidx, smin, nsub, p);
  for (size_t sc = 0; sc < nsub; ++sc) s->sopen[sc] = static_cast<char>(!((closed >> sc) & 1));
}
#endif

// The sub-columns of the points b..e-1 of a cell with corner (x0, y0): each point's sub-column
// (s->sidx, by k - b), their lowest points and which are open. Raw pointers and locals: through
// the members the compiler reloads them at every point (a char store may alias anything). The
// open test branch-free: it follows no pattern.
void openSubColumns(const GroundGrid& grid, uint32_t b, uint32_t e, double x0, double y0,
                    const TrunkExtractorParams& p, SubColumns* s) {
#if DTIF_AVX2_PATHS
  if (s->avx2 && s->smin.size() <= 32) return openSubColumnsAvx2(grid, b, e, x0, y0, p, s);
#endif
  const int ns = s->ns;
  std::fill(s->smin.begin(), s->smin.end(), std::numeric_limits<float>::infinity());
  std::fill(s->sopen.begin(), s->sopen.end(), 1);
  s->sidx.resize(e - b);
  const GroundGrid::SortedPoint* P = grid.sorted.data();
  float* smin = s->smin.data();
  char* sopen = s->sopen.data();
  int* sidx = s->sidx.data();
  const Divisor by_sub = s->by_sub;
  // The first read of the sorted points since binGroundGrid wrote them.
  for (uint32_t k = b; k < e; ++k) {
    const GroundGrid::SortedPoint& q = P[k];
    prefetchAhead(P, k, grid.sorted.size());
    const int sx = std::clamp(static_cast<int>(by_sub(q.x - x0)), 0, ns - 1);
    const int sy = std::clamp(static_cast<int>(by_sub(q.y - y0)), 0, ns - 1);
    const int sc = sy * ns + sx;
    sidx[k - b] = sc;
    smin[sc] = std::min(smin[sc], q.z);
  }
  const double gap = p.ground_open_gap_m, top = p.ground_open_top_m;
  for (uint32_t k = b; k < e; ++k) {
    const int sc = sidx[k - b];
    const float dz = P[k].z - smin[sc];
    sopen[sc] &= static_cast<char>(!((dz > gap) & (dz <= top)));
  }
}

#if DTIF_AVX2_PATHS
// Packs the lanes of v whose bit is set in keep (four bits) to out; returns their count.
DTIF_TARGET_AVX2 size_t packFour(__m128 v, int keep, float* out) {
  const __m128i lanes = _mm_load_si128(reinterpret_cast<const __m128i*>(kLanes.lane[keep]));
  _mm_storeu_ps(out, _mm_permutevar_ps(v, lanes));
  return static_cast<size_t>(kLanes.count[keep]);
}

// groundOfCell's ground points of the cell's points b..e-1, eight at a time, for at most 16
// sub-columns (smin, sopen: nsub of them; the caller checks useAvx2()): the same float difference
// and double comparison per point, the kept z packed in order. Returns the count written to zs
// and the first point not taken in *k.
DTIF_TARGET_AVX2 size_t groundPointsAvx2(const GroundGrid::SortedPoint* P, uint32_t b, uint32_t e,
                                         const int* sidx, const float* smin, const char* sopen,
                                         size_t nsub, double band, float* zs, uint32_t* k_out) {
  const __m256d vband = _mm256_set1_pd(band);
  const Table16 low = table16(smin, nsub), open = flagTable16(sopen, nsub);
  size_t nz = 0;
  uint32_t k = b;
  for (; k + 8 <= e; k += 8) {
    const EightAbove a = eightAbove(P, k, b, sidx, low);
    const __m256 d = a.dz;
    const int is_open = _mm256_movemask_ps(lookup16(open, a.sc));
    const int near0 = _mm256_movemask_pd(
        _mm256_cmp_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(d)), vband, _CMP_LE_OQ));
    const int near1 = _mm256_movemask_pd(
        _mm256_cmp_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(d, 1)), vband, _CMP_LE_OQ));
    nz += packFour(a.z0, near0 & is_open & 15, zs + nz);
    nz += packFour(a.z1, near1 & (is_open >> 4), zs + nz);
  }
  *k_out = k;
  return nz;
}
#endif

// Ground evidence of cell c (which holds points): its open sub-columns and their ground points.
void groundOfCell(const GroundGrid& grid, size_t c, const TrunkExtractorParams& p, SubColumns* s,
                  GroundCells* cells) {
  const uint32_t b = grid.start[c], e = grid.start[c + 1];
  const int ns = s->ns;
  const double x0 = grid.minx + static_cast<double>(c % grid.nx) * grid.cell_m;
  const double y0 = grid.miny + static_cast<double>(c / grid.nx) * grid.cell_m;
  openSubColumns(grid, b, e, x0, y0, p, s);
  // The ground points, branch-free.
  const GroundGrid::SortedPoint* P = grid.sorted.data();
  const float* smin = s->smin.data();
  const char* sopen = s->sopen.data();
  const int* sidx = s->sidx.data();
  const double band = p.ground_band_m;
  s->zs.resize(e - b);
  float* zs_out = s->zs.data();
  size_t nz = 0;
  uint32_t from = b;
#if DTIF_AVX2_PATHS
  if (s->avx2 && s->smin.size() <= 16)
    nz = groundPointsAvx2(P, b, e, sidx, smin, sopen, s->smin.size(), band, zs_out, &from);
#endif
  for (uint32_t k = from; k < e; ++k) {
    const int sc = sidx[k - b];
    const float z = P[k].z;
    zs_out[nz] = z;
    nz += static_cast<size_t>((sopen[sc] != 0) & (z - smin[sc] <= band));
  }
  s->zs.resize(nz);
  int nopen = 0;
  for (size_t sc = 0; sc < s->smin.size(); ++sc) {
    nopen += s->sopen[sc] && std::isfinite(s->smin[sc]);
    cells->min[c] = std::min(cells->min[c], s->smin[sc]);
  }
  std::vector<float>& zs = s->zs;
  if (zs.size() < 3 || nopen < p.ground_min_open_fraction * static_cast<double>(ns * ns)) return;
  const size_t q = static_cast<size_t>(p.ground_percentile * (zs.size() - 1));
  std::nth_element(zs.begin(), zs.begin() + q, zs.end());
  cells->low[c] = zs[q];
  cells->count[c] = static_cast<uint32_t>(zs.size());
}

// Ground cells of the (2 h + 1)^2 window around cell (cx, cy), offsets from its centre: the
// first n of the arrays (sized for the window, kept between cells). Branch-free within the grid
// (each cell written, n advanced when it is a ground cell): ~3,600 windows of 49 cells per submap.
struct GroundWindow {
  std::vector<double> x, y, z, w;  // offset [m], cell value [m], weight
  size_t n = 0;
  void gather(const GroundCells& cells, const GroundGrid& grid, int cx, int cy, int h) {
    const size_t cap = static_cast<size_t>(2 * h + 1) * static_cast<size_t>(2 * h + 1);
    if (x.size() < cap) x.resize(cap), y.resize(cap), z.resize(cap), w.resize(cap);
    double *X = x.data(), *Y = y.data(), *Z = z.data(), *W = w.data();
    const uint32_t* count = cells.count.data();
    const float* low = cells.low.data();
    const double g = grid.cell_m;
    const int dy0 = std::max(-h, -cy), dy1 = std::min(h, grid.ny - 1 - cy);
    const int dx0 = std::max(-h, -cx), dx1 = std::min(h, grid.nx - 1 - cx);
    n = 0;
    for (int dy = dy0; dy <= dy1; ++dy) {
      const size_t row = static_cast<size_t>(cy + dy) * grid.nx;
      for (int dx = dx0; dx <= dx1; ++dx) {
        const size_t cc = row + static_cast<size_t>(cx + dx);
        X[n] = dx * g, Y[n] = dy * g, Z[n] = low[cc];
        W[n] = count[cc] >= 5 ? 1.0 : 0.3;  // sparse cells give a poor percentile
        n += count[cc] != 0;
      }
    }
  }
};

// The ground cell of a local point of the grid's points: cellOf without its floor (every offset
// from the grid's corner is >= 0 there, where truncation is the floor).
class PointCell {
 public:
  explicit PointCell(const GroundGrid& g)
      : x0_(g.minx), y0_(g.miny), by_g_(g.cell_m), nx_(g.nx), ny_(g.ny) {}
  uint32_t operator()(float x, float y) const {
    const int gx = std::min(static_cast<int>(by_g_(x - x0_)), nx_ - 1);
    const int gy = std::min(static_cast<int>(by_g_(y - y0_)), ny_ - 1);
    return static_cast<uint32_t>(gy) * nx_ + gx;
  }

 private:
  double x0_, y0_;
  Divisor by_g_;
  int nx_, ny_;
};

#if DTIF_AVX2_PATHS
// PointCell of four points, and their cells' centres as GroundGrid::cellCentre computes them
// (c % nx is the column: the column is clamped to [0, nx - 1]).
struct GroundCellLanes {
  DTIF_TARGET_AVX2 explicit GroundCellLanes(const GroundGrid& g)
      : x0(_mm256_set1_pd(g.minx)),
        y0(_mm256_set1_pd(g.miny)),
        by_g(Divisor(g.cell_m)),
        cell(_mm256_set1_pd(g.cell_m)),
        nx1(_mm_set1_epi32(g.nx - 1)),
        ny1(_mm_set1_epi32(g.ny - 1)),
        nx(_mm_set1_epi32(g.nx)) {}
  DTIF_TARGET_AVX2 __m128i operator()(__m256d x, __m256d y, __m256d* cx, __m256d* cy) const {
    const __m128i gx = column(x, x0, nx1), gy = column(y, y0, ny1);
    const __m256d half = _mm256_set1_pd(0.5);
    *cx = _mm256_add_pd(x0, _mm256_mul_pd(_mm256_add_pd(_mm256_cvtepi32_pd(gx), half), cell));
    *cy = _mm256_add_pd(y0, _mm256_mul_pd(_mm256_add_pd(_mm256_cvtepi32_pd(gy), half), cell));
    return _mm_add_epi32(_mm_mullo_epi32(gy, nx), gx);
  }
  // The cells of the eight points (x, y)[0..7].
  DTIF_TARGET_AVX2 __m256i eight(const float* x, const float* y) const {
    return _mm256_setr_m128i(four(_mm_loadu_ps(x), _mm_loadu_ps(y)),
                             four(_mm_loadu_ps(x + 4), _mm_loadu_ps(y + 4)));
  }
  // The cells of four points.
  DTIF_TARGET_AVX2 __m128i four(__m128 x, __m128 y) const {
    const __m128i gx = column(_mm256_cvtps_pd(x), x0, nx1);
    return _mm_add_epi32(_mm_mullo_epi32(column(_mm256_cvtps_pd(y), y0, ny1), nx), gx);
  }
  // PointCell's column (or row) of coordinates v from corner v0, at most last.
  DTIF_TARGET_AVX2 __m128i column(__m256d v, __m256d v0, __m128i last) const {
    return _mm_min_epi32(_mm256_cvttpd_epi32(by_g(_mm256_sub_pd(v, v0))), last);
  }
  __m256d x0, y0;
  DivisorLanes by_g;
  __m256d cell;
  __m128i nx1, ny1, nx;
};

// The lanes j of cells c where the cell changes (c[j] != c[j - 1], lane 0 against run), as bits.
DTIF_TARGET_AVX2 unsigned cellChanges(__m256i c, uint32_t run) {
  // c shifted up by one lane, run in lane 0: per 128-bit half, (c : t) >> 12 bytes with t's low
  // half the run's and its high half c's low half.
  const __m256i before = _mm256_alignr_epi8(
      c, _mm256_permute2x128_si256(c, _mm256_set1_epi32(static_cast<int32_t>(run)), 0x02), 12);
  return static_cast<unsigned>(
      ~_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(c, before))) & 0xff);
}

// binGroundGrid's counts per cell (into count) of the points 0.. eight at a time: a run of points
// in one cell (neighbours on a scan line mostly are) is counted in a register, not by an
// increment of the cell per point, whose chain through memory bounded the pass. Returns the
// count of points done (the rest: fewer than eight).
DTIF_TARGET_AVX2 size_t binCountAvx2(const LocalPoints& pts, const GroundGrid& grid,
                                     uint32_t* count) {
  const size_t n = pts.size();
  const float *X = pts.x.data(), *Y = pts.y.data();
  const GroundCellLanes cells(grid);
  uint32_t run = 0, hits = 0;
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n);
    const __m256i c = cells.eight(X + i, Y + i);
    const __m256i same = _mm256_cmpeq_epi32(c, _mm256_set1_epi32(static_cast<int32_t>(run)));
    if (_mm256_movemask_epi8(same) == -1) {
      hits += 8;
      continue;
    }
    // A jump per change of cell instead of a test per point, whose outcome follows no pattern.
    alignas(32) uint32_t k[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(k), c);
    uint32_t from = 0;
    for (unsigned changes = cellChanges(c, run); changes != 0; changes &= changes - 1) {
      const uint32_t j = static_cast<uint32_t>(__builtin_ctz(changes));
      count[run] += hits + (j - from);
      run = k[j], hits = 0, from = j;
    }
    hits += 8 - from;
  }
  count[run] += hits;
  return i;
}

// binGroundGrid's placing of the points 0.. by their cells' next places (fill), eight at a
// time: within a run of one cell the place is a register (see binCountAvx2). Returns the count
// of points done.
DTIF_TARGET_AVX2 size_t binFillAvx2(const LocalPoints& pts, const GroundGrid& grid, uint32_t* fill,
                                    GroundGrid::SortedPoint* out) {
  const size_t n = pts.size();
  const float *X = pts.x.data(), *Y = pts.y.data(), *Z = pts.z.data();
  const GroundCellLanes cells(grid);
  uint32_t run = 0, at = fill[0];
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n), prefetchAhead(Z, i, n);
    const __m256i c = cells.eight(X + i, Y + i);
    const __m256i same = _mm256_cmpeq_epi32(c, _mm256_set1_epi32(static_cast<int32_t>(run)));
    if (_mm256_movemask_epi8(same) == -1) {
      for (size_t j = i; j < i + 8; ++j) out[at++] = {X[j], Y[j], Z[j]};
      continue;
    }
    // Each lane's place: its run's first place less the run's first lane, plus the lane. A jump
    // per change of cell (lane j against lane j - 1), not a test per point.
    alignas(32) uint32_t k[8], place[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(k), c);
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    uint32_t base = at;  // place of lane 0 of the run
    __m256i bases = _mm256_set1_epi32(static_cast<int32_t>(base));
    for (unsigned changes = cellChanges(c, run); changes != 0; changes &= changes - 1) {
      const uint32_t j = static_cast<uint32_t>(__builtin_ctz(changes));
      fill[run] = base + j, run = k[j], base = fill[run] - j;  // wraps back when fill < j
      const __m256i from_j =
          _mm256_cmpgt_epi32(lane, _mm256_set1_epi32(static_cast<int32_t>(j) - 1));
      bases = _mm256_blendv_epi8(bases, _mm256_set1_epi32(static_cast<int32_t>(base)), from_j);
    }
    at = base + 8;
    _mm256_store_si256(reinterpret_cast<__m256i*>(place), _mm256_add_epi32(bases, lane));
    for (size_t j = 0; j < 8; ++j) out[place[j]] = {X[i + j], Y[i + j], Z[i + j]};
  }
  fill[run] = at;
  return i;
}
#endif

}  // namespace

LocalPoints toLocalPoints(const Cloud& cloud) {
  LocalPoints pts;
  bool have_origin = false;
  // Sized once and written by index: this runs once per point of every submap.
  pts.x.resize(cloud.size()), pts.y.resize(cloud.size()), pts.z.resize(cloud.size());
  size_t n = 0;
  for (const auto& pt : cloud.points) {
    if (!std::isfinite(pt.x) || !std::isfinite(pt.y) || !std::isfinite(pt.z)) continue;
    // Absurd magnitudes would overflow the cell indices; they are not survey points.
    if (std::abs(pt.x) > 1e8f || std::abs(pt.y) > 1e8f || std::abs(pt.z) > 1e8f) continue;
    if (!have_origin) {
      pts.ox = std::floor(pt.x), pts.oy = std::floor(pt.y), pts.oz = std::floor(pt.z);
      have_origin = true;
    }
    pts.x[n] = static_cast<float>(pt.x - pts.ox);
    pts.y[n] = static_cast<float>(pt.y - pts.oy);
    pts.z[n] = static_cast<float>(pt.z - pts.oz);
    ++n;
  }
  pts.x.resize(n), pts.y.resize(n), pts.z.resize(n);
  return pts;
}

namespace {

// fitGroundPlane's weights of the points i..: w0 times the Tukey weight of the residual from plane
// pl about (x0, y0) (constant c_up above it, c_down below). Returns the first point not taken.
size_t reweightScalar(const double* x, const double* y, const double* z, const double* w0, size_t i,
                      size_t n, const GroundPlane& pl, double x0, double y0, double c_up,
                      double c_down, double* w) {
  for (; i < n; ++i) {
    const double r = z[i] - (pl.a + pl.b * (x[i] - x0) + pl.c * (y[i] - y0));
    w[i] = w0[i] * tukeyWeight(r, r > 0.0 ? c_up : c_down);
  }
  return i;
}

#if DTIF_AVX2_PATHS
// reweightScalar four points at a time (the caller checks useAvx2()): the same IEEE operations
// per point, tukeyWeight's test as "not |r| >= c" so that a NaN residual weighs NaN as there.
DTIF_TARGET_AVX2 size_t reweightAvx2(const double* x, const double* y, const double* z,
                                     const double* w0, size_t n, const GroundPlane& pl, double x0,
                                     double y0, double c_up, double c_down, double* w) {
  const __m256d a = _mm256_set1_pd(pl.a), b = _mm256_set1_pd(pl.b), c = _mm256_set1_pd(pl.c);
  const __m256d vx0 = _mm256_set1_pd(x0), vy0 = _mm256_set1_pd(y0);
  const __m256d up = _mm256_set1_pd(c_up), down = _mm256_set1_pd(c_down);
  const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
  const __m256d sign = _mm256_set1_pd(-0.0);
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    const __m256d dx = _mm256_sub_pd(_mm256_loadu_pd(x + i), vx0);
    const __m256d dy = _mm256_sub_pd(_mm256_loadu_pd(y + i), vy0);
    const __m256d at = _mm256_add_pd(_mm256_add_pd(a, _mm256_mul_pd(b, dx)), _mm256_mul_pd(c, dy));
    const __m256d r = _mm256_sub_pd(_mm256_loadu_pd(z + i), at);
    const __m256d cc = _mm256_blendv_pd(down, up, _mm256_cmp_pd(r, zero, _CMP_GT_OQ));
    const __m256d in = _mm256_cmp_pd(_mm256_andnot_pd(sign, r), cc, _CMP_NGE_UQ);
    const __m256d u = _mm256_div_pd(r, cc);
    const __m256d t = _mm256_sub_pd(one, _mm256_mul_pd(u, u));
    const __m256d tw = _mm256_and_pd(in, _mm256_mul_pd(t, t));
    _mm256_storeu_pd(w + i, _mm256_mul_pd(_mm256_loadu_pd(w0 + i), tw));
  }
  return i;
}
#endif

}  // namespace

GroundPlane fitGroundPlane(const double* x, const double* y, const double* z, const double* w0,
                           size_t n, double x0, double y0, double c_up, double c_down,
                           int iterations) {
  GroundPlane p;
  thread_local std::vector<double> w_of_thread;  // ~3,600 fits per submap: no allocation each
  std::vector<double>& w = w_of_thread;
  w.assign(w0, w0 + n);
  const bool avx2 = useAvx2();
  for (int it = 0; it <= iterations; ++it) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
    double sw = 0.0;
    double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0, sz = 0, sxz = 0, syz = 0;
    for (size_t i = 0; i < n; ++i) {
      // A point of weight 0 (or a negative one, which no caller passes) adds +0 terms: the
      // sums start at +0 and stay as they were, without a branch on the weights' pattern.
      const double wi = w[i] > 0.0 ? w[i] : 0.0;
      const double dx = x[i] - x0, dy = y[i] - y0;
      sw += wi, sx += wi * dx, sy += wi * dy;
      sxx += wi * dx * dx, sxy += wi * dx * dy, syy += wi * dy * dy;
      sz += wi * z[i], sxz += wi * dx * z[i], syz += wi * dy * z[i];
    }
    A << sw, sx, sy, sx, sxx, sxy, sy, sxy, syy;
    rhs << sz, sxz, syz;
    if (sw <= 0.0) break;
    A(1, 1) += 1e-3 * sw;
    A(2, 2) += 1e-3 * sw;
    const Eigen::Vector3d s = A.ldlt().solve(rhs);
    if (!s.allFinite()) break;
    p.a = s(0), p.b = s(1), p.c = s(2);
    if (it == iterations) break;
    size_t i = 0;
#if DTIF_AVX2_PATHS
    if (avx2) i = reweightAvx2(x, y, z, w0, n, p, x0, y0, c_up, c_down, w.data());
#endif
    reweightScalar(x, y, z, w0, i, n, p, x0, y0, c_up, c_down, w.data());
  }
  return p;
}

double GroundGrid::groundAt(double x, double y) const {
  int gx, gy;
  cellOf(x, y, &gx, &gy);
  const GroundPlane& pl = plane[static_cast<size_t>(gy) * nx + gx];
  const double x0 = minx + (gx + 0.5) * cell_m, y0 = miny + (gy + 0.5) * cell_m;
  return pl.at(x - x0, y - y0);
}

GroundGrid binGroundGrid(const LocalPoints& pts, const TrunkExtractorParams& p) {
  GroundGrid grid;
  binGroundGrid(pts, p, &grid);
  return grid;
}

void binGroundGrid(const LocalPoints& pts, const TrunkExtractorParams& p, GroundGrid* out) {
  GroundGrid& grid = *out;
  const size_t n = pts.size();
  const float *X = pts.x.data(), *Y = pts.y.data();
  float minx = X[0], maxx = X[0], miny = Y[0], maxy = Y[0];
  if (pts.has_extent) minx = pts.minx, maxx = pts.maxx, miny = pts.miny, maxy = pts.maxy;
  for (size_t i = pts.has_extent ? n : 1; i < n; ++i) {
    minx = std::min(minx, X[i]), maxx = std::max(maxx, X[i]);
    miny = std::min(miny, Y[i]), maxy = std::max(maxy, Y[i]);
  }
  double g = p.ground_cell_m;
  // Guard against a few far outliers blowing up the dense ground grid.
  const double area_cells = (maxx - minx) / g * ((maxy - miny) / g);
  if (area_cells > p.max_ground_cells) g *= std::sqrt(area_cells / p.max_ground_cells);
  grid.minx = minx, grid.miny = miny, grid.cell_m = g;
  grid.nx = static_cast<int>(std::floor((maxx - minx) / g)) + 1;
  grid.ny = static_cast<int>(std::floor((maxy - miny) / g)) + 1;
  const size_t gcells = grid.cells();
  // Counting sort of the points by ground cell; the cell is computed again where needed (cheaper
  // than an array of them, read back twice: this is bound by memory traffic).
  grid.start.assign(gcells + 1, 0);
  const PointCell cell_of(grid);
  // Raw pointers: through the members the compiler reloads them at every point.
  uint32_t* count = grid.start.data() + 1;
  size_t done = 0;
#if DTIF_AVX2_PATHS
  const bool avx2 = useAvx2();
  if (avx2) done = binCountAvx2(pts, grid, count);
#endif
  for (size_t i = done; i < n; ++i) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n);
    ++count[cell_of(X[i], Y[i])];
  }
  for (size_t c = 0; c < gcells; ++c) grid.start[c + 1] += grid.start[c];
  std::vector<uint32_t> fill(grid.start.begin(), grid.start.end() - 1);
  grid.sorted.resize(n);
  GroundGrid::SortedPoint* out_pts = grid.sorted.data();
  const float* Z = pts.z.data();
#if DTIF_AVX2_PATHS
  if (avx2) done = binFillAvx2(pts, grid, fill.data(), out_pts);
#endif
  for (size_t i = done; i < n; ++i) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n), prefetchAhead(Z, i, n);
    out_pts[fill[cell_of(X[i], Y[i])]++] = {X[i], Y[i], Z[i]};
  }
}

GroundCells openGroundCells(const LocalPoints& /*pts: read through grid.sorted*/,
                            const GroundGrid& grid, const TrunkExtractorParams& p) {
  const size_t gcells = grid.cells();
  GroundCells cells;
  cells.low.assign(gcells, std::numeric_limits<float>::quiet_NaN());
  cells.count.assign(gcells, 0);
  cells.any.assign(gcells, 0);
  cells.min.assign(gcells, std::numeric_limits<float>::infinity());
  SubColumns s;
  s.ns = std::max(1, static_cast<int>(std::lround(grid.cell_m / p.ground_sub_cell_m)));
  s.sub = grid.cell_m / s.ns;
  s.by_sub = Divisor(s.sub);
  s.smin.resize(static_cast<size_t>(s.ns) * s.ns);
  s.sopen.resize(s.smin.size());
  s.avx2 = useAvx2();
  for (size_t c = 0; c < gcells; ++c) {
    if (grid.start[c] == grid.start[c + 1]) continue;
    cells.any[c] = 1;
    groundOfCell(grid, c, p, &s, &cells);
  }
  return cells;
}

void dropRaisedGroundCells(const GroundGrid& grid, const TrunkExtractorParams& p,
                           GroundCells* cells) {
  const int gnx = grid.nx, gny = grid.ny;
  const float max_step = static_cast<float>(p.ground_max_step * grid.cell_m);
  std::vector<uint32_t> keep = cells->count;
  for (int cy = 0; cy < gny; ++cy) {
    for (int cx = 0; cx < gnx; ++cx) {
      const size_t c = static_cast<size_t>(cy) * gnx + cx;
      if (cells->count[c] == 0) continue;
      for (int dy = -1; dy <= 1 && keep[c]; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = cx + dx, yy = cy + dy;
          if (xx < 0 || yy < 0 || xx >= gnx || yy >= gny) continue;
          if (cells->low[c] - cells->min[static_cast<size_t>(yy) * gnx + xx] > max_step) {
            keep[c] = 0;
            break;
          }
        }
      }
    }
  }
  cells->count.swap(keep);
}

void fitLocalGroundPlanes(const GroundCells& cells, const TrunkExtractorParams& p,
                          GroundGrid* grid) {
  const int half =
      std::max(1, static_cast<int>(std::lround(0.5 * p.ground_window_m / grid->cell_m)));
  const size_t min_cells = static_cast<size_t>(p.ground_min_cells);
  grid->plane.assign(grid->cells(), GroundPlane());
  grid->seen.assign(grid->cells(), 0);
  GroundWindow win;
  for (int cy = 0; cy < grid->ny; ++cy) {
    for (int cx = 0; cx < grid->nx; ++cx) {
      const size_t c = static_cast<size_t>(cy) * grid->nx + cx;
      if (!cells.any[c]) continue;
      win.gather(cells, *grid, cx, cy, half);
      grid->seen[c] = win.n >= min_cells;
      if (!grid->seen[c]) win.gather(cells, *grid, cx, cy, 3 * half);
      if (win.n < min_cells) {
        // No ground anywhere near: the lowest point of the cell is the best guess left.
        grid->plane[c].a = cells.min[c];
        continue;
      }
      // Downweight cells above the plane: what is left of vegetation fills cells from above.
      grid->plane[c] =
          fitGroundPlane(win.x.data(), win.y.data(), win.z.data(), win.w.data(), win.n, 0.0, 0.0,
                         p.ground_plane_c_up_m, p.ground_plane_c_down_m, /*iterations=*/5);
    }
  }
}

GroundGrid estimateLocalGround(const LocalPoints& pts, const TrunkExtractorParams& p) {
  GroundGrid grid;
  estimateLocalGround(pts, p, &grid);
  return grid;
}

void estimateLocalGround(const LocalPoints& pts, const TrunkExtractorParams& p, GroundGrid* out) {
  GroundGrid& grid = *out;
  binGroundGrid(pts, p, &grid);
  GroundCells cells = openGroundCells(pts, grid, p);
  dropRaisedGroundCells(grid, p, &cells);
  fitLocalGroundPlanes(cells, p, &grid);
}

std::vector<float> heightsAboveGround(const LocalPoints& pts, const GroundGrid& grid) {
  std::vector<float> h;
  heightsAboveGround(pts, grid, &h);
  return h;
}

namespace {

// Each cell's plane about its centre, once per cell instead of two divisions per point.
struct Centred {
  GroundPlane pl;
  double x0, y0;
};

std::vector<Centred> centredPlanes(const GroundGrid& grid) {
  std::vector<Centred> cells(grid.cells());
  for (size_t c = 0; c < cells.size(); ++c) {
    cells[c].pl = grid.plane[c];
    grid.cellCentre(c, &cells[c].x0, &cells[c].y0);
  }
  return cells;
}

// heightsAboveGround into *out.
void heightsPass(const LocalPoints& pts, const GroundGrid& grid, std::vector<float>* out) {
  std::vector<float>& h = *out;
  const size_t n = pts.size();
  const std::vector<Centred> cells = centredPlanes(grid);
  h.resize(n);
  const PointCell cell_of(grid);
  const float *X = pts.x.data(), *Y = pts.y.data(), *Z = pts.z.data();
  float* H = h.data();
  for (size_t i = 0; i < n; ++i) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n), prefetchAhead(Z, i, n);
    const Centred& cc = cells[cell_of(X[i], Y[i])];
    H[i] = static_cast<float>(Z[i] - cc.pl.at(X[i] - cc.x0, Y[i] - cc.y0));
  }
}

// The cells' geometry without their arrays (cellOf works on it).
GroundMapCells cellGeometry(const GroundMapCells& mc) {
  GroundMapCells g;
  g.copyGeometry(mc);
  return g;
}

// What heightsSlabPass carries from point to point: the slab's count and the map cells' run of
// points in one cell (consecutive returns mostly are), whose lowest point and count stay in
// registers instead of a read-modify-write of the cell per point.
struct SlabRun {
  size_t ns = 0;
  size_t run = GroundMapCells::npos;
  float run_low = std::numeric_limits<float>::infinity();
  uint32_t run_hits = 0;

  // Point i of height class `in_slab`, and with kMapCells its map cell k and local z.
  template <bool kMapCells>
  void add(uint32_t* S, size_t i, bool in_slab, size_t k, float z, GroundMapCells* map_cells) {
    S[ns] = static_cast<uint32_t>(i);
    ns += static_cast<size_t>(in_slab);
    if (kMapCells) addCell(k, z, map_cells);
  }
  // A point of map cell k and local z.
  void addCell(size_t k, float z, GroundMapCells* map_cells) {
    if (k != run) {
      map_cells->addRun(run, run_low, run_hits);
      run = k, run_low = z, run_hits = 0;
    }
    run_low = std::min(run_low, z);
    ++run_hits;
  }
};

#if DTIF_AVX2_PATHS
// GroundMapCells::cellOf of four points, -1 for npos. In double: the floors and the corner are
// whole numbers far below 2^53, so their differences and the index are exact.
struct MapCellLanes {
  DTIF_TARGET_AVX2 explicit MapCellLanes(const GroundMapCells& m)
      : ox(_mm256_set1_pd(m.ox)),
        oy(_mm256_set1_pd(m.oy)),
        by_cell(m.byCell()),
        x0(_mm256_set1_pd(static_cast<double>(m.x0))),
        y0(_mm256_set1_pd(static_cast<double>(m.y0))),
        w(_mm256_set1_pd(static_cast<double>(m.width))),
        h(_mm256_set1_pd(static_cast<double>(m.height))) {}
  DTIF_TARGET_AVX2 __m128i operator()(__m256d x, __m256d y) const {
    const __m256d ix = _mm256_sub_pd(_mm256_floor_pd(by_cell(_mm256_add_pd(x, ox))), x0);
    const __m256d iy = _mm256_sub_pd(_mm256_floor_pd(by_cell(_mm256_add_pd(y, oy))), y0);
    const __m256d zero = _mm256_setzero_pd();
    const __m256d in = _mm256_and_pd(
        _mm256_and_pd(_mm256_cmp_pd(ix, zero, _CMP_GE_OQ), _mm256_cmp_pd(ix, w, _CMP_LT_OQ)),
        _mm256_and_pd(_mm256_cmp_pd(iy, zero, _CMP_GE_OQ), _mm256_cmp_pd(iy, h, _CMP_LT_OQ)));
    const __m256d k = _mm256_add_pd(_mm256_mul_pd(iy, w), ix);
    return _mm256_cvttpd_epi32(_mm256_blendv_pd(_mm256_set1_pd(-1.0), k, in));
  }
  __m256d ox, oy;
  DivisorLanes by_cell;
  __m256d x0, y0, w, h;
};

static_assert(sizeof(GroundPlane) == 3 * sizeof(double), "planes are read as rows of doubles");

// heightsSlabPass four points at a time: the cells, centres, planes and heights in lanes, the
// same IEEE operations per point as heightsSlabScalar (no fused multiply-add); the heights by
// one store, the slab's indices packed from a table of lanes, and the map cells' run in one go
// where all four points continue it.
struct HeightsAvx2 {
  DTIF_TARGET_AVX2 HeightsAvx2(const GroundGrid& g, const GroundMapCells& geometry, double lo,
                               double hi)
      : cell_of(g),
        map_of(geometry),
        plane(&g.plane.data()->a),
        lo(_mm256_set1_pd(lo)),
        hi(_mm256_set1_pd(hi)) {}
  // Points i.. (count of them, <= 4) of X, Y, Z from x, y, z (four readable each).
  template <bool kMapCells>
  DTIF_TARGET_AVX2 void block(const float* x, const float* y, const float* z, size_t i, int count,
                              float* H, uint32_t* S, SlabRun* run, GroundMapCells* mc) const {
    const __m128 zf = _mm_loadu_ps(z);
    const __m256d vx = _mm256_cvtps_pd(_mm_loadu_ps(x)), vy = _mm256_cvtps_pd(_mm_loadu_ps(y));
    __m256d cx, cy;
    const __m128i c = cell_of(vx, vy, &cx, &cy);
    const __m128i c3 = _mm_add_epi32(c, _mm_add_epi32(c, c));
    __m256d a, b, s;
    planes(c3, &a, &b, &s);
    // pl.at(x - x0, y - y0) = (a + b (x - x0)) + s (y - y0); h rounded to float, as stored.
    const __m256d at = _mm256_add_pd(_mm256_add_pd(a, _mm256_mul_pd(b, _mm256_sub_pd(vx, cx))),
                                     _mm256_mul_pd(s, _mm256_sub_pd(vy, cy)));
    const __m128 h = _mm256_cvtpd_ps(_mm256_sub_pd(_mm256_cvtps_pd(zf), at));
    const __m256d hd = _mm256_cvtps_pd(h);
    const int slab = _mm256_movemask_pd(
        _mm256_and_pd(_mm256_cmp_pd(hd, lo, _CMP_GE_OQ), _mm256_cmp_pd(hd, hi, _CMP_LT_OQ)));
    const __m128i k = kMapCells ? map_of(vx, vy) : _mm_setzero_si128();
    if (count == 4) return four<kMapCells>(h, slab, k, zf, i, H, S, run, mc);
    alignas(16) float hv[4], zv[4];
    alignas(16) int32_t kv[4];
    _mm_store_ps(hv, h), _mm_store_ps(zv, zf);
    _mm_store_si128(reinterpret_cast<__m128i*>(kv), k);
    for (int j = 0; j < count; ++j) {
      H[i + j] = hv[j];
      run->add<kMapCells>(S, i + j, (slab >> j) & 1, cellOfLane(kv[j]), zv[j], mc);
    }
  }
  // block's four points i..i+3 of heights h, slab lanes `slab`, map cells k (-1: npos) and
  // local z. S has room for four more: run->ns <= i.
  template <bool kMapCells>
  DTIF_TARGET_AVX2 void four(__m128 h, int slab, __m128i k, __m128 z, size_t i, float* H,
                             uint32_t* S, SlabRun* run, GroundMapCells* mc) const {
    _mm_storeu_ps(H + i, h);
    const __m128i lanes = _mm_load_si128(reinterpret_cast<const __m128i*>(kLanes.lane[slab]));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(S + run->ns),
                     _mm_add_epi32(_mm_set1_epi32(static_cast<int32_t>(i)), lanes));
    run->ns += static_cast<size_t>(kLanes.count[slab]);
    if (kMapCells) cells4(k, z, run, mc);
  }
  // Four points of map cells k (-1: npos) and local z added to the run as add() adds them one by
  // one: the lanes that continue the run, then from each change of cell (mostly none) on, each
  // part's lowest z by one reduction (leftMin).
  DTIF_TARGET_AVX2 static void cells4(__m128i k, __m128 z, SlabRun* run, GroundMapCells* mc) {
    alignas(16) float zv[4];
    alignas(16) int32_t kv[4];
    if (_mm_movemask_ps(_mm_cmpunord_ps(z, z))) {  // a NaN: leftMin would not be the chain's
      _mm_store_ps(zv, z), _mm_store_si128(reinterpret_cast<__m128i*>(kv), k);
      for (int j = 0; j < 4; ++j) run->addCell(cellOfLane(kv[j]), zv[j], mc);
      return;
    }
    // npos is -1 as an int32; no real cell is (at most 4e6 cells).
    const __m128i prev = _mm_alignr_epi8(k, _mm_set1_epi32(static_cast<int32_t>(run->run)), 12);
    uint32_t change = ~_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(k, prev))) & 15u;
    int j = 0;
    while (change) {
      const int e = __builtin_ctz(change);
      run->run_low = leftMin(run->run_low, z, j, e), run->run_hits += e - j;
      mc->addRun(run->run, run->run_low, run->run_hits);
      _mm_store_ps(zv, z), _mm_store_si128(reinterpret_cast<__m128i*>(kv), k);
      run->run = cellOfLane(kv[e]), run->run_low = zv[e], run->run_hits = 0;
      j = e, change &= change - 1;
    }
    run->run_low = leftMin(run->run_low, z, j, 4), run->run_hits += 4 - j;
  }
  DTIF_TARGET_AVX2 static size_t cellOfLane(int32_t k) {
    return k < 0 ? GroundMapCells::npos : static_cast<size_t>(k);
  }
  // The chain low = std::min(low, z[l]) over lanes l = j..e-1, without NaN. std::min keeps its
  // first argument unless the second is lower: over values without NaN that is the first lowest
  // of the sequence however the mins are grouped (a -0/+0 tie keeps the chain's sign), and a +inf
  // in the lanes left out changes nothing.
  DTIF_TARGET_AVX2 static float leftMin(float low, __m128 z, int j, int e) {
    const __m128i lane = _mm_setr_epi32(0, 1, 2, 3);
    const __m128i in = _mm_andnot_si128(_mm_cmpgt_epi32(_mm_set1_epi32(j), lane),
                                        _mm_cmpgt_epi32(_mm_set1_epi32(e), lane));
    const __m128 v =
        _mm_blendv_ps(_mm_set1_ps(std::numeric_limits<float>::infinity()), z, _mm_castsi128_ps(in));
    // _mm_min_ps(b, a) is b < a ? b : a, std::min(a, b): lanes 0 and 2 = min(v0, v1), min(v2, v3).
    const __m128 pairs = _mm_min_ps(_mm_shuffle_ps(v, v, _MM_SHUFFLE(2, 3, 0, 1)), v);
    const __m128 all = _mm_min_ss(_mm_movehl_ps(pairs, pairs), pairs);
    return _mm_cvtss_f32(_mm_min_ss(all, _mm_set_ss(low)));
  }
  // The planes (a, b, c) of the four cells at 3 c: four masked loads of a row (nothing read past
  // it) and a transpose, shorter in latency than three gathers.
  DTIF_TARGET_AVX2 void planes(__m128i c3, __m256d* a, __m256d* b, __m256d* s) const {
    const __m256i row = _mm256_setr_epi64x(-1, -1, -1, 0);
    const __m256d r0 = _mm256_maskload_pd(plane + _mm_cvtsi128_si32(c3), row);
    const __m256d r1 = _mm256_maskload_pd(plane + _mm_extract_epi32(c3, 1), row);
    const __m256d r2 = _mm256_maskload_pd(plane + _mm_extract_epi32(c3, 2), row);
    const __m256d r3 = _mm256_maskload_pd(plane + _mm_extract_epi32(c3, 3), row);
    const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);
    const __m256d t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);
    *a = _mm256_permute2f128_pd(t0, t2, 0x20);
    *b = _mm256_permute2f128_pd(t1, t3, 0x20);
    *s = _mm256_permute2f128_pd(t0, t2, 0x31);
  }
  GroundCellLanes cell_of;
  MapCellLanes map_of;
  const double* plane;  // a, b, c of each cell
  __m256d lo, hi;
};

// heightsSlabPass's points, all of them: the last few through a padded copy (the last point
// repeated, so every lane has a cell).
template <bool kMapCells>
DTIF_TARGET_AVX2 void heightsSlabAvx2(const LocalPoints& pts, const GroundGrid& grid, double lo,
                                      double hi, float* H, uint32_t* S, SlabRun* r,
                                      GroundMapCells* map_cells) {
  const size_t n = pts.size();
  const float *X = pts.x.data(), *Y = pts.y.data(), *Z = pts.z.data();
  const GroundMapCells geometry = kMapCells ? cellGeometry(*map_cells) : GroundMapCells();
  const HeightsAvx2 lanes(grid, geometry, lo, hi);
  SlabRun run = *r;
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n), prefetchAhead(Z, i, n);
    lanes.block<kMapCells>(X + i, Y + i, Z + i, i, 4, H, S, &run, map_cells);
  }
  if (i < n) {
    float x[4], y[4], z[4];
    for (size_t j = 0; j < 4; ++j) {
      const size_t k = std::min(i + j, n - 1);
      x[j] = X[k], y[j] = Y[k], z[j] = Z[k];
    }
    lanes.block<kMapCells>(x, y, z, i, static_cast<int>(n - i), H, S, &run, map_cells);
  }
  *r = run;
}
#endif

// heightsSlabPass's points one at a time.
template <bool kMapCells>
void heightsSlabScalar(const LocalPoints& pts, const GroundGrid& grid, double lo, double hi,
                       float* H, uint32_t* S, SlabRun* r, GroundMapCells* map_cells) {
  const size_t n = pts.size();
  const std::vector<Centred> cells = centredPlanes(grid);
  const PointCell cell_of(grid);
  const float *X = pts.x.data(), *Y = pts.y.data(), *Z = pts.z.data();
  // A copy of the cells' geometry in locals: through the pointer, each store to a cell would
  // make the compiler reload it and the point arrays.
  const GroundMapCells geometry = kMapCells ? cellGeometry(*map_cells) : GroundMapCells();
  SlabRun run = *r;
  for (size_t i = 0; i < n; ++i) {
    prefetchAhead(X, i, n), prefetchAhead(Y, i, n), prefetchAhead(Z, i, n);
    const float x = X[i], y = Y[i], z = Z[i];
    const Centred& cc = cells[cell_of(x, y)];
    const float hv = static_cast<float>(z - cc.pl.at(x - cc.x0, y - cc.y0));
    H[i] = hv;
    // Branch-free, as slabColumns selects: about a quarter of the points are in the slab, in no
    // predictable pattern.
    const size_t k = kMapCells ? geometry.cellOf(x, y) : 0;
    run.add<kMapCells>(S, i, (hv >= lo) & (hv < hi), k, z, map_cells);
  }
  *r = run;
}

// heightsAndSlab, and with kMapCells each point added to *map_cells.
template <bool kMapCells>
void heightsSlabPass(const LocalPoints& pts, const GroundGrid& grid, const TrunkExtractorParams& p,
                     std::vector<float>* out, std::vector<uint32_t>* slab,
                     GroundMapCells* map_cells) {
  const size_t n = pts.size();
  out->resize(n);
  slab->resize(n);
  SlabRun run;
  bool done = false;
#if DTIF_AVX2_PATHS
  if (useAvx2()) {
    heightsSlabAvx2<kMapCells>(pts, grid, p.slab_min_h_m, p.slab_max_h_m, out->data(), slab->data(),
                               &run, map_cells);
    done = true;
  }
#endif
  if (!done) {
    heightsSlabScalar<kMapCells>(pts, grid, p.slab_min_h_m, p.slab_max_h_m, out->data(),
                                 slab->data(), &run, map_cells);
  }
  if (kMapCells) map_cells->addRun(run.run, run.run_low, run.run_hits);
  slab->resize(run.ns);
}

}  // namespace

void heightsAboveGround(const LocalPoints& pts, const GroundGrid& grid, std::vector<float>* out) {
  heightsPass(pts, grid, out);
}

void heightsAndSlab(const LocalPoints& pts, const GroundGrid& grid, const TrunkExtractorParams& p,
                    std::vector<float>* h, std::vector<uint32_t>* slab) {
  heightsSlabPass<false>(pts, grid, p, h, slab, nullptr);
}

void heightsAndSlab(const LocalPoints& pts, const GroundGrid& grid, const TrunkExtractorParams& p,
                    std::vector<float>* h, std::vector<uint32_t>* slab, GroundMapCells* map_cells) {
  heightsSlabPass<true>(pts, grid, p, h, slab, map_cells);
}

bool GroundMapCells::init(const LocalPoints& pts, double cell, double max_z_bound) {
  used = false;
  if (pts.size() == 0 || !(cell > 0.0)) return false;
  float minx = pts.x[0], maxx = minx, miny = pts.y[0], maxy = miny;
  if (pts.has_extent) {
    minx = pts.minx, maxx = pts.maxx, miny = pts.miny, maxy = pts.maxy;
  } else {
    for (size_t i = 1; i < pts.size(); ++i) {
      minx = std::min(minx, pts.x[i]), maxx = std::max(maxx, pts.x[i]);
      miny = std::min(miny, pts.y[i]), maxy = std::max(maxy, pts.y[i]);
    }
  }
  cell_m = cell;
  by_cell_ = Divisor(cell);
  ox = pts.ox, oy = pts.oy, oz = pts.oz;
  // Floor and the division are monotonic: every point's cell lies between the extent's.
  x0 = floorIndex(by_cell_(minx + ox)), y0 = floorIndex(by_cell_(miny + oy));
  width = floorIndex(by_cell_(maxx + ox)) - x0 + 1;
  height = floorIndex(by_cell_(maxy + oy)) - y0 + 1;
  if (!(width > 0 && height > 0 && static_cast<double>(width) * height <= 4e6)) return false;
  low.assign(static_cast<size_t>(width * height), std::numeric_limits<float>::infinity());
  hits.assign(low.size(), 0);
  max_z = max_z_bound;
  used = true;
  return true;
}

Footprint trunkFootprint(const Cloud& cloud, const TrunkExtractorParams& p) {
  if (!(p.footprint_cell_m > 0.0)) return Footprint();
  return makeFootprint(trunkHeightCells(cloud, Pose::Identity(), p.footprint_cell_m,
                                        static_cast<size_t>(p.footprint_max_samples)),
                       p.footprint_cell_m);
}

}  // namespace dtif
