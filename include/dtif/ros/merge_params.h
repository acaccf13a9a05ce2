// Node-level parameters of dtif/MapMergeNodelet (the core's sections `merge` and `stems`,
// config/merge.yaml, are read separately into the core's own structs). Declared here so tests can
// check the shipped YAML against them.
#pragma once

#include <string>
#include <vector>

namespace dtif {
namespace ros_glue {

struct MapMergeNodeParams {
  std::vector<std::string> robots;              ///< robots whose descriptors are subscribed
  std::string descriptor_topic = "descriptor";  ///< subscribes `<robot>/<descriptor_topic>`
  std::string cloud_topic = "/submap_cloud";  ///< absolute: one for all robots; relative: per robot
  std::string loop_topic = "loop_closures";   ///< accepted loops of the loop-closure nodelet
  std::string map_frame = "map";              ///< first map frame; others `<map_frame>_<k>`
  std::string database_file;                  ///< old run's submaps loaded at start, if any
  std::string stem_map_file;    ///< field stem map CSV (x,y[,dbh]) anchoring `map`, if any
  std::string stem_map_plot;    ///< its plot_id column's value to use ("": every row)
  double solve_period_s = 1.0;  ///< re-solve at most this often (wall) [s]
  double tf_rate_hz = 10.0;     ///< map -> odometry TF re-publication [Hz]
  double cloud_voxel_m = 0.2;   ///< voxel of stored submap clouds [m]
  int queue_size = 1000;        ///< messages waiting; the oldest is dropped

  template <class V>
  void visit(V& v) {
    v("robots", robots);
    v("descriptor_topic", descriptor_topic);
    v("cloud_topic", cloud_topic);
    v("loop_topic", loop_topic);
    v("map_frame", map_frame);
    v("database_file", database_file);
    v("stem_map_file", stem_map_file);
    v("stem_map_plot", stem_map_plot);
    v("solve_period_s", solve_period_s);
    v("tf_rate_hz", tf_rate_hz);
    v("cloud_voxel_m", cloud_voxel_m);
    v("queue_size", queue_size);
  }
};

}  // namespace ros_glue
}  // namespace dtif
