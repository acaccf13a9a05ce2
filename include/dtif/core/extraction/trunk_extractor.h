// Trunk landmark extraction from a gravity-aligned submap (paper Sec. 3.B, after Zhang et al.):
// vertical-continuity voxel columns at low height above the local ground, merged into trunk
// candidates, robust circle fit at breast height, stem-base elevation from the local ground.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/extraction/footprint.h"
#include "dtif/core/extraction/ground_map.h"
#include "dtif/core/types.h"

namespace dtif {

/// Parameters of trunk extraction. Heights are above the local ground unless stated.
struct TrunkExtractorParams {
  /// Bounds of what extraction sizes its grids from (docs/limits.md): points farther than
  /// max_range_m from the cloud's median point along x, y or z are dropped and counted
  /// (TrunkExtractionStats::far_points), never gridded. The MID-360 sees 70 m at most and a
  /// submap is a walk of tens of metres, so survey points lie well inside.
  double max_range_m = 250.0;       ///< half side of the kept box about the median point [m]
  int max_points = 20000000;        ///< a larger cloud is refused whole (over_point_limit) [points]
  double ground_cell_m = 1.0;       ///< cell of the local ground grid [m]
  double ground_window_m = 5.0;     ///< window of the ground percentile around a cell [m]
  double ground_percentile = 0.05;  ///< low percentile of z taken as ground [0..1]
  double max_ground_cells = 4e6;    ///< larger extents (far outliers) coarsen the ground grid
                                    ///< until it has this many cells [cells]
  /// A point counts as ground only in an "open" sub-column of its ground cell: one with nothing
  /// between ground_open_gap_m and ground_open_top_m above its lowest point (a stem, a shrub or
  /// a log fills that space; the MID-360 sees no lower than -7 deg, so the lowest points of a
  /// cell are often the lowest hits on a stem). Cell value: a low percentile of those points.
  double ground_sub_cell_m = 0.25;         ///< sub-column size [m]
  double ground_band_m = 0.3;              ///< ground points: this far above the sub-column's
                                           ///< lowest point at most [m]
  double ground_open_gap_m = 0.3;          ///< open sub-column: empty from this height... [m]
  double ground_open_top_m = 1.5;          ///< ...up to this height above its lowest point [m]
  double ground_min_open_fraction = 0.75;  ///< open sub-columns a ground cell needs (the lower
                                           ///< field-of-view cut through stems leaves scattered
                                           ///< open ones; seen ground fills the cell) [0..1]
  double ground_max_step = 1.0;      ///< steepest ground step between neighbouring cells, per metre
                                     ///< of ground cell (25 deg slopes plus roughness) [m/m]
  int ground_min_cells = 3;          ///< ground cells a window needs for its plane; fewer: a three
                                     ///< times wider window, and the ground counts as not seen
                                     ///< [cells]
  double ground_plane_c_up_m = 0.3;  ///< Tukey constant of the window plane for cells above
                                     ///< it (what is left of vegetation fills cells from
                                     ///< above) [m]
  double ground_plane_c_down_m = 1.0;   ///< Tukey constant for cells below it [m]
  double slab_min_h_m = 0.4;            ///< lowest height of the trunk slab [m]
  double slab_max_h_m = 3.0;            ///< highest height of the trunk slab [m]
  double column_cell_m = 0.15;          ///< horizontal size of a voxel column [m]
  double layer_h_m = 0.2;               ///< vertical size of a voxel inside a column [m]
  int min_column_points = 6;            ///< points a column needs in the slab
  double min_continuity = 0.5;          ///< fraction of slab layers a column must occupy [0..1]
  double cluster_gap_m = 0.25;          ///< columns closer than this merge into one candidate [m]
  double fit_min_h_m = 0.9;             ///< lower edge of the circle-fit band [m]
  double fit_max_h_m = 1.7;             ///< upper edge of the circle-fit band [m]
  int min_fit_points = 12;              ///< points needed in the fit band
  double min_radius_m = 0.04;           ///< smallest accepted trunk radius [m]
  double max_radius_m = 0.6;            ///< largest accepted trunk radius [m]
  int ransac_iterations = 150;          ///< circle RANSAC iterations (fixed seed)
  int ransac_min_iterations = 25;       ///< before the adaptive stop may end RANSAC [iterations]
  int ransac_score_points = 400;        ///< hypotheses are scored on this many points at most,
                                        ///< evenly strided [points]
  double ransac_inlier_m = 0.03;        ///< circle RANSAC inlier distance [m]
  double min_inlier_ratio = 0.85;       ///< inliers / (inliers + points inside the circle) [0..1]
  double min_shell_ratio = 0.75;        ///< inliers / points within 3 ransac_inlier_m [0..1]
  double min_arc_deg = 80.0;            ///< angular coverage of inliers around the centre [deg]
  double max_lean_deg = 15.0;           ///< largest stem lean across the fit band [deg]
  double lean_shell_m = 0.15;           ///< the lean check uses band points within this outside the
                                        ///< circle only, so a close neighbour cannot pull it [m]
  double base_ring_inner_m = 0.2;       ///< ground ring around the stem, gap to the bark [m]
  double base_ring_outer_m = 1.5;       ///< ground ring around the stem, outer radius [m]
  double min_trunk_separation_m = 0.3;  ///< closer trunks are duplicates; the larger fit wins [m]
  double max_fit_rms_m = 0.02;          ///< largest RMS of the inliers about the circle [m]
  double base_max_dh_m = 0.4;           ///< ring points farther from the local ground are not
                                        ///< ground (shrubs, logs, noise) [m]
  int min_base_points = 8;              ///< ring points needed, else the grid ground is used
  double base_below_m = 0.3;            ///< a ring point this far below the base plane is lower
                                        ///< ground than the base [m]
  int max_base_below_points = 2;        ///< more such points: the base is not seen (it sits on a
                                        ///< shrub or log)
  double base_plane_c_up_m = 0.12;      ///< Tukey constant of the base plane for ring points
                                        ///< above it: tighter than the grid, litter and grass sit
                                        ///< on the ground surface [m]
  double base_plane_c_down_m = 0.25;    ///< Tukey constant for ring points below it [m]
  double stem_shell_m = 0.08;           ///< stem points: within this of the fitted circle [m]
  double base_max_gap_m = 0.5;     ///< a seen base: the stem's lowest point within this of it [m]
  int max_fits_per_candidate = 3;  ///< circles tried per candidate (trunks merged by
                                   ///< close spacing or undergrowth)
  double footprint_cell_m = 1.0;   ///< cell of the submap's footprint (occupied cells of
                                   ///< points 0.3-3 m above ground, DATASET.md); 0: none [m]
  int footprint_max_samples = 200000;  ///< points the footprint's ground percentiles use (an
                                       ///< even subsample; it is timed); 0: all [points]
  /// Ground map (lowest point per cell) for the elevation of loops that no pair of seen stem
  /// bases fixes: built when fewer than ground_map_below_seen of the trunks have a seen base
  /// (0: never, above 1: always). It costs descriptor bytes: the dense_slope scene's mean
  /// descriptor grows from 2.4 to 7.3 kB.
  double ground_map_cell_m = 0.5;       ///< cell of the ground map; 0: none [m]
  double ground_map_z_step_m = 0.05;    ///< quantisation of its elevations [m]
  double ground_map_below_seen = 1.01;  ///< seen-base share under which a map is built [0..1.01]
  double ground_map_margin_m = 2.0;     ///< the map covers the trunks' box plus this [m]
  int ground_map_min_points = 10;       ///< a cell with fewer points stays empty
  /// Density adaptation: the trunk-detection point counts (min_column_points, min_fit_points)
  /// hold for clouds at least as dense as density_reference; sparser clouds (a unit that keeps
  /// every n-th return, a slower sensor) get them scaled by density / density_reference, at
  /// least by density_min_scale. The ground and stem-base counts stay: scaled, they let bases on
  /// shrubs through (a false loop, 0.75 m off in z, on dense_slope at a third of the returns). The
  /// density: the median over the trunks a first pass fits (at least density_min_trunks, at least
  /// density_min_range_m from the submap origin, the sensor) of their breast-height inliers per
  /// m^2 of bark seen, times (range / 10 m)^2: points per m^2 of bark 10 m from the sensor.
  double density_reference = 130.0;  ///< 0: no adaptation [points/m^2 at 10 m]
  double density_min_scale = 0.5;    ///< smallest factor on the count thresholds (0..1]
  double density_min_range_m = 8.0;  ///< nearer trunks: bark saturated by the voxel filter [m]
  int density_min_trunks = 5;        ///< fewer such trunks: no adaptation

  /// Returns an empty string when the values are usable, else what is wrong.
  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("max_range_m", max_range_m);
    v("max_points", max_points);
    v("ground_cell_m", ground_cell_m);
    v("ground_window_m", ground_window_m);
    v("ground_percentile", ground_percentile);
    v("max_ground_cells", max_ground_cells);
    v("ground_sub_cell_m", ground_sub_cell_m);
    v("ground_band_m", ground_band_m);
    v("ground_open_gap_m", ground_open_gap_m);
    v("ground_open_top_m", ground_open_top_m);
    v("ground_min_open_fraction", ground_min_open_fraction);
    v("ground_max_step", ground_max_step);
    v("ground_min_cells", ground_min_cells);
    v("ground_plane_c_up_m", ground_plane_c_up_m);
    v("ground_plane_c_down_m", ground_plane_c_down_m);
    v("slab_min_h_m", slab_min_h_m);
    v("slab_max_h_m", slab_max_h_m);
    v("column_cell_m", column_cell_m);
    v("layer_h_m", layer_h_m);
    v("min_column_points", min_column_points);
    v("min_continuity", min_continuity);
    v("cluster_gap_m", cluster_gap_m);
    v("fit_min_h_m", fit_min_h_m);
    v("fit_max_h_m", fit_max_h_m);
    v("min_fit_points", min_fit_points);
    v("min_radius_m", min_radius_m);
    v("max_radius_m", max_radius_m);
    v("ransac_iterations", ransac_iterations);
    v("ransac_min_iterations", ransac_min_iterations);
    v("ransac_score_points", ransac_score_points);
    v("ransac_inlier_m", ransac_inlier_m);
    v("min_inlier_ratio", min_inlier_ratio);
    v("min_shell_ratio", min_shell_ratio);
    v("min_arc_deg", min_arc_deg);
    v("max_lean_deg", max_lean_deg);
    v("lean_shell_m", lean_shell_m);
    v("base_ring_inner_m", base_ring_inner_m);
    v("base_ring_outer_m", base_ring_outer_m);
    v("min_trunk_separation_m", min_trunk_separation_m);
    v("max_fit_rms_m", max_fit_rms_m);
    v("base_max_dh_m", base_max_dh_m);
    v("min_base_points", min_base_points);
    v("base_below_m", base_below_m);
    v("max_base_below_points", max_base_below_points);
    v("base_plane_c_up_m", base_plane_c_up_m);
    v("base_plane_c_down_m", base_plane_c_down_m);
    v("stem_shell_m", stem_shell_m);
    v("base_max_gap_m", base_max_gap_m);
    v("max_fits_per_candidate", max_fits_per_candidate);
    v("footprint_cell_m", footprint_cell_m);
    v("footprint_max_samples", footprint_max_samples);
    v("ground_map_cell_m", ground_map_cell_m);
    v("ground_map_z_step_m", ground_map_z_step_m);
    v("ground_map_below_seen", ground_map_below_seen);
    v("ground_map_margin_m", ground_map_margin_m);
    v("ground_map_min_points", ground_map_min_points);
    v("density_reference", density_reference);
    v("density_min_scale", density_min_scale);
    v("density_min_range_m", density_min_range_m);
    v("density_min_trunks", density_min_trunks);
  }
};

/// What happened during one extraction; for logs and benchmarks.
struct TrunkExtractionStats {
  size_t input_points = 0;        ///< points given
  size_t finite_points = 0;       ///< points left after dropping NaN/inf
  size_t far_points = 0;          ///< finite points beyond max_range_m, dropped (a warning)
  bool over_point_limit = false;  ///< more than max_points: nothing extracted (a warning)
  size_t candidate_columns = 0;   ///< voxel columns that passed density and continuity
  size_t candidates = 0;          ///< merged trunk candidates
  size_t rejected_fit = 0;        ///< candidates whose circle fit failed or was implausible
  size_t rejected_lean = 0;       ///< candidates rejected as leaning clutter
  size_t rejected_arc = 0;      ///< fits dropped for too little arc coverage (part of rejected_fit)
  size_t duplicates = 0;        ///< trunks dropped as duplicates
  size_t ground_fallbacks = 0;  ///< trunks whose base came from the grid, not the ring
  size_t unseen_bases = 0;      ///< trunks whose base was not observed (base_seen false)
  /// Bark density the first pass measured (TrunkExtractorParams::density_reference); 0: not
  /// measured (too few trunks) [points/m^2 at 10 m].
  double density = 0.0;
  double density_scale = 1.0;  ///< factor on the count thresholds; below 1: a second pass ran
};

struct TrunkExtractionResult {
  Trunks trunks;
  Footprint footprint;   ///< where the submap saw anything at trunk height (verification overlap)
  GroundMap ground_map;  ///< lowest point per cell; empty unless few bases were seen (and the
                         ///< caller wanted it: extractTrunks)
  TrunkExtractionStats stats;
};

/// Asked by extractTrunks before it builds a ground map, with the trunks and footprint found.
using GroundMapWanted = std::function<bool(const TrunkExtractionResult&)>;

/// Settings of the robust circle fit.
struct CircleFitParams {
  int iterations = 150;        ///< RANSAC iterations
  int min_iterations = 25;     ///< before the adaptive stop (99 % confidence of one all-inlier
                               ///< sample) may end the search, so an early lucky sample on a
                               ///< branch does not [iterations]
  int score_points = 400;      ///< hypotheses are scored on at most this many points, evenly
                               ///< strided: enough to rank circles, bounded cost on dense
                               ///< slices [points]
  double inlier_m = 0.03;      ///< inlier distance to the circle [m]
  double min_radius_m = 0.04;  ///< smallest radius a hypothesis may have [m]
  double max_radius_m = 0.6;   ///< largest radius a hypothesis may have [m]
  uint32_t seed = 1;           ///< RANSAC seed (fixed: results are reproducible)
};

/// A fitted circle and the evidence for it.
struct CircleFit {
  bool ok = false;              ///< false when there were too few points or no hypothesis
  double cx = 0.0;              ///< centre [m]
  double cy = 0.0;              ///< centre [m]
  double r = 0.0;               ///< radius [m]
  size_t inliers = 0;           ///< points within inlier_m of the circle
  double inlier_ratio = 0.0;    ///< inliers / (inliers + points inside the circle); a stem
                                ///< is opaque, points inside it speak against it [0..1]
  double shell_ratio = 0.0;     ///< inliers / points within 3 inlier_m of the circle; bark is
                                ///< a thin surface, foliage fills the shell [0..1]
  double arc_deg = 0.0;         ///< angular coverage of the inliers around the centre [deg]
  double rms_m = 0.0;           ///< RMS distance of the inliers to the circle [m]
  std::vector<char> is_inlier;  ///< per input point
};

/// Robust circle fit to horizontal points (paper Sec. 3.B, "circle fitting"): RANSAC over
/// 3-point circles (fixed seed), then an algebraic Kasa fit of the inliers, then a
/// Tukey-weighted geometric Gauss-Newton refinement, which removes the Kasa bias on partial
/// arcs. Deterministic; never throws.
CircleFit fitCircleRobust(const std::vector<Eigen::Vector2d>& xy, const CircleFitParams& params);

/// Extracts trunk landmarks from a gravity-aligned cloud in the submap frame.
/// Thread-safe and deterministic: the result depends on the cloud and params only. Each thread
/// keeps its largest working arrays between calls (~40 bytes per point of the largest cloud it
/// extracted) so that the next submap needs no fresh pages. Non-finite points are ignored; an
/// empty or degenerate cloud yields an empty result, never an exception.
///
/// `wanted` (when set) is asked once the trunks and footprint are in the result, before a
/// ground map is built: false leaves the map empty (a caller whose byte budget would drop it).
TrunkExtractionResult extractTrunks(const Cloud& cloud, const TrunkExtractorParams& params,
                                    const GroundMapWanted& wanted = nullptr);

}  // namespace dtif
