// Descriptor database of all robots and sequential loop detection: screening, correspondences,
// decoupled pose and verification (paper Alg. 1 and Sec. 3.D, plus dtif's false-loop checks).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/matching/matcher.h"
#include "dtif/core/pose/pose_estimator.h"
#include "dtif/core/verification/verification.h"

namespace dtif {

struct DatabaseParams {
  double exclude_recent_s = 30.0;  ///< same-robot submaps closer in time are not loops [s]
  int max_candidates = 25;         ///< screened candidates passed to matching, best first
  /// Of those, the best this many may fall back to pose voting (MatcherParams::vote_fallback)
  /// when their triangles give no hypothesis. Voting costs ~1 ms per candidate; in dense
  /// understory the histogram screening ranks true candidates down to 9th-19th (seeds 2 and 3
  /// of dense_slope: 2 loops each beyond the best 8). 0: none.
  int max_vote_candidates = 25;
  /// When a query's best loop is with its own robot, also look for its best loop with another
  /// robot (query's `inter_robot` output), verifying at most this many hypotheses beyond those
  /// the best loop needed (each may be a lattice search in a plantation): the map merge needs
  /// such loops to join robots, and a robot that walks its own earlier path beside another's
  /// may otherwise never report one. 0: off. The evaluation protocol scores the best loop only.
  int inter_robot_verifications = 2;
  /// At most this many of a query's verifications may search the lattice (an ambiguous
  /// hypothesis in a repetitive stand, VerifierParams::max_fit_ambiguity; 5-20 ms each); a
  /// further hypothesis that would need one is left unverified. A plantation query whose best
  /// loop scores low otherwise searches for every candidate (25 searches, ~0.2 s); the replayed
  /// protocol's best loops needed at most 7 (plantation, seeds 1-3). 0: no limit.
  int max_lattice_searches = 8;
  /// A query matches its screened candidates best first and stops at the first loop that
  /// scores at least this (a hypothesis whose score bound reaches it is verified at once), with
  /// another robot, or with any when the query asks for no inter-robot loop beside; the
  /// candidates after it are not matched. The best loop among those matched is returned, which
  /// may differ from the one that matching every candidate would return. Plantation loops score
  /// 0.01-0.2, so this never stops them; 0.7 changed 3 of the 585 replayed best loops (8 scenes,
  /// seeds 1-3) and raised the mean translation error by 1 %, 0.8 one (a better one). 0: every
  /// candidate is matched [0..1].
  double decisive_score = 0.8;

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("exclude_recent_s", exclude_recent_s);
    v("max_candidates", max_candidates);
    v("max_vote_candidates", max_vote_candidates);
    v("inter_robot_verifications", inter_robot_verifications);
    v("max_lattice_searches", max_lattice_searches);
    v("decisive_score", decisive_score);
  }
};

struct LoopDetectorParams {
  MatcherParams matcher;
  PoseEstimatorParams pose;
  VerifierParams verification;
  DatabaseParams database;
  std::string validate() const;
};

/// Where a database entry's submap lies in its robot's odometry frame. Saved with the database so
/// that a later run that loads it can place the old submaps (relocalisation). Empty frame: not
/// known (entries of version-1 files, or inserted without it).
struct EntryOdometry {
  std::string odom_frame;
  Pose T_O_S = Pose::Identity();
  bool known() const { return !odom_frame.empty(); }
};

/// An accepted loop (q, c, T_c_q), T_c_q and T_hypothesis in the submaps' own frames S (also
/// when the descriptors were levelled), covariance too.
struct Loop {
  std::string query_robot;
  int64_t query_id = -1;
  std::string candidate_robot;
  int64_t candidate_id = -1;
  Pose T_c_q = Pose::Identity();
  /// Covariance of (x, y, z, roll, pitch, yaw) [m^2, rad^2], ROS PoseWithCovariance order.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Identity();
  int inliers = 0;     ///< trunk pairs supporting T_c_q after guided refinement
  double score = 0.0;  ///< verification score (co-visible ratio x inlier weight share) [0..1]
  std::vector<std::pair<int, int>> inlier_pairs;  ///< (query trunk, candidate trunk), refined
  std::vector<std::pair<int, int>> all_pairs;     ///< every correspondence that was solved
  /// The pose solver's hypothesis before verification's guided refinement (what a back-end
  /// comparison scores; T_c_q is the refined pose).
  Pose T_hypothesis = Pose::Identity();
};

/// A pose solver on weighted correspondences, in place of estimatePose (back-end comparisons).
/// It must fill T_c_q, ok, inliers_T and inlier_weight; verification also reads the
/// yaw/translation consensus fields (leave runner-ups at 0 when the solver has no such measure).
using PoseSolver = std::function<PoseEstimate(const std::vector<Correspondence>&)>;

/// Per-query timings and counts.
struct QueryStats {
  double screen_ms = 0.0;  ///< histogram screening
  double match_ms = 0.0;   ///< correspondence construction
  double solver_ms = 0.0;  ///< pose estimation only
  double verify_ms = 0.0;  ///< verification
  size_t eligible = 0;     ///< database entries after recent-submap exclusion
  size_t screened_in = 0;  ///< entries passing histogram screening
  size_t matched = 0;      ///< candidates that reached pose estimation
  size_t verified = 0;     ///< candidates that passed verification
  /// Hypotheses query left unverified: their score bound could not beat the loop it found.
  size_t unverified = 0;
  size_t inter_robot_verified = 0;  ///< of verified: verified only to find an inter-robot loop
  size_t lattice_searches = 0;      ///< verifications that searched the lattice
  /// Hypotheses left unverified as they would search the lattice beyond max_lattice_searches.
  size_t lattice_skipped = 0;
  /// Screened candidates matched (hypotheses built): all of them unless a loop scoring at
  /// least DatabaseParams::decisive_score ended matching.
  size_t hypothesized = 0;
  std::vector<int64_t> candidates;  ///< submap ids of the screened candidates, best first
};

/// Matches one pair end to end (correspondences, pose, verification), without the database.
/// Returns the loop when verified; `est`/`ver` (optional) receive the intermediate results.
/// `solver` (optional) replaces estimatePose(corrs, params.pose); `tq`/`tc` (optional) are the
/// sides' matchTriangles, computed here when null.
std::optional<Loop> matchPair(const Descriptor& q, const Descriptor& c,
                              const LoopDetectorParams& params, PoseEstimate* est = nullptr,
                              Verification* ver = nullptr, QueryStats* stats = nullptr,
                              const PoseSolver* solver = nullptr,
                              const std::vector<MatchTriangle>* tq = nullptr,
                              const std::vector<MatchTriangle>* tc = nullptr);

/// Bounds of a database (docs/limits.md): a descriptor is 0.5-8 kB, so a day of six units
/// (10 s submaps) is ~50,000 entries and well under 1 GB. Beyond: insert refuses, a larger file
/// is refused before it is read.
constexpr size_t kMaxDatabaseEntries = 200000;
constexpr uint64_t kMaxDatabaseBytes = uint64_t{1} << 30;

/// What a database file holds: its entries, their odometry poses (pairwise; unknown in version-1
/// files) and the accepted loops (none in version-1 files).
struct DatabaseContents {
  std::vector<std::shared_ptr<const Descriptor>> entries;
  std::vector<EntryOdometry> odometry;
  std::vector<Loop> loops;
  /// Each entry's matchTriangles as saved (version 3 files), computed with neighbour_triangles
  /// = triangles_k; empty, or saved with another k: computed again when the contents enter.
  std::vector<std::vector<MatchTriangle>> triangles;
  int triangles_k = -1;
};

/// The contents of a database file (LoopDetector::save's format), read without any lock held:
/// a regular file of at most kMaxDatabaseBytes (a FIFO or a device is refused before it is
/// opened), every entry valid, no (robot, submap id) twice, at most kMaxDatabaseEntries.
/// Throws std::runtime_error naming the file and the problem.
DatabaseContents readDatabaseFile(const std::string& path);

/// Pose estimation runs between the descriptors' levelled frames (Descriptor::level_rotation);
/// loops are reported in the submaps' own frames: T_Sc_Sq = R_Lc_Sc^-1 * T_Lc_Lq * R_Lq_Sq.
/// Identity rotations give T_Lc_Lq unchanged.
Pose submapFramePose(const Descriptor& q, const Descriptor& c, const Pose& T_Lc_Lq);

/// Sequential loop detector. Not thread-safe: callers serialise access. Descriptors are held
/// by shared_ptr to const and may be shared with other owners.
class LoopDetector {
 public:
  explicit LoopDetector(const LoopDetectorParams& params);

  /// Best verified loop of q against the database (same-robot recent entries excluded).
  /// `inter_robot` (optional): when that loop is with q's own robot, the best loop with another
  /// robot among the hypotheses verified (DatabaseParams::inter_robot_verifications), if any
  /// (nullopt otherwise). The best loop is the same with or without it.
  std::optional<Loop> query(const Descriptor& q, QueryStats* stats = nullptr,
                            std::optional<Loop>* inter_robot = nullptr) const;

  /// Inserts q with its odometry pose (optional); invalid descriptors are ignored (returns
  /// false), as is any once the database holds kMaxDatabaseEntries.
  bool insert(std::shared_ptr<const Descriptor> d, const EntryOdometry& odometry = {});

  /// Replaces the entry of d's (robot, submap id) by d, its odometry kept (forward
  /// accumulation describes a stored submap again once its successors exist). False, nothing
  /// changed, when d is invalid or no such entry exists.
  bool replace(std::shared_ptr<const Descriptor> d);

  size_t size() const { return entries_.size(); }
  /// Bytes the database holds: the screening index, the entries' descriptors (trunks,
  /// triangles, histograms) and their match triangles; the same built live or loaded.
  size_t memoryBytes() const;
  const std::vector<std::shared_ptr<const Descriptor>>& entries() const { return entries_; }
  /// The match triangles of entries()[i] (matchTriangles with the matcher's
  /// neighbour_triangles), computed when it entered or read from the file it was loaded from.
  const std::vector<MatchTriangle>& matchTrianglesOf(size_t i) const { return triangles_.at(i); }
  /// The odometry pose of entries()[i], as inserted or loaded.
  const EntryOdometry& odometry(size_t i) const { return odometry_.at(i); }
  /// Keeps an accepted loop between entries, saved with the database (trunk pairs are not), so
  /// that a later run that loads it can rebuild this run's map (relocalisation).
  void recordLoop(const Loop& loop) { loops_.push_back(loop); }
  /// The recorded loops, as recorded or loaded.
  const std::vector<Loop>& loops() const { return loops_; }
  const LoopDetectorParams& params() const { return params_; }
  /// Replaces estimatePose by another solver on the same correspondences (empty: estimatePose).
  void setSolver(PoseSolver solver) { solver_ = std::move(solver); }

  /// Writes the database to path atomically (temporary file, then rename). Throws on failure.
  void save(const std::string& path) const;
  /// Replaces the database by the file's content (version 1 files: odometry unknown, no loops;
  /// version 1 and 2 files: match triangles computed).
  /// Throws
  /// std::runtime_error (naming the file and the problem) on a missing, corrupt or
  /// version-mismatched file; then nothing changes.
  void load(const std::string& path);
  /// Replaces the database by a file's contents (readDatabaseFile's; it checked them).
  void replaceContents(DatabaseContents contents);

 private:
  LoopDetectorParams params_;
  std::vector<std::shared_ptr<const Descriptor>> entries_;
  std::vector<EntryOdometry> odometry_;  // parallel to entries_
  std::vector<Loop> loops_;
  PoseSolver solver_;
  /// matchTriangles of each entry, computed when it enters (insert, load): the neighbour
  /// triangles of a descriptor do not depend on the query. Computed up front rather than on
  /// first match so that a database's memory is the same whether it was built live or loaded,
  /// and query stays const without a mutable cache.
  std::vector<std::vector<MatchTriangle>> triangles_;

  /// The screening index: what query's screening reads of every entry, in flat arrays (one
  /// pass over contiguous memory instead of a pointer chase and a robot-name comparison per
  /// entry). Parallel to entries_; insert and replaceContents maintain it.
  struct ScreenRow {
    uint32_t robot = 0;  ///< into robots_
    uint32_t edge_n = 0, radius_n = 0;
    size_t offset = 0;  ///< of the edge histogram in hists_; the radius histogram follows
    double stamp = 0.0;
    int64_t submap_id = -1;
  };
  std::vector<ScreenRow> screen_;
  std::vector<float> hists_;
  std::vector<std::string> robots_;
  std::unordered_map<std::string, uint32_t> robot_ids_;  ///< robots_ by name
  /// Indexes d; its match triangles are `triangles` when given, else computed.
  void indexEntry(const Descriptor& d, std::vector<MatchTriangle>* triangles = nullptr);
  /// The index of entries_, with saved match triangles (one per entry) when given.
  void rebuildIndex(std::vector<std::vector<MatchTriangle>>* saved = nullptr);
  /// query's screening: the best max_candidates eligible entries by histogram similarity,
  /// best first (indices into entries_).
  std::vector<size_t> screen(const Descriptor& q, QueryStats* st) const;
  /// query's matching and verification of the screened entries.
  std::optional<Loop> matchCandidates(const Descriptor& q, const std::vector<size_t>& cands,
                                      QueryStats* st, std::optional<Loop>* inter_robot) const;
};

/// Indices of db's entries in (stamp, robot) order, ties in database order: the order in which
/// live submaps enter, so that a database replayed into the map merge is anchored on the robot
/// that came first, as it was live.
std::vector<size_t> entriesInStampOrder(const LoopDetector& db);

}  // namespace dtif
