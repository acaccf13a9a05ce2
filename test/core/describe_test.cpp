// describeCloud: extract -> describe -> stamp in one call, on a fixed-seed synthetic plot.
#include "dtif/core/descriptor/describe.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace dtif {
namespace {

/// Flat noisy ground over [-10, 10]^2 and full stems of radius r at the given centres.
Cloud plot(const std::vector<Eigen::Vector3d>& stems, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 0.01);
  Cloud cloud;
  auto push = [&](double x, double y, double z) {
    cloud.push_back(
        pcl::PointXYZ(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)));
  };
  for (double x = -10.0; x <= 10.0; x += 0.1)
    for (double y = -10.0; y <= 10.0; y += 0.1) push(x, y, n(rng));
  for (const Eigen::Vector3d& s : stems) {  // (x, y, radius)
    for (double th = 0.0; th < 2.0 * M_PI; th += 0.04 / s.z())
      for (double h = 0.0; h < 6.0; h += 0.04) {
        const double r = s.z() + n(rng);
        push(s.x() + r * std::cos(th), s.y() + r * std::sin(th), h + n(rng));
      }
  }
  return cloud;
}

const std::vector<Eigen::Vector3d> kStems{{-6.0, -5.0, 0.12}, {-2.0, 4.0, 0.20}, {3.0, -3.0, 0.30},
                                          {6.0, 5.0, 0.16},   {-7.0, 6.0, 0.25}, {1.0, 0.5, 0.09}};

TEST(DescribeCloud, EqualsExtractThenDescribeThenStamp) {
  const Cloud cloud = plot(kStems, 1);
  const TrunkExtractorParams ep;
  const DescriptorParams dp;
  const SubmapKey key{"robot_b", 42, 123.25};
  DescribeTimings timings;
  TrunkExtractionResult ext;
  const Descriptor d = describeCloud(cloud, key, ep, dp, &timings, &ext);

  const TrunkExtractionResult ref_ext = extractTrunks(cloud, ep);
  Descriptor ref = describeSubmap(ref_ext, dp);
  ref.robot = "robot_b";
  ref.submap_id = 42;
  ref.stamp = 123.25;

  ASSERT_EQ(ext.trunks.size(), kStems.size());
  ASSERT_TRUE(d.valid) << d.invalid_reason;
  EXPECT_EQ(d.robot, "robot_b");
  EXPECT_EQ(d.submap_id, 42);
  EXPECT_EQ(d.stamp, 123.25);
  EXPECT_EQ(encodeDescriptor(d), encodeDescriptor(ref));  // identity, trunks, faces, histograms
  ASSERT_EQ(d.trunks.size(), ref.trunks.size());
  for (size_t i = 0; i < d.trunks.size(); ++i) {
    EXPECT_EQ(d.trunks[i].x, ref.trunks[i].x);
    EXPECT_EQ(d.trunks[i].y, ref.trunks[i].y);
    EXPECT_EQ(d.trunks[i].z, ref.trunks[i].z);
    EXPECT_EQ(d.trunks[i].r, ref.trunks[i].r);
  }
  // The extraction result handed back is the one described.
  ASSERT_EQ(ext.trunks.size(), ref_ext.trunks.size());
  for (size_t i = 0; i < ext.trunks.size(); ++i) EXPECT_EQ(ext.trunks[i].x, ref_ext.trunks[i].x);
  // total covers extraction and description from the same start.
  EXPECT_GE(timings.extract_ms, 0.0);
  EXPECT_GE(timings.total_ms, timings.extract_ms);
}

TEST(DescribeCloud, OptionalOutputsAndEmptyCloud) {
  const Cloud cloud = plot(kStems, 2);
  const Descriptor d =
      describeCloud(cloud, {"a", 7, 1.5}, TrunkExtractorParams{}, DescriptorParams{});
  EXPECT_TRUE(d.valid);
  EXPECT_EQ(d.submap_id, 7);
  // An empty cloud still gives a stamped (invalid) descriptor, never an exception.
  TrunkExtractionResult ext;
  ext.trunks.resize(3);  // overwritten
  const Descriptor e = describeCloud(Cloud{}, {"a", 8, 2.5}, TrunkExtractorParams{},
                                     DescriptorParams{}, nullptr, &ext);
  EXPECT_FALSE(e.valid);
  EXPECT_FALSE(e.invalid_reason.empty());
  EXPECT_EQ(e.robot, "a");
  EXPECT_EQ(e.submap_id, 8);
  EXPECT_EQ(e.stamp, 2.5);
  EXPECT_TRUE(ext.trunks.empty());
}

}  // namespace
}  // namespace dtif
