// Helpers of the map-merge rostests: simulating the tiny scene, playing its bag, collecting the
// robots' descriptors and scoring the merge nodelet's `map` TF against ground truth.
#pragma once

#include <gtest/gtest.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/buffer.h>

#include <Eigen/Geometry>
#include <cmath>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "dtif/io/dataset.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/msgs.h"

namespace dtif::test {

constexpr double kMergeStampTolS = 1e-3;

// The latest message of a (latched) topic.
template <class Msg>
struct Latest {
  std::mutex mutex;
  boost::shared_ptr<const Msg> msg;
  void cb(const boost::shared_ptr<const Msg>& m) {
    std::lock_guard<std::mutex> lock(mutex);
    msg = m;
  }
  boost::shared_ptr<const Msg> latest() {
    std::lock_guard<std::mutex> lock(mutex);
    return msg;
  }
};

// Dataset id of the submap of `robot` anchored at `stamp`, or -1.
inline int64_t datasetId(const Dataset& ds, const std::string& robot, double stamp) {
  for (const SubmapRecord& s : ds.submaps) {
    if (s.robot == robot && std::fabs(s.stamp - stamp) <= kMergeStampTolS) return s.id;
  }
  return -1;
}

// One submap the nodelets published: its dataset id, odometry frame and T_O_S.
struct SeenSubmap {
  int64_t dataset_id = -1;
  int64_t submap_id = -1;  ///< as the nodelets number it
  double stamp = 0.0;      ///< anchor time [s]
  std::string robot;
  std::string odom_frame;
  Pose T_O_S = Pose::Identity();
};

inline std::vector<SeenSubmap> seenSubmaps(
    const Dataset& ds, const std::vector<boost::shared_ptr<const dtif::TrunkDescriptor>>& msgs,
    const std::string& as_robot = "") {
  std::vector<SeenSubmap> out;
  for (const auto& d : msgs) {
    SeenSubmap s;
    s.robot = d->robot;
    s.submap_id = d->submap_id;
    s.stamp = d->header.stamp.toSec();
    s.dataset_id = datasetId(ds, as_robot.empty() ? d->robot : as_robot, d->header.stamp.toSec());
    s.odom_frame = d->header.frame_id;
    if (s.dataset_id < 0 || !ros_glue::fromMsg(d->odom_pose, &s.T_O_S)) continue;
    out.push_back(s);
  }
  return out;
}

// The latest transform target <- source, or false.
inline bool lookup(const tf2_ros::Buffer& tf, const std::string& target, const std::string& source,
                   Pose* T) {
  try {
    *T = tf2::transformToEigen(tf.lookupTransform(target, source, ros::Time(0)));
    return true;
  } catch (const tf2::TransformException&) {
    return false;
  }
}

// The rigid transform (least squares, no scale) that best maps `est` onto `gt` positions.
inline Pose alignPositions(const std::vector<Eigen::Vector3d>& est,
                           const std::vector<Eigen::Vector3d>& gt) {
  Eigen::Matrix3Xd a(3, est.size()), b(3, gt.size());
  for (size_t i = 0; i < est.size(); ++i) {
    a.col(i) = est[i];
    b.col(i) = gt[i];
  }
  Pose T = Pose::Identity();
  T.matrix() = Eigen::umeyama(a, b, false);
  return T;
}

// Position residuals [m] of estimated submap positions against ground truth after the best
// rigid alignment, as DATASET.md's ATE.
inline std::vector<double> alignedResiduals(const std::vector<Eigen::Vector3d>& est,
                                            const std::vector<Eigen::Vector3d>& gt) {
  const Pose T = alignPositions(est, gt);
  std::vector<double> r;
  for (size_t i = 0; i < est.size(); ++i) r.push_back((T * est[i] - gt[i]).norm());
  return r;
}

// A robot's merged submap poses from its nav_msgs/Path (each pose stamped with its submap's
// anchor time): dataset id -> T_map_S.
inline std::map<int64_t, Pose> pathPoses(const Dataset& ds, const std::string& robot,
                                         const nav_msgs::Path& path) {
  std::map<int64_t, Pose> out;
  for (const auto& p : path.poses) {
    const int64_t id = datasetId(ds, robot, p.header.stamp.toSec());
    Pose T;
    if (id >= 0 && ros_glue::fromMsg(p.pose, &T)) out[id] = T;
  }
  return out;
}

inline double rms(const std::vector<double>& v) {
  double s = 0.0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / v.size());
}

}  // namespace dtif::test
