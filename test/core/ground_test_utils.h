// Synthetic lowest surfaces for ground-map tests: a hilly 20 deg slope with shrubs, seen from a
// view that may miss the ground downhill (as a helmet's -7 deg lower field-of-view limit does).
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include "dtif/core/extraction/ground_map.h"

namespace dtif {
namespace test {

/// Terrain elevation of the test world: 20 deg uphill towards +y, hills and 5 cm bumps.
inline double terrainZ(double x, double y) {
  return std::tan(20.0 * M_PI / 180.0) * y + 0.8 * std::sin(0.25 * x + 0.3) * std::cos(0.2 * y) +
         0.05 * std::sin(2.1 * x) * std::sin(1.7 * y);
}

/// Lowest surface points (world frame) within `radius` of `centre`, on a jittered 0.15 m grid.
/// Shrubs (fixed in the world) cover the ground in every view. With `full_view` false the view
/// sees the ground only uphill of y = centre.y - hidden_m; below it the lowest returns are
/// canopy 8-11 m up.
inline std::vector<Eigen::Vector3d> hillyGround(std::mt19937& rng, const Eigen::Vector2d& centre,
                                                double radius, bool full_view,
                                                double hidden_m = 2.0) {
  std::mt19937 shrub_rng(2024);  // the same shrubs in every view
  std::uniform_real_distribution<double> where(-10.0, 60.0);
  std::vector<Eigen::Vector2d> shrubs;
  for (int i = 0; i < 200; ++i) {
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const double y = where(shrub_rng);
    shrubs.emplace_back(where(shrub_rng), y);
  }
  std::uniform_real_distribution<double> jitter(-0.07, 0.07);
  std::normal_distribution<double> noise(0.0, 0.01);
  std::vector<Eigen::Vector3d> out;
  for (double x = centre.x() - radius; x <= centre.x() + radius; x += 0.15) {
    for (double y = centre.y() - radius; y <= centre.y() + radius; y += 0.15) {
      const double jy = jitter(rng);  // drawn before x, as gcc did: the same data for any compiler
      const Eigen::Vector2d p(x + jitter(rng), y + jy);
      if ((p - centre).norm() > radius) continue;
      double z = terrainZ(p.x(), p.y());
      bool shrub = false;
      for (const auto& s : shrubs) shrub = shrub || (p - s).norm() < 0.8;
      if (shrub)
        z += 1.2;
      else if (!full_view && p.y() < centre.y() - hidden_m)
        z += 9.5 + 1.5 * std::sin(0.7 * p.x()) * std::cos(0.9 * p.y());
      out.emplace_back(p.x(), p.y(), z + noise(rng));
    }
  }
  return out;
}

/// Ground map of world points seen from the submap frame S (T_W_S), cells of >= 3 points.
inline GroundMap mapOf(const std::vector<Eigen::Vector3d>& world, const Pose& T_W_S, double cell_m,
                       double z_step_m) {
  const Pose T_S_W = T_W_S.inverse();
  std::vector<float> x, y, z;
  for (const auto& p : world) {
    const Eigen::Vector3d s = T_S_W * p;
    x.push_back(static_cast<float>(s.x()));
    y.push_back(static_cast<float>(s.y()));
    z.push_back(static_cast<float>(s.z()));
  }
  return makeGroundMap(x.data(), y.data(), z.data(), x.size(), Eigen::Vector3d::Zero(),
                       Eigen::Vector2d(-1e4, -1e4), Eigen::Vector2d(1e4, 1e4), cell_m, z_step_m, 3);
}

}  // namespace test
}  // namespace dtif
