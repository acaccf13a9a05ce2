// The map merger's state (private to src/core/merge): every robot's submap chain, the loops
// between submaps grouped by robot pair, and what the last solve made of them. MapMerger
// (map_merger.cpp) owns one and runs the pieces declared below, one file per concern. Not
// thread-safe: the pieces read and write it in turn.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <map>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "dtif/core/merge/merge_types.h"
#include "dtif/core/merge/pcm.h"

namespace dtif {

using Vector6d = Eigen::Matrix<double, 6, 1>;

inline double rotationAngle(const Eigen::Matrix3d& R) { return Eigen::AngleAxisd(R).angle(); }

struct MergeGraph {
  struct Node {
    int64_t id = -1;
    std::string robot;
    double stamp = 0.0;
    Pose T_O_S = Pose::Identity();
    Trunks trunks;
    bool open_stand = false;  // MergeSubmap::open_stand
    double travelled = 0.0;   // along the robot's chain from its first submap [m]
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();  // estimate of T_M_S
    Eigen::Vector3d t = Eigen::Vector3d::Zero();
    Pose pose() const {
      Pose T = Pose::Identity();
      T.linear() = q.toRotationMatrix();
      T.translation() = t;
      return T;
    }
    void setPose(const Pose& T) {
      q = Eigen::Quaterniond(T.rotation()).normalized();
      t = T.translation();
    }
  };
  struct Robot {
    std::vector<size_t> nodes;
    Eigen::Matrix3d R_L_O = Eigen::Matrix3d::Identity();
    int component = -1;
    int64_t frame = -1;  // anchor submap id whose M the estimates are in (-1: none yet)
    size_t order = 0;    // insertion order
  };
  /// A loop normalised to (a, b) with a on the group's first robot: T_a_b.
  struct LoopRec {
    Loop loop;
    size_t a = 0, b = 0;
    Pose T_a_b = Pose::Identity();
    Vector6d sigmas = Vector6d::Ones();
    bool used = true;
    double residual_sigmas = 0.0;
  };
  struct Group {
    std::vector<size_t> loops;
    ConsistencyGraph adjacency;
  };

  MergeParams p;
  std::vector<Node> nodes;
  std::unordered_map<int64_t, size_t> index;
  std::map<std::string, Robot> robots;
  std::vector<LoopRec> loops;
  std::map<std::pair<std::string, std::string>, Group> groups;
  std::vector<MergeEvent> events;
  std::vector<FieldStem> field;
  StemMapRegistration registration;
  std::vector<MergedStem> stems;
  bool dirty = true;
  bool refined = false;  // the landmark refinement ran on the current graph

  explicit MergeGraph(const MergeParams& params) : p(params) {}

  // Noise models (merge_graph.cpp).
  Vector6d odomSigmas(double d) const;
  /// The loop's sigmas, floored; open_stand: a submap of the loop is in an open stand.
  Vector6d loopSigmas(const Matrix6d& cov, bool open_stand) const;
  Pose odom(size_t from, size_t to) const { return nodes[from].T_O_S.inverse() * nodes[to].T_O_S; }

  /// Robots with submaps, in insertion order.
  std::vector<std::string> robotOrder() const;
  int countComponents() const;
  /// From a component's M to the output frame: the field stem map's P for component 0 when
  /// registered, else M itself.
  Pose outputTransform(int component) const {
    return component == 0 && registration.ok ? registration.T_P_M : Pose::Identity();
  }
};

// Loop consistency, PCM (merge_consistency.cpp).
/// Adds loop `loop_index` to its robot pair's group, checking it against the group's loops.
void addToGroup(MergeGraph& m, size_t loop_index);
/// Marks each loop used or rejected.
void runPcm(MergeGraph& m);

// Components (merge_components.cpp).
/// Numbers the components of robots joined by used loops, expresses each in its anchor's M and
/// appends an event for every robot that changed component or frame.
void updateComponents(MergeGraph& m);

// The Ceres solve (merge_solve.cpp, the only file of the merger that includes Ceres).
MergeSolveStats solveGraph(MergeGraph& m);
/// landmark_rounds rounds of associating trunks and solving with them as landmarks.
void refineWithLandmarks(MergeGraph& m, MergeSolveStats* st);
/// Each loop's residual in sigmas under the current poses.
void updateLoopResiduals(MergeGraph& m);

// Stem inventory and joins (merge_inventory.cpp).
/// Loops that join components to component 0 by registering their stem inventories (appends
/// one event per loop).
std::vector<Loop> inventoryJoins(MergeGraph& m);
/// Registers the field stem map (if any) and fuses the merged inventory.
void buildInventory(MergeGraph& m);

}  // namespace dtif
