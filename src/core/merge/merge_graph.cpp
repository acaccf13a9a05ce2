#include "core/merge/merge_graph.h"

#include <algorithm>
#include <cmath>
#include <set>

namespace dtif {

Vector6d MergeGraph::odomSigmas(double d) const {
  Vector6d s;
  const double xy = p.odom_sigma_xy_m + p.odom_sigma_xy_per_m * d;
  const double z = p.odom_sigma_z_m + p.odom_sigma_z_per_m * d;
  const double tilt = p.odom_sigma_tilt_rad + p.odom_sigma_tilt_per_m * d;
  const double yaw = p.odom_sigma_rot_rad + p.odom_sigma_rot_per_m * d;
  s << xy, xy, z, tilt, tilt, yaw;
  return s;
}

Vector6d MergeGraph::loopSigmas(const Matrix6d& cov, bool open_stand) const {
  const double xy = open_stand ? p.loop_open_sigma_xy_min_m : p.loop_sigma_xy_min_m;
  const Vector6d floor = (Vector6d() << xy, xy, p.loop_sigma_z_min_m, p.loop_sigma_rot_min_rad,
                          p.loop_sigma_rot_min_rad, p.loop_sigma_rot_min_rad)
                             .finished();
  Vector6d s;
  for (int i = 0; i < 6; ++i) {
    const double v = cov(i, i);
    s(i) = std::max(floor(i), std::isfinite(v) && v > 0.0 ? std::sqrt(v) : 0.0);
  }
  return s;
}

std::vector<std::string> MergeGraph::robotOrder() const {
  std::vector<std::string> out;
  for (const auto& [name, r] : robots) {
    if (!r.nodes.empty()) out.push_back(name);
  }
  std::sort(out.begin(), out.end(), [&](const std::string& a, const std::string& b) {
    return robots.at(a).order < robots.at(b).order;
  });
  return out;
}

int MergeGraph::countComponents() const {
  std::set<int> c;
  for (const auto& [name, r] : robots) {
    if (!r.nodes.empty()) c.insert(r.component);
  }
  return static_cast<int>(c.size());
}

}  // namespace dtif
