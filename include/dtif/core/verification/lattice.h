// Repetitive stands (plantation grids): a pose hypothesis may sit on any site of the lattice.
// Every lattice-consistent pose is fitted to all trunks and the clearly best fit wins.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <utility>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/verification/verification.h"

namespace dtif {

/// Fit of a pose to the whole trunk sets: guided refinement from `T0` (pairs within the
/// targets' radius), then the Tukey-weighted count of the mutual pairs, sum of
/// (1 - (d / score_radius)^2)^2.
/// Trunk centres are fitted to a few cm, so a pose shifted or turned onto another lattice site
/// of a jittered plantation scores clearly lower than the true one even though it pairs as
/// many trunks.
struct Fit {
  Pose T = Pose::Identity();
  double score = 0.0;
  double median_xy = 0.0;                  ///< median horizontal residual of the pairs [m]
  std::vector<std::pair<int, int>> pairs;  ///< the refined mutual pairs under T
};
/// `targets`: c's, made once for the several poses fitted (their radius is the refinement's).
Fit fitPose(const Descriptor& q, const Descriptor& c, const RefineTargets& targets, const Pose& T0,
            double score_radius);

/// Lattice-consistent translations for the rotation R: every (query, candidate) trunk pair
/// votes for c_j - R q_i in 0.5 m bins; the bins whose 3 x 3 neighbourhood holds a local
/// maximum of at least `min_votes` votes (the trunks that pair up under that translation) and
/// a third of the highest, strongest first, at most `max_peaks`, each as the mean translation
/// of its neighbourhood.
std::vector<Eigen::Vector2d> translationPeaks(const Descriptor& q, const Descriptor& c,
                                              const Eigen::Matrix2d& R, int min_votes,
                                              size_t max_peaks);

/// Repetitive stands: the hypothesis may sit on any site of the lattice, several spacings
/// from the true one. Every lattice-consistent pose is tried: T0's yaw turned by 0, 90, 180
/// and 270 deg, each with the translations where many trunks pair up (translationPeaks); all
/// are fitted to the full trunk sets and the best fit wins.
/// Returns the winner and the runner-up's share of its score.
std::pair<Fit, double> resolveByFit(const Descriptor& q, const Descriptor& c, const Pose& T0,
                                    const VerifierParams& params);

}  // namespace dtif
