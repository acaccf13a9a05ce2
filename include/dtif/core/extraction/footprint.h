// Where a submap saw anything at trunk height: the occupied horizontal cells of its points
// 0.3-3.0 m above the local ground, in the submap frame S. These are the cells of the evaluation
// protocol's overlap (DATASET.md), so verification can measure how much an aligned pair shares.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#ifdef __SSE2__
#include <emmintrin.h>
#endif
#include <utility>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/extraction/avx2.h"
#include "dtif/core/types.h"

#if DTIF_AVX2_PATHS
#include <immintrin.h>
#endif

namespace dtif {

/// Occupancy bitmap of horizontal cells in S. Cell (ix, iy) covers
/// [ix * cell_m, (ix + 1) * cell_m) x [iy * cell_m, (iy + 1) * cell_m). Immutable once built.
struct Footprint {
  double cell_m = 0.0;        ///< cell size; 0: no footprint [m]
  int32_t x0 = 0, y0 = 0;     ///< cell index of the bitmap's first column / row
  int32_t width = 0;          ///< columns
  int32_t height = 0;         ///< rows
  std::vector<uint8_t> bits;  ///< row-major; cell (x0 + k % width, y0 + k / width) is bit k

  bool empty() const { return cell_m <= 0.0 || count() == 0; }
  /// A cell size, a size that fits the wire formats (16-bit sides) and a bitmap of that size.
  bool wellFormed() const;
  size_t count() const;                         ///< occupied cells
  bool occupied(int64_t ix, int64_t iy) const;  ///< false outside the bitmap
};

/// Largest bitmap side [cells]; a wider extent doubles the cell size until it fits, which keeps
/// the descriptor within its radio budget (at most kMaxFootprintSide^2 / 8 bytes).
constexpr int32_t kMaxFootprintSide = 160;

/// Footprint of the given occupied cells (indices at `cell_m`); duplicates are fine.
Footprint makeFootprint(const std::vector<std::pair<int64_t, int64_t>>& cells, double cell_m);

/// Overlap of two footprints under T_c_q (query cells mapped into the candidate frame):
/// |cells(q) ∩ cells(c)| / min(|cells(q)|, |cells(c)|), DATASET.md's definition. Returns -1
/// when either footprint is empty.
double footprintOverlap(const Footprint& q, const Footprint& c, const Pose& T_c_q);

/// DATASET.md's overlap cells: the cells (side `cell_m`, in frame F) of a submap's points
/// 0.3-3.0 m above its local ground, the local ground of each 2 m tile of S being the 5th
/// percentile of z in the 6 m window around it. `max_ground_samples` > 0 takes the percentiles
/// on an even subsample of at most that many points (the descriptor's footprint, timed);
/// 0 uses every point (the evaluation). Sorted, unique.
std::vector<std::pair<int64_t, int64_t>> trunkHeightCells(const Cloud& cloud_S, const Pose& T_F_S,
                                                          double cell_m,
                                                          size_t max_ground_samples = 0);

/// trunkHeightCells of a cloud, marked point by point by a caller that passes over the cloud
/// anyway (extraction): the tiles' ground comes first from the ground samples (every stride-th
/// point of a cloud without non-finite points), then add() marks each point's cell. The same
/// cells as trunkHeightCells(cloud_S, Identity, cell_m, max_ground_samples) when every point of
/// the cloud was added, in order or not, and the cloud had no non-finite point.
class HeightCellMarks {
 public:
  /// Tile ground from the samples (sx, sy, sz) and the cells of the box [lo, hi] (S) that the
  /// added points lie in. false (then use trunkHeightCells) without samples, beyond 1e6 m from
  /// the origin, or when either grid would be large.
  bool init(const std::vector<float>& sx, const std::vector<float>& sy,
            const std::vector<float>& sz, double cell_m, const Eigen::Vector2d& lo,
            const Eigen::Vector2d& hi);
  /// add() for a pass over many points, branch-free (about half the points lie in the band, in
  /// no pattern the branch predictor follows) and held in the caller's registers: through the
  /// object, each mark (a byte store, which may alias anything) made the compiler reload every
  /// member. finish() it before complete() or cells().
  class Pass {
   public:
    /// Marks the cell of a point (inside the box) when it lies in the trunk-height band; a
    /// point without a tile or outside the band marks the sink, one byte past the cells.
    void add(float x, float y, float z) {
      // floor(x / 2^k) = floor(floor(x) / 2^k) = floor(x) >> k: the 2 m tile and, for cells of
      // 2^k m (k >= 0, the default 1 m), the cell from one floor of each coordinate.
      const int64_t fx = floorOf(x), fy = floorOf(y);
      bool tile;
      const float h = z - tileGround((fx >> 1) - tx0_, (fy >> 1) - ty0_, &tile);  // NaN: none
      const bool band = tile & (h >= kMin) & (h <= kMax);
      mark(band, (shift_ >= 0 ? fx >> shift_ : floorOf(cellDiv(x))) - cx0_,
           (shift_ >= 0 ? fy >> shift_ : floorOf(cellDiv(y))) - cy0_);
    }

#ifdef __SSE2__
    /// add() of four finite points, lanes of x, y and z: the same marks and flag. The floors,
    /// tiles, band and cells four at a time (int32 lanes: init bounds the box to 1e6 m), the
    /// ground reads, indices and marks one by one; one by one all of it made ~70 % of the
    /// extraction's first pass.
    void add4(__m128 x, __m128 y, __m128 z) {
      if (shift_ < 0) {  // cells not of 2^k m: add() lane by lane
        alignas(16) float px[4], py[4], pz[4];
        _mm_store_ps(px, x), _mm_store_ps(py, y), _mm_store_ps(pz, z);
        for (int j = 0; j < 4; ++j) add(px[j], py[j], pz[j]);
        return;
      }
      const __m128i fx = floor4(x), fy = floor4(y);
      alignas(16) int32_t tx[4], ty[4], cx[4], cy[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(tx),
                      _mm_sub_epi32(_mm_srai_epi32(fx, 1), _mm_set1_epi32(int32_t(tx0_))));
      _mm_store_si128(reinterpret_cast<__m128i*>(ty),
                      _mm_sub_epi32(_mm_srai_epi32(fy, 1), _mm_set1_epi32(int32_t(ty0_))));
      const __m128i shift = _mm_cvtsi32_si128(shift_);
      _mm_store_si128(reinterpret_cast<__m128i*>(cx),
                      _mm_sub_epi32(_mm_sra_epi32(fx, shift), _mm_set1_epi32(int32_t(cx0_))));
      _mm_store_si128(reinterpret_cast<__m128i*>(cy),
                      _mm_sub_epi32(_mm_sra_epi32(fy, shift), _mm_set1_epi32(int32_t(cy0_))));
      alignas(16) float g[4];
      bool tile[4];
      for (int j = 0; j < 4; ++j) g[j] = tileGround(tx[j], ty[j], &tile[j]);
      // h >= kMin and h <= kMax as float comparisons with the bounds' nearest floats inside.
      const __m128 h = _mm_sub_ps(z, _mm_load_ps(g));
      const int in_band = _mm_movemask_ps(
          _mm_and_ps(_mm_cmpge_ps(h, _mm_set1_ps(kMinF)), _mm_cmple_ps(h, _mm_set1_ps(kMaxF))));
      for (int j = 0; j < 4; ++j) mark(tile[j] & ((in_band >> j) & 1), cx[j], cy[j]);
    }
#endif

#if DTIF_AVX2_PATHS
    /// add4 of eight finite points (AVX2; the caller checks useAvx2()): the tiles' ground
    /// gathered and the indices selected in lanes, only the marks' byte stores one by one.
    DTIF_TARGET_AVX2 void add8(__m256 x, __m256 y, __m256 z) {
      if (shift_ < 0) {  // cells not of 2^k m: add() lane by lane
        alignas(32) float px[8], py[8], pz[8];
        _mm256_store_ps(px, x), _mm256_store_ps(py, y), _mm256_store_ps(pz, z);
        for (int j = 0; j < 8; ++j) add(px[j], py[j], pz[j]);
        return;
      }
      const __m256i fx = floor8(x), fy = floor8(y);
      const __m256i tx = _mm256_sub_epi32(_mm256_srai_epi32(fx, 1), set8(tx0_));
      const __m256i ty = _mm256_sub_epi32(_mm256_srai_epi32(fy, 1), set8(ty0_));
      const __m256i tile = _mm256_and_si256(below8(tx, tw_), below8(ty, th_));
      // tileGround: tile 0's ground outside the tile grid, as there (the products of those
      // lanes, which may wrap, are not used).
      const __m256i at =
          _mm256_and_si256(tile, _mm256_add_epi32(_mm256_mullo_epi32(ty, set8(tw_)), tx));
      const __m256 all = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
      const __m256 g = _mm256_mask_i32gather_ps(_mm256_setzero_ps(), ground_, at, all, 4);
      const __m256 h = _mm256_sub_ps(z, g);
      const __m256i band = _mm256_and_si256(
          tile,
          _mm256_castps_si256(_mm256_and_ps(_mm256_cmp_ps(h, _mm256_set1_ps(kMinF), _CMP_GE_OQ),
                                            _mm256_cmp_ps(h, _mm256_set1_ps(kMaxF), _CMP_LE_OQ))));
      const __m128i shift = _mm_cvtsi32_si128(shift_);
      const __m256i cx = _mm256_sub_epi32(_mm256_sra_epi32(fx, shift), set8(cx0_));
      const __m256i cy = _mm256_sub_epi32(_mm256_sra_epi32(fy, shift), set8(cy0_));
      const __m256i box = _mm256_and_si256(below8(cx, cw_), below8(cy, ch_));
      outside_ |= _mm256_movemask_epi8(_mm256_andnot_si256(box, band)) != 0;
      // mark: the cell where in the band and the box, else the sink.
      const __m256i cell = _mm256_add_epi32(_mm256_mullo_epi32(cx, set8(ch_)), cy);
      const __m256i in = _mm256_and_si256(band, box);
      alignas(32) int32_t k[8];
      _mm256_store_si256(reinterpret_cast<__m256i*>(k),
                         _mm256_blendv_epi8(set8(static_cast<int64_t>(sink_)), cell, in));
      for (int j = 0; j < 8; ++j) marks_[static_cast<uint32_t>(k[j])] = 1;
    }
#endif

   private:
    friend class HeightCellMarks;
#if DTIF_AVX2_PATHS
    // floor4 of eight floats.
    DTIF_TARGET_AVX2 static __m256i floor8(__m256 v) {
      const __m256i i = _mm256_cvttps_epi32(v);
      return _mm256_add_epi32(
          i, _mm256_castps_si256(_mm256_cmp_ps(v, _mm256_cvtepi32_ps(i), _CMP_LT_OQ)));
    }
    DTIF_TARGET_AVX2 static __m256i set8(int64_t v) {
      return _mm256_set1_epi32(static_cast<int32_t>(v));
    }
    // Lanes with 0 <= v < n (n > 0): the unsigned comparison of tileGround and mark.
    DTIF_TARGET_AVX2 static __m256i below8(__m256i v, int64_t n) {
      const __m256i nonneg = _mm256_cmpgt_epi32(v, _mm256_set1_epi32(-1));
      return _mm256_and_si256(nonneg, _mm256_cmpgt_epi32(set8(n), v));
    }
#endif
    // The ground of tile (tx, ty) (tile grid indices); *tile false when it lies outside the grid
    // (then tile 0's ground, which band tests discard).
    float tileGround(int64_t tx, int64_t ty, bool* tile) const {
      *tile = (static_cast<uint64_t>(tx) < static_cast<uint64_t>(tw_)) &
              (static_cast<uint64_t>(ty) < static_cast<uint64_t>(th_));
      return ground_[select(*tile, static_cast<size_t>(ty * tw_ + tx), 0)];
    }
    // Marks cell (cx, cy) (cell grid indices) when the point is in the band, else the sink; a
    // band point outside the box (only by rounding at the box's edge) sets outside_.
    void mark(bool band, int64_t cx, int64_t cy) {
      const bool box = (static_cast<uint64_t>(cx) < static_cast<uint64_t>(cw_)) &
                       (static_cast<uint64_t>(cy) < static_cast<uint64_t>(ch_));
      outside_ |= band & !box;
      marks_[select(band & box, static_cast<size_t>(cx * ch_ + cy), sink_)] = 1;
    }
#ifdef __SSE2__
    // floorOf of four floats (|v| < 2^31): truncation, one less where that rose above v.
    static __m128i floor4(__m128 v) {
      const __m128i i = _mm_cvttps_epi32(v);
      return _mm_add_epi32(i, _mm_castps_si128(_mm_cmplt_ps(v, _mm_cvtepi32_ps(i))));
    }
#endif
    // c ? a : b by a mask: the compiler made a branch of the conditional.
    static size_t select(bool c, size_t a, size_t b) {
      const size_t m = size_t{0} - static_cast<size_t>(c);
      return (a & m) | (b & ~m);
    }
    double cellDiv(float v) const { return pow2_ ? v * inv_cell_ : v / cell_m_; }
    double cell_m_ = 1.0, inv_cell_ = 1.0;
    bool pow2_ = true;
    int shift_ = 0;                                // k of cells of 2^k m, k >= 0; else -1
    int64_t tx0_ = 0, ty0_ = 0, tw_ = 0, th_ = 0;  // tile grid
    int64_t cx0_ = 0, cy0_ = 0, cw_ = 0, ch_ = 0;  // cell grid
    const float* ground_ = nullptr;
    uint8_t* marks_ = nullptr;
    size_t sink_ = 0;
    bool outside_ = false;
  };
  /// A pass over points that add() each (init succeeded).
  Pass pass() {
    Pass p = grid_;
    p.ground_ = ground_.data(), p.marks_ = marks_.data(), p.sink_ = marks_.size() - 1;
    return p;
  }
  void finish(const Pass& p) { grid_.outside_ = grid_.outside_ || p.outside_; }
  /// Marks the cell of a point (inside the box) when it lies in the trunk-height band.
  void add(float x, float y, float z) {
    Pass p = pass();
    p.add(x, y, z);
    finish(p);
  }
  /// false when a point fell outside the box: then cells() misses it.
  bool complete() const { return !grid_.outside_; }
  /// The marked cells, sorted, unique.
  std::vector<std::pair<int64_t, int64_t>> cells() const;

 private:
  static int64_t floorOf(double v) {  // floor without libm's call; |v| < 2^40 here
    const int64_t i = static_cast<int64_t>(v);
    return i - (v < static_cast<double>(i));
  }
  static int64_t floorOf(float v) {  // exact: i converts back exactly (|v| >= 2^23 is whole)
    const int64_t i = static_cast<int64_t>(v);
    return i - (v < static_cast<float>(i));
  }
  static constexpr double kMin = 0.3, kMax = 3.0;  // the band, as trunkHeightCells compares it
  // For a float h, h >= kMin exactly when h >= kMinF, and h <= kMax when h <= kMaxF: the
  // nearest floats at or inside the band (0.3f lies above 0.3; 3 is a float).
  static constexpr float kMinF = 0.3f, kMaxF = 3.0f;
  static_assert(static_cast<double>(kMinF) >= kMin && static_cast<double>(kMaxF) <= kMax);
  // The tile grid (ground_), the cell grid (marks_, column-major) and whether a point fell
  // outside; pass() hands out a copy pointing at the vectors.
  Pass grid_;
  std::vector<float> ground_;   // per tile; NaN: no sample in its window
  std::vector<uint8_t> marks_;  // and the sink, last
};

}  // namespace dtif
