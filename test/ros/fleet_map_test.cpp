// The map merge nodelet's fleet bookkeeping without a master (ros_glue::FleetMap): chains and
// their frames, the merger's own ids, loops waiting for their submaps, submap clouds, an earlier
// run's database, and submap_ids.csv.
#include "dtif/ros/fleet_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "dtif/core/descriptor/descriptor.h"
#include "test_utils.h"

namespace dtif::ros_glue {
namespace {

Descriptor submap(const std::string& robot, int64_t id) {
  Descriptor d;
  d.robot = robot;
  d.submap_id = id;
  return d;
}

// A valid descriptor (a database holds only those): five trunks of a small stand.
std::shared_ptr<Descriptor> entry(const std::string& robot, int64_t id) {
  Trunks t;
  for (const auto& [x, y] :
       {std::pair{0.0, 0.0}, {4.0, 1.0}, {1.0, 5.0}, {6.0, 6.0}, {-3.0, 4.0}}) {
    TrunkLandmark l;
    l.x = x, l.y = y, l.z = 0.0, l.r = 0.15;
    t.push_back(l);
  }
  auto d = std::make_shared<Descriptor>(buildDescriptor(t, DescriptorParams{}));
  d->robot = robot;
  d->submap_id = id;
  return d;
}

Loop loop(const std::string& q, int64_t qi, const std::string& c, int64_t ci, double dx) {
  Loop l;
  l.query_robot = q, l.query_id = qi, l.candidate_robot = c, l.candidate_id = ci;
  l.T_c_q = test::makePose(dx, 0.0, 0.0, 0.0, 0.0, 0.0);
  return l;
}

TEST(FleetMap, EachRobotKeepsOneOdometryFrameAndBadSubmapsAreDroppedWithTheReason) {
  FleetMap m(MergeParams{}, {}, 0.1);
  EXPECT_EQ(m.addSubmap(submap("a", 0), "a/camera_init", 1.0, Pose::Identity()), "");
  EXPECT_EQ(m.addSubmap(submap("b", 0), "b/camera_init", 1.0, Pose::Identity()), "");
  EXPECT_EQ(m.addSubmap(submap("a", 0), "a/camera_init", 2.0, Pose::Identity()), "already merged");
  const std::string other = m.addSubmap(submap("a", 1), "camera_init", 2.0, Pose::Identity());
  EXPECT_NE(other.find("the robot's is a/camera_init"), std::string::npos) << other;
  EXPECT_NE(m.addSubmap(submap("a", 2), "", 3.0, Pose::Identity()), "");
  Pose nan = Pose::Identity();
  nan.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(m.addSubmap(submap("a", 3), "a/camera_init", 4.0, nan), "");
  EXPECT_EQ(m.merger().submapCount(), 2u);
  EXPECT_EQ(m.robotOfFrame("b/camera_init"), "b");
  EXPECT_EQ(m.robotOfFrame("camera_init"), "");
  ASSERT_EQ(m.chains().size(), 2u);
  EXPECT_TRUE(m.chains().at("a").live);
}

TEST(FleetMap, ALoopWaitsForItsSubmapsAndEntersUnderTheMergersIds) {
  FleetMap m(MergeParams{}, {}, 0.1);
  ASSERT_EQ(m.addSubmap(submap("a", 10), "a/odom", 1.0, Pose::Identity()), "");
  ASSERT_EQ(m.addSubmap(submap("b", 20), "b/odom", 1.5, Pose::Identity()), "");
  m.addLoop(loop("b", 20, "a", 11, 1.0));  // a's submap 11 has not come yet
  bool dropped = true;
  EXPECT_FALSE(m.addPendingLoops(10, nullptr, &dropped));
  EXPECT_FALSE(dropped);
  EXPECT_EQ(m.waitingLoops(), 1u);
  ASSERT_EQ(m.addSubmap(submap("a", 11), "a/odom", 2.0, test::makePose(1, 0, 0, 0, 0, 0)), "");
  std::vector<Loop> refused;
  EXPECT_TRUE(m.addPendingLoops(10, &refused, &dropped));
  EXPECT_TRUE(refused.empty());
  EXPECT_EQ(m.waitingLoops(), 0u);
  ASSERT_EQ(m.merger().loops().size(), 1u);
  // The merger numbers submaps as they come: a/10 -> 0, b/20 -> 1, a/11 -> 2.
  EXPECT_EQ(m.merger().loops()[0].query_id, 1);
  EXPECT_EQ(m.merger().loops()[0].candidate_id, 2);
  EXPECT_DOUBLE_EQ(m.stampOf(2), 2.0);

  // Loops of submaps that never come: beyond max_waiting the oldest goes.
  for (int k = 0; k < 3; ++k) m.addLoop(loop("b", 30 + k, "a", 10, 0.0));
  EXPECT_FALSE(m.addPendingLoops(2, &refused, &dropped));
  EXPECT_TRUE(dropped);
  EXPECT_EQ(m.waitingLoops(), 2u);
}

TEST(FleetMap, CloudsAreKeptInTheirSubmapFrameAndMergedInTheMapFrame) {
  FleetMap m(MergeParams{}, {}, 0.1);
  const Pose T_O_S = test::makePose(10.0, 5.0, 0.0, 0.0, 0.0, M_PI / 2);
  ASSERT_EQ(m.addSubmap(submap("a", 0), "a/odom", 7.0, T_O_S), "");
  Cloud in_O;
  for (const Eigen::Vector3d& p_S :
       {Eigen::Vector3d(1.0, 0.0, 0.5), Eigen::Vector3d(0.0, 2.0, 1.0)}) {
    const Eigen::Vector3d p_O = T_O_S * p_S;
    in_O.push_back(pcl::PointXYZ(p_O.x(), p_O.y(), p_O.z()));
  }
  EXPECT_EQ(m.addCloud("a", 7.5, in_O, {}), "matches no submap");
  EXPECT_EQ(m.addCloud("b", 7.0, in_O, {}), "matches no submap");
  ASSERT_EQ(m.addCloud("a", 7.0, in_O, {}), "");
  m.merger().solve();
  const std::vector<MergedPose> poses = m.merger().poses();
  ASSERT_EQ(poses.size(), 1u);
  const Cloud::Ptr merged = m.mergedCloud(poses, poses[0].component);
  ASSERT_TRUE(merged);
  ASSERT_EQ(merged->size(), 2u);
  for (const auto& p : *merged) {
    // Back in S through the submap's map pose: one of the two points, within float rounding.
    const Eigen::Vector3d p_S = poses[0].T_M_S.inverse() * p.getVector3fMap().cast<double>();
    const double d = std::min((p_S - Eigen::Vector3d(1.0, 0.0, 0.5)).norm(),
                              (p_S - Eigen::Vector3d(0.0, 2.0, 1.0)).norm());
    EXPECT_LT(d, 1e-4);
  }
  EXPECT_FALSE(m.mergedCloud(poses, poses[0].component + 1));
}

TEST(FleetMap, AnEarlierRunsDatabaseBecomesChainsOfItsOwnWithItsLoops) {
  LoopDetector db{LoopDetectorParams{}};
  ASSERT_TRUE(db.insert(entry("a", 0), {"a/odom", Pose::Identity()}));
  ASSERT_TRUE(db.insert(entry("b", 0), {"b/odom", test::makePose(0, 1, 0, 0, 0, 0)}));
  ASSERT_TRUE(db.insert(entry("c", 0)));  // no odometry: skipped
  db.recordLoop(loop("b", 0, "a", 0, 2.0));
  db.recordLoop(loop("c", 0, "a", 0, 2.0));  // c's submap is not placed

  FleetMap m(MergeParams{}, {}, 0.1);
  ASSERT_EQ(m.addSubmap(submap("z", 0), "z/odom", 1.0, Pose::Identity()), "");
  const FleetMap::Loaded n = m.loadDatabase(db);
  EXPECT_EQ(n.submaps, 2u);
  EXPECT_EQ(n.loops, 1u);
  EXPECT_EQ(n.without_odometry, 1u);
  ASSERT_EQ(m.chains().size(), 2u);  // z's chain went with the map it replaced
  EXPECT_FALSE(m.chains().at("a@database").live);
  EXPECT_EQ(m.chains().at("b@database").odom_frame, "b/odom");
  // The new run's robot a gets a live chain of its own beside a@database.
  EXPECT_EQ(m.addSubmap(submap("a", 5), "a/odom", 9.0, Pose::Identity()), "");
  EXPECT_TRUE(m.chains().at("a").live);

  m.merger().solve();
  const std::filesystem::path dir = test::freshTempDir("dtif_fleet_map_ids");
  const std::string path = (dir / "submap_ids.csv").string();
  m.writeSubmapIds(path, m.merger().poses());
  std::ifstream f(path);
  std::stringstream text;
  text << f.rdbuf();
  EXPECT_EQ(text.str().substr(0, text.str().find('\n')), "id,chain,robot,submap_id,stamp");
  EXPECT_NE(text.str().find("a@database,a,0,"), std::string::npos) << text.str();
  EXPECT_NE(text.str().find(",a,a,5,9\n"), std::string::npos) << text.str();
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
}

// A levelled entry holds its trunks in L: the merger takes them back in S, as from a live
// descriptor (the stems would otherwise stand tilted by the levelling in the map).
TEST(FleetMap, ALevelledDatabaseEntrysTrunksEnterTheMergerInS) {
  auto levelled = entry("a", 0);
  levelled->level_rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()));
  const Eigen::Vector3d p_L(1.0, 5.0, 0.0);  // the entry's third trunk
  LoopDetector db{LoopDetectorParams{}};
  ASSERT_TRUE(db.insert(levelled, {"a/odom", Pose::Identity()}));
  FleetMap m(MergeParams{}, {}, 0.1);
  ASSERT_EQ(m.loadDatabase(db).submaps, 1u);
  m.merger().refine();
  const Eigen::Vector3d p_S = levelled->level_rotation.conjugate() * p_L;
  ASSERT_FALSE(m.merger().stems().empty());
  double nearest = std::numeric_limits<double>::infinity();
  for (const MergedStem& s : m.merger().stems()) {
    nearest = std::min(nearest, std::hypot(s.x - p_S.x(), s.y - p_S.y()));
  }
  EXPECT_LT(nearest, 1e-6);  // in L it would be 5 (1 - cos 0.2) = 0.10 m off
}

}  // namespace
}  // namespace dtif::ros_glue
