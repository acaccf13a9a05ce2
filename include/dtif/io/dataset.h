// Reading and writing the dataset format of DATASET.md (submaps.csv, submaps/<id>.pcd,
// ground_truth.csv, stems.csv, dataset.yaml).
#pragma once

#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/types.h"

namespace dtif {

/// A dataset that breaks the contract, or a file that cannot be read. what() is one line
/// naming the file and the problem.
class DatasetError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One row of submaps.csv.
struct SubmapRecord {
  int64_t id = -1;
  std::string robot;
  double stamp = 0.0;             ///< anchor time [s]
  std::string file;               ///< relative to the dataset folder
  Pose T_O_S = Pose::Identity();  ///< pose in the robot's odometry frame (drifting)
};

/// One row of stems.csv (ground-truth trunk in W).
struct StemRecord {
  int64_t stem_id = -1;
  double x = 0.0, y = 0.0, z_base = 0.0;  ///< [m]
  double dbh = 0.0;                       ///< diameter at 1.3 m above the base [m]
};

struct Dataset {
  std::string root;                   ///< folder
  std::vector<SubmapRecord> submaps;  ///< file order = acquisition order
  std::map<int64_t, Pose> T_W_S;      ///< ground truth (empty when absent)
  std::vector<StemRecord> stems;      ///< empty when absent
};

/// Reads a dataset folder. Throws DatasetError on any contract violation (missing required
/// file, bad header, bad number, duplicate id, bad robot name, missing PCD, unnormalised
/// quaternion, ground truth without a submap).
Dataset readDataset(const std::string& dir);

/// Loads a submap's cloud (NaN/inf dropped). Throws DatasetError naming the file.
Cloud::Ptr loadSubmapCloud(const Dataset& ds, const SubmapRecord& rec);

/// Loads any PCD with x y z fields (NaN/inf dropped). Throws DatasetError naming the file.
Cloud::Ptr loadPcd(const std::string& path);

/// Writes submaps.csv, ground_truth.csv (if T_W_S non-empty) and stems.csv (if non-empty).
/// Clouds are written separately with writeSubmapCloud. Throws DatasetError on I/O failure.
void writeDatasetTables(const Dataset& ds);

/// Writes a cloud as binary-compressed PCD to <ds.root>/<rec.file>, creating folders.
void writeSubmapCloud(const Dataset& ds, const SubmapRecord& rec, const Cloud& cloud);

/// One query of an online loop-closure run, as the LoopClosureNodelet logs it (~loop_log): a
/// CSV row per descriptor queried, accepted or not. Times are ROS times (simulated under a bag
/// replay with --clock) except wall_time.
struct LoopLogRow {
  std::string query_robot;
  int64_t query_id = -1;        ///< the robot's own submap id
  double query_stamp = 0.0;     ///< anchor time of the query submap [s]
  double query_data_end = 0.0;  ///< stamp of the query submap's last cloud [s]
  bool accepted = false;
  std::string candidate_robot;  ///< empty unless accepted
  int64_t candidate_id = -1;
  double candidate_stamp = 0.0;   ///< [s]
  Pose T_c_q = Pose::Identity();  ///< estimate (identity unless accepted)
  int inliers = 0;
  double score = 0.0;
  double t_loop_ms = 0.0;  ///< query time, wall clock [ms]
  double ros_time = 0.0;   ///< when the result was published [s]
  double wall_time = 0.0;  ///< the same moment on the wall clock [s]
};

/// The header line of a loop log and one row of it (no newline).
std::string loopLogHeader();
std::string formatLoopLogRow(const LoopLogRow& r);

/// Reads a loop log. Throws DatasetError naming the file and line.
std::vector<LoopLogRow> readLoopLog(const std::string& path);

/// query id -> candidate id of the accepted rows of eval's results.csv. Throws DatasetError.
std::map<int64_t, int64_t> readAcceptedLoops(const std::string& results_csv);

/// Trunk-map CSV `x,y,z,r` (header optional; extra columns ignored, except a fifth column named
/// `base_seen` (0/1) in the header, which dtif extract writes). Throws DatasetError.
Trunks readTrunkCsv(const std::string& path);
void writeTrunkCsv(const std::string& path, const Trunks& trunks);

}  // namespace dtif
