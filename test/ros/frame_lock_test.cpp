// Which odometry frame the trunk extraction nodelet accepts (issue #17: a first cloud in the
// wrong frame blocked the robot for good).
#include "dtif/ros/frame_lock.h"

#include <gtest/gtest.h>

namespace dtif {
namespace ros_glue {
namespace {

using V = FrameLock::Verdict;

TEST(FrameLock, AWrongFirstFrameIsReplacedByTheOneThatKeepsComing) {
  FrameLock lock("");
  EXPECT_EQ(lock.check("stray"), V::kAccept);  // learnt from the first message
  for (int i = 1; i < FrameLock::kSwitchAfter; ++i) EXPECT_EQ(lock.check("camera_init"), V::kDrop);
  EXPECT_EQ(lock.check("camera_init"), V::kSwitched);
  EXPECT_EQ(lock.frame(), "camera_init");
  EXPECT_EQ(lock.check("camera_init"), V::kAccept);
  EXPECT_EQ(lock.check("stray"), V::kDrop);
}

TEST(FrameLock, OccasionalStrayFramesNeverSwitch) {
  FrameLock lock("");
  EXPECT_EQ(lock.check("odom"), V::kAccept);
  for (int i = 0; i < 100; ++i) {
    EXPECT_EQ(lock.check(i % 2 ? "a" : "b"), V::kDrop);  // two strays alternating
    if (i % 5 == 0) EXPECT_EQ(lock.check("odom"), V::kAccept);
  }
  EXPECT_EQ(lock.frame(), "odom");
}

TEST(FrameLock, AConfiguredFrameNeverSwitches) {
  FrameLock lock("odom");
  for (int i = 0; i < 3 * FrameLock::kSwitchAfter; ++i) EXPECT_EQ(lock.check("other"), V::kDrop);
  EXPECT_EQ(lock.check("odom"), V::kAccept);
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
