// The merged map of a fleet as the map merge nodelet keeps it, ROS-free so that it is tested
// without a master: each robot's chain of submaps under the merger's own ids, loops waiting for
// their submaps, the submaps' clouds (and the points near their trunks for the DBH), and an
// earlier run's database as chains of its own. MapMergeNodelet converts messages, logs what
// this returns and publishes; the merging itself is the core's MapMerger.
#pragma once

#include <deque>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/merge/map_merger.h"
#include "dtif/core/merge/slice_store.h"

namespace dtif {
namespace ros_glue {

/// Thread-safety: none; the nodelet holds it under one mutex. Copyable: save_map works on a
/// copy while the live map goes on (clouds are shared, never modified).
class FleetMap {
 public:
  using Key = std::pair<std::string, int64_t>;  ///< (robot, the robot's own submap id)

  /// One robot chain of the merger: a live robot, or an earlier run's submaps from a database
  /// (merger robot name "<robot>@database": its own chain, its odometry frame no longer live).
  struct Chain {
    std::string odom_frame;
    bool live = true;
  };

  /// What loadDatabase took from a database file.
  struct Loaded {
    size_t submaps = 0;
    size_t loops = 0;
    size_t without_odometry = 0;  ///< entries of a version-1 file: no pose, skipped
  };

  /// `field`: the plot's field stem map (may be empty); `cloud_voxel_m`: the voxel of the kept
  /// submap clouds and of the merged cloud [m].
  FleetMap(const MergeParams& params, std::vector<FieldStem> field, double cloud_voxel_m);

  /// A robot's submap (d.robot; its trunks and level rotation, odometry pose T_O_S, anchor stamp)
  /// on its chain. Returns "" or why it was dropped: no odometry frame, another frame than the
  /// robot's earlier submaps, already merged, or refused by the merger.
  std::string addSubmap(const Descriptor& d, const std::string& odom_frame, double stamp,
                        const Pose& T_O_S);

  /// A loop in the robots' own submap ids; it goes to the merger once both submaps are in.
  void addLoop(const Loop& l) { pending_.push_back(l); }

  /// The waiting loops whose submaps are both in go to the merger; those it refuses are appended
  /// to `refused`. At most max_waiting stay waiting: beyond, the oldest is dropped and
  /// `*dropped` set. Returns true when a loop went in.
  bool addPendingLoops(size_t max_waiting, std::vector<Loop>* refused, bool* dropped);
  size_t waitingLoops() const { return pending_.size(); }

  /// The robot whose submaps come in odometry frame `frame` ("" when none does yet).
  std::string robotOfFrame(const std::string& frame) const;

  /// A submap cloud in the robot's odometry frame, stamped with its submap's anchor time: kept
  /// voxel-downsampled in the submap frame S and, with stems.dbh_from_points, its points near the
  /// trunks of `known` (the inventory so far); with stems.slice_defer_clouds, held for the slices
  /// until that many later clouds came, and the clouds then due cut down to `known`. Returns ""
  /// or why it was dropped.
  std::string addCloud(const std::string& robot, double stamp, const Cloud& cloud_O,
                       const std::vector<MergedStem>& known);

  /// Replaces everything by the database's submaps whose odometry is known (version-2 files),
  /// one chain "<robot>@database" per robot, and its loops: loops of a new run against them then
  /// place the new robots in that map.
  Loaded loadDatabase(const LoopDetector& db);

  /// Component `component`'s submap clouds in its map frame under `poses`, voxel-downsampled;
  /// null when it has none.
  Cloud::Ptr mergedCloud(const std::vector<MergedPose>& poses, int component) const;

  MapMerger& merger() { return merger_; }
  const MapMerger& merger() const { return merger_; }
  const std::map<std::string, Chain>& chains() const { return chains_; }
  const SlicePointStore& slices() const { return slices_; }
  /// The anchor stamp of merger id `id` (0 when unknown).
  double stampOf(int64_t id) const;
  /// submap_ids.csv of save_map: the merger's ids (merged_poses.csv, pose_graph.g2o) as the
  /// robots' own submap ids and anchor stamps; chain is the merger's robot. Throws
  /// std::runtime_error when it cannot write.
  void writeSubmapIds(const std::string& path, const std::vector<MergedPose>& poses) const;

 private:
  // Everything dropped: a new merger (with the field stem map), no chains.
  void reset();
  // The merger's addSubmap of s (its robot's own name and id) as a submap of `chain` under the
  // next id; "" or why not.
  std::string addToMerger(const std::string& chain, MergeSubmap s);
  Cloud::Ptr voxelDown(const Cloud& in) const;
  // Merger id's component and current pose T_M_S; -1 and identity while it has none.
  std::pair<int, Pose> placement(int64_t id) const;

  MergeParams params_;
  std::vector<FieldStem> field_;
  double cloud_voxel_m_;
  MapMerger merger_;
  std::map<std::string, Chain> chains_;                            // merger robot -> chain
  std::map<Key, int64_t> global_id_;                               // (robot, own id) -> id
  std::map<std::pair<std::string, double>, int64_t> stamp_index_;  // (robot, stamp) -> id
  std::map<int64_t, double> stamp_of_;                             // id -> anchor stamp
  std::map<int64_t, std::string> chain_of_;                        // id -> merger robot
  std::map<int64_t, Pose> odom_of_;                                // id -> T_O_S
  std::map<int64_t, Cloud::Ptr> clouds_;                           // id -> cloud in S
  SlicePointStore slices_;                                         // id -> points near trunks
  std::deque<Loop> pending_;
  int64_t next_id_ = 0;
};

}  // namespace ros_glue
}  // namespace dtif
