// Multi-submap trunk sets: sightings merged, odometry chained in 6-DoF, limits respected.
#include "dtif/core/descriptor/trunk_accumulator.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <vector>

namespace dtif {
namespace {

TrunkLandmark trunk(double x, double y, double z, double r) {
  TrunkLandmark t;
  t.x = x, t.y = y, t.z = z, t.r = r;
  return t;
}

Pose pose(double x, double y, double z, double yaw, double roll = 0.0, double pitch = 0.0) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(x, y, z);
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}

// Stems in the odometry frame O, as seen from a submap frame with pose T_O_S.
Trunks seenFrom(const Pose& T_O_S, const std::vector<Eigen::Vector4d>& stems_O) {
  Trunks out;
  const Pose T_S_O = T_O_S.inverse();
  for (const auto& s : stems_O) {
    const Eigen::Vector3d p = T_S_O * s.head<3>();
    out.push_back(trunk(p.x(), p.y(), p.z(), s.w()));
  }
  return out;
}

bool contains(const Trunks& ts, const Eigen::Vector3d& p, double tol) {
  for (const auto& t : ts) {
    if ((Eigen::Vector3d(t.x, t.y, t.z) - p).norm() < tol) return true;
  }
  return false;
}

TEST(MultiSubmapParams, DefaultsValidateAndBadValuesAreNamed) {
  EXPECT_EQ(MultiSubmapParams().validate(), "");
  MultiSubmapParams p;
  p.merge_radius_m = 0.0;
  p.target_trunks = 2;
  const std::string err = p.validate();
  EXPECT_NE(err.find("merge_radius_m"), std::string::npos);
  EXPECT_NE(err.find("target_trunks"), std::string::npos);
}

TEST(StemMerger, MergesSightingsOfOneStemAndCountsSources) {
  StemMerger m(0.5);
  m.add(trunk(0, 0, 0, 0.20), 0);
  m.add(trunk(5, 0, 0, 0.30), 0);
  m.add(trunk(0.2, 0.1, 0, 0.22), 1);  // the first stem again
  m.add(trunk(9, 9, 0, 0.25), 1);      // seen once only
  m.add(trunk(0.1, -0.1, 0, 0.24), 2);
  EXPECT_EQ(m.size(), 3u);
  const Trunks two = m.stable(2, 2);
  ASSERT_EQ(two.size(), 1u);
  EXPECT_DOUBLE_EQ(two[0].x, 0.0);  // the first (most trusted) sighting's position
  EXPECT_NEAR(two[0].r, 0.22, 1e-12);
  EXPECT_EQ(m.stable(1, 2).size(), 3u);
  EXPECT_EQ(m.stable(1, 0).size(), 2u);  // first seen by source 0
}

TEST(StemMerger, TwoStemsOfOneSubmapNeverMerge) {
  StemMerger m(0.5);
  m.add(trunk(0, 0, 0, 0.2), 0);
  m.add(trunk(0.35, 0, 0, 0.2), 0);  // a close neighbour in the same submap
  EXPECT_EQ(m.size(), 2u);
  m.add(trunk(0.3, 0, 0, 0.2), 1);  // joins the nearest one
  const Trunks s = m.stable(2, 1);
  ASSERT_EQ(s.size(), 1u);
  EXPECT_DOUBLE_EQ(s[0].x, 0.35);
}

TEST(TrunkAccumulator, EnoughStableOwnTrunksAreKeptAsTheyAre) {
  MultiSubmapParams p;
  p.min_trunks = 2;
  TrunkAccumulator acc(p);
  // The previous submap (at the origin of O) saw the two thick stems; the current one (5 m
  // along x) sees them again, plus a one-off and a juvenile: its own trunks are kept, all four.
  acc.add(0.0, pose(0, 0, 0, 0), {trunk(6, 2, 0, 0.2), trunk(9, 1, 0, 0.1)});
  const Trunks own = {trunk(1, 2, 0, 0.2), trunk(4, 1, 0, 0.1), trunk(-3, 5, 0, 0.2),
                      trunk(-3, 2, 0, 0.01)};
  const AccumulatedTrunks out = acc.add(10.0, pose(5, 0, 0, 0), own);
  EXPECT_EQ(out.submaps, 1);
  ASSERT_EQ(out.trunks.size(), own.size());
  for (size_t i = 0; i < own.size(); ++i) EXPECT_DOUBLE_EQ(out.trunks[i].x, own[i].x);

  // One stable trunk short of min_trunks: the stable stems of both submaps instead.
  p.min_trunks = 3;
  TrunkAccumulator few(p);
  few.add(0.0, pose(0, 0, 0, 0), {trunk(6, 2, 0, 0.2), trunk(9, 1, 0, 0.1)});
  const AccumulatedTrunks ext = few.add(10.0, pose(5, 0, 0, 0), own);
  EXPECT_EQ(ext.submaps, 2);
  EXPECT_EQ(ext.trunks.size(), 2u);
}

TEST(TrunkAccumulator, ChainsTiltedOdometryIntoTheCurrentFrame) {
  // Stems (x, y, z_base, r) in O; the robot walks along x with a tilted frame (as an un-levelled
  // camera_init gives) and turns; each submap sees the stems within 12 m.
  const std::vector<Eigen::Vector4d> stems = {{2, 3, 0.1, 0.2},    {6, -4, 0.0, 0.25},
                                              {11, 2, 0.3, 0.3},   {15, -3, 0.2, 0.2},
                                              {19, 4, -0.1, 0.22}, {24, -2, 0.0, 0.28}};
  MultiSubmapParams p;
  p.min_trunks = 8;
  p.target_trunks = 6;
  p.min_observations = 2;
  TrunkAccumulator acc(p);
  AccumulatedTrunks out;
  std::vector<Pose> poses;
  for (int k = 0; k < 5; ++k) {
    const Pose T_O_S = pose(5.0 * k, 0.3 * k, 0.1 * k, 0.2 * k, 0.15, -0.1);
    poses.push_back(T_O_S);
    Trunks seen;
    for (const auto& t : seenFrom(T_O_S, stems)) {
      if (std::hypot(t.x, t.y) < 12.0) seen.push_back(t);
    }
    out = acc.add(10.0 * k, T_O_S, seen);
  }
  // Every stem the last submap or its predecessors saw twice, in the last frame, exactly.
  const Pose T_S_O = poses.back().inverse();
  EXPECT_GE(out.submaps, 2);
  EXPECT_GE(out.trunks.size(), 4u);
  for (const auto& t : out.trunks) {
    bool on_stem = false;
    for (const auto& s : stems) {
      const Eigen::Vector3d e = T_S_O * s.head<3>();
      if ((Eigen::Vector3d(t.x, t.y, t.z) - e).norm() < 1e-9) on_stem = true;
    }
    EXPECT_TRUE(on_stem) << t.x << " " << t.y << " " << t.z;
  }
  // No stem twice.
  for (size_t i = 0; i < out.trunks.size(); ++i)
    for (size_t j = i + 1; j < out.trunks.size(); ++j)
      EXPECT_GT(std::hypot(out.trunks[i].x - out.trunks[j].x, out.trunks[i].y - out.trunks[j].y),
                1.0);
}

TEST(TrunkAccumulator, OneOffAndThinSightingsAreDropped) {
  MultiSubmapParams p;
  p.min_trunks = 8;
  p.target_trunks = 10;
  p.min_radius_m = 0.05;
  TrunkAccumulator acc(p);
  // Same frame twice (the robot stands still): a stem seen twice, a one-off, a juvenile twice.
  acc.add(0.0, Pose::Identity(), {trunk(1, 1, 0, 0.2), trunk(3, 3, 0, 0.2), trunk(5, 5, 0, 0.03)});
  const AccumulatedTrunks out = acc.add(
      10.0, Pose::Identity(), {trunk(1.1, 1, 0, 0.2), trunk(-4, 2, 0, 0.2), trunk(5, 5, 0, 0.03)});
  ASSERT_EQ(out.trunks.size(), 1u);
  EXPECT_DOUBLE_EQ(out.trunks[0].x, 1.1);  // the current submap's sighting
  EXPECT_EQ(out.submaps, 2);
}

TEST(TrunkAccumulator, StopsAtTheTargetAndRespectsSpanLimits) {
  MultiSubmapParams p;
  p.min_trunks = 8;
  p.target_trunks = 2;
  p.max_span_m = 12.0;
  p.max_span_s = 35.0;
  p.max_submaps = 10;
  TrunkAccumulator acc(p);
  // Stem j stands at x = 5 j + 1 in O; submap k (origin x = 5 k) sees stems k and k + 1.
  const Trunks seen = {trunk(1.0, 0, 0, 0.2), trunk(6.0, 0, 0, 0.2)};  // in S
  AccumulatedTrunks out;
  for (int k = 0; k < 6; ++k) out = acc.add(10.0 * k, pose(5.0 * k, 0, 0, 0), seen);
  // Stems 5 (seen by submaps 4, 5) and 4 (by 3, 4) are stable with the previous submap alone:
  // no older one is used. Stem 6 is seen by submap 5 only.
  EXPECT_EQ(out.submaps, 2);
  EXPECT_NEAR(out.span_m, 5.0, 1e-9);
  EXPECT_EQ(out.trunks.size(), 2u);
  EXPECT_TRUE(contains(out.trunks, Eigen::Vector3d(1.0, 0.0, 0.0), 1e-9));
  EXPECT_TRUE(contains(out.trunks, Eigen::Vector3d(-4.0, 0.0, 0.0), 1e-9));

  // A target out of reach: every predecessor within 12 m and 35 s (submaps 4 and 3), no
  // farther: stem 2 (x = -14 in S), seen by submap 2 only, is not there.
  p.target_trunks = 50;
  p.min_observations = 1;
  TrunkAccumulator far(p);
  for (int k = 0; k < 6; ++k) out = far.add(10.0 * k, pose(5.0 * k, 0, 0, 0), seen);
  EXPECT_EQ(out.submaps, 3);
  EXPECT_NEAR(out.span_m, 10.0, 1e-9);
  EXPECT_EQ(out.trunks.size(), 4u);  // stems 3 to 6
  EXPECT_TRUE(contains(out.trunks, Eigen::Vector3d(-9.0, 0.0, 0.0), 1e-9));
  EXPECT_FALSE(contains(out.trunks, Eigen::Vector3d(-14.0, 0.0, 0.0), 0.1));
  EXPECT_LE(far.history(), 4u);  // older than 35 s are forgotten

  // max_submaps bounds the chain even within the span.
  p.max_span_m = 100.0;
  p.max_span_s = 100.0;
  p.max_submaps = 1;
  p.forward_submaps = 0;
  TrunkAccumulator one(p);
  for (int k = 0; k < 6; ++k) out = one.add(10.0 * k, pose(5.0 * k, 0, 0, 0), seen);
  EXPECT_EQ(out.submaps, 2);
  EXPECT_EQ(one.history(), 1u);
  // Forward updates keep the predecessors of the oldest submap they reach as well.
  p.forward_submaps = 2;
  TrunkAccumulator forward(p);
  for (int k = 0; k < 6; ++k) out = forward.add(10.0 * k, pose(5.0 * k, 0, 0, 0), seen);
  EXPECT_EQ(out.submaps, 2);
  EXPECT_EQ(forward.history(), 4u);  // 1 + 2 successors + the newest
}

TEST(TrunkAccumulator, OnlyTheSubmapsOwnBasesCountAsSeen) {
  // The odometry's vertical drift makes a predecessor's base elevation a guess in S.
  MultiSubmapParams p;
  p.min_trunks = 8;
  TrunkAccumulator acc(p);
  acc.add(0.0, pose(0, 0, 0, 0), {trunk(6, 2, 0, 0.2), trunk(9, 1, 0, 0.2)});
  const AccumulatedTrunks out = acc.add(10.0, pose(5, 0, 0, 0), {trunk(1, 2, 0, 0.2)});
  ASSERT_EQ(out.trunks.size(), 1u);  // (9, 1) is seen once
  EXPECT_TRUE(out.trunks[0].base_seen);
  TrunkAccumulator later(p);
  later.add(0.0, pose(0, 0, 0, 0), {trunk(6, 2, 0, 0.2)});
  later.add(10.0, pose(1, 0, 0, 0), {trunk(5, 2, 0, 0.2)});
  const AccumulatedTrunks old = later.add(20.0, pose(2, 0, 0, 0), {});
  ASSERT_EQ(old.trunks.size(), 1u);  // seen by both predecessors, not by the submap itself
  EXPECT_FALSE(old.trunks[0].base_seen);
  EXPECT_NEAR(old.trunks[0].x, 4.0, 1e-12);
}

TEST(TrunkAccumulator, FirstSubmapAndDisabledKeepOwnTrunks) {
  MultiSubmapParams p;
  p.min_trunks = 8;
  TrunkAccumulator acc(p);
  const Trunks own = {trunk(1, 1, 0, 0.2), trunk(3, 3, 0, 0.03)};
  EXPECT_EQ(acc.add(0.0, Pose::Identity(), own).trunks.size(), 2u);  // nothing to chain yet
  p.min_trunks = 0;
  TrunkAccumulator off(p);
  off.add(0.0, Pose::Identity(), own);
  const AccumulatedTrunks out = off.add(10.0, Pose::Identity(), own);
  EXPECT_EQ(out.submaps, 1);
  EXPECT_EQ(out.trunks.size(), 2u);
}

}  // namespace
}  // namespace dtif

namespace dtif {
namespace {

// Stems every 5 m along x (y alternating +-3 m), in O.
std::vector<Eigen::Vector4d> rowOfStems() {
  std::vector<Eigen::Vector4d> stems;
  for (int i = -4; i <= 16; ++i) stems.emplace_back(5.0 * i, i % 2 ? 3.0 : -3.0, 0.0, 0.2);
  return stems;
}

// The stems within `range` of the submap origin (horizontally), in its frame.
Trunks seenWithin(const Pose& T_O_S, const std::vector<Eigen::Vector4d>& stems_O, double range) {
  std::vector<Eigen::Vector4d> near;
  for (const auto& s : stems_O) {
    if (std::hypot(s.x() - T_O_S.translation().x(), s.y() - T_O_S.translation().y()) <= range) {
      near.push_back(s);
    }
  }
  return seenFrom(T_O_S, near);
}

TEST(TrunkAccumulator, ForwardUpdatesExtendStoredSubmapsWithTheirSuccessors) {
  MultiSubmapParams p;
  p.min_trunks = 100;     // every submap is extended
  p.target_trunks = 100;  // with every submap in reach
  p.forward_submaps = 2;
  p.open_stand_share = 0.0;
  const std::vector<Eigen::Vector4d> stems = rowOfStems();
  // The robot walks along x, 10 m per submap, turning slightly; each submap sees 12 m around.
  auto T = [](int k) { return pose(10.0 * k, 0.5 * k, 0.1 * k, 0.05 * k); };
  TrunkAccumulator acc(p);
  std::vector<ForwardUpdate> u;
  acc.add(0.0, T(0), seenWithin(T(0), stems, 12.0), &u);
  EXPECT_TRUE(u.empty());
  acc.add(10.0, T(1), seenWithin(T(1), stems, 12.0), &u);
  ASSERT_EQ(u.size(), 1u);
  EXPECT_EQ(u[0].stamp, 0.0);
  EXPECT_EQ(u[0].successors, 1);
  u.clear();
  const AccumulatedTrunks q2 = acc.add(20.0, T(2), seenWithin(T(2), stems, 12.0), &u);
  ASSERT_EQ(u.size(), 2u);  // submap 0 (2nd successor) and submap 1
  EXPECT_EQ(u[0].stamp, 0.0);
  EXPECT_EQ(u[1].stamp, 10.0);
  // The stem at x = 20 m: seen by submaps 1 and 2, not by 0 (20 m away); now in 0's entry, in
  // 0's frame. The query itself holds only its past.
  const Eigen::Vector3d p20 = T(0).inverse() * Eigen::Vector3d(20.0, -3.0, 0.0);
  EXPECT_TRUE(contains(u[0].trunks.trunks, p20, 1e-6));
  EXPECT_EQ(u[0].successors, 2);
  const Eigen::Vector3d p25 = T(2).inverse() * Eigen::Vector3d(25.0, 3.0, 0.0);
  EXPECT_FALSE(contains(q2.trunks, p25, 0.1)) << "seen by submap 2 only";
  // Submap 0 has had its forward_submaps successors: not described again.
  u.clear();
  acc.add(30.0, T(3), seenWithin(T(3), stems, 12.0), &u);
  ASSERT_EQ(u.size(), 2u);
  EXPECT_EQ(u[0].stamp, 10.0);
  EXPECT_EQ(u[1].stamp, 20.0);

  p.forward_submaps = 0;
  TrunkAccumulator none(p);
  u.clear();
  for (int k = 0; k < 4; ++k) none.add(10.0 * k, T(k), seenWithin(T(k), stems, 12.0), &u);
  EXPECT_TRUE(u.empty());
}

TEST(TrunkAccumulator, SubmapsWithEnoughStableTrunksAreNotDescribedAgain) {
  MultiSubmapParams p;
  p.min_trunks = 2;  // every submap but the first has >= 2 stems seen again
  p.forward_submaps = 3;
  p.open_stand_share = 0.0;
  const std::vector<Eigen::Vector4d> stems = rowOfStems();
  auto T = [](int k) { return pose(5.0 * k, 0, 0, 0); };
  TrunkAccumulator acc(p);
  std::vector<ForwardUpdate> u;
  for (int k = 0; k < 5; ++k) acc.add(10.0 * k, T(k), seenWithin(T(k), stems, 12.0), &u);
  EXPECT_TRUE(u.empty());
  EXPECT_FALSE(acc.openStand());
}

// A submap of `real` stems near x0 (seen by every submap) and `one_off` fits nowhere else.
Trunks standSubmap(double x0, int real, int one_off, int k) {
  Trunks t;
  for (int i = 0; i < real; ++i) t.push_back(trunk(3.0 * i - x0, i % 2 ? 2.0 : -2.0, 0.0, 0.2));
  for (int i = 0; i < one_off; ++i) {
    t.push_back(trunk(1.1 * i - x0, 6.0 + 1.3 * k, 0.0, 0.1));  // 1.3 m apart: never merged
  }
  return t;
}

// Open-stand thresholds as the defaults, medians from the third submap; min_trunks so low that
// alone it would keep every submap's own trunks.
MultiSubmapParams openStandParams(int forward_submaps) {
  MultiSubmapParams p;
  p.min_trunks = 2;
  p.open_stand_share = 0.4;
  p.open_stand_trunks = 13;
  p.open_stand_min_submaps = 3;
  p.forward_submaps = forward_submaps;
  return p;
}

TEST(TrunkAccumulator, OpenStandsAreDescribedWithStableStemsOnly) {
  const MultiSubmapParams p = openStandParams(0);
  // Open: 4 stems seen again among 16 one-off fits (share 0.2).
  TrunkAccumulator open(p);
  std::vector<AccumulatedTrunks> out;
  for (int k = 0; k < 5; ++k)
    out.push_back(open.add(10.0 * k, pose(k, 0, 0, 0), standSubmap(k, 4, 16, k)));
  EXPECT_EQ(out[1].trunks.size(), 20u);  // one submap counted: own trunks
  EXPECT_EQ(out[2].trunks.size(), 20u);
  EXPECT_FALSE(out[2].open_stand);
  for (int k = 3; k < 5; ++k) {
    EXPECT_TRUE(out[k].open_stand) << k;
    EXPECT_EQ(out[k].trunks.size(), 4u) << k;
  }
  EXPECT_TRUE(open.openStand());
  // Closed: 16 stems seen again among 4 one-offs (share 0.8): own trunks throughout.
  TrunkAccumulator closed(p);
  for (int k = 0; k < 5; ++k) {
    const AccumulatedTrunks a = closed.add(10.0 * k, pose(k, 0, 0, 0), standSubmap(k, 16, 4, k));
    EXPECT_EQ(a.trunks.size(), 20u) << k;
    EXPECT_FALSE(a.open_stand);
  }
  // Few stable stems but a high share (a small submap of a closed stand): not open either.
  TrunkAccumulator small(p);
  for (int k = 0; k < 5; ++k) {
    EXPECT_FALSE(small.add(10.0 * k, pose(k, 0, 0, 0), standSubmap(k, 4, 1, k)).open_stand);
  }
  // Many stable stems at a low share (a dense stand with clutter): not open.
  TrunkAccumulator dense(p);
  for (int k = 0; k < 5; ++k) {
    EXPECT_FALSE(dense.add(10.0 * k, pose(k, 0, 0, 0), standSubmap(k, 14, 40, k)).open_stand);
  }
}

TEST(TrunkAccumulator, SubmapsBeforeAnOpenStandIsKnownAreDescribedAgainWithStableStems) {
  const MultiSubmapParams p = openStandParams(4);
  // 4 stems seen again among 16 one-off fits: submaps 1 and 2 keep their own 20 trunks (the
  // medians need 3 submaps), yet each looks open on its own, so each keeps what a later
  // description takes (its frame).
  TrunkAccumulator open(p);
  std::vector<ForwardUpdate> u;
  for (int k = 0; k < 3; ++k) {
    const AccumulatedTrunks a = open.add(10.0 * k, pose(k, 0, 0, 0), standSubmap(k, 4, 16, k), &u);
    EXPECT_FALSE(a.open_stand) << k;
    EXPECT_EQ(a.trunks.size(), 20u) << k;
    EXPECT_TRUE(open.newestMayBeUpdated()) << k;
  }
  // The fourth submap makes the stand open: the three before it are described again with the
  // 4 stable stems.
  u.clear();
  const AccumulatedTrunks a3 = open.add(30.0, pose(3, 0, 0, 0), standSubmap(3, 4, 16, 3), &u);
  EXPECT_TRUE(a3.open_stand);
  ASSERT_EQ(u.size(), 3u);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(u[k].stamp, 10.0 * k);
    EXPECT_TRUE(u[k].trunks.open_stand) << k;
    EXPECT_EQ(u[k].trunks.trunks.size(), 4u) << k;
  }
  // A closed stand's submaps with enough stable trunks keep no frame: nothing to describe again.
  TrunkAccumulator closed(p);
  closed.add(0.0, pose(0, 0, 0, 0), standSubmap(0, 16, 4, 0), &u);
  for (int k = 1; k < 5; ++k) {
    closed.add(10.0 * k, pose(k, 0, 0, 0), standSubmap(k, 16, 4, k), &u);
    EXPECT_FALSE(closed.newestMayBeUpdated()) << k;
  }
}

TEST(MultiSubmapParams, ForwardAndOpenStandLimitsAreNamed) {
  MultiSubmapParams p;
  p.forward_submaps = -1;
  p.open_stand_share = 1.5;
  p.open_stand_min_submaps = 20;  // more than the window
  const std::string err = p.validate();
  EXPECT_NE(err.find("forward_submaps"), std::string::npos);
  EXPECT_NE(err.find("open_stand_share"), std::string::npos);
  EXPECT_NE(err.find("open_stand_min_submaps"), std::string::npos);
}

}  // namespace
}  // namespace dtif
