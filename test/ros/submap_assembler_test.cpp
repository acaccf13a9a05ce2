// Submap assembly from registered clouds + odometry, without a master.
#include "dtif/ros/submap_assembler.h"

#include <gtest/gtest.h>

#include <cmath>
#include <optional>

#include "test_utils.h"

namespace dtif {
namespace ros_glue {
namespace {

using Status = SubmapAssembler::Status;

using test::makePose;

Cloud cloudOf(std::initializer_list<Eigen::Vector3f> pts) {
  Cloud c;
  for (const auto& p : pts) c.push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  return c;
}

TEST(GravityAlignedPose, KeepsPositionAndYawDropsRollPitch) {
  const Pose T_O_S = gravityAlignedPose(makePose(3, 4, 1, 0.1, -0.05, 0.8));
  EXPECT_TRUE(T_O_S.translation().isApprox(Eigen::Vector3d(3, 4, 1)));
  EXPECT_NEAR(T_O_S.rotation()(2, 2), 1.0, 1e-12);  // z up
  const Eigen::Vector3d x = T_O_S.rotation().col(0);
  EXPECT_NEAR(std::atan2(x.y(), x.x()), 0.8, 0.01);
}

TEST(SubmapAssembler, WindowsCloudsIntoTheAnchorFrame) {
  SubmapAssemblerParams p;
  p.window_s = 1.0;
  SubmapAssembler a(p, 5);
  const double yaw = M_PI / 2;
  for (int i = 0; i <= 30; ++i) {
    ASSERT_EQ(a.addOdometry(10.0 + 0.1 * i, makePose(2.0 + 0.1 * i, 0, 0, 0, 0, yaw)), Status::kOk);
  }
  std::optional<AssembledSubmap> done;
  // Anchor at t = 10.0: sensor at (2, 0, 0) facing +y. A point at O (2, 1, 0.5) is 1 m ahead.
  EXPECT_EQ(a.addCloud(10.0, cloudOf({{2, 1, 0.5f}}), &done), Status::kOk);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(10.5, cloudOf({{2, 3, 0}}), &done), Status::kOk);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(11.05, cloudOf({{0, 0, 0}}), &done), Status::kOk);  // closes the window
  ASSERT_TRUE(done);
  EXPECT_EQ(done->id, 5);
  EXPECT_DOUBLE_EQ(done->stamp, 10.0);
  EXPECT_TRUE(done->T_O_S.translation().isApprox(Eigen::Vector3d(2, 0, 0), 1e-9));
  ASSERT_EQ(done->cloud->size(), 2u);
  EXPECT_NEAR((*done->cloud)[0].x, 1.0, 1e-5);  // 1 m ahead = +x of S
  EXPECT_NEAR((*done->cloud)[0].y, 0.0, 1e-5);
  EXPECT_NEAR((*done->cloud)[0].z, 0.5, 1e-5);
  EXPECT_NEAR((*done->cloud)[1].x, 3.0, 1e-5);
  // The closing cloud anchors the next submap (sensor at x = 3.05 m, interpolated).
  const auto next = a.flush();
  ASSERT_TRUE(next);
  EXPECT_EQ(next->id, 6);
  EXPECT_NEAR(next->T_O_S.translation().x(), 3.05, 1e-6);
  EXPECT_NEAR((*next->cloud)[0].y, 3.05, 1e-5);  // O origin lies 3.05 m to the left of S
}

TEST(SubmapAssembler, DropsDuplicateAndOutOfOrderStamps) {
  SubmapAssembler a{SubmapAssemblerParams()};
  EXPECT_EQ(a.addOdometry(1.0, Pose::Identity()), Status::kOk);
  EXPECT_EQ(a.addOdometry(1.0, Pose::Identity()), Status::kDuplicateStamp);
  EXPECT_EQ(a.addOdometry(0.9, Pose::Identity()), Status::kOutOfOrder);
  EXPECT_EQ(a.addOdometry(1.1, Pose::Identity()), Status::kOk);
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addCloud(1.05, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addCloud(1.05, cloudOf({{1, 1, 1}}), &done), Status::kDuplicateStamp);
  EXPECT_EQ(a.addCloud(1.00, cloudOf({{1, 1, 1}}), &done), Status::kOutOfOrder);
  EXPECT_EQ(a.addCloud(1.08, Cloud(), &done), Status::kEmptyCloud);
  const auto s = a.flush();
  ASSERT_TRUE(s);
  EXPECT_EQ(s->cloud->size(), 1u);
}

TEST(SubmapAssembler, NeedsOdometryNearTheAnchor) {
  SubmapAssembler a{SubmapAssemblerParams()};
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addCloud(1.0, cloudOf({{1, 1, 1}}), &done), Status::kNoOdometry);
  EXPECT_EQ(a.addOdometry(2.0, Pose::Identity()), Status::kOk);
  EXPECT_EQ(a.addCloud(3.0, cloudOf({{1, 1, 1}}), &done), Status::kNoOdometry);  // 1 s stale
  EXPECT_EQ(a.addCloud(3.1, cloudOf({{1, 1, 1}}), &done), Status::kNoOdometry);
  EXPECT_FALSE(a.flush());
}

TEST(SubmapAssembler, OdometryGapDiscardsTheOpenSubmap) {
  SubmapAssembler a{SubmapAssemblerParams()};
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addOdometry(1.0, Pose::Identity()), Status::kOk);
  EXPECT_EQ(a.addCloud(1.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addOdometry(5.0, Pose::Identity()), Status::kOdometryGap);
  EXPECT_FALSE(a.flush());
  EXPECT_EQ(a.addCloud(5.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);  // starts afresh
  EXPECT_TRUE(a.flush());
}

TEST(SubmapAssembler, CapsPointsAndSkipsNaN) {
  SubmapAssemblerParams p;
  p.max_submap_points = 2;
  SubmapAssembler a(p);
  std::optional<AssembledSubmap> done;
  a.addOdometry(1.0, Pose::Identity());
  Cloud c = cloudOf({{1, 0, 0}, {NAN, 0, 0}, {2, 0, 0}, {3, 0, 0}});
  EXPECT_EQ(a.addCloud(1.0, c, &done), Status::kTruncated);
  const auto s = a.flush();
  ASSERT_TRUE(s);
  ASSERT_EQ(s->cloud->size(), 2u);
  EXPECT_FLOAT_EQ((*s->cloud)[1].x, 2.0f);
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
