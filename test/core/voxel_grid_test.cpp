// The centroid voxel filter shared by the simulator's submaps and the ROS submap assembler.
#include "dtif/core/voxel_grid.h"

#include <gtest/gtest.h>

#include <random>

namespace dtif {
namespace {

TEST(VoxelCentroidGrid, MeanPerVoxelInKeyOrder) {
  VoxelCentroidGrid g(1.0);
  g.add({0.5f, 2.5f, 0.1f});   // voxel (0, 2, 0)
  g.add({-0.5f, 9.0f, 9.0f});  // (-1, 9, 9): smallest x index, added second
  g.add({0.7f, 2.1f, 0.3f});   // (0, 2, 0) again
  g.add({0.2f, 0.2f, 5.5f});   // (0, 0, 5): same x, smaller y than (0, 2, 0)
  EXPECT_EQ(g.raw(), 4u);
  EXPECT_EQ(g.voxels(), 3u);
  const std::vector<Eigen::Vector3f> c = g.centroids();
  ASSERT_EQ(c.size(), 3u);
  EXPECT_TRUE(c[0].isApprox(Eigen::Vector3f(-0.5f, 9.0f, 9.0f)));
  EXPECT_TRUE(c[1].isApprox(Eigen::Vector3f(0.2f, 0.2f, 5.5f)));
  EXPECT_TRUE(c[2].isApprox(Eigen::Vector3f(0.6f, 2.3f, 0.2f)));
}

TEST(VoxelCentroidGrid, OrderOfPointsDoesNotMatterAndClearEmpties) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-30.0f, 30.0f);
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 200000; ++i) {  // grows
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const float z = 0.1f * u(rng);
    const float y = u(rng);
    pts.emplace_back(u(rng), y, z);
  }
  VoxelCentroidGrid a(0.5), b(0.5);
  for (const auto& p : pts) a.add(p);
  for (auto it = pts.rbegin(); it != pts.rend(); ++it) b.add(*it);
  const auto ca = a.centroids(), cb = b.centroids();
  ASSERT_EQ(ca.size(), cb.size());
  EXPECT_GT(ca.size(), 50000u);
  for (size_t i = 0; i < ca.size(); ++i) ASSERT_TRUE(ca[i].isApprox(cb[i], 1e-5f)) << i;
  a.clear();
  EXPECT_EQ(a.raw(), 0u);
  EXPECT_TRUE(a.centroids().empty());
  a.add({1.0f, 1.0f, 1.0f});
  ASSERT_EQ(a.centroids().size(), 1u);
}

TEST(VoxelCentroidGrid, IgnoresPointsBeyondTheGrid) {
  VoxelCentroidGrid g(0.05);  // 2^20 voxels of 0.05 m: +-52 km
  g.add({6e4f, 0.0f, 0.0f});
  g.add({0.0f, -6e4f, 0.0f});
  g.add({1.0f, 1.0f, 1.0f});
  EXPECT_EQ(g.raw(), 1u);
  EXPECT_EQ(g.centroids().size(), 1u);
}

}  // namespace
}  // namespace dtif
