// Assembles gravity-aligned submaps from a registered cloud stream (FAST-LIO2's
// cloud_registered, points in the odometry frame O) and its odometry, over a time window.
// ROS-free so it is unit-tested without a master.
//
// Windows partition time as the simulator does (src/core/sim_survey.cpp): window k of a stream
// covers (t0 + k * window_s, t0 + (k + 1) * window_s], where t0 = the first cloud's stamp minus
// cloud_period_s (a cloud's stamp is the end of the time it covers, FAST-LIO2's lidar_end_time).
// A submap is anchored at its window's centre (DATASET.md's anchor time): S is gravity-aligned at
// the odometry pose interpolated there, and the submap's stamp is that centre. So a submap of a
// simulated bag has the stamp and the frame of the dataset's submap of the same robot and window.
#pragma once

#include <cstdint>
#include <deque>
#include <optional>
#include <string>

#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/types.h"
#include "dtif/core/voxel_grid.h"

namespace dtif {
namespace ros_glue {

struct SubmapAssemblerParams {
  double window_s = 10.0;           ///< submap length [s]
  double cloud_period_s = 0.1;      ///< time one cloud covers, ending at its stamp [s]
  double max_odom_gap_s = 0.5;      ///< odometry silence that discards the open submap [s]
  double max_odom_age_s = 0.2;      ///< the anchor needs odometry this close in time [s]
  int max_submap_points = 3000000;  ///< further points of a window are dropped
  /// Centroid voxel filter of the finished submap in S, on the grid dtif simulate uses for the
  /// dataset's submaps (default: its submap.voxel_m), so that the same returns give the same
  /// submap; 0 keeps every point [m].
  double voxel_m = 0.05;
  /// A stamp this much older than the previous one of its stream is a clock jump (a bag replayed
  /// again, or the previous message was stamped in the future): the stream starts afresh (a
  /// warning) instead of dropping every later message as out of order [s].
  double clock_jump_s = 5.0;

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("window_s", window_s);
    v("cloud_period_s", cloud_period_s);
    v("max_odom_gap_s", max_odom_gap_s);
    v("max_odom_age_s", max_odom_age_s);
    v("max_submap_points", max_submap_points);
    v("voxel_m", voxel_m);
    v("clock_jump_s", clock_jump_s);
  }
};

/// A finished submap: cloud in its own frame S (voxel centroids when voxel_m > 0) (gravity-aligned,
/// origin at the sensor position at the anchor time, yaw from odometry) and its pose T_O_S.
struct AssembledSubmap {
  int64_t id = -1;
  double stamp = 0.0;      ///< anchor time = centre of the window [s]
  double end_stamp = 0.0;  ///< stamp of the window's last cloud [s]
  Pose T_O_S = Pose::Identity();
  Cloud::Ptr cloud;
};

/// Not thread-safe: one caller (the subscriber callbacks, serialised by the caller's lock).
class SubmapAssembler {
 public:
  enum class Status {
    kOk,
    kDuplicateStamp,  ///< same stamp as the previous message: dropped
    kOutOfOrder,      ///< older than the previous message: dropped
    kNoAnchorPose,    ///< no odometry at the closed window's centre: that submap was discarded
    kOdometryGap,     ///< odometry was silent too long: the open submap was discarded
    kEmptyCloud,      ///< nothing to add
    kTruncated,       ///< max_submap_points reached: some points dropped
    kClockJump,       ///< stamp clock_jump_s older than the last: the stream started afresh
  };

  explicit SubmapAssembler(const SubmapAssemblerParams& params, int64_t first_id = 0);

  /// T_O_B: pose of the sensor body in the odometry frame at stamp.
  Status addOdometry(double stamp, const Pose& T_O_B);

  /// cloud_O: points in O (non-finite ones are skipped). A window is finished by its last cloud
  /// (stamp at the window's end) or, when that cloud is missing, by the first cloud of a later
  /// window; the finished submap is then returned in *done.
  Status addCloud(double stamp, const Cloud& cloud_O, std::optional<AssembledSubmap>* done);

  /// Finishes the open (incomplete) submap, if any, when its anchor pose is known.
  std::optional<AssembledSubmap> flush();

  /// Drops the open submap and the odometry history.
  void reset();

  static const char* describe(Status s);

 private:
  struct Stamped {
    double stamp;
    Pose T_O_B;
  };
  /// Stamps closer than this to a window's end belong to it (bags keep nanoseconds) [s].
  static constexpr double kStampTolS = 1e-4;
  struct Window {
    int64_t index = 0;  ///< k: covers (t0 + k * window_s, t0 + (k + 1) * window_s]
    double end_stamp = 0.0;
    Cloud::Ptr cloud_O;
  };
  std::optional<Pose> poseAt(double stamp) const;
  int64_t windowOf(double stamp) const;
  double centreOf(int64_t window) const;
  /// Moves the open window into a submap in S; nullopt when its anchor pose is unknown.
  std::optional<AssembledSubmap> close();

  SubmapAssemblerParams params_;
  int64_t next_id_;
  std::deque<Stamped> odom_;
  double last_cloud_stamp_ = -1.0;
  std::optional<double> t0_;  ///< start of window 0 of the current stream
  std::optional<Window> open_;
  VoxelCentroidSorter voxels_;  ///< reused by close()
};

/// The assembler's voxel filter (voxel_m > 0): replaces the points of a submap in S by the
/// centroids of its voxels of S, in voxel key order (VoxelCentroidSorter: the points the
/// simulator's VoxelCentroidGrid gives). `voxels` (made with voxel_m) is scratch, reused across
/// submaps to keep its buffers. Exposed so that a caller can assemble with voxel_m 0
/// and filter elsewhere (TrunkExtractionNodelet filters on its worker thread, not in the
/// callback); the result is the same.
void voxelFilterSubmap(VoxelCentroidSorter* voxels, Cloud* cloud_S);

/// Gravity-aligned submap pose from a body pose: position kept, roll and pitch removed, yaw of
/// the body's x axis kept.
Pose gravityAlignedPose(const Pose& T_O_B);

}  // namespace ros_glue
}  // namespace dtif
