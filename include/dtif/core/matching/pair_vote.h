// Pose voting over trunk pairs: the fallback hypothesis generator for submaps that share too few
// Delaunay faces (beyond the paper). Two submaps that see only a fifth of their stems in common
// (dense understory hides most stems from one side or the other) share almost no triangle,
// because any trunk seen by one side only changes the triangulation around it; they still share
// every *pair* of common trunks. Each pair of query trunks and each pair of candidate trunks of
// consistent length and radii (Cons_l, Cons_r of Eq. 3.4) proposes a planar pose (yaw, t_xy);
// the true pose collects a vote from every pair of common trunks, wrong ones scatter.
// Generalised Hough voting on 2-point correspondences; the verification of the loop detector
// then decides, exactly as for a triangle hypothesis.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/matching/matcher.h"

namespace dtif {

/// A local maximum of the vote accumulator.
struct VotePeak {
  double yaw = 0.0;                             ///< [rad], of T_c_q
  Eigen::Vector2d t = Eigen::Vector2d::Zero();  ///< horizontal translation of T_c_q [m]
  double votes = 0.0;                           ///< votes in the peak's neighbourhood of bins
};

/// The strongest `max_peaks` poses proposed by the trunk pairs of `q` and `c` no longer than
/// params.vote_max_pair_m, strongest first; peaks are at least two bins apart in yaw or
/// translation. Votes of a proposal go to its (yaw, x, y) bin of params.vote_yaw_bin_deg and
/// params.vote_xy_bin_m; a peak's pose is the mean of the proposals in its 3 x 3 x 3 bins.
/// Empty when either side has fewer than 2 trunks. Pure; deterministic; thread-safe.
std::vector<VotePeak> votePoses(const Descriptor& q, const Descriptor& c,
                                const MatcherParams& params, int max_peaks);

}  // namespace dtif
