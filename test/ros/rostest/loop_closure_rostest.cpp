// Integration test run by test/loop_closure.test, which includes the shipped launch files: a
// base station for robots alpha and bravo, and a trunk-extraction nodelet for robot charlie, all
// in one manager. Publishes hand-built descriptors and raw clouds, waits with deadlines (no fixed
// sleeps for results), asserts on loop closures, TF, the database services and that bad input
// leaves both nodelets working.
#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <pcl_conversions/pcl_conversions.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <mutex>
#include <random>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/msgs.h"
#include "rostest_utils.h"

namespace dtif {
namespace {

using ros_glue::fromMsg;
using ros_glue::toMsg;
using test::Inbox;
using test::waitFor;

Pose pose2d(double x, double y, double z, double yaw) {
  Pose T = Pose::Identity();
  T.linear() = rotZ(yaw);
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

// Fixed-seed forest in W: trunks at least 3 m apart on a gentle slope.
Trunks forestW() {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> xy(-30.0, 30.0), r(0.1, 0.35);
  Trunks t;
  for (int tries = 0; tries < 20000 && t.size() < 110; ++tries) {
    TrunkLandmark c{xy(rng), xy(rng), 0.0, r(rng)};
    c.z = 0.05 * c.x - 0.02 * c.y;
    bool ok = true;
    for (const TrunkLandmark& o : t) ok = ok && std::hypot(o.x - c.x, o.y - c.y) > 3.0;
    if (ok) t.push_back(c);
  }
  return t;
}

// The trunks within radius of the submap origin, in the submap frame S.
Trunks submapTrunks(const Trunks& w, const Pose& T_W_S, double radius) {
  const Pose T_S_W = T_W_S.inverse();
  Trunks out;
  for (const TrunkLandmark& t : w) {
    const Eigen::Vector3d p = T_S_W * Eigen::Vector3d(t.x, t.y, t.z);
    if (std::hypot(p.x(), p.y()) <= radius) out.push_back(TrunkLandmark{p.x(), p.y(), p.z(), t.r});
  }
  return out;
}

dtif::TrunkDescriptor descriptorMsg(const std::string& robot, int64_t id, double stamp,
                                    const Trunks& trunks, const Pose& T_O_S) {
  Descriptor d = buildDescriptor(trunks, DescriptorParams());
  d.robot = robot;
  d.submap_id = id;
  d.stamp = stamp;
  return toMsg(d, T_O_S, robot + "/odom");
}

class LoopClosureRostest : public ::testing::Test {
 protected:
  void SetUp() override {
    spinner_.start();
    alpha_pub_ = nh_.advertise<dtif::TrunkDescriptor>("/alpha/descriptor", 10);
    bravo_pub_ = nh_.advertise<dtif::TrunkDescriptor>("/bravo/descriptor", 10);
    loop_sub_ = nh_.subscribe("/loop_closures", 10, &Inbox<dtif::LoopClosure>::cb, &loops_);
    ASSERT_TRUE(waitFor(
        [&] {
          return alpha_pub_.getNumSubscribers() > 0 && bravo_pub_.getNumSubscribers() > 0 &&
                 loop_sub_.getNumPublishers() > 0;
        },
        30.0))
        << "the loop-closure nodelet did not come up";
  }

  ros::NodeHandle nh_;
  ros::AsyncSpinner spinner_{2};
  ros::Publisher alpha_pub_, bravo_pub_;
  ros::Subscriber loop_sub_;
  Inbox<dtif::LoopClosure> loops_;
};

TEST_F(LoopClosureRostest, InterRobotLoopTfServicesAndBadInput) {
  const Trunks w = forestW();
  const Pose T_W_Sa = pose2d(-6.0, 1.0, 0.4, 0.3);
  const Pose T_W_Sb = pose2d(5.0, 3.0, 0.1, -1.0);
  const Pose T_Oa_Sa = pose2d(1.0, 2.0, 0.0, 0.1);
  const Pose T_Ob_Sb = pose2d(-3.0, 4.0, 0.1, 0.5);
  const Trunks ta = submapTrunks(w, T_W_Sa, 20.0);
  const Trunks tb = submapTrunks(w, T_W_Sb, 20.0);
  ASSERT_GE(ta.size(), 20u);
  ASSERT_GE(tb.size(), 20u);

  // Bad input first: 2 trunks, a NaN trunk, a face past the end, a robot on the wrong topic.
  {
    dtif::TrunkDescriptor two = descriptorMsg("bravo", 90, 150.0, {tb[0], tb[1]}, T_Ob_Sb);
    two.valid = true;  // lie: the nodelet must still refuse it
    bravo_pub_.publish(two);
    dtif::TrunkDescriptor nan = descriptorMsg("alpha", 91, 151.0, ta, T_Oa_Sa);
    nan.trunks[0].x = std::numeric_limits<float>::quiet_NaN();
    alpha_pub_.publish(nan);
    dtif::TrunkDescriptor face = descriptorMsg("alpha", 92, 152.0, ta, T_Oa_Sa);
    face.faces[0] = 60000;
    alpha_pub_.publish(face);
    bravo_pub_.publish(descriptorMsg("alpha", 93, 153.0, ta, T_Oa_Sa));
  }
  ros::ServiceClient size_srv =
      nh_.serviceClient<dtif::GetDatabaseSize>("/loop_closure/database_size");
  ASSERT_TRUE(size_srv.waitForExistence(ros::Duration(10.0)));
  dtif::GetDatabaseSize size;
  // The worker drains the queue in order; the size service answers between descriptors.
  ASSERT_TRUE(size_srv.call(size));

  alpha_pub_.publish(descriptorMsg("alpha", 1, 100.0, ta, T_Oa_Sa));
  ASSERT_TRUE(waitFor([&] { return size_srv.call(size) && size.response.size == 1; }, 10.0))
      << "alpha's descriptor was not inserted (size " << size.response.size << ")";
  bravo_pub_.publish(descriptorMsg("bravo", 1, 200.0, tb, T_Ob_Sb));
  ASSERT_TRUE(waitFor([&] { return loops_.size() >= 1; }, 20.0)) << "no loop closure";

  const auto lc = loops_.at(0);
  EXPECT_EQ(lc->query_robot, "bravo");
  EXPECT_EQ(lc->query_id, 1);
  EXPECT_EQ(lc->candidate_robot, "alpha");
  EXPECT_EQ(lc->candidate_id, 1);
  EXPECT_EQ(lc->header.frame_id, "alpha/odom");
  EXPECT_NEAR(lc->header.stamp.toSec(), 200.0, 1e-6);
  EXPECT_GE(lc->inliers, 6);
  EXPECT_EQ(lc->inlier_query_trunks.size(), lc->inlier_candidate_trunks.size());
  Pose T_c_q;
  ASSERT_TRUE(fromMsg(lc->T_c_q, &T_c_q));
  const Pose T_c_q_true = T_W_Sa.inverse() * T_W_Sb;
  EXPECT_LT((T_c_q.translation() - T_c_q_true.translation()).norm(), 0.05);
  EXPECT_LT(Eigen::AngleAxisd(T_c_q.rotation().transpose() * T_c_q_true.rotation()).angle(),
            0.2 * M_PI / 180.0);

  // TF alpha/odom <- bravo/odom = T_Oa_Sa * T_c_q * inverse(T_Ob_Sb).
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  std::string tf_error;
  ASSERT_TRUE(
      buffer.canTransform("alpha/odom", "bravo/odom", ros::Time(0), ros::Duration(5.0), &tf_error))
      << tf_error;
  const auto tf = buffer.lookupTransform("alpha/odom", "bravo/odom", ros::Time(0));
  const Pose T_Oa_Ob_true = T_Oa_Sa * T_c_q_true * T_Ob_Sb.inverse();
  EXPECT_NEAR(tf.transform.translation.x, T_Oa_Ob_true.translation().x(), 0.05);
  EXPECT_NEAR(tf.transform.translation.y, T_Oa_Ob_true.translation().y(), 0.05);
  EXPECT_NEAR(tf.transform.translation.z, T_Oa_Ob_true.translation().z(), 0.05);

  // Database services: size, save, corrupt load refused (database unchanged), load.
  ASSERT_TRUE(size_srv.call(size));
  EXPECT_EQ(size.response.size, 2u);
  ASSERT_EQ(size.response.robots.size(), 2u);
  EXPECT_EQ(size.response.robots[0], "alpha");
  EXPECT_EQ(size.response.per_robot[0], 1u);
  const std::string dir = "/tmp/dtif_rostest_" + std::to_string(getpid());
  ASSERT_EQ(system(("mkdir -p " + dir).c_str()), 0);
  dtif::SaveDatabase save;
  save.request.path = dir + "/db.bin";
  ASSERT_TRUE(ros::service::call("/loop_closure/save_database", save));
  EXPECT_TRUE(save.response.success) << save.response.message;
  EXPECT_EQ(save.response.size, 2u);
  {
    std::ofstream corrupt(dir + "/corrupt.bin");
    corrupt << "this is not a dtif database\n";
  }
  dtif::LoadDatabase load;
  load.request.path = dir + "/corrupt.bin";
  ASSERT_TRUE(ros::service::call("/loop_closure/load_database", load));
  EXPECT_FALSE(load.response.success);
  EXPECT_FALSE(load.response.message.empty());
  EXPECT_EQ(load.response.size, 2u);
  load.request.path = dir + "/db.bin";
  ASSERT_TRUE(ros::service::call("/loop_closure/load_database", load));
  EXPECT_TRUE(load.response.success) << load.response.message;
  EXPECT_EQ(load.response.size, 2u);
  ASSERT_EQ(system(("rm -rf " + dir).c_str()), 0);

  // After reloading, a third submap of bravo close to the first still closes a loop.
  const Pose T_W_Sb2 = pose2d(-4.0, -1.0, 0.2, 2.0);
  bravo_pub_.publish(
      descriptorMsg("bravo", 2, 300.0, submapTrunks(w, T_W_Sb2, 20.0), pose2d(0, 0, 0, 0)));
  ASSERT_TRUE(waitFor([&] { return loops_.size() >= 2; }, 20.0)) << "no loop after reload";
  EXPECT_EQ(loops_.at(1)->query_id, 2);
}

TEST(TrunkExtractionRostest, AssemblesSubmapsAndSurvivesBadClouds) {
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(1);
  spinner.start();
  ros::Publisher odom_pub = nh.advertise<nav_msgs::Odometry>("/charlie/Odometry", 100);
  ros::Publisher cloud_pub =
      nh.advertise<sensor_msgs::PointCloud2>("/charlie/cloud_registered", 20);
  Inbox<dtif::TrunkDescriptor> descriptors;
  ros::Subscriber sub =
      nh.subscribe("/charlie/descriptor", 10, &Inbox<dtif::TrunkDescriptor>::cb, &descriptors);
  ASSERT_TRUE(waitFor(
      [&] {
        return odom_pub.getNumSubscribers() > 0 && cloud_pub.getNumSubscribers() > 0 &&
               sub.getNumPublishers() > 0;
      },
      30.0))
      << "the trunk-extraction nodelet did not come up";

  auto cloudMsg = [](const pcl::PointCloud<pcl::PointXYZ>& c, double stamp,
                     const std::string& frame) {
    sensor_msgs::PointCloud2 m;
    pcl::toROSMsg(c, m);
    m.header.stamp.fromSec(stamp);
    m.header.frame_id = frame;
    return m;
  };
  // Bad clouds: empty, all NaN, wrong frame, no fields.
  pcl::PointCloud<pcl::PointXYZ> empty, nan;
  nan.push_back(pcl::PointXYZ(NAN, NAN, NAN));
  cloud_pub.publish(cloudMsg(empty, 0.5, "charlie/odom"));
  cloud_pub.publish(cloudMsg(nan, 0.6, "charlie/odom"));
  sensor_msgs::PointCloud2 fieldless;
  fieldless.header.frame_id = "charlie/odom";
  cloud_pub.publish(fieldless);

  // Odometry at 20 Hz for 3 s: sensor at (1, 2, 0.5) rolled 0.1 rad, yaw 30 deg, then moving.
  const double yaw = 30.0 * M_PI / 180.0;
  for (int i = 0; i <= 60; ++i) {
    const double t = 1.0 + 0.05 * i;
    nav_msgs::Odometry o;
    o.header.stamp.fromSec(t);
    o.header.frame_id = "charlie/odom";
    const Eigen::Quaterniond q(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()));
    o.pose.pose.position.x = 1.0 + 0.2 * (t - 1.0);
    o.pose.pose.position.y = 2.0;
    o.pose.pose.position.z = 0.5;
    o.pose.pose.orientation.x = q.x();
    o.pose.pose.orientation.y = q.y();
    o.pose.pose.orientation.z = q.z();
    o.pose.pose.orientation.w = q.w();
    odom_pub.publish(o);
  }
  // Odometry and clouds travel on different connections: let the odometry arrive first.
  ros::WallDuration(1.0).sleep();
  pcl::PointCloud<pcl::PointXYZ> stem;
  for (int k = 0; k < 30; ++k) stem.push_back(pcl::PointXYZ(5.0f, 2.0f, 0.1f * k));
  // The first cloud (1.0, covering 0.9-1.0) starts window (0.9, 1.9]; its centre 1.4 anchors it.
  cloud_pub.publish(cloudMsg(stem, 1.0, "charlie/odom"));
  cloud_pub.publish(cloudMsg(stem, 1.0, "charlie/odom"));  // duplicate stamp
  cloud_pub.publish(cloudMsg(stem, 1.5, "wrong_frame"));
  cloud_pub.publish(cloudMsg(stem, 1.6, "charlie/odom"));
  cloud_pub.publish(cloudMsg(stem, 1.3, "charlie/odom"));  // older than the previous one
  cloud_pub.publish(cloudMsg(stem, 2.2, "charlie/odom"));  // next window: finishes the first

  ASSERT_TRUE(waitFor([&] { return descriptors.size() >= 1; }, 15.0)) << "no descriptor";
  const auto d = descriptors.at(0);
  EXPECT_EQ(d->robot, "charlie");
  EXPECT_EQ(d->submap_id, 0);
  EXPECT_EQ(d->header.frame_id, "charlie/odom");
  EXPECT_NEAR(d->header.stamp.toSec(), 1.4, 1e-6);
  EXPECT_NEAR(d->data_end.toSec(), 1.6, 1e-6);
  Pose T_O_S;
  ASSERT_TRUE(fromMsg(d->odom_pose, &T_O_S));
  EXPECT_NEAR(T_O_S.translation().x(), 1.08, 1e-6);  // odometry at 1.4
  EXPECT_NEAR(T_O_S.translation().y(), 2.0, 1e-6);
  EXPECT_NEAR(T_O_S.rotation()(2, 2), 1.0, 1e-9);  // gravity-aligned: roll removed
  EXPECT_NEAR(std::atan2(T_O_S.rotation()(1, 0), T_O_S.rotation()(0, 0)), yaw, 1e-3);
  EXPECT_FALSE(d->valid);  // one synthetic stem: too few trunks
}

}  // namespace
}  // namespace dtif

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "loop_closure_rostest");
  return RUN_ALL_TESTS();
}
