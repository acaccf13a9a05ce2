#include "dtif/core/pose/pose_estimator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "core/match_test_utils.h"

namespace dtif {
namespace {

/// n correspondences of which a share are outliers (random candidate points); inliers follow
/// T_c_q with Gaussian noise. Trunk indices are unique so no TIM is skipped.
std::vector<Correspondence> makeCorrs(std::mt19937& rng, const Pose& T_c_q, int n,
                                      double outlier_ratio, double noise,
                                      const Eigen::Vector3d& offset = Eigen::Vector3d::Zero()) {
  std::uniform_real_distribution<double> u(-15.0, 15.0), uz(-0.5, 0.5), uw(1.0, 2.5);
  std::normal_distribution<double> nn(0.0, noise);
  std::vector<Correspondence> out;
  const int n_out = static_cast<int>(std::round(outlier_ratio * n));
  for (int i = 0; i < n; ++i) {
    Correspondence c;
    c.iq = i;
    c.ic = i;
    c.pq = offset + Eigen::Vector3d(u(rng), u(rng), uz(rng));
    if (i < n_out) {
      c.pc = T_c_q * offset + Eigen::Vector3d(u(rng), u(rng), uz(rng));
    } else {
      c.pc = T_c_q * c.pq + Eigen::Vector3d(nn(rng), nn(rng), nn(rng));
    }
    c.w = uw(rng);
    out.push_back(c);
  }
  std::shuffle(out.begin(), out.end(), rng);
  return out;
}

void expectPose(const PoseEstimate& e, const Pose& T, double rot_deg, double t_m) {
  ASSERT_TRUE(e.ok);
  EXPECT_LT(test::yawError(e.T_c_q, T) * 180.0 / M_PI, rot_deg);
  EXPECT_LT((e.T_c_q.translation() - T.translation()).norm(), t_m)
      << e.T_c_q.translation().transpose() << " vs " << T.translation().transpose();
}

TEST(PoseEstimator, ExactInliersRecoveredExactly) {
  std::mt19937 rng(1);
  const Pose T = test::poseXyYaw(3.0, -7.5, 0.8, 0.6);
  const auto corrs = makeCorrs(rng, T, 30, 0.0, 0.0);
  const PoseEstimate e = estimatePose(corrs, PoseEstimatorParams{});
  expectPose(e, T, 1e-6, 1e-6);
  EXPECT_EQ(e.inliers_T.size(), 30u);
  EXPECT_NEAR(e.yaw_rad, 0.6, 1e-9);
}

TEST(PoseEstimator, HalfOutliersWithNoise) {
  std::mt19937 rng(2);
  for (double yaw : {0.3, -1.2, 2.9, M_PI}) {
    const Pose T = test::poseXyYaw(-12.0, 4.0, -1.5, yaw);
    const auto corrs = makeCorrs(rng, T, 60, 0.5, 0.03);
    const PoseEstimate e = estimatePose(corrs, PoseEstimatorParams{});
    expectPose(e, T, 0.3, 0.05);
    // The inliers are the 30 true ones (an outlier may land within beta by chance).
    int true_in = 0;
    for (int k : e.inliers_T) true_in += (corrs[k].pc - T * corrs[k].pq).norm() < 0.2;
    EXPECT_GE(true_in, 28);
    EXPECT_LE(static_cast<int>(e.inliers_T.size()) - true_in, 1);
    EXPECT_NEAR(e.T_c_q.translation().z(), -1.5, 0.05);
  }
}

TEST(PoseEstimator, HeavyOutliers80Percent) {
  std::mt19937 rng(3);
  const Pose T = test::poseXyYaw(1.0, 2.0, 0.0, -2.2);
  const auto corrs = makeCorrs(rng, T, 100, 0.8, 0.02);
  expectPose(estimatePose(corrs, PoseEstimatorParams{}), T, 0.3, 0.05);
}

TEST(PoseEstimator, Rotation180AndHugeCoordinates) {
  std::mt19937 rng(4);
  const Pose T = test::poseXyYaw(5.0, -3.0, 2.0, M_PI);
  const auto corrs = makeCorrs(rng, T, 40, 0.3, 0.02, Eigen::Vector3d(1e5, -1e5, 250.0));
  const PoseEstimate e = estimatePose(corrs, PoseEstimatorParams{});
  ASSERT_TRUE(e.ok);
  EXPECT_LT(test::yawError(e.T_c_q, T) * 180.0 / M_PI, 0.3);
  // Check the effect on the points, not the raw translation (which is ~2e5 m here).
  for (int k : e.inliers_T) EXPECT_LT((e.T_c_q * corrs[k].pq - corrs[k].pc).norm(), 0.15);
  EXPECT_GE(e.inliers_T.size(), 25u);
}

TEST(PoseEstimator, UnitWeightsSwitchChangesTheWinner) {
  // Two consistent groups with different poses: 6 heavy (w = 6) vs 9 light (w = 1).
  // Weighted TIM consensus: 15 pairs x 6 = 90 > 36 x 1. Unit weights: 15 < 36.
  std::mt19937 rng(5);
  const Pose A = test::poseXyYaw(0, 0, 0, 0.5), B = test::poseXyYaw(8, -3, 0, -1.4);
  std::vector<Correspondence> corrs;
  std::uniform_real_distribution<double> u(-15.0, 15.0);
  for (int i = 0; i < 15; ++i) {
    Correspondence c;
    c.iq = c.ic = i;
    c.pq = Eigen::Vector3d(u(rng), u(rng), 0.0);
    c.pc = (i < 6 ? A : B) * c.pq;
    c.w = i < 6 ? 6.0 : 1.0;
    corrs.push_back(c);
  }
  PoseEstimatorParams p;
  expectPose(estimatePose(corrs, p), A, 1e-6, 1e-6);
  p.unit_weights = true;
  const PoseEstimate e = estimatePose(corrs, p);
  expectPose(e, B, 1e-6, 1e-6);
  EXPECT_DOUBLE_EQ(e.inlier_weight, 9.0);  // unit weights
}

TEST(PoseEstimator, DegenerateInputs) {
  EXPECT_FALSE(estimatePose({}, PoseEstimatorParams{}).ok);
  Correspondence c;
  c.iq = c.ic = 0;
  EXPECT_FALSE(estimatePose({c}, PoseEstimatorParams{}).ok);
  // Two correspondences of the same query trunk carry no rotation information.
  Correspondence d = c;
  d.ic = 1;
  d.pc = Eigen::Vector3d(1, 0, 0);
  EXPECT_FALSE(estimatePose({c, d}, PoseEstimatorParams{}).ok);
}

TEST(PoseEstimator, DeterministicAndSubsampled) {
  std::mt19937 rng(6);
  const Pose T = test::poseXyYaw(2, 2, 0, 1.0);
  const auto corrs = makeCorrs(rng, T, 300, 0.6, 0.03);  // 44,850 pairs
  PoseEstimatorParams p;
  p.max_tim_pairs = 5000;
  const PoseEstimate a = estimatePose(corrs, p), b = estimatePose(corrs, p);
  ASSERT_TRUE(a.ok);
  EXPECT_EQ(a.yaw_rad, b.yaw_rad);
  EXPECT_EQ(a.inliers_T, b.inliers_T);
  expectPose(a, T, 0.3, 0.05);
}

TEST(PoseEstimator, ParamsValidate) {
  EXPECT_EQ(PoseEstimatorParams{}.validate(), "");
  PoseEstimatorParams p;
  p.beta_yaw_m = 0;
  EXPECT_NE(p.validate(), "");
  p = PoseEstimatorParams{};
  p.max_tim_pairs = 0;
  EXPECT_NE(p.validate(), "");
}

}  // namespace
}  // namespace dtif
