#include "dtif/ros/frames.h"

#include <cstdio>

namespace dtif {
namespace ros_glue {

std::string robotFrame(const std::string& robot, const std::string& frame) {
  const std::string f = !frame.empty() && frame[0] == '/' ? frame.substr(1) : frame;
  if (f.empty()) return f;
  const std::string prefix = robot + "/";
  if (f.compare(0, prefix.size(), prefix) == 0) return f;
  return prefix + f;
}

std::string outputOdomFrame(const std::string& robot, const std::string& input_frame,
                            const std::string& configured) {
  return configured.empty() ? robotFrame(robot, input_frame) : configured;
}

void InputWatch::watch(const std::string& topic, double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  topics_[topic] = State{now, false};
}

void InputWatch::seen(const std::string& topic, double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = topics_.find(topic);
  if (it == topics_.end()) return;
  it->second.since = now;
  it->second.ever = true;
}

std::vector<InputWatch::Silence> InputWatch::silent(double now) const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<Silence> out;
  for (const auto& [topic, state] : topics_) {
    const double s = now - state.since;
    if (s >= timeout_s_) out.push_back(Silence{topic, s, state.ever});
  }
  return out;
}

std::string InputWatch::describe(const Silence& s) {
  char seconds[32];
  std::snprintf(seconds, sizeof(seconds), "%.0f s", s.seconds);
  if (s.ever) {
    return s.topic + ": no message for " + seconds + " (its publisher stopped, or the bag ended)";
  }
  return "waiting for " + s.topic + ": no message in " + seconds +
         " (nothing publishes there: check the topic names and remaps, see README \"Your own "
         "FAST-LIO2 units and bags\")";
}

}  // namespace ros_glue
}  // namespace dtif
