// Elevation and residual tilt of verified loops: seen stem bases (mode, MAP tilt fit), ground
// maps when no base pair fixes t_z, and rejection when t_z is unobserved or ambiguous.
#include "dtif/core/verification/elevation.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>
#include <string>

#include "core/ground_test_utils.h"
#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_detector.h"

namespace dtif {
namespace {

using test::describe;
using test::observe;
using test::overlappingPairs;
using test::PairCase;
using test::poseXyYaw;
using test::rotationErrorDeg;
using test::tilted;

/// Ground maps for both sides of the pair: one hilly slope (world = the candidate frame); the
/// query sees no ground 6 m downhill of its centre.
void addGroundMaps(std::mt19937& rng, PairCase* pc) {
  const Pose T_W_c = Pose::Identity(), T_W_q = pc->T_c_q;
  pc->c.ground_map =
      test::mapOf(test::hillyGround(rng, Eigen::Vector2d::Zero(), 14.0, true), T_W_c, 0.5, 0.05);
  pc->q.ground_map = test::mapOf(
      test::hillyGround(rng, T_W_q.translation().head<2>(), 14.0, false, 6.0), T_W_q, 0.5, 0.05);
}

/// A submap pose at (xy, z) with a random yaw and roll and pitch within +-0.5 deg. One draw per
/// statement (pitch, roll, yaw: the order gcc evaluated them in when they were arguments), so the
/// data are the same whatever the compiler.
Pose randomTiltedPose(std::mt19937& rng, const Eigen::Vector2d& xy, double z) {
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI), tilt(-0.5, 0.5);
  const double pitch = tilt(rng);
  const double roll = tilt(rng);
  const double heading = yaw(rng);
  return tilted(poseXyYaw(xy.x(), xy.y(), z, heading), roll, pitch);
}

/// Only a few stem bases close together seen on both sides (dense understory): the plain
/// least-squares tilt follows their noise, the 4-DoF model leaves the odometry's tilt; the
/// prior on the residual tilt (tilt_prior_deg, a MAP fit) does better than both.
TEST(Elevation, TiltPriorSteadiesFewCloseBases) {
  struct Variant {
    const char* name;
    int min_pairs;
    double prior_deg;
    double sum_rot = 0.0;
    int accepted = 0;
  };
  std::vector<Variant> variants = {{"MAP", 4, 0.5}, {"least squares", 4, 0.0}, {"4-DoF", 0, 0.5}};
  for (Variant& var : variants) {
    LoopDetectorParams params;
    params.verification.tilt_min_pairs = var.min_pairs;
    params.verification.tilt_min_spread_m = 0.0;
    params.verification.tilt_prior_deg = var.prior_deg;
    std::mt19937 rng(11);
    test::ObservationNoise nz;
    nz.z_sigma_m = 0.05;
    const Eigen::Vector2d seen_centre(53.0, 48.5);  // between the two submaps
    auto hideFar = [&](Descriptor* d, const Pose& T_w_s) {
      for (TrunkLandmark& t : d->trunks) {
        const Eigen::Vector3d w = T_w_s * Eigen::Vector3d(t.x, t.y, t.z);
        t.base_seen = (w.head<2>() - seen_centre).norm() < 6.0;
      }
    };
    for (int i = 0; i < 30; ++i) {
      const Trunks world = test::randomStand(rng, 100, 100, 600);
      const Eigen::Vector2d cc(50, 50), qc(56, 47);
      const Pose T_w_c = randomTiltedPose(rng, cc, 0.5);
      const Pose T_w_q = randomTiltedPose(rng, qc, -0.3);
      Descriptor c = describe(observe(rng, world, cc, T_w_c, nz), "a", 0, 0.0);
      Descriptor q = describe(observe(rng, world, qc, T_w_q, nz), "b", 1, 0.0);
      hideFar(&c, T_w_c);
      hideFar(&q, T_w_q);
      const auto lc = matchPair(q, c, params);
      if (!lc) continue;
      ++var.accepted;
      var.sum_rot += rotationErrorDeg(lc->T_c_q, T_w_c.inverse() * T_w_q);
    }
    std::printf("[ info ] %s: accepted %d/30, rotation error %.3f deg\n", var.name, var.accepted,
                var.sum_rot / std::max(1, var.accepted));
    ASSERT_GE(var.accepted, 25) << var.name;
  }
  const double map = variants[0].sum_rot / variants[0].accepted;
  EXPECT_LT(map, variants[1].sum_rot / variants[1].accepted);
  EXPECT_LT(map, variants[2].sum_rot / variants[2].accepted);
}

/// Hidden stem bases (sensor's lower field-of-view limit, occlusion): the extractor flags them
/// and reports extrapolated terrain, too high. Here the query saw half its bases too high (it
/// walked downhill), the candidate a fifth. Elevation must come from seen bases only.
TEST(Elevation, ElevationComesFromSeenBasesOnly) {
  std::mt19937 rng(77);
  std::uniform_real_distribution<double> u01(0.0, 1.0), lift(0.5, 3.0);
  auto hide = [&](Descriptor* d, double share, bool flag) {
    for (TrunkLandmark& t : d->trunks) {
      if (u01(rng) >= share) continue;
      t.z += lift(rng);
      t.base_seen = !flag;
    }
  };
  const LoopDetectorParams params;
  for (const bool flag : {true, false}) {
    std::vector<PairCase> cases = overlappingPairs(30, 99);
    int accepted = 0, unobserved = 0;
    double sum_z = 0.0, max_z = 0.0;
    for (PairCase& pc : cases) {
      hide(&pc.q, 0.5, flag);
      hide(&pc.c, 0.2, flag);
      PoseEstimate est;
      Verification ver;
      const auto lc = matchPair(pc.q, pc.c, params, &est, &ver);
      if (!lc) continue;
      const double ez = std::fabs(lc->T_c_q.translation().z() - pc.T_c_q.translation().z());
      if (ver.z_pairs == 0) {
        // Nothing to measure t_z with: the loop must say so in its covariance.
        EXPECT_GE(lc->covariance(2, 2), 1.0);
        ++unobserved;
        continue;
      }
      ++accepted;
      sum_z += ez;
      max_z = std::max(max_z, ez);
    }
    std::printf(
        "[ info ] hidden bases %s: accepted %d/%zu (+%d without a seen base pair), z error "
        "mean %.3f max %.3f m\n",
        flag ? "flagged" : "unflagged", accepted, cases.size(), unobserved, sum_z / accepted,
        max_z);
    if (flag) {
      ASSERT_GE(accepted, 20);
      EXPECT_LE(unobserved, 3);
      EXPECT_LT(sum_z / accepted, 0.05);
      EXPECT_LT(max_z, 0.2);
    } else {
      // The control: unflagged, wrong bases still corrupt t_z (the mode absorbs some of them,
      // max_z_ambiguity rejects about half of these loops).
      ASSERT_GE(accepted, 10);
      EXPECT_GT(max_z, 0.5);
      EXPECT_GT(sum_z / accepted, 0.1);
    }
  }
}

/// No stem base seen in either submap (a steep slope seen from a helmet): t_z comes from the
/// ground maps when both carry one, else the loop is rejected rather than given a guessed t_z.
TEST(Elevation, ElevationFromGroundMapsWhenNoBaseIsSeen) {
  const LoopDetectorParams params;
  std::mt19937 rng(31);
  int with_maps = 0, checked = 0;
  for (PairCase& pc : overlappingPairs(12, 515)) {
    for (TrunkLandmark& t : pc.q.trunks) t.base_seen = false;
    for (TrunkLandmark& t : pc.c.trunks) t.base_seen = false;
    Verification ver;
    const auto none = matchPair(pc.q, pc.c, params, nullptr, &ver);
    EXPECT_FALSE(none.has_value());
    // Rejected before the elevation otherwise.
    if (ver.rejection != Rejection::kElevationUnobserved || ver.vote_rejection != Rejection::kNone)
      continue;
    ++checked;
    addGroundMaps(rng, &pc);
    Verification v2;
    const auto lc = matchPair(pc.q, pc.c, params, nullptr, &v2);
    ASSERT_TRUE(lc.has_value()) << v2.reason();
    EXPECT_EQ(v2.z_pairs, 0);
    EXPECT_GE(v2.ground_cells, params.verification.min_ground_cells);
    EXPECT_NEAR(lc->T_c_q.translation().z(), pc.T_c_q.translation().z(), 0.05);
    EXPECT_LE(lc->covariance(2, 2), 0.01);
    ++with_maps;
    // One map alone fixes nothing.
    pc.c.ground_map = GroundMap();
    Verification v3;
    EXPECT_FALSE(matchPair(pc.q, pc.c, params, nullptr, &v3).has_value());
    EXPECT_EQ(v3.rejection, Rejection::kElevationUnobserved);
    EXPECT_EQ(v3.reason(), "elevation unobserved");
  }
  EXPECT_GE(checked, 8);
  EXPECT_EQ(with_maps, checked);
}

/// Bases flagged seen can still be wrong (a shrub under the stem, dense understory): t_z is the
/// mode of the seen pairs' elevation differences, so 3 right pairs outvote 3 wrong ones that
/// disagree with each other (their median would be a wrong one), and only agreeing pairs count.
/// (Wrong ones that agree with each other are AgreeingWrongBasesMakeTheElevationAmbiguous.)
TEST(Elevation, ElevationIsTheModeOfSeenBasePairs) {
  const LoopDetectorParams params;
  int checked = 0;
  for (PairCase& pc : overlappingPairs(20, 4242)) {
    Verification ver;
    if (!matchPair(pc.q, pc.c, params, nullptr, &ver) || ver.pairs.size() < 8) continue;
    for (TrunkLandmark& t : pc.q.trunks) t.base_seen = false;
    for (TrunkLandmark& t : pc.c.trunks) t.base_seen = false;
    const double lift[] = {0.0, 0.0, 0.0, 0.6, 1.2, 1.8};
    for (int k = 0; k < 6; ++k) {
      const auto [i, j] = ver.pairs[k];
      pc.q.trunks[i].base_seen = pc.c.trunks[j].base_seen = true;
      pc.c.trunks[j].z += lift[k];
    }
    Verification v2;
    const auto lc = matchPair(pc.q, pc.c, params, nullptr, &v2);
    ASSERT_TRUE(lc.has_value()) << v2.reason();
    EXPECT_EQ(v2.z_pairs, 3);
    EXPECT_LT(std::fabs(lc->T_c_q.translation().z() - pc.T_c_q.translation().z()), 0.1);
    ++checked;
  }
  EXPECT_GE(checked, 10);
}

/// Two neighbouring stems whose bases both sit on one shrub agree on a wrong t_z as well as two
/// good pairs agree on the right one: 2 against 2 is rejected as ambiguous, 3 against 2 too,
/// 2 against 1 is not. A lone seen pair fixes t_z but is reported with a 0.3 m std dev.
TEST(Elevation, AgreeingWrongBasesMakeTheElevationAmbiguous) {
  const LoopDetectorParams params;
  struct Case {
    int right, wrong;
    bool accepted;
  };
  const Case cases[] = {{2, 2, false}, {3, 2, false}, {2, 1, true}, {1, 0, true}};
  int checked = 0;
  for (PairCase& pc : overlappingPairs(20, 4343)) {
    Verification ver;
    if (!matchPair(pc.q, pc.c, params, nullptr, &ver) || ver.pairs.size() < 8) continue;
    for (const Case& cs : cases) {
      Descriptor q = pc.q, c = pc.c;
      for (TrunkLandmark& t : q.trunks) t.base_seen = false;
      for (TrunkLandmark& t : c.trunks) t.base_seen = false;
      for (int k = 0; k < cs.right + cs.wrong; ++k) {
        const auto [i, j] = ver.pairs[k];
        q.trunks[i].base_seen = c.trunks[j].base_seen = true;
        if (k >= cs.right) q.trunks[i].z += 1.6;  // both on one shrub, 1.6 m up
      }
      Verification v2;
      const auto lc = matchPair(q, c, params, nullptr, &v2);
      EXPECT_EQ(lc.has_value(), cs.accepted)
          << cs.right << " right, " << cs.wrong << " wrong pairs: " << v2.reason();
      if (!cs.accepted) {
        EXPECT_NE(v2.reason().find("elevation ambiguous"), std::string::npos) << v2.reason();
        continue;
      }
      if (!lc) continue;
      EXPECT_LT(std::fabs(lc->T_c_q.translation().z() - pc.T_c_q.translation().z()), 0.1);
      if (cs.right == 1) {
        EXPECT_EQ(v2.z_pairs, 1);
        EXPECT_NEAR(lc->covariance(2, 2), 0.09, 1e-9);
      }
    }
    ++checked;
  }
  EXPECT_GE(checked, 10);
}

/// One good seen-base pair against one on a shrub leaves t_z ambiguous; when both submaps carry
/// ground maps, their difference settles it (and the loop's z variance is the maps').
TEST(Elevation, GroundMapsSettleAnAmbiguousElevation) {
  const LoopDetectorParams params;
  std::mt19937 rng(37);
  int checked = 0;
  for (PairCase& pc : overlappingPairs(20, 4444)) {
    Verification ver;
    if (!matchPair(pc.q, pc.c, params, nullptr, &ver) || ver.pairs.size() < 8) continue;
    for (TrunkLandmark& t : pc.q.trunks) t.base_seen = false;
    for (TrunkLandmark& t : pc.c.trunks) t.base_seen = false;
    for (int k = 0; k < 2; ++k) {
      const auto [i, j] = ver.pairs[k];
      pc.q.trunks[i].base_seen = pc.c.trunks[j].base_seen = true;
      if (k == 1) pc.q.trunks[i].z += 1.6;  // on a shrub
    }
    Verification v1;
    EXPECT_FALSE(matchPair(pc.q, pc.c, params, nullptr, &v1).has_value());
    EXPECT_EQ(v1.rejection, Rejection::kElevationAmbiguous);
    EXPECT_EQ(v1.reason(), "elevation ambiguous");

    addGroundMaps(rng, &pc);
    Verification v2;
    const auto lc = matchPair(pc.q, pc.c, params, nullptr, &v2);
    ASSERT_TRUE(lc.has_value()) << v2.reason();
    EXPECT_GE(v2.ground_cells, params.verification.min_ground_cells);
    EXPECT_NEAR(lc->T_c_q.translation().z(), pc.T_c_q.translation().z(), 0.05);
    EXPECT_LE(lc->covariance(2, 2), 0.01);
    ++checked;
  }
  EXPECT_GE(checked, 10);
}

/// Submaps are gravity-aligned only up to the odometry's residual roll/pitch; the refinement
/// fits what is left from the seen stem bases (tilt_min_pairs = 0: the paper's 4-DoF model).
TEST(Elevation, FitsResidualTiltFromSeenBases) {
  for (const int min_pairs : {8, 0}) {
    LoopDetectorParams params;
    params.verification.tilt_min_pairs = min_pairs;
    std::mt19937 rng(5);
    test::ObservationNoise nz;
    nz.z_sigma_m = 0.02;
    int accepted = 0;
    double sum_rot = 0.0, sum_z = 0.0;
    for (int i = 0; i < 30; ++i) {
      const Trunks world = test::randomStand(rng, 100, 100, 600);
      const Eigen::Vector2d cc(50, 50), qc(56, 47);
      const Pose T_w_c = randomTiltedPose(rng, cc, 0.5);
      const Pose T_w_q = randomTiltedPose(rng, qc, -0.3);
      const Descriptor c = describe(observe(rng, world, cc, T_w_c, nz), "a", 0, 0.0);
      const Descriptor q = describe(observe(rng, world, qc, T_w_q, nz), "b", 1, 0.0);
      const Pose T_c_q = T_w_c.inverse() * T_w_q;
      const auto lc = matchPair(q, c, params);
      if (!lc) continue;
      ++accepted;
      sum_rot += rotationErrorDeg(lc->T_c_q, T_c_q);
      sum_z += std::fabs(lc->T_c_q.translation().z() - T_c_q.translation().z());
    }
    std::printf("[ info ] tilt_min_pairs %d: accepted %d/30, rotation error %.3f deg, z %.3f m\n",
                min_pairs, accepted, sum_rot / accepted, sum_z / accepted);
    ASSERT_GE(accepted, 25);
    if (min_pairs > 0) {
      EXPECT_LT(sum_rot / accepted, 0.15);
      EXPECT_LT(sum_z / accepted, 0.05);
    } else {
      EXPECT_GT(sum_rot / accepted, 0.25);  // relative tilt of up to 1 deg left uncorrected
    }
  }
}

/// Few stem bases seen, all close together (a third of the returns, shrubs): they cannot tell
/// the residual tilt. The two submaps' ground maps overlap over 20-30 m and differ by t_z plus
/// that tilt's plane, so the fit recovers it from them (tilt_min_ground_cells 0: the bases
/// alone, as before the ground maps took part) and reports a tighter roll/pitch variance.
TEST(Elevation, FitsResidualTiltFromGroundMaps) {
  for (const int min_cells : {50, 0}) {
    LoopDetectorParams params;
    params.verification.tilt_min_ground_cells = min_cells;
    std::mt19937 rng(23);
    test::ObservationNoise nz;
    nz.z_sigma_m = 0.02;
    int accepted = 0, fitted = 0;
    double sum_rot = 0.0, sum_z = 0.0, sum_sd = 0.0;
    for (int i = 0; i < 20; ++i) {
      const Trunks world = test::randomStand(rng, 100, 100, 600);
      const Eigen::Vector2d cc(30, 30), qc(36, 27), seen(33, 28.5);
      const Pose T_w_c = randomTiltedPose(rng, cc, test::terrainZ(cc.x(), cc.y()) + 1.7);
      const Pose T_w_q = randomTiltedPose(rng, qc, test::terrainZ(qc.x(), qc.y()) + 1.7);
      Descriptor c = describe(observe(rng, world, cc, T_w_c, nz), "a", 0, 0.0);
      Descriptor q = describe(observe(rng, world, qc, T_w_q, nz), "b", 1, 0.0);
      for (auto [d, T] : {std::pair<Descriptor*, Pose>(&c, T_w_c), {&q, T_w_q}}) {
        for (TrunkLandmark& t : d->trunks)
          t.base_seen = ((T * Eigen::Vector3d(t.x, t.y, t.z)).head<2>() - seen).norm() < 3.0;
      }
      c.ground_map = test::mapOf(test::hillyGround(rng, cc, 14.0, true), T_w_c, 0.5, 0.05);
      q.ground_map = test::mapOf(test::hillyGround(rng, qc, 14.0, true), T_w_q, 0.5, 0.05);
      const Pose T_c_q = T_w_c.inverse() * T_w_q;
      Verification ver;
      const auto lc = matchPair(q, c, params, nullptr, &ver);
      if (!lc) continue;
      ++accepted;
      fitted += ver.tilt_ground_cells > 0;
      sum_rot += rotationErrorDeg(lc->T_c_q, T_c_q);
      sum_z += std::fabs(lc->T_c_q.translation().z() - T_c_q.translation().z());
      sum_sd += std::sqrt(lc->covariance(3, 3)) * 180.0 / M_PI;
    }
    std::printf(
        "[ info ] tilt_min_ground_cells %d: accepted %d/20 (%d tilts from the ground), rotation "
        "error %.3f deg, z %.3f m, roll std dev %.3f deg\n",
        min_cells, accepted, fitted, sum_rot / accepted, sum_z / accepted, sum_sd / accepted);
    ASSERT_GE(accepted, 16);
    if (min_cells > 0) {
      EXPECT_EQ(fitted, accepted);
      EXPECT_LT(sum_rot / accepted, 0.1);
      EXPECT_LT(sum_z / accepted, 0.05);
      // The fit's own std dev (~0.06 deg here) plus ground_tilt_floor_deg in quadrature.
      EXPECT_LT(sum_sd / accepted, 0.25);
    } else {
      EXPECT_EQ(fitted, 0);
      EXPECT_GT(sum_rot / accepted, 0.25);  // the relative tilt (up to 1 deg) mostly left
      EXPECT_GE(sum_sd / accepted, 0.3);
    }
  }
}

/// No stem base seen, and the two submaps' levelled frames off by a residual tilt of about
/// 1 deg (each robot's levelling error: tenths of a degree, up to ~1 deg for its first
/// submaps): their ground maps, 40 m across, differ by t_z plus a plane, spread over
/// +-0.3 m, and the mode of the differences alone is too weak or ambiguous to trust. The search
/// over the residual tilt (ground_tilt_search_deg) settles t_z; without it (0) the same loops
/// are rejected.
TEST(Elevation, GroundMapsOfTiltedFramesSettleTheElevation) {
  int checked = 0, accepted_flat = 0, accepted_search = 0;
  std::mt19937 rng(47);
  for (PairCase& pc : overlappingPairs(12, 515)) {
    for (TrunkLandmark& t : pc.q.trunks) t.base_seen = false;
    for (TrunkLandmark& t : pc.c.trunks) t.base_seen = false;
    Verification ver;
    EXPECT_FALSE(matchPair(pc.q, pc.c, LoopDetectorParams(), nullptr, &ver).has_value());
    // Rejected before the elevation otherwise.
    if (ver.rejection != Rejection::kElevationUnobserved || ver.vote_rejection != Rejection::kNone)
      continue;
    ++checked;
    // The query's frame turned by the residual tilt about its origin (the true t_z stays): its
    // trunks in that frame (their faces change by millimetres) and its ground map seen from it.
    const Pose T_W_c = Pose::Identity(), T_W_q = tilted(pc.T_c_q, 1.0, -0.8);
    const Pose T_q_tilted = pc.T_c_q.inverse() * T_W_q;
    for (TrunkLandmark& t : pc.q.trunks) {
      const Eigen::Vector3d p = T_q_tilted.inverse() * Eigen::Vector3d(t.x, t.y, t.z);
      t.x = p.x(), t.y = p.y(), t.z = p.z();
    }
    pc.T_c_q = T_W_q;
    // The query was levelled by dtif (a stock FAST-LIO2 frame 8 deg off): the search is for
    // its levelling error. Trunks and maps are in the levelled frame L, the loop in S.
    pc.q.level_rotation =
        Eigen::Quaterniond(Eigen::AngleAxisd(8.0 * M_PI / 180.0, Eigen::Vector3d::UnitX()));
    Pose R_L_S = Pose::Identity();
    R_L_S.linear() = pc.q.level_rotation.toRotationMatrix();
    const Pose T_c_q_S = T_W_q * R_L_S;
    pc.c.ground_map =
        test::mapOf(test::hillyGround(rng, Eigen::Vector2d::Zero(), 20.0, true), T_W_c, 0.5, 0.05);
    pc.q.ground_map = test::mapOf(
        test::hillyGround(rng, pc.T_c_q.translation().head<2>(), 20.0, true), T_W_q, 0.5, 0.05);
    LoopDetectorParams flat;
    flat.verification.ground_tilt_search_deg = 0.0;
    Verification v_flat;
    const auto lf = matchPair(pc.q, pc.c, flat, nullptr, &v_flat);
    accepted_flat += lf.has_value();
    Verification v;
    const auto lc = matchPair(pc.q, pc.c, LoopDetectorParams(), nullptr, &v);
    if (!lc) continue;
    ++accepted_search;
    EXPECT_EQ(v.z_pairs, 0);
    EXPECT_GE(v.ground_cells, LoopDetectorParams().verification.min_ground_cells);
    EXPECT_NEAR(lc->T_c_q.translation().z(), T_c_q_S.translation().z(), 0.05);
    EXPECT_LT(rotationErrorDeg(lc->T_c_q, T_c_q_S), 0.3);  // the tilt found, not only t_z
    // Between frames that were not levelled it does not search.
    pc.q.level_rotation = Eigen::Quaterniond::Identity();
    Verification v_level;
    EXPECT_EQ(matchPair(pc.q, pc.c, LoopDetectorParams(), nullptr, &v_level).has_value(),
              lf.has_value());
  }
  std::printf(
      "[ info ] tilted frames, no base seen: %d pairs, %d accepted untilted, %d with the "
      "tilt search\n",
      checked, accepted_flat, accepted_search);
  EXPECT_GE(checked, 8);
  EXPECT_LT(accepted_flat, checked);  // the case the search is for: measured 7 of 12
  EXPECT_EQ(accepted_search, checked);
}

}  // namespace
}  // namespace dtif
