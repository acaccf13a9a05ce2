// False-loop verification of a pose hypothesis (dtif's checks after paper Sec. 3.D): guided
// refinement on every co-located trunk pair, elevation, lattice disambiguation, co-visibility
// and footprint overlap.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/matching/matcher.h"
#include "dtif/core/pose/pose_estimator.h"
#include "dtif/core/verification/trunk_grid.h"

namespace dtif {

/// Acceptance of a loop. False loops corrupt merged maps, so these err on rejecting.
struct VerifierParams {
  int min_hypothesis_inliers = 4;  ///< |I_T| from the descriptor correspondences at least
  int min_inliers = 6;             ///< trunk pairs co-located after guided refinement at least
  double min_inlier_weight = 8.0;  ///< sum of omega_k over I_T at least
  double max_rms_xy_m = 0.2;       ///< RMS horizontal residual of the refined pairs at most [m]
  double match_radius_m = 0.4;     ///< trunks this close after alignment co-locate [m]
  /// Co-located share of trunks in the common area at least [0..1]. Dense understory hides
  /// half of the stems from either side, so correct loops there score 0.35-0.45.
  double min_covisible_ratio = 0.35;
  int min_covisible = 6;  ///< co-located trunks (both directions summed) at least
  /// Runner-up hypothesis (another yaw > 10 deg away, or another translation mode) with more
  /// than this share of the best one's support: ambiguous (repetitive stand), rejected [0..1].
  double max_ambiguity = 0.5;
  /// Residual roll/pitch: submaps are gravity-aligned only up to the odometry's tilt error
  /// (a few tenths of a degree). With at least this many refined pairs whose stem bases were
  /// both seen, the refinement fits the tilt to their elevations; 0 keeps the paper's 4-DoF
  /// model (Eq. 3.1).
  int tilt_min_pairs = 4;
  double tilt_min_spread_m = 0.0;  ///< the pairs' horizontal spread (smaller std dev) at least [m]
  double max_tilt_deg = 2.0;       ///< a larger fitted tilt is not trusted; 4-DoF kept [deg]
  /// Prior on the residual tilt between two submaps (std dev per axis; the front end's
  /// levelling error, ~0.3 deg per submap): the fit is a MAP estimate that shrinks towards no
  /// tilt when the pairs are few or close together. 0: plain least squares [deg].
  double tilt_prior_deg = 0.5;
  double base_sigma_m = 0.05;  ///< std dev of a seen stem base's elevation (weighs the prior) [m]
  /// The two submaps' ground maps (lowest point per cell) measure the same residual tilt over
  /// tens of metres: when at least this many overlapping cells agree with the plane fitted
  /// through them (and the seen-base pairs), the tilt is fitted to both. 0: bases only.
  int tilt_min_ground_cells = 50;
  /// Std dev of one ground-map cell's elevation difference as the tilt fit weighs it against a
  /// base pair and the prior; above the cells' scatter, since neighbouring cells share their
  /// errors [m].
  double ground_cell_sigma_m = 0.2;
  /// Added in quadrature to the roll/pitch std dev of a tilt fitted with ground cells: a
  /// submap is not rigid (the odometry's drift within its window shears its ground by tenths of
  /// a degree), which hundreds of cells do not average out (measured 0.22 deg RMS error against
  /// 0.07-0.12 deg from the fit alone) [deg].
  double ground_tilt_floor_deg = 0.2;
  /// Overlap of the aligned footprints (occupied cells at trunk height, DATASET.md's measure)
  /// at least; pairs without footprints (trunk maps) skip the check [0..1].
  double min_overlap = 0.3;
  /// An ambiguous hypothesis (max_ambiguity) is replaced by the best fit to all trunks of every
  /// lattice-consistent pose (its yaw turned by 0/90/180/270 deg, each with the translations
  /// where at least min_inliers trunks pair up); that fit is kept when the runner-up pose scores
  /// at most this share of it. 0: ambiguous is always rejected [0..1).
  double max_fit_ambiguity = 0.7;
  /// The lattice search ranks every lattice-consistent pose (~1,500 in a plantation) by a
  /// coarse fit first (the pairs of one nearest-trunk pass, refitted once), then this many of
  /// the best by the finer quick fit (a second pass under the refitted pose), whose best 8 are
  /// fitted to all trunks. 0: every pose by the quick fit (no coarse ranking).
  int lattice_refined_poses = 32;
  /// A fit scores each refined pair (1 - (d / r)^2)^2 for residuals d below this r: tight, so
  /// a wrong lattice site, paired only to the planting jitter, scores little [m].
  double fit_score_radius_m = 0.2;
  /// The fitted winner's median horizontal pair residual at most: a wrong site of a jittered
  /// lattice pairs the trunks only to the planting jitter (0.15 m: median 0.18-0.21 m), the
  /// right one to the centre noise (0.04-0.09 m in the plantation scene) [m].
  double max_fit_median_m = 0.1;
  /// Refined pairs whose stem bases were both seen and agree on t_z at least; with none t_z is
  /// a guess and the loop is rejected rather than reported with a wrong elevation. One pair is
  /// enough once bases on vegetation are flagged (TrunkExtractorParams::max_base_below_points)
  /// and a disagreeing pair makes the elevation ambiguous (max_z_ambiguity): over 3 seeds of
  /// the six scenes 16 more loops, none false; a lone pair's t_z gets a 0.3 m std dev.
  int min_z_pairs = 1;
  /// Another group of seen-base pairs agreeing on a different t_z, over the mode's pairs, at
  /// most this; else the loop is rejected as `elevation ambiguous` (two stems on one shrub).
  double max_z_ambiguity = 0.5;
  /// A loop without such a pair takes t_z from the submaps' ground maps (lowest point per
  /// cell, TrunkExtractorParams::ground_map_cell_m) when at least this many cells agree on it
  /// within ground_window_m; 0: never, such loops are rejected as `elevation unobserved`.
  int min_ground_cells = 100;
  double ground_window_m = 0.15;  ///< cells within this of the mode agree [m]
  /// The highest other difference (more than 2 ground_window_m away) over the mode, at most;
  /// a wrong horizontal pose gives a flat histogram [0..1].
  double max_ground_ambiguity = 0.6;
  /// When the ground maps' mode is too weak or ambiguous under the loop's pose and either
  /// submap was levelled (tilted odometry frame), it is searched again with the query turned by
  /// a residual tilt of up to this per axis (roll, pitch): two robots' levelled frames differ by
  /// their levelling errors, which smear the differences of maps 20-40 m across. 0: no search
  /// [deg].
  double ground_tilt_search_deg = 1.0;
  /// An accepted loop with an accumulated descriptor on either side (open stands) is refitted
  /// in yaw and t_xy to the two submaps' own trunks (refineOnOwnTrunks) that pair up mutually
  /// within this radius under its pose; 0: off [m].
  double own_match_radius_m = 0.5;
  int own_min_pairs = 3;  ///< fewer own pairs: the pose stays

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("min_hypothesis_inliers", min_hypothesis_inliers);
    v("min_inliers", min_inliers);
    v("min_inlier_weight", min_inlier_weight);
    v("max_rms_xy_m", max_rms_xy_m);
    v("match_radius_m", match_radius_m);
    v("min_covisible_ratio", min_covisible_ratio);
    v("min_covisible", min_covisible);
    v("max_ambiguity", max_ambiguity);
    v("tilt_min_pairs", tilt_min_pairs);
    v("tilt_min_spread_m", tilt_min_spread_m);
    v("max_tilt_deg", max_tilt_deg);
    v("tilt_prior_deg", tilt_prior_deg);
    v("base_sigma_m", base_sigma_m);
    v("tilt_min_ground_cells", tilt_min_ground_cells);
    v("ground_cell_sigma_m", ground_cell_sigma_m);
    v("ground_tilt_floor_deg", ground_tilt_floor_deg);
    v("min_overlap", min_overlap);
    v("max_fit_ambiguity", max_fit_ambiguity);
    v("max_fit_median_m", max_fit_median_m);
    v("lattice_refined_poses", lattice_refined_poses);
    v("fit_score_radius_m", fit_score_radius_m);
    v("min_z_pairs", min_z_pairs);
    v("max_z_ambiguity", max_z_ambiguity);
    v("min_ground_cells", min_ground_cells);
    v("ground_window_m", ground_window_m);
    v("max_ground_ambiguity", max_ground_ambiguity);
    v("ground_tilt_search_deg", ground_tilt_search_deg);
    v("own_match_radius_m", own_match_radius_m);
    v("own_min_pairs", own_min_pairs);
  }
};

/// Why a pair was not accepted as a loop. The first four mean the triangles gave no pose
/// hypothesis at all (see isNoHypothesis); the last three are the vote fallback's own.
enum class Rejection {
  kNone,                  ///< accepted (or not verified yet)
  kFewCorrespondences,    ///< fewer correspondences than min_hypothesis_inliers
  kNoPose,                ///< the pose solver found no pose
  kFewHypothesisInliers,  ///< |I_T| below min_hypothesis_inliers
  kLowInlierWeight,       ///< inlier weight below min_inlier_weight
  kAmbiguous,             ///< repetitive stand: the lattice fit could not pick one site
  kRefinementDiverged,    ///< guided refinement moved or turned away from the hypothesis
  kFewInliers,            ///< fewer refined pairs than min_inliers
  kElevationUnobserved,   ///< no seen-base pair and no usable ground maps
  kElevationAmbiguous,    ///< seen-base pairs (or ground maps) agree on several t_z
  kLargeResidual,         ///< refined RMS above max_rms_xy_m
  kFewCovisible,          ///< fewer co-located trunks than min_covisible
  kLowCovisibility,       ///< co-located share below min_covisible_ratio
  kSmallOverlap,          ///< aligned footprints overlap less than min_overlap
  kNoVotedPose,           ///< vote fallback: no voted pose pairs any trunk
  kAmbiguousVotes,        ///< vote fallback: a distinct runner-up scores too close to the best
  kFewVotedPairs,         ///< vote fallback: the best fit pairs too few trunks
};

/// The rejection's text as written to misses.csv and logs ("none" for kNone).
const char* toString(Rejection r);

/// The triangles gave no pose hypothesis at all (as opposed to a hypothesis that failed a
/// check): the case the vote fallback (MatcherParams::vote_fallback) is for.
bool isNoHypothesis(Rejection r);

/// Outcome of verifying one pose hypothesis (exposed for tests and diagnostics).
struct Verification {
  bool accepted = false;
  Pose T_c_q = Pose::Identity();           ///< pose after guided refinement (the one verified)
  std::vector<std::pair<int, int>> pairs;  ///< mutual nearest trunk pairs under T_c_q
  double rms_xy_m = 0.0;                   ///< RMS horizontal residual of pairs [m]
  double rms_z_m = 0.0;                    ///< RMS elevation residual of the z pairs [m]
  int z_pairs = 0;  ///< pairs with both stem bases seen that agree on t_z (0: t_z unobserved)
  bool tilt_fitted = false;      ///< residual roll/pitch estimated (seen bases, ground maps)
  int tilt_ground_cells = 0;     ///< ground-map cells the tilt fit kept (0: bases only)
  double z_ambiguity = -1.0;     ///< runner-up / mode group of seen-base pairs; -1: none seen
  int ground_cells = 0;          ///< ground-map cells that fixed t_z (0: not used)
  double ground_ambiguity = -1;  ///< runner-up / mode of the ground-map differences; -1: none
  double ground_sigma_m = 0.0;   ///< std dev of the agreeing ground-map differences [m]
  double roll_var = 0.0;         ///< when fitted: posterior variance of the roll [rad^2]
  double pitch_var = 0.0;        ///< when fitted: posterior variance of the pitch [rad^2]
  double overlap = -1.0;         ///< overlap of the aligned footprints; -1 when not measured
  double fit_ambiguity = -1.0;   ///< runner-up / best lattice fit; -1 when not needed
  /// Why rejected (kNone when accepted); after a failed vote fallback, the triangles' reason.
  Rejection rejection = Rejection::kNone;
  /// The vote fallback's reason when it ran and failed too (kNone: it did not run or passed).
  Rejection vote_rejection = Rejection::kNone;
  double covisible_ratio = 0.0;  ///< co-located share of trunks inside the other's hull
  int covisible = 0;             ///< co-located trunks (both directions)
  double ambiguity = 0.0;        ///< runner-up / best support (max of yaw and translation)
  double score = 0.0;            ///< covisible_ratio x inlier weight share

  /// The rejection as text, e.g. "few correspondences; votes: ambiguous votes" (empty when
  /// accepted): what misses.csv's outcome column and the logs show.
  std::string reason() const;
};

/// Verifies T_c_q (from estimatePose on corrs) between query q and candidate c. The pose is
/// first refined on every mutually nearest trunk pair (guided matching): the descriptor
/// correspondences give the hypothesis, all co-located trunks then fix it more precisely.
Verification verifyLoop(const Descriptor& q, const Descriptor& c,
                        const std::vector<Correspondence>& corrs, const PoseEstimate& est,
                        const VerifierParams& params);

/// verifyLoop's first checks, on the solver's result alone: kNoPose, kFewHypothesisInliers,
/// kLowInlierWeight (no hypothesis, see isNoHypothesis), else kNone.
Rejection hypothesisRejection(const PoseEstimate& est, const VerifierParams& params);

/// Whether verifyLoop of this hypothesis searches the lattice (resolveByFit, 5-20 ms in a
/// plantation): it passes hypothesisRejection, but its yaw or translation runner-up exceeds
/// max_ambiguity, and max_fit_ambiguity allows the search.
bool needsLatticeSearch(const PoseEstimate& est, const VerifierParams& params);

/// The inlier weight share of a hypothesis, sum of omega_k over I_T / over all corrs (0 for
/// none). An accepted loop scores covisible_ratio (at most 1) times it, so it bounds the score
/// before verification: LoopDetector::query verifies no candidate that cannot beat its best.
double inlierWeightShare(const std::vector<Correspondence>& corrs, const PoseEstimate& est);

/// Result of guidedRefine.
struct Refined {
  Pose T = Pose::Identity();
  std::vector<std::pair<int, int>> pairs;  ///< mutually nearest (query, candidate) trunks
  double rms_xy = 0.0;                     ///< of the pairs [m]; the elevation is refineElevation's
};

/// A candidate's trunk centres and their lookup grid for guidedRefine within `radius` [m]: made
/// once for the several poses a lattice search or the vote fallback refines against one
/// candidate (the grid cost about as much as a refinement).
struct RefineTargets {
  RefineTargets(const Descriptor& c, double radius);
  std::vector<Eigen::Vector2d> xy;  ///< c's trunk centres, by index
  double radius;                    ///< the grid's reach [m]
  TrunkGrid grid;
};

/// Guided matching: re-associate every trunk by mutual nearest neighbour (within radius [m])
/// under the current pose, then solve Eq. (3.11) by least squares on those pairs (2-D
/// Procrustes for yaw and t_xy; t_z is refineElevation's); a few rounds until the pairs stop
/// changing.
Refined guidedRefine(const Descriptor& q, const Descriptor& c, const Pose& T0, double radius);
/// The same against targets made for the candidate (and the radius).
Refined guidedRefine(const Descriptor& q, const RefineTargets& c, const Pose& T0);

/// An accumulated descriptor's trunks carry its neighbours' sightings through odometry, and with
/// them the odometry's drift over its span (0.17-0.22 m of loop translation in very_sparse).
/// When q or c is accumulated and their own trunks (Descriptor::observedTrunks) pair up
/// mutually within own_match_radius_m under v->T_c_q, at least own_min_pairs of them with an
/// RMS of at most max_rms_xy_m, yaw and t_xy are refitted to those pairs (a few rounds, as
/// guidedRefine); roll, pitch and t_z stay. Returns whether the pose was refitted.
bool refineOnOwnTrunks(const Descriptor& q, const Descriptor& c, const VerifierParams& params,
                       Verification* v);

}  // namespace dtif
