// FPFH registration baseline: recovers a known transform between two views of a synthetic
// stand (fixed seed).
#include "dtif/baselines/fpfh_registration.h"

#include <gtest/gtest.h>

#include <random>

#include "core/match_test_utils.h"

namespace dtif::baselines {
namespace {

/// Undulating ground, trunks of various radii and leaning boxes of shrub in 30 m x 30 m.
Cloud syntheticStand(uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 30.0), ur(0.08, 0.35), ua(0.0, 2.0 * M_PI),
      uh(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.01);
  Cloud c;
  auto ground = [](double x, double y) {
    return 0.4 * std::sin(0.3 * x) + 0.25 * std::cos(0.5 * y);
  };
  for (double x = 0; x < 30; x += 0.2) {
    for (double y = 0; y < 30; y += 0.2)
      c.push_back(pcl::PointXYZ(x, y, ground(x, y) + noise(rng)));
  }
  for (int t = 0; t < 40; ++t) {
    const double cx = u(rng), cy = u(rng), r = ur(rng), h = 4.0 + 8.0 * uh(rng);
    for (double z = 0; z < h; z += 0.1) {
      for (int k = 0; k < 24; ++k) {
        const double a = ua(rng);
        c.push_back(pcl::PointXYZ(cx + r * std::cos(a), cy + r * std::sin(a), ground(cx, cy) + z));
      }
    }
  }
  for (int b = 0; b < 25; ++b) {
    const double cx = u(rng), cy = u(rng), sx = 0.5 + 2 * uh(rng), sy = 0.5 + 2 * uh(rng),
                 sz = 0.3 + 1.2 * uh(rng);
    for (int k = 0; k < 800; ++k) {
      const double x = cx + sx * uh(rng), y = cy + sy * uh(rng);
      c.push_back(pcl::PointXYZ(x, y, ground(x, y) + sz * uh(rng) * uh(rng)));
    }
  }
  return c;
}

TEST(FpfhRegistration, RecoversAKnownTransformOfTheSameStand) {
  const Cloud q = syntheticStand(21);
  const Pose T_c_q = test::poseXyYaw(3.0, -2.0, 0.2, 0.7);
  Cloud c;
  for (const auto& p : q) {
    const Eigen::Vector3d v = T_c_q * Eigen::Vector3d(p.x, p.y, p.z);
    c.push_back(pcl::PointXYZ(v.x(), v.y(), v.z()));
  }
  FpfhParams params;
  params.voxel_m = 0.3;
  const auto fq = computeFpfh(q, params), fc = computeFpfh(c, params);
  EXPECT_GT(fpfhPoints(*fq), 1000u);
  const FpfhRegistration r = registerFpfh(*fq, *fc, params);
  EXPECT_GT(r.correspondences, 50);
  ASSERT_TRUE(r.accepted);
  EXPECT_LT(test::yawError(r.T_c_q, T_c_q) * 180.0 / M_PI, 1.0);
  EXPECT_LT((r.T_c_q.translation() - T_c_q.translation()).norm(), 0.3);
}

TEST(FpfhRegistration, UnknownSolverThrows) {
  FpfhParams params;
  params.solver = "teaser";
  EXPECT_THROW(solveFpfh({}, params), std::invalid_argument);
}

}  // namespace
}  // namespace dtif::baselines
