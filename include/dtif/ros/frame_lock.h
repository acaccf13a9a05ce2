// Which odometry frame a trunk extraction nodelet accepts. Configured (~odom_frame): that frame
// only. Learnt from the first message otherwise; a first message in the wrong frame (or a
// front end restarted under another name) used to block the robot for good, so a frame that
// alone arrives for kSwitchAfter messages in a row replaces the learnt one, with a warning.
#pragma once

#include <string>

namespace dtif {
namespace ros_glue {

class FrameLock {
 public:
  enum class Verdict { kAccept, kDrop, kSwitched };
  /// Messages in a row, all in one other frame and none in the learnt one, before a switch.
  static constexpr int kSwitchAfter = 10;

  /// configured: ~odom_frame ("" = learn it).
  explicit FrameLock(std::string configured) : configured_(std::move(configured)) {}

  /// Verdict on a message in `frame` (never empty: the caller drops those first).
  Verdict check(const std::string& frame);

  /// The accepted frame ("" before the first message when none is configured).
  const std::string& frame() const { return configured_.empty() ? learnt_ : configured_; }

 private:
  std::string configured_, learnt_;
  std::string other_;  ///< the other frame seen in a row since the last accepted message
  int other_run_ = 0;
};

}  // namespace ros_glue
}  // namespace dtif
