// Trunk landmark extraction (paper Sec. 3.B, "Trunk landmark extraction", after Zhang et al.):
// no explicit ground segmentation; a local ground from a low z percentile, vertical-continuity
// voxel columns in a low slab above it, connected columns as trunk candidates, a robust circle
// fit at breast height, and the stem-base elevation z_m from the ground ring around the stem.
// The stages are in extraction_stages.h; this file holds the per-candidate stages and the
// pipeline.
//
// The main pass uses flat arrays, counting sorts and an open-addressing hash instead of PCL
// kd-trees: the whole descriptor must take <= 40 ms per submap on one core (DESIGN.md).
#include "dtif/core/extraction/trunk_extractor.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "dtif/core/extraction/avx2.h"
#include "dtif/core/extraction/extraction_stages.h"
#include "dtif/core/extraction/point_bounds.h"

#ifdef __SSE2__
#include <emmintrin.h>
#endif
#if DTIF_AVX2_PATHS
#include <immintrin.h>
#endif

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Collects what is wrong with a parameter set, "; "-separated.
class Checks {
 public:
  void require(bool ok, const char* what) {
    if (!ok) err_ << what << "; ";
  }
  void positive(const char* name, double v) {
    if (!(v > 0.0) || !std::isfinite(v)) err_ << name << " must be > 0 (got " << v << "); ";
  }
  void unit(const char* name, double v) {
    if (!(v >= 0.0 && v <= 1.0)) err_ << name << " must be in [0, 1] (got " << v << "); ";
  }
  std::string str() const {
    std::string s = err_.str();
    if (s.size() >= 2) s.resize(s.size() - 2);
    return s;
  }

 private:
  std::ostringstream err_;
};

void checkBounds(const TrunkExtractorParams& p, Checks* c) {
  c->require(p.max_range_m >= 10.0 && p.max_range_m <= 10000.0,
             "max_range_m must be in [10, 10000]");
  c->require(p.max_points >= 1 && p.max_points <= 100000000, "max_points must be in [1, 1e8]");
  // The ground grid's cost grows with (max_range_m / ground_cell_m)^2 cells, each fitting a
  // plane over (ground_window_m / ground_cell_m)^2 cells: bounded so no value hangs.
  c->require(!(p.ground_cell_m < 0.25 || p.ground_cell_m > 20.0),
             "ground_cell_m must be in [0.25, 20]");
  c->require(!(p.ground_window_m > 20.0 * p.ground_cell_m || p.ground_window_m > 100.0),
             "ground_window_m must be <= 20 ground_cell_m and <= 100");
  c->require(!(p.ground_sub_cell_m < 0.05 || p.ground_sub_cell_m > p.ground_cell_m),
             "ground_sub_cell_m must be in [0.05, ground_cell_m]");
  c->require(!(p.column_cell_m < 0.02 || p.column_cell_m > 2.0),
             "column_cell_m must be in [0.02, 2]");
  c->require(!(p.ransac_iterations > 100000 || p.max_fits_per_candidate > 100),
             "ransac_iterations must be <= 1e5 and max_fits_per_candidate <= 100");
  c->require(!(p.ground_map_cell_m > 0.0 && p.ground_map_cell_m < 0.05),
             "ground_map_cell_m must be 0 or >= 0.05");
  c->require(!(p.footprint_cell_m > 0.0 && p.footprint_cell_m < 0.05),
             "footprint_cell_m must be 0 or >= 0.05");
}

void checkGroundAndColumns(const TrunkExtractorParams& p, Checks* c) {
  c->positive("ground_cell_m", p.ground_cell_m);
  c->positive("ground_window_m", p.ground_window_m);
  c->unit("ground_percentile", p.ground_percentile);
  c->require(p.max_ground_cells >= 1.0 && std::isfinite(p.max_ground_cells),
             "max_ground_cells must be >= 1");
  c->positive("ground_sub_cell_m", p.ground_sub_cell_m);
  c->require(p.ground_band_m >= 0.0, "ground_band_m must be >= 0");
  c->require(p.ground_open_gap_m >= 0.0, "ground_open_gap_m must be >= 0");
  c->require(p.ground_open_top_m > p.ground_open_gap_m,
             "ground_open_top_m must exceed ground_open_gap_m");
  c->unit("ground_min_open_fraction", p.ground_min_open_fraction);
  c->positive("ground_max_step", p.ground_max_step);
  c->require(p.ground_min_cells >= 1, "ground_min_cells must be >= 1");
  c->positive("ground_plane_c_up_m", p.ground_plane_c_up_m);
  c->positive("ground_plane_c_down_m", p.ground_plane_c_down_m);
  c->require(p.slab_min_h_m >= 0.0, "slab_min_h_m must be >= 0");
  c->require(p.slab_max_h_m > p.slab_min_h_m, "slab_max_h_m must exceed slab_min_h_m");
  c->positive("column_cell_m", p.column_cell_m);
  c->positive("layer_h_m", p.layer_h_m);
  c->require(!(p.layer_h_m > 0.0 && (p.slab_max_h_m - p.slab_min_h_m) / p.layer_h_m > 64.0),
             "layer_h_m too small: at most 64 layers fit in the slab");
  c->require(p.min_column_points >= 1, "min_column_points must be >= 1");
  c->unit("min_continuity", p.min_continuity);
  c->require(p.cluster_gap_m >= 0.0, "cluster_gap_m must be >= 0");
  c->require(!(p.column_cell_m > 0.0 && p.cluster_gap_m / p.column_cell_m > 10.0),
             "cluster_gap_m must be <= 10 column cells");
}

void checkCircleFit(const TrunkExtractorParams& p, Checks* c) {
  c->require(p.fit_max_h_m > p.fit_min_h_m, "fit_max_h_m must exceed fit_min_h_m");
  c->require(p.fit_min_h_m >= p.slab_min_h_m && p.fit_max_h_m <= p.slab_max_h_m,
             "fit band [fit_min_h_m, fit_max_h_m] must lie inside the slab");
  c->require(p.min_fit_points >= 3, "min_fit_points must be >= 3");
  c->positive("min_radius_m", p.min_radius_m);
  c->require(p.max_radius_m > p.min_radius_m, "max_radius_m must exceed min_radius_m");
  c->require(p.ransac_iterations >= 1, "ransac_iterations must be >= 1");
  c->require(p.ransac_min_iterations >= 1, "ransac_min_iterations must be >= 1");
  c->require(p.ransac_score_points >= 1, "ransac_score_points must be >= 1");
  c->positive("ransac_inlier_m", p.ransac_inlier_m);
  c->unit("min_inlier_ratio", p.min_inlier_ratio);
  c->unit("min_shell_ratio", p.min_shell_ratio);
  c->require(p.min_arc_deg >= 0.0 && p.min_arc_deg <= 360.0, "min_arc_deg must be in [0, 360]");
  c->require(p.max_lean_deg > 0.0 && p.max_lean_deg < 90.0, "max_lean_deg must be in (0, 90)");
  c->require(p.lean_shell_m >= 0.0, "lean_shell_m must be >= 0");
}

void checkBaseAndOutputs(const TrunkExtractorParams& p, Checks* c) {
  c->require(p.base_ring_inner_m >= 0.0, "base_ring_inner_m must be >= 0");
  c->require(p.base_ring_outer_m > p.base_ring_inner_m,
             "base_ring_outer_m must exceed base_ring_inner_m");
  c->require(p.min_trunk_separation_m >= 0.0, "min_trunk_separation_m must be >= 0");
  c->positive("max_fit_rms_m", p.max_fit_rms_m);
  c->positive("base_max_dh_m", p.base_max_dh_m);
  c->require(p.min_base_points >= 3, "min_base_points must be >= 3");
  c->positive("base_below_m", p.base_below_m);
  c->require(p.max_base_below_points >= 0, "max_base_below_points must be >= 0");
  c->positive("base_plane_c_up_m", p.base_plane_c_up_m);
  c->positive("base_plane_c_down_m", p.base_plane_c_down_m);
  c->require(p.stem_shell_m >= 0.0, "stem_shell_m must be >= 0");
  c->positive("base_max_gap_m", p.base_max_gap_m);
  c->require(p.max_fits_per_candidate >= 1, "max_fits_per_candidate must be >= 1");
  c->require(p.footprint_cell_m >= 0.0 && p.footprint_cell_m <= 20.0,
             "footprint_cell_m must be in [0, 20] (0: no footprint)");
  c->require(p.footprint_max_samples >= 0, "footprint_max_samples must be >= 0 (0: all points)");
  c->require(p.ground_map_cell_m >= 0.0 && p.ground_map_cell_m <= 20.0,
             "ground_map_cell_m must be in [0, 20] (0: no ground map)");
  c->require(p.ground_map_z_step_m >= 0.001 && p.ground_map_z_step_m <= 1.0,
             "ground_map_z_step_m must be in [0.001, 1]");
  c->require(p.ground_map_min_points >= 1, "ground_map_min_points must be >= 1");
  c->require(p.ground_map_margin_m >= 0.0, "ground_map_margin_m must be >= 0");
  c->require(p.ground_map_below_seen >= 0.0 && p.ground_map_below_seen <= 1.01,
             "ground_map_below_seen must be in [0, 1.01]");
}

void checkDensity(const TrunkExtractorParams& p, Checks* c) {
  c->require(p.density_reference >= 0.0 && std::isfinite(p.density_reference),
             "density_reference must be >= 0 (0: no adaptation)");
  c->require(p.density_min_scale > 0.0 && p.density_min_scale <= 1.0,
             "density_min_scale must be in (0, 1]");
  c->require(p.density_min_range_m >= 0.0 && std::isfinite(p.density_min_range_m),
             "density_min_range_m must be >= 0");
  c->require(p.density_min_trunks >= 1, "density_min_trunks must be >= 1");
}

// What lies around a stem of local centre (cx, cy) and radius r. The arrays only grow (kept per
// thread between stems); the counts say how much of them is filled.
struct BaseRing {
  std::vector<double> bx, by, bz;   // ground points of the ring (|h| <= base_max_dh_m) [m]
  std::vector<uint32_t> on_ground;  // the same, by their place in grid.sorted
  size_t ground = 0;                // their count
  std::vector<uint32_t> ring;       // every point over the ring, by its place in grid.sorted
  size_t over = 0;                  // their count
  double stem_low = std::numeric_limits<double>::infinity();  // lowest stem point [m]

  void clear() {
    ground = over = 0;
    stem_low = std::numeric_limits<double>::infinity();
  }
  // Room for n more points of each kind: the gathering writes every point and keeps some.
  void room(size_t n) {
    if (on_ground.size() < ground + n) on_ground.resize(ground + n);
    if (ring.size() < over + n) ring.resize(over + n);
  }
  // The ground points' coordinates, from their places (a few of the points gathered).
  void groundPoints(const GroundGrid& grid) {
    if (bx.size() < ground) bx.resize(ground), by.resize(ground), bz.resize(ground);
    for (size_t g = 0; g < ground; ++g) {
      const GroundGrid::SortedPoint& q = grid.sorted[on_ground[g]];
      bx[g] = q.x, by[g] = q.y, bz[g] = q.z;
    }
  }
};

// True when no point of ground cell (gx, gy) can lie within r_out (the ring's and the stem
// shell's outer radius) of (cx, cy): a corner of the ring's box. Inner cells only (edge cells hold
// the points clamped into the grid), with a millimetre for the rounding of the points' cell.
bool outsideRing(const GroundGrid& grid, int gx, int gy, double cx, double cy, double r_out) {
  if (gx == 0 || gy == 0 || gx == grid.nx - 1 || gy == grid.ny - 1) return false;
  const double x0 = grid.minx + gx * grid.cell_m, y0 = grid.miny + gy * grid.cell_m;
  const double dx = std::max({x0 - cx, cx - (x0 + grid.cell_m), 0.0});
  const double dy = std::max({y0 - cy, cy - (y0 + grid.cell_m), 0.0});
  const double reach = r_out + 1e-3;
  return dx * dx + dy * dy > reach * reach;
}

// What places a point of one ground cell: the stem's centre, the squared radii of its shell
// and of the ring, the ground band, and the cell's plane about the cell's centre (x0, y0).
struct RingTests {
  double cx, cy, r_stem2, r_in2, r_out2, max_dh;
  GroundPlane pl;
  double x0, y0;
  bool avx2;  // useAvx2()
};

// Point k written at every point as a ring point and as a ground point, kept by the counts.
// stem_low: the lowest stem point.
struct RingOut {
  uint32_t *ground_at, *ring;
  size_t ground, over;
  double stem_low;

  void put(uint32_t k, bool in_ring, bool on_ground) {
    ring[over] = k;
    over += in_ring;
    ground_at[ground] = k;
    ground += in_ring & on_ground;
  }
};

// Points k0.. of a cell two at a time, as gatherCell's loop takes them one by one: the same
// IEEE operations per point (x86-64 has no fused multiply-add here). The stem's lowest point is
// a minimum per lane, merged after: the same value (only the sign of a zero could differ, which
// no comparison of it sees). Returns the first point not taken (k1 or k1 - 1).
uint32_t gatherPairs(const GroundGrid::SortedPoint* sorted, size_t ns, uint32_t k0, uint32_t k1,
                     const RingTests& t, RingOut* out) {
  uint32_t k = k0;
#ifdef __SSE2__
  const __m128d vcx = _mm_set1_pd(t.cx), vcy = _mm_set1_pd(t.cy), vx0 = _mm_set1_pd(t.x0);
  const __m128d vy0 = _mm_set1_pd(t.y0), va = _mm_set1_pd(t.pl.a), vb = _mm_set1_pd(t.pl.b);
  const __m128d vc = _mm_set1_pd(t.pl.c), vstem = _mm_set1_pd(t.r_stem2);
  const __m128d vin = _mm_set1_pd(t.r_in2), vout = _mm_set1_pd(t.r_out2);
  const __m128d vdh = _mm_set1_pd(t.max_dh);
  const __m128d inf = _mm_set1_pd(std::numeric_limits<double>::infinity());
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  __m128d low = inf;
  for (; k + 2 <= k1; k += 2) {
    prefetchAhead(sorted, k, ns);  // the row's next cells
    // (x0, y0, z0, x1) and (y1, z1): the pair's 24 bytes, nothing past them (the 8 bytes
    // through __m128i, which may alias floats, not through a double).
    const __m128 p = _mm_loadu_ps(&sorted[k].x);
    const __m128 q =
        _mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(&sorted[k + 1].y)));
    const __m128 yz = _mm_shuffle_ps(p, q, _MM_SHUFFLE(1, 0, 2, 1));  // y0 z0 y1 z1
    const __m128d x = _mm_cvtps_pd(_mm_shuffle_ps(p, p, _MM_SHUFFLE(3, 3, 3, 0)));
    const __m128d y = _mm_cvtps_pd(_mm_shuffle_ps(yz, yz, _MM_SHUFFLE(3, 3, 2, 0)));
    const __m128d z = _mm_cvtps_pd(_mm_shuffle_ps(yz, yz, _MM_SHUFFLE(3, 3, 3, 1)));
    const __m128d dx = _mm_sub_pd(x, vcx), dy = _mm_sub_pd(y, vcy);
    const __m128d d2 = _mm_add_pd(_mm_mul_pd(dx, dx), _mm_mul_pd(dy, dy));
    const __m128d on_stem = _mm_cmplt_pd(d2, vstem);
    low = _mm_min_pd(_mm_or_pd(_mm_and_pd(on_stem, z), _mm_andnot_pd(on_stem, inf)), low);
    const int in_ring = _mm_movemask_pd(_mm_and_pd(_mm_cmpge_pd(d2, vin), _mm_cmple_pd(d2, vout)));
    // pl.at(x - x0, y - y0) = (a + b (x - x0)) + c (y - y0); h rounded to float, as stored.
    const __m128d at = _mm_add_pd(_mm_add_pd(va, _mm_mul_pd(vb, _mm_sub_pd(x, vx0))),
                                  _mm_mul_pd(vc, _mm_sub_pd(y, vy0)));
    const __m128 h = _mm_and_ps(_mm_cvtpd_ps(_mm_sub_pd(z, at)), abs_mask);
    const int high = _mm_movemask_pd(_mm_cmpgt_pd(_mm_cvtps_pd(h), vdh));
    out->put(k, in_ring & 1, !(high & 1));
    out->put(k + 1, in_ring >> 1, !(high >> 1));
  }
  const double lane_low = std::min(_mm_cvtsd_f64(low), _mm_cvtsd_f64(_mm_unpackhi_pd(low, low)));
  out->stem_low = std::min(out->stem_low, lane_low);
#endif
  return k;
}

#if DTIF_AVX2_PATHS
// Four sorted points (lanes of x, y, z, as doubles) from their 48 bytes.
DTIF_TARGET_AVX2 void quadLanes(const GroundGrid::SortedPoint* q, __m256d* x, __m256d* y,
                                __m256d* z) {
  __m128 fx, fy, fz;
  deinterleave4(&q->x, &fx, &fy, &fz);
  *x = _mm256_cvtps_pd(fx), *y = _mm256_cvtps_pd(fy), *z = _mm256_cvtps_pd(fz);
}

// gatherPairs four points at a time (AVX2; the caller checks useAvx2()): the same IEEE
// operations per point, the stem's lowest point a minimum per lane as there. Returns the first
// point not taken.
DTIF_TARGET_AVX2 uint32_t gatherQuads(const GroundGrid::SortedPoint* sorted, size_t ns, uint32_t k0,
                                      uint32_t k1, const RingTests& t, RingOut* out) {
  const __m256d vcx = _mm256_set1_pd(t.cx), vcy = _mm256_set1_pd(t.cy);
  const __m256d vx0 = _mm256_set1_pd(t.x0), vy0 = _mm256_set1_pd(t.y0);
  const __m256d va = _mm256_set1_pd(t.pl.a), vb = _mm256_set1_pd(t.pl.b);
  const __m256d vc = _mm256_set1_pd(t.pl.c), vstem = _mm256_set1_pd(t.r_stem2);
  const __m256d vin = _mm256_set1_pd(t.r_in2), vout = _mm256_set1_pd(t.r_out2);
  const __m256d vdh = _mm256_set1_pd(t.max_dh);
  const __m256d inf = _mm256_set1_pd(std::numeric_limits<double>::infinity());
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  __m256d low = inf;
  uint32_t k = k0;
  for (; k + 4 <= k1; k += 4) {
    prefetchAhead(sorted, k, ns);  // the row's next cells
    __m256d x, y, z;
    quadLanes(sorted + k, &x, &y, &z);
    const __m256d dx = _mm256_sub_pd(x, vcx), dy = _mm256_sub_pd(y, vcy);
    const __m256d d2 = _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy));
    low = _mm256_min_pd(_mm256_blendv_pd(inf, z, _mm256_cmp_pd(d2, vstem, _CMP_LT_OQ)), low);
    const int in_ring = _mm256_movemask_pd(
        _mm256_and_pd(_mm256_cmp_pd(d2, vin, _CMP_GE_OQ), _mm256_cmp_pd(d2, vout, _CMP_LE_OQ)));
    // pl.at(x - x0, y - y0) = (a + b (x - x0)) + c (y - y0); h rounded to float, as stored.
    const __m256d at = _mm256_add_pd(_mm256_add_pd(va, _mm256_mul_pd(vb, _mm256_sub_pd(x, vx0))),
                                     _mm256_mul_pd(vc, _mm256_sub_pd(y, vy0)));
    const __m128 h = _mm_and_ps(_mm256_cvtpd_ps(_mm256_sub_pd(z, at)), abs_mask);
    const int high = _mm256_movemask_pd(_mm256_cmp_pd(_mm256_cvtps_pd(h), vdh, _CMP_GT_OQ));
    // put() of the four, packed: the lanes kept in order at the counts (room for four: the
    // arrays have room for every point of the cell).
    const __m128i kk = _mm_set1_epi32(static_cast<int32_t>(k));
    const int ground = in_ring & ~high;
    _mm_storeu_si128(
        reinterpret_cast<__m128i*>(out->ring + out->over),
        _mm_add_epi32(kk, _mm_load_si128(reinterpret_cast<const __m128i*>(kLanes.lane[in_ring]))));
    _mm_storeu_si128(
        reinterpret_cast<__m128i*>(out->ground_at + out->ground),
        _mm_add_epi32(kk, _mm_load_si128(reinterpret_cast<const __m128i*>(kLanes.lane[ground]))));
    out->over += kLanes.count[in_ring], out->ground += kLanes.count[ground];
  }
  const __m128d low2 = _mm_min_pd(_mm256_castpd256_pd128(low), _mm256_extractf128_pd(low, 1));
  const double lane_low = std::min(_mm_cvtsd_f64(low2), _mm_cvtsd_f64(_mm_unpackhi_pd(low2, low2)));
  out->stem_low = std::min(out->stem_low, lane_low);
  return k;
}
#endif

// The points of ground cell c in the ring: every one is written and the counts advance by its
// tests (branch-free: whether a point is in the ring or on the ground follows no pattern).
void gatherCell(const GroundGrid& grid, size_t c, RingTests t, BaseRing* b) {
  const uint32_t k0 = grid.start[c], k1 = grid.start[c + 1];
  b->room(k1 - k0);
  // The points' heights from their cell's plane, as heightsAboveGround computes them: no
  // gather from the height array, in point order.
  t.pl = grid.plane[c];
  grid.cellCentre(c, &t.x0, &t.y0);
  RingOut out{b->on_ground.data(), b->ring.data(), b->ground, b->over, b->stem_low};
  const GroundGrid::SortedPoint* sorted = grid.sorted.data();
  constexpr double kInf = std::numeric_limits<double>::infinity();
  uint32_t from = k0;
#if DTIF_AVX2_PATHS
  if (t.avx2) from = gatherQuads(sorted, grid.sorted.size(), k0, k1, t, &out);
#endif
  for (uint32_t k = gatherPairs(sorted, grid.sorted.size(), from, k1, t, &out); k < k1; ++k) {
    const GroundGrid::SortedPoint& q = sorted[k];
    const double dx = q.x - t.cx, dy = q.y - t.cy;
    const double d2 = dx * dx + dy * dy;
    // std::min(stem_low, z) on the stem, else no change: the chain from point to point is one
    // minimum, not a minimum and a select.
    out.stem_low = std::min(out.stem_low, d2 < t.r_stem2 ? static_cast<double>(q.z) : kInf);
    const bool in_ring = (d2 >= t.r_in2) & (d2 <= t.r_out2);  // d2 is never NaN
    const float h = static_cast<float>(q.z - t.pl.at(q.x - t.x0, q.y - t.y0));
    out.put(k, in_ring, !(std::abs(h) > t.max_dh));
  }
  b->ground = out.ground, b->over = out.over, b->stem_low = out.stem_low;
}

void gatherBaseRing(const GroundGrid& grid, double cx, double cy, double r,
                    const TrunkExtractorParams& p, BaseRing* b) {
  b->clear();
  const double r_in = r + p.base_ring_inner_m, r_out = r + p.base_ring_outer_m;
  // Lowest point on the stem itself: a base counts as seen only if the stem is visible
  // down to the ground (not hidden by shrubs or below the sensor's field of view).
  const double r_stem2 = (r + p.stem_shell_m) * (r + p.stem_shell_m);
  RingTests t{cx, cy, r_stem2, r_in * r_in, r_out * r_out, p.base_max_dh_m, {}, 0.0, 0.0, false};
  t.avx2 = useAvx2();
  int gx0, gy0, gx1, gy1;
  grid.cellOf(cx - r_out, cy - r_out, &gx0, &gy0);
  grid.cellOf(cx + r_out, cy + r_out, &gx1, &gy1);
  for (int gy = gy0; gy <= gy1; ++gy) {
    for (int gx = gx0; gx <= gx1; ++gx) {
      if (outsideRing(grid, gx, gy, cx, cy, std::max(r_out, r + p.stem_shell_m))) continue;
      gatherCell(grid, static_cast<size_t>(gy) * grid.nx + gx, t, b);
    }
  }
  b->groundPoints(grid);
}

// Removes the fit's inliers from the band (and their heights) before the next attempt.
void removeInliers(const CircleFit& fit, std::vector<Eigen::Vector2d>* band,
                   std::vector<float>* h_band) {
  size_t w = 0;
  for (size_t m = 0; m < band->size(); ++m)
    if (!fit.is_inlier[m]) (*band)[w] = (*band)[m], (*h_band)[w] = (*h_band)[m], ++w;
  band->resize(w), h_band->resize(w);
}

// Plausibility: bark is an opaque thin surface, so few points inside the circle and few in a
// thin shell around it (foliage and shrubs fill both), a smooth surface, and enough arc that
// the radius is determined (partial arcs give absurd radii). Counts rejections in *st.
// The cloud itself when every finite point lies inside b, else *kept (its points inside b).
const Cloud& keptPoints(const Cloud& cloud, const PointBounds& b, Cloud* kept, size_t* far) {
  *far = 0;
  for (const pcl::PointXYZ& q : cloud) {
    if (std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z) && !b.inside(q)) {
      *kept = pointsInside(cloud, b, far);
      return *kept;
    }
  }
  return cloud;
}

// Every stride-th point of the cloud, the footprint's ground samples when every point is finite;
// false when a sample is not finite (then they are not those samples).
bool takeFootprintSamples(const Cloud& cloud, size_t stride, std::vector<float>* sx,
                          std::vector<float>* sy, std::vector<float>* sz) {
  // Sized once and written through raw pointers: push_back on the workspace's vectors had the
  // compiler look the thread's workspace up again (__tls_get_addr) for every sample.
  const size_t n = cloud.empty() ? 0 : (cloud.size() - 1) / stride + 1;
  sx->resize(n), sy->resize(n), sz->resize(n);
  float *X = sx->data(), *Y = sy->data(), *Z = sz->data();
  const pcl::PointXYZ* P = cloud.points.data();
  for (size_t k = 0; k < n; ++k) {
    const pcl::PointXYZ& q = P[k * stride];
    if (!std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z)) return false;
    X[k] = q.x, Y[k] = q.y, Z[k] = q.z;
  }
  return true;
}

// firstPass's tests and local coordinates of one point. With SSE2 the point (x, y, z and PCL's
// padding, 16 bytes) is one register and the tests take its three lanes at once. The local
// coordinates are float differences: ox, the floor of a float, is a float, and a float
// difference rounded through double is the one rounded directly (53 >= 2 * 24 + 2), so they are
// the values toLocalPoints computes through double.
#ifdef __SSE2__
class PointLanes {
 public:
  explicit PointLanes(const pcl::PointXYZ& q) : v_(_mm_loadu_ps(q.data)) {}
  bool finite() const { return xyz(_mm_cmple_ps(abs(), _mm_set1_ps(FLT_MAX))) == 7; }  // no NaN
  bool absurd() const { return xyz(_mm_cmpgt_ps(abs(), _mm_set1_ps(1e8f))) != 0; }
  // PointBounds::inside: |x - cx| <= hs in double, x and y in two lanes.
  bool inside(const __m128d& cxy, const __m128d& cz, const __m128d& hs) const {
    const __m128d sign = _mm_set1_pd(-0.0);
    const __m128d dxy = _mm_andnot_pd(sign, _mm_sub_pd(_mm_cvtps_pd(v_), cxy));
    const __m128d dz = _mm_andnot_pd(sign, _mm_sub_pd(_mm_cvtps_pd(_mm_movehl_ps(v_, v_)), cz));
    const int in_xy = _mm_movemask_pd(_mm_cmple_pd(dxy, hs));
    const int in_z = _mm_movemask_pd(_mm_cmple_pd(dz, hs)) & 1;
    return (in_xy == 3) & (in_z == 1);
  }
  __m128 minus(const __m128& o) const { return _mm_sub_ps(v_, o); }

 private:
  static int xyz(__m128 mask) { return _mm_movemask_ps(mask) & 7; }
  __m128 abs() const { return _mm_and_ps(v_, _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff))); }
  __m128 v_;
};
#endif

#ifdef __SSE2__
// Whether four points (lanes of x, y, z) are all finite, inside b (PointLanes::inside, in
// double) and of sane magnitude (not PointLanes::absurd).
bool fourUsable(__m128 x, __m128 y, __m128 z, const __m128d& cxy, const __m128d& cz,
                const __m128d& hs) {
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const __m128 ax = _mm_and_ps(x, abs_mask), ay = _mm_and_ps(y, abs_mask),
               az = _mm_and_ps(z, abs_mask);
  const __m128 sane = _mm_set1_ps(1e8f);  // finite (no NaN, no inf) and not absurd
  if (_mm_movemask_ps(_mm_and_ps(_mm_and_ps(_mm_cmple_ps(ax, sane), _mm_cmple_ps(ay, sane)),
                                 _mm_cmple_ps(az, sane))) != 15) {
    return false;
  }
  const __m128d sign = _mm_set1_pd(-0.0);
  const __m128d cx = _mm_unpacklo_pd(cxy, cxy), cy = _mm_unpackhi_pd(cxy, cxy);
  const auto in = [&](__m128 v, const __m128d& c) {  // |v - c| <= hs, four lanes, in double
    const __m128d lo2 = _mm_andnot_pd(sign, _mm_sub_pd(_mm_cvtps_pd(v), c));
    const __m128d hi2 = _mm_andnot_pd(sign, _mm_sub_pd(_mm_cvtps_pd(_mm_movehl_ps(v, v)), c));
    return _mm_movemask_pd(_mm_cmple_pd(lo2, hs)) | _mm_movemask_pd(_mm_cmple_pd(hi2, hs)) << 2;
  };
  return (in(x, cx) & in(y, cy) & in(z, cz)) == 15;
}

float horizontalMin(__m128 v) {
  v = _mm_min_ps(v, _mm_movehl_ps(v, v));
  return _mm_cvtss_f32(_mm_min_ss(v, _mm_shuffle_ps(v, v, 1)));
}

float horizontalMax(__m128 v) {
  v = _mm_max_ps(v, _mm_movehl_ps(v, v));
  return _mm_cvtss_f32(_mm_max_ss(v, _mm_shuffle_ps(v, v, 1)));
}
#endif

#if DTIF_AVX2_PATHS
// What firstPassLoop carries through eightAtATime: its counts, marks and extent lanes.
struct EightState {
  size_t n, nf;
  HeightCellMarks::Pass marker;
  __m128 lox, loy, hix, hiy;
};

// Points P[0] and P[4] (x, y, z, padding each), one in each half.
DTIF_TARGET_AVX2 __m256 pointPair(const pcl::PointXYZ* P) {
  return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(P[0].data)),
                              _mm_loadu_ps(P[4].data), 1);
}

// The minimum (maximum) of four lanes' and of eight lanes' values, as four lanes.
DTIF_TARGET_AVX2 __m128 joinMin(__m128 a, __m256 v) {
  return _mm_min_ps(a, _mm_min_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1)));
}
DTIF_TARGET_AVX2 __m128 joinMax(__m128 a, __m256 v) {
  return _mm_max_ps(a, _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1)));
}

// Eight points (lanes of x, y, z) from P[0..7]: two 4 x 4 transposes side by side.
DTIF_TARGET_AVX2 void transpose8(const pcl::PointXYZ* P, __m256* x, __m256* y, __m256* z) {
  const __m256 r0 = pointPair(P), r1 = pointPair(P + 1), r2 = pointPair(P + 2);
  const __m256 r3 = pointPair(P + 3);
  const __m256 t0 = _mm256_unpacklo_ps(r0, r1), t1 = _mm256_unpackhi_ps(r0, r1);
  const __m256 t2 = _mm256_unpacklo_ps(r2, r3), t3 = _mm256_unpackhi_ps(r2, r3);
  *x = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
  *y = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
  *z = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
}

// fourUsable of eight points: mask of the lanes with |v - c| <= hs, in double.
DTIF_TARGET_AVX2 int insideLanes(__m256 v, __m256d c, __m256d hs) {
  const __m256d sign = _mm256_set1_pd(-0.0);
  const __m256d lo =
      _mm256_andnot_pd(sign, _mm256_sub_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(v)), c));
  const __m256d hi =
      _mm256_andnot_pd(sign, _mm256_sub_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)), c));
  return _mm256_movemask_pd(_mm256_cmp_pd(lo, hs, _CMP_LE_OQ)) |
         _mm256_movemask_pd(_mm256_cmp_pd(hi, hs, _CMP_LE_OQ)) << 4;
}

DTIF_TARGET_AVX2 bool eightUsable(__m256 x, __m256 y, __m256 z, const PointBounds& b) {
  const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  const __m256 sane = _mm256_set1_ps(1e8f);  // finite (no NaN, no inf) and not absurd
  const __m256 ok =
      _mm256_and_ps(_mm256_and_ps(_mm256_cmp_ps(_mm256_and_ps(x, abs_mask), sane, _CMP_LE_OQ),
                                  _mm256_cmp_ps(_mm256_and_ps(y, abs_mask), sane, _CMP_LE_OQ)),
                    _mm256_cmp_ps(_mm256_and_ps(z, abs_mask), sane, _CMP_LE_OQ));
  if (_mm256_movemask_ps(ok) != 255) return false;
  const __m256d hs = _mm256_set1_pd(b.half_side_m);
  return (insideLanes(x, _mm256_set1_pd(b.centre.x()), hs) &
          insideLanes(y, _mm256_set1_pd(b.centre.y()), hs) &
          insideLanes(z, _mm256_set1_pd(b.centre.z()), hs)) == 255;
}

// firstPassLoop's four-at-a-time step eight points at a time (AVX2; the caller checks
// useAvx2()) from point i on, while all eight are usable: the same local points, marks and
// extent (the lanes' minima joined in another order: the same values, as there). Returns where
// it stopped: at eight points not all usable (firstPassLoop takes them) or fewer than eight left.
DTIF_TARGET_AVX2 size_t eightAtATime(const pcl::PointXYZ* P, size_t size, size_t i,
                                     const PointBounds& b, const float origin[3], bool marking,
                                     float* X, float* Y, float* Z, EightState* st) {
  HeightCellMarks::Pass marker = st->marker;
  size_t n = st->n;
  const __m256 ox = _mm256_set1_ps(origin[0]), oy = _mm256_set1_ps(origin[1]);
  const __m256 oz = _mm256_set1_ps(origin[2]);
  constexpr float kInf = std::numeric_limits<float>::infinity();
  __m256 lox = _mm256_set1_ps(kInf), loy = lox, hix = _mm256_set1_ps(-kInf), hiy = hix;
  for (; i + 8 <= size; i += 8) {
    __m256 x, y, z;
    transpose8(P + i, &x, &y, &z);
    if (!eightUsable(x, y, z, b)) break;
    if (marking) marker.add8(x, y, z);
    const __m256 lx = _mm256_sub_ps(x, ox), ly = _mm256_sub_ps(y, oy);
    _mm256_storeu_ps(X + n, lx), _mm256_storeu_ps(Y + n, ly);
    _mm256_storeu_ps(Z + n, _mm256_sub_ps(z, oz));
    lox = _mm256_min_ps(lx, lox), loy = _mm256_min_ps(ly, loy);
    hix = _mm256_max_ps(lx, hix), hiy = _mm256_max_ps(ly, hiy);
    n += 8;
  }
  st->lox = joinMin(st->lox, lox), st->loy = joinMin(st->loy, loy);
  st->hix = joinMax(st->hix, hix), st->hiy = joinMax(st->hiy, hiy);
  st->nf += n - st->n, st->n = n, st->marker = marker;
  return i;
}
#endif

// What firstPass's loop finds: the local origin (a floor of the first usable point), the local
// points' extent and how many points it kept (n) and found finite (nf).
struct FirstPassFound {
  float ox = 0.0f, oy = 0.0f, oz = 0.0f;
  float minx = 0.0f, maxx = 0.0f, miny = 0.0f, maxy = 0.0f;
  size_t n = 0, nf = 0;
};

#ifdef __SSE2__
// firstPassLoop's state and steps. A local of firstPassLoop, all of it inlined there: through
// the members of an object in memory (or raw pointers' targets), the compiler reloads them at
// every point.
struct FirstPassSse2 {
  const pcl::PointXYZ* P;
  float *X, *Y, *Z;
  bool marking;
  HeightCellMarks::Pass marker;
  __m128d cxy, cz, hs;
  float ox = 0.0f, oy = 0.0f, oz = 0.0f;
  bool have_origin = false;
  size_t n = 0, nf = 0;
  // The extent in lanes x and y, in the order binGroundGrid would take it (one by one), and in
  // lanes of four points (four at a time), joined at the end: the same values (only the sign of
  // a zero extent may differ, which no cell index depends on).
  __m128 origin{}, lo{}, hi{}, lox{}, loy{}, hix{}, hiy{};

  // One point; false when it is finite and outside b.
  bool one(size_t i) {
    const PointLanes q(P[i]);
    if (!q.finite()) return true;
    ++nf;
    if (!q.inside(cxy, cz, hs)) return false;
    if (marking) marker.add(P[i].x, P[i].y, P[i].z);
    // As toLocalPoints: absurd magnitudes would overflow the cell indices.
    if (q.absurd()) return true;
    if (!have_origin) {
      ox = std::floor(P[i].x), oy = std::floor(P[i].y), oz = std::floor(P[i].z);
      origin = _mm_set_ps(0.0f, oz, oy, ox), have_origin = true;
    }
    const __m128 l = q.minus(origin);
    _mm_store_ss(X + n, l), _mm_store_ss(Y + n, _mm_shuffle_ps(l, l, 1));
    _mm_store_ss(Z + n, _mm_movehl_ps(l, l));
    lo = _mm_min_ps(l, lo), hi = _mm_max_ps(l, hi);  // std::min(lo, l), std::max(hi, l)
    ++n;
    return true;
  }
  // Points i..i+3 (point i + j in lane j) at once where all four are finite, inside b and of
  // sane magnitude (in survey data, every block), else one by one. false as one().
  bool four(size_t i, __m128 ox4, __m128 oy4, __m128 oz4) {
    __m128 x = _mm_loadu_ps(P[i].data), y = _mm_loadu_ps(P[i + 1].data);
    __m128 z = _mm_loadu_ps(P[i + 2].data), w = _mm_loadu_ps(P[i + 3].data);
    _MM_TRANSPOSE4_PS(x, y, z, w);
    if (!fourUsable(x, y, z, cxy, cz, hs)) return one(i) && one(i + 1) && one(i + 2) && one(i + 3);
    nf += 4;
    if (marking) marker.add4(x, y, z);
    const __m128 lx = _mm_sub_ps(x, ox4), ly = _mm_sub_ps(y, oy4);
    _mm_storeu_ps(X + n, lx), _mm_storeu_ps(Y + n, ly), _mm_storeu_ps(Z + n, _mm_sub_ps(z, oz4));
    lox = _mm_min_ps(lx, lox), loy = _mm_min_ps(ly, loy);
    hix = _mm_max_ps(lx, hix), hiy = _mm_max_ps(ly, hiy);
    n += 4;
    return true;
  }
#if DTIF_AVX2_PATHS
  // eightAtATime from point i on: returns where it stopped.
  size_t eights(size_t size, size_t i, const PointBounds& b) {
    const float o[3] = {ox, oy, oz};
    EightState st{n, nf, marker, lox, loy, hix, hiy};
    i = eightAtATime(P, size, i, b, o, marking, X, Y, Z, &st);
    n = st.n, nf = st.nf, marker = st.marker;
    lox = st.lox, loy = st.loy, hix = st.hix, hiy = st.hiy;
    return i;
  }
#endif
  void found(FirstPassFound* f) const {
    f->ox = ox, f->oy = oy, f->oz = oz, f->n = n, f->nf = nf;
    f->minx = std::min(_mm_cvtss_f32(lo), horizontalMin(lox));
    f->miny = std::min(_mm_cvtss_f32(_mm_shuffle_ps(lo, lo, 1)), horizontalMin(loy));
    f->maxx = std::max(_mm_cvtss_f32(hi), horizontalMax(hix));
    f->maxy = std::max(_mm_cvtss_f32(_mm_shuffle_ps(hi, hi, 1)), horizontalMax(hiy));
  }
};

// firstPass's loop over the cloud: the local points into X, Y, Z, each finite point marked
// (marking), the rest into *found. false when a finite point lies outside b.
bool firstPassLoop(const Cloud& cloud, const PointBounds& b, float* X, float* Y, float* Z,
                   bool marking, HeightCellMarks::Pass* marks, FirstPassFound* found) {
  const size_t size = cloud.size();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const __m128 inf = _mm_set1_ps(kInf), minus_inf = _mm_set1_ps(-kInf);
  FirstPassSse2 s{cloud.points.data(),
                  X,
                  Y,
                  Z,
                  marking,
                  *marks,
                  _mm_set_pd(b.centre.y(), b.centre.x()),
                  _mm_set1_pd(b.centre.z()),
                  _mm_set1_pd(b.half_side_m)};
  s.lo = s.lox = s.loy = inf, s.hi = s.hix = s.hiy = minus_inf;
  size_t i = 0;
  for (; i < size && !s.have_origin; ++i) {
    if (!s.one(i)) return false;
  }
  const __m128 ox4 = _mm_set1_ps(s.ox), oy4 = _mm_set1_ps(s.oy), oz4 = _mm_set1_ps(s.oz);
#if DTIF_AVX2_PATHS
  const bool avx2 = useAvx2();
#endif
  for (; i + 4 <= size; i += 4) {
#if DTIF_AVX2_PATHS
    // Eight at a time while all eight are usable; four (or one by one) where they are not.
    if (avx2 && i + 8 <= size && (i = s.eights(size, i, b)) + 4 > size) break;
#endif
    if (!s.four(i, ox4, oy4, oz4)) return false;
  }
  for (; i < size; ++i) {
    if (!s.one(i)) return false;
  }
  *marks = s.marker;
  s.found(found);
  return true;
}
#else
// firstPass's loop over the cloud, one point at a time (see the SSE2 form above).
bool firstPassLoop(const Cloud& cloud, const PointBounds& b, float* X, float* Y, float* Z,
                   bool marking, HeightCellMarks::Pass* marks, FirstPassFound* found) {
  const pcl::PointXYZ* P = cloud.points.data();
  HeightCellMarks::Pass marker = *marks;
  const double cx = b.centre.x(), cy = b.centre.y(), cz = b.centre.z(), hs = b.half_side_m;
  constexpr float kInf = std::numeric_limits<float>::infinity();
  float minx = kInf, maxx = -kInf, miny = kInf, maxy = -kInf, ox = 0.0f, oy = 0.0f, oz = 0.0f;
  bool have_origin = false;
  size_t n = 0, nf = 0;
  for (size_t i = 0; i < cloud.size(); ++i) {
    const float x = P[i].x, y = P[i].y, z = P[i].z;
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
    ++nf;
    if (!(std::abs(x - cx) <= hs && std::abs(y - cy) <= hs && std::abs(z - cz) <= hs)) return false;
    if (marking) marker.add(x, y, z);
    if (std::abs(x) > 1e8f || std::abs(y) > 1e8f || std::abs(z) > 1e8f) continue;
    if (!have_origin)
      ox = std::floor(x), oy = std::floor(y), oz = std::floor(z), have_origin = true;
    const float lx = x - ox, ly = y - oy;
    X[n] = lx, Y[n] = ly, Z[n] = z - oz;
    minx = std::min(minx, lx), maxx = std::max(maxx, lx);
    miny = std::min(miny, ly), maxy = std::max(maxy, ly);
    ++n;
  }
  *marks = marker;
  found->ox = ox, found->oy = oy, found->oz = oz, found->n = n, found->nf = nf;
  found->minx = minx, found->maxx = maxx, found->miny = miny, found->maxy = maxy;
  return true;
}
#endif

}  // namespace

bool firstPass(const Cloud& cloud, const PointBounds& b, LocalPoints* pts, HeightCellMarks* marks,
               size_t* finite) {
  const size_t size = cloud.size();
  pts->x.resize(size), pts->y.resize(size), pts->z.resize(size);
  const bool marking = marks != nullptr;
  HeightCellMarks::Pass marker = marking ? marks->pass() : HeightCellMarks::Pass();
  FirstPassFound f;
  if (!firstPassLoop(cloud, b, pts->x.data(), pts->y.data(), pts->z.data(), marking, &marker, &f))
    return false;
  if (marking) marks->finish(marker);
  if (f.n == 0) f.minx = f.maxx = f.miny = f.maxy = 0.0f;
  pts->ox = f.ox, pts->oy = f.oy, pts->oz = f.oz;
  pts->minx = f.minx, pts->maxx = f.maxx, pts->miny = f.miny, pts->maxy = f.maxy;
  pts->has_extent = f.n > 0;
  pts->x.resize(f.n), pts->y.resize(f.n), pts->z.resize(f.n);
  *finite = f.nf;
  return true;
}

namespace {

// The largest arrays of an extraction, kept per thread between submaps: reused storage needs no
// fresh pages (page faults on ~50 MB cost ~10 % of a 1 M-point extraction). Held: ~40 bytes per
// point of the largest cloud the thread has extracted.
struct Workspace {
  LocalPoints pts;
  std::vector<float> fsx, fsy, fsz;  // the footprint's ground samples
  HeightCellMarks marks;
  GroundGrid ground;
  std::vector<float> h;
  VoxelColumns cols;
  GroundMapCells map_cells;
};

// The footprint's marks ready for firstPass, or null when the footprint is made otherwise.
HeightCellMarks* footprintMarks(const Cloud& cloud, const PointBounds& b,
                                const TrunkExtractorParams& p, Workspace* ws) {
  if (!(p.footprint_cell_m > 0.0) || cloud.empty()) return nullptr;
  // The footprint samples every stride-th finite point, the stride from the finite count: here
  // the cloud's size, checked after the pass.
  const size_t fp_max = static_cast<size_t>(p.footprint_max_samples);
  const size_t stride = fp_max > 0 ? std::max<size_t>(1, cloud.size() / fp_max) : 1;
  if (!takeFootprintSamples(cloud, stride, &ws->fsx, &ws->fsy, &ws->fsz)) return nullptr;
  const Eigen::Vector2d half = Eigen::Vector2d::Constant(b.half_side_m);
  const Eigen::Vector2d centre = b.centre.head<2>();
  if (!ws->marks.init(ws->fsx, ws->fsy, ws->fsz, p.footprint_cell_m, centre - half, centre + half))
    return nullptr;
  return &ws->marks;
}

bool plausibleBark(const CircleFit& fit, const TrunkExtractorParams& p, TrunkExtractionStats* st) {
  if (fit.inlier_ratio < p.min_inlier_ratio || fit.shell_ratio < p.min_shell_ratio ||
      fit.rms_m > p.max_fit_rms_m) {
    ++st->rejected_fit;
    return false;
  }
  if (fit.arc_deg < p.min_arc_deg) {
    ++st->rejected_fit, ++st->rejected_arc;
    return false;
  }
  return true;
}

}  // namespace

std::string TrunkExtractorParams::validate() const {
  Checks c;
  checkBounds(*this, &c);
  checkGroundAndColumns(*this, &c);
  checkCircleFit(*this, &c);
  checkBaseAndOutputs(*this, &c);
  checkDensity(*this, &c);
  return c.str();
}

CircleFitParams circleFitParams(const TrunkExtractorParams& p) {
  CircleFitParams cfp;
  cfp.iterations = p.ransac_iterations;
  cfp.min_iterations = p.ransac_min_iterations;
  cfp.score_points = p.ransac_score_points;
  cfp.inlier_m = p.ransac_inlier_m;
  cfp.min_radius_m = p.min_radius_m;
  cfp.max_radius_m = p.max_radius_m;
  return cfp;
}

bool stemLeans(const std::vector<Eigen::Vector2d>& band, const std::vector<float>& h_band,
               const CircleFit& fit, const TrunkExtractorParams& p) {
  const double h_mid = 0.5 * (p.fit_min_h_m + p.fit_max_h_m);
  std::vector<Eigen::Vector2d> lo, hi;
  double h_lo = 0.0, h_hi = 0.0;
  for (size_t m = 0; m < band.size(); ++m) {
    if (planarDist(band[m].x() - fit.cx, band[m].y() - fit.cy) > fit.r + p.lean_shell_m) continue;
    const double h = h_band[m];
    if (h < h_mid)
      lo.push_back(band[m]), h_lo += h;
    else
      hi.push_back(band[m]), h_hi += h;
  }
  const size_t need = static_cast<size_t>(p.min_fit_points) / 2 + 3;
  Eigen::Vector2d c_lo(fit.cx, fit.cy), c_hi(fit.cx, fit.cy);
  if (lo.size() >= need && hi.size() >= need &&
      fitCentreFixedRadius(lo, fit.r, 2.0 * p.ransac_inlier_m, &c_lo, need) &&
      fitCentreFixedRadius(hi, fit.r, 2.0 * p.ransac_inlier_m, &c_hi, need)) {
    const double dh = h_hi / hi.size() - h_lo / lo.size();
    const double lean = std::atan2((c_hi - c_lo).norm(), std::max(dh, 1e-3));
    return lean > p.max_lean_deg * kPi / 180.0;
  }
  return false;
}

StemBase stemBase(const LocalPoints& /*pts: read through grid.sorted*/,
                  const std::vector<float>& /*h: from grid.plane, as heightsAboveGround*/,
                  const GroundGrid& grid, double cx, double cy, double r,
                  const TrunkExtractorParams& p) {
  // Robust plane through the ground points in a ring around the stem, evaluated at the
  // centre. The grid ground only gates which points count as ground. (The paper's 0.44 m z
  // error comes from a weaker base estimate, Sec. 4.B.)
  thread_local BaseRing ring_of_thread;  // kept between stems
  BaseRing& b = ring_of_thread;
  gatherBaseRing(grid, cx, cy, r, p, &b);
  StemBase base;
  int cgx, cgy;
  grid.cellOf(cx, cy, &cgx, &cgy);
  const bool ground_seen = grid.seen[static_cast<size_t>(cgy) * grid.nx + cgx];
  base.ring_seen = b.ground >= static_cast<size_t>(p.min_base_points);
  bool ground_below = false;
  if (base.ring_seen) {
    thread_local std::vector<double> w_of_thread;
    std::vector<double>& w = w_of_thread;
    if (w.size() < b.ground) w.assign(b.ground, 1.0);  // only ever ones
    // Tighter than the grid's: litter and grass sit on the ground surface, noise is cm.
    const GroundPlane pl =
        fitGroundPlane(b.bx.data(), b.by.data(), b.bz.data(), w.data(), b.ground, cx, cy,
                       p.base_plane_c_up_m, p.base_plane_c_down_m, /*iterations=*/6);
    base.z = pl.a;
    // Ground is the lowest surface: returns well below the fitted plane around the stem
    // mean the plane lies on a shrub or log and the real base is lower. In the dense_slope
    // scene this flags 26 of the 66 seen bases that are 0.45-1.6 m too high, and 9 of the
    // 673 good ones.
    int below = 0;
    for (size_t m = 0; m < b.over; ++m) {
      const GroundGrid::SortedPoint& q = grid.sorted[b.ring[m]];
      below += q.z < pl.at(q.x - cx, q.y - cy) - p.base_below_m;
    }
    ground_below = below > p.max_base_below_points;
  } else {
    base.z = grid.groundAt(cx, cy);
  }
  base.seen = ground_seen && base.ring_seen && !ground_below &&
              b.stem_low - base.z < p.base_max_gap_m && base.z - b.stem_low < p.base_max_gap_m;
  return base;
}

void fitCandidate(const LocalPoints& pts, const std::vector<float>& h, const GroundGrid& grid,
                  const TrunkCandidates& cand, int l, const TrunkExtractorParams& p,
                  std::vector<FoundTrunk>* found, TrunkExtractionStats* st) {
  // The candidate's points in the fit band, in candidate order. Branch-free (every point
  // written, the count advanced by the test): a point's height follows no pattern.
  thread_local std::vector<Eigen::Vector2d> band_of_thread;  // kept between candidates
  thread_local std::vector<float> h_band_of_thread;
  std::vector<Eigen::Vector2d>& band = band_of_thread;
  std::vector<float>& h_band = h_band_of_thread;
  const uint32_t* idx = cand.points.data() + cand.start[l];
  const size_t np = cand.start[l + 1] - cand.start[l];
  band.resize(np), h_band.resize(np);
  Eigen::Vector2d* bp = band.data();
  float* hp = h_band.data();
  const double lo = p.fit_min_h_m, hi = p.fit_max_h_m;
  size_t nb = 0;
  for (size_t k = 0; k < np; ++k) {
    prefetchGather(h.data(), idx, k, np), prefetchGather(pts.x.data(), idx, k, np);
    prefetchGather(pts.y.data(), idx, k, np);
    const uint32_t i = idx[k];
    const float hk = h[i];
    bp[nb] = Eigen::Vector2d(pts.x[i], pts.y[i]);
    hp[nb] = hk;
    nb += (hk >= lo) & (hk <= hi);
  }
  band.resize(nb), h_band.resize(nb);
  CircleFitParams cfp = circleFitParams(p);
  for (int attempt = 0; attempt < p.max_fits_per_candidate; ++attempt) {
    if (band.size() < static_cast<size_t>(p.min_fit_points)) break;
    cfp.seed = 0x9e3779b9u ^ static_cast<uint32_t>(l * 131 + attempt);
    const CircleFit fit = fitCircleRobust(band, cfp);
    if (!fit.ok || fit.inliers < static_cast<size_t>(p.min_fit_points)) {
      ++st->rejected_fit;
      break;
    }
#ifdef DTIF_EXTRACT_DEBUG
    fprintf(stderr, "FIT %.2f %.2f r %.3f inl %zu ratio %.2f arc %.0f rms %.4f band %zu\n",
            fit.cx + pts.ox, fit.cy + pts.oy, fit.r, fit.inliers, fit.inlier_ratio, fit.arc_deg,
            fit.rms_m, band.size());
    fprintf(stderr, "  shell %.2f\n", fit.shell_ratio);
#endif
    const bool bark = plausibleBark(fit, p, st);
    const bool leaning = bark && stemLeans(band, h_band, fit, p);
    if (leaning) ++st->rejected_lean;
    if (bark && !leaning) {
      const StemBase base = stemBase(pts, h, grid, fit.cx, fit.cy, fit.r, p);
      if (!base.ring_seen) ++st->ground_fallbacks;
      if (!base.seen) ++st->unseen_bases;
#ifdef DTIF_EXTRACT_DEBUG
      fprintf(stderr, "ACC %.2f %.2f r %.3f inl %zu ratio %.2f arc %.0f rms %.4f band %zu\n",
              fit.cx + pts.ox, fit.cy + pts.oy, fit.r, fit.inliers, fit.inlier_ratio, fit.arc_deg,
              fit.rms_m, band.size());
#endif
      FoundTrunk f;
      f.trunk.x = fit.cx + pts.ox;
      f.trunk.y = fit.cy + pts.oy;
      f.trunk.z = base.z + pts.oz;
      f.trunk.r = fit.r;
      f.trunk.base_seen = base.seen;
      f.inliers = fit.inliers;
      f.arc_deg = fit.arc_deg;
      found->push_back(f);
    }
    removeInliers(fit, &band, &h_band);
  }
}

Trunks keepDistinctTrunks(std::vector<FoundTrunk> found, const TrunkExtractorParams& p,
                          TrunkExtractionStats* st) {
  Trunks trunks;
  std::stable_sort(found.begin(), found.end(),
                   [](const FoundTrunk& a, const FoundTrunk& b) { return a.inliers > b.inliers; });
  for (const FoundTrunk& f : found) {
    bool dup = false;
    for (const TrunkLandmark& k : trunks) {
      const double d = planarDist(f.trunk.x - k.x, f.trunk.y - k.y);
      if (d < p.min_trunk_separation_m || d < f.trunk.r + k.r) {
        dup = true;
        break;
      }
    }
    if (dup)
      ++st->duplicates;
    else
      trunks.push_back(f.trunk);
  }
  std::sort(trunks.begin(), trunks.end(), [](const TrunkLandmark& a, const TrunkLandmark& b) {
    return a.x != b.x ? a.x < b.x : a.y < b.y;
  });
  return trunks;
}

namespace {

// The ground map's box: the trunks' box plus ground_map_margin_m (trunks not empty). Only
// around the trunks: loops align trunks, so only there can two maps overlap.
void groundMapBox(const Trunks& trunks, const TrunkExtractorParams& p, Eigen::Vector2d* lo,
                  Eigen::Vector2d* hi) {
  *lo = Eigen::Vector2d(trunks[0].x, trunks[0].y), *hi = *lo;
  for (const TrunkLandmark& t : trunks) {
    *lo = lo->cwiseMin(Eigen::Vector2d(t.x, t.y));
    *hi = hi->cwiseMax(Eigen::Vector2d(t.x, t.y));
  }
  const Eigen::Vector2d margin = Eigen::Vector2d::Constant(p.ground_map_margin_m);
  *lo -= margin, *hi += margin;
}

// groundMapIfFewBasesSeen of an extraction: from the cells gathered in the heights pass when
// there are (the same map without a pass over the points).
GroundMap groundMapOfExtraction(const Trunks& trunks, const LocalPoints& pts,
                                const GroundGrid& ground, const GroundMapCells& cells,
                                const TrunkExtractorParams& p) {
  if (!fewBasesSeen(trunks, p)) return GroundMap();
  Eigen::Vector2d lo, hi;
  groundMapBox(trunks, p, &lo, &hi);
  GroundMap m;
  if (groundMapOfCells(cells, ground, lo, hi, p, &m)) return m;
  return groundMapIfFewBasesSeen(trunks, pts, p);
}

}  // namespace

GroundMap groundMapAroundTrunks(const Trunks& trunks, const float* x, const float* y,
                                const float* z, size_t n, const Eigen::Vector3d& origin,
                                const TrunkExtractorParams& p) {
  if (!(p.ground_map_cell_m > 0.0) || trunks.empty()) return GroundMap();
  Eigen::Vector2d lo, hi;
  groundMapBox(trunks, p, &lo, &hi);
  return makeGroundMap(x, y, z, n, origin, lo, hi, p.ground_map_cell_m, p.ground_map_z_step_m,
                       static_cast<uint32_t>(p.ground_map_min_points));
}

bool fewBasesSeen(const Trunks& trunks, const TrunkExtractorParams& p) {
  const size_t seen = static_cast<size_t>(std::count_if(
      trunks.begin(), trunks.end(), [](const TrunkLandmark& t) { return t.base_seen; }));
  return p.ground_map_cell_m > 0.0 && !trunks.empty() &&
         static_cast<double>(seen) < p.ground_map_below_seen * trunks.size();
}

GroundMap groundMapIfFewBasesSeen(const Trunks& trunks, const LocalPoints& pts,
                                  const TrunkExtractorParams& p) {
  if (!fewBasesSeen(trunks, p)) return GroundMap();
  return groundMapAroundTrunks(trunks, pts.x.data(), pts.y.data(), pts.z.data(), pts.size(),
                               Eigen::Vector3d(pts.ox, pts.oy, pts.oz), p);
}

namespace {

// Slab columns, candidates and their circle fits: the trunks found (before duplicates are
// dropped) into *found. false when there is no candidate.
bool findTrunks(const LocalPoints& pts, const std::vector<float>& h, const GroundGrid& ground,
                const TrunkExtractorParams& p, VoxelColumns* cols, std::vector<FoundTrunk>* found,
                TrunkExtractionStats* st) {
  columnsOfSlab(pts, h, p, cols);  // the slab from heightsAndSlab
  if (cols->slab.empty()) return false;
  st->candidate_columns = cols->passing;
  const TrunkCandidates cand = clusterColumns(*cols, p);
  st->candidates = static_cast<size_t>(cand.count);
  if (cand.count == 0) return false;
  for (int l = 0; l < cand.count; ++l) fitCandidate(pts, h, ground, cand, l, p, found, st);
  return true;
}

}  // namespace

TrunkExtractionResult extractTrunks(const Cloud& cloud, const TrunkExtractorParams& p,
                                    const GroundMapWanted& wanted) {
  TrunkExtractionResult result;
  TrunkExtractionStats& st = result.stats;
  st.input_points = cloud.size();
  if (!p.validate().empty()) return result;
  if (cloud.size() > static_cast<size_t>(p.max_points)) {
    st.over_point_limit = true;
    return result;
  }
  // Points beyond what the sensor sees are dropped before any grid is sized; survey data
  // keeps every point and takes no copy, and one pass makes the local points and the footprint.
  const PointBounds bounds = pointBounds(cloud, p.max_range_m);
  thread_local Workspace ws_of_thread;
  Workspace& ws = ws_of_thread;
  HeightCellMarks* marks = footprintMarks(cloud, bounds, p, &ws);
  Cloud kept;
  LocalPoints& pts = ws.pts;
  size_t finite = 0;
  const bool all_inside = firstPass(cloud, bounds, &pts, marks, &finite);
  if (!all_inside) pts = toLocalPoints(keptPoints(cloud, bounds, &kept, &st.far_points));
  const Cloud& in = all_inside ? cloud : kept;
  st.finite_points = pts.size() + st.far_points;
  if (pts.size() < static_cast<size_t>(p.min_fit_points)) return result;

  const GroundGrid& ground = ws.ground;
  estimateLocalGround(pts, p, &ws.ground);
  const std::vector<float>& h = ws.h;
  // The ground map's cells in the same pass, when a map may be built.
  if (p.ground_map_cell_m > 0.0 && p.ground_map_below_seen > 0.0 &&
      ws.map_cells.init(pts, p.ground_map_cell_m,
                        bounds.centre.z() + bounds.half_side_m + 1.0)) {  // no z above
    heightsAndSlab(pts, ground, p, &ws.h, &ws.cols.slab, &ws.map_cells);
  } else {
    ws.map_cells.used = false;
    heightsAndSlab(pts, ground, p, &ws.h, &ws.cols.slab);
  }
  // DATASET.md's overlap cells, so verification measures an aligned pair's overlap as the
  // protocol does.
  result.footprint = all_inside && marks && finite == cloud.size() && marks->complete()
                         ? makeFootprint(marks->cells(), p.footprint_cell_m)
                         : trunkFootprint(in, p);

  std::vector<FoundTrunk> found;
  if (!findTrunks(pts, h, ground, p, &ws.cols, &found, &st)) return result;
  // A sparse cloud (every n-th return, a slower sensor): the count thresholds scaled to its
  // density, all stages after the ground again. Clouds at the reference density or denser
  // take the first pass as it is.
  st.density = barkDensity(found, p);
  st.density_scale = densityScale(st.density, p);
  const TrunkExtractorParams q = scaledForDensity(p, st.density_scale);
  if (st.density_scale < 1.0) {
    const TrunkExtractionStats first = st;
    st = TrunkExtractionStats();
    st.input_points = first.input_points, st.finite_points = first.finite_points;
    st.far_points = first.far_points;
    st.density = first.density, st.density_scale = first.density_scale;
    found.clear();
    if (!findTrunks(pts, h, ground, q, &ws.cols, &found, &st)) return result;
  }
  result.trunks = keepDistinctTrunks(std::move(found), q, &st);
  // When too few stem bases were seen to fix a loop's elevation (steep slopes seen from a
  // helmet), the lowest surface of the whole submap has to.
  // A map the caller would drop (its byte budget) is not built: a pass over every point.
  if (fewBasesSeen(result.trunks, q) && (!wanted || wanted(result)))
    result.ground_map = groundMapOfExtraction(result.trunks, pts, ground, ws.map_cells, q);
  return result;
}

}  // namespace dtif
