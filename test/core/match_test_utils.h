// Synthetic trunk maps for the matching tests: random stands, plantation grids and noisy
// submap observations with a known T_world_submap. Fixed seeds everywhere.
#pragma once

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/types.h"

namespace dtif::test {

/// Random stand in [0, w] x [0, h] with `stems_per_ha`, a minimum stem spacing of 1 m (trees
/// compete for light), radii 6-30 cm, and a gentle terrain slope for the base elevations.
inline Trunks randomStand(std::mt19937& rng, double w, double h, double stems_per_ha) {
  const int n = static_cast<int>(std::round(stems_per_ha * w * h / 10000.0));
  std::uniform_real_distribution<double> ux(0.0, w), uy(0.0, h);
  std::lognormal_distribution<double> ur(std::log(0.13), 0.35);
  Trunks out;
  int tries = 0;
  while (static_cast<int>(out.size()) < n && tries++ < 100 * n) {
    TrunkLandmark t;
    t.x = ux(rng);
    t.y = uy(rng);
    bool ok = true;
    for (const TrunkLandmark& o : out) {
      if (std::hypot(o.x - t.x, o.y - t.y) < 1.0) {
        ok = false;
        break;
      }
    }
    if (!ok) continue;
    t.r = std::clamp(ur(rng), 0.06, 0.30);
    t.z = 0.05 * t.x - 0.03 * t.y + 0.3 * std::sin(0.1 * t.x);
    out.push_back(t);
  }
  return out;
}

/// Plantation: a spacing x spacing grid, planting jitter (std, per axis), radii 15 +- 1 cm.
inline Trunks plantation(std::mt19937& rng, double w, double h, double spacing, double jitter) {
  std::normal_distribution<double> nj(0.0, jitter), nr(0.15, 0.01);
  Trunks out;
  for (double x = 0.0; x <= w; x += spacing) {
    for (double y = 0.0; y <= h; y += spacing) {
      TrunkLandmark t;
      t.x = x + nj(rng);
      t.y = y + nj(rng);
      t.r = nr(rng);
      t.z = 0.02 * t.x;
      out.push_back(t);
    }
  }
  return out;
}

struct ObservationNoise {
  double radius_m = 15.0;     ///< submap window: trunks within this of the centre
  double pos_sigma_m = 0.03;  ///< trunk centre noise per axis
  double rad_sigma_m = 0.01;  ///< radius noise
  double z_sigma_m = 0.03;    ///< base elevation noise
  double miss_ratio = 0.2;    ///< trunks not detected
  double false_ratio = 0.05;  ///< false trunks added (share of the detected ones)
};

/// Observes the world trunks within a window around `centre` (world frame) and expresses them
/// in the submap frame S, where T_world_S = T_w_s.
inline Trunks observe(std::mt19937& rng, const Trunks& world, const Eigen::Vector2d& centre,
                      const Pose& T_w_s, const ObservationNoise& nz = {}) {
  std::normal_distribution<double> np(0.0, nz.pos_sigma_m), nr(0.0, nz.rad_sigma_m),
      nzz(0.0, nz.z_sigma_m);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const Pose T_s_w = T_w_s.inverse();
  Trunks out;
  for (const TrunkLandmark& t : world) {
    if (std::hypot(t.x - centre.x(), t.y - centre.y()) > nz.radius_m) continue;
    if (u01(rng) < nz.miss_ratio) continue;
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const double dz = nzz(rng);
    const double dy = np(rng);
    const double dx = np(rng);
    const Eigen::Vector3d p = T_s_w * Eigen::Vector3d(t.x + dx, t.y + dy, t.z + dz);
    out.push_back({p.x(), p.y(), p.z(), std::max(0.03, t.r + nr(rng))});
  }
  const int n_false = static_cast<int>(std::round(nz.false_ratio * out.size()));
  std::uniform_real_distribution<double> ua(0.0, 2.0 * M_PI), ud(0.0, 1.0);
  std::uniform_real_distribution<double> ur(0.05, 0.3);
  for (int i = 0; i < n_false; ++i) {
    const double a = ua(rng), d = nz.radius_m * std::sqrt(ud(rng));
    const Eigen::Vector3d p =
        T_s_w * Eigen::Vector3d(centre.x() + d * std::cos(a), centre.y() + d * std::sin(a), 0.0);
    out.push_back({p.x(), p.y(), p.z(), ur(rng)});
  }
  // Trunk order carries no information: shuffle it.
  std::shuffle(out.begin(), out.end(), rng);
  return out;
}

inline Pose poseXyYaw(double x, double y, double z, double yaw) {
  Pose T = Pose::Identity();
  T.linear() = rotZ(yaw);
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

/// Descriptor of a trunk set with the default parameters and the given identity.
inline Descriptor describe(const Trunks& t, const std::string& robot, int64_t id,
                           double stamp = 0.0) {
  Descriptor d = buildDescriptor(t, DescriptorParams{});
  d.robot = robot;
  d.submap_id = id;
  d.stamp = stamp;
  return d;
}

/// A query and a candidate descriptor with the true T_c_q.
struct PairCase {
  Descriptor q, c;
  Pose T_c_q;
};

inline double yawError(const Pose& a, const Pose& b) {
  const Eigen::Matrix3d d = a.linear().transpose() * b.linear();
  return std::fabs(std::atan2(d(1, 0), d(0, 0)));
}

}  // namespace dtif::test
