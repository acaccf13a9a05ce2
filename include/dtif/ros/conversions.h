// Conversions between ROS messages and the core's types, in one place (toMsg/fromMsg pairs).
// All functions are pure and thread-safe. fromMsg functions never trust the message: they
// return false with a reason (NaN, bad index, wrong layout) instead of throwing or crashing.
#pragma once

#include <geometry_msgs/Pose.h>
#include <geometry_msgs/Transform.h>
#include <sensor_msgs/PointCloud2.h>

#include <string>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/types.h"
#include "dtif/ros/msgs.h"

namespace dtif {
namespace ros_glue {

/// Pose <-> geometry_msgs/Pose. fromMsg fails on non-finite values or a zero quaternion; a
/// non-unit quaternion is normalised.
geometry_msgs::Pose toMsg(const Pose& T);
bool fromMsg(const geometry_msgs::Pose& msg, Pose* T, std::string* error = nullptr);
geometry_msgs::Transform toTransformMsg(const Pose& T);

/// Descriptor <-> dtif/TrunkDescriptor. The message carries the identity (robot, submap id,
/// stamp), T_O_S, trunks, faces as canonical uint16 triples and the histograms. header.frame_id
/// is the robot's odometry frame, given by the caller.
dtif::TrunkDescriptor toMsg(const Descriptor& d, const Pose& T_O_S, const std::string& odom_frame);

/// Rebuilds the core descriptor with decodeDescriptor's rules (acceptReceivedDescriptor in
/// core/descriptor/validation.h): triangles re-encoded from the trunks and face triples in
/// buildDescriptor's order, a descriptor valid for its sender but too small for the receiver's
/// `params` marked invalid. Fails (with checkDescriptor's reason) on non-finite trunks or
/// histograms, out-of-range or repeated face indices, a malformed footprint or ground map, more
/// trunks than uint16 faces can index, faces that are not triples or a bad pose. T_O_S may be
/// null.
bool fromMsg(const dtif::TrunkDescriptor& msg, const DescriptorParams& params, Descriptor* d,
             Pose* T_O_S, std::string* error = nullptr);

/// Loop <-> dtif/LoopClosure. header is left to the caller. all_pairs is not carried.
dtif::LoopClosure toMsg(const Loop& lc);
bool fromMsg(const dtif::LoopClosure& msg, Loop* lc, std::string* error = nullptr);

/// PointCloud2 (fields x, y, z as float32 or float64) -> core cloud; non-finite points are
/// dropped (count in *dropped). Fails when x, y or z is missing or the layout is inconsistent.
bool fromMsg(const sensor_msgs::PointCloud2& msg, Cloud* cloud, size_t* dropped = nullptr,
             std::string* error = nullptr);

}  // namespace ros_glue
}  // namespace dtif
