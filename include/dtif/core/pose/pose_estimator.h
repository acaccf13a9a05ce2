// Reliability-weighted decoupled robust pose (paper Sec. 3.D, Eqs. 3.11-3.17): yaw from
// translation-invariant measurements by GNC-TLS, then weighted TLS horizontal translation,
// then weighted TLS elevation.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "dtif/core/matching/matcher.h"
#include "dtif/core/types.h"

namespace dtif {

struct PoseEstimatorParams {
  double beta_yaw_m = 0.3;       ///< beta_R: TLS bound on TIM residuals, Eq. (3.14) [m]
  double beta_xy_m = 0.3;        ///< beta_xy: TLS bound on horizontal residuals, Eq. (3.16) [m]
  double beta_z_m = 0.3;         ///< beta_z: TLS bound on elevation residuals, Eq. (3.17) [m]
  double gnc_factor = 1.4;       ///< GNC continuation factor of mu
  int gnc_max_iterations = 100;  ///< GNC outer iterations at most
  int max_tim_pairs = 20000;     ///< translation-invariant pairs used at most (fixed subsample)
  bool unit_weights = false;     ///< ablation: every omega_k = 1

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("beta_yaw_m", beta_yaw_m);
    v("beta_xy_m", beta_xy_m);
    v("beta_z_m", beta_z_m);
    v("gnc_factor", gnc_factor);
    v("gnc_max_iterations", gnc_max_iterations);
    v("max_tim_pairs", max_tim_pairs);
    v("unit_weights", unit_weights);
  }
};

struct PoseEstimate {
  bool ok = false;                ///< false when there were fewer than 2 correspondences
  Pose T_c_q = Pose::Identity();  ///< R_z(theta*), (t_xy*, t_z*)
  double yaw_rad = 0.0;           ///< theta*
  std::vector<int> inliers_R;     ///< I_R: indices into the correspondences
  std::vector<int> inliers_T;     ///< I_T: subset of I_R consistent with t_xy
  double inlier_weight = 0.0;     ///< sum of omega_k over I_T
  double rms_xy_m = 0.0;          ///< RMS horizontal residual over I_T [m]
  double rms_z_m = 0.0;           ///< RMS elevation residual over I_T (seen bases) [m]
  // Hypothesis distinctiveness, for verification in repetitive stands:
  double yaw_consensus = 0.0;          ///< weighted TIM consensus at the best yaw
  double yaw_runner_up = 0.0;          ///< best consensus at yaws > 10 deg away from it
  double translation_consensus = 0.0;  ///< weight of I_R within beta_xy of t_xy
  double translation_runner_up = 0.0;  ///< best such weight of a mode > 2 beta_xy away
};

/// Calls fn(a, b) for the correspondence pairs a < b of k correspondences, in order: all of
/// them, or with more than max_pairs a fixed stride over their enumeration, a deterministic and
/// evenly spread subsample (the translation-invariant measurements of Eq. 3.13).
template <class Fn>
void forEachSampledPair(int k, int max_pairs, Fn&& fn) {
  const int64_t total = static_cast<int64_t>(k) * (k - 1) / 2;
  const double stride = std::max(1.0, static_cast<double>(total) / static_cast<double>(max_pairs));
  double next = 0.0;
  int64_t index = 0;
  for (int a = 0; a < k; ++a) {
    for (int b = a + 1; b < k; ++b, ++index) {
      if (static_cast<double>(index) < next) continue;
      next += stride;
      fn(a, b);
    }
  }
}

/// Solves Eqs. (3.11)-(3.17) on weighted correspondences. Pure; thread-safe; deterministic.
PoseEstimate estimatePose(const std::vector<Correspondence>& corrs,
                          const PoseEstimatorParams& params);

}  // namespace dtif
