// The centroid voxel filter shared by the simulator's submaps and the ROS submap assembler.
#include "dtif/core/voxel_grid.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "dtif/core/cells.h"

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

TEST(CellIndex, IsTheFloorInsideTheRangeSaturatedOutsideAndZeroForNaN) {
  // Around integers (both sides, one ulp away), at +-0, and up to the saturation's edge.
  std::vector<double> v = {0.0, -0.0, 0.5, -0.5, 1e12, -1e12, 4.5e15, -4.5e15};
  for (double k : {1.0, -1.0, 7.0, -7.0, 1e6, -1e6, 1099511627775.0, -1099511627775.0}) {
    v.push_back(k);
    v.push_back(std::nextafter(k, 0.0));
    v.push_back(std::nextafter(k, k > 0 ? 1e300 : -1e300));
  }
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1e6, 1e6);
  for (int i = 0; i < 10000; ++i) v.push_back(u(rng));
  for (const double x : v) {
    const double f = std::floor(x);
    const int64_t want = f >= static_cast<double>(kMaxCellIndex)    ? kMaxCellIndex
                         : f <= -static_cast<double>(kMaxCellIndex) ? -kMaxCellIndex
                                                                    : static_cast<int64_t>(f);
    EXPECT_EQ(cellIndex(x), want) << x;
  }
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_EQ(cellIndex(inf), kMaxCellIndex);
  EXPECT_EQ(cellIndex(-inf), -kMaxCellIndex);
  EXPECT_EQ(cellIndex(std::numeric_limits<double>::quiet_NaN()), 0);
}

/// The grid's centroids of `cloud`, its points added in order.
std::vector<Eigen::Vector3f> gridCentroids(const Cloud& cloud, double voxel_m) {
  VoxelCentroidGrid g(voxel_m);
  for (const auto& p : cloud) g.add(p.getVector3fMap());
  return g.centroids();
}

/// Whether the sorter turns `cloud` into the grid's centroids, bit for bit and in order.
void expectSorterEqualsGrid(Cloud cloud, double voxel_m, VoxelCentroidSorter* sorter) {
  const std::vector<Eigen::Vector3f> want = gridCentroids(cloud, voxel_m);
  cloud.header.frame_id = "S";
  sorter->filter(&cloud);
  ASSERT_EQ(cloud.size(), want.size());
  EXPECT_EQ(cloud.width, want.size());
  EXPECT_EQ(cloud.height, want.empty() ? 0u : 1u);
  EXPECT_EQ(cloud.header.frame_id, "S");
  for (size_t i = 0; i < want.size(); ++i) {
    const Eigen::Vector3f got = cloud[i].getVector3fMap();
    ASSERT_EQ(std::memcmp(got.data(), want[i].data(), sizeof(float) * 3), 0)
        << i << ": " << got.transpose() << " vs " << want[i].transpose();
  }
}

TEST(VoxelCentroidSorter, EqualsTheGridBitForBit) {
  // Returns clustered on stems and ground (tens per voxel, summed in their order), points on
  // voxel edges and at -0, far points the grid ignores, NaN and infinity.
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-60.0f, 60.0f), jitter(-0.04f, 0.04f);
  Cloud cloud;
  for (int c = 0; c < 4000; ++c) {
    const float z = 0.05f * u(rng);
    const float y = u(rng);
    const float x = u(rng);
    for (int k = 0; k < 40; ++k) {
      const float dz = jitter(rng);
      const float dy = jitter(rng);
      cloud.push_back(pcl::PointXYZ(x + jitter(rng), y + dy, z + dz));
    }
  }
  for (int i = -40; i <= 40; ++i) cloud.push_back(pcl::PointXYZ(0.05f * i, -0.05f * i, 0.0f));
  cloud.push_back(pcl::PointXYZ(-0.0f, 0.0f, -0.0f));
  cloud.push_back(pcl::PointXYZ(6e4f, 1.0f, 1.0f));  // beyond 2^20 voxels of 0.05 m
  cloud.push_back(pcl::PointXYZ(1.0f, -6e4f, 1.0f));
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  cloud.push_back(pcl::PointXYZ(nan, 1.0f, 1.0f));  // the grid keeps NaN in voxel index 0
  cloud.push_back(pcl::PointXYZ(inf, 1.0f, 1.0f));
  cloud.push_back(pcl::PointXYZ(1.0f, 1.0f, -inf));
  std::shuffle(cloud.points.begin() + 1000, cloud.points.end(), rng);
  VoxelCentroidSorter sorter(0.05);
  expectSorterEqualsGrid(cloud, 0.05, &sorter);
  // The same sorter again (buffers reused), other sizes of voxel.
  expectSorterEqualsGrid(cloud, 0.05, &sorter);
  VoxelCentroidSorter coarse(0.3), fine(0.01);
  expectSorterEqualsGrid(cloud, 0.3, &coarse);
  expectSorterEqualsGrid(cloud, 0.01, &fine);
}

TEST(VoxelCentroidSorter, WideExtentsEmptyAndSingleVoxels) {
  VoxelCentroidSorter sorter(0.05);
  Cloud cloud;
  expectSorterEqualsGrid(cloud, 0.05, &sorter);  // empty
  cloud.push_back(pcl::PointXYZ(1.0f, 2.0f, 3.0f));
  expectSorterEqualsGrid(cloud, 0.05, &sorter);  // one point
  cloud.push_back(pcl::PointXYZ(1.01f, 2.01f, 3.01f));
  expectSorterEqualsGrid(cloud, 0.05, &sorter);  // one voxel of two
  // Keys of ~60 bits (every radix pass): +-50 km on every axis, the grid's range at 0.05 m.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> wide(-5.2e4f, 5.2e4f);
  for (int i = 0; i < 20000; ++i) {
    const float z = wide(rng);
    const float y = wide(rng);
    cloud.push_back(pcl::PointXYZ(wide(rng), y, z));
    cloud.push_back(cloud.back());  // pairs in one voxel, so sums are tested too
  }
  expectSorterEqualsGrid(cloud, 0.05, &sorter);
  Cloud far;
  far.push_back(pcl::PointXYZ(6e4f, 0.0f, 0.0f));
  expectSorterEqualsGrid(far, 0.05, &sorter);  // nothing in range
}

}  // namespace
}  // namespace dtif
