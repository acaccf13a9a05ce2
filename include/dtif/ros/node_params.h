// Node-level parameters of the two nodelets (the core's parameter sections are read separately
// into the core's own structs). Declared here so tests can check the shipped YAMLs against them.
#pragma once

#include <string>
#include <vector>

namespace dtif {
namespace ros_glue {

/// Node-level parameters (the core's sections `trunk_extraction` and `descriptor` are read
/// separately).
struct TrunkExtractionNodeParams {
  std::string input = "odometry";  ///< "odometry": cloud_registered + Odometry; "submap"
  std::string robot;               ///< robot name; empty: last element of the namespace
  std::string odom_frame;          ///< expected odometry frame; empty: take it from the input
  /// Odometry frame of everything published (descriptors, markers, clouds, body TF); empty:
  /// `<robot>/<input frame>` (ros_glue::robotFrame), so units sharing `camera_init` differ.
  std::string output_odom_frame;
  bool publish_body_tf = true;    ///< TF output_odom_frame -> `<robot>/<child_frame_id>` (Odometry)
  double input_timeout_s = 10.0;  ///< warn while an input topic is silent this long; 0: never [s]
  /// sensor_msgs/Imu of the body frame (FAST-LIO2 on a MID-360: /livox/imu); "": no IMU. Its
  /// accelerometer over each submap adds a gravity reading to the levelling.
  std::string imu_topic;
  int first_submap_id = 0;            ///< id of the first submap (raise it after a restart)
  int queue_size = 2;                 ///< submaps waiting for extraction; the oldest is dropped
  bool publish_submap_cloud = false;  ///< publish the assembled submap on `submap_cloud`
  int marker_history = 100;           ///< submaps whose trunk markers are published again
  double marker_period_s = 2.0;       ///< wall-clock period of that; 0: markers published once [s]

  template <class V>
  void visit(V& v) {
    v("input", input);
    v("robot", robot);
    v("odom_frame", odom_frame);
    v("output_odom_frame", output_odom_frame);
    v("publish_body_tf", publish_body_tf);
    v("input_timeout_s", input_timeout_s);
    v("imu_topic", imu_topic);
    v("first_submap_id", first_submap_id);
    v("queue_size", queue_size);
    v("publish_submap_cloud", publish_submap_cloud);
    v("marker_history", marker_history);
    v("marker_period_s", marker_period_s);
  }
};

/// Node-level parameters (the core's sections `matcher`, `pose`, `verification`, `database`
/// are read separately).
struct LoopClosureNodeParams {
  std::vector<std::string> robots;              ///< robots whose descriptors are subscribed
  std::string descriptor_topic = "descriptor";  ///< subscribes `<robot>/<descriptor_topic>`
  /// Subscribes `<robot>/<descriptor_update_topic>`: stored entries described again with their
  /// successors' stems (multi_submap/forward_submaps) replace their entries; empty: none.
  std::string descriptor_update_topic = "descriptor_updates";
  std::string database_file;      ///< loaded at startup when it exists
  bool publish_tf = true;         ///< TF between odometry frames of linked robots
  double tf_rate_hz = 10.0;       ///< TF re-publication rate [Hz]
  int queue_size = 100;           ///< descriptors waiting; the oldest is dropped
  std::string loop_log;           ///< CSV of every query's result; empty: none
  double marker_period_s = 2.0;   ///< latest loop's markers again (wall); 0: once [s]
  double input_timeout_s = 30.0;  ///< warn while a robot's descriptor topic is silent; 0: never [s]

  template <class V>
  void visit(V& v) {
    v("robots", robots);
    v("descriptor_topic", descriptor_topic);
    v("descriptor_update_topic", descriptor_update_topic);
    v("database_file", database_file);
    v("publish_tf", publish_tf);
    v("tf_rate_hz", tf_rate_hz);
    v("queue_size", queue_size);
    v("loop_log", loop_log);
    v("marker_period_s", marker_period_s);
    v("input_timeout_s", input_timeout_s);
  }
};

}  // namespace ros_glue
}  // namespace dtif
