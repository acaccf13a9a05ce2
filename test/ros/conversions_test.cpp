// Glue tests without a master: message conversions round trip and reject bad input.
#include "dtif/ros/conversions.h"

#include <gtest/gtest.h>
#include <pcl/point_types.h>
#include <pcl_conversions/pcl_conversions.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "core/descriptor_test_utils.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/descriptor/validation.h"
#include "test_utils.h"

namespace dtif {
namespace ros_glue {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

using test::makePose;

// A fixed-seed trunk map with plausible spacing (about 4 m) and radii.
Trunks forest(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> xy(-15.0, 15.0), z(-0.3, 0.3), r(0.08, 0.35);
  Trunks t;
  while (static_cast<int>(t.size()) < n) {
    TrunkLandmark c{xy(rng), xy(rng), z(rng), r(rng)};
    bool ok = true;
    for (const TrunkLandmark& o : t) ok = ok && std::hypot(o.x - c.x, o.y - c.y) > 2.0;
    if (ok) t.push_back(c);
  }
  return t;
}

TEST(PoseConversion, RoundTrip) {
  const Pose T = makePose(1.5, -2.0, 0.25, 0.02, -0.01, 2.5);
  Pose back;
  ASSERT_TRUE(fromMsg(toMsg(T), &back));
  EXPECT_TRUE(back.isApprox(T, 1e-12));
}

TEST(PoseConversion, RejectsNaNAndZeroQuaternionNormalisesOthers) {
  geometry_msgs::Pose m = toMsg(Pose::Identity());
  Pose T;
  std::string error;
  m.position.y = kNaN;
  EXPECT_FALSE(fromMsg(m, &T, &error));
  EXPECT_NE(error.find("non-finite"), std::string::npos);
  m = geometry_msgs::Pose();  // all zero, quaternion too
  EXPECT_FALSE(fromMsg(m, &T, &error));
  m.orientation.w = 2.0;  // not unit: normalised
  ASSERT_TRUE(fromMsg(m, &T));
  EXPECT_TRUE(T.linear().isApprox(Eigen::Matrix3d::Identity()));
}

TEST(DescriptorConversion, RoundTripRebuildsTriangles) {
  Trunks trunks = forest(25, 7);
  for (size_t i = 0; i < trunks.size(); i += 3) trunks[i].base_seen = false;
  Descriptor d = buildDescriptor(trunks, DescriptorParams());
  d.footprint = makeFootprint({{-4, 2}, {-3, 2}, {7, 9}, {0, 0}}, 1.0);
  d.robot = "alpha";
  d.submap_id = 42;
  d.stamp = 1234.5;
  ASSERT_FALSE(d.triangles.empty());
  const Pose T_O_S = makePose(10.0, 20.0, -1.0, 0.0, 0.0, 0.7);
  const dtif::TrunkDescriptor m = toMsg(d, T_O_S, "alpha/odom");
  EXPECT_EQ(m.header.frame_id, "alpha/odom");
  EXPECT_EQ(m.faces.size(), 3 * d.triangles.size());

  Descriptor back;
  Pose T_back;
  std::string error;
  ASSERT_TRUE(fromMsg(m, DescriptorParams(), &back, &T_back, &error)) << error;
  EXPECT_EQ(back.robot, "alpha");
  EXPECT_EQ(back.submap_id, 42);
  EXPECT_NEAR(back.stamp, 1234.5, 1e-6);
  EXPECT_TRUE(T_back.isApprox(T_O_S, 1e-12));
  EXPECT_EQ(back.valid, d.valid);
  EXPECT_EQ(back.invalid_reason, d.invalid_reason);
  ASSERT_EQ(back.trunks.size(), d.trunks.size());
  for (size_t i = 0; i < d.trunks.size(); ++i) {
    EXPECT_NEAR(back.trunks[i].x, d.trunks[i].x, 1e-5);
    EXPECT_NEAR(back.trunks[i].y, d.trunks[i].y, 1e-5);
    EXPECT_NEAR(back.trunks[i].z, d.trunks[i].z, 1e-5);
    EXPECT_NEAR(back.trunks[i].r, d.trunks[i].r, 1e-6);
    EXPECT_EQ(back.trunks[i].base_seen, d.trunks[i].base_seen) << "trunk " << i;
  }
  ASSERT_EQ(back.triangles.size(), d.triangles.size());
  for (size_t i = 0; i < d.triangles.size(); ++i) {
    EXPECT_EQ(back.triangles[i].v, d.triangles[i].v) << "triangle " << i;
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(back.triangles[i].len[k], d.triangles[i].len[k], 1e-4);
      EXPECT_NEAR(back.triangles[i].r[k], d.triangles[i].r[k], 1e-6);
    }
  }
  EXPECT_EQ(back.edge_hist, d.edge_hist);
  EXPECT_EQ(back.radius_hist, d.radius_hist);
  EXPECT_EQ(back.footprint.cell_m, 1.0);
  EXPECT_EQ(back.footprint.x0, -4);
  EXPECT_EQ(back.footprint.y0, 0);
  EXPECT_EQ(back.footprint.bits, d.footprint.bits);
  EXPECT_TRUE(back.footprint.occupied(7, 9));

  EXPECT_FALSE(back.accumulated);
  EXPECT_TRUE(back.own_trunks.empty());

  // An accumulated descriptor's own trunks travel beside its trunks.
  d.accumulated = true;
  d.own_trunks = {TrunkLandmark{3.0, -2.0, 0.4, 0.15, true},
                  TrunkLandmark{8.0, 1.0, 0.1, 0.3, false}};
  ASSERT_TRUE(fromMsg(toMsg(d, T_O_S, "alpha/odom"), DescriptorParams(), &back, &T_back, &error))
      << error;
  EXPECT_TRUE(back.accumulated);
  ASSERT_EQ(back.own_trunks.size(), 2u);
  EXPECT_NEAR(back.own_trunks[1].x, 8.0, 1e-6);
  EXPECT_NEAR(back.own_trunks[0].r, 0.15, 1e-6);
  EXPECT_TRUE(back.own_trunks[0].base_seen);
  EXPECT_FALSE(back.own_trunks[1].base_seen);
  EXPECT_EQ(back.trunks.size(), d.trunks.size());
  dtif::TrunkDescriptor nan_own = toMsg(d, T_O_S, "alpha/odom");
  nan_own.own_trunks[0].r = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(fromMsg(nan_own, DescriptorParams(), &back, &T_back, &error));
  EXPECT_NE(error.find("own trunks"), std::string::npos) << error;

  // A bitmap that does not fit its size is rejected, not read past its end.
  dtif::TrunkDescriptor bad = m;
  bad.footprint_bits.pop_back();
  EXPECT_FALSE(fromMsg(bad, DescriptorParams(), &back, &T_back, &error));
  EXPECT_NE(error.find("footprint"), std::string::npos) << error;
}

TEST(DescriptorConversion, RejectsBadMessages) {
  const Descriptor d = buildDescriptor(forest(10, 3), DescriptorParams());
  ASSERT_FALSE(d.triangles.empty());
  const dtif::TrunkDescriptor good = toMsg(d, Pose::Identity(), "o");
  Descriptor out;
  std::string error;

  dtif::TrunkDescriptor m = good;
  m.faces.back() = static_cast<uint16_t>(m.trunks.size());  // index past the end
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));
  EXPECT_NE(error.find("missing trunk"), std::string::npos) << error;

  m = good;
  m.faces.pop_back();  // not triples
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));

  m = good;
  m.faces[1] = m.faces[0];  // repeated vertex
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));

  m = good;
  m.trunks[0].x = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));

  m = good;
  m.edge_hist.push_back(std::numeric_limits<float>::infinity());
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));

  m = good;
  m.odom_pose.orientation.w = kNaN;
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));
  EXPECT_NE(error.find("odom_pose"), std::string::npos) << error;

  m = dtif::TrunkDescriptor();  // empty: converts, stays invalid
  m.odom_pose.orientation.w = 1.0;
  ASSERT_TRUE(fromMsg(m, DescriptorParams(), &out, nullptr, &error)) << error;
  EXPECT_TRUE(out.trunks.empty());
  EXPECT_FALSE(out.valid);
}

// fromMsg and decodeDescriptor end in the same acceptReceivedDescriptor: what one rejects the
// other rejects, in the same words, and both rebuild the same faces.
std::string decodeError(const Descriptor& d) {
  try {
    decodeDescriptor(encodeDescriptor(d), DescriptorParams());
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(DescriptorConversion, RejectsWhatDecodeRejectsInTheSameWords) {
  const Descriptor good = buildDescriptor(forest(12, 4), DescriptorParams());
  ASSERT_TRUE(good.valid);
  ASSERT_GT(good.triangles.size(), 4u);
  const auto corruptions = test::descriptorCorruptions();
  for (size_t i = 0; i < corruptions.size(); ++i) {
    Descriptor bad = good;
    corruptions[i](bad);
    const std::string want = checkDescriptor(bad);
    ASSERT_NE(want, "") << "case " << i;
    EXPECT_EQ(decodeError(bad), want) << "case " << i;
    Descriptor out;
    std::string error;
    EXPECT_FALSE(
        fromMsg(toMsg(bad, Pose::Identity(), "o"), DescriptorParams(), &out, nullptr, &error));
    EXPECT_EQ(error, want) << "case " << i;
  }
  // What only a message can carry: its words are checkDescriptor's too.
  dtif::TrunkDescriptor m = toMsg(good, Pose::Identity(), "o");
  m.footprint_cell_m = -1.0f;
  Descriptor bad = good;
  bad.footprint.cell_m = -1.0;
  Descriptor out;
  std::string error;
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));
  EXPECT_EQ(error, checkDescriptor(bad));
  m = toMsg(good, Pose::Identity(), "o");
  m.radius_hist.assign(256, 1.0f / 256);
  bad = good;
  bad.radius_hist = m.radius_hist;
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));
  EXPECT_EQ(error, checkDescriptor(bad));
  m = toMsg(good, Pose::Identity(), "o");
  m.ground_map = {1, 2, 3};
  EXPECT_FALSE(fromMsg(m, DescriptorParams(), &out, nullptr, &error));
  GroundMap unused;
  EXPECT_EQ(error, decodeReceivedGroundMap(m.ground_map.data(), m.ground_map.size(), &unused));
}

TEST(DescriptorConversion, ReceiverParamsAndFacesAsDecodeHasThem) {
  Descriptor good = buildDescriptor(forest(12, 4), DescriptorParams());
  ASSERT_TRUE(good.valid);
  const int n = static_cast<int>(good.trunks.size());
  DescriptorParams strict;
  strict.min_trunks = n + 1;
  const dtif::TrunkDescriptor m = toMsg(good, Pose::Identity(), "o");
  Descriptor from_msg;
  std::string error;
  ASSERT_TRUE(fromMsg(m, strict, &from_msg, nullptr, &error)) << error;  // not an error
  const Descriptor decoded = decodeDescriptor(encodeDescriptor(good), strict);
  EXPECT_FALSE(from_msg.valid);
  EXPECT_FALSE(decoded.valid);
  EXPECT_EQ(from_msg.invalid_reason, decoded.invalid_reason);
  EXPECT_NE(from_msg.invalid_reason.find("too few trunks"), std::string::npos);
  // The loosest params keep the sender's word; a lying sender (2 trunks "valid") is caught.
  ASSERT_TRUE(fromMsg(m, loosestDescriptorParams(), &from_msg, nullptr, &error)) << error;
  EXPECT_TRUE(from_msg.valid);
  dtif::TrunkDescriptor two = m;
  two.trunks.resize(2);
  two.faces.clear();
  ASSERT_TRUE(fromMsg(two, loosestDescriptorParams(), &from_msg, nullptr, &error)) << error;
  EXPECT_FALSE(from_msg.valid);
  // Faces in a shuffled order come back in buildDescriptor's order, as decode gives them.
  dtif::TrunkDescriptor shuffled = m;
  for (size_t f = 0; f + 3 < shuffled.faces.size(); f += 6) {
    std::swap_ranges(shuffled.faces.begin() + f, shuffled.faces.begin() + f + 3,
                     shuffled.faces.begin() + f + 3);
  }
  ASSERT_NE(shuffled.faces, m.faces);
  ASSERT_TRUE(fromMsg(shuffled, DescriptorParams(), &from_msg, nullptr, &error)) << error;
  const Descriptor plain = decodeDescriptor(encodeDescriptor(good), DescriptorParams());
  ASSERT_EQ(from_msg.triangles.size(), plain.triangles.size());
  for (size_t i = 0; i < plain.triangles.size(); ++i) {
    EXPECT_EQ(from_msg.triangles[i].v, plain.triangles[i].v) << "face " << i;
    EXPECT_EQ(from_msg.triangles[i].v, good.triangles[i].v) << "face " << i;
  }
}

TEST(LoopClosureConversion, RoundTrip) {
  Loop lc;
  lc.query_robot = "bravo";
  lc.query_id = 7;
  lc.candidate_robot = "alpha";
  lc.candidate_id = 3;
  lc.T_c_q = makePose(4.0, -3.0, 0.2, 0.0, 0.0, -1.2);
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) lc.covariance(r, c) = r == c ? 0.01 * (r + 1) : 0.001 * (r + c);
  }
  lc.inliers = 3;
  lc.score = 0.8;
  lc.inlier_pairs = {{0, 5}, {2, 1}, {9, 4}};
  const dtif::LoopClosure m = toMsg(lc);
  EXPECT_EQ(m.covariance[6 * 1 + 2], lc.covariance(1, 2));  // row-major
  Loop back;
  ASSERT_TRUE(fromMsg(m, &back));
  EXPECT_EQ(back.query_robot, "bravo");
  EXPECT_EQ(back.query_id, 7);
  EXPECT_EQ(back.candidate_robot, "alpha");
  EXPECT_EQ(back.candidate_id, 3);
  EXPECT_TRUE(back.T_c_q.isApprox(lc.T_c_q, 1e-12));
  EXPECT_TRUE(back.covariance.isApprox(lc.covariance));
  EXPECT_EQ(back.inliers, 3);
  EXPECT_DOUBLE_EQ(back.score, 0.8);
  EXPECT_EQ(back.inlier_pairs, lc.inlier_pairs);

  dtif::LoopClosure bad = m;
  bad.inlier_candidate_trunks.pop_back();
  EXPECT_FALSE(fromMsg(bad, &back));
  bad = m;
  bad.covariance[3] = kNaN;
  EXPECT_FALSE(fromMsg(bad, &back));
}

TEST(CloudConversion, DropsNonFinitePointsAndKeepsTheRest) {
  pcl::PointCloud<pcl::PointXYZI> in;
  in.push_back(pcl::PointXYZI(1.0f));
  in.back().x = 1.0f;
  in.back().y = 2.0f;
  in.back().z = 3.0f;
  pcl::PointXYZI nan_point;
  nan_point.x = std::numeric_limits<float>::quiet_NaN();
  in.push_back(nan_point);
  pcl::PointXYZI inf_point;
  inf_point.z = std::numeric_limits<float>::infinity();
  in.push_back(inf_point);
  in.push_back(pcl::PointXYZI(0.5f));
  in.back().x = -4.0f;
  sensor_msgs::PointCloud2 msg;
  pcl::toROSMsg(in, msg);
  Cloud out;
  size_t dropped = 0;
  std::string error;
  ASSERT_TRUE(fromMsg(msg, &out, &dropped, &error)) << error;
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(dropped, 2u);
  EXPECT_FLOAT_EQ(out[0].x, 1.0f);
  EXPECT_FLOAT_EQ(out[0].z, 3.0f);
  EXPECT_FLOAT_EQ(out[1].x, -4.0f);
}

TEST(CloudConversion, ReadsFloat64AndEmptyClouds) {
  sensor_msgs::PointCloud2 msg;
  const char* names[3] = {"x", "y", "z"};
  for (int i = 0; i < 3; ++i) {
    sensor_msgs::PointField f;
    f.name = names[i];
    f.offset = 8 * i;
    f.datatype = sensor_msgs::PointField::FLOAT64;
    f.count = 1;
    msg.fields.push_back(f);
  }
  msg.point_step = 24;
  msg.height = 1;
  msg.width = 1;
  msg.row_step = 24;
  const double xyz[3] = {1.25, -2.5, 1e5};
  msg.data.resize(24);
  std::memcpy(msg.data.data(), xyz, 24);
  Cloud out;
  ASSERT_TRUE(fromMsg(msg, &out));
  ASSERT_EQ(out.size(), 1u);
  EXPECT_FLOAT_EQ(out[0].y, -2.5f);
  EXPECT_FLOAT_EQ(out[0].z, 1e5f);

  msg.width = 0;
  msg.row_step = 0;
  msg.data.clear();
  ASSERT_TRUE(fromMsg(msg, &out));
  EXPECT_TRUE(out.empty());
}

TEST(CloudConversion, RejectsMissingFieldsAndShortData) {
  pcl::PointCloud<pcl::PointXYZ> in;
  in.push_back(pcl::PointXYZ(1, 2, 3));
  sensor_msgs::PointCloud2 msg;
  pcl::toROSMsg(in, msg);
  Cloud out;
  std::string error;
  sensor_msgs::PointCloud2 bad = msg;
  bad.data.resize(bad.data.size() / 2);
  EXPECT_FALSE(fromMsg(bad, &out, nullptr, &error));
  bad = msg;
  bad.fields[2].name = "intensity";
  EXPECT_FALSE(fromMsg(bad, &out, nullptr, &error));
  EXPECT_NE(error.find("no field z"), std::string::npos) << error;
  bad = msg;
  bad.fields[0].datatype = sensor_msgs::PointField::UINT8;
  EXPECT_FALSE(fromMsg(bad, &out, nullptr, &error));
  bad = msg;
  bad.point_step = 4;  // fields beyond the point
  bad.row_step = 4;
  EXPECT_FALSE(fromMsg(bad, &out, nullptr, &error));
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
