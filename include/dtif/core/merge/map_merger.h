// Map merging back end (issue #16): a pose graph over every robot's submap chain and every
// accepted loop, solved with Ceres incrementally as loops arrive; pairwise-consistency (PCM)
// outlier rejection; one gravity-aligned map frame M per connected component of robots; the
// merged stem inventory; an optional field stem map as a fixed anchor. ROS-free.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/merge/merge_types.h"
#include "dtif/core/merge/stem_inventory.h"
#include "dtif/core/merge/stem_map.h"
#include "dtif/core/types.h"

namespace dtif {

class MapMerger {
 public:
  explicit MapMerger(const MergeParams& params = {});
  ~MapMerger();
  MapMerger(MapMerger&&) noexcept;
  MapMerger& operator=(MapMerger&&) noexcept;
  /// A deep copy: e.g. a snapshot to refine and save while the original keeps taking submaps.
  MapMerger(const MapMerger& other);
  MapMerger& operator=(const MapMerger& other);

  /// Appends a submap to its robot's chain (a new robot starts its own component). Throws
  /// std::invalid_argument on a duplicate id or a non-finite pose.
  void addSubmap(const MergeSubmap& submap);
  /// Per-robot levelling R_L_O: the robot's odometry frame O into a gravity-aligned frame
  /// (identity by default), used to make M z up (its anchor submap gets R_L_O R_O_S). A tilted O
  /// is constant per robot, a levelled submap's R_L_S is not (S turns about O's z with the yaw):
  /// pass levellingInOdom(R_L_S, T_O_S) of the robot's latest levelled submap. Applies from the
  /// next solve.
  void setLevelling(const std::string& robot, const Eigen::Matrix3d& R_L_O);
  /// Adds an accepted loop (both submaps must be known). Returns false (and ignores the loop)
  /// when a submap is unknown or the pose is not finite.
  bool addLoop(const Loop& loop);
  /// A field stem map (plot frame P) as a fixed anchor: from the next solve on, component 0's M
  /// is P when its stems register to it. Empty: no anchor.
  void setStemMap(const std::vector<FieldStem>& field);

  /// PCM over the loops, then a warm-started Ceres solve. Cheap when nothing changed.
  MergeSolveStats solve();

  /// solve(), then the landmark refinement (MergeParams::landmarks) of that solution: the final
  /// map (dtif merge, save_map). Costlier than solve() (every trunk is a factor), so not run on
  /// every loop; the next solve() starts from the refined poses. Cheap when nothing changed.
  MergeSolveStats refine();

  /// Component changes since the last call.
  std::vector<MergeEvent> takeEvents();

  size_t submapCount() const;
  std::vector<std::string> robots() const;
  /// The component of a robot (0 = largest), -1 when unknown.
  int component(const std::string& robot) const;
  int componentCount() const;
  /// T_M_S of a submap, nullopt when unknown.
  std::optional<Pose> pose(int64_t id) const;
  /// T_M_O: the robot's odometry frame in its component's M (TF map -> odom); nullopt when
  /// unknown.
  std::optional<Pose> mapFromOdom(const std::string& robot) const;
  /// Every submap, in insertion order.
  std::vector<MergedPose> poses() const;
  std::vector<LoopVerdict> loops() const;
  /// The merged stem inventory (one entry per physical tree), per component in its M.
  std::vector<MergedStem> stems() const;
  /// The field stem map registration of component 0 (ok = false when none or it failed).
  StemMapRegistration stemMapRegistration() const;
  /// The pose graph's edges (odometry and used loops), for export.
  std::vector<MergeGraphEdge> graphEdges() const;
  const MergeParams& params() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dtif
