// The merged stem inventory: trunks seen by many submaps and robots, fused into one entry per
// physical tree (issue #16).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "dtif/core/types.h"

namespace dtif {

struct StemFusionParams {
  double cluster_radius_m = 0.5;  ///< observations of one tree lie within this of its centre [m]
  double radius_rel_tol = 1.0;    ///< |r - r_cluster| <= max(abs, rel * r_cluster) ...
  double radius_abs_tol_m =
      0.2;  ///< ... to join a cluster (loose: one submap's radius can be far off) [m]
  int min_observations = 1;  ///< fewer contributing submaps: dropped (false trunks)
  /// Each observation fitted its circle 1.3 m above its own base estimate: one whose base lies
  /// within this of the tree's fitted near breast height, so its centre counts for the tree's
  /// position and its radius is the reference of the taper estimate [m].
  double base_tol_m = 1.0;
  /// Observations whose base is off the tree's by more are left out of the DBH and position
  /// (when others remain): their ground was a guess far from the stem [m].
  double max_base_offset_m = 3.0;
  /// A tree with no seen base takes its base from a surface through the seen bases of the
  /// trees within this radius (at least 4, spread over >= 1 m); 0: never [m].
  double terrain_radius_m = 12.0;
  /// Where that finds no surface, the ground points within this; <= terrain_radius_m: never [m].
  double terrain_far_radius_m = 24.0;
  /// Those points weighted by their distance (Gaussian of this sigma), the surface quadratic
  /// where enough weight lies around, else a plane; 0: an unweighted plane. Rolling ground
  /// bends within a plane's 24 m, and hidden bases lie in its hollows [m].
  double terrain_sigma_m = 4.0;
  /// The robots walked on the ground: where understory hides the bases, the ground under the
  /// sensor positions (SensorPosition) joins the seen bases in that surface. Each robot's sensor
  /// height is the median of its positions' height above the seen bases' surface; a robot with
  /// fewer such positions than this, or whose heights spread (median absolute deviation) more
  /// than path_max_spread_m, adds no ground (a drone, a mast that moves); 0: never.
  int path_min_samples = 3;
  double path_max_spread_m = 0.6;  ///< [m]
  /// Radii fitted above (below) breast height are too small (large) by the stand's taper,
  /// estimated from the inventory itself: the radius change per metre of base offset within
  /// trees whose base was seen. Fewer such observations than this: no correction; 0: never.
  int taper_min_pairs = 30;
  /// An entry whose circle comes within this of the circle of an entry seen by at least twice
  /// as many submaps is dropped (two trunks cannot overlap: a second fit of the same stem);
  /// < 0: never [m].
  double overlap_margin_m = 0.1;
  /// The margin for an entry seen by one submap only (against one seen by at least two): a
  /// second circle that close to a stem that other submaps saw alone is more likely a branch, a
  /// sapling under its crown or a misplaced fit of it than a tree they all missed; below
  /// overlap_margin_m: that applies [m].
  double single_overlap_margin_m = 0.3;
  /// The margin between two entries seen by one submap each: the one of smaller DBH is dropped
  /// (mostly one submap's second circle beside a stem, on part of its bark with clutter: two real
  /// stems that close are rarely each seen by one submap only); < 0: never [m].
  double single_pair_margin_m = 0.15;
  /// An entry seen by this many submaps or more is well seen: they had the spot beside it in
  /// clear view, and a tree there would be seen by more than one of them; 0: none is.
  int well_seen_observations = 8;
  /// The margin for an entry seen by one submap only against a well-seen one (below
  /// single_overlap_margin_m: that applies) [m].
  double single_well_seen_margin_m = 0.6;
  /// DBH from the points (StemSlices; `dtif merge`, which reads the submap clouds again): each
  /// stem's slice slice_min_h_m..slice_max_h_m above its base, within r + slice_margin_m of its
  /// centre, pooled from every submap placed by the merged poses, one robust circle fitted. A
  /// stem seen from several sides loses the one-sided fits' range-noise bias. Where the slice
  /// is too thin the observations' median stays; where its circle is one-sided or shrunk, the
  /// median stays or goes half-way to the circle (slice_blend_min_arc_deg).
  bool dbh_from_points = true;
  double slice_min_h_m = 1.1;             ///< slice's lower edge above the stem's base [m]
  double slice_max_h_m = 1.5;             ///< slice's upper edge above the stem's base [m]
  double slice_margin_m = 0.15;           ///< gathered within r + this of the centre [m]
  int slice_max_points_per_submap = 256;  ///< per stem and submap, evenly strided [points]
  int slice_min_points = 20;              ///< fewer pooled points: the median stays [points]
  int slice_min_submaps = 2;              ///< fewer contributing submaps: the median stays
  double slice_min_arc_deg = 240.0;       ///< narrower pooled inlier arc: the median stays [deg]
  double slice_inlier_m = 0.04;           ///< circle inlier distance (Tukey: twice this) [m]
  /// A pooled circle smaller than the observations' median radius by more than this fraction
  /// of it: the median stays. Each submap's own fit is biased small by the range noise, not
  /// large, so a pooled circle well inside them means the submaps' arcs do not line up (poses
  /// centimetres off: the fit takes the inner envelope of the offset arcs) [0..1]
  double slice_max_shrink = 0.1;
  /// A pooled circle refused only as one-sided or shrunk whose inliers still cover at least
  /// this: DBH is the mean of its diameter and the observations' median. Both are off there
  /// (the median small from one-sided views or large from a neighbour in a view, the circle
  /// small from offset arcs), by 2-5 cm each and not together; > 360: never [deg]
  double slice_blend_min_arc_deg = 180.0;
  /// A pooled circle whose inliers are fewer than this fraction of its inliers and the points
  /// inside it: the median stays. No return comes from inside a stem, so a circle with points
  /// inside encloses it: dead branches or a shrub around the stem at breast height [0..1]
  double slice_min_inlier_ratio = 0.8;
  /// Before the refit, each submap's slices are aligned on the bark (alignSliceViews): a planar
  /// correction per submap, drawn towards none with this std dev per axis, that brings the
  /// well-seen stems' arcs onto common circles; <= 0: off [m]
  double slice_align_sigma_m = 0.03;
  double slice_align_sigma_deg = 0.3;  ///< ... and its yaw's [deg]
  /// Online (MapMergeNodelet, keepSliceCandidates): what each arriving submap cloud keeps for
  /// the refit at save_map, around the submap's own trunks, before the merged stems exist. The
  /// merged stem's centre, radius and base differ from this submap's trunk by centimetres
  /// (decimetres for a guessed base), so the kept cylinder is wider and taller than the slice.
  double slice_keep_margin_m = 0.25;  ///< kept within r + slice_margin_m + this [m]
  double slice_keep_band_m = 0.5;     ///< kept slice_min_h_m - this .. slice_max_h_m + this [m]
  int slice_keep_max_points = 2048;   ///< per trunk and submap, evenly strided [points]
  /// A cloud is held whole within the height of any slice (keepSliceBand) until this many later
  /// clouds came, then cut down to the stems known then: a stem that one of those submaps
  /// extracts, of its robot or another, gets this submap's points too. 0: cut at arrival.
  int slice_defer_clouds = 24;
  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("cluster_radius_m", cluster_radius_m);
    v("radius_rel_tol", radius_rel_tol);
    v("radius_abs_tol_m", radius_abs_tol_m);
    v("min_observations", min_observations);
    v("base_tol_m", base_tol_m);
    v("max_base_offset_m", max_base_offset_m);
    v("terrain_radius_m", terrain_radius_m);
    v("terrain_far_radius_m", terrain_far_radius_m);
    v("terrain_sigma_m", terrain_sigma_m);
    v("path_min_samples", path_min_samples);
    v("path_max_spread_m", path_max_spread_m);
    v("taper_min_pairs", taper_min_pairs);
    v("overlap_margin_m", overlap_margin_m);
    v("single_overlap_margin_m", single_overlap_margin_m);
    v("single_pair_margin_m", single_pair_margin_m);
    v("well_seen_observations", well_seen_observations);
    v("single_well_seen_margin_m", single_well_seen_margin_m);
    v("dbh_from_points", dbh_from_points);
    v("slice_min_h_m", slice_min_h_m);
    v("slice_max_h_m", slice_max_h_m);
    v("slice_margin_m", slice_margin_m);
    v("slice_max_points_per_submap", slice_max_points_per_submap);
    v("slice_min_points", slice_min_points);
    v("slice_min_submaps", slice_min_submaps);
    v("slice_min_arc_deg", slice_min_arc_deg);
    v("slice_inlier_m", slice_inlier_m);
    v("slice_max_shrink", slice_max_shrink);
    v("slice_blend_min_arc_deg", slice_blend_min_arc_deg);
    v("slice_min_inlier_ratio", slice_min_inlier_ratio);
    v("slice_align_sigma_m", slice_align_sigma_m);
    v("slice_align_sigma_deg", slice_align_sigma_deg);
    v("slice_keep_margin_m", slice_keep_margin_m);
    v("slice_keep_band_m", slice_keep_band_m);
    v("slice_keep_max_points", slice_keep_max_points);
    v("slice_defer_clouds", slice_defer_clouds);
  }
};

/// One trunk of one submap, already in the component's map frame M.
struct StemObservation {
  int64_t submap = -1;
  int component = 0;
  double x = 0.0, y = 0.0, z = 0.0;  ///< centre and base elevation in M [m]
  double r = 0.0;                    ///< radius [m]
  bool base_seen = true;
};

/// Where a robot's sensor was (a submap frame's origin), in its component's M.
struct SensorPosition {
  int component = 0;
  int robot = 0;                     ///< any id, the same for all of one robot's positions
  double x = 0.0, y = 0.0, z = 0.0;  ///< [m]
};

/// One physical tree of the inventory, in its component's M.
struct MergedStem {
  int64_t stem_id = -1;  ///< 0.. in output order
  int component = 0;
  double x = 0.0, y = 0.0, z_base = 0.0;  ///< median of the observations [m]
  double dbh = 0.0;      ///< 2 x median radius, or 2 x the pooled slice's radius (StemSlices) [m]
  int observations = 0;  ///< contributing submaps
  std::string field_id;  ///< the field stem map's tree id when matched
};

/// Clusters observations per component (greedy, nearest cluster centre within the radius and
/// a similar radius, at most one observation per submap in a cluster; then clusters closer than
/// the radius with no submap in common are joined) and fuses each cluster robustly. The tree's
/// base: the median of the observations whose base was seen, else the seen bases of the trees
/// around it and the ground under the robots' paths there (a local surface; StemFusionParams::
/// path_min_samples), else the median of all. Each observation fitted its circle 1.3 m above
/// its own base estimate, which for a hidden base can be metres too high: DBH is the median
/// radius of the observations within max_base_offset_m of the tree's base, each corrected to
/// breast height by the stand's taper (taperFromObservations), and x, y the median of those
/// within base_tol_m (a leaning stem's centre moves with height); all observations when none
/// qualify. Deterministic: the output is ordered by component, then x, then y; stem ids follow
/// that order.
std::vector<MergedStem> fuseStems(const std::vector<StemObservation>& observations,
                                  const StemFusionParams& params,
                                  const std::vector<SensorPosition>& sensors = {});

/// One observation of a tree whose base was seen: its base offset from the tree's base (dz,
/// metres up) and its radius minus the radius of the tree's observations at breast height.
struct TaperPair {
  double dz = 0.0, dr = 0.0;  ///< [m]
};

/// The stand's taper [m of radius per m of height] from observations fitted above breast
/// height (base_tol_m < dz <= max_base_offset_m): least squares of -dr = taper * dz, clamped to
/// [0, 0.05]; 0 with fewer than taper_min_pairs such pairs (or taper_min_pairs 0).
double taperFromObservations(const std::vector<TaperPair>& pairs, const StemFusionParams& params);

}  // namespace dtif
