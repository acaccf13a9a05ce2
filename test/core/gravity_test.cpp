// Levelling (extraction/gravity.h): gravity from upright structure on synthetic stands with a
// slope and leaning stems, the per-robot running estimate in the odometry frame, the IMU input,
// and the round trip of levelled loops back to the tilted submap frames.
#include "dtif/core/extraction/gravity.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"

namespace dtif {
namespace {

constexpr double kDeg = M_PI / 180.0;

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) / kDeg;
}

// camera_init-like tilt: z leans by tilt_deg towards azimuth_deg.
Eigen::Matrix3d tilt(double tilt_deg, double azimuth_deg) {
  const double a = azimuth_deg * kDeg;
  return Eigen::AngleAxisd(tilt_deg * kDeg, Eigen::Vector3d(-std::sin(a), std::cos(a), 0.0))
      .toRotationMatrix();
}

struct StandSpec {
  double slope_deg = 0.0;  // ground rises along +x
  double lean_deg = 0.0;   // stems lean up to this, in random directions
  int stems = 100;
  int shrubs = 10;
  int ground_points = 20000;
  double ground_half_m = 20.0;  // ground covers [-half, half]^2
};

// A stand in a gravity frame G (z up): noisy sloped ground, leaning stems 0-8 m, shrub blobs.
// *mean_axis (optional): the stems' mean axis, the vertical as the stems have it.
Cloud stand(const StandSpec& spec, uint32_t seed, Eigen::Vector3d* mean_axis = nullptr) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> n(0.0, 1.0);
  if (mean_axis) mean_axis->setZero();
  const double slope = std::tan(spec.slope_deg * kDeg);
  auto ground = [&](double x) { return slope * x; };
  Cloud c;
  auto add = [&](const Eigen::Vector3d& p) {
    c.push_back(pcl::PointXYZ(static_cast<float>(p.x()), static_cast<float>(p.y()),
                              static_cast<float>(p.z())));
  };
  const double g = spec.ground_half_m;
  for (int i = 0; i < spec.ground_points; ++i) {
    const double x = -g + 2 * g * u(rng), y = -g + 2 * g * u(rng);
    add({x, y, ground(x) + 0.03 * n(rng)});
  }
  for (int s = 0; s < spec.stems; ++s) {
    const double x = -18 + 36 * u(rng), y = -18 + 36 * u(rng), r = 0.08 + 0.17 * u(rng);
    const double lean = spec.lean_deg * u(rng) * kDeg, dir = 2 * M_PI * u(rng);
    const Eigen::Vector3d axis(std::sin(lean) * std::cos(dir), std::sin(lean) * std::sin(dir),
                               std::cos(lean));
    if (mean_axis) *mean_axis += axis / spec.stems;
    const Eigen::Vector3d e1 = axis.unitOrthogonal(), e2 = axis.cross(e1);
    const Eigen::Vector3d base(x, y, ground(x));
    // The side facing the origin (a sensor sees half the bark).
    const double facing = std::atan2(-y, -x);
    for (int k = 0; k < 800; ++k) {
      const double h = 8.0 * u(rng), phi = facing + (u(rng) - 0.5) * M_PI;
      const Eigen::Vector3d radial = std::cos(phi) * e1 + std::sin(phi) * e2;
      add(base + h * axis + (r + 0.01 * n(rng)) * radial);
    }
  }
  for (int b = 0; b < spec.shrubs; ++b) {
    const double x = -18 + 36 * u(rng), y = -18 + 36 * u(rng);
    for (int k = 0; k < 400; ++k) {
      add({x + 0.6 * n(rng), y + 0.6 * n(rng), ground(x) + 0.8 + 0.4 * n(rng)});
    }
  }
  return c;
}

Cloud rotated(const Cloud& c, const Eigen::Matrix3d& R) {
  Cloud out;
  for (const auto& p : c) {
    const Eigen::Vector3f q = R.cast<float>() * p.getVector3fMap();
    out.push_back(pcl::PointXYZ(q.x(), q.y(), q.z()));
  }
  return out;
}

LevellingParams enabled() {
  LevellingParams p;
  p.enable = true;
  return p;
}

// A 12 deg tilt on a 20 deg slope with 100 stems leaning up to 5 deg: the stems give the
// vertical (the ground alone would be 20 deg off). The mean lean of 100 such stems is ~0.3 deg
// (3 sigma ~0.9), which no estimate from stems can remove: the estimate is held to the stems'
// mean axis tightly, to gravity within that.
TEST(Gravity, RecoversTiltOnASlopeWithLeaningStems) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(seed);
    const Eigen::Matrix3d R_G_S = tilt(12.0, 70.0 + 100.0 * seed);
    Eigen::Vector3d axis_G;
    const Cloud cloud_S = rotated(stand({20.0, 5.0}, seed, &axis_G), R_G_S.transpose());
    const Eigen::Vector3d true_up_S = R_G_S.transpose() * Eigen::Vector3d::UnitZ();
    const GravityObservation o = observeGravity(cloud_S, Eigen::Vector3d::UnitZ(), enabled());
    ASSERT_TRUE(o.ok);
    EXPECT_FALSE(o.from_ground);
    // Within 0.3 deg of the stems' mean axis (the estimate weighs a stem by its bark cells, the
    // mean counts each stem once), and that one within a few tenths of gravity.
    EXPECT_LT(angleDeg(o.up_S, R_G_S.transpose() * axis_G.normalized()), 0.3);
    EXPECT_LT(angleDeg(o.up_S, true_up_S), 1.0);
    EXPECT_GT(o.sigma_deg, 0.0);
    EXPECT_LT(o.sigma_deg, 1.0);
    EXPECT_GE(o.support_cells, 20);
  }
}

TEST(Gravity, LevelSubmapStaysLevel) {
  Eigen::Vector3d axis;
  const GravityObservation o =
      observeGravity(stand({8.0, 4.0}, 7, &axis), Eigen::Vector3d::UnitZ(), enabled());
  ASSERT_TRUE(o.ok);
  EXPECT_LT(angleDeg(o.up_S, axis.normalized()), 0.3);
  EXPECT_LT(angleDeg(o.up_S, Eigen::Vector3d::UnitZ()), 1.0);
}

// No upright structure: the ground normals, flagged and with the slope-sized uncertainty.
TEST(Gravity, GroundFallbackWithoutStems) {
  StandSpec open;
  open.stems = 0;
  open.shrubs = 0;
  open.ground_points = 80000;  // ~200 points per m^2, as near a helmet
  open.ground_half_m = 10.0;
  const Eigen::Matrix3d R_G_S = tilt(8.0, 10.0);
  const Cloud cloud_S = rotated(stand(open, 3), R_G_S.transpose());
  const GravityObservation o = observeGravity(cloud_S, Eigen::Vector3d::UnitZ(), enabled());
  ASSERT_TRUE(o.ok);
  EXPECT_TRUE(o.from_ground);
  EXPECT_DOUBLE_EQ(o.sigma_deg, enabled().ground_sigma_deg);
  EXPECT_LT(angleDeg(o.up_S, R_G_S.transpose() * Eigen::Vector3d::UnitZ()), 0.5);
  EXPECT_FALSE(observeGravity(Cloud(), Eigen::Vector3d::UnitZ(), enabled()).ok);
}

TEST(Gravity, LevelRotationTakesUpToZWithoutYaw) {
  const Eigen::Vector3d up = (tilt(14.0, 200.0).transpose() * Eigen::Vector3d::UnitZ());
  const Eigen::Quaterniond R = levelRotation(up);
  EXPECT_LT(angleDeg(R * up, Eigen::Vector3d::UnitZ()), 1e-9);
  // The smallest rotation: its axis is horizontal (no turn about z).
  EXPECT_NEAR(Eigen::AngleAxisd(R).axis().z(), 0.0, 1e-9);
  EXPECT_NEAR(Eigen::AngleAxisd(R).angle() / kDeg, 14.0, 1e-9);
}

// One robot: a tilted O, submaps at several yaws in O. The estimate lives in O, its levelling
// of each submap is within a few tenths of a degree, and the IMU adds to it.
TEST(GravityEstimator, RunningEstimateInTheOdometryFrame) {
  const Eigen::Matrix3d R_G_O = tilt(9.0, 130.0);  // O's attitude from gravity
  const Eigen::Vector3d true_up_O = R_G_O.transpose() * Eigen::Vector3d::UnitZ();
  LevellingParams every = enabled();
  every.warmup_submaps = 100;  // observe every submap
  GravityEstimator est(every);
  EXPECT_FALSE(est.estimate().valid);
  EXPECT_TRUE(est.levelRotationOf(Eigen::Quaterniond::Identity()).coeffs() ==
              Eigen::Quaterniond::Identity().coeffs());
  for (int k = 0; k < 6; ++k) {
    const Eigen::Quaterniond R_O_S(Eigen::AngleAxisd(0.9 * k, Eigen::Vector3d::UnitZ()));
    const Eigen::Matrix3d R_G_S = R_G_O * R_O_S.toRotationMatrix();
    const Cloud cloud_S = rotated(stand({15.0, 4.0}, 10 + k), R_G_S.transpose());
    EXPECT_TRUE(est.addSubmap(cloud_S, R_O_S).ok);
    const GravityEstimate& e = est.estimate();
    ASSERT_TRUE(e.valid);
    EXPECT_EQ(e.submaps, k + 1);
    // One stand's mean lean is a few tenths; six stands average it down.
    EXPECT_LT(angleDeg(e.up_O, true_up_O), k == 0 ? 1.0 : 0.5);
    // Levelling this submap: its gravity goes to z.
    const Eigen::Vector3d up_S = R_G_S.transpose() * Eigen::Vector3d::UnitZ();
    EXPECT_LT(angleDeg(est.levelRotationOf(R_O_S) * up_S, Eigen::Vector3d::UnitZ()),
              k == 0 ? 1.0 : 0.5);
  }
  EXPECT_LT(angleDeg(est.estimate().up_O, true_up_O), 0.3);
  EXPECT_NEAR(est.estimate().tilt_deg, 9.0, 0.3);
  EXPECT_GT(est.estimate().sigma_deg, 0.0);
  EXPECT_LT(est.estimate().sigma_deg, 0.5);
}

TEST(GravityEstimator, ImuAloneAndBadImuIgnored) {
  GravityEstimator est(enabled());
  est.addImu(Eigen::Vector3d(0, 0, 0));
  est.addImu(Eigen::Vector3d(NAN, 0, 9.8));
  EXPECT_FALSE(est.estimate().valid);
  const Eigen::Vector3d accel = 9.81 * (tilt(6.0, 45.0).transpose() * Eigen::Vector3d::UnitZ());
  est.addImu(accel, 0.2);
  ASSERT_TRUE(est.estimate().valid);
  EXPECT_EQ(est.estimate().imu, 1);
  EXPECT_LT(angleDeg(est.estimate().up_O, accel.normalized()), 1e-9);
  EXPECT_NEAR(est.estimate().sigma_deg, 0.2, 1e-9);
  EXPECT_NEAR(est.estimate().tilt_deg, 6.0, 1e-9);
}

TEST(Leveller, PerRobotAndDisabledIsIdentity) {
  const Cloud tilted = rotated(stand({10.0, 4.0}, 21), tilt(10.0, 0.0).transpose());
  LevellingParams disabled;
  disabled.enable = false;
  Leveller off(disabled);
  const Leveller::Result r0 = off.level("a", tilted, Eigen::Quaterniond::Identity());
  EXPECT_TRUE(r0.R_L_S.coeffs() == Eigen::Quaterniond::Identity().coeffs());
  EXPECT_FALSE(off.estimate("a").valid);

  Leveller on(enabled());
  const Leveller::Result r1 = on.level("a", tilted, Eigen::Quaterniond::Identity());
  EXPECT_TRUE(r1.observation.ok);
  EXPECT_NEAR(Eigen::AngleAxisd(r1.R_L_S).angle() / kDeg, 10.0, 0.5);
  EXPECT_TRUE(on.estimate("a").valid);
  EXPECT_FALSE(on.estimate("b").valid);  // robots do not share estimates
}

// A loop estimated between levelled frames goes back to the tilted submap frames exactly.
TEST(Levelling, LoopRoundTripThroughLevelledFrames) {
  Descriptor q, c;
  q.level_rotation = Eigen::Quaterniond(tilt(11.0, 30.0));
  c.level_rotation = Eigen::Quaterniond(tilt(7.0, 250.0));
  Pose T_Sc_Sq = Pose::Identity();
  T_Sc_Sq.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.1, -0.2, 1).normalized()).matrix();
  T_Sc_Sq.translation() = Eigen::Vector3d(3.0, -4.0, 0.5);
  Pose R_Lq_Sq = Pose::Identity(), R_Lc_Sc = Pose::Identity();
  R_Lq_Sq.linear() = q.level_rotation.toRotationMatrix();
  R_Lc_Sc.linear() = c.level_rotation.toRotationMatrix();
  const Pose T_Lc_Lq = R_Lc_Sc * T_Sc_Sq * R_Lq_Sq.inverse();
  const Pose back = submapFramePose(q, c, T_Lc_Lq);
  EXPECT_LT((back.matrix() - T_Sc_Sq.matrix()).norm(), 1e-12);
  // Not levelled: unchanged.
  const Descriptor plain;
  EXPECT_TRUE(submapFramePose(plain, plain, T_Lc_Lq).isApprox(T_Lc_Lq, 1e-15));
}

// The wire encoding carries the rotation only when there is one: a level descriptor's bytes
// are those of before.
TEST(Levelling, DescriptorEncodingCarriesTheRotation) {
  Trunks trunks;
  for (int i = 0; i < 8; ++i) {
    trunks.push_back({3.0 * std::cos(i * 0.8) + 0.3 * i, 4.0 * std::sin(i * 1.3), 0.1 * i, 0.15});
  }
  Descriptor d = buildDescriptor(trunks, DescriptorParams());
  ASSERT_TRUE(d.valid);
  const std::vector<uint8_t> plain = encodeDescriptor(d);
  EXPECT_FALSE(decodeDescriptor(plain, DescriptorParams()).levelled());
  d.level_rotation = Eigen::Quaterniond(tilt(12.0, 100.0));
  const std::vector<uint8_t> levelled = encodeDescriptor(d);
  EXPECT_EQ(levelled.size(), plain.size() + 16);
  const Descriptor back = decodeDescriptor(levelled, DescriptorParams());
  EXPECT_TRUE(back.levelled());
  EXPECT_LT(back.level_rotation.angularDistance(d.level_rotation), 1e-6);
}

}  // namespace
}  // namespace dtif
