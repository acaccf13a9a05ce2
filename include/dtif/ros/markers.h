// rviz markers of trunk maps, Delaunay topologies and loop closures (pure functions), and the
// recent markers the nodelets publish again.
#pragma once

#include <visualization_msgs/MarkerArray.h>

#include <cstddef>
#include <deque>
#include <mutex>
#include <string>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/types.h"

namespace dtif {
namespace ros_glue {

/// The building blocks of every dtif marker (also the map merge's).
std_msgs::ColorRGBA color(float r, float g, float b, float a = 1.0f);
geometry_msgs::Point point(const Eigen::Vector3d& p);
/// An ADD marker with identity orientation (scale, colour and points are the caller's).
visualization_msgs::Marker newMarker(const std::string& frame, const std::string& ns, int id,
                                     int type, const ros::Time& stamp);

/// One cylinder per trunk (base at z, 2 m tall, diameter 2r) and the Delaunay edges, placed in
/// `frame` by T_F_S. Namespaces are prefixed with ns; stamp is the marker stamp.
visualization_msgs::MarkerArray trunkMarkers(const Descriptor& d, const Pose& T_F_S,
                                             const std::string& frame, const std::string& ns,
                                             const ros::Time& stamp);

/// A loop closure in the query's frame F: the query topology (T_F_Sq), the candidate topology
/// aligned by the estimate (T_F_Sq * inverse(T_c_q)), every solved vertex pair (grey) and the
/// inliers (green). Replaces the previous loop's markers (fixed ids).
visualization_msgs::MarkerArray loopMarkers(const Descriptor& q, const Descriptor& c,
                                            const Loop& lc, const Pose& T_F_Sq,
                                            const std::string& frame, const ros::Time& stamp);

/// The marker arrays of the latest `capacity` publications (e.g. one per submap), to publish again
/// on a timer: rviz drops a marker whose frame it cannot yet transform to the fixed frame (another
/// robot's odometry frame is linked only once a loop between the robots fixes it), so markers
/// published once before that would never show. Thread-safe (a worker adds, a timer reads).
class RecentMarkers {
 public:
  explicit RecentMarkers(size_t capacity) : capacity_(capacity) {}
  /// Keeps m; the oldest kept array is dropped beyond capacity (capacity 0: nothing kept).
  void add(visualization_msgs::MarkerArray m);
  /// Every kept marker, oldest array first (a later array's DELETEALL or same ns/id wins, as when
  /// they were first published); null when nothing is kept.
  boost::shared_ptr<const visualization_msgs::MarkerArray> all() const;
  size_t size() const;

 private:
  const size_t capacity_;
  mutable std::mutex mutex_;
  std::deque<visualization_msgs::MarkerArray> kept_;
};

}  // namespace ros_glue
}  // namespace dtif
