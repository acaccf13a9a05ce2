// What the map-merge nodelet keeps of the submap clouds for the inventory's DBH from the points
// (StemSlices): it sees each cloud once, as it arrives, long before save_map knows the merged
// stems, and keeping the clouds whole would grow without bound. So each submap keeps only its
// full-resolution points near its own trunks and the stems known then (keepSliceCandidates), in
// its own frame S; at save_map StemSlices runs over them with the merged poses, as `dtif merge`
// runs it over the dataset's whole clouds (refitStemDbh). "Then" is a while after the cloud
// came (slice_defer_clouds): a submap sees about twice the stems it extracts, and many of the
// others are first extracted by the submaps that follow it.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/merge/map_merger.h"
#include "dtif/core/merge/stem_slices.h"

namespace dtif {

/// Per submap (the merger's id): its trunks, and its kept points once its cloud came.
/// Copies share the kept clouds (never modified). Not thread-safe.
class SlicePointStore {
 public:
  explicit SlicePointStore(const StemFusionParams& params = StemFusionParams{}) : p_(params) {}

  /// A submap's own trunks in S (MergeSubmap::trunks) and its levelling R_L_S (identity when
  /// unlevelled: Descriptor::level_rotation), from its descriptor.
  void addTrunks(int64_t id, const Trunks& trunks_S, const Eigen::Matrix3d& R_L_S);

  /// Its cloud in S: the points kept near its own trunks and near the stems of `known` (the
  /// inventory so far, MapMerger::stems()) in `component`, placed by the submap's current pose
  /// T_M_S in that component: a submap sees about twice the stems it extracts as trunks, and
  /// `dtif merge` pools the points of all of them. A later cloud of the same submap replaces
  /// the points. False when the submap's trunks are unknown (no descriptor yet): nothing kept.
  bool addCloud(int64_t id, const Cloud& cloud_S, const std::vector<MergedStem>& known = {},
                int component = -1, const Pose& T_M_S = Pose::Identity());

  /// Its cloud in S held until slice_defer_clouds later clouds came (keepSliceBand: whatever
  /// height any slice can take), then settled: cut down as addCloud cuts it, with the stems and
  /// pose of then. Replaces what the submap kept or held. False when its trunks are unknown.
  bool holdCloud(int64_t id, const Cloud& cloud_S);
  /// The held submaps with slice_defer_clouds or more later clouds, oldest first.
  std::vector<int64_t> overdue() const;
  /// addCloud of held submap `id`'s cloud (known, component, T_M_S as there); false when none
  /// is held.
  bool settle(int64_t id, const std::vector<MergedStem>& known, int component, const Pose& T_M_S);

  /// The inventory with the DBH refitted on the kept and held points (StemSlices::refit), the
  /// submaps placed by `poses`; submaps without points or pose contribute nothing.
  std::vector<MergedStem> refit(const std::vector<MergedStem>& stems,
                                const std::vector<MergedPose>& poses,
                                StemSliceStats* stats = nullptr) const;

  size_t submapsWithPoints() const { return clouds_.size() + held_.size(); }
  size_t heldClouds() const { return held_.size(); }
  /// Kept and held points.
  size_t points() const { return points_; }
  /// Memory of the kept and held points and the waiting trunks [bytes].
  size_t bytes() const;

 private:
  struct Source {
    Trunks trunks_S;
    Eigen::Matrix3d R_L_S = Eigen::Matrix3d::Identity();
  };

  struct Held {
    Cloud::ConstPtr cloud;  // within the slices' band
    size_t arrival = 0;     // holds_ when it came: holds_ - 1 - arrival later clouds came since
  };

  // Forgets submap id's kept or held points.
  void drop(int64_t id);

  StemFusionParams p_;
  std::map<int64_t, Source> sources_;
  std::map<int64_t, Cloud::ConstPtr> clouds_;  // kept: cut down to the stems near the submap
  std::map<int64_t, Held> held_;
  size_t holds_ = 0;  // clouds held so far
  size_t points_ = 0;
};

}  // namespace dtif
