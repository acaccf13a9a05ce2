// Trunks as landmarks of the merged map (issue #16): every submap observes trunks in its own
// frame; observations of one tree by different submaps (of any robot) are associated through
// the current merged poses, so that the map merger can refine the submap poses with
// submap-landmark factors. This ties together submaps that overlap without a detected loop.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <vector>

namespace dtif {

struct LandmarkAssociationParams {
  double gate_m = 0.3;            ///< horizontal distance to a landmark's centre [m]
  double open_gate_m = 0.8;       ///< ... for observations of submaps in an open stand [m]
  double radius_abs_tol_m = 0.1;  ///< |r - r_landmark| <= max(abs, rel * r_landmark) ...
  double radius_rel_tol = 0.5;    ///< ... (one submap's radius can be a few cm off)
  int min_observations = 2;       ///< landmarks seen by fewer submaps are dropped
};

/// One trunk of one submap: its base point in the submap (S) and in the map frame (M, through
/// the current pose).
struct LandmarkObservation {
  size_t submap = 0;  ///< any id; observations of one submap are consecutive
  Eigen::Vector3d p_S = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_M = Eigen::Vector3d::Zero();
  double r = 0.0;         ///< radius [m]
  bool base_seen = true;  ///< else p_S's elevation is a guess (horizontal only)
  /// Of a submap in an open stand (MergeSubmap::open_stand): associated within open_gate_m.
  bool open_stand = false;
};

/// Groups observations into landmarks (physical trees), submap by submap in the given order:
/// an observation joins the landmark whose centre (the mean of its members in M) is nearest
/// horizontally within gate_m (open_gate_m for an open stand's) with a similar radius, when that is
/// mutual (the observation is its submap's nearest to the landmark), unambiguous (no second
/// landmark within the gate) and the landmark has no observation of that submap yet; an observation
/// with no landmark within the gate starts one. Returns the landmarks with at least
/// min_observations members, each as its members' indices into `observations`. Deterministic.
std::vector<std::vector<size_t>> associateLandmarks(
    const std::vector<LandmarkObservation>& observations, const LandmarkAssociationParams& params);

}  // namespace dtif
