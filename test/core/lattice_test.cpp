// Repetitive stands (plantation grids): the lattice search resolves ambiguous hypotheses by
// fitting every lattice-consistent pose to all trunks, and rejects different places.
#include "dtif/core/verification/lattice.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>
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

/// Overlapping places (3-8 m apart, any headings) of a jittered 3 m plantation, n pairs; every
/// `bad_every`-th query trunk centre is moved 0.3 m (0: none). Counts the accepted loops, the
/// wrong ones (> 0.3 deg or 0.15 m) and those resolved by the lattice fit.
struct PlantationTrial {
  int accepted = 0, wrong = 0, resolved = 0;
};
PlantationTrial plantationTrial(const LoopDetectorParams& params, uint32_t seed, int n,
                                size_t bad_every) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI), off(3.0, 8.0), pos(40, 140);
  PlantationTrial out;
  for (int i = 0; i < n; ++i) {
    const Trunks world = test::plantation(rng, 180, 180, 3.0, 0.15);
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const double by = pos(rng);
    const Eigen::Vector2d b(pos(rng), by);
    const double a = yaw(rng);
    const Eigen::Vector2d qc = b + off(rng) * Eigen::Vector2d(std::cos(a), std::sin(a));
    const Pose T_w_c = poseXyYaw(b.x(), b.y(), 0.0, yaw(rng));
    const Pose T_w_q = poseXyYaw(qc.x(), qc.y(), 0.0, yaw(rng));
    const Descriptor c = describe(observe(rng, world, b, T_w_c), "b", 1, 0.0);
    Trunks tq = observe(rng, world, qc, T_w_q);
    for (size_t k = 0; bad_every > 0 && k < tq.size(); k += bad_every) {
      const double dir = yaw(rng);
      tq[k].x += 0.3 * std::cos(dir);
      tq[k].y += 0.3 * std::sin(dir);
    }
    const Descriptor q = describe(tq, "a", 0, 0.0);
    Verification ver;
    const auto lc = matchPair(q, c, params, nullptr, &ver);
    if (!lc) continue;
    ++out.accepted;
    out.resolved += ver.fit_ambiguity >= 0.0;
    const Pose T_c_q = T_w_c.inverse() * T_w_q;
    if (test::yawError(lc->T_c_q, T_c_q) > 0.3 * M_PI / 180.0 ||
        (lc->T_c_q.translation() - T_c_q.translation()).head<2>().norm() > 0.15) {
      ++out.wrong;
    }
  }
  return out;
}

/// The same places of a jittered plantation: the correspondences cannot tell the lattice sites
/// apart (ambiguous), the fit of all trunks can. max_fit_ambiguity = 0 is the control.
TEST(Lattice, ResolvesOverlappingPairsOfAPlantationGridByFit) {
  for (const double max_fit : {0.7, 0.0}) {
    LoopDetectorParams params;
    params.verification.max_fit_ambiguity = max_fit;
    const int n = 30;
    const PlantationTrial t = plantationTrial(params, 123, n, 0);
    std::printf(
        "[ info ] plantation, max_fit_ambiguity %.1f: accepted %d/%d (%d resolved by fit)\n",
        max_fit, t.accepted, n, t.resolved);
    EXPECT_EQ(t.wrong, 0);
    if (max_fit > 0.0) {
      EXPECT_GE(t.accepted, 2 * n / 3);
      EXPECT_GE(t.resolved, n / 3);
    } else {
      EXPECT_EQ(t.resolved, 0);
      EXPECT_LT(t.accepted, n / 2);
    }
  }
}

/// As above, but a fifth of the query's trunk centres are 0.3 m off (partial arcs fitted
/// badly): the right lattice site then pairs most trunks to a few cm and those to 0.3 m, an RMS
/// of ~0.14 m, above a wrong site's. Its median residual still tells them apart.
TEST(Lattice, LatticeFitJudgesTheMedianResidual) {
  const int n = 30;
  const PlantationTrial t = plantationTrial(LoopDetectorParams{}, 321, n, 5);
  std::printf("[ info ] plantation, 20 %% bad centres: accepted %d/%d (%d resolved by fit)\n",
              t.accepted, n, t.resolved);
  EXPECT_EQ(t.wrong, 0);
  EXPECT_GE(t.resolved, n / 3);
  EXPECT_GE(t.accepted, n / 2);
}

/// Pair i of a plantation's submaps: the candidate at (90, 90), the query 12 m away in a
/// direction and with a heading that change with i, and a hypothesis on a wrong lattice site
/// far from the true one (3 and 2 spacings off, turned by 90 deg), as the triangles of a
/// plantation give when the submaps overlap only in part.
struct FarHypothesisPair {
  Descriptor q, c;
  Pose T_true, T_wrong;
};

FarHypothesisPair farHypothesisPair(std::mt19937& rng, const Trunks& world, int i) {
  // The candidate frame is axis-aligned on a lattice node, so lattice vectors and 90 deg
  // turns about its origin map lattice nodes onto lattice nodes.
  const Pose T_w_c = poseXyYaw(90.0, 90.0, 0.0, 0.0);
  const double a = 0.7 * i;
  const Eigen::Vector2d qc(90.0 + 12.0 * std::cos(a), 90.0 + 12.0 * std::sin(a));
  const Pose T_w_q = poseXyYaw(qc.x(), qc.y(), 0.0, 0.4 + a);
  FarHypothesisPair p;
  // One draw sequence per statement: the candidate's observation first, as before.
  p.c = describe(observe(rng, world, Eigen::Vector2d(90.0, 90.0), T_w_c), "b", 1);
  p.q = describe(observe(rng, world, qc, T_w_q), "a", 0);
  p.T_true = T_w_c.inverse() * T_w_q;
  p.T_wrong = poseXyYaw(9.0, -6.0, 0.0, M_PI / 2.0) * p.T_true;
  return p;
}

/// farHypothesisPair's wrong hypotheses: the lattice search must reach the true site, not
/// only the hypothesis' neighbours.
TEST(Lattice, LatticeFitReachesSitesFarFromTheHypothesis) {
  std::mt19937 rng(2024);
  const Trunks world = test::plantation(rng, 180, 180, 3.0, 0.15);
  int resolved = 0;
  const int n = 6;
  for (int i = 0; i < n; ++i) {
    const auto [q, c, T_true, T_wrong] = farHypothesisPair(rng, world, i);
    std::vector<Correspondence> corrs;  // what an ambiguous triangle hypothesis looks like
    const PoseEstimate est = hypothesis(T_wrong, true, &corrs);
    const Verification v = verifyLoop(q, c, corrs, est, VerifierParams{});
    ASSERT_GT(v.ambiguity, VerifierParams{}.max_ambiguity);
    if (!v.accepted) {
      std::printf("[ info ] pair %d rejected: %s (fit ambiguity %.2f)\n", i, v.reason().c_str(),
                  v.fit_ambiguity);
      continue;
    }
    ++resolved;
    EXPECT_LT(test::yawError(v.T_c_q, T_true), 0.3 * M_PI / 180.0) << "pair " << i;
    EXPECT_LT((v.T_c_q.translation() - T_true.translation()).head<2>().norm(), 0.15)
        << "pair " << i;
  }
  std::printf("[ info ] hypothesis 3 x 2 sites and 90 deg off: %d/%d resolved\n", resolved, n);
  EXPECT_GE(resolved, n - 1);
}

/// The lattice search ranks its ~1,000 poses coarse to fine: the coarse fit must put the true
/// site first, so that refining only its best pose (lattice_refined_poses 1) still reaches it
/// from farHypothesisPair's hypotheses; with the default the search returns what
/// ranking every pose by the finer fit (0) returns.
TEST(Lattice, CoarseRankingPutsTheTrueSiteFirst) {
  std::mt19937 rng(2024);
  const Trunks world = test::plantation(rng, 180, 180, 3.0, 0.15);
  VerifierParams all, one;
  all.lattice_refined_poses = 0;
  one.lattice_refined_poses = 1;
  int reached = 0;
  const int n = 6;
  for (int i = 0; i < n; ++i) {
    const auto [q, c, T_true, T_wrong] = farHypothesisPair(rng, world, i);
    const auto [fit_all, ratio_all] = resolveByFit(q, c, T_wrong, all);
    const auto [fit, ratio] = resolveByFit(q, c, T_wrong, VerifierParams{});
    EXPECT_TRUE(fit.T.isApprox(fit_all.T, 1e-12)) << "pair " << i;
    EXPECT_EQ(fit.score, fit_all.score) << "pair " << i;
    EXPECT_EQ(ratio, ratio_all) << "pair " << i;

    const Fit fit_one = resolveByFit(q, c, T_wrong, one).first;
    const bool at_true = test::yawError(fit_one.T, T_true) < 0.3 * M_PI / 180.0 &&
                         (fit_one.T.translation() - T_true.translation()).head<2>().norm() < 0.15;
    reached += at_true;
  }
  std::printf("[ info ] only the coarse ranking's best pose refined: %d/%d at the true site\n",
              reached, n);
  EXPECT_GE(reached, n - 1);
}

TEST(Lattice, RejectsDifferentPlacesOfAPlantationGrid) {
  // 3 m x 3 m grid, 0.15 m planting jitter, radii 15 +- 1 cm: every window looks alike up to
  // the jitter. Pairs of windows >= 33 m apart share no tree; each must be rejected.
  std::mt19937 rng(99);
  const LoopDetectorParams params;
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI), pos(20, 160);
  int false_accepts = 0, tried = 0, reached_pose = 0;
  double min_ambiguity = 1.0;
  for (int i = 0; i < 60; ++i) {
    const Trunks world = test::plantation(rng, 180, 180, 3.0, 0.15);
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const double ay = pos(rng);
    const double ax = pos(rng);
    const double by = pos(rng);
    const Eigen::Vector2d a(ax, ay), b(pos(rng), by);
    if ((a - b).norm() < 33.0) continue;
    // Headings near multiples of 90 deg are the hardest: the grids line up.
    const double ya = (i % 2) ? yaw(rng) : 0.5 * M_PI * (i % 4) + 0.01;
    const Descriptor q =
        describe(observe(rng, world, a, poseXyYaw(a.x(), a.y(), 0, ya)), "a", 0, 0.0);
    const Descriptor c =
        describe(observe(rng, world, b, poseXyYaw(b.x(), b.y(), 0, 0)), "b", 1, 0.0);
    ++tried;
    PoseEstimate est;
    Verification ver;
    if (matchPair(q, c, params, &est, &ver)) {
      ++false_accepts;
      std::printf(
          "[ info ] false accept: fit ambiguity %.2f, rms %.3f m, pairs %zu, overlap %.2f\n",
          ver.fit_ambiguity, ver.rms_xy_m, ver.pairs.size(), ver.overlap);
    }
    if (est.ok) ++reached_pose;
    min_ambiguity = std::min(min_ambiguity, ver.ambiguity);
  }
  std::printf(
      "[ info ] plantation: %d pairs, %d reached the pose solver, %d accepted, "
      "lowest runner-up/best support %.2f\n",
      tried, reached_pose, false_accepts, min_ambiguity);
  ASSERT_GT(tried, 30);
  EXPECT_EQ(false_accepts, 0);
}

/// A query that is the candidate shifted by t: every trunk votes for t, so the strongest
/// translation peak is t; nothing votes without trunks or above the trunk count.
TEST(Lattice, TranslationPeaksFindTheShift) {
  std::mt19937 rng(3);
  const Trunks world = test::randomStand(rng, 40, 40, 400);
  Descriptor c, q;
  c.trunks = world;
  const Eigen::Vector2d t(7.3, -2.1);
  for (TrunkLandmark tr : world) {
    tr.x -= t.x();
    tr.y -= t.y();
    q.trunks.push_back(tr);
  }
  const int n = static_cast<int>(world.size());
  ASSERT_GE(n, 40);
  const auto peaks = translationPeaks(q, c, Eigen::Matrix2d::Identity(), 6, 10);
  ASSERT_FALSE(peaks.empty());
  EXPECT_LT((peaks[0] - t).norm(), 0.1);
  EXPECT_LE(peaks.size(), 10u);
  EXPECT_EQ(translationPeaks(q, c, Eigen::Matrix2d::Identity(), 6, 1).size(), 1u);
  EXPECT_TRUE(translationPeaks(q, c, Eigen::Matrix2d::Identity(), 4 * n, 10).empty());
  EXPECT_TRUE(translationPeaks(Descriptor{}, c, Eigen::Matrix2d::Identity(), 6, 10).empty());
}

}  // namespace
}  // namespace dtif
