// Helpers of the rostest nodes (test/ros/rostest/*.cpp): waiting with deadlines, collecting
// messages.
#pragma once

#include <ros/ros.h>

#include <functional>
#include <mutex>
#include <vector>

namespace dtif::test {

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
