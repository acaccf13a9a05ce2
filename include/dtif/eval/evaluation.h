// Evaluation protocol of DATASET.md: sequential loop detection over a dataset, overlap ground
// truth, pose errors (paper Eq. 4.4 and ZYX Euler residuals), precision/recall, times.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include "dtif/io/config.h"
#include "dtif/io/dataset.h"

namespace dtif {

struct EvalParams {
  double true_loop_overlap = 0.3;  ///< overlap that makes a pair a true loop
  double max_rot_err_deg = 2.0;    ///< a true positive's rotation error at most [deg]
  double max_trans_err_m = 0.5;    ///< a true positive's translation error at most [m]
};

/// Errors of an estimate against ground truth.
struct PoseError {
  double roll_deg = 0, pitch_deg = 0, yaw_deg = 0, rot_deg = 0;  ///< absolute values [deg]
  double x_m = 0, y_m = 0, z_m = 0, trans_m = 0;                 ///< absolute values [m]
};

/// e_R of Eq. (4.4); roll/pitch/yaw from the ZYX decomposition of R_gt^T R_est; translation
/// residual t_est - t_gt.
PoseError poseError(const Pose& T_gt, const Pose& T_est);

/// Occupied 1 m x 1 m cells in W of a submap's points 0.3-3.0 m above its local ground
/// (DATASET.md), trunkHeightCells on every point. Cell keys pack (ix, iy). A submap frame
/// tilted more than kTruthLevelDeg from gravity (upstream FAST-LIO2) is first levelled with
/// its ground-truth attitude, so that "above the local ground" means what it means for a level
/// one; level frames (up to the front end's residual) are taken as they are.
std::unordered_set<int64_t> overlapCells(const Cloud& cloud_S, const Pose& T_W_S);
constexpr double kTruthLevelDeg = 3.0;
std::unordered_set<int64_t> overlapCells(const Cloud& cloud_S, const Pose& T_W_S);

/// |A cap B| / min(|A|, |B|); 0 when either is empty.
double cellOverlap(const std::unordered_set<int64_t>& a, const std::unordered_set<int64_t>& b);

/// One row of results.csv.
struct EvalRow {
  int64_t query = -1;
  std::optional<int64_t> candidate;  ///< accepted candidate
  bool accepted = false;
  bool true_loop = false;  ///< accepted pair is a true loop (overlap >= threshold)
  bool has_loop = false;   ///< some eligible entry forms a true loop with the query
  double overlap = 0.0;    ///< of the accepted pair (0 if none)
  std::optional<PoseError> err;
  int inliers = 0;
  double score = 0.0;
  double t_desc_ms = 0.0, t_loop_ms = 0.0, t_solver_ms = 0.0;
  std::optional<Pose> T_c_q_est;
  bool true_positive = false;
  size_t trunks = 0;            ///< trunks extracted (extra, not in results.csv)
  size_t described_trunks = 0;  ///< trunks in the descriptor (extra; multi_submap may add)
  int described_submaps = 1;    ///< submaps whose trunks it holds (extra; 1: its own only)
  /// Earlier entries of its robot it described again (extra; multi_submap/forward_submaps).
  size_t forward_updates = 0;
  std::string invalid_reason;  ///< why the descriptor was excluded (extra)
};

struct EvalSummary {
  std::string dataset;
  size_t submaps = 0, queries_with_loop = 0, accepted = 0, true_positives = 0, false_positives = 0;
  std::optional<double> precision, recall;
  std::optional<PoseError> mean_err_all, mean_err_tp;
  std::optional<double> rmse_rot_deg, rmse_trans_m;
  double t_desc_ms = 0, t_loop_ms = 0, t_solver_ms = 0, t_total_ms = 0;
  double descriptor_bytes_mean = 0;
  size_t descriptor_bytes_max = 0;  ///< largest encoded descriptor (DESIGN: <= 8 KB on the wire)
  /// Loops reported beside a query's best one, with another robot (DatabaseParams::
  /// inter_robot_verifications; not part of the protocol's scores), and how many of them are true
  /// positives.
  size_t inter_robot_extra = 0, inter_robot_extra_true = 0;
  bool online = false;  ///< scored from an online run's loop log: only t_loop_ms is measured
};

/// Trunk extraction of one submap against the ground-truth stems (stems.csv); an extra output
/// of eval (detection.csv), not part of DATASET.md's protocol.
struct DetectionRow {
  int64_t submap = -1;
  size_t points = 0;           ///< finite points of the submap
  size_t visible_stems = 0;    ///< stems with >= 10 points on them 0.5-2.5 m above their base
  size_t trunks = 0;           ///< trunks extracted
  size_t trunks_on_stems = 0;  ///< trunks within 0.5 m of a stem (the rest are false trunks)
  size_t visible_found = 0;    ///< visible stems with a trunk within 0.5 m
  size_t bases_seen = 0;       ///< trunks on stems whose base was seen (base_seen)
  double radius_mae_m = 0.0;   ///< mean |r - dbh / 2| over trunks on stems [m]
  double base_mae_m = 0.0;     ///< mean |z - z_base| over trunks on stems with seen bases [m]
};

/// Matches `trunks` (in S) to the stems (in W) under the ground-truth pose.
DetectionRow trunkDetection(const Cloud& cloud_S, const Pose& T_W_S, const Trunks& trunks,
                            const std::vector<StemRecord>& stems);

/// A query with a true loop that was not found (or not within the TP tolerances): why, for
/// its best ground-truth candidate. An extra output of eval (misses.csv) for tuning.
struct MissRow {
  int64_t query = -1;
  int64_t candidate = -1;  ///< the eligible earlier submap of largest overlap
  double overlap = 0.0;    ///< their ground-truth overlap
  int rank = 0;            ///< its place in the query's screened candidates (1: best); 0: not kept
  size_t hypothesis_inliers = 0;  ///< |I_T| of the solver's hypothesis
  std::string outcome;  ///< matchPair on the pair alone: "accepted" or the rejection reason
  std::optional<PoseError> hypothesis_err;  ///< the solver's hypothesis against ground truth
  double ambiguity = 0.0;                   ///< Verification::ambiguity
  double fit_ambiguity = -1.0;              ///< Verification::fit_ambiguity
  int pairs = 0;                            ///< refined trunk pairs
  double covisible_ratio = 0.0;
  double aligned_overlap = -1.0;  ///< Verification::overlap
  int z_pairs = 0;
  int ground_cells = 0;
};

/// Levelling of one submap (params `levelling`, gravity.h) against ground truth: an extra output
/// of eval (levelling.csv), only when levelling is enabled.
struct LevellingRow {
  int64_t submap = -1;
  std::string robot;
  double true_tilt_deg = 0.0;  ///< S's z from gravity (ground truth T_W_S) [deg]
  double used_tilt_deg = 0.0;  ///< tilt of S the levelling removed (R_L_S) [deg]
  double error_deg = 0.0;      ///< levelled frame L's z from gravity: the levelling error [deg]
  double observation_error_deg = -1.0;  ///< this submap's own observation vs truth; -1: none
  double sigma_deg = 0.0;               ///< the estimate's reported uncertainty [deg]
  int support_cells = 0;                ///< of the observation
  bool from_ground = false;             ///< observation from ground normals (few stems)
};

/// Per robot: mean and max levelling error, the last submap's, the reported uncertainty.
struct LevellingSummary {
  std::string robot;
  size_t submaps = 0;
  double true_tilt_deg = 0.0;  ///< mean over the robot's submaps [deg]
  double mean_error_deg = 0.0, max_error_deg = 0.0, last_error_deg = 0.0, last_sigma_deg = 0.0;
};
std::vector<LevellingSummary> summarizeLevelling(const std::vector<LevellingRow>& rows);
/// levelling.csv: one row per LevellingRow. Throws DatasetError.
void writeLevellingCsv(const std::string& path, const std::vector<LevellingRow>& rows);
/// A text table of the per-robot summaries.
std::string formatLevelling(const std::vector<LevellingSummary>& s);

struct EvalResult {
  std::vector<EvalRow> rows;
  std::vector<LevellingRow> levelling;  ///< per submap; empty unless levelling is enabled
  EvalSummary summary;
  std::vector<DetectionRow> detection;  ///< per submap; empty without stems.csv
  std::vector<MissRow> misses;          ///< queries with a true loop and no true positive
};

/// misses.csv: one row per MissRow. Throws DatasetError.
void writeMissesCsv(const std::string& path, const std::vector<MissRow>& rows);

/// detection.csv: one row per submap, the fields of DetectionRow. Throws DatasetError.
void writeDetectionCsv(const std::string& path, const std::vector<DetectionRow>& rows);

/// DATASET.md step 2: c is in q's database unless it is the same robot's within
/// exclude_recent_s seconds.
bool eligiblePair(const SubmapRecord& q, const SubmapRecord& c, double exclude_recent_s);

/// Scores an accepted loop (q, c, T_c_q_est) of a pair with the given overlap: fills the row's
/// accepted, T_c_q_est, err, overlap, true_loop and true_positive (DATASET.md's TP rule).
void scoreAcceptedLoop(const Pose& T_c_q_gt, const Pose& T_c_q_est, double overlap,
                       const EvalParams& eval, EvalRow* row);

/// The summary of DATASET.md over one row per submap (means, RMSE, precision/recall, times);
/// bytes_sum is the encoded descriptor size summed over the rows.
EvalSummary summarizeRows(const std::vector<EvalRow>& rows, const std::string& dataset,
                          double bytes_sum);

/// Called by runEvaluation after each query with the submap's descriptor (its trunks), the
/// accepted loop and the inter-robot loop beside it, if any (what a back end such as
/// `dtif merge` consumes).
using QueryObserver = std::function<void(const Descriptor& desc, const std::optional<Loop>& loop,
                                         const std::optional<Loop>& inter_robot_loop)>;

/// Runs the protocol. progress(i, n) is called after each submap, on_query (optional) after each
/// query. Throws DatasetError when ground truth is missing or a cloud cannot be read.
EvalResult runEvaluation(const Dataset& ds, const DtifParams& params, const EvalParams& eval,
                         const std::function<void(size_t, size_t)>& progress = {},
                         const QueryObserver& on_query = {});

/// Scores an online run (the LoopClosureNodelet's loop log, e.g. on a bag of this dataset from
/// dtif simulate) with runEvaluation's ground truth and metrics. Log rows are matched to the
/// dataset's submaps by robot and stamp (within 1 ms); rows come out in the dataset's order, a
/// submap the run never queried counting as a query without a loop. t_loop_ms is the log's mean
/// over queried submaps; the summary is marked online. Log rows whose query or candidate is not
/// in the dataset are skipped and described in *unmatched. Throws DatasetError.
EvalResult scoreLoopLog(const Dataset& ds, const std::vector<LoopLogRow>& log,
                        double exclude_recent_s, const EvalParams& eval,
                        std::vector<std::string>* unmatched = nullptr);

/// results.csv and summary.json (exact columns/keys of DATASET.md). Throws DatasetError.
void writeResultsCsv(const std::string& path, const std::vector<EvalRow>& rows);
void writeSummaryJson(const std::string& path, const EvalSummary& s);
/// The paper's Table 1 layout, plus precision/recall, as plain text.
std::string formatTable(const EvalSummary& s, const std::string& method = "dtif");

}  // namespace dtif
