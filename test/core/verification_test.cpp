// False-loop verification: guided refinement, footprint overlap and the rejection reasons.
#include "dtif/core/verification/verification.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>
#include <set>
#include <string>

#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_detector.h"

namespace dtif {
namespace {

using test::describe;
using test::hypothesis;
using test::observe;
using test::overlappingPairs;
using test::PairCase;
using test::poseXyYaw;

/// Footprints: a correct alignment of submaps sharing 20 % of their cells is no loop by
/// DATASET.md (threshold 0.3), one sharing 60 % is.
TEST(Verification, RejectsCorrectAlignmentsOfBarelyOverlappingSubmaps) {
  const LoopDetectorParams params;
  const std::vector<PairCase> cases = overlappingPairs(12, 31);
  int checked = 0;
  for (const PairCase& base : cases) {
    PairCase pc = base;
    std::vector<std::pair<int64_t, int64_t>> c_cells;
    for (int64_t y = -15; y < 15; ++y)
      for (int64_t x = -15; x < 15; ++x) c_cells.emplace_back(x, y);
    pc.c.footprint = makeFootprint(c_cells, 1.0);
    // The query saw the same 30 m square shifted along the candidate's x by `shift`.
    auto queryFootprint = [&](double shift) {
      std::vector<std::pair<int64_t, int64_t>> cells;
      const Pose T_q_c = pc.T_c_q.inverse();
      for (int64_t y = -15; y < 15; ++y) {
        for (int64_t x = -15; x < 15; ++x) {
          const Eigen::Vector3d p = T_q_c * Eigen::Vector3d(x + 0.5 + shift, y + 0.5, 0.0);
          cells.emplace_back(static_cast<int64_t>(std::floor(p.x())),
                             static_cast<int64_t>(std::floor(p.y())));
        }
      }
      return makeFootprint(cells, 1.0);
    };
    pc.q.footprint = Footprint{};
    if (!matchPair(pc.q, pc.c, params)) continue;  // only pairs that match without footprints
    ++checked;
    pc.q.footprint = queryFootprint(12.0);
    Verification ver;
    const auto good = matchPair(pc.q, pc.c, params, nullptr, &ver);
    EXPECT_TRUE(good.has_value()) << ver.reason();
    EXPECT_NEAR(ver.overlap, 0.6, 0.05);
    pc.q.footprint = queryFootprint(24.0);
    const auto small = matchPair(pc.q, pc.c, params, nullptr, &ver);
    EXPECT_FALSE(small.has_value());
    EXPECT_EQ(ver.rejection, Rejection::kSmallOverlap);
    EXPECT_EQ(ver.reason(), "small overlap");
    EXPECT_NEAR(ver.overlap, 0.2, 0.05);
  }
  EXPECT_GE(checked, 10);
}

/// A rough hypothesis (1.5 deg of yaw off about the overlap) of wide submaps: its correction
/// moves query trunks 25 m out by 0.65 m, more than match_radius_m, but the paired trunks near the
/// overlap by a few cm; that is no jump onto other trunks, and the loop is kept.
TEST(Verification, RefinementMayCorrectTheYawOfAWideSubmap) {
  std::mt19937 rng(77);
  test::ObservationNoise wide;
  wide.radius_m = 25.0;
  int accepted = 0;
  const int n = 5;
  for (int i = 0; i < n; ++i) {
    const Trunks world = test::randomStand(rng, 120, 120, 500);
    const Pose T_w_c = poseXyYaw(60.0, 60.0, 0.0, 0.3 * i);
    const Pose T_w_q = poseXyYaw(66.0, 58.0, 0.0, 1.0 + 0.3 * i);
    const Descriptor c = describe(observe(rng, world, {60.0, 60.0}, T_w_c, wide), "b", 1);
    const Descriptor q = describe(observe(rng, world, {66.0, 58.0}, T_w_q, wide), "a", 0);
    const Pose T_true = T_w_c.inverse() * T_w_q;
    // 1.5 deg about the query's origin, inside the overlap.
    const Pose T_rough = T_true * poseXyYaw(0.0, 0.0, 0.0, 1.5 * M_PI / 180.0);
    std::vector<Correspondence> corrs;
    const PoseEstimate est = hypothesis(T_rough, false, &corrs);  // no lattice refit
    const Verification v = verifyLoop(q, c, corrs, est, VerifierParams{});
    EXPECT_EQ(v.fit_ambiguity, -1.0);
    if (!v.accepted) {
      std::printf("[ info ] wide pair %d rejected: %s\n", i, v.reason().c_str());
      continue;
    }
    ++accepted;
    EXPECT_LT(test::yawError(v.T_c_q, T_true), 0.2 * M_PI / 180.0) << "pair " << i;
    EXPECT_LT((v.T_c_q.translation() - T_true.translation()).head<2>().norm(), 0.1) << "pair " << i;
  }
  EXPECT_EQ(accepted, n);
}

/// Every rejection has its own text (misses.csv's outcome column and the logs tell them apart);
/// the texts are the ones those files have always carried.
TEST(Verification, RejectionTextsAreDistinctAndNonEmpty) {
  std::set<std::string> texts;
  const int last = static_cast<int>(Rejection::kFewVotedPairs);
  for (int i = 0; i <= last; ++i) {
    const std::string t = toString(static_cast<Rejection>(i));
    EXPECT_FALSE(t.empty()) << i;
    EXPECT_TRUE(texts.insert(t).second) << "duplicate text " << t;
  }
  EXPECT_EQ(texts.size(), static_cast<size_t>(last + 1));
  EXPECT_STREQ(toString(Rejection::kFewCorrespondences), "few correspondences");
  EXPECT_STREQ(toString(Rejection::kElevationUnobserved), "elevation unobserved");
  EXPECT_STREQ(toString(Rejection::kElevationAmbiguous), "elevation ambiguous");
  EXPECT_STREQ(toString(Rejection::kFewCovisible), "few co-visible trunks");
  EXPECT_STREQ(toString(Rejection::kAmbiguousVotes), "ambiguous votes");
}

/// Only the four "no hypothesis at all" reasons send a pair to the vote fallback.
TEST(Verification, NoHypothesisReasons) {
  const std::set<Rejection> no_hypothesis = {Rejection::kFewCorrespondences, Rejection::kNoPose,
                                             Rejection::kFewHypothesisInliers,
                                             Rejection::kLowInlierWeight};
  for (int i = 0; i <= static_cast<int>(Rejection::kFewVotedPairs); ++i) {
    const Rejection r = static_cast<Rejection>(i);
    EXPECT_EQ(isNoHypothesis(r), no_hypothesis.count(r) > 0) << toString(r);
  }
}

/// reason(): empty when accepted, the rejection's text, and after a failed vote fallback both.
TEST(Verification, ReasonJoinsTheTrianglesAndTheVotes) {
  Verification v;
  EXPECT_EQ(v.reason(), "");
  v.rejection = Rejection::kSmallOverlap;
  EXPECT_EQ(v.reason(), "small overlap");
  v.rejection = Rejection::kFewHypothesisInliers;
  v.vote_rejection = Rejection::kAmbiguousVotes;
  EXPECT_EQ(v.reason(), "few hypothesis inliers; votes: ambiguous votes");
}

/// The solver's hypothesis alone decides the first rejections, in this order.
TEST(Verification, RejectsWeakHypotheses) {
  const std::vector<PairCase> cases = overlappingPairs(1, 7);
  const Descriptor& q = cases[0].q;
  const Descriptor& c = cases[0].c;
  std::vector<Correspondence> corrs;
  PoseEstimate est = hypothesis(cases[0].T_c_q, false, &corrs);
  const VerifierParams params;
  EXPECT_TRUE(verifyLoop(q, c, corrs, est, params).accepted);
  PoseEstimate e = est;
  e.inlier_weight = params.min_inlier_weight - 1.0;
  EXPECT_EQ(verifyLoop(q, c, corrs, e, params).rejection, Rejection::kLowInlierWeight);
  e.inliers_T.resize(params.min_hypothesis_inliers - 1);
  EXPECT_EQ(verifyLoop(q, c, corrs, e, params).rejection, Rejection::kFewHypothesisInliers);
  e.ok = false;
  const Verification v = verifyLoop(q, c, corrs, e, params);
  EXPECT_FALSE(v.accepted);
  EXPECT_EQ(v.rejection, Rejection::kNoPose);
  EXPECT_EQ(v.reason(), "no pose");
}

// Open stands: a loop between accumulated descriptors carries the odometry's drift of their
// neighbours' stems; the two submaps' own trunks, paired under its pose, pull yaw and x/y back to
// what the submaps themselves saw. Roll, pitch and t_z stay; too few own pairs leave the pose.
TEST(Verification, OwnTrunksRefitTheLoopOfAccumulatedDescriptors) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-12.0, 12.0);
  const Pose tilt(Eigen::AngleAxisd(0.004, Eigen::Vector3d::UnitX()));
  const Pose expected = poseXyYaw(5.0, -3.0, 0.3, 0.4) * tilt;  // T_c_q: a small residual tilt
  Descriptor q, c;
  q.accumulated = c.accumulated = true;
  for (int k = 0; k < 9; ++k) {  // 5 stems both saw (k < 5), 2 one-off fits on either side
    const Eigen::Vector3d p_c(u(rng), u(rng), 0.0);
    if (k < 5 || k >= 7) c.own_trunks.push_back(TrunkLandmark{p_c.x(), p_c.y(), p_c.z(), 0.2});
    const Eigen::Vector3d p_q = expected.inverse() * p_c;
    if (k < 7) q.own_trunks.push_back(TrunkLandmark{p_q.x(), p_q.y(), p_q.z(), 0.2});
  }
  // The loop's pose as the accumulated stems gave it: 0.25 m and 0.4 deg off in the plane.
  const Pose drifted = poseXyYaw(0.25, -0.15, 0.0, 0.4 * M_PI / 180.0) * expected;
  VerifierParams params;
  Verification v;
  v.T_c_q = drifted;
  ASSERT_TRUE(refineOnOwnTrunks(q, c, params, &v));
  EXPECT_LT((v.T_c_q.translation() - expected.translation()).head<2>().norm(), 1e-6);
  EXPECT_NEAR(v.T_c_q.translation().z(), drifted.translation().z(), 1e-9);
  // The tilt (the query's z in c) is the one the loop had; the yaw is the truth's.
  const Eigen::Vector3d z = Eigen::Vector3d::UnitZ();
  EXPECT_NEAR(std::acos((v.T_c_q.linear() * z).dot(z)), std::acos((drifted.linear() * z).dot(z)),
              1e-9);
  const Eigen::Vector3d x_c = v.T_c_q.linear() * Eigen::Vector3d::UnitX();
  const Eigen::Vector3d x_e = expected.linear() * Eigen::Vector3d::UnitX();
  EXPECT_LT((x_c - x_e).norm(), 1e-6);

  // Neither side accumulated, the stage off, or fewer own pairs than own_min_pairs: unchanged.
  Descriptor q_own = q, c_own = c;
  q_own.accumulated = c_own.accumulated = false;
  q_own.trunks = q.own_trunks, c_own.trunks = c.own_trunks;
  v.T_c_q = drifted;
  EXPECT_FALSE(refineOnOwnTrunks(q_own, c_own, params, &v));
  EXPECT_TRUE(v.T_c_q.isApprox(drifted));
  VerifierParams off = params;
  off.own_match_radius_m = 0.0;
  EXPECT_FALSE(refineOnOwnTrunks(q, c, off, &v));
  VerifierParams many = params;
  many.own_min_pairs = 6;  // 5 stems in common
  EXPECT_FALSE(refineOnOwnTrunks(q, c, many, &v));
  EXPECT_TRUE(v.T_c_q.isApprox(drifted));
  // One side accumulated is enough (its stems carry the drift into the loop).
  q.accumulated = false;
  q.trunks = q.own_trunks;
  q.own_trunks.clear();
  EXPECT_TRUE(refineOnOwnTrunks(q, c, params, &v));
  EXPECT_LT((v.T_c_q.translation() - expected.translation()).head<2>().norm(), 1e-6);
  many.own_min_pairs = 1;
  EXPECT_NE(many.validate().find("own_min_pairs"), std::string::npos);
}

}  // namespace
}  // namespace dtif
