// The IMU's gravity reading in the odometry frame (core/extraction/gravity.h, ImuGravityWindow):
// synthetic 200 Hz IMU and 10 Hz odometry of a body turning in a tilted odometry frame.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "dtif/core/extraction/gravity.h"

namespace dtif {
namespace {

constexpr double kDeg = M_PI / 180.0;

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) / kDeg;
}

struct Motion {
  double yaw_rate = 0.9;  ///< the body turns about O's z (a stale attitude: ~0.4 deg off) [rad/s]
  double bob_amplitude = 0.0;  ///< walking: vertical and forward acceleration [m/s^2]
  double noise = 0.05;         ///< accelerometer noise per axis [m/s^2]
  int impact_every = 0;        ///< a 4 g spike every this many samples (0: none)
};

// up_O: gravity's up in O (O tilted 10 deg). The body's attitude R_O_B turns about O's z and
// rocks 5 deg; the accelerometer reads the specific force R_B_O (a_O + g up_O).
class Scenario {
 public:
  explicit Scenario(const Motion& m) : m_(m) {}
  Eigen::Vector3d up_O = Eigen::AngleAxisd(10.0 * kDeg, Eigen::Vector3d(1, 2, 0).normalized()) *
                         Eigen::Vector3d::UnitZ();

  Eigen::Quaterniond attitude(double t) const {
    return Eigen::Quaterniond(
        Eigen::AngleAxisd(m_.yaw_rate * t, Eigen::Vector3d::UnitZ()) *
        Eigen::AngleAxisd(5.0 * kDeg * std::sin(1.3 * t), Eigen::Vector3d::UnitX()));
  }
  Eigen::Vector3d gyro(double t) const {
    return Eigen::Vector3d(5.0 * kDeg * 1.3 * std::cos(1.3 * t), 0.0, m_.yaw_rate);
  }
  Eigen::Vector3d accel(double t, int sample, std::mt19937* rng) const {
    std::normal_distribution<double> n(0.0, m_.noise);
    const Eigen::Vector3d a_O =
        m_.bob_amplitude * Eigen::Vector3d(std::sin(4 * M_PI * t), 0.0, std::cos(4 * M_PI * t));
    Eigen::Vector3d f_O = a_O + 9.81 * up_O;
    if (m_.impact_every > 0 && sample % m_.impact_every == 0) f_O *= 4.0;
    const double nx = n(*rng);
    const double ny = n(*rng);
    const double nz = n(*rng);
    return attitude(t).conjugate() * f_O + Eigen::Vector3d(nx, ny, nz);
  }

  /// `seconds` of IMU at 200 Hz and odometry at 10 Hz into w (odometry starts at 0).
  void feed(ImuGravityWindow* w, double seconds) const {
    std::mt19937 rng(7);
    int sample = 0;
    for (int k = 0; k <= static_cast<int>(seconds * 10); ++k) {
      const double t_odom = 0.1 * k;
      for (int i = 1; i <= 20 && k > 0; ++i) {
        const double t = t_odom - 0.1 + 0.005 * i;
        w->addImu(t, accel(t, sample++, &rng), gyro(t));
      }
      w->addOdometry(t_odom, attitude(t_odom));
    }
  }

 private:
  Motion m_;
};

TEST(ImuGravity, TurningBodyGivesGravityInTheOdometryFrame) {
  const Scenario sc(Motion{});
  ImuGravityWindow w;
  sc.feed(&w, 10.0);
  const ImuGravityWindow::Reading r = w.take();
  ASSERT_TRUE(r.ok);
  EXPECT_EQ(r.samples, 2000);
  // Noise 0.05 m/s^2 per sample is 0.3 deg; 2000 samples average it to ~0.01 deg.
  EXPECT_LT(angleDeg(r.up_O, sc.up_O), 0.05);
}

TEST(ImuGravity, WalkingAccelerationsAverageOut) {
  Motion m;
  m.bob_amplitude = 2.0;  // +-0.2 g, two steps per second
  const Scenario sc(m);
  ImuGravityWindow w;
  sc.feed(&w, 10.0);
  const ImuGravityWindow::Reading r = w.take();
  ASSERT_TRUE(r.ok);
  EXPECT_LT(angleDeg(r.up_O, sc.up_O), 0.1);
  EXPECT_GT(r.spread_deg, 5.0);  // single samples are far off: only the mean is gravity
}

TEST(ImuGravity, ImpactsAreLeftOut) {
  Motion m;
  m.impact_every = 100;
  const Scenario sc(m);
  ImuGravityWindow w;
  sc.feed(&w, 10.0);
  const ImuGravityWindow::Reading r = w.take();
  ASSERT_TRUE(r.ok);
  EXPECT_EQ(r.samples, 2000 - 20);  // every 100th of 2000
  EXPECT_LT(angleDeg(r.up_O, sc.up_O), 0.05);
}

// The attitude comes from odometry 10 times a second: without interpolation a body turning at
// 3 rad/s would tilt each sample's rotation by up to 17 deg; above max_gyro_rad_s they are out.
TEST(ImuGravity, FastTurnsAreLeftOutAndTooFewSamplesGiveNoReading) {
  Motion m;
  m.yaw_rate = 3.0;
  const Scenario sc(m);
  ImuGravityWindow w;
  sc.feed(&w, 10.0);
  const ImuGravityWindow::Reading r = w.take();
  EXPECT_FALSE(r.ok);
  EXPECT_EQ(r.samples, 0);
}

TEST(ImuGravity, SamplesBeforeTheFirstOdometryOrNotFiniteAreDropped) {
  ImuGravityWindow w(ImuGravityParams{1.0, 0.3, 1});
  EXPECT_FALSE(w.addImu(0.0, Eigen::Vector3d(NAN, 0, 9.8), Eigen::Vector3d::Zero()));
  EXPECT_FALSE(w.addImu(0.0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()));
  EXPECT_TRUE(w.addImu(0.5, Eigen::Vector3d(0, 0, 9.8), Eigen::Vector3d::Zero()));
  w.addOdometry(1.0, Eigen::Quaterniond::Identity());  // no pose before 0.5: dropped
  EXPECT_FALSE(w.take().ok);
  EXPECT_TRUE(w.addImu(1.05, Eigen::Vector3d(0, 0, 9.8), Eigen::Vector3d::Zero()));
  w.addOdometry(1.1, Eigen::Quaterniond::Identity());
  const ImuGravityWindow::Reading r = w.take();
  ASSERT_TRUE(r.ok);
  EXPECT_EQ(r.samples, 1);
  EXPECT_LT(angleDeg(r.up_O, Eigen::Vector3d::UnitZ()), 1e-9);
  EXPECT_FALSE(w.take().ok);  // a new, empty window
}

TEST(ImuGravity, ParamsValidate) {
  EXPECT_EQ(ImuGravityParams().validate(), "");
  const ImuGravityParams slow{0.0, 0.3, 200}, wide{1.0, 1.5, 200}, none{1.0, 0.3, 0};
  EXPECT_NE(slow.validate(), "");
  EXPECT_NE(wide.validate(), "");
  EXPECT_NE(none.validate(), "");
}

}  // namespace
}  // namespace dtif
