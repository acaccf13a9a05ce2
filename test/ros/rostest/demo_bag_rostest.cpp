// Integration test run by test/demo_bag.test, which includes the shipped demo launch file (both
// nodelets for robots alpha and bravo in one manager). This node simulates the tiny scene as a
// dataset and a bag (dtif simulate, seed 1), plays the bag (rosbag play --clock) while injecting
// bad messages, and asserts that
//  - every submap of the dataset comes out of the nodelets with the dataset's stamp and T_O_S;
//  - the loop closures are those dtif eval finds on the dataset, each a true positive of the
//    protocol (overlap, 2 deg / 0.5 m of ground truth T_c_q = inv(T_W_c) * T_W_q);
//  - the loop log scores (dtif score's path) to the same loops;
//  - the database holds every valid descriptor and its services round-trip;
//  - the bad messages left both nodelets working.
#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <pcl_conversions/pcl_conversions.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <set>
#include <thread>

#include "dtif/eval/evaluation.h"
#include "dtif/io/config.h"
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

sensor_msgs::PointCloud2 cloudMsg(const Cloud& c, double stamp, const std::string& frame) {
  sensor_msgs::PointCloud2 m;
  pcl::toROSMsg(c, m);
  m.header.stamp.fromSec(stamp);
  m.header.frame_id = frame;
  return m;
}

// Bad input on alpha's and bravo's topics while the bag plays: clouds out of order, in the wrong
// frame, empty or NaN; odometry going back or NaN; descriptors of two trunks or a NaN trunk
// (submap ids 900 and 901). `last` is one of alpha's played clouds.
void publishBadInput(const sensor_msgs::PointCloud2& last, ros::Publisher* bad_cloud,
                     ros::Publisher* bad_odom, ros::Publisher* bad_desc) {
  const double t = last.header.stamp.toSec();
  Cloud wall;  // what must never reach a submap
  for (int k = 0; k < 400; ++k) wall.push_back(pcl::PointXYZ(3.0f, 0.01f * k, 0.005f * k));
  Cloud nan;
  nan.push_back(pcl::PointXYZ(NAN, NAN, NAN));
  bad_cloud->publish(last);                                           // duplicate stamp
  bad_cloud->publish(cloudMsg(wall, t - 1.0, last.header.frame_id));  // older stamp
  bad_cloud->publish(cloudMsg(wall, t + 0.01, "wrong_frame"));
  bad_cloud->publish(cloudMsg(Cloud(), t + 0.02, last.header.frame_id));  // empty
  bad_cloud->publish(cloudMsg(nan, t + 0.03, last.header.frame_id));      // only NaN
  nav_msgs::Odometry odom;
  odom.header.stamp.fromSec(t - 2.0);  // older than alpha's odometry stream
  odom.header.frame_id = last.header.frame_id;
  odom.pose.pose.orientation.w = 1.0;
  bad_odom->publish(odom);
  odom.header.stamp = ros::Time::now() + ros::Duration(0.02);
  odom.pose.pose.position.x = NAN;
  bad_odom->publish(odom);
  // A descriptor of two trunks that claims to be valid, and one with a NaN trunk.
  dtif::TrunkDescriptor two;
  two.header.stamp.fromSec(t);
  two.header.frame_id = "bravo/odom";
  two.robot = "bravo";
  two.submap_id = 900;
  two.odom_pose.orientation.w = 1.0;
  two.trunks.resize(2);
  two.trunks[1].x = 4.0f;
  two.valid = true;
  bad_desc->publish(two);
  two.submap_id = 901;
  two.trunks.resize(5);
  two.trunks[0].x = NAN;
  bad_desc->publish(two);
}

using Positions = std::map<std::pair<std::string, int64_t>, int>;  // (robot, nodelet id) -> dataset

// Each dataset submap came out of the nodelets with its stamp and its frame S; returns where each
// descriptor's submap is in the dataset.
Positions checkSubmapsAreTheDatasets(const Dataset& ds,
                                     const std::vector<dtif::TrunkDescriptor::ConstPtr>& descs) {
  Positions position;
  for (const auto& d : descs) {
    if (d->submap_id >= 900) continue;  // the injected ones
    const int i = findSubmap(ds, d->robot, d->header.stamp.toSec());
    EXPECT_GE(i, 0) << d->robot << " submap at " << d->header.stamp << " is not in the dataset";
    if (i < 0) continue;
    position[{d->robot, d->submap_id}] = i;
    Pose T_O_S;
    EXPECT_TRUE(ros_glue::fromMsg(d->odom_pose, &T_O_S));
    const Pose& T_O_S_ds = ds.submaps[i].T_O_S;
    EXPECT_LT((T_O_S.translation() - T_O_S_ds.translation()).norm(), 1e-3) << d->robot;
    EXPECT_LT(Eigen::AngleAxisd(T_O_S.rotation().transpose() * T_O_S_ds.rotation()).angle(), 1e-4);
    EXPECT_NEAR(d->data_end.toSec(), d->header.stamp.toSec() + 5.0, 1e-3);  // last cloud
  }
  EXPECT_EQ(position.size(), ds.submaps.size());
  return position;
}

// The loops, each within the protocol's tolerance of ground truth (an inter-robot loop beside a
// query's best, own-robot one alike); returns the best loops, query id -> candidate id.
std::map<int64_t, int64_t> checkLoopsAgainstGroundTruth(
    const Dataset& ds, const Positions& position,
    const std::vector<dtif::LoopClosure::ConstPtr>& loops) {
  std::map<int64_t, int64_t> online_loops;
  for (const auto& lc : loops) {
    const auto q = position.find({lc->query_robot, lc->query_id});
    const auto c = position.find({lc->candidate_robot, lc->candidate_id});
    EXPECT_TRUE(q != position.end() && c != position.end());
    if (q == position.end() || c == position.end()) continue;
    const int64_t qid = ds.submaps[q->second].id, cid = ds.submaps[c->second].id;
    if (lc->inter_robot_extra) {
      EXPECT_NE(lc->query_robot, lc->candidate_robot) << qid << " -> " << cid;
    } else {
      EXPECT_EQ(online_loops.count(qid), 0u) << "two loops for query " << qid;
      online_loops[qid] = cid;
    }
    Pose T_c_q;
    EXPECT_TRUE(ros_glue::fromMsg(lc->T_c_q, &T_c_q));
    const Pose T_c_q_gt = ds.T_W_S.at(cid).inverse() * ds.T_W_S.at(qid);
    const PoseError e = poseError(T_c_q_gt, T_c_q);
    EXPECT_LE(e.rot_deg, 2.0) << qid << " -> " << cid;
    EXPECT_LE(e.trans_m, 0.5) << qid << " -> " << cid;
  }
  return online_loops;
}

// The queries that close loops are dtif eval's: the bag carries every return and the assembler
// applies the dataset's voxel filter, so the nodelets' submaps are the dataset's (up to float
// rounding at voxel borders; test/ros/bag_submaps_test.cpp). Candidates may differ where a
// query has several true candidates, and descriptors of two robots that end at the same time
// enter the database in either order.
void expectTheQueriesOfEval(const std::map<int64_t, int64_t>& online_loops,
                            const std::map<int64_t, int64_t>& offline_loops) {
  std::set<int64_t> online_queries, offline_queries;
  for (const auto& l : online_loops) online_queries.insert(l.first);
  for (const auto& l : offline_loops) offline_queries.insert(l.first);
  std::vector<int64_t> differ;
  std::set_symmetric_difference(online_queries.begin(), online_queries.end(),
                                offline_queries.begin(), offline_queries.end(),
                                std::back_inserter(differ));
  EXPECT_TRUE(differ.empty()) << "online " << ::testing::PrintToString(online_queries)
                              << ", dtif eval " << ::testing::PrintToString(offline_queries);
  for (const auto& l : online_loops) {
    std::cout << "loop " << l.first << " -> " << l.second << " (dtif eval: "
              << (offline_loops.count(l.first) ? std::to_string(offline_loops.at(l.first)) : "-")
              << ")\n";
  }
}

// Database services: save, a corrupt file refused (the database unchanged), load back.
void checkDatabaseServices(const fs::path& dir, uint64_t n) {
  dtif::SaveDatabase save;
  save.request.path = (dir / "db.bin").string();
  ASSERT_TRUE(ros::service::call("/loop_closure/save_database", save));
  EXPECT_TRUE(save.response.success) << save.response.message;
  {
    std::ofstream corrupt(dir / "corrupt.bin");
    corrupt << "DTIF but not a database";
  }
  dtif::LoadDatabase load;
  load.request.path = (dir / "corrupt.bin").string();
  ASSERT_TRUE(ros::service::call("/loop_closure/load_database", load));
  EXPECT_FALSE(load.response.success);
  EXPECT_EQ(load.response.size, n);
  load.request.path = save.request.path;
  ASSERT_TRUE(ros::service::call("/loop_closure/load_database", load));
  EXPECT_TRUE(load.response.success) << load.response.message;
  EXPECT_EQ(load.response.size, n);
}

// What dtif eval finds on the dataset with the parameters the launch files load: query id ->
// candidate id.
std::map<int64_t, int64_t> acceptedLoops(const EvalResult& offline) {
  std::map<int64_t, int64_t> loops;
  for (const EvalRow& r : offline.rows) {
    if (r.accepted) loops[r.query] = *r.candidate;
  }
  return loops;
}

TEST(DemoBagRostest, LoopsMatchEvalAndGroundTruthDespiteBadInput) {
  ros::NodeHandle nh, pnh("~");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  std::string loop_log;
  double rate = 3.0;
  ASSERT_TRUE(pnh.getParam("loop_log", loop_log));
  pnh.getParam("rate", rate);

  // The scene as a dataset and a bag, generated here (a few seconds).
  const fs::path dir = test::scratchDir("demo_bag_rostest");
  const std::string bag = (dir / "tiny.bag").string();
  ASSERT_EQ(test::simulateScene("tiny", dir, "--bag " + bag), "");
  const Dataset ds = readDataset((dir / "dataset").string());
  ASSERT_FALSE(ds.T_W_S.empty());
  const DtifParams params;
  const EvalResult offline = runEvaluation(ds, params, EvalParams{});
  const std::map<int64_t, int64_t> offline_loops = acceptedLoops(offline);
  ASSERT_GE(offline_loops.size(), 3u) << "the tiny scene has loops within and between robots";

  Inbox<dtif::LoopClosure> loops;
  Inbox<dtif::TrunkDescriptor> descriptors;
  Inbox<sensor_msgs::PointCloud2> alpha_clouds;
  ros::Subscriber loop_sub =
      nh.subscribe("/loop_closures", 50, &Inbox<dtif::LoopClosure>::cb, &loops);
  ros::Subscriber da =
      nh.subscribe("/alpha/descriptor", 50, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors);
  ros::Subscriber db =
      nh.subscribe("/bravo/descriptor", 50, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors);
  ros::Subscriber ca = nh.subscribe("/alpha/cloud_registered", 5,
                                    &Inbox<sensor_msgs::PointCloud2>::cb, &alpha_clouds);
  ros::Publisher bad_cloud = nh.advertise<sensor_msgs::PointCloud2>("/alpha/cloud_registered", 5);
  ros::Publisher bad_odom = nh.advertise<nav_msgs::Odometry>("/alpha/Odometry", 5);
  ros::Publisher bad_desc = nh.advertise<dtif::TrunkDescriptor>("/bravo/descriptor", 5);
  ASSERT_TRUE(waitFor(
      [&] {
        return bad_cloud.getNumSubscribers() > 1 && bad_odom.getNumSubscribers() > 0 &&
               bad_desc.getNumSubscribers() > 1 && loop_sub.getNumPublishers() > 0;
      },
      30.0))
      << "the nodelets did not come up";

  // Play the bag (the launch file's rosbag node is off: play:=false).
  const std::string play = "rosbag play --clock --quiet --delay 1 --rate " + std::to_string(rate) +
                           " " + bag + " > " + (dir / "play.log").string() + " 2>&1";
  int play_status = -1;
  std::thread player([&] { play_status = std::system(play.c_str()); });
  // Bad input while the bag plays, once alpha's stream has started.
  const bool started = waitFor([&] { return alpha_clouds.size() >= 20; }, 60.0);
  if (started) {
    publishBadInput(*alpha_clouds.at(alpha_clouds.size() - 1), &bad_cloud, &bad_odom, &bad_desc);
  }
  player.join();
  ASSERT_TRUE(started) << "no clouds played";
  ASSERT_EQ(play_status, 0) << play;

  // Every valid descriptor is queried and inserted; then the run is complete.
  ros::ServiceClient size_srv =
      nh.serviceClient<dtif::GetDatabaseSize>("/loop_closure/database_size");
  auto validDescriptors = [&] {
    size_t n = 0;
    for (const auto& d : descriptors.all())
      n += d->valid && d->trunks.size() >= 3 && d->submap_id < 900;
    return n;
  };
  dtif::GetDatabaseSize size;
  ASSERT_TRUE(waitFor(
      [&] {
        return descriptors.size() >= ds.submaps.size() + 2 && size_srv.call(size) &&
               size.response.size == validDescriptors();
      },
      60.0))
      << descriptors.size() << " descriptors, database " << size.response.size;

  const Positions position = checkSubmapsAreTheDatasets(ds, descriptors.all());
  const std::map<int64_t, int64_t> online_loops =
      checkLoopsAgainstGroundTruth(ds, position, loops.all());
  expectTheQueriesOfEval(online_loops, offline_loops);
  // The loop log, scored as dtif score does: the same loops, all true positives (overlap >= 0.3
  // and within 2 deg / 0.5 m), as many as eval's.
  const EvalResult scored =
      scoreLoopLog(ds, readLoopLog(loop_log), params.loop.database.exclude_recent_s, EvalParams{});
  EXPECT_EQ(scored.summary.accepted, online_loops.size());
  EXPECT_EQ(scored.summary.true_positives, online_loops.size());
  EXPECT_EQ(scored.summary.true_positives, offline.summary.true_positives);
  EXPECT_EQ(scored.summary.queries_with_loop, offline.summary.queries_with_loop);
  checkDatabaseServices(dir, size.response.size);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace dtif

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "demo_bag_rostest");
  return RUN_ALL_TESTS();
}
