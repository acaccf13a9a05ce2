// Point-feature global registration baseline standing in for Quatro++ / GROR-style front ends
// (paper Tables 1-2): voxel downsampling, normals, FPFH (Rusu et al. 2009, PCL's
// FPFHEstimationOMP on one thread), mutual nearest neighbours in feature space, pruning on
// pairwise length consistency (a greedy clique, as Quatro++/TEASER++'s maximum clique), then a
// robust solver of solvers.h on those point correspondences. ROS-free; PCL's feature templates stay
// in fpfh_registration.cpp.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/matching/matcher.h"

namespace dtif::baselines {

struct FpfhParams {
  double voxel_m = 0.5;           ///< voxel grid leaf before features [m]
  size_t max_points = 10000;      ///< keypoints: voxels evenly thinned to at most this many
  double normal_radius_m = 1.0;   ///< normal estimation radius [m]
  double feature_radius_m = 2.0;  ///< FPFH support radius [m]
  double inlier_m = 0.5;          ///< solver's inlier bound (about one voxel) [m]
  int min_inliers = 12;           ///< accepted when the estimate has this many inliers [-]
  std::string solver = "quatro";  ///< "quatro" (Quatro++-like) or "svd_ransac"
  bool prune = true;              ///< greedyConsistentSet (max-clique stand-in) before the solver
};

/// Downsampled points and their FPFH signatures (opaque; PCL types stay in the .cpp).
struct FpfhFeatures;
using FpfhFeaturesPtr = std::shared_ptr<const FpfhFeatures>;

/// Voxel grid, thinning, normals and FPFH of one submap (the baseline's "descriptor").
FpfhFeaturesPtr computeFpfh(const Cloud& cloud, const FpfhParams& params);
/// Number of keypoints (downsampled points) and the bytes their signatures would take.
size_t fpfhPoints(const FpfhFeatures& f);
size_t fpfhBytes(const FpfhFeatures& f);

/// Mutual nearest neighbours in FPFH space (unit weights; z_ok true).
std::vector<Correspondence> matchFpfh(const FpfhFeatures& q, const FpfhFeatures& c);

struct FpfhRegistration {
  bool accepted = false;
  Pose T_c_q = Pose::Identity();
  int correspondences = 0;
  int inliers = 0;
  double match_ms = 0.0;   ///< feature matching [ms]
  double solver_ms = 0.0;  ///< robust solver [ms]
};

/// Solves T_c_q from matchFpfh's correspondences with params.solver; accepted when
/// params.min_inliers support it (match_ms is left 0).
FpfhRegistration solveFpfh(const std::vector<Correspondence>& corrs, const FpfhParams& params);

/// matchFpfh, then solveFpfh.
FpfhRegistration registerFpfh(const FpfhFeatures& q, const FpfhFeatures& c,
                              const FpfhParams& params);

}  // namespace dtif::baselines
