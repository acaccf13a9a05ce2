// Baseline pose solvers on dtif's weighted correspondences, for the back-end comparison of
// issue #5 (paper Tables 3-4): a 6-DoF SVD-RANSAC, a Quatro-like decoupled estimator and Fast
// Global Registration. Written from the papers' descriptions; ROS-free; not part of dtif_core.
//
// Every solver returns a PoseEstimate that LoopDetector::setSolver accepts: T_c_q, ok,
// inliers_T (horizontal residual within the solver's inlier bound), inlier_weight (sum of the
// correspondences' omega over inliers_T, so verification thresholds mean the same for all),
// rms_xy_m/rms_z_m. None of them measures hypothesis ambiguity: yaw_consensus and
// translation_consensus are the inlier weight, the runner-ups 0.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "dtif/core/matching/matcher.h"
#include "dtif/core/pose/pose_estimator.h"

namespace dtif::baselines {

/// 6-DoF RANSAC over minimal samples of 3 correspondences, each solved by SVD (Kabsch/Umeyama
/// without scale), then a least-squares refit on the best consensus set. Unit weights.
struct RansacParams {
  double inlier_m = 0.3;       ///< 3-D residual bound of an inlier [m]
  int max_iterations = 10000;  ///< samples at most
  double confidence = 0.999;   ///< stop once a better set is this unlikely [0..1)
  uint32_t seed = 1;           ///< fixed: results are repeatable
};
PoseEstimate svdRansac(const std::vector<Correspondence>& corrs, const RansacParams& params);

/// Quatro-like (Lim et al., gravity-aligned quasi-SO(3)): yaw by GNC-TLS on the
/// translation-invariant measurements of *all* correspondence pairs (no max-clique pruning,
/// no length pre-filter, no global consensus sweep, pairs sharing a trunk kept), then
/// component-wise translation (TEASER's COTE: adaptive voting per axis, x, y and z alike) on
/// the rotation inliers. Unit weights. Unlike dtif's unit-weight ablation it has no exact yaw
/// sweep guarding GNC, no vote threshold on rotation inliers, no joint 2-D mode for t_xy, no
/// Procrustes refit, and takes t_z from every pair whether or not its stem bases were seen.
struct QuatroParams {
  double beta_m = 0.3;           ///< TLS bound of TIM and translation residuals [m]
  double gnc_factor = 1.4;       ///< GNC continuation factor of mu
  int gnc_max_iterations = 100;  ///< GNC iterations at most
  int max_tim_pairs = 20000;     ///< TIMs used at most (fixed stride over the pairs, as dtif)
};
PoseEstimate quatroLike(const std::vector<Correspondence>& corrs, const QuatroParams& params);

/// Fast Global Registration (Zhou et al. 2016) on given correspondences: Geman-McClure
/// objective with Black-Rangarajan line processes l = (mu / (mu + r^2))^2, mu starting at the
/// squared diameter of the correspondences and divided by `div_factor` every 4 iterations down
/// to final_scale_m^2. Each iteration solves the weighted least squares in closed form (SVD)
/// instead of one Gauss-Newton step. 6-DoF, identity start, unit weights.
struct FgrParams {
  double final_scale_m = 0.3;  ///< delta: mu stops decreasing at delta^2; also the inlier bound
  double div_factor = 1.4;     ///< mu /= div_factor every 4 iterations
  int iterations = 64;         ///< outer iterations
};
PoseEstimate fastGlobalRegistration(const std::vector<Correspondence>& corrs,
                                    const FgrParams& params);

/// Outlier pruning on pairwise length consistency, standing in for the maximum-clique step of
/// TEASER++/Quatro++ (and GROR's node reliability): correspondences i, j agree when
/// | |q_i - q_j| - |c_i - c_j| | <= eps (a rigid motion keeps lengths); a greedy clique is grown
/// from the highest-degree correspondence, adding the next-highest ones that agree with every
/// member. Returns indices into corrs (all of them when fewer than 3).
std::vector<int> greedyConsistentSet(const std::vector<Correspondence>& corrs, double eps);

}  // namespace dtif::baselines
