// Trunks as landmarks of the merged map: the association across submaps, and the map merger's
// refinement with them recovering what drifting odometry got wrong where no loop was found.
#include "dtif/core/merge/landmarks.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdio>
#include <random>

#include "dtif/core/merge/map_merger.h"
#include "test_utils.h"

namespace dtif {
namespace {

LandmarkObservation obs(size_t submap, double x, double y, double r) {
  LandmarkObservation o;
  o.submap = submap;
  o.p_M = o.p_S = Eigen::Vector3d(x, y, 0.0);
  o.r = r;
  return o;
}

TEST(AssociateLandmarks, JoinsOneTreeAcrossSubmapsOncePerSubmap) {
  const std::vector<LandmarkObservation> o = {
      obs(0, 0.0, 0.0, 0.2),   obs(0, 5.0, 0.0, 0.3),                          // submap 0
      obs(1, 0.1, 0.05, 0.21), obs(1, 0.15, 0.0, 0.2), obs(1, 5.0, 0.1, 0.3),  // submap 1
      obs(2, 5.05, 0.0, 0.6)};  // radius far off: not the tree at (5, 0)
  const auto groups = associateLandmarks(o, {});
  // (0, 0): submap 0's and the nearer of submap 1's two (mutual); (5, 0): submaps 0 and 1.
  ASSERT_EQ(groups.size(), 2u);
  EXPECT_EQ(groups[0], (std::vector<size_t>{0, 2}));
  EXPECT_EQ(groups[1], (std::vector<size_t>{1, 4}));
}

TEST(AssociateLandmarks, AmbiguousObservationsJoinNothing) {
  // Two trees 0.5 m apart: an observation half way is within the 0.3 m gate of both.
  const std::vector<LandmarkObservation> o = {obs(0, 0.0, 0.0, 0.2), obs(0, 0.5, 0.0, 0.2),
                                              obs(1, 0.25, 0.0, 0.2), obs(2, 0.0, 0.0, 0.2)};
  const auto groups = associateLandmarks(o, {});
  ASSERT_EQ(groups.size(), 1u);
  EXPECT_EQ(groups[0], (std::vector<size_t>{0, 3}));
}

// A submap in an open stand associates within the wider open_gate_m: its poses are looser, its
// trees far apart. Its own observations only: a dense stand's next to it keeps gate_m.
TEST(AssociateLandmarks, OpenStandObservationsUseTheWiderGate) {
  LandmarkObservation far = obs(1, 0.6, 0.0, 0.2);  // 0.6 m from the tree seen by submap 0
  const std::vector<LandmarkObservation> dense = {obs(0, 0.0, 0.0, 0.2), far};
  EXPECT_TRUE(associateLandmarks(dense, {}).empty());  // two trees of one sighting each
  far.open_stand = true;
  const auto groups = associateLandmarks({obs(0, 0.0, 0.0, 0.2), far}, {});
  ASSERT_EQ(groups.size(), 1u);
  EXPECT_EQ(groups[0], (std::vector<size_t>{0, 1}));
  far.p_M.x() = 0.9;  // beyond open_gate_m (0.8 m) too
  EXPECT_TRUE(associateLandmarks({obs(0, 0.0, 0.0, 0.2), far}, {}).empty());
  // Still unambiguous only: a second tree within the wider gate leaves it out.
  far.p_M.x() = 0.6;
  const auto two = associateLandmarks(
      {obs(0, 0.0, 0.0, 0.2), obs(0, 1.3, 0.0, 0.2), far, obs(2, 0.0, 0.0, 0.2)}, {});
  ASSERT_EQ(two.size(), 1u);
  EXPECT_EQ(two[0], (std::vector<size_t>{0, 3}));
}

/// Trees on a jittered 4 m grid over 60 m x 20 m (jitter 0 and one radius: a plantation).
std::vector<Eigen::Vector4d> forest(unsigned seed = 3, double jitter_m = 1.0) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-jitter_m, jitter_m),
      radius(0.1, jitter_m > 0.0 ? 0.3 : 0.1), ground(-0.3, 0.3);
  std::vector<Eigen::Vector4d> trees;  // x, y, base z, r
  for (int i = 0; i < 16; ++i) {
    for (int j = 0; j < 6; ++j) {
      const double x = -4.0 + 4.0 * i + jitter(rng), y = -10.0 + 4.0 * j + jitter(rng);
      const double z = ground(rng), r = radius(rng);
      trees.emplace_back(x, y, z, r);
    }
  }
  return trees;
}

/// The trees within 8 m of a submap, in its frame, with 1 cm of noise (fixed seed).
Trunks observe(const std::vector<Eigen::Vector4d>& trees, const Pose& T_W_S, std::mt19937* rng) {
  std::normal_distribution<double> noise(0.0, 0.01);
  Trunks out;
  for (const Eigen::Vector4d& t : trees) {
    const Eigen::Vector3d p = T_W_S.inverse() * t.head<3>();
    if (p.head<2>().norm() > 8.0) continue;
    TrunkLandmark tr;
    tr.x = p.x() + noise(*rng);
    tr.y = p.y() + noise(*rng);
    tr.z = p.z() + noise(*rng);
    tr.r = t(3);
    out.push_back(tr);
  }
  return out;
}

/// Robots a and b walk side by side 3 m apart along x, a submap every 4 m, seeing the same
/// trees. One inter-robot loop at the start joins them; none after. b's odometry drifts
/// (yaw 0.15 deg and 1 cm up per submap), so without landmarks its end is decimetres off; each
/// submap's error relative to its predecessor is within the association gate.
struct SideBySide {
  std::vector<MergeSubmap> submaps;
  std::map<int64_t, Pose> gt;
  Loop loop;
};

/// b_forest: the seed of the trees robot b sees (another forest than a's when not 3).
SideBySide sideBySide(unsigned b_forest = 3, double jitter_m = 1.0) {
  const auto trees = forest(3, jitter_m), b_trees = forest(b_forest, jitter_m);
  std::mt19937 rng(5);
  SideBySide sc;
  for (const std::string robot : {"a", "b"}) {
    const bool b = robot == "b";
    Pose T_O_S = Pose::Identity();
    for (int k = 0; k < 13; ++k) {
      const Pose T_W_S = test::makePose(4.0 * k, b ? 3.0 : 0.0, 0.0, 0.0, 0.0, 0.0);
      if (k > 0 && b) T_O_S = T_O_S * test::makePose(4.0, 0.0, 0.01, 0.0, 0.0, 0.15 * M_PI / 180);
      if (k > 0 && !b) T_O_S = T_O_S * test::makePose(4.0, 0.0, 0.0, 0.0, 0.0, 0.0);
      MergeSubmap s;
      s.robot = robot;
      s.id = (b ? 100 : 0) + k;
      s.stamp = k;
      s.T_O_S = T_O_S;
      s.trunks = observe(b ? b_trees : trees, T_W_S, &rng);
      sc.gt[s.id] = T_W_S;
      sc.submaps.push_back(s);
    }
  }
  sc.loop.query_id = 100;
  sc.loop.query_robot = "b";
  sc.loop.candidate_id = 0;
  sc.loop.candidate_robot = "a";
  sc.loop.T_c_q = sc.gt.at(0).inverse() * sc.gt.at(100);
  sc.loop.covariance = Matrix6d::Identity() * 1e-4;
  sc.loop.inliers = 10;
  return sc;
}

/// Where b's k-th submap is relative to a's k-th: the error of that relative pose.
std::pair<double, double> relativeError(const MapMerger& m, const SideBySide& sc, int k) {
  const Pose est = m.pose(k)->inverse() * *m.pose(100 + k);
  const Pose gt = sc.gt.at(k).inverse() * sc.gt.at(100 + k);
  const Pose e = gt.inverse() * est;
  return {e.translation().norm(), Eigen::AngleAxisd(e.linear()).angle()};
}

MapMerger mergeSideBySide(const SideBySide& sc, bool landmarks) {
  MergeParams p;
  p.landmarks = landmarks;
  MapMerger m(p);
  for (const auto& s : sc.submaps) m.addSubmap(s);
  EXPECT_TRUE(m.addLoop(sc.loop));
  m.refine();
  return m;
}

TEST(LandmarkRefinement, RecoversTheRelativePoseOfSubmapsThatOverlapWithoutALoop) {
  const SideBySide sc = sideBySide();
  const MapMerger plain = mergeSideBySide(sc, false);
  const auto [t0, r0] = relativeError(plain, sc, 12);
  EXPECT_GT(t0, 0.15);  // b's drift, uncorrected: one loop at the start is all the graph has
  EXPECT_GT(r0, 0.02);
  const MapMerger refined = mergeSideBySide(sc, true);
  // Along the whole walk, not just at the end. (Each robot's own path stays a compromise of
  // the two odometries: the trees say where b is relative to a, not which of them drifted.)
  for (int k = 0; k < 13; ++k) {
    const auto [t1, r1] = relativeError(refined, sc, k);
    EXPECT_LT(t1, 0.03) << k;
    EXPECT_LT(r1, 0.002) << k;
  }
}

TEST(LandmarkRefinement, CappedObservationsStillTieTheRobots) {
  const SideBySide sc = sideBySide();
  MergeParams p;
  p.landmark_max_observations = 0;  // all
  MapMerger all(p);
  p.landmark_max_observations = 3;
  MapMerger capped(p);
  for (MapMerger* m : {&all, &capped}) {
    for (const auto& s : sc.submaps) m->addSubmap(s);
    ASSERT_TRUE(m->addLoop(sc.loop));
  }
  const MergeSolveStats sa = all.refine(), sc3 = capped.refine();
  // Each tree is seen by up to 8 submaps here: the cap keeps 3 of them, spread over both robots.
  ASSERT_GT(sa.landmark_observations, 3 * sa.landmarks);
  EXPECT_LE(sc3.landmark_observations, 3 * sc3.landmarks);
  EXPECT_GE(sc3.landmark_observations, 2 * sc3.landmarks);
  // Fewer observations tie the robots less tightly than all of them (0.1 deg), but far better
  // than none (the end > 0.15 m and 1.1 deg off): within 3 cm and 0.25 deg all along.
  for (int k = 0; k < 13; ++k) {
    const auto [t, r] = relativeError(capped, sc, k);
    EXPECT_LT(t, 0.03) << k;
    EXPECT_LT(r, 0.25 * M_PI / 180.0) << k;
  }
  p.landmark_max_observations = 1;  // a landmark needs two observations to tie anything
  EXPECT_NE(p.validate().find("landmark_max_observations"), std::string::npos);
  MergeParams q;
  q.landmark_open_rounds = 0;
  EXPECT_NE(q.validate().find("landmark_open_rounds"), std::string::npos);
  q = MergeParams();
  q.landmark_open_gate_m = 0.0;
  EXPECT_NE(q.validate().find("landmark gate"), std::string::npos);
}

MapMerger mergeWithoutLoop(const SideBySide& sc, int join_min_pairs) {
  MergeParams p;
  p.join_min_pairs = join_min_pairs;
  MapMerger m(p);
  for (const auto& s : sc.submaps) m.addSubmap(s);
  m.solve();
  EXPECT_EQ(m.componentCount(), 2);  // no loop: each robot its own map
  m.refine();
  return m;
}

TEST(InventoryJoin, ARobotThatOverlapsWithoutALoopJoinsByItsStemInventory) {
  const SideBySide sc = sideBySide();
  const MapMerger off = mergeWithoutLoop(sc, 0);
  EXPECT_EQ(off.componentCount(), 2);
  MapMerger m = mergeWithoutLoop(sc, MergeParams().join_min_pairs);
  ASSERT_EQ(m.componentCount(), 1);
  const std::vector<MergeEvent> events = m.takeEvents();
  EXPECT_TRUE(std::any_of(events.begin(), events.end(), [](const MergeEvent& e) {
    return e.text.find("stem inventory") != std::string::npos;
  }));
  // The join loop and then the landmarks place b beside a all along (its drift included).
  for (int k = 0; k < 13; ++k) {
    const auto [t, r] = relativeError(m, sc, k);
    EXPECT_LT(t, 0.03) << k;
    EXPECT_LT(r, 0.25 * M_PI / 180.0) << k;
  }
}

TEST(InventoryJoin, ARobotInAnotherForestStaysApart) {
  // b walks the same path through other trees (a jittered grid of the same spacing and radii):
  // its inventory must not register to a's.
  const MapMerger m = mergeWithoutLoop(sideBySide(11), MergeParams().join_min_pairs);
  EXPECT_EQ(m.componentCount(), 2);
}

TEST(InventoryJoin, APlantationJoinsAtItsTruePlaceOrNotAtAll) {
  // On a perfect lattice every shift by the row spacing pairs as many stems: a join there
  // would put b 4 m off. The inventory registration must find the true place or none.
  const SideBySide sc = sideBySide(3, 0.0);
  const MapMerger m = mergeWithoutLoop(sc, MergeParams().join_min_pairs);
  std::printf("[ info ] plantation: %d component(s)\n", m.componentCount());
  if (m.componentCount() == 2) return;
  for (int k = 0; k < 13; ++k) {
    const auto [t, r] = relativeError(m, sc, k);
    EXPECT_LT(t, 0.05) << k;
    EXPECT_LT(r, 0.25 * M_PI / 180.0) << k;
  }
}

TEST(LandmarkRefinement, ChangesNothingWhenOff) {
  const SideBySide sc = sideBySide();
  MergeParams p;
  p.landmarks = false;
  MapMerger a(p), b(p);
  for (const auto& s : sc.submaps) {
    a.addSubmap(s);
    b.addSubmap(s);
  }
  a.addLoop(sc.loop);
  b.addLoop(sc.loop);
  a.solve();
  b.refine();
  for (const MergedPose& q : a.poses()) {
    EXPECT_TRUE(q.T_M_S.isApprox(*b.pose(q.id), 1e-12)) << q.id;
  }
}

TEST(LandmarkRefinement, ACopyRefinesWithoutTouchingTheOriginal) {
  // save_map refines a copy off the merge lock while the original goes on taking submaps.
  const SideBySide sc = sideBySide();
  MapMerger live;
  for (const auto& s : sc.submaps) live.addSubmap(s);
  ASSERT_TRUE(live.addLoop(sc.loop));
  live.solve();
  const std::vector<MergedPose> before = live.poses();
  MapMerger snapshot(live);
  snapshot.refine();
  const MapMerger refined_in_place = mergeSideBySide(sc, true);
  for (const MergedPose& q : before) {
    EXPECT_TRUE(live.pose(q.id)->isApprox(q.T_M_S, 1e-12)) << q.id;
    EXPECT_TRUE(snapshot.pose(q.id)->isApprox(*refined_in_place.pose(q.id), 1e-9)) << q.id;
  }
  const auto [t_live, r_live] = relativeError(live, sc, 12);
  const auto [t_snap, r_snap] = relativeError(snapshot, sc, 12);
  EXPECT_GT(t_live, 0.15);  // the original is still the plain solve
  EXPECT_LT(t_snap, 0.03);
  live = snapshot;  // copy-assigned: the refined map, and independent of the snapshot after
  snapshot.addSubmap([&] {
    MergeSubmap s = sc.submaps.back();
    s.id = 999;
    s.stamp += 1.0;
    return s;
  }());
  EXPECT_EQ(live.submapCount(), sc.submaps.size());
  EXPECT_EQ(snapshot.submapCount(), sc.submaps.size() + 1);
}

}  // namespace
}  // namespace dtif
