// Robot-qualified frame names and the watch on silent input topics, shared by both nodelets.
// ROS-free so they are unit-tested without a master.
//
// Stock FAST-LIO2 units all publish in the same frames (`camera_init`, `body`): dtif keys
// everything by its own robot name and publishes `<robot>/<frame>` instead, whatever the input
// carries, so that the frames of several units never collide on one master or in one rviz.
#pragma once

#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace dtif {
namespace ros_glue {

/// `<robot>/<frame>` (a leading '/' of frame dropped, tf2 names have none); a frame already under
/// `<robot>/` is returned as it is, so qualifying twice changes nothing. Empty frame: empty.
std::string robotFrame(const std::string& robot, const std::string& frame);

/// The odometry frame a nodelet publishes for a robot: `configured` when set, else
/// robotFrame(robot, input_frame).
std::string outputOdomFrame(const std::string& robot, const std::string& input_frame,
                            const std::string& configured);

/// Which watched input topics have been silent for at least timeout_s (times in seconds of any
/// monotonic clock the caller uses, wall time in the nodelets, so a paused bag still warns).
/// Thread-safe: subscriber callbacks call seen(), a timer calls silent().
class InputWatch {
 public:
  struct Silence {
    std::string topic;
    double seconds = 0.0;  ///< since the last message, or since watching began when none came
    bool ever = false;     ///< a message came once (the stream stopped) or never (never started)
  };

  explicit InputWatch(double timeout_s) : timeout_s_(timeout_s) {}
  /// Starts watching topic at time now (again: restarts its clock).
  void watch(const std::string& topic, double now);
  /// A message on topic at time now (an unwatched topic is ignored).
  void seen(const std::string& topic, double now);
  /// The watched topics silent for at least timeout_s at time now, in topic order.
  std::vector<Silence> silent(double now) const;
  /// One warning line for s, naming the topic and the seconds waited.
  static std::string describe(const Silence& s);

 private:
  struct State {
    double since = 0.0;
    bool ever = false;
  };
  const double timeout_s_;
  mutable std::mutex mutex_;
  std::map<std::string, State> topics_;
};

}  // namespace ros_glue
}  // namespace dtif
