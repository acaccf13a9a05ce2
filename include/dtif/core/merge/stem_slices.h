// DBH of the merged stem inventory from the points themselves (issue #16): each merged stem's
// breast-height slice, pooled from every submap cloud placed by the merged poses, and one circle
// fitted to it. One submap sees a stem from one side, and a circle fitted to such an arc under
// along-ray range noise is too small by about 2 sigma^2 / r; seen from several sides the biases
// cancel, and an elliptical stem's axes average out.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/merge/slice_alignment.h"
#include "dtif/core/merge/stem_inventory.h"
#include "dtif/core/types.h"

namespace dtif {

/// What the refit did (StemSlices::refit).
struct StemSliceStats {
  size_t stems = 0;         ///< stems of the inventory
  size_t refitted = 0;      ///< DBH from the pooled slice
  size_t too_few = 0;       ///< kept the observations' median: too few points or submaps
  size_t one_sided = 0;     ///< kept it: the pooled arc was narrower than slice_min_arc_deg
  size_t no_fit = 0;        ///< kept it: no plausible circle (radius or centre far off)
  size_t shrunk = 0;        ///< kept it: the circle well inside the median (slice_max_shrink)
  size_t enclosing = 0;     ///< kept it: points inside the circle (slice_min_inlier_ratio)
  size_t blended = 0;       ///< one-sided or shrunk, arc >= slice_blend_min_arc_deg: mean of both
  size_t points = 0;        ///< slice points kept over all stems
  size_t submap_views = 0;  ///< (stem, submap) pairs that contributed points
  SliceAlignmentStats alignment;  ///< the submaps' alignment on the bark before the refit
};

/// Gathers the breast-height slice points of a fixed set of merged stems from submap clouds, one
/// submap at a time (the clouds are never held together), then refits every stem's DBH.
/// Not thread-safe; the stems are copied at construction.
class StemSlices {
 public:
  /// `stems` in their components' map frames M (MapMerger::stems()); the slice parameters are
  /// StemFusionParams' slice_* (validated by StemFusionParams::validate).
  StemSlices(const std::vector<MergedStem>& stems, const StemFusionParams& params);

  /// The points of one submap's cloud (in S, non-finite points skipped) within
  /// r + slice_margin_m of a stem of `component` and slice_min_h_m..slice_max_h_m above its
  /// base, placed by T_M_S (the pose MapMerger::poses() reports, in the same frame as the
  /// stems); at most slice_max_points_per_submap per stem, evenly strided.
  void addSubmap(int component, const Pose& T_M_S, const Cloud& cloud_S);

  /// First, unless slice_align_sigma_m <= 0, each submap's points are moved by its correction
  /// from alignSliceViews over the stems whose pooled circle is accepted (the merged poses are
  /// centimetres off each other; stats->alignment). Then the stems with dbh = 2 r and centre
  /// (x, y) of a robust circle fit (fitCircleRobust) to each pooled slice,
  /// where it has at least slice_min_points points from slice_min_submaps submaps and its
  /// inliers cover at least slice_min_arc_deg; dbh = the mean of 2 r and the inventory's dbh
  /// (centre unchanged) where the circle was refused only as one-sided or shrunk and its
  /// inliers cover at least slice_blend_min_arc_deg; everything else unchanged. Deterministic.
  std::vector<MergedStem> refit(StemSliceStats* stats = nullptr) const;

  /// One stem's pooled slice, horizontal points in M (for tests and diagnostics).
  const std::vector<Eigen::Vector2f>& slice(size_t stem) const { return slices_[stem].xy; }

 private:
  struct Slice {
    std::vector<Eigen::Vector2f> xy;
    std::vector<uint32_t> view;  // per point: the addSubmap call it came from
    int submaps = 0;
  };

  bool enoughPoints(size_t k) const;  // slice_min_points from slice_min_submaps
  // Each view's correction by alignSliceViews; empty when off (the points stay as they are).
  std::vector<ViewCorrection> alignViews(StemSliceStats* st) const;
  // Stem k's slice with its views' corrections (none: as gathered).
  std::vector<Eigen::Vector2d> correctedSlice(size_t k, const std::vector<ViewCorrection>& c) const;

  std::vector<MergedStem> stems_;
  std::vector<Eigen::Vector2d> origins_;  // per view: the submap's origin in M
  StemFusionParams p_;
  std::vector<Slice> slices_;
  std::unordered_map<int64_t, std::vector<size_t>> grid_;  // 1 m cell -> stems near it
};

/// What a submap cloud can give any stem's slice, whatever the stem's base turns out to be: the
/// points of `cloud_S` (non-finite skipped, in their order) no higher, levelled by R_L_S, than
/// slice_max_h_m + slice_keep_band_m + 1 m above the lowest point of their 1 m cell. The lowest
/// point of a cell is at or above its ground, and the metre covers a slope's rise across it;
/// the crowns, most of a submap under a canopy, go.
Cloud::Ptr keepSliceBand(const Cloud& cloud_S, const Eigen::Matrix3d& R_L_S,
                         const StemFusionParams& params);

/// Online counterpart of a submap cloud kept for StemSlices (MapMergeNodelet): the points of
/// `cloud_S` (in S, non-finite skipped, in their order) that lie, levelled by R_L_S (identity for
/// an unlevelled submap), within r + slice_margin_m + slice_keep_margin_m of one of the submap's
/// own trunks (`trunks_S`, in S as MergeSubmap::trunks) and slice_min_h_m - slice_keep_band_m ..
/// slice_max_h_m + slice_keep_band_m above its base; at most slice_keep_max_points per trunk,
/// evenly strided. For a merged stem within slice_keep_margin_m (centre and radius together) and
/// slice_keep_band_m (base) of the submap's trunk, and below the cap, StemSlices::addSubmap then
/// gathers the very points it gathers from the whole cloud: a superset filtered in order.
Cloud::Ptr keepSliceCandidates(const Cloud& cloud_S, const Trunks& trunks_S,
                               const Eigen::Matrix3d& R_L_S, const StemFusionParams& params);

/// The circle fit a pooled slice gets: fitCircleRobust with the radius bounded to
/// [0.5 r0, 2 r0 + 0.05 m] about the inventory's radius r0, inlier distance slice_inlier_m.
/// `ok` false when the fit failed, the centre is more than slice_margin_m from (x0, y0), the
/// inliers' arc is narrower than slice_min_arc_deg (then one_sided), the radius is below
/// (1 - slice_max_shrink) r0 (then shrunk) or too many points lie inside the circle
/// (slice_min_inlier_ratio; then encloses).
struct SliceFit {
  bool ok = false;
  double cx = 0.0, cy = 0.0, r = 0.0;  ///< [m]
  double arc_deg = 0.0;                ///< inlier coverage [deg]
  bool one_sided = false;              ///< the fit was fine but its arc too narrow
  bool shrunk = false;                 ///< the fit was fine but its radius well below r0
  bool encloses = false;               ///< the fit was fine (not one-sided, not shrunk) but
                                       ///< points lie inside it
};
SliceFit fitStemSlice(const std::vector<Eigen::Vector2d>& xy, double x0, double y0, double r0,
                      const StemFusionParams& params);

}  // namespace dtif
