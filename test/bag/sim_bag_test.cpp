// The simulator's bag sink without ROS: per-frame cloud reduction, parameters, frame names.
// Its bags read back with rosbag itself: test/ros/rosbag_writer_test.cpp.
#include "dtif/bag/sim_bag.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>

#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
  return test::freshTempDir("dtif_sim_bag_test_" + name);
}

TEST(SimBag, VoxelFilterAveragesPerVoxelInFirstSeenOrder) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<Eigen::Vector3f> pts = {
      {0.1f, 0.1f, 0.1f},  {2.5f, 0.0f, 0.0f}, {0.3f, 0.5f, 0.9f},   // voxels A, B, A
      {-0.5f, 0.2f, 0.2f}, {nan, 0.0f, 0.0f},  {0.9f, 0.9f, 0.2f}};  // C (x < 0), dropped, A
  const std::vector<float> in = {10, 20, 30, 40, 50, 80};
  std::vector<Eigen::Vector3f> out;
  std::vector<float> out_i;
  sim::voxelFilter(pts, in, 1.0, &out, &out_i);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_TRUE(out[0].isApprox(Eigen::Vector3f(1.3f / 3, 1.5f / 3, 1.2f / 3), 1e-6f));
  EXPECT_TRUE(out[1].isApprox(Eigen::Vector3f(2.5f, 0, 0)));
  EXPECT_TRUE(out[2].isApprox(Eigen::Vector3f(-0.5f, 0.2f, 0.2f)));
  EXPECT_FLOAT_EQ(out_i[0], 40.0f);
  EXPECT_FLOAT_EQ(out_i[1], 20.0f);
  EXPECT_FLOAT_EQ(out_i[2], 40.0f);

  // Far from the origin the centroid stays exact (sums relative to the voxel's first point;
  // float steps are 1/32 m at 5e5 m).
  const Eigen::Vector3f far(500000.0f, 0.0f, 0.0f), step(0.03125f, 0.0f, 0.0f);
  sim::voxelFilter({far, far + step, far + 2 * step}, {}, 1.0, &out, &out_i);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].x(), 500000.03125f);
  EXPECT_EQ(out_i, std::vector<float>{0.0f});  // no intensities: zeros

  // voxel 0: a copy without the NaN point.
  sim::voxelFilter(pts, in, 0.0, &out, &out_i);
  ASSERT_EQ(out.size(), 5u);
  EXPECT_EQ(out[3], pts[3]);
  EXPECT_EQ(out[4], pts[5]);
  EXPECT_EQ(out_i, (std::vector<float>{10, 20, 30, 40, 80}));

  sim::voxelFilter({}, {}, 0.1, &out, &out_i);
  EXPECT_TRUE(out.empty());
  EXPECT_TRUE(out_i.empty());
}

TEST(SimBag, ThinEvenlyKeepsSpreadIndices) {
  std::vector<Eigen::Vector3f> p;
  std::vector<float> in;
  for (int i = 0; i < 10; ++i) {
    p.emplace_back(static_cast<float>(i), 0.0f, 0.0f);
    in.push_back(static_cast<float>(100 + i));
  }
  auto q = p;
  auto qi = in;
  sim::thinEvenly(4, &q, &qi);  // floor(i * 10 / 4) = 0, 2, 5, 7
  ASSERT_EQ(q.size(), 4u);
  EXPECT_EQ(q[1].x(), 2.0f);
  EXPECT_EQ(q[2].x(), 5.0f);
  EXPECT_EQ(q[3].x(), 7.0f);
  EXPECT_EQ(qi, (std::vector<float>{100, 102, 105, 107}));
  q = p;
  sim::thinEvenly(0, &q, &qi);  // no limit
  EXPECT_EQ(q.size(), 10u);
  sim::thinEvenly(10, &q, &qi);
  EXPECT_EQ(q, p);
}

TEST(SimBag, ParamsValidateAndFrameNames) {
  EXPECT_EQ(sim::BagParams{}.validate(), "");
  sim::BagParams p;
  p.voxel_m = -1.0;
  p.node = "a/b";
  EXPECT_NE(p.validate().find("voxel_m"), std::string::npos);
  EXPECT_NE(p.validate().find("node"), std::string::npos);
  EXPECT_THROW(sim::BagFrameSink((tempDir("params") / "x.bag").string(), p), bag::RosbagError);
  EXPECT_EQ(sim::odomFrame("alpha"), "alpha/odom");
  EXPECT_EQ(sim::bodyFrame("alpha"), "alpha/base_link");
}

}  // namespace
}  // namespace dtif
