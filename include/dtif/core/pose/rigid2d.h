// Planar rigid motion from point pairs (2-D Procrustes), the least-squares solution of
// Eq. (3.11)'s yaw and horizontal translation once the pairs are fixed.
#pragma once

#include <Eigen/Core>
#include <utility>
#include <vector>

#include "dtif/core/types.h"

namespace dtif {

using PointPair2d = std::pair<Eigen::Vector2d, Eigen::Vector2d>;

/// Weighted 2-D Procrustes: the yaw of the rotation taking the first point of each pair onto
/// the second about their weighted centroids (returned in mean_a, mean_b). `weights` null: all
/// pairs weigh 1. Needs a positive total weight.
double procrustesYaw(const std::vector<PointPair2d>& pairs, const std::vector<double>* weights,
                     Eigen::Vector2d* mean_a, Eigen::Vector2d* mean_b);

/// Least-squares planar rigid motion taking the first point of each pair onto the second, as a
/// pose with elevation t_z. Needs at least 2 pairs.
Pose rigid2d(const std::vector<PointPair2d>& pairs, double t_z);

}  // namespace dtif
