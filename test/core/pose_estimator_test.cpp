#include "dtif/core/pose/pose_estimator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <random>
#include <set>

#include "core/match_test_utils.h"
#include "dtif/core/pose/pose_estimator_stages.h"
#include "test_utils.h"

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
    c.pq = offset + test::randomVector(rng, u, u, uz);
    if (i < n_out) {
      c.pc = T_c_q * offset + test::randomVector(rng, u, u, uz);
    } else {
      c.pc = T_c_q * c.pq + test::randomVector(rng, nn, nn, nn);
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
    // The inliers are the 30 true ones (makeCorrs: iq >= 30), all of them; an outlier may land
    // within beta by chance, at most one.
    std::set<int> true_in;
    for (int k : e.inliers_T) {
      if (corrs[k].iq >= 30) true_in.insert(corrs[k].iq);
    }
    EXPECT_EQ(true_in.size(), 30u) << "yaw " << yaw;
    EXPECT_LE(e.inliers_T.size() - true_in.size(), 1u) << "yaw " << yaw;
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
    const double y = u(rng);  // drawn before x, as gcc did: the same data for any compiler
    c.pq = Eigen::Vector3d(u(rng), y, 0.0);
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

// --- Stages (pose_estimator_stages.h) ---

Correspondence corr(int iq, int ic, const Eigen::Vector3d& pq, const Eigen::Vector3d& pc,
                    double w = 1.0, bool z_ok = true) {
  Correspondence c;
  c.iq = iq;
  c.ic = ic;
  c.pq = pq;
  c.pc = pc;
  c.w = w;
  c.z_ok = z_ok;
  return c;
}

TEST(PoseStages, TimsSkipSharedTrunksCoincidentPointsAndLengthMismatches) {
  using pose_stages::Tim;
  const std::vector<Correspondence> corrs{
      corr(0, 0, {0, 0, 0}, {0, 0, 0}), corr(1, 1, {3, 0, 0}, {0, 3, 0}),
      corr(0, 2, {0, 0, 0}, {5, 5, 0}),  // shares query trunk 0 with the first
      corr(3, 3, {3, 0, 0}, {0, 3, 0}),  // same points as the second: coincident with it
  };
  const std::vector<double> w{4.0, 1.0, 1.0, 9.0};
  const std::vector<Tim> tims =
      pose_stages::translationInvariantMeasurements(corrs, w, PoseEstimatorParams{});
  // (0, 2) share a trunk, (1, 3) coincide, (1, 2) and (2, 3) differ in length by 2.4 m.
  ASSERT_EQ(tims.size(), 2u);
  EXPECT_EQ(tims[0].a, 0);
  EXPECT_EQ(tims[0].b, 1);
  EXPECT_EQ(tims[1].a, 0);
  EXPECT_EQ(tims[1].b, 3);
  EXPECT_DOUBLE_EQ(tims[0].qx, -3.0);
  EXPECT_DOUBLE_EQ(tims[0].cy, -3.0);
  EXPECT_DOUBLE_EQ(tims[0].w, 2.0);  // omega_ab = sqrt(4 * 1)
  EXPECT_DOUBLE_EQ(tims[1].w, 6.0);  // sqrt(4 * 9)
}

TEST(PoseStages, TimsKeptExactlyWhenTheirLengthsDifferByAtMostBeta) {
  // Length differences within 1e-7 m of beta_R, lengths from 1 m to 10 km, random directions:
  // a TIM is kept exactly when |hypot(d^q) - hypot(d^c)| <= beta_R, whatever shortcut decides
  // the far ones first.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const PoseEstimatorParams p;
  const std::vector<double> w{1.0, 1.0};
  int kept = 0;
  for (int trial = 0; trial < 100000; ++trial) {
    const double len = std::pow(10.0, 4.0 * unit(rng));
    const double diff = p.beta_yaw_m + (unit(rng) - 0.5) * 2e-7;
    const double a = 2.0 * M_PI * unit(rng), b = 2.0 * M_PI * unit(rng);
    const Eigen::Vector3d q(len * std::cos(a), len * std::sin(a), 0.0);
    const double lc = len + (trial % 2 ? diff : -diff);
    const Eigen::Vector3d c(lc * std::cos(b), lc * std::sin(b), 0.0);
    const std::vector<Correspondence> corrs{corr(0, 0, {0, 0, 0}, {0, 0, 0}), corr(1, 1, q, c)};
    const bool want =
        std::fabs(std::hypot(q.x(), q.y()) - std::hypot(c.x(), c.y())) <= p.beta_yaw_m;
    const size_t got = pose_stages::translationInvariantMeasurements(corrs, w, p).size();
    ASSERT_EQ(got, want ? 1u : 0u) << "trial " << trial;
    kept += want;
  }
  EXPECT_GT(kept, 40000);  // both sides of the boundary are exercised
  EXPECT_LT(kept, 60000);
}

TEST(PoseStages, EstimateYawIsExactOnCleanTimsAndReportsConsensus) {
  std::mt19937 rng(11);
  const Pose T = test::poseXyYaw(4.0, -2.0, 0.0, -2.5);
  const auto corrs = makeCorrs(rng, T, 12, 0.0, 0.0);
  std::vector<double> w;
  for (const Correspondence& c : corrs) w.push_back(c.w);
  const PoseEstimatorParams p;
  const auto tims = pose_stages::translationInvariantMeasurements(corrs, w, p);
  ASSERT_EQ(tims.size(), 66u);
  const pose_stages::YawEstimate yaw = pose_stages::estimateYaw(tims, p);
  EXPECT_NEAR(std::remainder(yaw.theta + 2.5, 2.0 * M_PI), 0.0, 1e-9);
  double total = 0.0;
  for (const auto& m : tims) total += m.w;
  EXPECT_NEAR(yaw.consensus, total, 1e-9);        // every TIM agrees
  EXPECT_LT(yaw.runner_up, 0.5 * yaw.consensus);  // short TIMs only, far from the yaw
}

/// gncTlsYaw as it computed before 2026-11-29: each TIM's weight by branches, the terms summed
/// through weightedYaw's expression. *steps counts its steps with a weight strictly between 0
/// and 1 somewhere.
double referenceGncYaw(const std::vector<pose_stages::Tim>& tims, double beta,
                       const PoseEstimatorParams& p, int* mixed_steps) {
  const auto yaw_of = [&](const auto& weight) {
    double sc = 0.0, ss = 0.0;
    for (const auto& m : tims) {
      const double u = weight(m);
      sc += u * m.w * (m.qx * m.cx + m.qy * m.cy);
      ss += u * m.w * (m.qx * m.cy - m.qy * m.cx);
    }
    return std::atan2(ss, sc);
  };
  const auto r2_of = [](const pose_stages::Tim& m, double c, double s) {
    const double rx = m.cx - (c * m.qx - s * m.qy), ry = m.cy - (s * m.qx + c * m.qy);
    return rx * rx + ry * ry;
  };
  const double c2 = beta * beta;
  double theta = yaw_of([](const pose_stages::Tim&) { return 1.0; });
  double max_r2 = 0.0;
  for (const auto& m : tims) max_r2 = std::max(max_r2, r2_of(m, std::cos(theta), std::sin(theta)));
  if (max_r2 <= c2) return theta;
  double mu = c2 / std::max(2.0 * max_r2 - c2, 1e-12);
  for (int it = 0; it < p.gnc_max_iterations; ++it) {
    const double c = std::cos(theta), s = std::sin(theta);
    const double lo = mu / (mu + 1.0) * c2, hi = (mu + 1.0) / mu * c2;
    bool binary = true;
    const double next = yaw_of([&](const pose_stages::Tim& m) {
      const double r2 = r2_of(m, c, s);
      if (r2 >= hi) return 0.0;
      if (r2 <= lo) return 1.0;
      binary = false;
      return beta * std::sqrt(mu * (mu + 1.0) / r2) - mu;
    });
    *mixed_steps += !binary;
    const double step = std::fabs(std::atan2(std::sin(next - theta), std::cos(next - theta)));
    theta = next;
    if (binary && step < 1e-9) break;
    mu *= p.gnc_factor;
  }
  return theta;
}

TEST(PoseStages, GncYawIsBitForBitTheWeightByWeightForm) {
  std::mt19937 rng(2029);
  const PoseEstimatorParams p;
  int mixed_steps = 0, cases = 0;
  // Odd and even counts (two TIMs per SSE2 step, then the rest one by one), clean and outlier
  // laden, exact and noisy.
  for (int n : {2, 3, 4, 9, 30, 61}) {
    for (double outliers : {0.0, 0.4, 0.8}) {
      for (double noise : {0.0, 0.05}) {
        const Pose T =
            test::poseXyYaw(3.0, -1.0, 0.0, std::uniform_real_distribution<>(-3, 3)(rng));
        const auto corrs = makeCorrs(rng, T, n, outliers, noise);
        std::vector<double> w;
        for (const Correspondence& c : corrs) w.push_back(c.w);
        const auto tims = pose_stages::translationInvariantMeasurements(corrs, w, p);
        if (tims.empty()) continue;
        for (double beta : {0.05, p.beta_yaw_m, 2.0}) {
          const double got = pose_stages::gncTlsYaw(tims, beta, p);
          const double want = referenceGncYaw(tims, beta, p, &mixed_steps);
          EXPECT_EQ(std::memcmp(&got, &want, sizeof got), 0)
              << "n " << n << ", outliers " << outliers << ", beta " << beta << ": " << got
              << " vs " << want;
          ++cases;
        }
      }
    }
  }
  EXPECT_GT(cases, 80);
  EXPECT_GT(mixed_steps, 100);  // the weights strictly between 0 and 1 were exercised
}

/// The yaw sweep's consensus and runner-up as consensusYaw computed them with std::sort and
/// wrapAngle throughout: (best, runner-up).
std::pair<double, double> referenceSweep(const std::vector<pose_stages::Tim>& tims, double beta) {
  const auto wrap = [](double a) { return std::atan2(std::sin(a), std::cos(a)); };
  std::vector<std::pair<double, double>> ev;  // (angle, dw)
  double wrap_start = 0.0;
  for (const auto& m : tims) {
    const double a = std::hypot(m.qx, m.qy), b = std::hypot(m.cx, m.cy);
    const double cosd = (a * a + b * b - beta * beta) / (2.0 * a * b);
    if (cosd > 1.0) continue;
    const double half = cosd <= -1.0 ? M_PI : std::acos(cosd);
    const double phi = std::atan2(m.qx * m.cy - m.qy * m.cx, m.qx * m.cx + m.qy * m.cy);
    if (half >= M_PI) {
      wrap_start += m.w;
      continue;
    }
    const double s = wrap(phi - half), e = wrap(phi + half);
    ev.emplace_back(s, m.w);
    ev.emplace_back(e, -m.w);
    if (s > e) wrap_start += m.w;
  }
  std::sort(ev.begin(), ev.end(), [](const auto& x, const auto& y) {
    return x.first < y.first || (x.first == y.first && x.second > y.second);
  });
  double cur = wrap_start, best = cur, theta = -M_PI;
  for (size_t i = 0; i < ev.size(); ++i) {
    cur += ev[i].second;
    if (cur > best + 1e-12) {
      best = cur;
      theta = 0.5 * (ev[i].first + (i + 1 < ev.size() ? ev[i + 1].first : M_PI));
    }
  }
  const auto far = [&](double ang) { return std::fabs(wrap(ang - theta)) > 10.0 * M_PI / 180.0; };
  double cur2 = wrap_start, runner = far(-M_PI) ? cur2 : 0.0;
  for (size_t i = 0; i < ev.size(); ++i) {
    cur2 += ev[i].second;
    const double next = i + 1 < ev.size() ? ev[i + 1].first : M_PI;
    if (far(0.5 * (ev[i].first + next))) runner = std::max(runner, cur2);
  }
  return {best, runner};
}

TEST(PoseStages, YawSweepEqualsTheFullSortWithWrappedAngles) {
  // Hundreds of TIMs (the sweep's radix sort, its arc ends wrapped by one turn and its shortcut
  // around wrapAngle), with outliers and with duplicated TIMs (arc ends at equal angles), against
  // the sweep done plainly, its arc ends by wrapAngle.
  std::mt19937 rng(19);
  size_t cases = 0;
  for (const double outliers : {0.0, 0.3, 0.7}) {
    const Pose T = test::poseXyYaw(2.0, 1.0, 0.0, 1.0 - outliers);
    const auto corrs = makeCorrs(rng, T, 120, outliers, 0.02);
    std::vector<double> w;
    for (const Correspondence& c : corrs) w.push_back(c.w);
    const PoseEstimatorParams p;
    std::vector<pose_stages::Tim> tims = pose_stages::translationInvariantMeasurements(corrs, w, p);
    const size_t n = tims.size();
    for (size_t i = 0; i < n; i += 3) tims.push_back(tims[i]);  // equal arc ends
    ASSERT_GT(tims.size(), 200u) << outliers;                   // over 256 arc ends: the radix sort
    const pose_stages::YawEstimate yaw = pose_stages::estimateYaw(tims, p);
    const auto [best, runner] = referenceSweep(tims, p.beta_yaw_m);
    EXPECT_EQ(yaw.consensus, best);
    EXPECT_EQ(yaw.runner_up, runner);
    cases += runner > 0.0;
  }
  EXPECT_GT(cases, 0u);  // a runner-up was there to find
}

TEST(PoseStages, RotationInliersNeedAFifthOfTheBestVoteCount) {
  using pose_stages::Tim;
  std::vector<Tim> tims;
  const Tim in{0, 0, 1.0, 0.0, 1.0, 0.0, 1.0}, out{0, 0, 1.0, 0.0, -1.0, 0.0, 1.0};
  auto add = [&](Tim m, int a, int b) {
    m.a = a;
    m.b = b;
    tims.push_back(m);
  };
  for (int a = 0; a < 6; ++a)
    for (int b = a + 1; b < 6; ++b) add(in, a, b);  // 5 votes each, 6 for correspondence 0
  add(in, 0, 6);                                    // correspondence 6: one lucky TIM
  add(out, 1, 6);                                   // residual 2 m at yaw 0
  add(out, 2, 7);
  // min votes = ceil(0.2 * 6) = 2: 6 has one, 7 none.
  EXPECT_EQ(pose_stages::rotationInliers(tims, 8, 0.0, 0.3), (std::vector<int>{0, 1, 2, 3, 4, 5}));
  // At yaw pi the outlier TIMs agree and the others do not.
  EXPECT_EQ(pose_stages::rotationInliers(tims, 8, M_PI, 0.3), (std::vector<int>{1, 2, 6, 7}));
}

TEST(PoseStages, TlsLocationTakesTheHeaviestModeAndReportsTheRunnerUp) {
  const std::vector<Eigen::Vector2d> obs{
      {0.0, 0.0}, {5.0, 5.0}, {0.1, 0.0}, {5.1, 5.0}, {0.0, 0.1}};
  const std::vector<double> w{1.0, 1.2, 1.0, 1.2, 1.0};
  const pose_stages::Location loc = pose_stages::tlsLocation(obs, w, 0.3);
  EXPECT_NEAR(loc.t.x(), 0.1 / 3.0, 1e-12);
  EXPECT_NEAR(loc.t.y(), 0.1 / 3.0, 1e-12);
  EXPECT_DOUBLE_EQ(loc.best, 3.0);
  EXPECT_DOUBLE_EQ(loc.runner_up, 2.4);
  const pose_stages::Location none = pose_stages::tlsLocation({}, {}, 0.3);
  EXPECT_EQ(none.t, Eigen::Vector2d::Zero());
  EXPECT_EQ(none.best, 0.0);
}

TEST(PoseStages, SolveTranslationKeepsTheSetMembersNearTheMode) {
  const Pose T = test::poseXyYaw(2.0, -1.0, 0.0, 0.5);
  std::vector<Correspondence> corrs;
  for (int i = 0; i < 5; ++i) {
    const Eigen::Vector3d pq(3.0 * i, 1.0 - i, 0.0);
    // Correspondence 2 is 1 m off in x.
    corrs.push_back(corr(i, i, pq, T * pq + Eigen::Vector3d(i == 2 ? 1.0 : 0.0, 0.0, 0.0)));
  }
  const std::vector<double> w(5, 1.0);
  pose_stages::Location loc;
  const std::vector<int> inl =
      pose_stages::solveTranslation(corrs, w, 0.5, {4, 2, 1, 0}, 0.3, &loc);
  EXPECT_EQ(inl, (std::vector<int>{4, 1, 0}));  // in the order of the set, without 2
  EXPECT_NEAR(loc.t.x(), 2.0, 1e-12);
  EXPECT_NEAR(loc.t.y(), -1.0, 1e-12);
  EXPECT_DOUBLE_EQ(loc.best, 3.0);
}

TEST(PoseStages, RefineJointlyRemovesAYawBias) {
  std::mt19937 rng(12);
  const Pose T = test::poseXyYaw(-3.0, 6.0, 0.0, 0.4);
  const auto corrs = makeCorrs(rng, T, 20, 0.0, 0.0);
  const std::vector<double> w(corrs.size(), 1.0);
  std::vector<int> all(corrs.size());
  std::iota(all.begin(), all.end(), 0);
  double theta = 0.4 + 0.004;  // 0.23 deg off: every trunk within 15 m still within beta
  pose_stages::Location loc;
  std::vector<int> inl = pose_stages::solveTranslation(corrs, w, theta, all, 0.3, &loc);
  ASSERT_EQ(inl.size(), corrs.size());
  pose_stages::refineJointly(corrs, w, all, 0.3, &theta, &loc, &inl);
  EXPECT_NEAR(theta, 0.4, 1e-12);
  EXPECT_NEAR((loc.t - T.translation().head<2>()).norm(), 0.0, 1e-9);
  EXPECT_EQ(inl, all);
}

TEST(PoseStages, ElevationFromSeenBasesOnlyUnlessThereAreNone) {
  std::vector<Correspondence> corrs{
      corr(0, 0, {0, 0, 0}, {0, 0, 1.0}, 1.0, true),
      corr(1, 1, {1, 0, 0}, {1, 0, 1.0}, 1.0, true),
      corr(2, 2, {2, 0, 0}, {2, 0, 3.0}, 1.0, false),  // hidden bases: extrapolated terrain
      corr(3, 3, {3, 0, 0}, {3, 0, 3.0}, 1.0, false),
      corr(4, 4, {4, 0, 0}, {4, 0, 3.0}, 1.0, false),
  };
  const std::vector<double> w(corrs.size(), 1.0);
  EXPECT_DOUBLE_EQ(pose_stages::estimateElevation(corrs, w, {0, 1, 2, 3, 4}, 0.3), 1.0);
  EXPECT_DOUBLE_EQ(pose_stages::estimateElevation(corrs, w, {2, 3, 4}, 0.3), 3.0);
}

TEST(PoseStages, ResidualsCountSeenBasesForTheElevation) {
  std::vector<Correspondence> corrs{
      corr(0, 0, {0, 0, 0}, {0.3, 0.4, 0.2}, 2.0, true),   // xy residual 0.5
      corr(1, 1, {1, 0, 0}, {1.0, 0.0, -0.2}, 3.0, true),  // xy residual 0
      corr(2, 2, {2, 0, 0}, {2.0, 0.0, 5.0}, 4.0, false),  // z ignored: bases hidden
  };
  PoseEstimate est;
  est.inliers_T = {0, 1, 2};
  pose_stages::addResiduals(corrs, {2.0, 3.0, 4.0}, &est);
  EXPECT_NEAR(est.rms_xy_m, std::sqrt(0.25 / 3.0), 1e-12);
  EXPECT_NEAR(est.rms_z_m, 0.2, 1e-12);
  EXPECT_DOUBLE_EQ(est.inlier_weight, 9.0);
}

}  // namespace
}  // namespace dtif
