// The stages of estimatePose (pose_estimator.h), paper Sec. 3.D, in the order it runs them:
// translation-invariant measurements (Eq. 3.13), robust yaw (Eq. 3.14) and its inliers I_R,
// weighted TLS horizontal translation (Eqs. 3.15-3.16) and its inliers I_T, joint Procrustes
// refinement (Eq. 3.11), weighted TLS elevation (Eq. 3.17), residuals. Exposed for unit tests;
// callers use estimatePose. All pure and thread-safe.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "dtif/core/matching/matcher.h"
#include "dtif/core/pose/pose_estimator.h"

namespace dtif {
namespace pose_stages {

/// One translation-invariant measurement (TIM) of Eq. (3.13): correspondences a and b.
struct Tim {
  int a, b;
  double qx, qy, cx, cy;  // d^q_ab, d^c_ab
  double w;               // omega_ab
  /// |d^q_ab|, |d^c_ab| (hypot) as translationInvariantMeasurements measured them, so that the
  /// yaw sweep need not measure them again; negative: not measured (a TIM made by hand).
  double lq = -1.0, lc = -1.0;
};

/// Eq. (3.13): the TIMs over the correspondence pairs (a fixed subsample beyond
/// params.max_tim_pairs), omega_ab = sqrt(w_a w_b). Pairs sharing a trunk, pairs of (near)
/// coincident points and pairs whose lengths differ by more than beta_R are left out.
std::vector<Tim> translationInvariantMeasurements(const std::vector<Correspondence>& corrs,
                                                  const std::vector<double>& w,
                                                  const PoseEstimatorParams& params);

/// The robust yaw of Eq. (3.14) and how distinct it is.
struct YawEstimate {
  double theta = 0.0;      ///< theta* (not wrapped) [rad]
  double consensus = 0.0;  ///< weighted TIM consensus at the best yaw of the sweep
  double runner_up = 0.0;  ///< best consensus > 10 deg away from it
};

/// GNC-TLS (Yang et al. 2020) for Eq. (3.14) alone: continuation on mu from a convex surrogate
/// to the truncated least squares cost of TIM residuals beyond beta; each step the closed-form
/// weighted rotation. The yaw it reaches (not wrapped) [rad]. Exposed for unit tests.
double gncTlsYaw(const std::vector<Tim>& tims, double beta, const PoseEstimatorParams& params);

/// Eq. (3.14): GNC-TLS, guarded by the exact 1-D consensus sweep over the circle; of the two
/// refined yaws the one with the lower TLS cost. `tims` must not be empty.
YawEstimate estimateYaw(const std::vector<Tim>& tims, const PoseEstimatorParams& params);

/// I_R: the correspondences (of k) taking part in at least a fifth of the best vote count of
/// TIMs with residual <= beta_r at yaw theta (at least one), ascending.
std::vector<int> rotationInliers(const std::vector<Tim>& tims, int k, double theta, double beta_r);

/// A weighted TLS location estimate (tlsLocation).
struct Location {
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  double best = 0.0;       ///< weight of the observations within beta of t
  double runner_up = 0.0;  ///< best seed support outside 2 beta of t
};

/// Weighted TLS location estimate: the densest mode first (each observation as a seed,
/// weighted count within beta), then TLS alternation (inlier mean). Empty `obs`: zero.
Location tlsLocation(const std::vector<Eigen::Vector2d>& obs, const std::vector<double>& w,
                     double beta);

/// Eqs. (3.15)-(3.16): the rotation-compensated observations p^c - R(yaw) p^q of the
/// correspondences in `set`, their weighted TLS location (in *loc) and the members of `set`
/// within beta_xy of it (I_T), in the order of `set`.
std::vector<int> solveTranslation(const std::vector<Correspondence>& corrs,
                                  const std::vector<double>& w, double yaw,
                                  const std::vector<int>& set, double beta_xy, Location* loc);

/// Joint refinement of Eq. (3.11) on I_T (*inliers_t): weighted 2-D Procrustes is its exact
/// LS solution once the inliers are fixed, then the translation again over I_R. Up to three
/// rounds; a round is kept only when it does not lose inliers. Updates *theta, *loc, *inliers_t.
void refineJointly(const std::vector<Correspondence>& corrs, const std::vector<double>& w,
                   const std::vector<int>& inliers_r, double beta_xy, double* theta, Location* loc,
                   std::vector<int>* inliers_t);

/// Eq. (3.17): weighted TLS elevation t_z over I_T. Only pairs whose stem bases were both seen
/// measure it; with none of those, all of I_T vote.
double estimateElevation(const std::vector<Correspondence>& corrs, const std::vector<double>& w,
                         const std::vector<int>& inliers_t, double beta_z);

/// Fills est->rms_xy_m, rms_z_m and inlier_weight from the residuals of est->T_c_q over
/// est->inliers_T (non-empty); the elevation RMS counts only seen bases when there are any.
void addResiduals(const std::vector<Correspondence>& corrs, const std::vector<double>& w,
                  PoseEstimate* est);

}  // namespace pose_stages
}  // namespace dtif
