// Robot-qualified frame names and the silent-input watch (no master).
#include "dtif/ros/frames.h"

#include <gtest/gtest.h>

namespace dtif {
namespace {

using ros_glue::InputWatch;
using ros_glue::outputOdomFrame;
using ros_glue::robotFrame;

TEST(RobotFrame, QualifiesStockNamesOnce) {
  // Every stock FAST-LIO2 unit publishes camera_init and body: dtif's names differ per robot.
  EXPECT_EQ(robotFrame("unit1", "camera_init"), "unit1/camera_init");
  EXPECT_EQ(robotFrame("unit2", "camera_init"), "unit2/camera_init");
  EXPECT_EQ(robotFrame("unit1", "body"), "unit1/body");
  EXPECT_EQ(robotFrame("unit1", "/camera_init"), "unit1/camera_init");
  // Already qualified (the simulator's default bags): unchanged, also when qualified twice.
  EXPECT_EQ(robotFrame("alpha", "alpha/odom"), "alpha/odom");
  EXPECT_EQ(robotFrame("alpha", "/alpha/odom"), "alpha/odom");
  EXPECT_EQ(robotFrame("alpha", robotFrame("alpha", "odom")), "alpha/odom");
  // Another robot's prefix, or a name that merely starts like the robot's, is qualified.
  EXPECT_EQ(robotFrame("alpha", "bravo/odom"), "alpha/bravo/odom");
  EXPECT_EQ(robotFrame("alpha", "alphabet"), "alpha/alphabet");
  EXPECT_EQ(robotFrame("alpha", ""), "");
  EXPECT_EQ(robotFrame("alpha", "/"), "");
}

TEST(RobotFrame, ConfiguredNameWins) {
  EXPECT_EQ(outputOdomFrame("unit1", "camera_init", ""), "unit1/camera_init");
  EXPECT_EQ(outputOdomFrame("unit1", "camera_init", "unit1/odom"), "unit1/odom");
}

TEST(InputWatch, ReportsSilentTopicsWithTheTimeWaited) {
  InputWatch w(10.0);
  w.watch("/unit1/cloud_registered", 100.0);
  w.watch("/unit1/Odometry", 100.0);
  w.seen("/unit1/other", 101.0);  // not watched: ignored
  EXPECT_TRUE(w.silent(109.9).empty());

  auto s = w.silent(112.0);  // nothing came: both, never seen, in topic order
  ASSERT_EQ(s.size(), 2u);
  EXPECT_EQ(s[0].topic, "/unit1/Odometry");
  EXPECT_DOUBLE_EQ(s[0].seconds, 12.0);
  EXPECT_FALSE(s[0].ever);
  EXPECT_EQ(InputWatch::describe(s[1]).rfind(
                "waiting for /unit1/cloud_registered: no message in 12 s", 0),
            0u)
      << InputWatch::describe(s[1]);

  w.seen("/unit1/Odometry", 113.0);
  s = w.silent(120.0);  // the odometry came 7 s ago
  ASSERT_EQ(s.size(), 1u);
  EXPECT_EQ(s[0].topic, "/unit1/cloud_registered");
  EXPECT_DOUBLE_EQ(s[0].seconds, 20.0);

  w.seen("/unit1/cloud_registered", 121.0);
  s = w.silent(135.0);  // both streams stopped
  ASSERT_EQ(s.size(), 2u);
  EXPECT_TRUE(s[0].ever);
  EXPECT_DOUBLE_EQ(s[0].seconds, 22.0);
  EXPECT_DOUBLE_EQ(s[1].seconds, 14.0);
  EXPECT_EQ(InputWatch::describe(s[1]).rfind("/unit1/cloud_registered: no message for 14 s", 0),
            0u);
}

}  // namespace
}  // namespace dtif
