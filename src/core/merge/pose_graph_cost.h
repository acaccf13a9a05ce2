// The relative-pose residual of the pose graph (as Ceres's pose_graph_3d example): the error
// of T_a_b_measured^-1 * T_a^-1 * T_b as (translation, 2 x quaternion vector), whitened.
#pragma once

#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace dtif {

class RelativePoseCost {
 public:
  RelativePoseCost(const Eigen::Vector3d& t_ab, const Eigen::Quaterniond& q_ab,
                   const Eigen::Matrix<double, 6, 6>& sqrt_information)
      : t_ab_(t_ab), q_ab_(q_ab), sqrt_information_(sqrt_information) {}

  template <typename T>
  bool operator()(const T* const q_a_ptr, const T* const t_a_ptr, const T* const q_b_ptr,
                  const T* const t_b_ptr, T* residuals_ptr) const {
    Eigen::Map<const Eigen::Quaternion<T>> q_a(q_a_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_a(t_a_ptr);
    Eigen::Map<const Eigen::Quaternion<T>> q_b(q_b_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_b(t_b_ptr);
    const Eigen::Quaternion<T> q_a_inv = q_a.conjugate();
    const Eigen::Quaternion<T> q_ab_est = q_a_inv * q_b;
    const Eigen::Matrix<T, 3, 1> t_ab_est = q_a_inv * (t_b - t_a);
    const Eigen::Quaternion<T> dq = q_ab_.template cast<T>() * q_ab_est.conjugate();
    Eigen::Map<Eigen::Matrix<T, 6, 1>> residuals(residuals_ptr);
    residuals.template block<3, 1>(0, 0) = t_ab_est - t_ab_.template cast<T>();
    residuals.template block<3, 1>(3, 0) = T(2.0) * dq.vec();
    residuals.applyOnTheLeft(sqrt_information_.template cast<T>());
    return true;
  }

  static ceres::CostFunction* create(const Eigen::Vector3d& t_ab, const Eigen::Quaterniond& q_ab,
                                     const Eigen::Matrix<double, 6, 6>& sqrt_information) {
    return new ceres::AutoDiffCostFunction<RelativePoseCost, 6, 4, 3, 4, 3>(
        new RelativePoseCost(t_ab, q_ab, sqrt_information));
  }

  EIGEN_MAKE_ALIGNED_OPERATOR_NEW

 private:
  Eigen::Vector3d t_ab_;
  Eigen::Quaterniond q_ab_;
  Eigen::Matrix<double, 6, 6> sqrt_information_;
};

/// A submap's observation of a landmark: the observed point p_S moved into M by the submap's
/// pose, minus the landmark's position, divided by the standard deviations (x, y, z).
class LandmarkCost {
 public:
  LandmarkCost(const Eigen::Vector3d& p_S, const Eigen::Vector3d& sigmas)
      : p_S_(p_S), inv_sigmas_(sigmas.cwiseInverse()) {}

  template <typename T>
  bool operator()(const T* const q_ptr, const T* const t_ptr, const T* const l_ptr,
                  T* residuals_ptr) const {
    Eigen::Map<const Eigen::Quaternion<T>> q(q_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(t_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> l(l_ptr);
    Eigen::Map<Eigen::Matrix<T, 3, 1>> residuals(residuals_ptr);
    residuals = (q * p_S_.template cast<T>() + t - l).cwiseProduct(inv_sigmas_.template cast<T>());
    return true;
  }

  static ceres::CostFunction* create(const Eigen::Vector3d& p_S, const Eigen::Vector3d& sigmas) {
    return new ceres::AutoDiffCostFunction<LandmarkCost, 3, 4, 3, 3>(new LandmarkCost(p_S, sigmas));
  }

  EIGEN_MAKE_ALIGNED_OPERATOR_NEW

 private:
  Eigen::Vector3d p_S_;
  Eigen::Vector3d inv_sigmas_;
};

}  // namespace dtif
