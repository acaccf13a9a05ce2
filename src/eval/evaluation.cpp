// The evaluation protocol of DATASET.md, exactly: sequential descriptor/query/insert over the
// submaps in file order, overlap ground truth from occupied 1 m cells, paper-style errors.
#include "dtif/eval/evaluation.h"

#include <pcl/common/point_tests.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iomanip>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <tuple>
#include <unordered_map>

#include "dtif/core/cells.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/database/loop_pair.h"
#include "dtif/core/descriptor/describe.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/descriptor/trunk_accumulator.h"
#include "dtif/core/extraction/gravity.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/timing.h"
#include "dtif/eval/front_end.h"

namespace dtif {

namespace {

constexpr double kRadToDeg = 180.0 / M_PI;
constexpr double kCellM = 1.0;  // overlap cell (DATASET.md)

}  // namespace

PoseError poseError(const Pose& T_gt, const Pose& T_est) {
  PoseError e;
  const Eigen::Matrix3d R = T_gt.rotation().transpose() * T_est.rotation();
  // Eq. (4.4), argument clipped to [-1, 1].
  const double c = std::clamp((R.trace() - 1.0) / 2.0, -1.0, 1.0);
  e.rot_deg = std::acos(c) * kRadToDeg;
  // ZYX Euler decomposition R = Rz(yaw) Ry(pitch) Rx(roll).
  e.yaw_deg = std::fabs(std::atan2(R(1, 0), R(0, 0))) * kRadToDeg;
  e.pitch_deg = std::fabs(std::asin(std::clamp(-R(2, 0), -1.0, 1.0))) * kRadToDeg;
  e.roll_deg = std::fabs(std::atan2(R(2, 1), R(2, 2))) * kRadToDeg;
  const Eigen::Vector3d dt = T_est.translation() - T_gt.translation();
  e.x_m = std::fabs(dt.x());
  e.y_m = std::fabs(dt.y());
  e.z_m = std::fabs(dt.z());
  e.trans_m = dt.norm();
  return e;
}

std::unordered_set<int64_t> overlapCells(const Cloud& cloud_S, const Pose& T_W_S) {
  const Eigen::Vector3d up_S = T_W_S.rotation().transpose() * Eigen::Vector3d::UnitZ();
  if (std::acos(std::clamp(up_S.z(), -1.0, 1.0)) * kRadToDeg > kTruthLevelDeg) {
    const Eigen::Quaterniond R_G_S = levelRotation(up_S);
    Pose T_W_G = T_W_S;
    T_W_G.linear() = T_W_S.rotation() * R_G_S.conjugate().toRotationMatrix();
    return overlapCells(rotateCloud(cloud_S, R_G_S), T_W_G);
  }
  std::unordered_set<int64_t> cells;
  for (const auto& [ix, iy] : trunkHeightCells(cloud_S, T_W_S, kCellM)) {
    cells.insert(packCell(ix, iy));
  }
  return cells;
}

namespace {

// The true stems near a submap, in its frame S, bucketed in 1 m cells; each counts the submap's
// points on its trunk (how visible it was).
class StemsInS {
 public:
  struct Stem {
    Eigen::Vector3d base;
    double r;
    size_t hits = 0;
  };

  // Stems within 1 m of the extent [minx, maxx] x [miny, maxy] of the submap's points.
  StemsInS(const std::vector<StemRecord>& stems, const Pose& T_S_W, float minx, float maxx,
           float miny, float maxy) {
    for (const StemRecord& st : stems) {
      const Eigen::Vector3d b = T_S_W * Eigen::Vector3d(st.x, st.y, st.z_base);
      if (b.x() < minx - 1 || b.x() > maxx + 1 || b.y() < miny - 1 || b.y() > maxy + 1) continue;
      grid_[packCell(cellIndex(b.x()), cellIndex(b.y()))].push_back(static_cast<int>(s_.size()));
      s_.push_back({b, 0.5 * st.dbh});
    }
  }

  std::vector<Stem>& stems() { return s_; }

  // Calls f(k) for every stem k in the 3 x 3 cells around (x, y).
  template <class F>
  void near(double x, double y, F&& f) const {
    for (int64_t dx = -1; dx <= 1; ++dx)
      for (int64_t dy = -1; dy <= 1; ++dy) {
        const auto it = grid_.find(packCell(cellIndex(x) + dx, cellIndex(y) + dy));
        if (it != grid_.end())
          for (int k : it->second) f(k);
      }
  }

  // Points within `shell_m` of a stem's surface, `low_m`-`high_m` above its base, as its hits.
  void countHits(const Cloud& cloud_S, double shell_m, double low_m, double high_m) {
    for (const auto& p : cloud_S) {
      if (!pcl::isFinite(p)) continue;
      near(p.x, p.y, [&](int k) {
        Stem& s = s_[static_cast<size_t>(k)];
        const double h = p.z - s.base.z();
        if (h < low_m || h > high_m) return;
        if (std::hypot(p.x - s.base.x(), p.y - s.base.y()) <= s.r + shell_m) ++s.hits;
      });
    }
  }

 private:
  std::vector<Stem> s_;
  std::unordered_map<int64_t, std::vector<int>> grid_;
};

}  // namespace

DetectionRow trunkDetection(const Cloud& cloud_S, const Pose& T_W_S, const Trunks& trunks,
                            const std::vector<StemRecord>& stems) {
  constexpr double kMatchM = 0.5, kShellM = 0.05, kLowM = 0.5, kHighM = 2.5;
  constexpr size_t kMinVisiblePoints = 10;
  DetectionRow row;
  row.trunks = trunks.size();
  float minx = std::numeric_limits<float>::infinity(), maxx = -minx, miny = minx, maxy = -minx;
  for (const auto& p : cloud_S) {
    if (!pcl::isFinite(p)) continue;
    ++row.points;
    minx = std::min(minx, p.x), maxx = std::max(maxx, p.x);
    miny = std::min(miny, p.y), maxy = std::max(maxy, p.y);
  }
  StemsInS near_stems(stems, T_W_S.inverse(), minx, maxx, miny, maxy);
  near_stems.countHits(cloud_S, kShellM, kLowM, kHighM);
  std::vector<StemsInS::Stem>& local = near_stems.stems();
  std::vector<char> found(local.size(), 0);
  double sum_r = 0.0, sum_z = 0.0;
  for (const TrunkLandmark& t : trunks) {
    int best = -1;
    double bd = kMatchM;
    near_stems.near(t.x, t.y, [&](int k) {
      const double d = std::hypot(t.x - local[k].base.x(), t.y - local[k].base.y());
      if (d < bd) bd = d, best = k;
    });
    if (best < 0) continue;
    ++row.trunks_on_stems;
    found[best] = 1;
    sum_r += std::abs(t.r - local[best].r);
    if (t.base_seen) {
      ++row.bases_seen;
      sum_z += std::abs(t.z - local[best].base.z());
    }
  }
  for (size_t k = 0; k < local.size(); ++k) {
    if (local[k].hits < kMinVisiblePoints) continue;
    ++row.visible_stems;
    row.visible_found += found[k];
  }
  if (row.trunks_on_stems) row.radius_mae_m = sum_r / static_cast<double>(row.trunks_on_stems);
  if (row.bases_seen) row.base_mae_m = sum_z / static_cast<double>(row.bases_seen);
  return row;
}

void writeDetectionCsv(const std::string& path, const std::vector<DetectionRow>& rows) {
  std::ofstream os(path);
  os << "submap,points,visible_stems,trunks,trunks_on_stems,visible_found,bases_seen,"
        "radius_mae_m,base_mae_m\n";
  for (const DetectionRow& r : rows) {
    os << r.submap << ',' << r.points << ',' << r.visible_stems << ',' << r.trunks << ','
       << r.trunks_on_stems << ',' << r.visible_found << ',' << r.bases_seen << ','
       << r.radius_mae_m << ',' << r.base_mae_m << '\n';
  }
  os.flush();
  if (!os) throw DatasetError(path + ": write failed");
}

void writeMissesCsv(const std::string& path, const std::vector<MissRow>& rows) {
  std::ofstream os(path);
  os << "query,candidate,overlap,rank,hypothesis_inliers,outcome,hyp_err_rot_deg,hyp_err_trans_m,"
        "ambiguity,fit_ambiguity,pairs,covisible_ratio,aligned_overlap,z_pairs,ground_cells\n";
  os << std::setprecision(4);
  for (const MissRow& r : rows) {
    std::string outcome = r.outcome;  // a CSV field: no separators inside
    std::replace(outcome.begin(), outcome.end(), ',', ';');
    os << r.query << ',' << r.candidate << ',' << r.overlap << ',' << r.rank << ','
       << r.hypothesis_inliers << ',' << outcome << ',';
    if (r.hypothesis_err)
      os << r.hypothesis_err->rot_deg << ',' << r.hypothesis_err->trans_m;
    else
      os << ',';
    os << ',' << r.ambiguity << ',' << r.fit_ambiguity << ',' << r.pairs << ',' << r.covisible_ratio
       << ',' << r.aligned_overlap << ',' << r.z_pairs << ',' << r.ground_cells << '\n';
  }
  os.flush();
  if (!os) throw DatasetError(path + ": write failed");
}

double cellOverlap(const std::unordered_set<int64_t>& a, const std::unordered_set<int64_t>& b) {
  if (a.empty() || b.empty()) return 0.0;
  const auto& small = a.size() < b.size() ? a : b;
  const auto& large = a.size() < b.size() ? b : a;
  size_t common = 0;
  for (int64_t c : small) common += large.count(c);
  return static_cast<double>(common) / static_cast<double>(small.size());
}

bool eligiblePair(const SubmapRecord& q, const SubmapRecord& c, double exclude_recent_s) {
  return eligibleLoopPair(q.robot, q.stamp, c.robot, c.stamp, exclude_recent_s);
}

void scoreAcceptedLoop(const Pose& T_c_q_gt, const Pose& T_c_q_est, double overlap,
                       const EvalParams& eval, EvalRow* row) {
  row->accepted = true;
  row->T_c_q_est = T_c_q_est;
  row->err = poseError(T_c_q_gt, T_c_q_est);
  row->overlap = overlap;
  row->true_loop = overlap >= eval.true_loop_overlap;
  row->true_positive = row->true_loop && row->err->rot_deg <= eval.max_rot_err_deg &&
                       row->err->trans_m <= eval.max_trans_err_m;
}

namespace {

using CellSets = std::vector<std::unordered_set<int64_t>>;

// The earlier submap (file position) of largest overlap with submap i among those i may be
// matched with (not the same robot's within exclude_recent_s), and that overlap; (i, -1) when
// there is none.
std::pair<size_t, double> bestEligibleOverlap(const Dataset& ds, const CellSets& cells, size_t i,
                                              double exclude_recent_s) {
  std::pair<size_t, double> best{i, -1.0};
  for (size_t j = 0; j < i; ++j) {
    if (!eligiblePair(ds.submaps[i], ds.submaps[j], exclude_recent_s)) continue;
    const double o = cellOverlap(cells[i], cells[j]);
    if (o > best.second) best = {j, o};
  }
  return best;
}

// DATASET.md's ground truth: does some submap before i (file order) that i may be matched
// with (not the same robot's within exclude_recent_s) form a true loop with it?
bool hasTrueLoop(const Dataset& ds, const CellSets& cells, size_t i, double exclude_recent_s,
                 const EvalParams& eval) {
  const auto [j, overlap] = bestEligibleOverlap(ds, cells, i, exclude_recent_s);
  return j != i && overlap >= eval.true_loop_overlap;
}

// Ground-truth T_c_q of query i and candidate j (file positions), Eq. (4.2).
Pose trueTcq(const Dataset& ds, size_t i, size_t j) {
  return ds.T_W_S.at(ds.submaps[j].id).inverse() * ds.T_W_S.at(ds.submaps[i].id);
}

// Why query i missed its loop: its eligible earlier submap of largest overlap, matched alone.
MissRow explainMiss(const Dataset& ds, const CellSets& cells,
                    const std::vector<std::shared_ptr<const Descriptor>>& descs, size_t i,
                    const QueryStats& qs, const LoopDetectorParams& params) {
  MissRow m;
  m.query = ds.submaps[i].id;
  size_t best = i;
  std::tie(best, m.overlap) = bestEligibleOverlap(ds, cells, i, params.database.exclude_recent_s);
  if (best == i) return m;
  m.candidate = ds.submaps[best].id;
  const auto it = std::find(qs.candidates.begin(), qs.candidates.end(), m.candidate);
  if (it != qs.candidates.end()) m.rank = static_cast<int>(it - qs.candidates.begin()) + 1;
  const Descriptor& q = *descs[i];
  const Descriptor& c = *descs[best];
  if (!q.valid || !c.valid) {
    m.outcome = "invalid descriptor: " + (q.valid ? c.invalid_reason : q.invalid_reason);
    return m;
  }
  PoseEstimate est;
  Verification ver;
  const bool ok = matchPair(q, c, params, &est, &ver).has_value();
  m.outcome = ok ? "accepted" : ver.reason();
  m.hypothesis_inliers = est.inliers_T.size();
  if (est.ok) m.hypothesis_err = poseError(trueTcq(ds, i, best), submapFramePose(q, c, est.T_c_q));
  m.ambiguity = ver.ambiguity;
  m.fit_ambiguity = ver.fit_ambiguity;
  m.pairs = static_cast<int>(ver.pairs.size());
  m.covisible_ratio = ver.covisible_ratio;
  m.aligned_overlap = ver.overlap;
  m.z_pairs = ver.z_pairs;
  m.ground_cells = ver.ground_cells;
  return m;
}

// An accepted loop of query i with candidate j (file positions) and its estimate T_c_q, scored.
void scoreAccepted(const Dataset& ds, const CellSets& cells, size_t i, size_t j, const Pose& T_c_q,
                   const EvalParams& eval, EvalRow* row) {
  row->candidate = ds.submaps[j].id;
  scoreAcceptedLoop(trueTcq(ds, i, j), T_c_q, cellOverlap(cells[i], cells[j]), eval, row);
}

// The position of submap `id` among the i submaps before i (file order).
size_t submapIndex(const Dataset& ds, size_t i, int64_t id) {
  size_t j = 0;
  while (j < i && ds.submaps[j].id != id) ++j;
  if (j == i) {
    throw std::logic_error("loop detector returned an unknown candidate id " + std::to_string(id));
  }
  return j;
}

void checkGroundTruth(const Dataset& ds) {
  for (const auto& rec : ds.submaps) {
    if (!ds.T_W_S.count(rec.id)) {
      throw DatasetError(ds.root + "/ground_truth.csv: no ground truth for submap " +
                         std::to_string(rec.id) + " (evaluation needs every submap's T_W_S)");
    }
  }
}

// Counts, precision/recall, mean errors and RMSE of the rows; times averaged over the rows.
EvalSummary summarize(const std::vector<EvalRow>& rows) {
  EvalSummary s;
  s.submaps = rows.size();
  PoseError sum_all, sum_tp;
  double sq_rot = 0.0, sq_trans = 0.0;
  auto accumulate = [](PoseError& acc, const PoseError& e) {
    acc.roll_deg += e.roll_deg;
    acc.pitch_deg += e.pitch_deg;
    acc.yaw_deg += e.yaw_deg;
    acc.rot_deg += e.rot_deg;
    acc.x_m += e.x_m;
    acc.y_m += e.y_m;
    acc.z_m += e.z_m;
    acc.trans_m += e.trans_m;
  };
  auto scaled = [](PoseError e, double k) {
    e.roll_deg *= k;
    e.pitch_deg *= k;
    e.yaw_deg *= k;
    e.rot_deg *= k;
    e.x_m *= k;
    e.y_m *= k;
    e.z_m *= k;
    e.trans_m *= k;
    return e;
  };
  for (const auto& r : rows) {
    s.queries_with_loop += r.has_loop;
    s.t_desc_ms += r.t_desc_ms;
    s.t_loop_ms += r.t_loop_ms;
    s.t_solver_ms += r.t_solver_ms;
    if (!r.accepted) continue;
    ++s.accepted;
    accumulate(sum_all, *r.err);
    sq_rot += r.err->rot_deg * r.err->rot_deg;
    sq_trans += r.err->trans_m * r.err->trans_m;
    if (r.true_positive) {
      ++s.true_positives;
      accumulate(sum_tp, *r.err);
    }
  }
  s.false_positives = s.accepted - s.true_positives;
  if (!rows.empty()) {
    const double n = static_cast<double>(rows.size());
    s.t_desc_ms /= n;
    s.t_loop_ms /= n;
    s.t_solver_ms /= n;
  }
  s.t_total_ms = s.t_desc_ms + s.t_loop_ms;
  if (s.accepted > 0) {
    const double k = 1.0 / static_cast<double>(s.accepted);
    s.precision = static_cast<double>(s.true_positives) * k;
    s.mean_err_all = scaled(sum_all, k);
    s.rmse_rot_deg = std::sqrt(sq_rot * k);
    s.rmse_trans_m = std::sqrt(sq_trans * k);
  }
  if (s.true_positives > 0) {
    s.mean_err_tp = scaled(sum_tp, 1.0 / static_cast<double>(s.true_positives));
  }
  if (s.queries_with_loop > 0) {
    s.recall = static_cast<double>(s.true_positives) / static_cast<double>(s.queries_with_loop);
  }
  return s;
}

}  // namespace

EvalSummary summarizeRows(const std::vector<EvalRow>& rows, const std::string& dataset,
                          double bytes_sum) {
  EvalSummary s = summarize(rows);
  s.dataset = dataset;
  if (!rows.empty()) s.descriptor_bytes_mean = bytes_sum / static_cast<double>(rows.size());
  return s;
}

namespace {

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) * kRadToDeg;
}

// The levelling the front end applied to a submap, scored against its ground-truth attitude.
LevellingRow levellingRow(const SubmapRecord& rec, const Leveller::Result& r, const Pose& T_W_S) {
  const Eigen::Vector3d z = Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d true_up_S = T_W_S.rotation().transpose() * z;
  const Eigen::Vector3d used_up_S = r.R_L_S.conjugate() * z;
  LevellingRow row;
  row.submap = rec.id;
  row.robot = rec.robot;
  row.true_tilt_deg = angleDeg(true_up_S, z);
  row.used_tilt_deg = angleDeg(used_up_S, z);
  row.error_deg = angleDeg(used_up_S, true_up_S);
  if (r.observation.ok) row.observation_error_deg = angleDeg(r.observation.up_S, true_up_S);
  row.sigma_deg = r.estimate.valid ? r.estimate.sigma_deg : -1.0;
  row.support_cells = r.observation.support_cells;
  row.from_ground = r.observation.from_ground;
  return row;
}

// The submap levelled by R_L_S and its ground-truth pose, for trunkDetection (trunks are in L).
DetectionRow levelledDetection(const Cloud& cloud_S, const Eigen::Quaterniond& R_L_S,
                               const Pose& T_W_S, const Trunks& trunks,
                               const std::vector<StemRecord>& stems) {
  if (R_L_S.coeffs() == Eigen::Quaterniond::Identity().coeffs()) {
    return trunkDetection(cloud_S, T_W_S, trunks, stems);
  }
  Pose T_W_L = T_W_S;
  T_W_L.linear() = T_W_S.rotation() * R_L_S.conjugate().toRotationMatrix();
  return trunkDetection(rotateCloud(cloud_S, R_L_S), T_W_L, trunks, stems);
}

}  // namespace

std::vector<LevellingSummary> summarizeLevelling(const std::vector<LevellingRow>& rows) {
  std::vector<LevellingSummary> out;
  for (const LevellingRow& r : rows) {
    auto it = std::find_if(out.begin(), out.end(),
                           [&](const LevellingSummary& s) { return s.robot == r.robot; });
    if (it == out.end()) {
      out.push_back(LevellingSummary{r.robot});
      it = out.end() - 1;
    }
    ++it->submaps;
    it->true_tilt_deg += r.true_tilt_deg;
    it->mean_error_deg += r.error_deg;
    it->max_error_deg = std::max(it->max_error_deg, r.error_deg);
    it->last_error_deg = r.error_deg;
    it->last_sigma_deg = r.sigma_deg;
  }
  for (LevellingSummary& s : out) {
    s.true_tilt_deg /= static_cast<double>(s.submaps);
    s.mean_error_deg /= static_cast<double>(s.submaps);
  }
  return out;
}

void writeLevellingCsv(const std::string& path, const std::vector<LevellingRow>& rows) {
  std::ofstream os(path);
  os << "submap,robot,true_tilt_deg,used_tilt_deg,error_deg,observation_error_deg,sigma_deg,"
        "support_cells,from_ground\n";
  os << std::setprecision(5);
  for (const LevellingRow& r : rows) {
    os << r.submap << ',' << r.robot << ',' << r.true_tilt_deg << ',' << r.used_tilt_deg << ','
       << r.error_deg << ',' << r.observation_error_deg << ',' << r.sigma_deg << ','
       << r.support_cells << ',' << int(r.from_ground) << '\n';
  }
  os.flush();
  if (!os) throw DatasetError(path + ": write failed");
}

std::string formatLevelling(const std::vector<LevellingSummary>& s) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(2)
     << "| Robot | Submaps | True tilt | Levelling error mean | max | last | Reported sigma |\n"
     << "|---|---|---|---|---|---|---|\n";
  for (const LevellingSummary& r : s) {
    os << "| " << r.robot << " | " << r.submaps << " | " << r.true_tilt_deg << " | "
       << r.mean_error_deg << " | " << r.max_error_deg << " | " << r.last_error_deg << " | "
       << r.last_sigma_deg << " |\n";
  }
  os << "(degrees; error = angle between the levelled frame's z and gravity, ground truth)\n";
  return os.str();
}

namespace {

// What runEvaluation carries from query to query.
struct EvalRun {
  CellSets cells;
  std::vector<std::shared_ptr<const Descriptor>> descs;  // every submap's, for explainMiss
  double bytes_sum = 0.0;
  size_t bytes_max = 0;
  size_t inter_robot_extra = 0, inter_robot_extra_true = 0;
};

// A query's row before scoring: its descriptor, extraction and times.
EvalRow describedRow(const SubmapRecord& rec, const FrontEndStep& step, bool levelling) {
  EvalRow row;
  row.query = rec.id;
  row.described_trunks = step.desc->trunks.size();
  row.described_submaps = step.accumulated.submaps;
  row.t_desc_ms = step.descMs(levelling);
  row.trunks = step.extraction.trunks.size();
  row.invalid_reason = step.desc->invalid_reason;
  row.t_loop_ms = step.loop_ms;
  row.t_solver_ms = step.query.solver_ms;
  return row;
}

// Scores query i's loop (and the inter-robot loop beside it) against ground truth; a missed
// true loop gets its explanation.
void scoreQuery(const Dataset& ds, const DtifParams& params, const EvalParams& eval, size_t i,
                const FrontEndStep& step, EvalRun* run, EvalRow* row, EvalResult* result) {
  row->has_loop = hasTrueLoop(ds, run->cells, i, params.loop.database.exclude_recent_s, eval);
  if (step.loop) {
    const Loop& loop = *step.loop;
    row->inliers = loop.inliers;
    row->score = loop.score;
    scoreAccepted(ds, run->cells, i, submapIndex(ds, i, loop.candidate_id), loop.T_c_q, eval, row);
  }
  run->descs.push_back(step.desc);
  if (row->has_loop && !row->true_positive) {
    result->misses.push_back(explainMiss(ds, run->cells, run->descs, i, step.query, params.loop));
  }
  if (step.inter_robot_loop) {
    EvalRow extra;
    scoreAccepted(ds, run->cells, i, submapIndex(ds, i, step.inter_robot_loop->candidate_id),
                  step.inter_robot_loop->T_c_q, eval, &extra);
    ++run->inter_robot_extra;
    run->inter_robot_extra_true += extra.true_positive;
  }
}

}  // namespace

EvalResult runEvaluation(const Dataset& ds, const DtifParams& params, const EvalParams& eval,
                         const std::function<void(size_t, size_t)>& progress,
                         const QueryObserver& on_query) {
  checkGroundTruth(ds);
  EvalResult result;
  SequentialFrontEnd front_end(params);
  EvalRun run;
  run.cells.reserve(ds.submaps.size());
  const size_t n = ds.submaps.size();
  for (size_t i = 0; i < n; ++i) {
    const SubmapRecord& rec = ds.submaps[i];
    const Pose& T_W_q = ds.T_W_S.at(rec.id);
    const Cloud::Ptr cloud = loadSubmapCloud(ds, rec);
    run.cells.push_back(overlapCells(*cloud, T_W_q));

    // 1.-3. Descriptor (timed: desc, levelling included), query against all earlier
    // descriptors (timed: loop; solver alone: solver).
    const FrontEndStep step = front_end.describeAndQuery(rec, *cloud);
    if (front_end.levelling()) result.levelling.push_back(levellingRow(rec, step.level, T_W_q));
    EvalRow row = describedRow(rec, step, front_end.levelling());
    if (!ds.stems.empty()) {
      result.detection.push_back(
          levelledDetection(*cloud, step.level.R_L_S, T_W_q, step.extraction.trunks, ds.stems));
      result.detection.back().submap = rec.id;
    }
    const size_t bytes = encodeDescriptor(*step.desc).size();
    run.bytes_sum += static_cast<double>(bytes);
    run.bytes_max = std::max(run.bytes_max, bytes);
    scoreQuery(ds, params, eval, i, step, &run, &row, &result);
    if (on_query) on_query(*step.desc, step.loop, step.inter_robot_loop);

    // 4. Insert q (and replace the entries it extended forward, here too).
    front_end.insert(step);
    for (const auto& u : step.updates) run.descs[submapIndex(ds, i, u->submap_id)] = u;
    row.forward_updates = step.updates.size();
    result.rows.push_back(std::move(row));
    if (progress) progress(i + 1, n);
  }

  result.summary = summarize(result.rows);
  result.summary.dataset = ds.root;
  if (n > 0) result.summary.descriptor_bytes_mean = run.bytes_sum / static_cast<double>(n);
  result.summary.descriptor_bytes_max = run.bytes_max;
  result.summary.inter_robot_extra = run.inter_robot_extra;
  result.summary.inter_robot_extra_true = run.inter_robot_extra_true;
  return result;
}

namespace {

// The dataset index of a robot's submap by its stamp (the nodelets number submaps their own way).
std::optional<size_t> submapAt(const Dataset& ds, const std::string& robot, double stamp) {
  constexpr double kStampTolS = 1e-3;
  for (size_t i = 0; i < ds.submaps.size(); ++i) {
    const SubmapRecord& r = ds.submaps[i];
    if (r.robot == robot && std::fabs(r.stamp - stamp) <= kStampTolS) return i;
  }
  return std::nullopt;
}

std::string describeSubmap(const std::string& robot, int64_t id, double stamp) {
  std::ostringstream os;
  os << robot << "/" << id << " (stamp " << std::fixed << std::setprecision(3) << stamp << ")";
  return os.str();
}

// Scores one row of the loop log into result->rows; logged marks the queries seen. Returns
// false, with the reason in `unmatched`, for a row that names no submap of the dataset or
// repeats a query.
bool scoreLogRow(const Dataset& ds, const CellSets& cells, const LoopLogRow& l,
                 const EvalParams& eval, std::vector<char>* logged, EvalResult* result,
                 std::vector<std::string>* unmatched) {
  const auto reject = [&](const std::string& why) {
    if (unmatched) unmatched->push_back(why);
    return false;
  };
  const std::string query = describeSubmap(l.query_robot, l.query_id, l.query_stamp);
  const std::optional<size_t> i = submapAt(ds, l.query_robot, l.query_stamp);
  if (!i) return reject("query " + query);
  if ((*logged)[*i]) return reject("repeated query " + query);
  (*logged)[*i] = 1;
  EvalRow& row = result->rows[*i];
  row.t_loop_ms = l.t_loop_ms;
  if (!l.accepted) return true;
  const std::optional<size_t> j = submapAt(ds, l.candidate_robot, l.candidate_stamp);
  if (!j) {
    reject("candidate " + describeSubmap(l.candidate_robot, l.candidate_id, l.candidate_stamp) +
           " of query " + query);
    return true;  // the query itself was logged
  }
  row.inliers = l.inliers;
  row.score = l.score;
  scoreAccepted(ds, cells, *i, *j, l.T_c_q, eval, &row);
  return true;
}

}  // namespace

EvalResult scoreLoopLog(const Dataset& ds, const std::vector<LoopLogRow>& log,
                        double exclude_recent_s, const EvalParams& eval,
                        std::vector<std::string>* unmatched) {
  checkGroundTruth(ds);
  CellSets cells;
  cells.reserve(ds.submaps.size());
  for (const SubmapRecord& rec : ds.submaps) {
    cells.push_back(overlapCells(*loadSubmapCloud(ds, rec), ds.T_W_S.at(rec.id)));
  }
  EvalResult result;
  result.rows.resize(ds.submaps.size());
  std::vector<char> logged(ds.submaps.size(), 0);
  double t_loop_sum = 0.0;
  size_t queried = 0;
  for (const LoopLogRow& l : log) {
    if (!scoreLogRow(ds, cells, l, eval, &logged, &result, unmatched)) continue;
    ++queried;
    t_loop_sum += l.t_loop_ms;
  }
  for (size_t i = 0; i < ds.submaps.size(); ++i) {
    result.rows[i].query = ds.submaps[i].id;
    result.rows[i].has_loop = hasTrueLoop(ds, cells, i, exclude_recent_s, eval);
  }
  result.summary = summarize(result.rows);
  result.summary.dataset = ds.root;
  result.summary.online = true;
  result.summary.t_loop_ms = queried > 0 ? t_loop_sum / static_cast<double>(queried) : 0.0;
  return result;
}

void writeResultsCsv(const std::string& path, const std::vector<EvalRow>& rows) {
  std::ofstream os(path);
  if (!os) throw DatasetError(path + ": cannot open file for writing");
  os << "query,candidate,accepted,true_loop,has_loop,overlap,err_roll_deg,err_pitch_deg,"
        "err_yaw_deg,err_rot_deg,err_x_m,err_y_m,err_z_m,err_trans_m,inliers,score,t_desc_ms,"
        "t_loop_ms,t_solver_ms,est_tx,est_ty,est_tz,est_qx,est_qy,est_qz,est_qw\n";
  os << std::setprecision(9);
  for (const auto& r : rows) {
    os << r.query << ',';
    if (r.candidate) os << *r.candidate;
    os << ',' << int(r.accepted) << ',' << int(r.true_loop) << ',' << int(r.has_loop) << ','
       << r.overlap << ',';
    if (r.err) {
      const PoseError& e = *r.err;
      os << e.roll_deg << ',' << e.pitch_deg << ',' << e.yaw_deg << ',' << e.rot_deg << ',' << e.x_m
         << ',' << e.y_m << ',' << e.z_m << ',' << e.trans_m << ',';
    } else {
      os << ",,,,,,,,";
    }
    os << r.inliers << ',' << r.score << ',' << r.t_desc_ms << ',' << r.t_loop_ms << ','
       << r.t_solver_ms << ',';
    if (r.T_c_q_est) {
      const Eigen::Quaterniond q(r.T_c_q_est->rotation());
      const Eigen::Vector3d t = r.T_c_q_est->translation();
      os << t.x() << ',' << t.y() << ',' << t.z() << ',' << q.x() << ',' << q.y() << ',' << q.z()
         << ',' << q.w();
    } else {
      os << ",,,,,,";
    }
    os << '\n';
  }
  os.close();
  if (!os) throw DatasetError(path + ": write failed");
}

namespace {

nlohmann::json errJson(const std::optional<PoseError>& e) {
  nlohmann::json j;
  const char* keys[] = {"roll_deg", "pitch_deg", "yaw_deg", "rot_deg",
                        "x_m",      "y_m",       "z_m",     "trans_m"};
  if (!e) {
    for (const char* k : keys) j[k] = nullptr;
    return j;
  }
  const double v[] = {e->roll_deg, e->pitch_deg, e->yaw_deg, e->rot_deg,
                      e->x_m,      e->y_m,       e->z_m,     e->trans_m};
  for (int i = 0; i < 8; ++i) j[keys[i]] = v[i];
  return j;
}

nlohmann::json optJson(const std::optional<double>& v) {
  return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

std::string fmt(const std::optional<double>& v, int prec = 3) {
  if (!v) return "-";
  std::ostringstream ss;
  ss << std::fixed << std::setprecision(prec) << *v;
  return ss.str();
}

}  // namespace

void writeSummaryJson(const std::string& path, const EvalSummary& s) {
  nlohmann::ordered_json j;
  j["dataset"] = s.dataset;
  j["submaps"] = s.submaps;
  j["queries_with_loop"] = s.queries_with_loop;
  j["accepted"] = s.accepted;
  j["true_positives"] = s.true_positives;
  j["false_positives"] = s.false_positives;
  j["precision"] = optJson(s.precision);
  j["recall"] = optJson(s.recall);
  j["mean_err_all"] = errJson(s.mean_err_all);
  j["mean_err_tp"] = errJson(s.mean_err_tp);
  j["rmse_rot_deg"] = optJson(s.rmse_rot_deg);
  j["rmse_trans_m"] = optJson(s.rmse_trans_m);
  // An online run's log has query times only.
  const auto offline = [&](double v) {
    return s.online ? nlohmann::json(nullptr) : nlohmann::json(v);
  };
  j["time_ms"] = {{"desc", offline(s.t_desc_ms)},
                  {"loop", s.t_loop_ms},
                  {"solver", offline(s.t_solver_ms)},
                  {"total", offline(s.t_total_ms)}};
  j["descriptor_bytes_mean"] = offline(s.descriptor_bytes_mean);
  std::ofstream os(path);
  if (!os) throw DatasetError(path + ": cannot open file for writing");
  os << j.dump(2) << '\n';
  os.close();
  if (!os) throw DatasetError(path + ": write failed");
}

std::string formatTable(const EvalSummary& s, const std::string& method) {
  const auto& e = s.mean_err_all;
  auto f = [&](double PoseError::*m) { return e ? fmt((*e).*m) : std::string("-"); };
  // An online run's log has query times only.
  auto offline = [&](double v) { return s.online ? std::nullopt : std::optional<double>(v); };
  std::ostringstream os;
  os << "| Method | Roll | Pitch | Yaw | Rot. | X | Y | Z | Trans. | RMSE-R | RMSE-T | Desc. ms"
        " | Loop ms | Total ms | Solver ms | Precision | Recall | TP/Acc./Loops | Bytes |\n"
     << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  os << "| " << method << " | " << f(&PoseError::roll_deg) << " | " << f(&PoseError::pitch_deg)
     << " | " << f(&PoseError::yaw_deg) << " | " << f(&PoseError::rot_deg) << " | "
     << f(&PoseError::x_m) << " | " << f(&PoseError::y_m) << " | " << f(&PoseError::z_m) << " | "
     << f(&PoseError::trans_m) << " | " << fmt(s.rmse_rot_deg) << " | " << fmt(s.rmse_trans_m)
     << " | " << fmt(offline(s.t_desc_ms)) << " | " << fmt(s.t_loop_ms) << " | "
     << fmt(offline(s.t_total_ms)) << " | " << fmt(offline(s.t_solver_ms)) << " | "
     << fmt(s.precision) << " | " << fmt(s.recall) << " | " << s.true_positives << "/" << s.accepted
     << "/" << s.queries_with_loop << " | " << fmt(offline(s.descriptor_bytes_mean), 0) << " |\n";
  os << "(errors in deg and m, averaged over all accepted loops as in the paper; " << s.submaps
     << " submaps)\n";
  return os.str();
}

}  // namespace dtif
