// What dtif/MapMergeNodelet publishes, built from the merge back end's results: paths, the stem
// inventory, rviz markers of the merged plot. Pure functions of their arguments; thread-safe.
#pragma once

#include <nav_msgs/Path.h>
#include <ros/time.h>
#include <visualization_msgs/MarkerArray.h>

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "dtif/core/merge/map_merger.h"
#include "dtif/ros/msgs.h"

namespace dtif {
namespace ros_glue {

/// A robot's submaps (anchor stamp [s], T_M_S; in order) as a path in `frame`: each pose
/// stamped with its submap's anchor time, so a consumer can tell which submap it is.
nav_msgs::Path pathMsg(const std::vector<std::pair<double, Pose>>& T_M_S, const std::string& frame,
                       const ros::Time& stamp);

/// The stems of one component as an inventory in `frame`.
dtif::StemInventory stemInventoryMsg(const std::vector<MergedStem>& stems, int component,
                                     const std::string& frame, const ros::Time& stamp);

/// The merged plot in one frame (component): stems as cylinders (height 1.3 m, DBH wide),
/// submap origins as spheres coloured per robot, used loops as green lines between submap
/// origins and rejected loops (both submaps in the component) as red lines. `frame_of`
/// gives each component's frame ("" : not drawn).
visualization_msgs::MarkerArray mergedMapMarkers(const std::vector<MergedPose>& poses,
                                                 const std::vector<LoopVerdict>& loops,
                                                 const std::vector<MergedStem>& stems,
                                                 const std::function<std::string(int)>& frame_of,
                                                 const ros::Time& stamp);

}  // namespace ros_glue
}  // namespace dtif
