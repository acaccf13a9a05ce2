// Basic types shared by every part of the ROS-free core.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

namespace dtif {

/// A trunk landmark v_m = (x_m, y_m, z_m, r_m) of paper Sec. 3.B, in the submap frame S.
struct TrunkLandmark {
  double x = 0.0;  ///< horizontal centre [m]
  double y = 0.0;  ///< horizontal centre [m]
  double z = 0.0;  ///< stem base elevation (ground at the stem) [m]
  double r = 0.0;  ///< radius at breast height (1.3 m above the base) [m]
  /// The ground around the stem was observed, so `z` is a measurement. False when the base
  /// was hidden (occlusion, the sensor's lower field-of-view limit) and `z` is extrapolated
  /// terrain: such trunks still constrain yaw and x, y, but not the elevation.
  bool base_seen = true;
};
using Trunks = std::vector<TrunkLandmark>;

/// Rigid transform; T_a_b maps coordinates in frame b to frame a (p_a = T_a_b * p_b).
using Pose = Eigen::Isometry3d;

/// Yaw-only rotation about z (paper Eq. 3.1).
inline Eigen::Matrix3d rotZ(double yaw) {
  return Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

}  // namespace dtif
