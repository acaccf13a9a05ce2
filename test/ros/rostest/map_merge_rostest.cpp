// Integration test run by test/map_merge.test: the shipped demo launch file (extraction for
// alpha and bravo, loop closure and map merge in one manager) on the tiny scene's bag (dtif
// simulate, seed 1). Nothing is killed: once the bag has played and the merge nodelet reports
// an up-to-date solve, the test reads TF `map -> <robot odometry frame>` for every robot and
// checks that
//  - every robot is in the one frame `map` (tiny has loops between the robots);
//  - the merged submap poses (the robots' paths in map) are within the ATE tolerance of ground
//    truth after one rigid alignment of all robots together (DATASET.md's ATE);
//  - TF map -> odometry frame puts each robot's latest submap within tolerance of ground truth;
//  - get_map_info and save_map report and write the merged map;
//  - the saved inventory's DBH was measured on the points the submap clouds kept
//    (stems.dbh_from_points), within the median DBH error of the true stems;
//  - a false loop the test publishes on /loop_closures as soon as the first loop between the
//    robots arrives (#16's robustness check through the nodelets) is not in the saved pose
//    graph, and the map above is checked with it in.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <tf2_ros/transform_listener.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <sstream>
#include <thread>

#include "dtif/io/csv.h"
#include "dtif/io/dataset.h"
#include "dtif/io/merge_files.h"
#include "dtif/ros/msgs.h"
#include "dtif_test/test_config.h"
#include "merge_rostest_utils.h"
#include "rostest_utils.h"

namespace dtif {
namespace {

using test::Inbox;
using test::waitFor;
namespace fs = std::filesystem;

constexpr double kAteTolM = 0.10;   // issue #16's merged-map ATE target
constexpr double kTfTolM = 0.15;    // the map TF of each robot at its latest submap
constexpr double kDbhTolM = 0.015;  // median DBH error: 1.9 cm from the observations' median

// Median |DBH error| [m] of the saved stems matched (nearest within 0.5 m, as dtif merge scores
// them) to the true stems, the map placed by T_W_map; 1 m when none matches.
double medianDbhError(const std::vector<MergedStem>& stems, const Dataset& ds,
                      const Pose& T_W_map) {
  std::vector<double> err;
  for (const MergedStem& m : stems) {
    if (m.component != 0) continue;
    const Eigen::Vector3d p = T_W_map * Eigen::Vector3d(m.x, m.y, m.z_base);
    double best = 0.5, dbh = -1.0;
    for (const auto& t : ds.stems) {
      const double d = std::hypot(p.x() - t.x, p.y() - t.y);
      if (d < best) best = d, dbh = t.dbh;
    }
    if (dbh >= 0.0) err.push_back(std::fabs(m.dbh - dbh));
  }
  if (err.empty()) return 1.0;
  std::sort(err.begin(), err.end());
  return err[err.size() / 2];
}

size_t countLines(const fs::path& p) {
  std::ifstream f(p);
  size_t n = 0;
  for (std::string line; std::getline(f, line);) n += !line.empty();
  return n;
}

using Paths = std::map<std::string, test::Latest<nav_msgs::Path>>;

// Collects the loops and, when the first loop between two robots arrives, publishes one false
// loop as dtif merge --inject-false-loop makes it: between those robots' two submaps seen so far
// that lie farthest apart (ground truth), the query the later one, 3 m, -2 m and 0.4 rad off,
// with the real loop's covariance. Before the robots share a frame, with one real loop to weigh
// it against: if the back end took it, it would bend the map as the robots join.
struct FalseLoop {
  const Dataset* ds = nullptr;
  Inbox<dtif::TrunkDescriptor>* descriptors = nullptr;
  Inbox<dtif::LoopClosure>* loops = nullptr;
  ros::Publisher pub;
  std::mutex mutex;
  std::optional<Loop> sent;

  void cb(const dtif::LoopClosure::ConstPtr& m) {
    loops->cb(m);  // this one too, once published: the merge counts it
    std::lock_guard<std::mutex> lock(mutex);
    if (sent || m->query_robot == m->candidate_robot) return;
    double farthest = -1.0;
    Loop l;
    const std::vector<test::SeenSubmap> seen = test::seenSubmaps(*ds, descriptors->all());
    for (const test::SeenSubmap& c : seen) {
      if (c.robot != m->candidate_robot) continue;
      for (const test::SeenSubmap& q : seen) {
        if (q.robot != m->query_robot || q.stamp <= c.stamp) continue;
        const double d =
            (ds->T_W_S.at(q.dataset_id).translation() - ds->T_W_S.at(c.dataset_id).translation())
                .norm();
        if (d > farthest) farthest = d, l.query_id = q.submap_id, l.candidate_id = c.submap_id;
      }
    }
    if (farthest < 0.0) return;
    l.query_robot = m->query_robot;
    l.candidate_robot = m->candidate_robot;
    l.T_c_q.linear() = Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    l.T_c_q.translation() << 3.0, -2.0, 0.0;
    l.covariance =
        Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(m->covariance.data());
    l.inliers = std::max(12, m->inliers);
    l.score = 0.9;
    dtif::LoopClosure msg = ros_glue::toMsg(l);
    msg.header = m->header;
    pub.publish(msg);
    sent = l;
    std::cout << "false loop " << l.query_robot << "/" << l.query_id << " -> " << l.candidate_robot
              << "/" << l.candidate_id << " (" << farthest << " m apart) after " << loops->size()
              << " loops\n";
  }
};

// Whether the saved pose graph (pose_graph.g2o: odometry edges and the loops used) has an edge
// between the submaps of loop `l` (graph ids from submap_ids.csv).
bool inSavedGraph(const fs::path& map_dir, const Loop& l) {
  std::map<std::pair<std::string, int64_t>, std::string> graph_id;
  std::ifstream ids(map_dir / "submap_ids.csv");
  std::string line;
  std::getline(ids, line);  // id,chain,robot,submap_id,stamp
  while (std::getline(ids, line)) {
    const std::vector<std::string> cell = splitCsvLine(line);
    if (cell.size() >= 4) graph_id[{cell[2], std::stoll(cell[3])}] = cell[0];
  }
  const std::string q = graph_id[{l.query_robot, l.query_id}];
  const std::string c = graph_id[{l.candidate_robot, l.candidate_id}];
  EXPECT_FALSE(q.empty() || c.empty()) << "the false loop's submaps are not in submap_ids.csv";
  std::ifstream g2o(map_dir / "pose_graph.g2o");
  for (std::string tag, a, b; std::getline(g2o, line);) {
    std::stringstream(line) >> tag >> a >> b;
    if (tag.rfind("EDGE", 0) == 0 && ((a == q && b == c) || (a == c && b == q))) return true;
  }
  return false;
}

// The submaps on the robots' latest paths in map: positions, ground truth and robot of each.
struct PathPoints {
  std::vector<Eigen::Vector3d> est, gt;
  std::vector<std::string> robot_of;
};

PathPoints readPaths(const Dataset& ds, Paths* paths) {
  PathPoints pts;
  for (const std::string robot : {"alpha", "bravo"}) {
    const auto path = (*paths)[robot].latest();
    EXPECT_TRUE(path) << "no path of " << robot;
    if (!path) continue;
    EXPECT_EQ(path->header.frame_id, "map");
    for (const auto& [id, T] : test::pathPoses(ds, robot, *path)) {
      pts.est.push_back(T.translation());
      pts.gt.push_back(ds.T_W_S.at(id).translation());
      pts.robot_of.push_back(robot);
    }
  }
  return pts;
}

// Each robot's odometry frame from get_map_info; every robot must be in `map`.
std::map<std::string, std::string> odomFramesInMap(const dtif::GetMapInfo::Response& r) {
  std::map<std::string, std::string> odom_frame;
  for (size_t i = 0; i < r.robots.size(); ++i) {
    EXPECT_EQ(r.map_frames[i], "map") << r.robots[i] << " is not joined to the map";
    odom_frame[r.robots[i]] = r.odom_frames[i];
  }
  return odom_frame;
}

// The merged ATE of all robots (one alignment), printed per robot beside each robot's odometry
// aligned alone (`odom_est`, `odom_gt`).
double reportAte(const PathPoints& pts,
                 const std::map<std::string, std::vector<Eigen::Vector3d>>& odom_est,
                 const std::map<std::string, std::vector<Eigen::Vector3d>>& odom_gt) {
  const std::vector<double> res = test::alignedResiduals(pts.est, pts.gt);
  std::map<std::string, std::vector<double>> per_robot;
  for (size_t i = 0; i < res.size(); ++i) per_robot[pts.robot_of[i]].push_back(res[i]);
  for (const auto& p : per_robot) {
    std::cout << "merged " << p.first << ": ATE " << test::rms(p.second) << " m over "
              << p.second.size() << " submaps (odometry alone "
              << test::rms(test::alignedResiduals(odom_est.at(p.first), odom_gt.at(p.first)))
              << " m)\n";
  }
  return test::rms(res);
}

// TF map -> odometry frame (T_map_O per robot) places each robot's latest submap (where it is
// now) within kTfTolM of ground truth, the map aligned to the world by T_W_map.
void expectTfPlacesTheLatestSubmaps(const Dataset& ds,
                                    const std::map<std::string, test::SeenSubmap>& latest,
                                    const std::map<std::string, Pose>& T_map_O, const Pose& T_W_map,
                                    const char* when) {
  for (const auto& [robot, s] : latest) {
    const Eigen::Vector3d p = T_W_map * (T_map_O.at(robot) * s.T_O_S).translation();
    const double e = (p - ds.T_W_S.at(s.dataset_id).translation()).norm();
    std::cout << "map TF of " << robot << when << ": latest submap " << e
              << " m from ground truth\n";
    EXPECT_LE(e, kTfTolM) << robot;
  }
}

// TF map -> each robot's odometry frame, waited for.
bool lookupMapTfs(const tf2_ros::Buffer& tf, const std::map<std::string, std::string>& odom_frame,
                  std::map<std::string, Pose>* T_map_O, double timeout_s) {
  return waitFor(
      [&] {
        for (const auto& f : odom_frame) {
          if (!test::lookup(tf, "map", f.second, &(*T_map_O)[f.first])) return false;
        }
        return true;
      },
      timeout_s);
}

// save_map's files, and the DBH measured on the points the submap clouds kept (dtif merge on
// this dataset: 53 of 89 stems, median DBH error 1.9 -> 1.0 cm).
void expectTheSavedMap(const fs::path& map_dir, const Dataset& ds, ros::ServiceClient* info_srv,
                       const Pose& T_W_map) {
  // map_merge.test turns the submap clouds on, so the merged cloud is written too.
  for (const char* f :
       {"merged_poses.csv", "merged_stems.csv", "pose_graph.g2o", "merged_cloud.pcd"}) {
    EXPECT_TRUE(fs::exists(map_dir / f)) << f;
  }
  EXPECT_EQ(countLines(map_dir / "merged_poses.csv"), ds.submaps.size() + 1);  // + header
  EXPECT_GT(countLines(map_dir / "merged_stems.csv"), 10u);
  dtif::GetMapInfo info;
  ASSERT_TRUE(info_srv->call(info));
  std::cout << "DBH from the points: " << info.response.stems_dbh_from_points << " stems, "
            << info.response.slice_submaps << " submaps kept " << info.response.slice_bytes
            << " bytes\n";
  EXPECT_GE(info.response.slice_submaps, ds.submaps.size() / 2);
  EXPECT_GE(info.response.stems_dbh_from_points, 20u);
  const double dbh_err =
      medianDbhError(readMergedStemsCsv((map_dir / "merged_stems.csv").string()), ds, T_W_map);
  std::cout << "saved stems: median DBH error " << 100.0 * dbh_err << " cm\n";
  EXPECT_LE(dbh_err, kDbhTolM);
}

TEST(MapMergeRostest, EveryRobotsMapTfMatchesGroundTruth) {
  ros::NodeHandle nh, pnh("~");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  double rate = 3.0;
  pnh.getParam("rate", rate);
  tf2_ros::Buffer tf;
  tf2_ros::TransformListener listener(tf);

  const fs::path dir = test::scratchDir("map_merge_rostest");
  const std::string bag = (dir / "tiny.bag").string();
  ASSERT_EQ(test::simulateScene("tiny", dir, "--bag " + bag), "");
  const Dataset ds = readDataset((dir / "dataset").string());
  ASSERT_FALSE(ds.T_W_S.empty());

  Inbox<dtif::TrunkDescriptor> descriptors;
  Inbox<dtif::LoopClosure> loops;
  FalseLoop false_loop;
  false_loop.ds = &ds;
  false_loop.descriptors = &descriptors;
  false_loop.loops = &loops;
  ros::Subscriber da =
      nh.subscribe("/alpha/descriptor", 50, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors);
  ros::Subscriber db =
      nh.subscribe("/bravo/descriptor", 50, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors);
  ros::Subscriber ls = nh.subscribe("/loop_closures", 50, &FalseLoop::cb, &false_loop);
  Paths paths;
  std::vector<ros::Subscriber> path_subs;
  for (const std::string robot : {"alpha", "bravo"}) {
    path_subs.push_back(nh.subscribe("/map_merge/path/" + robot, 2,
                                     &test::Latest<nav_msgs::Path>::cb, &paths[robot]));
  }
  ros::ServiceClient info_srv = nh.serviceClient<dtif::GetMapInfo>("/map_merge/get_map_info");
  ASSERT_TRUE(waitFor([&] { return info_srv.exists() && ls.getNumPublishers() > 0; }, 30.0))
      << "the nodelets did not come up";
  // Advertised now: before, it would have counted as the loop closure nodelet's publisher.
  false_loop.pub = nh.advertise<dtif::LoopClosure>("/loop_closures", 10);

  // Each robot's submap windows start at its first cloud received, and the paths are matched to
  // the dataset by stamp: the player waits until every topic of the bag has its subscriber (this
  // node's TF listener takes /tf), as --delay alone did not on a loaded machine (a robot's first
  // clouds lost, its windows 0.1 s late, none of its submaps matched).
  const std::string play = "rosbag play --clock --quiet --delay 1 --wait-for-subscribers --rate " +
                           std::to_string(rate) + " " + bag + " > " + (dir / "play.log").string() +
                           " 2>&1";
  ASSERT_EQ(std::system(play.c_str()), 0) << play;

  // Every submap in the graph and the latest solve holding all of it.
  dtif::GetMapInfo info;
  auto merged = [&] {
    if (descriptors.size() < ds.submaps.size() || !info_srv.call(info)) return false;
    size_t n = 0;
    for (uint32_t k : info.response.submaps) n += k;
    return n == descriptors.size() && info.response.up_to_date &&
           info.response.loops_used + info.response.loops_rejected == loops.size();
  };
  ASSERT_TRUE(waitFor(merged, 60.0))
      << descriptors.size() << " descriptors, " << loops.size() << " loops";
  ASSERT_GE(loops.size(), 3u);
  const auto& r = info.response;
  ASSERT_EQ(r.robots.size(), 2u);
  std::map<std::string, std::string> odom_frame = odomFramesInMap(r);
  std::map<std::string, Pose> T_map_O;
  ASSERT_TRUE(lookupMapTfs(tf, odom_frame, &T_map_O, 10.0)) << "no TF map -> odometry frames";

  // The merged submap poses (each robot's path in map) against ground truth, all robots
  // aligned together (DATASET.md's ATE); each robot's own odometry aligned alone beside it.
  std::map<std::string, std::vector<Eigen::Vector3d>> odom_est, odom_gt;
  std::map<std::string, test::SeenSubmap> latest;  // each robot's latest submap
  for (const test::SeenSubmap& s : test::seenSubmaps(ds, descriptors.all())) {
    EXPECT_EQ(s.odom_frame, odom_frame[s.robot]);
    odom_est[s.robot].push_back(s.T_O_S.translation());
    odom_gt[s.robot].push_back(ds.T_W_S.at(s.dataset_id).translation());
    latest[s.robot] = s;
  }
  ASSERT_TRUE(waitFor(
      [&] {
        size_t n = 0;
        for (auto& p : paths) n += p.second.latest() ? p.second.latest()->poses.size() : 0;
        return n == ds.submaps.size();
      },
      10.0))
      << "the paths do not hold every submap";
  const PathPoints pts = readPaths(ds, &paths);
  ASSERT_EQ(pts.est.size(), ds.submaps.size()) << "a submap is missing from the paths";
  const double ate = reportAte(pts, odom_est, odom_gt);
  std::cout << "merged, all robots: ATE " << ate << " m; " << r.loops_used << " loops used, "
            << r.loops_rejected << " rejected, " << r.solves << " solves, latest "
            << r.last_solve_ms << " ms, longest " << r.max_solve_ms << " ms\n";
  EXPECT_LE(ate, kAteTolM);
  expectTfPlacesTheLatestSubmaps(ds, latest, T_map_O, test::alignPositions(pts.est, pts.gt), "");

  // save_map writes the merged map's files, and the map the nodelet publishes is then the
  // landmark-refined one: new paths, within the same tolerances.
  const auto alpha_before = paths["alpha"].latest(), bravo_before = paths["bravo"].latest();
  dtif::SaveMap save;
  save.request.directory = (dir / "map").string();
  ASSERT_TRUE(ros::service::call("/map_merge/save_map", save));
  EXPECT_TRUE(save.response.success) << save.response.message;
  ASSERT_TRUE(waitFor(
      [&] {
        return paths["alpha"].latest() != alpha_before && paths["bravo"].latest() != bravo_before;
      },
      10.0))
      << "no paths published after save_map";
  const PathPoints saved = readPaths(ds, &paths);
  ASSERT_EQ(saved.est.size(), ds.submaps.size());
  const double ate_saved = test::rms(test::alignedResiduals(saved.est, saved.gt));
  std::cout << "after save_map (landmark-refined), all robots: ATE " << ate_saved << " m\n";
  EXPECT_LE(ate_saved, kAteTolM);
  const Pose T_W_map_saved = test::alignPositions(saved.est, saved.gt);
  ros::WallDuration(1.0).sleep();  // the TF timer sends the refined map's transforms (wall time:
                                   // the bag's clock has stopped)
  std::map<std::string, Pose> T_map_O_saved;
  ASSERT_TRUE(lookupMapTfs(tf, odom_frame, &T_map_O_saved, 5.0));
  expectTfPlacesTheLatestSubmaps(ds, latest, T_map_O_saved, T_W_map_saved, " after save_map");
  expectTheSavedMap(dir / "map", ds, &info_srv, T_W_map_saved);
  ASSERT_TRUE(false_loop.sent) << "no loop between the robots: no false loop was published";
  EXPECT_FALSE(inSavedGraph(dir / "map", *false_loop.sent)) << "the back end used the false loop";
  EXPECT_GE(r.loops_rejected, 1u);
  if (!std::getenv("DTIF_KEEP_TEST_OUTPUT")) {
    fs::remove_all(dir);
  }
}

}  // namespace
}  // namespace dtif

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "map_merge_rostest");
  return RUN_ALL_TESTS();
}
