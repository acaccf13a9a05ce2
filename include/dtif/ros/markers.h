// rviz markers of trunk maps, Delaunay topologies and loop closures. Pure functions.
#pragma once

#include <visualization_msgs/MarkerArray.h>

#include <string>

#include "dtif/core/descriptor.h"
#include "dtif/core/loop_detector.h"
#include "dtif/core/types.h"

namespace dtif {
namespace ros_glue {

/// One cylinder per trunk (base at z, 2 m tall, diameter 2r) and the Delaunay edges, placed in
/// `frame` by T_F_S. Namespaces are prefixed with ns; stamp is the marker stamp.
visualization_msgs::MarkerArray trunkMarkers(const Descriptor& d, const Pose& T_F_S,
                                             const std::string& frame, const std::string& ns,
                                             const ros::Time& stamp);

/// A loop closure in the query's frame F: the query topology (T_F_Sq), the candidate topology
/// aligned by the estimate (T_F_Sq * inverse(T_c_q)), every solved vertex pair (grey) and the
/// inliers (green). Replaces the previous loop's markers (fixed ids).
visualization_msgs::MarkerArray loopMarkers(const Descriptor& q, const Descriptor& c,
                                            const LoopClosure& lc, const Pose& T_F_Sq,
                                            const std::string& frame, const ros::Time& stamp);

}  // namespace ros_glue
}  // namespace dtif
