// Baseline solvers of the benchmark: each recovers a known transform from correspondences
// with outliers (fixed seeds), and the loop detector runs a replacement solver.
#include "dtif/baselines/solvers.h"

#include <gtest/gtest.h>

#include <random>

#include "core/match_test_utils.h"
#include "dtif/baselines/bench.h"
#include "dtif/core/database/loop_detector.h"
#include "test_utils.h"

namespace dtif::baselines {
namespace {

struct Case {
  std::vector<Correspondence> corrs;
  Pose T_c_q;
  int inliers = 0;
};

/// n correspondences of points in a 40 m x 40 m x `height` box, T_c_q applied with 1 cm noise;
/// a share `outliers` of them get a random candidate point instead.
Case makeCase(uint32_t seed, int n, double outliers, const Pose& T, double height) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uxy(-20.0, 20.0), uz(0.0, height), u01(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.01);
  Case c;
  c.T_c_q = T;
  for (int i = 0; i < n; ++i) {
    Correspondence k;
    k.iq = k.ic = i;
    k.pq = test::randomVector(rng, uxy, uxy, uz);
    if (u01(rng) < outliers) {
      k.pc = test::randomVector(rng, uxy, uxy, uz);
    } else {
      k.pc = T * k.pq + test::randomVector(rng, noise, noise, noise);
      ++c.inliers;
    }
    c.corrs.push_back(k);
  }
  return c;
}

void expectClose(const PoseEstimate& est, const Pose& T, double max_deg, double max_m) {
  ASSERT_TRUE(est.ok);
  const Eigen::AngleAxisd d(T.linear().transpose() * est.T_c_q.linear());
  EXPECT_LT(std::fabs(d.angle()) * 180.0 / M_PI, max_deg);
  EXPECT_LT((est.T_c_q.translation() - T.translation()).norm(), max_m);
}

TEST(BaselineSolvers, QuatroLikeRecoversYawAndTranslationWithHalfOutliers) {
  const Case c = makeCase(7, 120, 0.5, test::poseXyYaw(4.0, -7.0, 0.4, 0.6), 1.0);
  const PoseEstimate est = quatroLike(c.corrs, QuatroParams{});
  expectClose(est, c.T_c_q, 0.2, 0.05);
  EXPECT_GE(static_cast<int>(est.inliers_T.size()), c.inliers - 2);
  EXPECT_LE(static_cast<int>(est.inliers_T.size()), c.inliers + 3);
}

TEST(BaselineSolvers, SvdRansacRecoversSixDofWithHalfOutliersRepeatably) {
  const Pose T = test::makePose(2.0, 3.0, -0.5, 0.02, -0.03, 2.5);
  const Case c = makeCase(11, 150, 0.5, T, 6.0);
  const PoseEstimate a = svdRansac(c.corrs, RansacParams{});
  expectClose(a, T, 0.2, 0.05);
  const PoseEstimate b = svdRansac(c.corrs, RansacParams{});
  EXPECT_TRUE(a.T_c_q.isApprox(b.T_c_q));  // fixed seed
  EXPECT_EQ(a.inliers_T, b.inliers_T);
}

TEST(BaselineSolvers, FgrRecoversSixDofWithOutliers) {
  const Pose T = test::makePose(-3.0, 1.0, 0.3, 0.01, 0.02, 0.5);
  const Case c = makeCase(3, 150, 0.3, T, 6.0);
  expectClose(fastGlobalRegistration(c.corrs, FgrParams{}), T, 0.3, 0.05);
}

TEST(BaselineSolvers, GreedyConsistentSetKeepsTheInliersOfHeavyOutliers) {
  const Pose T = test::makePose(2.0, -1.0, 0.3, 0.0, 0.0, 1.1);
  const Case c = makeCase(13, 200, 0.85, T, 4.0);
  const std::vector<int> set = greedyConsistentSet(c.corrs, 0.1);
  int good = 0;
  for (int i : set) good += (c.corrs[i].pc - T * c.corrs[i].pq).norm() < 0.1;
  EXPECT_GE(good, c.inliers - 2);
  EXPECT_LE(static_cast<int>(set.size()) - good, 2);
  // On the pruned set the Quatro-like estimator recovers T.
  std::vector<Correspondence> kept;
  for (int i : set) kept.push_back(c.corrs[i]);
  expectClose(quatroLike(kept, QuatroParams{}), T, 0.3, 0.05);
}

TEST(BaselineSolvers, TooFewCorrespondencesGiveNoPose) {
  const Case c = makeCase(5, 2, 0.0, Pose::Identity(), 1.0);
  EXPECT_FALSE(svdRansac(c.corrs, RansacParams{}).ok);
  EXPECT_FALSE(fastGlobalRegistration(c.corrs, FgrParams{}).ok);
  EXPECT_FALSE(quatroLike({}, QuatroParams{}).ok);
}

TEST(BaselineSolvers, QuatroLikeTakesElevationFromEveryPairUnlikeDtif) {
  // 60 % of the pairs have an unseen stem base 1.5 m off: dtif uses only the seen bases, the
  // Quatro-like estimator votes with every pair, so the wrong elevation mode wins.
  Case c = makeCase(9, 80, 0.0, test::poseXyYaw(1.0, 2.0, 0.2, 0.3), 0.5);
  for (size_t i = 0; i < c.corrs.size(); ++i) {
    if (i % 5 >= 3) continue;
    c.corrs[i].pc.z() += 1.5;
    c.corrs[i].z_ok = false;
  }
  const PoseEstimate d = estimatePose(c.corrs, PoseEstimatorParams{});
  const PoseEstimate q = quatroLike(c.corrs, QuatroParams{});
  ASSERT_TRUE(d.ok && q.ok);
  EXPECT_NEAR(d.T_c_q.translation().z(), 0.2, 0.02);
  EXPECT_GT(std::fabs(q.T_c_q.translation().z() - 0.2), 0.2);
}

TEST(BaselineSolvers, LoopDetectorRunsTheReplacementSolverAndKeepsItsHypothesis) {
  std::mt19937 rng(17);
  const Trunks world = test::randomStand(rng, 80, 80, 600);
  const Pose T_w_c = test::poseXyYaw(40, 40, 0, 0.4), T_w_q = test::poseXyYaw(46, 43, 0, -1.2);
  Descriptor c = buildDescriptor(test::observe(rng, world, {40, 40}, T_w_c), DescriptorParams{});
  Descriptor q = buildDescriptor(test::observe(rng, world, {46, 43}, T_w_q), DescriptorParams{});
  c.robot = "a";
  q.robot = "b";
  ASSERT_TRUE(c.valid && q.valid);
  for (const std::string name : {"quatro", "svd_ransac", "fgr"}) {
    SCOPED_TRACE(name);
    LoopDetector det{LoopDetectorParams{}};
    int calls = 0;
    const PoseSolver inner = makeBackEnd(name, PoseEstimatorParams{});
    det.setSolver([&](const std::vector<Correspondence>& k) {
      ++calls;
      return inner(k);
    });
    det.insert(std::make_shared<Descriptor>(c));
    const auto lc = det.query(q);
    EXPECT_GT(calls, 0);
    ASSERT_TRUE(lc.has_value());
    const Pose T_gt = T_w_c.inverse() * T_w_q;
    EXPECT_LT(test::yawError(lc->T_hypothesis, T_gt) * 180.0 / M_PI, 2.0);
    EXPECT_LT(test::yawError(lc->T_c_q, T_gt) * 180.0 / M_PI, 0.5);
  }
  EXPECT_THROW(makeBackEnd("teaser", PoseEstimatorParams{}), std::invalid_argument);
  EXPECT_FALSE(makeBackEnd("dtif", PoseEstimatorParams{}));
}

}  // namespace
}  // namespace dtif::baselines
