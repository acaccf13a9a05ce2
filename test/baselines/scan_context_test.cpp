// Scan-context baseline: a synthetic submap turned by a known yaw is recognised with its yaw,
// another place is farther, degenerate clouds give invalid descriptors (fixed seeds).
#include "dtif/baselines/scan_context.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace dtif::baselines {
namespace {

/// A gravity-aligned submap around its origin: sloped, rough ground over a 60 m square, trunks
/// of 4-20 m with a crown blob at the top, low shrubs. Different seeds are different places.
Cloud syntheticSubmap(uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-28.0, 28.0), u01(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.03);
  auto ground = [](double x, double y) { return 0.08 * x - 0.04 * y + 0.3 * std::sin(0.2 * y); };
  Cloud c;
  for (double x = -30.0; x <= 30.0; x += 0.4) {
    for (double y = -30.0; y <= 30.0; y += 0.4) {
      c.push_back(pcl::PointXYZ(x, y, ground(x, y) + noise(rng)));
    }
  }
  for (int t = 0; t < 45; ++t) {
    const double cx = u(rng), cy = u(rng), h = 4.0 + 16.0 * u01(rng), r = 0.1 + 0.2 * u01(rng);
    for (double z = 0.0; z < h; z += 0.2) {
      for (int k = 0; k < 6; ++k) {
        const double a = 2.0 * M_PI * u01(rng);
        c.push_back(pcl::PointXYZ(cx + r * std::cos(a), cy + r * std::sin(a), ground(cx, cy) + z));
      }
    }
    for (int k = 0; k < 300; ++k) {
      const double dx = 2.5 * (u01(rng) - 0.5), dy = 2.5 * (u01(rng) - 0.5);
      c.push_back(pcl::PointXYZ(cx + dx, cy + dy, ground(cx, cy) + h + 1.5 * u01(rng)));
    }
  }
  for (int s = 0; s < 40; ++s) {
    const double cx = u(rng), cy = u(rng);
    for (int k = 0; k < 150; ++k) {
      const double x = cx + 1.5 * u01(rng), y = cy + 1.5 * u01(rng);
      c.push_back(pcl::PointXYZ(x, y, ground(x, y) + 1.2 * u01(rng)));
    }
  }
  return c;
}

Cloud turned(const Cloud& in, double yaw) {
  Cloud out;
  const Eigen::Matrix3d R = rotZ(yaw);
  for (const auto& p : in) {
    const Eigen::Vector3d v = R * Eigen::Vector3d(p.x, p.y, p.z);
    out.push_back(pcl::PointXYZ(v.x(), v.y(), v.z()));
  }
  return out;
}

double angleDiff(double a, double b) { return std::abs(std::remainder(a - b, 2.0 * M_PI)); }

TEST(ScanContext, RecognisesATurnedSubmapWithItsYaw) {
  const ScanContextParams params;
  const Cloud q = syntheticSubmap(3);
  const double sector = 2.0 * M_PI / params.sectors;
  for (double yaw : {0.0, 0.77, -2.3, 3.0}) {
    SCOPED_TRACE(yaw);
    const ScanContext a = makeScanContext(q, params), b = makeScanContext(turned(q, yaw), params);
    ASSERT_TRUE(a.valid) << a.invalid_reason;
    ASSERT_TRUE(b.valid) << b.invalid_reason;
    // b is c: a point of q at azimuth phi is at phi + yaw in c, so T_c_q has this yaw.
    const ScanContextMatch m = scanContextDistance(a, b);
    EXPECT_LE(angleDiff(m.yaw_rad, yaw), sector);
    EXPECT_LT(m.distance, params.max_distance);
  }
}

TEST(ScanContext, QuarterTurnShiftsTheColumnsAndKeepsTheRingKey) {
  // A quarter turn maps the ground tiles onto each other, so only the columns move.
  const ScanContextParams params;
  const Cloud q = syntheticSubmap(10);
  const ScanContext a = makeScanContext(q, params),
                    b = makeScanContext(turned(q, M_PI / 2), params);
  const ScanContext other = makeScanContext(syntheticSubmap(11), params);
  EXPECT_LT(ringKeyDistance(a, b), 0.01 * ringKeyDistance(a, other));
  const ScanContextMatch m = scanContextDistance(a, b);
  EXPECT_EQ(m.shift, params.sectors / 4);
  EXPECT_LT(m.distance, 0.01);
}

TEST(ScanContext, AnotherPlaceIsFartherAndTheQueryPicksTheSamePlace) {
  const ScanContextParams params;
  const ScanContext q = makeScanContext(syntheticSubmap(5), params);
  const ScanContext same = makeScanContext(turned(syntheticSubmap(5), 1.1), params);
  const ScanContext other1 = makeScanContext(syntheticSubmap(6), params);
  const ScanContext other2 = makeScanContext(turned(syntheticSubmap(7), 1.1), params);
  const double d_same = scanContextDistance(q, same).distance;
  EXPECT_GT(scanContextDistance(q, other1).distance, 2.0 * d_same);
  EXPECT_GT(scanContextDistance(q, other2).distance, 2.0 * d_same);
  const ScanContextAnswer a = queryScanContext(q, {&other1, &same, &other2}, params);
  EXPECT_EQ(a.index, 1);
  EXPECT_NEAR(a.match.distance, d_same, 1e-12);
  EXPECT_LE(angleDiff(a.match.yaw_rad, 1.1), 2.0 * M_PI / params.sectors);
}

TEST(ScanContext, EmptyNanAndSparseCloudsAreInvalidNotFatal) {
  const ScanContextParams params;
  Cloud nan_cloud;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  for (int k = 0; k < 100; ++k) nan_cloud.push_back(pcl::PointXYZ(nan, k, 1.0f));
  nan_cloud.push_back(pcl::PointXYZ(1.0f, inf, 1.0f));
  Cloud far_cloud;  // every point beyond max_range_m
  for (int k = 0; k < 100; ++k) far_cloud.push_back(pcl::PointXYZ(100.0f + k, 0.0f, 5.0f));
  const ScanContext good = makeScanContext(syntheticSubmap(8), params);
  ASSERT_TRUE(good.valid);
  for (const Cloud& c : {Cloud(), nan_cloud, far_cloud}) {
    const ScanContext sc = makeScanContext(c, params);
    EXPECT_FALSE(sc.valid);
    EXPECT_FALSE(sc.invalid_reason.empty());
    EXPECT_EQ(sc.bins.size(), static_cast<size_t>(params.rings * params.sectors));
    EXPECT_EQ(scanContextDistance(sc, good).distance, 1.0);
    EXPECT_EQ(scanContextDistance(good, sc).distance, 1.0);
    EXPECT_EQ(queryScanContext(sc, {&good}, params).index, -1);
    EXPECT_EQ(queryScanContext(good, {&sc}, params).index, -1);
  }
  EXPECT_EQ(queryScanContext(good, {}, params).index, -1);
  EXPECT_EQ(queryScanContext(good, {nullptr}, params).index, -1);
}

TEST(ScanContext, DeterministicAndSized) {
  const ScanContextParams params;
  const Cloud c = syntheticSubmap(9);
  const ScanContext a = makeScanContext(c, params), b = makeScanContext(c, params);
  EXPECT_EQ(a.bins, b.bins);
  EXPECT_EQ(a.ring_key, b.ring_key);
  EXPECT_EQ(a.bytes(), (20u * 60u + 20u) * sizeof(float));
  const ScanContextMatch m1 = scanContextDistance(a, b), m2 = scanContextDistance(a, b);
  EXPECT_EQ(m1.distance, m2.distance);
  EXPECT_EQ(m1.shift, 0);
  EXPECT_NEAR(m1.distance, 0.0, 1e-9);
}

TEST(ScanContext, ValidateNamesEveryBadField) {
  EXPECT_EQ(ScanContextParams().validate(), "");
  ScanContextParams p;
  p.rings = 0;
  p.sectors = 1;
  p.max_range_m = std::numeric_limits<double>::quiet_NaN();
  p.ground_tile_m = 0.0;
  p.ground_percentile = 1.5;
  p.max_height_m = -1.0;
  p.min_occupied_bins = -1;
  p.candidates = 0;
  p.max_distance = 0.0;
  const std::string problems = p.validate();
  for (const char* field : {"rings", "sectors", "max_range_m", "ground_tile_m", "ground_percentile",
                            "max_height_m", "min_occupied_bins", "candidates", "max_distance"}) {
    EXPECT_NE(problems.find(field), std::string::npos) << field;
  }
  EXPECT_THROW(makeScanContext(Cloud(), p), std::invalid_argument);
}

}  // namespace
}  // namespace dtif::baselines
