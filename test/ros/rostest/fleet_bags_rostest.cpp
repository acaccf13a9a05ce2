// Integration test run by test/fleet_bags.test: stock FAST-LIO2 units whose bags were recorded
// separately. The .test file launches what README "Your own FAST-LIO2 units and bags" tells a user
// to: base_station.launch for alpha and bravo, and dtif.launch fleet:=true per unit. This node
// simulates a scene (~scene, tiny) with dtif simulate --bag-layout fastlio (a bag per unit, all
// with /cloud_registered, /Odometry, /tf in frames camera_init and body), plays each unit's bag
// with the README's remaps into the unit's namespace (no shared clock), and asserts that
//  - while no bag plays, each unit warns naming the topic it waits on;
//  - descriptors and loop closures carry robot-qualified frames (<robot>/camera_init);
//  - TF links the odometry frames of every pair of robots that has an inter-robot loop, within
//    tolerance of ground truth at the robots' latest submaps, and every unit's body frame is in
//    the first robot's tree (all robots joined);
//  - every loop closure is a true positive of the evaluation protocol;
//  - each robot's submaps are levelled to within 1.5 deg of gravity (~scene_append may tilt the
//    units' camera_init, as upstream FAST-LIO2 leaves it).
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <map>
#include <set>
#include <thread>

#include "dtif/eval/evaluation.h"
#include "dtif/io/dataset.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/msgs.h"
#include "dtif_test/test_config.h"
#include "rostest_utils.h"

namespace dtif {
namespace {

using test::findSubmap;
using test::Inbox;
using test::waitFor;
namespace fs = std::filesystem;

Pose toPose(const geometry_msgs::Transform& t) {
  return Eigen::Translation3d(t.translation.x, t.translation.y, t.translation.z) *
         Eigen::Quaterniond(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z);
}

// The README's command for one unit's bag: its stock topics into the unit's namespace, the
// unit's own /tf (camera_init -> body, the same names on every unit) out of the way.
std::string playCommand(const std::string& bag, const std::string& robot, double rate,
                        const std::string& log) {
  return "rosbag play --quiet --delay 1 --rate " + std::to_string(rate) + " " + bag +
         " /cloud_registered:=/" + robot + "/cloud_registered /Odometry:=/" + robot +
         "/Odometry /tf:=/" + robot + "/fastlio_tf > " + log + " 2>&1";
}

using Positions = std::map<std::pair<std::string, int64_t>, int>;  // (robot, id) -> dataset
using Descriptors = std::vector<dtif::TrunkDescriptor::ConstPtr>;
using LastDescriptors = std::map<std::string, dtif::TrunkDescriptor::ConstPtr>;  // per robot
using PairLoops = std::map<std::pair<std::string, std::string>, dtif::LoopClosure::ConstPtr>;

// Before any bag plays, each unit names the topics it waits on (after input_timeout_s, 10 s).
void expectWaitingWarnings(Inbox<rosgraph_msgs::Log>* log, const std::vector<std::string>& robots) {
  auto warned = [&](const std::string& text) {
    for (const auto& m : log->all()) {
      if (m->level == rosgraph_msgs::Log::WARN && m->msg.find(text) != std::string::npos) {
        return true;
      }
    }
    return false;
  };
  for (const std::string& r : robots) {
    for (const std::string topic : {"cloud_registered", "Odometry"}) {
      const std::string text = "waiting for /" + r + "/" + topic + ": no message in ";
      EXPECT_TRUE(waitFor([&] { return warned(text); }, 30.0)) << text;
    }
  }
}

// Each unit's bag played on its own, as recorded on the unit (no shared clock); false when a
// player failed.
bool playUnitBags(const fs::path& dir, const std::vector<std::string>& robots, double rate) {
  std::vector<std::thread> players;
  std::vector<int> status(robots.size(), -1);
  for (size_t i = 0; i < robots.size(); ++i) {
    const std::string cmd = playCommand((dir / ("unit_" + robots[i] + ".bag")).string(), robots[i],
                                        rate, (dir / ("play_" + robots[i] + ".log")).string());
    players.emplace_back([&status, i, cmd] { status[i] = std::system(cmd.c_str()); });
  }
  for (auto& p : players) p.join();
  bool ok = true;
  for (size_t i = 0; i < robots.size(); ++i) {
    EXPECT_EQ(status[i], 0) << robots[i];
    ok = ok && status[i] == 0;
  }
  return ok;
}

// Frames: the robot's own, whatever the unit called it; where each submap is in the dataset.
Positions expectQualifiedFrames(const Dataset& ds, const Descriptors& descriptors) {
  Positions position;
  for (const auto& d : descriptors) {
    EXPECT_EQ(d->header.frame_id, d->robot + "/camera_init");
    const int i = findSubmap(ds, d->robot, d->header.stamp.toSec());
    EXPECT_GE(i, 0) << d->robot << " submap at " << d->header.stamp << " is not in the dataset";
    if (i >= 0) position[{d->robot, d->submap_id}] = i;
  }
  EXPECT_EQ(position.size(), ds.submaps.size());
  return position;
}

// Levelling: each robot's last descriptor was extracted in a frame whose z is gravity's up,
// whatever its camera_init's tilt (the levelling error of `dtif eval` on these submaps).
LastDescriptors expectLevelled(const Dataset& ds, const Positions& position,
                               const Descriptors& descriptors) {
  LastDescriptors last;
  for (const auto& d : descriptors) last[d->robot] = d;
  for (const auto& [robot, d] : last) {
    const auto& q = d->level_rotation;
    const Eigen::Quaterniond R_L_S(q.w, q.x, q.y, q.z);
    const Pose& T_W_S = ds.T_W_S.at(ds.submaps[position.at({robot, d->submap_id})].id);
    const Eigen::Vector3d up_L =
        R_L_S.normalized() * (T_W_S.linear().transpose() * Eigen::Vector3d::UnitZ());
    const double err_deg = std::acos(std::clamp(up_L.z(), -1.0, 1.0)) * 180.0 / M_PI;
    std::cout << robot << ": levelled " << Eigen::AngleAxisd(R_L_S).angle() * 180.0 / M_PI
              << " deg, " << err_deg << " deg from gravity\n";
    EXPECT_LE(err_deg, 1.5) << robot;
  }
  return last;
}

// Loops: true positives of the protocol, in the candidate's qualified frame; returns the latest
// inter-robot loop of each pair of robots.
PairLoops expectTrueLoops(const Dataset& ds, const Positions& position,
                          const std::vector<dtif::LoopClosure::ConstPtr>& loops) {
  PairLoops latest;
  for (const auto& lc : loops) {
    EXPECT_EQ(lc->header.frame_id, lc->candidate_robot + "/camera_init");
    const int q = position.at({lc->query_robot, lc->query_id});
    const int c = position.at({lc->candidate_robot, lc->candidate_id});
    Pose T_c_q;
    EXPECT_TRUE(ros_glue::fromMsg(lc->T_c_q, &T_c_q));
    const int64_t qid = ds.submaps[q].id, cid = ds.submaps[c].id;
    const PoseError e = poseError(ds.T_W_S.at(cid).inverse() * ds.T_W_S.at(qid), T_c_q);
    EXPECT_LE(e.rot_deg, 2.0) << qid << " -> " << cid;
    EXPECT_LE(e.trans_m, 0.5) << qid << " -> " << cid;
    std::cout << "loop " << lc->query_robot << " " << qid << " -> " << lc->candidate_robot << " "
              << cid << ": " << e.rot_deg << " deg, " << e.trans_m << " m\n";
    if (lc->query_robot != lc->candidate_robot) {
      latest[std::minmax(lc->query_robot, lc->candidate_robot)] = lc;
    }
  }
  return latest;
}

// TF between the odometry frames of each linked pair, against ground truth at each robot's
// latest submap: the map merge places a robot's odometry frame by its latest submap (where the
// robot is now), so on long routes the TF drifts away from older loops' submaps by the
// odometry's own drift. It must put the query robot's latest submap where it truly is in the
// candidate's odometry frame, T_Oc_Sq = T_Oc_Sc * inverse(T_W_Sc) * T_W_Sq: within 1 deg, and
// within 0.5 m (a true loop's tolerance) plus what 0.5 deg of relative rotation moves a point
// at the two submaps' distance (the robots may be 70 m apart; the merged map's own accuracy
// is checked by map_merge.test).
void expectTfBetweenLinkedRobots(const tf2_ros::Buffer& tf_buffer, const Dataset& ds,
                                 const Positions& position, const LastDescriptors& last,
                                 const PairLoops& latest) {
  for (const auto& [pair, lc] : latest) {
    const std::string fc = lc->candidate_robot + "/camera_init";
    const std::string fq = lc->query_robot + "/camera_init";
    std::string error;
    const bool linked = tf_buffer.canTransform(fc, fq, ros::Time(0), ros::Duration(5.0), &error);
    EXPECT_TRUE(linked) << error;
    if (!linked) continue;
    const Pose T_Oc_Oq = toPose(tf_buffer.lookupTransform(fc, fq, ros::Time(0)).transform);
    const auto& dq = last.at(lc->query_robot);
    const auto& dc = last.at(lc->candidate_robot);
    const auto& sq = ds.submaps[position.at({lc->query_robot, dq->submap_id})];
    const auto& sc = ds.submaps[position.at({lc->candidate_robot, dc->submap_id})];
    const Pose truth = sc.T_O_S * ds.T_W_S.at(sc.id).inverse() * ds.T_W_S.at(sq.id);
    const PoseError e = poseError(truth, T_Oc_Oq * sq.T_O_S);
    const double apart_m =
        (ds.T_W_S.at(sc.id).translation() - ds.T_W_S.at(sq.id).translation()).norm();
    const double tol_m = 0.5 + apart_m * std::sin(0.5 * M_PI / 180.0);
    std::cout << "TF " << fc << " <- " << fq << " at submaps " << sc.id << ", " << sq.id << " ("
              << apart_m << " m apart): " << e.rot_deg << " deg, " << e.trans_m
              << " m from ground truth (tolerance " << tol_m << " m)\n";
    EXPECT_LE(e.rot_deg, 1.0) << fc << " <- " << fq;
    EXPECT_LE(e.trans_m, tol_m) << fc << " <- " << fq;
  }
}

TEST(FleetBagsRostest, StockUnitsGetQualifiedFramesAndTfBetweenRobots) {
  ros::NodeHandle nh, pnh("~");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  double rate = 3.0;
  pnh.getParam("rate", rate);
  // The scene (config/scenes/<scene>.yaml) and its robots, as the .test file launches them.
  std::string scene = "tiny";
  pnh.getParam("scene", scene);
  // Extra scene sections, e.g. FAST-LIO2's tilted camera_init (`fastlio:`).
  std::string scene_append;
  pnh.getParam("scene_append", scene_append);
  std::vector<std::string> robots;
  ASSERT_TRUE(pnh.getParam("robots", robots));
  ASSERT_GE(robots.size(), 2u);

  Inbox<rosgraph_msgs::Log> log;
  ros::Subscriber log_sub = nh.subscribe("/rosout", 200, &Inbox<rosgraph_msgs::Log>::cb, &log);
  Inbox<dtif::LoopClosure> loops;
  Inbox<dtif::TrunkDescriptor> descriptors;
  ros::Subscriber loop_sub =
      nh.subscribe("/loop_closures", 50, &Inbox<dtif::LoopClosure>::cb, &loops);
  std::vector<ros::Subscriber> desc_subs;
  for (const std::string& r : robots) {
    desc_subs.push_back(
        nh.subscribe("/" + r + "/descriptor", 50, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors));
  }
  tf2_ros::Buffer tf_buffer(ros::Duration(600.0));
  tf2_ros::TransformListener tf_listener(tf_buffer);

  // The scene as a dataset and a bag per unit, generated here (a few seconds).
  const fs::path dir = test::scratchDir("fleet_bags_rostest_" + scene);
  ASSERT_EQ(test::simulateScene(scene, dir,
                                "--bag " + (dir / "unit.bag").string() + " --bag-layout fastlio",
                                scene_append),
            "");
  const Dataset ds = readDataset((dir / "dataset").string());
  ASSERT_FALSE(ds.T_W_S.empty());
  std::set<std::string> scene_robots;
  for (const auto& sm : ds.submaps) scene_robots.insert(sm.robot);
  ASSERT_EQ(scene_robots, std::set<std::string>(robots.begin(), robots.end()));
  for (const std::string& r : robots) ASSERT_TRUE(fs::exists(dir / ("unit_" + r + ".bag"))) << r;

  expectWaitingWarnings(&log, robots);
  ASSERT_TRUE(waitFor(
      [&] {
        return loop_sub.getNumPublishers() > 0 && desc_subs[0].getNumPublishers() > 0 &&
               desc_subs[1].getNumPublishers() > 0;
      },
      30.0))
      << "the nodelets did not come up";
  ASSERT_TRUE(playUnitBags(dir, robots, rate));

  // Every submap's descriptor, and the database has all valid ones.
  ros::ServiceClient size_srv =
      nh.serviceClient<dtif::GetDatabaseSize>("/loop_closure/database_size");
  dtif::GetDatabaseSize size;
  auto valid = [&] {
    size_t n = 0;
    for (const auto& d : descriptors.all()) n += d->valid && d->trunks.size() >= 3;
    return n;
  };
  ASSERT_TRUE(waitFor(
      [&] {
        return descriptors.size() >= ds.submaps.size() && size_srv.call(size) &&
               size.response.size == valid();
      },
      60.0))
      << descriptors.size() << " descriptors of " << ds.submaps.size() << ", database "
      << size.response.size;

  const Positions position = expectQualifiedFrames(ds, descriptors.all());
  ASSERT_EQ(position.size(), ds.submaps.size());
  const LastDescriptors last = expectLevelled(ds, position, descriptors.all());
  ASSERT_GT(loops.size(), 0u);
  const PairLoops latest = expectTrueLoops(ds, position, loops.all());
  ASSERT_FALSE(latest.empty()) << "no inter-robot loop on " << scene;
  expectTfBetweenLinkedRobots(tf_buffer, ds, position, last, latest);
  // Each unit's body, from its odometry; the units' own /tf stayed out of the fleet's.
  for (const std::string& r : robots) {
    EXPECT_TRUE(tf_buffer.canTransform(robots[0] + "/camera_init", r + "/body", ros::Time(0)))
        << r << ": rviz in " << robots[0] << "'s frame could not place it";
  }
  EXPECT_FALSE(tf_buffer._frameExists("camera_init"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace dtif

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "fleet_bags_rostest");
  return RUN_ALL_TESTS();
}
