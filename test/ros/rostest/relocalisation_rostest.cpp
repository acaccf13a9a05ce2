// Integration test run by test/relocalisation.test: a second survey run placed in the map of a
// first through the first run's saved database. The node simulates the tiny scene (seed 1) and
// starts the shipped demo launch file itself, twice (roslaunch as a child process, on the
// rostest master):
//  1. robots alpha and bravo replay the bag; the loop-closure database is saved (version 2: each
//     entry's odometry pose and frame); the run is shut down (SIGINT to its process group);
//  2. robots charlie and delta replay the same bag (topics remapped: a second visit of the same
//     plot, with fresh odometry frames of the same names) with database_file := the saved file.
// Run 2's loops against the loaded submaps must place charlie and delta in run 1's `map`: the
// submaps' merged positions in run 2 within 0.15 m RMS of the same submaps' in run 1 (no
// realignment: the same frame), and TF map -> odometry frame within 0.15 m at the robots' latest
// submaps.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <signal.h>
#include <tf2_ros/transform_listener.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <thread>

#include "dtif/io/dataset.h"
#include "dtif/ros/msgs.h"
#include "dtif_test/test_config.h"
#include "merge_rostest_utils.h"
#include "rostest_utils.h"

namespace dtif {
namespace {

using test::Inbox;
using test::waitFor;
namespace fs = std::filesystem;

constexpr double kSameMapTolM = 0.15;  // issue #16: the second run lands in the same map

// One run of the demo launch file as a child process group; stopped on destruction.
class LaunchRun {
 public:
  LaunchRun(const std::string& args, const fs::path& log) {
    const fs::path pid_file = log.string() + ".pid";
    const std::string cmd =
        "setsid roslaunch dtif demo_bag.launch play:=false headless:=true "
        "bond:=false output:=log " +
        args + " > " + log.string() + " 2>&1 & echo $! > " + pid_file.string();
    if (std::system(cmd.c_str()) == 0) std::ifstream(pid_file) >> pid_;
  }
  ~LaunchRun() { stop(); }
  bool started() const { return pid_ > 0; }
  // SIGINT to the group (roslaunch shuts its nodes down), then waits for it to end.
  void stop() {
    if (pid_ <= 0) return;
    ::kill(-pid_, SIGINT);
    for (int i = 0; i < 300 && (::kill(pid_, 0) == 0 || errno != ESRCH); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    pid_ = -1;
  }

 private:
  pid_t pid_ = -1;
};

// What one run left: each robot's merged submap poses by dataset id and its map TF.
struct RunResult {
  std::map<int64_t, Pose> T_map_S;                 // dataset id -> merged pose in map
  std::map<std::string, Pose> T_map_O;             // odometry frame -> TF map <- it
  std::map<std::string, test::SeenSubmap> latest;  // odometry frame -> latest submap
};

// Plays the bag into a running launch of robots r1, r2 (bag topics of alpha and bravo remapped
// to them) and collects the merged map once it is up to date.
void playAndCollect(const Dataset& ds, const std::string& bag, const fs::path& dir,
                    const std::string& r1, const std::string& r2, RunResult* out) {
  ros::NodeHandle nh;
  tf2_ros::Buffer tf;
  tf2_ros::TransformListener listener(tf);
  Inbox<dtif::TrunkDescriptor> descriptors;
  std::map<std::string, test::Latest<nav_msgs::Path>> paths;
  std::vector<ros::Subscriber> subs;
  for (const std::string& r : {r1, r2}) {
    subs.push_back(
        nh.subscribe("/" + r + "/descriptor", 50, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors));
    subs.push_back(
        nh.subscribe("/map_merge/path/" + r, 2, &test::Latest<nav_msgs::Path>::cb, &paths[r]));
  }
  ros::ServiceClient info_srv = nh.serviceClient<dtif::GetMapInfo>("/map_merge/get_map_info");
  ASSERT_TRUE(waitFor(
      [&] {
        return info_srv.exists() && subs[0].getNumPublishers() > 0 &&
               subs[2].getNumPublishers() > 0;
      },
      60.0))
      << "the nodelets of " << r1 << ", " << r2 << " did not come up";
  std::string remap;
  for (const auto& [from, to] : {std::pair<std::string, std::string>{"alpha", r1}, {"bravo", r2}}) {
    for (const char* topic : {"cloud_registered", "Odometry"}) {
      remap += " /" + from + "/" + topic + ":=/" + to + "/" + topic;
    }
  }
  // The player waits until every topic has its subscriber (this node's TF listener takes /tf):
  // a robot's submap windows start at its first cloud received, and the submaps are matched to
  // the dataset by stamp.
  const std::string play =
      "rosbag play --clock --quiet --delay 1 --wait-for-subscribers --rate 3 " + bag + remap +
      " > " + (dir / ("play_" + r1 + ".log")).string() + " 2>&1";
  ASSERT_EQ(std::system(play.c_str()), 0) << play;

  dtif::GetMapInfo info;
  auto merged = [&] {
    if (descriptors.size() < ds.submaps.size() || !info_srv.call(info)) return false;
    size_t live = 0, in_paths = 0;
    for (size_t i = 0; i < info.response.robots.size(); ++i) {
      if (info.response.robots[i] == r1 || info.response.robots[i] == r2) {
        live += info.response.submaps[i];
      }
    }
    for (auto& p : paths) in_paths += p.second.latest() ? p.second.latest()->poses.size() : 0;
    return live == descriptors.size() && in_paths == live && info.response.up_to_date;
  };
  ASSERT_TRUE(waitFor(merged, 60.0)) << descriptors.size() << " descriptors";
  for (size_t i = 0; i < info.response.robots.size(); ++i) {
    std::cout << "run of " << r1 << ", " << r2 << ": " << info.response.robots[i] << " in "
              << info.response.map_frames[i] << " (" << info.response.submaps[i] << " submaps)\n";
    if (info.response.robots[i] == r1 || info.response.robots[i] == r2) {
      EXPECT_EQ(info.response.map_frames[i], "map") << info.response.robots[i];
    }
  }
  std::cout << "  " << info.response.loops_used << " loops used, " << info.response.loops_rejected
            << " rejected; latest solve " << info.response.last_solve_ms << " ms\n";
  const std::map<std::string, std::string> robot_as{{r1, "alpha"}, {r2, "bravo"}};
  for (const auto& [r, as] : robot_as) {
    const auto path = paths[r].latest();
    ASSERT_TRUE(path);
    for (const auto& [id, T] : test::pathPoses(ds, as, *path)) out->T_map_S[id] = T;
    std::vector<boost::shared_ptr<const dtif::TrunkDescriptor>> mine;
    for (const auto& d : descriptors.all()) {
      if (d->robot == r) mine.push_back(d);
    }
    for (const test::SeenSubmap& s : test::seenSubmaps(ds, mine, as)) out->latest[s.odom_frame] = s;
  }
  ASSERT_TRUE(waitFor(
      [&] {
        for (const auto& l : out->latest) {
          if (!test::lookup(tf, "map", l.first, &out->T_map_O[l.first])) return false;
        }
        return true;
      },
      10.0))
      << "no TF map -> odometry frames";
}

TEST(RelocalisationRostest, SecondRunLandsInTheFirstRunsMap) {
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const fs::path dir = test::scratchDir("relocalisation_rostest");
  const std::string bag = (dir / "tiny.bag").string();
  ASSERT_EQ(test::simulateScene("tiny", dir, "--bag " + bag), "");
  const Dataset ds = readDataset((dir / "dataset").string());
  const std::string db = (dir / "run1.db").string();

  RunResult run1, run2;
  {
    LaunchRun launch("robot1:=alpha robot2:=bravo", dir / "run1.log");
    ASSERT_TRUE(launch.started());
    playAndCollect(ds, bag, dir, "alpha", "bravo", &run1);
    ASSERT_FALSE(HasFatalFailure());
    dtif::SaveDatabase save;
    save.request.path = db;
    ASSERT_TRUE(ros::service::call("/loop_closure/save_database", save));
    ASSERT_TRUE(save.response.success) << save.response.message;
    launch.stop();
    ASSERT_TRUE(
        waitFor([] { return !ros::service::exists("/map_merge/get_map_info", false); }, 30.0));
  }
  {
    LaunchRun launch("robot1:=charlie robot2:=delta database_file:=" + db, dir / "run2.log");
    ASSERT_TRUE(launch.started());
    // Before any new submap arrives, the map merge solves the loaded run's map on its own.
    dtif::GetMapInfo loaded;
    ASSERT_TRUE(waitFor(
        [&] {
          return ros::service::call("/map_merge/get_map_info", loaded) &&
                 loaded.response.up_to_date && loaded.response.solves > 0;
        },
        60.0))
        << "the map merge did not solve the loaded database's map (" << loaded.response.solves
        << " solves)";
    EXPECT_GT(loaded.response.loops_used, 0u);
    playAndCollect(ds, bag, dir, "charlie", "delta", &run2);
    ASSERT_FALSE(HasFatalFailure());
  }

  // Every submap of run 2 where run 1 put the same submap.
  ASSERT_EQ(run1.T_map_S.size(), ds.submaps.size());
  ASSERT_EQ(run2.T_map_S.size(), ds.submaps.size());
  std::vector<double> diff;
  for (const auto& [id, T1] : run1.T_map_S) {
    diff.push_back((run2.T_map_S.at(id).translation() - T1.translation()).norm());
    std::cout << "  submap " << id << ": " << diff.back() << " m\n";
  }
  std::cout << "relocalisation: run 2's submaps " << test::rms(diff) << " m RMS, at most "
            << *std::max_element(diff.begin(), diff.end()) << " m from run 1's\n";
  EXPECT_LE(test::rms(diff), kSameMapTolM);
  // And the map TF at each robot's latest submap.
  for (const auto& [frame, s] : run2.latest) {
    // Run 2's robots replay run 1's bag, whose frames (alpha/odom) dtif qualifies with the new
    // robot's name (charlie/alpha/odom): the same odometry frame as run 1's alpha/odom.
    const std::string frame1 = frame.substr(frame.find('/') + 1);
    ASSERT_TRUE(run1.T_map_O.count(frame1)) << frame << " (run 1: " << frame1 << ")";
    const double e = ((run2.T_map_O.at(frame) * s.T_O_S).translation() -
                      (run1.T_map_O.at(frame1) * s.T_O_S).translation())
                         .norm();
    std::cout << "relocalisation: TF map -> " << frame << " within " << e
              << " m of run 1's at the latest submap\n";
    EXPECT_LE(e, kSameMapTolM) << frame;
  }
  if (!std::getenv("DTIF_KEEP_TEST_OUTPUT")) fs::remove_all(dir);
}

}  // namespace
}  // namespace dtif

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "relocalisation_rostest");
  return RUN_ALL_TESTS();
}
