// The stages of trunk extraction (paper Sec. 3.B), each usable and testable on its own.
// extractTrunks (trunk_extractor.h) runs them in this order:
//   toLocalPoints (firstPass) -> estimateLocalGround -> heightsAboveGround with the slab and the
//   ground map's cells (heightsAndSlab, GroundMapCells) -> (trunkFootprint) -> slabColumns
//   (columnsOfSlab) -> clusterColumns -> fitCandidate per candidate (fitCircleRobust,
//   stemLeans, stemBase) -> keepDistinctTrunks -> the ground map when fewBasesSeen and the
//   caller wants it (groundMapOfCells, else groundMapIfFewBasesSeen).
//
// Frames: the input cloud is gravity-aligned in the submap frame S. "Local" coordinates are S
// minus LocalPoints' origin, so float storage keeps cm precision with UTM-sized coordinates.
// Heights are above the local ground; every length is in metres.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/extraction/footprint.h"
#include "dtif/core/extraction/ground_map.h"
#include "dtif/core/extraction/point_bounds.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/types.h"

namespace dtif {

/// floor(v) as an int64, the value static_cast<int64_t>(std::floor(v)) has wherever that is
/// defined, without libm's call (not inlined on baseline x86-64; several run per point).
inline int64_t floorIndex(double v) {
  if (!(v > -4.5e15 && v < 4.5e15)) return static_cast<int64_t>(std::floor(v));
  const int64_t i = static_cast<int64_t>(v);  // truncates towards zero
  return i - (v < static_cast<double>(i));
}

/// x / d for many x: a multiplication by 1 / d when d is a power of two, where it gives the same
/// quotient (both round the same exact value), a division otherwise.
class Divisor {
 public:
  explicit Divisor(double d) : d_(d) {
    int e = 0;
    pow2_ = std::isfinite(d) && std::frexp(std::abs(d), &e) == 0.5 && e > -1000 && e < 1000;
    inv_ = pow2_ ? 1.0 / d : 0.0;
  }
  double operator()(double x) const { return pow2_ ? x * inv_ : x / d_; }
  /// Whether operator() multiplies (by factor()) rather than divides (by factor()).
  bool multiplies() const { return pow2_; }
  double factor() const { return pow2_ ? inv_ : d_; }

 private:
  double d_, inv_;
  bool pow2_;
};

/// Asks for a[i + ahead] (at most the last of its n elements) before a pass over a reaches it;
/// changes no value. The passes over the points stall where the hardware prefetcher stops (at
/// page boundaries); about 1 KB ahead keeps them streaming.
template <class T>
inline void prefetchAhead(const T* a, size_t i, size_t n) {
  constexpr size_t ahead = 1024 / sizeof(T);
  __builtin_prefetch(a + std::min(i + ahead, n - 1));
}

/// Asks for a[index[k + ahead]] (at most index's last) before a gather through index reaches it.
template <class T>
inline void prefetchGather(const T* a, const uint32_t* index, size_t k, size_t n) {
  constexpr size_t ahead = 16;
  __builtin_prefetch(a + index[std::min(k + ahead, n - 1)]);
}

/// Horizontal distance of an offset: std::hypot is exact but slow, and the local coordinates
/// here are small and well scaled [m].
inline double planarDist(double dx, double dy) { return std::sqrt(dx * dx + dy * dy); }

// --- Points ---------------------------------------------------------------------------------

struct GroundMapCells;  // below

/// The finite points of a cloud, relative to a local origin.
struct LocalPoints {
  double ox = 0.0, oy = 0.0, oz = 0.0;  ///< origin in S: floor of the first kept point [m]
  std::vector<float> x, y, z;           ///< local coordinates (S minus origin) [m]
  /// Horizontal extent of x and y, when a pass that made them noted it (has_extent) [m].
  float minx = 0.0f, maxx = 0.0f, miny = 0.0f, maxy = 0.0f;
  bool has_extent = false;
  size_t size() const { return x.size(); }
};

/// Keeps the finite points with coordinates below 1e8 m (larger ones would overflow the cell
/// indices; they are no survey points), relative to the floor of the first kept point.
LocalPoints toLocalPoints(const Cloud& cloud);
/// toLocalPoints of a cloud whose finite points all lie inside b (with the points' extent), and
/// (marks not null) each finite point added to the footprint's marks, in one pass over the
/// cloud, the largest array extraction reads. *finite counts the finite points. false when a
/// finite point lies outside b (then nothing is usable).
bool firstPass(const Cloud& cloud, const PointBounds& b, LocalPoints* pts, HeightCellMarks* marks,
               size_t* finite);

// --- Local ground ---------------------------------------------------------------------------

/// Plane z = a + b dx + c dy about the point (x0, y0) it was fitted about.
struct GroundPlane {
  double a = 0.0, b = 0.0, c = 0.0;  ///< height at (x0, y0) [m], slopes along x and y [m/m]
  /// Height at an offset (dx, dy) from the point the plane was fitted about [m].
  double at(double dx, double dy) const { return a + b * dx + c * dy; }
};

/// Robust plane through the weighted points (x, y, z, w0) about (x0, y0) by IRLS. Asymmetric
/// Tukey weights: residuals above the plane use c_up, below c_down [m] (points far above are
/// clutter, points slightly below are ground noise). Slopes are mildly ridge-regularised so a
/// collinear support (a narrow path) stays defined. `iterations` reweightings after the first
/// solve; a degenerate system leaves the last good plane (initially 0). Every coordinate finite
/// (a point of weight 0 still enters the sums, as +0 terms).
GroundPlane fitGroundPlane(const double* x, const double* y, const double* z, const double* w0,
                           size_t n, double x0, double y0, double c_up, double c_down,
                           int iterations);

/// Local ground as a dense horizontal grid over the points' extent, in local coordinates.
struct GroundGrid {
  float minx = 0.0f, miny = 0.0f;  ///< local corner of cell (0, 0) [m]
  double cell_m = 0.0;             ///< ground_cell_m, larger when the extent would need more than
                                   ///< max_ground_cells cells (far outliers) [m]
  int nx = 0, ny = 0;              ///< columns and rows
  /// A point in cell order: its local coordinates [m]. Those who need its height compute it
  /// from its cell's plane (no index back into the local points: this is bound by memory).
  struct SortedPoint {
    float x, y, z;
  };
  std::vector<uint32_t> start;  ///< points of cell c: sorted[start[c]] .. sorted[start[c+1]-1]
  /// The points sorted by cell, stable: the per-cell stages read these in sequence instead of
  /// gathering from all over the cloud, one 12-byte record each (the sort writes one cache line
  /// per point, not three).
  std::vector<SortedPoint> sorted;
  std::vector<GroundPlane> plane;  ///< per cell, about the cell centre, local z [m]
  std::vector<char> seen;          ///< the cell's window held enough ground cells: ground observed

  size_t cells() const { return static_cast<size_t>(nx) * static_cast<size_t>(ny); }
  /// Cell holding the local point (x, y), clamped to the grid. Inline: called per point.
  void cellOf(double x, double y, int* gx, int* gy) const {
    *gx = std::clamp(static_cast<int>(std::floor((x - minx) / cell_m)), 0, nx - 1);
    *gy = std::clamp(static_cast<int>(std::floor((y - miny) / cell_m)), 0, ny - 1);
  }
  /// Local centre of cell c, about which its plane is fitted [m].
  void cellCentre(size_t c, double* x0, double* y0) const {
    *x0 = minx + (static_cast<double>(c % static_cast<size_t>(nx)) + 0.5) * cell_m;
    *y0 = miny + (static_cast<double>(c / static_cast<size_t>(nx)) + 0.5) * cell_m;
  }
  /// Height of the local ground under the local point (x, y): its cell's plane [m].
  double groundAt(double x, double y) const;
};

/// Ground evidence per grid cell, before the planes.
struct GroundCells {
  std::vector<float> low;       ///< low percentile of the cell's open ground points; NaN: none [m]
  std::vector<uint32_t> count;  ///< ground points of the cell; 0: no ground cell
  std::vector<char> any;        ///< the cell holds any point
  std::vector<float> min;       ///< lowest point of the cell; +inf when empty [m]
};

/// The grid's geometry and the counting sort of the points by cell (planes not yet fitted).
/// Needs at least one point.
GroundGrid binGroundGrid(const LocalPoints& pts, const TrunkExtractorParams& p);
/// The same into *grid, reusing its arrays' storage (extraction keeps them between submaps).
void binGroundGrid(const LocalPoints& pts, const TrunkExtractorParams& p, GroundGrid* grid);

/// Ground points per cell: the points of "open" sub-columns (ground_sub_cell_m), those with
/// nothing between ground_open_gap_m and ground_open_top_m above their lowest point, within
/// ground_band_m of it. A cell is a ground cell when at least ground_min_open_fraction of its
/// sub-columns are open and 3 points qualify; its value is their ground_percentile.
GroundCells openGroundCells(const LocalPoints& pts, const GroundGrid& grid,
                            const TrunkExtractorParams& p);

/// Ground lies below everything: a ground cell higher than ground_max_step * cell_m above the
/// lowest point of a neighbouring cell (a branch or log top above unseen ground) is dropped.
void dropRaisedGroundCells(const GroundGrid& grid, const TrunkExtractorParams& p,
                           GroundCells* cells);

/// A robust plane per occupied cell through the ground cells of the ground_window_m window;
/// with fewer than ground_min_cells there, a three times wider window, and the cell counts as
/// not seen (Tukey constants ground_plane_c_up_m / _down_m). No ground cell anywhere near: a
/// flat plane at the cell's lowest point.
void fitLocalGroundPlanes(const GroundCells& cells, const TrunkExtractorParams& p,
                          GroundGrid* grid);

/// The local ground (Zhang et al.; no ground segmentation): the four steps above.
GroundGrid estimateLocalGround(const LocalPoints& pts, const TrunkExtractorParams& p);
/// The same into *grid, reusing its arrays' storage.
void estimateLocalGround(const LocalPoints& pts, const TrunkExtractorParams& p, GroundGrid* grid);

/// Height of every point above its cell's ground plane [m].
std::vector<float> heightsAboveGround(const LocalPoints& pts, const GroundGrid& grid);
/// The same into *h, reusing its storage.
void heightsAboveGround(const LocalPoints& pts, const GroundGrid& grid, std::vector<float>* h);
/// The same, and in that pass the indices of the points in the trunk slab [slab_min_h_m,
/// slab_max_h_m), in point order: slabColumns' slab (columnsOfSlab takes it from there).
void heightsAndSlab(const LocalPoints& pts, const GroundGrid& grid, const TrunkExtractorParams& p,
                    std::vector<float>* h, std::vector<uint32_t>* slab);
/// The same, and every point added to *map_cells (initialised; not null).
void heightsAndSlab(const LocalPoints& pts, const GroundGrid& grid, const TrunkExtractorParams& p,
                    std::vector<float>* h, std::vector<uint32_t>* slab, GroundMapCells* map_cells);

/// The ground map's cells (cells of S, side cell_m) over all the local points: the lowest point
/// and the point count of each, gathered in the heights pass, which reads every point anyway, so
/// that the map around the trunks (groundMapOfCells) reads only the points of its box's edge.
struct GroundMapCells {
  bool used = false;                              ///< init succeeded, every point fell inside
  double cell_m = 0.0;                            ///< ground_map_cell_m [m]
  double ox = 0.0, oy = 0.0, oz = 0.0;            ///< the local points' origin in S [m]
  int64_t x0 = 0, y0 = 0, width = 0, height = 0;  ///< first cell (index in S), cells per side
  std::vector<float> low;      ///< lowest local z per cell (row-major); +inf: no point [m]
  std::vector<uint32_t> hits;  ///< points per cell
  double max_z = 0.0;          ///< no point lies higher (S) [m]

  /// Sized over the points' extent, all empty; max_z_bound: a height no point exceeds (S).
  /// false (used stays false) without points, with cell_m 0, or beyond 4e6 cells.
  bool init(const LocalPoints& pts, double cell_m, double max_z_bound);
  /// Index of the cell of the local point (x, y), computed as makeGroundMap computes it; npos
  /// outside (cannot happen: the extent bounds every point). Inline: per point.
  size_t cellOf(float x, float y) const {
    const int64_t ix = floorIndex(by_cell_(x + ox)) - x0;
    const int64_t iy = floorIndex(by_cell_(y + oy)) - y0;
    if (ix < 0 || iy < 0 || ix >= width || iy >= height) return npos;
    return static_cast<size_t>(iy * width + ix);
  }
  /// Adds `hits` points of cell k (cellOf) whose lowest local z is `lowest`.
  void addRun(size_t k, float lowest, uint32_t count) {
    if (count == 0) return;
    if (k == npos) {
      used = false;
      return;
    }
    low[k] = std::min(low[k], lowest);
    hits[k] += count;
  }
  static constexpr size_t npos = ~size_t{0};
  /// x / cell_m as cellOf computes it.
  const Divisor& byCell() const { return by_cell_; }
  /// The cell size, origin and extent of `other`, not its cells (cellOf works on those alone).
  void copyGeometry(const GroundMapCells& other) {
    cell_m = other.cell_m, ox = other.ox, oy = other.oy, oz = other.oz;
    x0 = other.x0, y0 = other.y0, width = other.width, height = other.height;
    by_cell_ = other.by_cell_;
  }

 private:
  Divisor by_cell_{1.0};
};

/// DATASET.md's overlap cells of the cloud in S as a footprint of footprint_cell_m cells, the
/// ground percentiles on at most footprint_max_samples points. Empty when footprint_cell_m is 0.
Footprint trunkFootprint(const Cloud& cloud, const TrunkExtractorParams& p);

// --- Voxel columns and candidates -----------------------------------------------------------

/// Minimal open-addressing hash map from a 64-bit cell key to a dense index.
class CellHash {
 public:
  explicit CellHash(size_t expected = 0);
  /// Returns the index for key, inserting next_index when absent.
  int findOrInsert(uint64_t key, int next_index, bool* inserted);
  /// Index for key, -1 when absent.
  int find(uint64_t key) const;

 private:
  static constexpr uint64_t kEmpty = ~uint64_t{0};
  static size_t hash(uint64_t k);
  std::vector<uint64_t> keys_;
  std::vector<int> vals_;
  size_t mask_ = 0;
};

/// Key of the cell (ix, iy), both within +-2^31.
inline uint64_t cellKey(int64_t ix, int64_t iy) {
  return (static_cast<uint64_t>(ix + (int64_t{1} << 31)) << 32) |
         static_cast<uint64_t>(iy + (int64_t{1} << 31));
}

/// Voxel columns (column_cell_m wide, layer_h_m layers) of the points in the trunk slab
/// [slab_min_h_m, slab_max_h_m) above the ground.
struct VoxelColumns {
  std::vector<uint32_t> slab;   ///< indices of the slab points
  std::vector<int> slab_col;    ///< column of each slab point
  std::vector<int64_t> ix, iy;  ///< column cell (floor of local x, y / column_cell_m)
  std::vector<uint32_t> count;  ///< slab points per column
  std::vector<uint64_t> mask;   ///< bit l: layer l of the slab holds a point
  std::vector<char> pass;       ///< dense (min_column_points) and continuous (min_continuity)
  size_t passing = 0;           ///< columns that pass
  /// Column of each cell: a dense grid over the slab's cells (gx0, gy0: its first cell; gw x gh
  /// cells; -1: no column) unless that would be large for the slab, else a hash.
  std::vector<int> grid;
  int64_t gx0 = 0, gy0 = 0, gw = 0, gh = 0;
  CellHash index;  ///< cellKey(ix, iy) -> column, when grid is empty

  size_t size() const { return ix.size(); }
  /// Column of cell (ix, iy); -1 when it holds none.
  int find(int64_t cx, int64_t cy) const {
    if (grid.empty()) return index.find(cellKey(cx, cy));
    if (cx < gx0 || cy < gy0 || cx >= gx0 + gw || cy >= gy0 + gh) return -1;
    return grid[static_cast<size_t>((cy - gy0) * gw + (cx - gx0))];
  }
};

/// The slab's voxel columns and which of them pass density and vertical continuity (paper:
/// "high-density voxel columns with sufficient vertical continuity"). No slab point: no column.
VoxelColumns slabColumns(const LocalPoints& pts, const std::vector<float>& h,
                         const TrunkExtractorParams& p);
/// The same into *cols, reusing its arrays' storage.
void slabColumns(const LocalPoints& pts, const std::vector<float>& h, const TrunkExtractorParams& p,
                 VoxelColumns* cols);
/// slabColumns of the slab already in cols->slab (heightsAndSlab's): the rest of *cols anew.
void columnsOfSlab(const LocalPoints& pts, const std::vector<float>& h,
                   const TrunkExtractorParams& p, VoxelColumns* cols);

/// Slab points grouped by trunk candidate.
struct TrunkCandidates {
  int count = 0;                 ///< candidates
  std::vector<uint32_t> start;   ///< candidate l: points[start[l]] .. points[start[l+1]-1]
  std::vector<uint32_t> points;  ///< point indices, by candidate
};

/// Passing columns within cluster_gap_m of each other are one candidate (connected
/// components); failing columns touching a candidate join it, so bark columns at the edge of a
/// stem still feed the circle fit. Candidates are numbered by their first column.
TrunkCandidates clusterColumns(const VoxelColumns& cols, const TrunkExtractorParams& p);

// --- Per candidate: circle, lean, stem base --------------------------------------------------

/// The circle-fit settings of the extractor's parameters (seed left at its default).
CircleFitParams circleFitParams(const TrunkExtractorParams& p);

/// Robust centre of a circle of known radius r (Tukey-weighted Gauss-Newton, Tukey constant
/// c_tukey [m], from the start centre *c); false when fewer than min_support points support it.
bool fitCentreFixedRadius(const std::vector<Eigen::Vector2d>& xy, double r, double c_tukey,
                          Eigen::Vector2d* c, size_t min_support);

/// Leaning clutter (fallen or hung-up stems; paper: "outlier removal"): centres of the lower
/// and upper half of the fit band, radius held at the fit's, from the band points (local, with
/// heights h_band) within fit.r + lean_shell_m of the centre only, tilt more than max_lean_deg.
/// false when either half has too few points to tell.
bool stemLeans(const std::vector<Eigen::Vector2d>& band, const std::vector<float>& h_band,
               const CircleFit& fit, const TrunkExtractorParams& p);

/// Stem base of a fitted stem (local centre cx, cy, radius r).
struct StemBase {
  double z = 0.0;          ///< base elevation, local [m]
  bool ring_seen = false;  ///< min_base_points ground points in the ring; else z is the grid's
  bool seen = false;       ///< base observed: ground seen, stem visible down to it, not on a
                           ///< shrub or log (TrunkLandmark::base_seen)
};

/// Stem base z_m: robust plane (Tukey constants base_plane_c_up_m / _down_m) through the ground
/// points (|h| <= base_max_dh_m) of the ring [r + base_ring_inner_m, r + base_ring_outer_m]
/// around the stem, at the centre; the grid ground when the ring holds too few. Seen when the
/// grid cell's ground was seen, the ring held enough ground, at most max_base_below_points ring
/// points lie base_below_m below the plane, and the stem's lowest point (within stem_shell_m of
/// the circle) is within base_max_gap_m.
StemBase stemBase(const LocalPoints& pts, const std::vector<float>& h, const GroundGrid& grid,
                  double cx, double cy, double r, const TrunkExtractorParams& p);

/// A trunk found in a candidate and the support of its fit.
struct FoundTrunk {
  TrunkLandmark trunk;   ///< in S
  size_t inliers = 0;    ///< circle inliers
  double arc_deg = 0.0;  ///< angular coverage of the inliers [deg]
};

/// Fits up to max_fits_per_candidate circles in the breast-height band [fit_min_h_m,
/// fit_max_h_m] of candidate l (close stems or undergrowth can merge columns), each attempt on
/// the band points the previous circles left. Plausible, upright circles are appended to
/// *found with their stem base, in S; *stats counts the rejections.
void fitCandidate(const LocalPoints& pts, const std::vector<float>& h, const GroundGrid& grid,
                  const TrunkCandidates& cand, int l, const TrunkExtractorParams& p,
                  std::vector<FoundTrunk>* found, TrunkExtractionStats* stats);

// --- Density ---------------------------------------------------------------------------------

/// Bark density of the fitted trunks: the median over those at least density_min_range_m from
/// the origin of S (the sensor at the anchor time) of inliers / (bark seen in the fit band:
/// arc x radius x band height) x (range / 10 m)^2, the sensor's angular density as points per
/// m^2 of bark 10 m away. 0 when fewer than density_min_trunks trunks qualify.
double barkDensity(const std::vector<FoundTrunk>& found, const TrunkExtractorParams& p);

/// Factor on the point-count thresholds for a measured density: density / density_reference,
/// clamped to [density_min_scale, 1]; 1 when adaptation is off or nothing was measured.
double densityScale(double density, const TrunkExtractorParams& p);

/// The parameters with the trunk-detection point counts (min_column_points, min_fit_points)
/// scaled by `scale` (rounded; at least 2 and 5, or the count itself if lower); the same
/// parameters for scale 1.
TrunkExtractorParams scaledForDensity(const TrunkExtractorParams& p, double scale);

// --- Result ---------------------------------------------------------------------------------

/// Two stems cannot overlap: the better supported of two trunks closer than
/// min_trunk_separation_m or their radii sum is kept (stats->duplicates counts the others).
/// Sorted by x, then y: an order independent of the candidate numbering.
Trunks keepDistinctTrunks(std::vector<FoundTrunk> found, const TrunkExtractorParams& p,
                          TrunkExtractionStats* stats);

/// The lowest surface of the points (x, y, z) + origin around the trunks (their box plus
/// ground_map_margin_m); empty without trunks or with ground_map_cell_m 0.
GroundMap groundMapAroundTrunks(const Trunks& trunks, const float* x, const float* y,
                                const float* z, size_t n, const Eigen::Vector3d& origin,
                                const TrunkExtractorParams& p);

/// Whether extraction builds a ground map for these trunks: ground_map_cell_m > 0, trunks, and
/// fewer than ground_map_below_seen of them with a seen base.
bool fewBasesSeen(const Trunks& trunks, const TrunkExtractorParams& p);

/// makeGroundMap of the local points over the box lo..hi of S (ground_map_cell_m,
/// ground_map_z_step_m, ground_map_min_points), the same map, from the cells gathered in
/// `cells` and, for the cells on the box's edge, the points of the grid's cells there. false
/// (then *map is untouched: use makeGroundMap) when the cells were not gathered or the map would
/// need a coarser cell or z step than asked.
bool groundMapOfCells(const GroundMapCells& cells, const GroundGrid& grid,
                      const Eigen::Vector2d& lo, const Eigen::Vector2d& hi,
                      const TrunkExtractorParams& p, GroundMap* map);

/// groundMapAroundTrunks of the local points when fewBasesSeen; else empty.
GroundMap groundMapIfFewBasesSeen(const Trunks& trunks, const LocalPoints& pts,
                                  const TrunkExtractorParams& p);

}  // namespace dtif
