// Which map frame (map, map_1, ...) each robot is published in: one frame per connected
// component of the merged graph, kept stable as components grow and join. ROS-free so it is
// tested without a master; MapMergeNodelet logs every change it reports.
#pragma once

#include <map>
#include <set>
#include <string>
#include <vector>

namespace dtif {
namespace ros_glue {

class MapFrames {
 public:
  /// A robot whose frame changed: from "" when it is new.
  struct Change {
    std::string robot;
    std::string from;
    std::string to;
  };

  explicit MapFrames(std::string base = "map") : base_(std::move(base)) {}

  /// Assigns a frame to every component (sets of robot names). A component keeps the lowest
  /// frame (map < map_1 < ...) any of its robots held, unless a larger component took it first
  /// (components are served largest first, ties by their lowest robot name); the others get
  /// the lowest free frame. Returns the robots whose frame changed, sorted by robot.
  std::vector<Change> assign(const std::vector<std::set<std::string>>& components);

  /// The robot's frame, or "" when it has none.
  std::string frameOf(const std::string& robot) const;
  const std::map<std::string, std::string>& frames() const { return frame_of_; }

  /// Frame name of index k: base for 0, base_k otherwise.
  std::string name(int k) const { return k == 0 ? base_ : base_ + "_" + std::to_string(k); }

 private:
  std::string base_;
  std::map<std::string, int> index_of_;  // robot -> frame index
  std::map<std::string, std::string> frame_of_;
};

}  // namespace ros_glue
}  // namespace dtif
