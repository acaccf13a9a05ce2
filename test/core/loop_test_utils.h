// Shared cases of the loop detector, verification, elevation and lattice tests: overlapping
// submap pairs of random stands and hand-made pose hypotheses. Fixed seeds everywhere.
#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <vector>

#include "core/match_test_utils.h"
#include "dtif/core/matching/matcher.h"
#include "dtif/core/pose/pose_estimator.h"

namespace dtif::test {

/// Overlapping submap pairs of random stands (400-800 stems/ha): candidate at a random place
/// and heading, query 4-12 m away with any heading (including ~180 deg).
inline std::vector<PairCase> overlappingPairs(int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<PairCase> out;
  std::uniform_real_distribution<double> dens(400, 800), yaw(-M_PI, M_PI), off(4.0, 12.0),
      pos(30.0, 70.0), dz(-2.0, 2.0);
  for (int i = 0; i < n; ++i) {
    const Trunks world = test::randomStand(rng, 100, 100, dens(rng));
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const double cy = pos(rng);
    const Eigen::Vector2d cc(pos(rng), cy);
    const double a = yaw(rng), d = off(rng);
    const Eigen::Vector2d qc = cc + d * Eigen::Vector2d(std::cos(a), std::sin(a));
    const double yaw_c = yaw(rng);
    const Pose T_w_c = poseXyYaw(cc.x() + 3.0, cc.y() - 2.0, dz(rng), yaw_c);
    const double yaw_q = yaw(rng);
    const Pose T_w_q = poseXyYaw(qc.x() - 1.0, qc.y() + 4.0, dz(rng), yaw_q);
    PairCase pc;
    pc.c = describe(observe(rng, world, cc, T_w_c), "a", 2 * i, 0.0);
    pc.q = describe(observe(rng, world, qc, T_w_q), "b", 2 * i + 1, 0.0);
    pc.T_c_q = T_w_c.inverse() * T_w_q;
    out.push_back(pc);
  }
  return out;
}

inline double rotationErrorDeg(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180.0 / M_PI;
}

inline Pose tilted(const Pose& T, double roll_deg, double pitch_deg) {
  Pose out = T;
  out.linear() =
      T.linear() * (Eigen::AngleAxisd(roll_deg * M_PI / 180.0, Eigen::Vector3d::UnitX()) *
                    Eigen::AngleAxisd(pitch_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()))
                       .toRotationMatrix();
  return out;
}

/// A pose estimate `T` as the solver would give it from 6 correspondences of weight 2 (filled
/// into *corrs, which verifyLoop reads for the score), unambiguous or with an equal runner-up
/// in yaw and translation (a lattice).
inline PoseEstimate hypothesis(const Pose& T, bool ambiguous, std::vector<Correspondence>* corrs) {
  corrs->assign(6, Correspondence{});
  PoseEstimate est;
  est.ok = true;
  est.T_c_q = T;
  for (int k = 0; k < 6; ++k) {
    (*corrs)[k].iq = k, (*corrs)[k].ic = k, (*corrs)[k].w = 2.0;
    est.inliers_R.push_back(k);
    est.inliers_T.push_back(k);
  }
  est.inlier_weight = 12.0;
  est.yaw_consensus = est.translation_consensus = 1.0;
  if (ambiguous) est.yaw_runner_up = est.translation_runner_up = 1.0;
  return est;
}

}  // namespace dtif::test
