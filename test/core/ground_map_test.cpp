#include "dtif/core/extraction/ground_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>

#include "core/ground_test_utils.h"
#include "core/match_test_utils.h"

namespace dtif {
namespace {

using test::hillyGround;
using test::mapOf;
using test::poseXyYaw;

TEST(GroundMap, KeepsTheLowestPointPerCellAndSkipsSparseCells) {
  const std::vector<float> x{0.1f, 0.2f, 0.3f, 1.2f, 1.3f, NAN, 5.0f};
  const std::vector<float> y{0.1f, 0.4f, 0.2f, 0.1f, 0.2f, 0.0f, 5.0f};
  const std::vector<float> z{3.0f, 2.5f, 7.0f, 1.0f, 1.1f, 0.0f, -4.0f};
  const Eigen::Vector2d lo(-1, -1), hi(2, 2);  // the point at (5, 5) is outside
  const GroundMap m =
      makeGroundMap(x.data(), y.data(), z.data(), x.size(), Eigen::Vector3d(10, 20, 100),
                    lo + Eigen::Vector2d(10, 20), hi + Eigen::Vector2d(10, 20), 1.0, 0.05, 2);
  ASSERT_TRUE(m.wellFormed());
  double v = 0.0;
  ASSERT_TRUE(m.at(10.5, 20.5, &v));
  EXPECT_NEAR(v, 102.5, 1e-9);
  ASSERT_TRUE(m.at(11.5, 20.5, &v));
  EXPECT_NEAR(v, 101.0, 0.025);
  EXPECT_FALSE(m.at(15.0, 25.0, &v));
  EXPECT_EQ(m.count(), 2u);
  // Four points needed: both cells stay empty, the map is empty of values.
  const GroundMap sparse =
      makeGroundMap(x.data(), y.data(), z.data(), x.size(), Eigen::Vector3d(10, 20, 100),
                    lo + Eigen::Vector2d(10, 20), hi + Eigen::Vector2d(10, 20), 1.0, 0.05, 4);
  EXPECT_EQ(sparse.count(), 0u);
  // No finite point inside: empty.
  EXPECT_TRUE(
      makeGroundMap(x.data(), y.data(), z.data(), 0, Eigen::Vector3d::Zero(), lo, hi, 1.0, 0.05, 1)
          .empty());
}

TEST(GroundMap, EncodeDecodeRoundTripIncludingLargeSteps) {
  std::mt19937 rng(5);
  Pose T_W_S = poseXyYaw(3.0, -4.0, 12.0, 0.4);
  GroundMap m = mapOf(hillyGround(rng, Eigen::Vector2d(20, 20), 15.0, true), T_W_S, 0.5, 0.05);
  ASSERT_GT(m.count(), 1000u);
  // A cliff of 20 m: more than a byte's worth of steps, so the escape code is used.
  m.z[m.z.size() / 2] = static_cast<int16_t>(m.z[m.z.size() / 2 - 1] + 400);
  m.z[m.z.size() / 2 + 1] = GroundMap::kUnknown;
  const std::vector<uint8_t> bytes = encodeGroundMap(m);
  EXPECT_LT(bytes.size(), m.z.size());  // compressed below one byte per cell
  const GroundMap d = decodeGroundMap(bytes.data(), bytes.size());
  EXPECT_EQ(d.z, m.z);
  EXPECT_EQ(d.x0, m.x0);
  EXPECT_EQ(d.y0, m.y0);
  EXPECT_EQ(d.width, m.width);
  EXPECT_EQ(d.height, m.height);
  EXPECT_NEAR(d.cell_m, m.cell_m, 1e-6);
  EXPECT_NEAR(d.z_step_m, m.z_step_m, 1e-6);
  EXPECT_EQ(d.z0_m, m.z0_m);
  // An empty map is no bytes, and no bytes an empty map.
  EXPECT_TRUE(encodeGroundMap(GroundMap()).empty());
  EXPECT_TRUE(decodeGroundMap(nullptr, 0).empty());
}

TEST(GroundMap, CroppedAboutItsCentreToFitAByteBudget) {
  std::mt19937 rng(7);
  const GroundMap m =
      mapOf(hillyGround(rng, Eigen::Vector2d(20, 20), 15.0, true), Pose::Identity(), 0.5, 0.05);
  const size_t full = encodeGroundMap(m).size();
  ASSERT_GT(full, 1000u);
  // No limit, or a budget it already fits: the same map.
  EXPECT_EQ(fitGroundMapBytes(m, 0).z, m.z);
  EXPECT_EQ(fitGroundMapBytes(m, full).z, m.z);
  // Slightly less: the heights are kept at twice the step, the cells all stay, and the
  // rounding is unbiased (errors of +- a quarter of the new step that cancel on average).
  const GroundMap coarse = fitGroundMapBytes(m, full - 1);
  ASSERT_FALSE(coarse.empty());
  EXPECT_LE(encodeGroundMap(coarse).size(), full - 1);
  EXPECT_EQ(coarse.width, m.width);
  EXPECT_EQ(coarse.count(), m.count());
  EXPECT_NEAR(coarse.z_step_m, 2.0 * m.z_step_m, 1e-12);
  double sum = 0.0;
  size_t n = 0;
  for (int32_t r = 0; r < m.height; ++r) {
    for (int32_t k = 0; k < m.width; ++k) {
      const double x = (m.x0 + k + 0.5) * m.cell_m, y = (m.y0 + r + 0.5) * m.cell_m;
      double zm = 0.0, zc = 0.0;
      if (!m.at(x, y, &zm)) continue;
      ASSERT_TRUE(coarse.at(x, y, &zc));
      EXPECT_NEAR(zc, zm, 0.25 * coarse.z_step_m + 1e-9);
      sum += zc - zm, ++n;
    }
  }
  EXPECT_LT(std::abs(sum / n), 0.1 * m.z_step_m);
  // A quarter of the bytes: a smaller map within the budget whose cells are the coarse map's,
  // and whose centre stays where m's was (within a cell).
  const GroundMap c = fitGroundMapBytes(m, full / 4);
  ASSERT_FALSE(c.empty());
  EXPECT_LE(encodeGroundMap(c).size(), full / 4);
  EXPECT_LT(c.width, m.width);
  EXPECT_LT(c.height, m.height);
  EXPECT_LE(std::abs((2 * c.x0 + c.width) - (2 * m.x0 + m.width)), 2);
  EXPECT_LE(std::abs((2 * c.y0 + c.height) - (2 * m.y0 + m.height)), 2);
  for (int32_t r = 0; r < c.height; r += 7) {
    for (int32_t k = 0; k < c.width; k += 5) {
      const size_t in_m = static_cast<size_t>(c.y0 - m.y0 + r) * m.width + (c.x0 - m.x0 + k);
      ASSERT_EQ(c.z[static_cast<size_t>(r) * c.width + k], coarse.z[in_m]) << r << " " << k;
    }
  }
  // A budget below the header: nothing fits.
  EXPECT_TRUE(fitGroundMapBytes(m, 10).empty());
}

TEST(GroundMap, MalformedBytesThrow) {
  std::mt19937 rng(6);
  const GroundMap m =
      mapOf(hillyGround(rng, Eigen::Vector2d(0, 0), 10.0, true), Pose::Identity(), 0.5, 0.05);
  const std::vector<uint8_t> bytes = encodeGroundMap(m);
  auto decode = [](std::vector<uint8_t> b) { return decodeGroundMap(b.data(), b.size()); };
  EXPECT_THROW(decode({1, 2, 3}), std::runtime_error);  // shorter than the header
  std::vector<uint8_t> cut(bytes.begin(), bytes.end() - 5);
  EXPECT_THROW(decode(cut), std::runtime_error);
  std::vector<uint8_t> flipped = bytes;
  flipped[flipped.size() - 10] ^= 0x5a;  // zlib's checksum catches it
  EXPECT_THROW(decode(flipped), std::runtime_error);
  std::vector<uint8_t> zero_cell = bytes;
  std::fill(zero_cell.begin(), zero_cell.begin() + 4, 0);  // cell size 0
  EXPECT_THROW(decode(zero_cell), std::runtime_error);
  std::vector<uint8_t> wider = bytes;
  wider[24] ^= 0x01;  // width no longer matches the stream
  EXPECT_THROW(decode(wider), std::runtime_error);
}

/// Two views of one hilly 20 deg slope: each sees the ground only on its own side (the other
/// side's lowest points are shrub tops and canopy), so no stem base pair would fix t_z. Under
/// the right horizontal pose the maps agree on t_z to centimetres; under a wrong one they do not.
TEST(GroundMap, ElevationOfTwoViewsAndNoneUnderAWrongPose) {
  std::mt19937 rng(11);
  const Pose T_W_q = poseXyYaw(18.0, 22.0, 3.0, 0.7), T_W_c = poseXyYaw(24.0, 20.0, -1.5, -2.2);
  const auto world_q = hillyGround(rng, Eigen::Vector2d(18, 22), 16.0, false);
  const auto world_c = hillyGround(rng, Eigen::Vector2d(24, 20), 16.0, false);
  const GroundMap q = mapOf(world_q, T_W_q, 0.5, 0.05), c = mapOf(world_c, T_W_c, 0.5, 0.05);
  const Pose T_c_q = T_W_c.inverse() * T_W_q;
  for (const double err : {-2.0, 0.0, 1.3}) {
    Pose T = T_c_q;
    T.translation().z() += err;
    const GroundElevation g = groundElevation(q, c, T, 0.15);
    ASSERT_TRUE(g.ok);
    EXPECT_NEAR(g.dz_m, -err, 0.05);
    EXPECT_GE(g.support, 300);
    EXPECT_LT(g.ambiguity, 0.6);
  }
  // 3 m off horizontally, or 20 deg off in yaw: no elevation the maps agree on.
  for (const Pose& wrong : {Pose(Eigen::Translation3d(3.0, 0.0, 0.0) * T_c_q),
                            Pose(Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitZ()) * T_c_q)}) {
    const GroundElevation g = groundElevation(q, c, wrong, 0.15);
    std::printf("[ info ] wrong pose: support %d of %d, ambiguity %.2f\n", g.support, g.compared,
                g.ambiguity);
    EXPECT_TRUE(g.support < 100 || g.ambiguity > 0.6);
  }
  // No map, no elevation.
  EXPECT_FALSE(groundElevation(q, GroundMap(), T_c_q, 0.15).ok);
}

}  // namespace
}  // namespace dtif
