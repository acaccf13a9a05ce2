// Levelling of submaps whose frame is not gravity-aligned (upstream FAST-LIO2: camera_init is the
// IMU's attitude at start-up, up to ~15 deg off level, constant for the run). Gravity is
// estimated per robot from the data: stems and other upright structure give bark patches whose
// normals are horizontal and thin stems whose axes are vertical; their robust consensus is the
// vertical. Ground is not used while there is upright structure, because a slope tilts it (a
// stand on a 20 deg slope tilts every ground patch the same way); leaning trees lean in all
// directions and average out. The estimate lives in the robot's odometry frame O (where it is
// constant) and is refined as submaps arrive; an IMU's mean accelerometer reading in O may be
// added. Each submap is then rotated by R_L_S (the smallest rotation taking its up to z, no yaw)
// before extraction.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "dtif/core/cloud.h"

namespace dtif {

struct LevellingParams {
  bool enable = true;  ///< false: submaps are taken as gravity-aligned (no levelling)
  /// A robot whose estimated tilt is below this is taken as level (R_L_S identity): a front end
  /// that levels its odometry frame is better than the stems tell (its residual is a few tenths
  /// of a degree, a submap's observation ~0.5 deg), and level data stays as it was [deg].
  double min_tilt_deg = 2.0;
  /// After this many observations of a robot (and an uncertainty below 1 deg)...
  int warmup_submaps = 6;
  /// ...only every this-many-th submap is observed (the tilt is constant for a run) [submaps].
  int observe_every = 4;
  double voxel_m = 0.6;           ///< cell of the local shape analysis [m]
  int min_voxel_points = 8;       ///< points a cell needs for its shape
  double band_deg = 25.0;         ///< upright structure: bark normals within this of horizontal,
                                  ///< thin stems within this of vertical, of the current up [deg]
  double slab_min_h_m = 0.5;      ///< upright structure is taken from this height above the
                                  ///< lowest cell of its 2 m column (ground below)... [m]
  double slab_max_h_m = 6.0;      ///< ...up to this (crowns and foliage above) [m]
  double tukey_deg = 8.0;         ///< robust weight of a cell's angle to the up [deg]
  int iterations = 4;             ///< re-selections of the upright cells per submap
  int min_support_cells = 6;      ///< fewer 2 m cells with upright structure: ground is used
  double ground_sigma_deg = 3.0;  ///< uncertainty floor of a ground-only estimate (slopes) [deg]
  double max_tilt_deg = 30.0;     ///< observations farther than this from S's z are rejected [deg]
  /// Consecutive submaps see the same stems: their estimates count as this many times fewer
  /// independent ones in the running estimate's uncertainty.
  double overlap_factor = 3.0;
  double imu_sigma_deg = 0.5;  ///< default uncertainty of an IMU gravity vector [deg]
  int max_points = 150000;     ///< evenly strided subsample of the submap for the shape analysis

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("enable", enable);
    v("min_tilt_deg", min_tilt_deg);
    v("warmup_submaps", warmup_submaps);
    v("observe_every", observe_every);
    v("voxel_m", voxel_m);
    v("min_voxel_points", min_voxel_points);
    v("band_deg", band_deg);
    v("slab_min_h_m", slab_min_h_m);
    v("slab_max_h_m", slab_max_h_m);
    v("tukey_deg", tukey_deg);
    v("iterations", iterations);
    v("min_support_cells", min_support_cells);
    v("ground_sigma_deg", ground_sigma_deg);
    v("max_tilt_deg", max_tilt_deg);
    v("overlap_factor", overlap_factor);
    v("imu_sigma_deg", imu_sigma_deg);
    v("max_points", max_points);
  }
};

/// One submap's gravity observation: the unit "up" in S and its uncertainty.
struct GravityObservation {
  bool ok = false;
  Eigen::Vector3d up_S = Eigen::Vector3d::UnitZ();
  double sigma_deg = 180.0;  ///< 1-sigma angular uncertainty [deg]
  int support_cells = 0;     ///< 2 m cells that contributed (about one per stem)
  bool from_ground = false;  ///< too little upright structure: ground normals (slope-biased)
};

/// Estimates up in S from a cloud, starting from `prior_S` (unit; S's z when nothing is known).
/// Deterministic, thread-safe.
GravityObservation observeGravity(const Cloud& cloud_S, const Eigen::Vector3d& prior_S,
                                  const LevellingParams& params);

/// The smallest rotation R_L_S taking `up_S` to +z (no yaw about it).
Eigen::Quaterniond levelRotation(const Eigen::Vector3d& up_S);

/// The running estimate of one robot.
struct GravityEstimate {
  bool valid = false;
  Eigen::Vector3d up_O = Eigen::Vector3d::UnitZ();  ///< unit up in the odometry frame O
  double sigma_deg = 180.0;                         ///< 1-sigma uncertainty [deg]
  double tilt_deg = 0.0;                            ///< angle between up_O and O's z [deg]
  int submaps = 0;                                  ///< submap observations used
  int seen = 0;                                     ///< submaps offered (observed or not)
  bool applied = false;  ///< tilt_deg >= min_tilt_deg: submaps are levelled
  int imu = 0;           ///< IMU observations used
};

/// Per-robot running gravity estimate in the odometry frame O. Not thread-safe.
class GravityEstimator {
 public:
  explicit GravityEstimator(const LevellingParams& params) : params_(params) {}

  /// Observes a submap (points in S, R_O_S its odometry attitude) and folds it in; returns the
  /// observation (in S; not ok when it failed or was skipped, see observe_every).
  GravityObservation addSubmap(const Cloud& cloud_S, const Eigen::Quaterniond& R_O_S);
  /// Folds in an IMU gravity direction: the mean accelerometer reading at rest expressed in O
  /// (it points up: specific force). sigma_deg <= 0: the params' imu_sigma_deg.
  void addImu(const Eigen::Vector3d& accel_O, double sigma_deg = 0.0);

  const GravityEstimate& estimate() const { return estimate_; }
  /// Up in S for a submap of attitude R_O_S (S's z without an estimate).
  Eigen::Vector3d upInSubmap(const Eigen::Quaterniond& R_O_S) const;
  /// R_L_S for a submap of attitude R_O_S (identity without an estimate or below min_tilt_deg).
  Eigen::Quaterniond levelRotationOf(const Eigen::Quaterniond& R_O_S) const;

 private:
  struct Obs {
    Eigen::Vector3d up_O;
    double sigma_rad;
    bool imu;
  };
  void update();

  LevellingParams params_;
  std::vector<Obs> obs_;
  GravityEstimate estimate_;
};

/// An IMU's accelerometer as a gravity observation in the odometry frame O (issue #15): each
/// sample's specific force a_B (body = IMU frame, as FAST-LIO2's body; any unit: only the
/// direction counts) is rotated into O with the body's attitude interpolated between the two
/// odometry poses around it, and the rotated directions are averaged over a window. Walking
/// accelerations average out (their mean over a window is the change of velocity over its length,
/// a few hundredths of g), turns do not matter once the attitude is interpolated; samples while
/// the body turns fast (attitude uncertain) or whose magnitude is far from the window's median
/// (impacts) are left out. Not thread-safe.
struct ImuGravityParams {
  double max_gyro_rad_s = 1.0;  ///< samples while turning faster are left out [rad/s]
  double max_norm_dev = 0.3;    ///< |‖a‖ / median‖a‖ - 1| beyond this: left out (impacts)
  int min_samples = 200;        ///< a window needs this many usable samples (MID-360: 200 Hz)
  std::string validate() const;
};

class ImuGravityWindow {
 public:
  explicit ImuGravityWindow(const ImuGravityParams& params = {}) : params_(params) {}

  /// An IMU sample (stamp [s], specific force in B, angular rate in B [rad/s]). Kept until the
  /// odometry has passed its stamp. False (nothing kept) when not finite or zero.
  bool addImu(double stamp, const Eigen::Vector3d& accel_B, const Eigen::Vector3d& gyro_B);
  /// An odometry attitude R_O_B at a stamp: the waiting samples up to it are rotated into O
  /// (slerp from the previous pose); earlier samples with no previous pose are dropped.
  void addOdometry(double stamp, const Eigen::Quaterniond& R_O_B);

  struct Reading {
    bool ok = false;
    Eigen::Vector3d up_O = Eigen::Vector3d::UnitZ();  ///< mean direction of the force (up) in O
    int samples = 0;                                  ///< used
    double spread_deg = 0.0;  ///< RMS angle of the used samples to the mean [deg]
  };
  /// The window's reading, and a new window. Not ok with fewer than min_samples usable.
  Reading take();

 private:
  struct Sample {
    double stamp;
    Eigen::Vector3d accel_B;
    double gyro;
  };
  ImuGravityParams params_;
  std::vector<Sample> waiting_;           // not yet passed by the odometry
  std::vector<Eigen::Vector3d> rotated_;  // force in O, this window
  std::vector<double> norms_;
  double prev_stamp_ = -1.0;
  Eigen::Quaterniond prev_R_O_B_ = Eigen::Quaterniond::Identity();
};

/// Levelling of several robots' submaps as an online system does it: a submap, when it
/// arrives, is observed first and then levelled with the estimate as it stands after that (so
/// the first submap of a robot is levelled by its own observation). One GravityEstimator per
/// robot name. Disabled params: every R_L_S is identity and nothing is estimated. Not
/// thread-safe.
class Leveller {
 public:
  explicit Leveller(const LevellingParams& params) : params_(params) {}

  struct Result {
    Eigen::Quaterniond R_L_S = Eigen::Quaterniond::Identity();
    GravityObservation observation;  ///< of this submap
    GravityEstimate estimate;        ///< the robot's, after this submap
  };
  Result level(const std::string& robot, const Cloud& cloud_S, const Eigen::Quaterniond& R_O_S);
  /// GravityEstimator::addImu for a robot (ignored when disabled).
  void addImu(const std::string& robot, const Eigen::Vector3d& accel_O, double sigma_deg = 0.0);
  /// The robot's estimate (invalid when none yet).
  GravityEstimate estimate(const std::string& robot) const;
  bool enabled() const { return params_.enable; }

 private:
  GravityEstimator& of(const std::string& robot);
  LevellingParams params_;
  std::vector<std::pair<std::string, GravityEstimator>> robots_;
};

}  // namespace dtif
