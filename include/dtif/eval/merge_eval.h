// `dtif merge` offline: the evaluation protocol's sequential loop closure feeding the map merger
// (core/merge), and the merged map's scoring of DATASET.md ("Merged map", "How it is scored").
#pragma once

#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "dtif/core/merge/map_merger.h"
#include "dtif/core/merge/stem_slices.h"
#include "dtif/eval/evaluation.h"
#include "dtif/io/dataset.h"

namespace dtif {

/// What the sequential loop closure produced, in acquisition order.
struct MergeInput {
  std::vector<MergeSubmap> submaps;  ///< one per row of submaps.csv, with its trunks
  /// Accepted loops; loop_after[k] = index into submaps of the query (the loop arrives then).
  std::vector<Loop> loops;
  std::vector<size_t> loop_after;
  size_t inter_robot_extra = 0;    ///< of loops: inter-robot ones beside an own-robot best loop
  std::optional<EvalResult> eval;  ///< the protocol's scoring, when ground truth exists
  /// Each levelled robot's latest levelling, for its odometry frame: R_L_O (levellingInOdom;
  /// tilted odometry frames; none: level).
  std::map<std::string, Eigen::Matrix3d> levelling;
};

/// Runs the evaluation protocol's sequential loop closure: runEvaluation (scored) when the
/// dataset has ground truth, else the same steps unscored. Throws DatasetError.
MergeInput collectMergeInput(const Dataset& ds, const DtifParams& params, const EvalParams& eval,
                             const std::function<void(size_t, size_t)>& progress = {});

/// Where the robustness check's false loop goes.
enum class FalseLoopPair {
  kFirstLinked,  ///< the robots of the first inter-robot loop, half way through the loops
  kWeakest,      ///< the robots with the fewest inter-robot loops, with the first loop (with
                 ///< dropLoopsBetween: the only loop of its pair, which PCM cannot compare
                 ///< with another)
};

/// Removes the loops between robots a and b (either way) from `in`.
void dropLoopsBetween(MergeInput* in, const std::string& a, const std::string& b);

/// A deliberately false loop for the robustness check: between the two submaps of the pair's
/// robots that are farthest apart (ground truth when present, else odometry), with the pose and
/// covariance of a typical accepted loop and many inliers. nullopt with fewer than two robots.
std::optional<Loop> makeFalseLoop(const Dataset& ds, const MergeInput& in,
                                  FalseLoopPair pair = FalseLoopPair::kFirstLinked);

struct MergeRunStats {
  size_t solves = 0;
  size_t iterative_solves = 0;  ///< of them, with conjugate gradients (a dense factor)
  double solve_ms_total = 0.0, solve_ms_max = 0.0;
  double refine_ms =
      0.0;  ///< the final MapMerger::refine call (last.landmark_ms: its landmark part)
  MergeSolveStats last;
};

/// Feeds the submaps and loops into a merger in acquisition order, solving after each submap
/// that brings a loop (incremental, as online), and once at the end with the landmark
/// refinement (MapMerger::refine). `false_loop` (optional) is added half way through the
/// loops, or with the first one when `false_loop_first`. Events are appended to *events when
/// given.
MapMerger runMerger(const MergeInput& in, const MergeParams& params,
                    const std::optional<Loop>& false_loop = std::nullopt,
                    const std::vector<FieldStem>& stem_map = {},
                    std::vector<MergeEvent>* events = nullptr, MergeRunStats* stats = nullptr,
                    bool false_loop_first = false);

/// The inventory's DBH from the points (StemSlices, StemFusionParams::dbh_from_points): a
/// second pass over the dataset's submap clouds, one at a time, each placed by its merged pose.
/// Submaps without a pose are skipped. Throws DatasetError (an unreadable cloud).
std::vector<MergedStem> refitStemDbh(const Dataset& ds, const std::vector<MergedPose>& poses,
                                     const std::vector<MergedStem>& stems,
                                     const StemFusionParams& params,
                                     StemSliceStats* stats = nullptr);

struct TrajectoryScore {
  size_t submaps = 0;
  double ate_m = 0.0;        ///< RMS position residual after the alignment [m]
  double rot_rms_deg = 0.0;  ///< RMS rotation error after the alignment [deg]
};

struct StemScore {
  size_t listed = 0;         ///< stems in the inventory (scored components)
  size_t matched = 0;        ///< listed stems within match_radius of a true stem
  size_t true_in_range = 0;  ///< true stems within 10 m of a submap origin
  size_t found = 0;          ///< true stems in range with a listed stem
  size_t duplicates = 0;     ///< extra listed stems on one true stem
  double precision = 0.0, recall = 0.0, duplicate_rate = 0.0;  ///< duplicates / matched
  double mean_pos_err_m = 0.0;                                 ///< horizontal, over matched stems
  double median_dbh_err_m = 0.0;  ///< |dbh - dbh_true|, over matched stems
};

struct MergeScore {
  std::map<int, TrajectoryScore> component;         ///< aligned once per component
  std::map<std::string, TrajectoryScore> robot;     ///< residuals under the component's alignment
  std::map<std::string, TrajectoryScore> odometry;  ///< baseline: each robot aligned alone
  TrajectoryScore odometry_all;                     ///< the baseline over every submap
  std::map<int, Pose> T_W_M;                        ///< the alignment per component
  StemScore stems;
};

/// DATASET.md's scoring of a merged map against ground_truth.csv and stems.csv (stems scored
/// only when the dataset has stems.csv). Throws DatasetError without ground truth.
MergeScore scoreMerge(const Dataset& ds, const std::vector<MergedPose>& poses,
                      const std::vector<MergedStem>& stems, double match_radius_m = 0.5);

/// The least-squares rigid transform (no scale) taking `from` onto `to` (Umeyama).
Pose alignRigid(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to);

/// What summary.json of `dtif merge` holds.
struct MergeSummary {
  std::string dataset;
  size_t submaps = 0, robots = 0;
  int components = 0;
  std::map<std::string, int> robot_component;
  size_t loops_accepted = 0;                  ///< by loop closure (the front end)
  size_t loops_used = 0, loops_rejected = 0;  ///< by the back end (PCM)
  size_t inter_robot_used = 0, inter_robot_rejected = 0;
  size_t stems = 0;
  std::optional<StemSliceStats> stem_slices;  ///< when the DBH came from the points
  double stem_slices_ms = 0.0;                ///< that second pass over the clouds [ms]
  MergeRunStats run;
  bool false_loop_injected = false, false_loop_used = false;
  bool false_loop_added = false;          ///< the merger took it (both submaps known)
  std::optional<MergeScore> score;        ///< with ground truth
  std::optional<MergeScore> score_clean;  ///< with a false loop: the same merge without it
  std::optional<StemMapRegistration> stem_map;
  size_t stem_map_field_stems = 0;
};

/// summary.json of `dtif merge` (atomic write). Throws DatasetError.
void writeMergeSummaryJson(const std::string& path, const MergeSummary& s);

/// Merge results as a plain-text table (per component, per robot, baseline, stems).
std::string formatMergeTable(const MergeScore& s);

}  // namespace dtif
