#include "dtif/core/pose/rigid2d.h"

#include <Eigen/Geometry>
#include <cmath>

namespace dtif {

double procrustesYaw(const std::vector<PointPair2d>& pairs, const std::vector<double>* weights,
                     Eigen::Vector2d* mean_a, Eigen::Vector2d* mean_b) {
  const auto weight = [&](size_t k) { return weights ? (*weights)[k] : 1.0; };
  Eigen::Vector2d ma = Eigen::Vector2d::Zero(), mb = Eigen::Vector2d::Zero();
  double ws = 0.0;
  for (size_t k = 0; k < pairs.size(); ++k) {
    ma += weight(k) * pairs[k].first;
    mb += weight(k) * pairs[k].second;
    ws += weight(k);
  }
  ma /= ws;
  mb /= ws;
  double sc = 0.0, ss = 0.0;
  for (size_t k = 0; k < pairs.size(); ++k) {
    const Eigen::Vector2d a = pairs[k].first - ma, b = pairs[k].second - mb;
    sc += weight(k) * a.dot(b);
    ss += weight(k) * (a.x() * b.y() - a.y() * b.x());
  }
  *mean_a = ma;
  *mean_b = mb;
  return std::atan2(ss, sc);
}

Pose rigid2d(const std::vector<PointPair2d>& pairs, double t_z) {
  Eigen::Vector2d ma, mb;
  const double yaw = procrustesYaw(pairs, nullptr, &ma, &mb);
  Pose T = Pose::Identity();
  T.linear() = rotZ(yaw);
  const Eigen::Vector2d t = mb - Eigen::Rotation2Dd(yaw).toRotationMatrix() * ma;
  T.translation() = Eigen::Vector3d(t.x(), t.y(), t_z);
  return T;
}

}  // namespace dtif
