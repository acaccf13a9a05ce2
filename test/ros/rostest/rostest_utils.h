// Helpers of the rostest nodes (test/ros/rostest/*.cpp): the simulated scene, waiting with
// deadlines, collecting messages.
#pragma once

#include <ros/ros.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "dtif/io/dataset.h"
#include "dtif_test/test_config.h"

namespace dtif::test {

/// Dataset position of the submap of `robot` anchored at `stamp` (within 1 ms), or -1: the
/// nodelets number each robot's submaps their own way, the stamps are the dataset's.
inline int findSubmap(const Dataset& ds, const std::string& robot, double stamp) {
  for (size_t i = 0; i < ds.submaps.size(); ++i) {
    if (ds.submaps[i].robot == robot && std::fabs(ds.submaps[i].stamp - stamp) <= 1e-3) {
      return static_cast<int>(i);
    }
  }
  return -1;
}

/// This node's folder under ROS_HOME (else /tmp), named after the test and the process, empty.
inline std::filesystem::path scratchDir(const std::string& name) {
  const char* home = std::getenv("ROS_HOME");
  const std::filesystem::path dir =
      std::filesystem::path(home ? home : "/tmp") / (name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

/// `dtif simulate` of a built-in scene (seed 1) into dir/dataset, with `args` (the bag options),
/// its output in dir/simulate.log. Returns the command when it fails, else "".
/// `append` (YAML sections, e.g. a `fastlio:` section) is added to the scene file first.
inline std::string simulateScene(const std::string& scene, const std::filesystem::path& dir,
                                 const std::string& args, const std::string& append = "") {
  std::string file = std::string(DTIF_SCENES_DIR) + "/" + scene + ".yaml";
  if (!append.empty()) {
    const std::string copy = (dir / (scene + ".yaml")).string();
    std::ifstream in(file);
    std::ofstream out(copy);
    out << in.rdbuf() << "\n" << append << "\n";
    if (!in || !out) return "cannot write " + copy;
    file = copy;
  }
  const std::string cmd = std::string(DTIF_TOOL) + " simulate " + file + " --out " +
                          (dir / "dataset").string() + " --seed 1 " + args + " > " +
                          (dir / "simulate.log").string() + " 2>&1";
  return std::system(cmd.c_str()) == 0 ? "" : cmd;
}

// Spins until pred() holds or the deadline passes.
inline bool waitFor(const std::function<bool()>& pred, double timeout_s) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  while (ros::ok() && ros::WallTime::now() < end) {
    if (pred()) return true;
    ros::WallDuration(0.02).sleep();
  }
  return pred();
}

template <class Msg>
struct Inbox {
  std::mutex mutex;
  std::vector<boost::shared_ptr<const Msg>> msgs;
  void cb(const boost::shared_ptr<const Msg>& m) {
    std::lock_guard<std::mutex> lock(mutex);
    msgs.push_back(m);
  }
  size_t size() {
    std::lock_guard<std::mutex> lock(mutex);
    return msgs.size();
  }
  boost::shared_ptr<const Msg> at(size_t i) {
    std::lock_guard<std::mutex> lock(mutex);
    return msgs.at(i);
  }
  std::vector<boost::shared_ptr<const Msg>> all() {
    std::lock_guard<std::mutex> lock(mutex);
    return msgs;
  }
};

}  // namespace dtif::test
