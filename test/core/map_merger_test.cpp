// The map merger (core/merge): pose graph on drifting odometry and loops, PCM against a false
// loop, the trunks around a robot pair's only loop, components and their events, levelling of M.
#include "dtif/core/merge/map_merger.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

#include "dtif/core/merge/join_check.h"
#include "dtif/core/merge/pcm.h"
#include "test_utils.h"

namespace dtif {
namespace {

/// Two robots drive the same 40 m x 40 m square circuit (b starting a corner later), a submap
/// every 5 m, each back to its start (a loop closing its own circuit), and b's submaps close
/// loops with a's at the same places. Loops between parallel lines alone could not see a
/// common yaw drift; the circuits make it observable.
struct Scenario {
  std::vector<MergeSubmap> submaps;  // odometry with drift
  std::map<int64_t, Pose> gt;        // T_W_S
  std::vector<Loop> loops;           // true loops
};

constexpr int kA = 33, kB = 33;  // submaps per robot (k = 32 is back at the start)

Pose onSquare(double s, double z) {
  s = std::fmod(s, 160.0);
  if (s < 40.0) return test::makePose(s, 0.0, z, 0.0, 0.0, 0.0);
  if (s < 80.0) return test::makePose(40.0, s - 40.0, z, 0.0, 0.0, M_PI / 2);
  if (s < 120.0) return test::makePose(120.0 - s, 40.0, z, 0.0, 0.0, M_PI);
  return test::makePose(0.0, 160.0 - s, z, 0.0, 0.0, -M_PI / 2);
}

Pose gtPose(const std::string& robot, int k) {
  if (robot == "c") return onSquare(5.0 * k + 80.0, 1.0);
  return robot == "a" ? onSquare(5.0 * k, 0.0) : onSquare(5.0 * k + 40.0, 0.5);
}

/// Robot of a submap id: a from 0, b from 100, c from 200.
std::string robotOf(int64_t id) { return id >= 200 ? "c" : id >= 100 ? "b" : "a"; }

/// Odometry: the true increments with a yaw bias and noise (fixed seed), so that it drifts by
/// decimetres to metres over 200 m.
std::vector<MergeSubmap> drift(const std::string& robot, int n, double yaw_bias, std::mt19937* rng,
                               std::map<int64_t, Pose>* gt, int64_t first_id) {
  std::normal_distribution<double> nt(0.0, 0.01), nr(0.0, 0.001);
  std::vector<MergeSubmap> out;
  Pose T_O_S = Pose::Identity();
  for (int k = 0; k < n; ++k) {
    if (k > 0) {
      const Pose step = gtPose(robot, k - 1).inverse() * gtPose(robot, k);
      // One draw per statement, in the order gcc evaluated these arguments (last first), so the
      // data are the same whatever the compiler.
      double v[6];
      for (int i = 5; i >= 0; --i) v[i] = i < 3 ? nt(*rng) : nr(*rng);
      T_O_S = T_O_S * step * test::makePose(v[0], v[1], v[2], v[3], v[4], yaw_bias + v[5]);
    }
    MergeSubmap s;
    s.robot = robot;
    s.id = first_id + k;
    s.stamp = 10.0 * k;
    s.T_O_S = T_O_S;
    out.push_back(s);
    (*gt)[s.id] = gtPose(robot, k);
  }
  return out;
}

Loop makeLoop(const Scenario& sc, int64_t q, int64_t c, const Pose& noise) {
  Loop l;
  l.query_id = q;
  l.candidate_id = c;
  l.query_robot = robotOf(q);
  l.candidate_robot = robotOf(c);
  l.T_c_q = sc.gt.at(c).inverse() * sc.gt.at(q) * noise;
  l.covariance = Matrix6d::Identity() * 1e-4;
  l.inliers = 10;
  return l;
}

Scenario makeScenario() {
  Scenario sc;
  std::mt19937 rng(7);
  const auto a = drift("a", kA, 0.002, &rng, &sc.gt, 0);
  const auto b = drift("b", kB, -0.003, &rng, &sc.gt, 100);
  sc.submaps.insert(sc.submaps.end(), a.begin(), a.end());
  sc.submaps.insert(sc.submaps.end(), b.begin(), b.end());
  std::normal_distribution<double> nt(0.0, 0.01), nr(0.0, 0.001);
  auto noise = [&] {
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    double v[6];
    for (int k = 5; k >= 0; --k) v[k] = k < 3 ? nt(rng) : nr(rng);
    return test::makePose(v[0], v[1], v[2], v[3], v[4], v[5]);
  };
  sc.loops.push_back(makeLoop(sc, kA - 1, 0, noise()));  // a closes its circuit
  for (int k = 0; k + 8 < kA; k += 2) {
    sc.loops.push_back(makeLoop(sc, 100 + k, k + 8, noise()));  // b where a was
  }
  sc.loops.push_back(makeLoop(sc, 100 + kB - 1, 100, noise()));  // b closes its circuit
  return sc;
}

/// RMS position error after the least-squares rigid alignment.
double ate(const std::vector<std::pair<Pose, Pose>>& est_gt) {
  Eigen::Matrix3Xd a(3, est_gt.size()), b(3, est_gt.size());
  for (size_t i = 0; i < est_gt.size(); ++i) {
    a.col(i) = est_gt[i].first.translation();
    b.col(i) = est_gt[i].second.translation();
  }
  const Eigen::Matrix4d T = Eigen::umeyama(a, b, false);
  double ss = 0.0;
  for (size_t i = 0; i < est_gt.size(); ++i) {
    ss +=
        ((T.topLeftCorner<3, 3>() * a.col(i) + T.topRightCorner<3, 1>()) - b.col(i)).squaredNorm();
  }
  return std::sqrt(ss / est_gt.size());
}

double mergedAte(const MapMerger& m, const Scenario& sc) {
  std::vector<std::pair<Pose, Pose>> v;
  for (const MergedPose& p : m.poses()) v.emplace_back(p.T_M_S, sc.gt.at(p.id));
  return ate(v);
}

MapMerger merge(const Scenario& sc, const std::vector<Loop>& extra = {}, MergeParams p = {}) {
  MapMerger m(p);
  for (const auto& s : sc.submaps) m.addSubmap(s);
  for (const auto& l : sc.loops) EXPECT_TRUE(m.addLoop(l));
  for (const auto& l : extra) EXPECT_TRUE(m.addLoop(l));
  m.solve();
  return m;
}

TEST(MapMerger, RecoversTheTrajectoryFromDriftingOdometryAndLoops) {
  const Scenario sc = makeScenario();
  // The odometry of both robots in one frame (b placed by its first true pose) drifts apart.
  std::vector<std::pair<Pose, Pose>> odo;
  for (const auto& s : sc.submaps) {
    const Pose T_W_O = s.robot == "a" ? sc.gt.at(0) : sc.gt.at(100);
    odo.emplace_back(T_W_O * s.T_O_S, sc.gt.at(s.id));
  }
  const double odo_ate = ate(odo);
  const MapMerger m = merge(sc);
  EXPECT_EQ(m.componentCount(), 1);
  EXPECT_EQ(m.component("a"), 0);
  EXPECT_EQ(m.component("b"), 0);
  const double merged = mergedAte(m, sc);
  EXPECT_GT(odo_ate, 0.3);
  EXPECT_LT(merged, 0.05) << "odometry " << odo_ate;
  for (const LoopVerdict& v : m.loops()) EXPECT_TRUE(v.used);
}

TEST(MapMerger, ConjugateGradientsAgreeWithSparseCholesky) {
  const Scenario sc = makeScenario();
  MergeParams direct, iterative;
  direct.direct_solver_max_work = 1e300;
  iterative.direct_solver_max_work = 0.0;
  MapMerger md(direct), mi(iterative);
  for (MapMerger* m : {&md, &mi}) {
    for (const auto& s : sc.submaps) m->addSubmap(s);
    for (const auto& l : sc.loops) ASSERT_TRUE(m->addLoop(l));
  }
  EXPECT_FALSE(md.solve().iterative);
  EXPECT_TRUE(mi.solve().iterative);
  const std::vector<MergedPose> pd = md.poses(), pi = mi.poses();
  ASSERT_EQ(pd.size(), pi.size());
  double worst = 0.0;
  for (size_t i = 0; i < pd.size(); ++i) {
    worst = std::max(worst, (pd[i].T_M_S.translation() - pi[i].T_M_S.translation()).norm());
  }
  // eta = 0.01 gives ~2 mm on the soak test's 2,000-submap graph.
  EXPECT_LT(worst, 0.005);
  EXPECT_LT(mergedAte(mi, sc), 0.05);
}

TEST(MapMerger, PcmRejectsAFalseLoopAndTheMapDoesNotMove) {
  const Scenario sc = makeScenario();
  const MapMerger clean = merge(sc);
  // b's submap at (40, 20) "matched" a's at (20, 0), with a plausible pose.
  Loop wrong = makeLoop(sc, 104, 4, Pose::Identity());  // b at (40, 20), a at (20, 0)
  wrong.T_c_q = test::makePose(3.0, -2.0, 0.0, 0.0, 0.0, 0.4);
  const MapMerger m = merge(sc, {wrong});
  bool seen = false;
  for (const LoopVerdict& v : m.loops()) {
    if (v.query_id == 104 && v.candidate_id == 4) {
      EXPECT_FALSE(v.used);
      seen = true;
    } else {
      EXPECT_TRUE(v.used);
    }
  }
  EXPECT_TRUE(seen);
  for (const MergedPose& p : clean.poses()) {
    EXPECT_LT((m.pose(p.id)->translation() - p.T_M_S.translation()).norm(), 0.02) << p.id;
  }
  EXPECT_LT(std::fabs(mergedAte(m, sc) - mergedAte(clean, sc)), 0.02);
}

TEST(MapMerger, TheOnlyLoopOfTwoRobotsIsRejectedWhenPathsThroughAThirdContradictIt) {
  // c walks the circuit too; its first loop, with a, is false (turned 166 deg) and the only
  // a-c loop. It joins c to the map; then b-c loops arrive, and a-b are joined by many loops.
  Scenario sc = makeScenario();
  std::mt19937 rng(11);
  const auto c = drift("c", 24, 0.001, &rng, &sc.gt, 200);
  sc.submaps.insert(sc.submaps.end(), c.begin(), c.end());
  Loop wrong = makeLoop(sc, 202, 10, Pose::Identity());  // c at (10, 40), a at (50, 0)
  wrong.T_c_q = test::makePose(2.0, 1.0, 0.0, 0.0, 0.0, 2.9);
  std::vector<Loop> bc;
  for (int k = 0; k <= 8; k += 4)
    bc.push_back(makeLoop(sc, 200 + k, 100 + k + 8, Pose::Identity()));
  const MapMerger clean = merge(sc, bc);
  MapMerger m;
  for (const auto& s : sc.submaps) m.addSubmap(s);
  for (const auto& l : sc.loops) ASSERT_TRUE(m.addLoop(l));
  ASSERT_TRUE(m.addLoop(wrong));
  m.solve();
  EXPECT_EQ(m.component("c"), 0);  // joined by the false loop: nothing contradicts it yet
  for (const auto& l : bc) ASSERT_TRUE(m.addLoop(l));
  m.solve();
  EXPECT_EQ(m.component("c"), 0);
  for (const LoopVerdict& v : m.loops()) {
    EXPECT_EQ(v.used, !(v.query_id == 202 && v.candidate_id == 10)) << v.query_id;
  }
  for (const MergedPose& p : clean.poses()) {
    EXPECT_LT((m.pose(p.id)->translation() - p.T_M_S.translation()).norm(), 0.02) << p.id;
  }
  // One true a-c loop besides the b-c paths: it agrees with them and stays.
  MapMerger ok;
  for (const auto& s : sc.submaps) ok.addSubmap(s);
  for (const auto& l : sc.loops) ASSERT_TRUE(ok.addLoop(l));
  for (const auto& l : bc) ASSERT_TRUE(ok.addLoop(l));
  ASSERT_TRUE(ok.addLoop(makeLoop(sc, 202, 18, Pose::Identity())));  // c at (10, 40) = a's 18
  ok.solve();
  for (const LoopVerdict& v : ok.loops()) EXPECT_TRUE(v.used) << v.query_id;
}

/// A stand of trunks around the circuits (one every ~20 m^2, fixed seed) and each submap's
/// trunks within 12 m of it, in its own frame S; and only the robots' own loops (a and b never
/// meet in the loops).
Scenario withTrunksApart(Scenario sc) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-15.0, 55.0), radius(0.1, 0.3);
  std::vector<Eigen::Vector3d> stand;  // x, y, r in W
  for (int i = 0; i < 245; ++i) {
    const double x = u(rng), y = u(rng);
    stand.emplace_back(x, y, radius(rng));
  }
  for (MergeSubmap& s : sc.submaps) {
    const Pose T_S_W = sc.gt.at(s.id).inverse();
    for (const Eigen::Vector3d& t : stand) {
      const Eigen::Vector3d p = T_S_W * Eigen::Vector3d(t.x(), t.y(), 0.0);
      if (p.head<2>().norm() > 12.0) continue;
      TrunkLandmark l;
      l.x = p.x(), l.y = p.y(), l.z = p.z(), l.r = t.z();
      s.trunks.push_back(l);
    }
  }
  std::vector<Loop> own;
  for (const Loop& l : sc.loops) {
    if (l.query_robot == l.candidate_robot) own.push_back(l);
  }
  sc.loops = own;
  return sc;
}

bool usedLoop(const MapMerger& m, int64_t q, int64_t c) {
  for (const LoopVerdict& v : m.loops()) {
    if (v.query_id == q && v.candidate_id == c) return v.used;
  }
  ADD_FAILURE() << "no verdict for " << q << " -> " << c;
  return false;
}

TEST(JoinCheck, TrunksAgreeOnlyWhereTheyLieOnEachOtherAndWhereBothSidesSaw) {
  JoinSide a, b;
  a.origins = {{0.0, 0.0}};
  b.origins = {{2.0, 0.0}};
  a.trunks = {{1.0, 1.0}, {-3.0, 2.0}, {30.0, 0.0}};  // the last: beyond b's zone
  b.trunks = {{1.2, 1.1}, {-3.0, 4.0}};               // the second: 2 m from a's
  const TrunkAgreement ag = trunkAgreement(a, b, 8.0, 0.5);
  EXPECT_EQ(ag.compared, 4);  // a's first two, b's two
  EXPECT_EQ(ag.matched, 2);   // (1, 1) and (1.2, 1.1), each way
  EXPECT_DOUBLE_EQ(ag.fraction(), 0.5);
  EXPECT_EQ(trunkAgreement(a, JoinSide{}, 8.0, 0.5).compared, 0);
}

TEST(MapMerger, TheOnlyLoopOfTwoRobotsIsRejectedWhenTheirTrunksAroundItDisagree) {
  // a and b, no third robot: PCM cannot compare their one loop with anything.
  const Scenario sc = withTrunksApart(makeScenario());
  Loop wrong = makeLoop(sc, 104, 4, Pose::Identity());  // b at (40, 20), a at (20, 0)
  wrong.T_c_q = test::makePose(3.0, -2.0, 0.0, 0.0, 0.0, 0.4);
  const Loop right = makeLoop(sc, 110, 18, Pose::Identity());  // both at (30, 40)
  MapMerger m = merge(sc, {wrong});
  EXPECT_FALSE(usedLoop(m, 104, 4));
  EXPECT_NE(m.component("b"), m.component("a"));
  ASSERT_TRUE(m.addLoop(right));  // a true loop joins them, the false one stays out
  m.solve();
  EXPECT_TRUE(usedLoop(m, 110, 18));
  EXPECT_FALSE(usedLoop(m, 104, 4));
  EXPECT_EQ(m.component("b"), m.component("a"));
  EXPECT_LT(mergedAte(m, sc), 0.1);

  // An aliased pattern: b's submap holds a's trunks as the false pose would lay them, so the
  // two submaps agree; their neighbours do not.
  Scenario aliased = sc;
  for (MergeSubmap& s : aliased.submaps) {
    if (s.id != 104) continue;
    s.trunks.clear();
    for (const TrunkLandmark& t : aliased.submaps[4].trunks) {
      const Eigen::Vector3d p = wrong.T_c_q.inverse() * Eigen::Vector3d(t.x, t.y, t.z);
      s.trunks.push_back({p.x(), p.y(), p.z(), t.r, true});
    }
  }
  EXPECT_FALSE(usedLoop(merge(aliased, {wrong}), 104, 4));

  // Without the check, or without trunks to compare, the false loop joins b to a.
  MergeParams off;
  off.pcm_single_loop_trunks = false;
  EXPECT_TRUE(usedLoop(merge(sc, {wrong}, off), 104, 4));
  EXPECT_TRUE(usedLoop(merge(withTrunksApart(makeScenario()), {right}), 110, 18));
  Scenario bare = sc;
  for (MergeSubmap& s : bare.submaps) s.trunks.clear();
  EXPECT_TRUE(usedLoop(merge(bare, {wrong}), 104, 4));
}

TEST(MapMerger, RobustLossAloneLimitsAFalseLoop) {
  // Without PCM the false loop is in the solve; the Cauchy loss keeps it from tearing the map.
  const Scenario sc = makeScenario();
  Loop wrong = makeLoop(sc, 104, 4, Pose::Identity());  // b at (40, 20), a at (20, 0)
  wrong.T_c_q = test::makePose(3.0, -2.0, 0.0, 0.0, 0.0, 0.4);
  MergeParams p;
  p.pcm = false;
  const MapMerger m = merge(sc, {wrong}, p);
  EXPECT_LT(mergedAte(m, sc), 0.25);
}

TEST(MapMerger, LoopsOfSubmapsInAnOpenStandGetTheWiderFloor) {
  // b's submaps from 104 on are in an open stand: the loops of those are weighted at
  // loop_open_sigma_xy_min_m horizontally, the others at loop_sigma_xy_min_m; the loops' own
  // covariance (1 cm) is below both.
  Scenario sc = makeScenario();
  for (MergeSubmap& s : sc.submaps) s.open_stand = s.id >= 104;
  const MapMerger m = merge(sc);
  const MergeParams& p = m.params();
  ASSERT_GT(p.loop_open_sigma_xy_min_m, p.loop_sigma_xy_min_m);
  int open = 0, other = 0;
  for (const MergeGraphEdge& e : m.graphEdges()) {
    if (!e.loop) continue;
    const bool is_open = e.from >= 104 || e.to >= 104;
    const double sigma_xy = is_open ? p.loop_open_sigma_xy_min_m : p.loop_sigma_xy_min_m;
    ++(is_open ? open : other);
    for (int i : {0, 1}) {
      EXPECT_NEAR(e.information(i, i), 1.0 / (sigma_xy * sigma_xy), 1e-6) << e.from << "-" << e.to;
    }
    EXPECT_NEAR(e.information(2, 2), 1.0 / (p.loop_sigma_z_min_m * p.loop_sigma_z_min_m), 1e-6);
  }
  EXPECT_GT(open, 0);
  EXPECT_GT(other, 0);
}

TEST(MapMerger, ComponentsJoinWithAnEvent) {
  const Scenario sc = makeScenario();
  MapMerger m;
  for (const auto& s : sc.submaps) m.addSubmap(s);
  m.solve();
  EXPECT_EQ(m.componentCount(), 2);
  EXPECT_EQ(m.component("a"), 0);
  EXPECT_EQ(m.component("b"), 1);
  EXPECT_EQ(m.takeEvents().size(), 2u);  // both start
  ASSERT_TRUE(m.addLoop(makeLoop(sc, 100, 8, Pose::Identity())));
  m.solve();
  EXPECT_EQ(m.componentCount(), 1);
  EXPECT_EQ(m.component("b"), 0);
  const auto events = m.takeEvents();
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().robot, "b");
  EXPECT_EQ(events.back().from_component, 1);
  EXPECT_EQ(events.back().to_component, 0);
  // b's map-from-odometry maps its latest submap's odometry pose onto its merged pose.
  const Pose T_M_O = *m.mapFromOdom("b");
  const MergeSubmap& last = sc.submaps.back();
  EXPECT_TRUE((T_M_O * last.T_O_S).isApprox(*m.pose(last.id), 1e-9));
}

TEST(MapMerger, UnknownSubmapsAndBadPosesAreRefused) {
  const Scenario sc = makeScenario();
  MapMerger m;
  m.addSubmap(sc.submaps[0]);
  EXPECT_THROW(m.addSubmap(sc.submaps[0]), std::invalid_argument);
  MergeSubmap nan = sc.submaps[1];
  nan.T_O_S.translation().x() = std::nan("");
  EXPECT_THROW(m.addSubmap(nan), std::invalid_argument);
  EXPECT_FALSE(m.addLoop(sc.loops.front()));  // its query, submap 32, is unknown
  EXPECT_EQ(m.submapCount(), 1u);
}

TEST(MapMerger, LevellingMakesMGravityAligned) {
  // Robot a's odometry frame is tilted 10 deg (upstream FAST-LIO2): S is tilted the same way.
  const Scenario sc = makeScenario();
  const Eigen::Matrix3d R_tilt =
      test::makePose(0, 0, 0, 0.12, -0.1, 0.0).linear();  // roll, pitch of S from gravity
  MapMerger m;
  m.setLevelling("a", R_tilt);  // O -> level (here S keeps the tilt of O whatever its heading)
  for (const auto& s : sc.submaps) {
    if (s.robot != "a") continue;
    MergeSubmap t = s;
    Pose tilt = Pose::Identity();
    tilt.linear() = R_tilt.transpose();
    t.T_O_S = tilt * s.T_O_S * tilt.inverse();  // the same motion seen in tilted frames
    m.addSubmap(t);
  }
  m.solve();
  for (const MergedPose& p : m.poses()) {
    const Eigen::Vector3d up_S_est = p.T_M_S.linear().transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d up_S_true =
        R_tilt.transpose() * sc.gt.at(p.id).linear().transpose() * Eigen::Vector3d::UnitZ();
    const double angle = std::acos(std::min(1.0, up_S_est.dot(up_S_true)));
    // The anchor exactly; the others up to the odometry's roll/pitch random walk (1 mrad/step).
    EXPECT_LT(angle, p.id == 0 ? 1e-6 : 0.02) << p.id;
  }
}

TEST(MapMerger, LevellingOfTheLatestSubmapLevelsTheAnchorOfItsTurnedFrame) {
  // Upstream FAST-LIO2 as the simulator models it: O is tilted from gravity and every submap
  // frame S keeps O's z, turned about it by the heading. Gravity in S then turns with the
  // heading: the latest submap's R_L_S does not level the first one (it did, before: M was
  // tilted by up to twice the tilt on fastlio_stock, its inventory scattered).
  const Scenario sc = makeScenario();
  const Eigen::Matrix3d R_Ot_O = test::makePose(0, 0, 0, 0.15, -0.1, 0.0).linear();  // O -> O'
  MapMerger m;
  std::vector<MergeSubmap> tilted;
  for (const auto& s : sc.submaps) {
    if (s.robot != "a" || s.id > 24) continue;  // the last one heads -90 deg, the first 0 deg
    MergeSubmap t = s;
    t.T_O_S.translation() = R_Ot_O * s.T_O_S.translation();  // the same path, seen in O'
    tilted.push_back(t);
  }
  // Up in the S frame of submap k: R_O_S^T R_Ot_O z (S keeps O's z and O' is O tilted).
  auto upInS = [&](const MergeSubmap& s) {
    return Eigen::Vector3d(s.T_O_S.linear().transpose() * R_Ot_O * Eigen::Vector3d::UnitZ());
  };
  const MergeSubmap& last = tilted.back();
  const Eigen::Matrix3d R_L_S =
      Eigen::Quaterniond::FromTwoVectors(upInS(last), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  m.setLevelling("a", levellingInOdom(R_L_S, last.T_O_S));
  for (const auto& t : tilted) m.addSubmap(t);
  m.solve();
  for (const MergedPose& p : m.poses()) {
    const Eigen::Vector3d up_S_est = p.T_M_S.linear().transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d up_S_true = upInS(tilted.at(static_cast<size_t>(p.id)));
    EXPECT_LT(std::acos(std::min(1.0, up_S_est.dot(up_S_true))), 1e-6) << p.id;
  }
}

// A descriptor of accumulated trunks (open stands) gives the merger what its submap observed,
// back in S: a predecessor's stem carried in by odometry is no sighting of this submap.
TEST(MergeSubmapOf, TakesTheSubmapsOwnTrunksBackInS) {
  Descriptor d;
  d.robot = "a";
  d.submap_id = 4;
  d.stamp = 12.5;
  d.level_rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()));
  d.trunks = {TrunkLandmark{1.0, 2.0, 0.0, 0.2, true}, TrunkLandmark{-4.0, 3.0, 0.5, 0.3, false}};
  const Pose T_O_S = Pose::Identity();
  MergeSubmap own_only = mergeSubmapOf(d, T_O_S);
  ASSERT_EQ(own_only.trunks.size(), 2u);  // not accumulated: its trunks are its own

  d.accumulated = true;
  d.own_trunks = {TrunkLandmark{5.0, -1.0, 0.2, 0.25, true}};
  const MergeSubmap s = mergeSubmapOf(d, T_O_S);
  EXPECT_EQ(s.robot, "a");
  EXPECT_EQ(s.id, 4);
  ASSERT_EQ(s.trunks.size(), 1u);
  const Eigen::Vector3d p_S =
      d.level_rotation.conjugate() * Eigen::Vector3d(5.0, -1.0, 0.2);  // L back to S
  EXPECT_NEAR(s.trunks[0].x, p_S.x(), 1e-9);
  EXPECT_NEAR(s.trunks[0].y, p_S.y(), 1e-9);
  EXPECT_NEAR(s.trunks[0].z, p_S.z(), 1e-9);
  EXPECT_EQ(s.trunks[0].r, 0.25);

  d.own_trunks.clear();  // accumulated, and the submap saw nothing itself
  EXPECT_TRUE(mergeSubmapOf(d, T_O_S).trunks.empty());
}

TEST(Pcm, MaximumCliqueIsExactAndDeterministic) {
  // 0-1-2 a triangle, 3-4-5-6 a 4-clique, 7 alone.
  ConsistencyGraph g(8, std::vector<bool>(8, false));
  auto link = [&](size_t a, size_t b) { g[a][b] = g[b][a] = true; };
  link(0, 1), link(1, 2), link(0, 2);
  link(3, 4), link(3, 5), link(3, 6), link(4, 5), link(4, 6), link(5, 6);
  link(2, 3);
  EXPECT_EQ(maximumClique(g), (std::vector<size_t>{3, 4, 5, 6}));
  // The greedy fallback (grown from the best-connected vertex) finds it here too.
  EXPECT_EQ(maximumClique(g, 0), (std::vector<size_t>{3, 4, 5, 6}));
  ConsistencyGraph ties(2, std::vector<bool>(2, false));
  EXPECT_EQ(maximumClique(ties), (std::vector<size_t>{0}));
  EXPECT_TRUE(maximumClique({}).empty());
}

bool isClique(const ConsistencyGraph& g, const std::vector<size_t>& c) {
  for (size_t i = 0; i < c.size(); ++i) {
    for (size_t j = i + 1; j < c.size(); ++j) {
      if (!g[c[i]][c[j]]) return false;
    }
  }
  return true;
}

ConsistencyGraph randomGraph(size_t n, double density, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  ConsistencyGraph g(n, std::vector<bool>(n, false));
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j) g[i][j] = g[j][i] = u(rng) < density;
  }
  return g;
}

// The lexicographically first of the largest cliques, by enumerating every vertex subset.
std::vector<size_t> bruteForceClique(const ConsistencyGraph& g) {
  const size_t n = g.size();
  std::vector<size_t> best;
  for (uint32_t mask = 0; mask < (1u << n); ++mask) {
    std::vector<size_t> c;
    for (size_t i = 0; i < n; ++i) {
      if (mask & (1u << i)) c.push_back(i);
    }
    if (c.size() < best.size() || !isClique(g, c)) continue;
    if (c.size() > best.size() || c < best) best = c;
  }
  return best;
}

TEST(Pcm, TheColouringBoundKeepsTheExactAnswer) {
  for (unsigned seed = 1; seed <= 30; ++seed) {
    const double density = 0.3 + 0.02 * seed;  // 0.32 .. 0.9
    const ConsistencyGraph g = randomGraph(14, density, seed);
    EXPECT_EQ(maximumClique(g), bruteForceClique(g)) << "seed " << seed;
  }
}

// Hundreds of mostly consistent loops of one robot pair (the soak test's hour: PCM's search
// with the size bound alone ran for minutes there): the exact answer, here the 190 consistent
// loops, and with a budget of one step a valid clique no smaller than the greedy one.
TEST(Pcm, DenseLoopSetsAreSolvedAndTheBudgetKeepsAClique) {
  const size_t n = 200;
  ConsistencyGraph g(n, std::vector<bool>(n, true));
  for (size_t i = 0; i < n; ++i) g[i][i] = false;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (size_t bad = 0; bad < n; bad += 20) {  // 10 false loops, each consistent with ~30 %
    for (size_t j = 0; j < n; ++j) {
      if (j != bad) g[bad][j] = g[j][bad] = u(rng) < 0.3;
    }
  }
  const std::vector<size_t> c = maximumClique(g);
  EXPECT_TRUE(isClique(g, c));
  EXPECT_EQ(c.size(), 190u);
  for (size_t bad = 0; bad < n; bad += 20) {
    EXPECT_FALSE(std::binary_search(c.begin(), c.end(), bad)) << bad;
  }
  const std::vector<size_t> capped = maximumClique(g, 200, 1);
  EXPECT_TRUE(isClique(g, capped));
  EXPECT_GE(capped.size(), maximumClique(g, 0).size());
}

}  // namespace
}  // namespace dtif
