// The links between robots' odometry frames that accepted inter-robot loops establish, and a
// spanning tree of them to publish (TF allows one parent per frame).
#pragma once

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "dtif/core/types.h"

namespace dtif {

/// Undirected graph of odometry frames; each edge holds the latest estimate between its two
/// frames. Not thread-safe: the owner serialises add() and spanningTree() (the loop-closure
/// nodelet holds its database mutex for both). Copyable value type.
class RobotLinks {
 public:
  /// One tree edge: T_parent_child maps child-frame coordinates into the parent frame.
  struct Edge {
    std::string parent;
    std::string child;
    Pose T_parent_child = Pose::Identity();
  };

  /// Links frame_a and frame_b by T_a_b (the latest estimate wins): replaces an earlier link
  /// between them in either direction. A frame linked to itself is ignored.
  void add(const std::string& frame_a, const std::string& frame_b, const Pose& T_a_b);

  /// A spanning forest of the links: each connected group of frames hangs from its frame that
  /// sorts first and is walked breadth first, a frame's neighbours taken in the sorted order of
  /// their (a, b) link keys. Parents precede children. Deterministic: the same links give the
  /// same edges in the same order, whatever order they were added in.
  std::vector<Edge> spanningTree() const;

  bool empty() const { return links_.empty(); }
  size_t size() const { return links_.size(); }  ///< links (undirected)

 private:
  std::map<std::pair<std::string, std::string>, Pose> links_;  // (a, b) -> T_a_b
};

}  // namespace dtif
