#include "dtif/ros/frame_lock.h"

namespace dtif {
namespace ros_glue {

FrameLock::Verdict FrameLock::check(const std::string& frame) {
  if (!configured_.empty()) return frame == configured_ ? Verdict::kAccept : Verdict::kDrop;
  if (learnt_.empty() || frame == learnt_) {
    learnt_ = frame;
    other_run_ = 0;
    return Verdict::kAccept;
  }
  other_run_ = frame == other_ ? other_run_ + 1 : 1;
  other_ = frame;
  if (other_run_ < kSwitchAfter) return Verdict::kDrop;
  learnt_ = frame;
  other_run_ = 0;
  return Verdict::kSwitched;
}

}  // namespace ros_glue
}  // namespace dtif
