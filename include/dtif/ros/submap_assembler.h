// Assembles gravity-aligned submaps from a registered cloud stream (FAST-LIO2's
// cloud_registered, points in the odometry frame O) and its odometry, over a time window.
// ROS-free so it is unit-tested without a master.
#pragma once

#include <cstdint>
#include <deque>
#include <optional>
#include <string>

#include "dtif/core/trunk_extractor.h"
#include "dtif/core/types.h"

namespace dtif {
namespace ros_glue {

struct SubmapAssemblerParams {
  double window_s = 10.0;           ///< submap length: clouds within this time of the anchor [s]
  double max_odom_gap_s = 0.5;      ///< odometry silence that discards the open submap [s]
  double max_odom_age_s = 0.2;      ///< the anchor needs an odometry pose this close in time [s]
  int max_submap_points = 3000000;  ///< further points of a window are dropped

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("window_s", window_s);
    v("max_odom_gap_s", max_odom_gap_s);
    v("max_odom_age_s", max_odom_age_s);
    v("max_submap_points", max_submap_points);
  }
};

/// A finished submap: cloud in its own frame S (gravity-aligned, origin at the sensor position
/// at the anchor time, yaw from odometry) and its pose T_O_S.
struct AssembledSubmap {
  int64_t id = -1;
  double stamp = 0.0;  ///< anchor time [s]
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
    kNoOdometry,      ///< no odometry near the anchor time: cloud dropped, no submap started
    kOdometryGap,     ///< odometry was silent too long: the open submap was discarded
    kEmptyCloud,      ///< nothing to add
    kTruncated,       ///< max_submap_points reached: some points dropped
  };

  explicit SubmapAssembler(const SubmapAssemblerParams& params, int64_t first_id = 0);

  /// T_O_B: pose of the sensor body in the odometry frame at stamp.
  Status addOdometry(double stamp, const Pose& T_O_B);

  /// cloud_O: finite points in O. When this cloud closes the window, the finished submap is
  /// returned in *done and this cloud anchors the next one.
  Status addCloud(double stamp, const Cloud& cloud_O, std::optional<AssembledSubmap>* done);

  /// Finishes the open submap, if any (end of a bag).
  std::optional<AssembledSubmap> flush();

  /// Drops the open submap and the odometry history.
  void reset();

  static const char* describe(Status s);

 private:
  struct Stamped {
    double stamp;
    Pose T_O_B;
  };
  std::optional<Pose> poseAt(double stamp) const;
  bool startWindow(double stamp);

  SubmapAssemblerParams params_;
  int64_t next_id_;
  std::deque<Stamped> odom_;
  double last_cloud_stamp_ = -1.0;
  std::optional<AssembledSubmap> open_;
  Pose T_S_O_ = Pose::Identity();
};

/// Gravity-aligned submap pose from a body pose: position kept, roll and pitch removed, yaw of
/// the body's x axis kept.
Pose gravityAlignedPose(const Pose& T_O_B);

}  // namespace ros_glue
}  // namespace dtif
