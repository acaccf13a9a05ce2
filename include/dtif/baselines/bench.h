// Benchmark of issue #5 against the paper's baselines, on the protocol of DATASET.md: one pass
// over a dataset builds dtif's descriptors and the FPFH baseline's features once, then every
// back end runs the sequential protocol on dtif's own correspondences (Tables 3-4 style) and
// every front end registers the same submap pairs (Tables 1-2 style). Scoring is
// evaluation.h's (scoreAcceptedLoop, summarizeRows), never a copy of it.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "dtif/baselines/fpfh_registration.h"
#include "dtif/baselines/scan_context.h"
#include "dtif/eval/evaluation.h"
#include "dtif/io/config.h"
#include "dtif/io/dataset.h"

namespace dtif::baselines {

struct BenchOptions {
  EvalParams eval;
  /// Back ends on dtif's correspondences: "dtif", "dtif_unit", "quatro", "svd_ransac", "fgr".
  std::vector<std::string> back_ends{"dtif", "dtif_unit", "quatro", "svd_ransac", "fgr"};
  bool front_ends = true;  ///< also the FPFH baseline and dtif on the same pairs
  std::vector<std::string> fpfh_solvers{"quatro", "svd_ransac"};
  FpfhParams fpfh;
  bool pr_curve = true;           ///< a loosely verified dtif run, swept over the inlier threshold
  bool place_recognition = true;  ///< the scan-context baseline vs dtif as place recognition
  ScanContextParams scan_context;
};

/// The solver of a back-end name (empty function for "dtif": estimatePose). Throws
/// std::invalid_argument on an unknown name.
PoseSolver makeBackEnd(const std::string& name, const PoseEstimatorParams& pose);

/// One method's rows (one per submap, DATASET.md's results.csv) and their summary.
struct MethodRun {
  std::string method;
  std::string table;  ///< "back_end" or "front_end"
  std::vector<EvalRow> rows;
  EvalSummary summary;
};

/// Per submap: sizes and stage times (time per stage vs trunks per submap).
struct SubmapStats {
  int64_t id = -1;
  size_t points = 0, trunks = 0, bytes = 0, fpfh_points = 0;
  double t_extract_ms = 0.0;       ///< trunk extraction
  double t_desc_ms = 0.0;          ///< extraction + descriptor (DATASET.md's desc)
  double t_loop_ms = 0.0;          ///< dtif's query (DATASET.md's loop)
  double t_fpfh_ms = 0.0;          ///< voxel grid + normals + FPFH
  double t_scan_context_ms = 0.0;  ///< scan-context descriptor
};

/// Precision and recall when accepting only loops with at least `threshold` inliers (scan
/// context: answers with a distance below `threshold`).
struct PrPoint {
  std::string method;
  double threshold = 0.0;
  size_t accepted = 0, true_positives = 0;
  double precision = 0.0, recall = 0.0;
};
/// A PrPoint from its counts: precision 1 without answers, recall 0 without loops.
PrPoint prPoint(const std::string& method, double threshold, size_t accepted, size_t true_positives,
                size_t loops);

/// A method scored as place recognition: an accepted loop counts as correct when its pair is a
/// true loop (overlap ground truth), whatever its pose error. rows: one per submap; t_desc_ms
/// and t_loop_ms are the method's own; err->yaw_deg is meaningful, other errors are not for
/// scan context (it estimates no translation: est_t* are 0).
struct PlaceRecognitionRun {
  std::string method;
  std::vector<EvalRow> rows;
  double bytes_sum = 0.0;  ///< descriptor bytes summed over the rows
};

struct PlaceRecognitionSummary {
  size_t submaps = 0, answers = 0, correct = 0, queries_with_loop = 0;
  std::optional<double> precision;           ///< correct / answers
  std::optional<double> recall;              ///< correct / queries with a loop
  std::optional<double> yaw_err_deg;         ///< mean |yaw error| of correct answers [deg]
  std::optional<double> yaw_err_median_deg;  ///< their median [deg]
  double t_desc_ms = 0.0, t_query_ms = 0.0;  ///< means per submap [ms]
  double bytes_mean = 0.0;
};
PlaceRecognitionSummary summarizePlaceRecognition(const std::vector<EvalRow>& rows,
                                                  double bytes_sum);
/// The place-recognition table's markdown header and one row.
std::string placeRecognitionHeader(const std::string& first);
std::string placeRecognitionRow(const PlaceRecognitionSummary& s, const std::string& method);

struct SceneBench {
  std::string scene;
  std::vector<MethodRun> runs;
  std::vector<SubmapStats> submaps;
  std::vector<PrPoint> pr;
  std::vector<PlaceRecognitionRun> place;  ///< scan context, then dtif (if it ran as back end)
  std::vector<std::shared_ptr<const Descriptor>> descriptors;  ///< valid ones, for scaling
};

/// Runs everything on one dataset. progress(stage) reports what is running.
SceneBench runSceneBench(const Dataset& ds, const std::string& scene, const DtifParams& params,
                         const BenchOptions& options,
                         const std::function<void(const std::string&)>& progress = {});

/// Query time against databases of growing size.
struct ScalingPoint {
  size_t db_size = 0;
  bool indexed = false;
  double query_ms = 0.0;   ///< mean wall-clock per query
  double screen_ms = 0.0;  ///< of which histogram screening
  double match_ms = 0.0;   ///< of which correspondences
  double solver_ms = 0.0;  ///< of which pose estimation
  double screened_in = 0.0;
};

/// A perturbed copy of d, as another survey of the same place: its trunks turned and shifted
/// (random yaw and translation), jittered by 2 cm, 10 % dropped, described again.
Descriptor perturbedCopy(const Descriptor& d, uint32_t seed, const DescriptorParams& params);

/// Databases of `sizes` entries made of perturbed copies of `pool` (cycling through it in a
/// fixed shuffled order), each
/// queried by every descriptor of `queries`; the mean per query at each size.
std::vector<ScalingPoint> runScaling(const std::vector<std::shared_ptr<const Descriptor>>& pool,
                                     const std::vector<std::shared_ptr<const Descriptor>>& queries,
                                     const DtifParams& params, const std::vector<size_t>& sizes);

/// The markdown row of formatTable for one summary (no header).
std::string tableRow(const EvalSummary& s, const std::string& method);
/// formatTable's header lines, with the first column named `first`.
std::string tableHeader(const std::string& first);

}  // namespace dtif::baselines
