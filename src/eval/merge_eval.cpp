#include "dtif/eval/merge_eval.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <tuple>

#include "dtif/core/timing.h"
#include "dtif/eval/front_end.h"

namespace dtif {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

bool hasGroundTruth(const Dataset& ds) {
  for (const auto& rec : ds.submaps) {
    if (!ds.T_W_S.count(rec.id)) return false;
  }
  return !ds.submaps.empty();
}

MergeSubmap toMergeSubmap(const SubmapRecord& rec, const Descriptor& desc) {
  MergeSubmap s = mergeSubmapOf(desc, rec.T_O_S);
  s.robot = rec.robot;
  s.id = rec.id;
  s.stamp = rec.stamp;
  return s;
}

/// The protocol's steps 1-4 without ground truth (nothing to score), through the same front end
/// as runEvaluation: levelled and accumulated per robot alike.
void sequentialLoopsUnscored(const Dataset& ds, const DtifParams& params,
                             const std::function<void(size_t, size_t)>& progress,
                             const QueryObserver& on_query) {
  SequentialFrontEnd front_end(params);
  for (size_t i = 0; i < ds.submaps.size(); ++i) {
    const SubmapRecord& rec = ds.submaps[i];
    const FrontEndStep step = front_end.describeAndQuery(rec, *loadSubmapCloud(ds, rec));
    on_query(*step.desc, step.loop, step.inter_robot_loop);
    front_end.insert(step);
    if (progress) progress(i + 1, ds.submaps.size());
  }
}

double rms(const std::vector<double>& v) {
  if (v.empty()) return 0.0;
  double s = 0.0;
  for (double x : v) s += x * x;
  return std::sqrt(s / v.size());
}

struct Residuals {
  std::vector<double> pos, rot_deg;
  TrajectoryScore score() const { return {pos.size(), rms(pos), rms(rot_deg)}; }
  void add(const Residuals& o) {
    pos.insert(pos.end(), o.pos.begin(), o.pos.end());
    rot_deg.insert(rot_deg.end(), o.rot_deg.begin(), o.rot_deg.end());
  }
};

/// Aligns estimated poses to ground truth (positions, least squares) and returns per-submap
/// residuals; fewer than 3 submaps: aligned on the first submap's pose.
Pose alignPoses(const std::vector<Pose>& est, const std::vector<Pose>& gt) {
  if (est.size() < 3) return gt.front() * est.front().inverse();
  std::vector<Eigen::Vector3d> a, b;
  for (size_t i = 0; i < est.size(); ++i) {
    a.push_back(est[i].translation());
    b.push_back(gt[i].translation());
  }
  return alignRigid(a, b);
}

Residuals residuals(const std::vector<Pose>& est, const std::vector<Pose>& gt, const Pose& T_W_M) {
  Residuals r;
  for (size_t i = 0; i < est.size(); ++i) {
    const Pose T = T_W_M * est[i];
    r.pos.push_back((T.translation() - gt[i].translation()).norm());
    r.rot_deg.push_back(Eigen::AngleAxisd(gt[i].linear().transpose() * T.linear()).angle() *
                        kRadToDeg);
  }
  return r;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t h = v.size() / 2;
  return v.size() % 2 ? v[h] : 0.5 * (v[h - 1] + v[h]);
}

StemScore scoreStems(const Dataset& ds, const std::vector<MergedStem>& stems,
                     const std::map<int, Pose>& T_W_M, double radius) {
  StemScore s;
  std::vector<int> hits(ds.stems.size(), 0);
  std::vector<double> pos_err, dbh_err;
  for (const MergedStem& m : stems) {
    auto it = T_W_M.find(m.component);
    if (it == T_W_M.end()) continue;
    ++s.listed;
    const Eigen::Vector3d p = it->second * Eigen::Vector3d(m.x, m.y, m.z_base);
    size_t best = ds.stems.size();
    double best_d = radius;
    for (size_t j = 0; j < ds.stems.size(); ++j) {
      const double d = std::hypot(p.x() - ds.stems[j].x, p.y() - ds.stems[j].y);
      if (d < best_d) {
        best_d = d;
        best = j;
      }
    }
    if (best == ds.stems.size()) continue;
    ++s.matched;
    ++hits[best];
    pos_err.push_back(best_d);
    dbh_err.push_back(std::fabs(m.dbh - ds.stems[best].dbh));
  }
  constexpr double kRangeM = 10.0;
  for (size_t j = 0; j < ds.stems.size(); ++j) {
    if (hits[j] > 1) s.duplicates += hits[j] - 1;
    bool in_range = false;
    for (const auto& [id, T] : ds.T_W_S) {
      if (std::hypot(T.translation().x() - ds.stems[j].x, T.translation().y() - ds.stems[j].y) <=
          kRangeM) {
        in_range = true;
        break;
      }
    }
    if (!in_range) continue;
    ++s.true_in_range;
    if (hits[j] > 0) ++s.found;
  }
  if (s.listed) s.precision = static_cast<double>(s.matched) / s.listed;
  if (s.true_in_range) s.recall = static_cast<double>(s.found) / s.true_in_range;
  if (s.matched) s.duplicate_rate = static_cast<double>(s.duplicates) / s.matched;
  double sum = 0.0;
  for (double e : pos_err) sum += e;
  if (!pos_err.empty()) s.mean_pos_err_m = sum / pos_err.size();
  s.median_dbh_err_m = median(dbh_err);
  return s;
}

}  // namespace

std::vector<MergedStem> refitStemDbh(const Dataset& ds, const std::vector<MergedPose>& poses,
                                     const std::vector<MergedStem>& stems,
                                     const StemFusionParams& params, StemSliceStats* stats) {
  std::map<int64_t, const MergedPose*> pose_of;
  for (const MergedPose& p : poses) pose_of[p.id] = &p;
  StemSlices slices(stems, params);
  for (const SubmapRecord& rec : ds.submaps) {  // one cloud in memory at a time
    auto it = pose_of.find(rec.id);
    if (it == pose_of.end()) continue;
    slices.addSubmap(it->second->component, it->second->T_M_S, *loadSubmapCloud(ds, rec));
  }
  return slices.refit(stats);
}

MergeInput collectMergeInput(const Dataset& ds, const DtifParams& params, const EvalParams& eval,
                             const std::function<void(size_t, size_t)>& progress) {
  MergeInput in;
  std::map<int64_t, size_t> row_of;
  for (size_t i = 0; i < ds.submaps.size(); ++i) row_of[ds.submaps[i].id] = i;
  const QueryObserver collect = [&](const Descriptor& desc, const std::optional<Loop>& loop,
                                    const std::optional<Loop>& inter_robot_loop) {
    const size_t i = in.submaps.size();
    in.submaps.push_back(toMergeSubmap(ds.submaps.at(i), desc));
    if (desc.levelled()) {
      in.levelling[desc.robot] =
          levellingInOdom(desc.level_rotation.toRotationMatrix(), in.submaps.back().T_O_S);
    }
    for (const std::optional<Loop>* l : {&loop, &inter_robot_loop}) {
      if (!*l) continue;
      in.loops.push_back(**l);
      in.loop_after.push_back(i);
    }
    in.inter_robot_extra += inter_robot_loop.has_value();
  };
  if (hasGroundTruth(ds)) {
    in.eval = runEvaluation(ds, params, eval, progress, collect);
  } else {
    sequentialLoopsUnscored(ds, params, progress, collect);
  }
  return in;
}

namespace {

bool between(const Loop& l, const std::string& a, const std::string& b) {
  return (l.query_robot == a && l.candidate_robot == b) ||
         (l.query_robot == b && l.candidate_robot == a);
}

/// The two robots (in submap order) with the fewest inter-robot loops between them; ties: the
/// first pair in that order. Empty with fewer than two robots.
std::pair<std::string, std::string> weakestPair(const MergeInput& in) {
  std::vector<std::string> robots;
  for (const MergeSubmap& s : in.submaps) {
    if (std::find(robots.begin(), robots.end(), s.robot) == robots.end()) robots.push_back(s.robot);
  }
  std::pair<std::string, std::string> best;
  size_t fewest = std::numeric_limits<size_t>::max();
  for (size_t i = 0; i < robots.size(); ++i) {
    for (size_t j = i + 1; j < robots.size(); ++j) {
      const size_t n =
          static_cast<size_t>(std::count_if(in.loops.begin(), in.loops.end(), [&](const Loop& l) {
            return between(l, robots[i], robots[j]);
          }));
      if (n < fewest) fewest = n, best = {robots[i], robots[j]};
    }
  }
  return best;
}

}  // namespace

void dropLoopsBetween(MergeInput* in, const std::string& a, const std::string& b) {
  std::vector<Loop> loops;
  std::vector<size_t> after;
  for (size_t k = 0; k < in->loops.size(); ++k) {
    if (between(in->loops[k], a, b)) continue;
    loops.push_back(in->loops[k]);
    after.push_back(in->loop_after[k]);
  }
  in->loops = std::move(loops);
  in->loop_after = std::move(after);
}

std::optional<Loop> makeFalseLoop(const Dataset& ds, const MergeInput& in, FalseLoopPair pair) {
  // Between the robots of the first inter-robot loop (so that PCM has loops to compare it with),
  // else the first two robots; or between the weakest-linked pair.
  std::string ra, rb;
  if (pair == FalseLoopPair::kWeakest) std::tie(ra, rb) = weakestPair(in);
  for (const Loop& l : in.loops) {
    if (!ra.empty()) break;
    if (l.query_robot != l.candidate_robot) {
      ra = l.candidate_robot;
      rb = l.query_robot;
      break;
    }
  }
  if (ra.empty()) {
    for (const MergeSubmap& s : in.submaps) {
      if (ra.empty()) ra = s.robot;
      if (s.robot != ra) {
        rb = s.robot;
        break;
      }
    }
  }
  if (rb.empty()) return std::nullopt;
  const bool gt = hasGroundTruth(ds);
  auto position = [&](const MergeSubmap& s) {
    return gt ? ds.T_W_S.at(s.id).translation() : s.T_O_S.translation();
  };
  const MergeSubmap* best_c = nullptr;
  const MergeSubmap* best_q = nullptr;
  double best_d = -1.0;
  for (const MergeSubmap& c : in.submaps) {
    if (c.robot != ra) continue;
    for (const MergeSubmap& q : in.submaps) {
      if (q.robot != rb || q.stamp <= c.stamp) continue;
      const double d = (position(c) - position(q)).norm();
      if (d > best_d) {
        best_d = d;
        best_c = &c;
        best_q = &q;
      }
    }
  }
  if (!best_c) return std::nullopt;
  Loop l;
  l.query_robot = rb;
  l.query_id = best_q->id;
  l.candidate_robot = ra;
  l.candidate_id = best_c->id;
  // A plausible wrong answer: a few metres and a quarter turn, as an aliased trunk pattern gives.
  l.T_c_q = Pose::Identity();
  l.T_c_q.linear() = rotZ(0.4);
  l.T_c_q.translation() << 3.0, -2.0, 0.0;
  l.inliers = 12;
  l.score = 0.9;
  if (!in.loops.empty()) {
    l.covariance = in.loops.front().covariance;
    for (const Loop& t : in.loops) l.inliers = std::max(l.inliers, t.inliers);
  }
  return l;
}

MapMerger runMerger(const MergeInput& in, const MergeParams& params,
                    const std::optional<Loop>& false_loop, const std::vector<FieldStem>& stem_map,
                    std::vector<MergeEvent>* events, MergeRunStats* stats, bool false_loop_first) {
  MapMerger merger(params);
  if (!stem_map.empty()) merger.setStemMap(stem_map);
  for (const auto& [robot, R_L_O] : in.levelling) merger.setLevelling(robot, R_L_O);
  MergeRunStats st;
  auto solve = [&]() {
    const auto t0 = std::chrono::steady_clock::now();
    st.last = merger.solve();
    const double ms = msSince(t0);
    ++st.solves;
    st.iterative_solves += st.last.iterative ? 1 : 0;
    st.solve_ms_total += ms;
    st.solve_ms_max = std::max(st.solve_ms_max, ms);
    auto ev = merger.takeEvents();
    if (events) events->insert(events->end(), ev.begin(), ev.end());
  };
  // The false loop arrives half way through the loops (or with the first): early enough to
  // bend the map if the back end let it; later when one of its submaps has not arrived yet.
  const size_t false_at = false_loop_first ? 0 : in.loops.size() / 2;
  bool false_pending = false_loop.has_value();
  size_t k = 0;
  for (size_t i = 0; i < in.submaps.size(); ++i) {
    merger.addSubmap(in.submaps[i]);
    bool any = false;
    for (; k < in.loops.size() && in.loop_after[k] == i; ++k) {
      any = merger.addLoop(in.loops[k]) || any;
    }
    if (false_pending && (k > false_at || in.loops.empty()) && merger.addLoop(*false_loop)) {
      false_pending = false;
      any = true;
    }
    if (any) solve();
  }
  solve();
  // The final map: refined with the trunks as landmarks (not part of the re-solve times).
  const auto t0 = std::chrono::steady_clock::now();
  st.last = merger.refine();
  st.refine_ms = msSince(t0);
  auto ev = merger.takeEvents();  // a component joined by its inventory (refine)
  if (events) events->insert(events->end(), ev.begin(), ev.end());
  if (stats) *stats = st;
  return merger;
}

Pose alignRigid(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to) {
  Eigen::Matrix3Xd a(3, from.size()), b(3, to.size());
  for (size_t i = 0; i < from.size(); ++i) {
    a.col(i) = from[i];
    b.col(i) = to[i];
  }
  Pose T = Pose::Identity();
  T.matrix() = Eigen::umeyama(a, b, false);
  return T;
}

MergeScore scoreMerge(const Dataset& ds, const std::vector<MergedPose>& poses,
                      const std::vector<MergedStem>& stems, double match_radius_m) {
  if (!hasGroundTruth(ds)) {
    throw DatasetError(ds.root + "/ground_truth.csv: scoring a merge needs every submap's T_W_S");
  }
  MergeScore s;
  std::map<int, std::vector<const MergedPose*>> by_comp;
  for (const MergedPose& p : poses) by_comp[p.component].push_back(&p);
  for (const auto& [comp, list] : by_comp) {
    std::vector<Pose> est, gt;
    for (const MergedPose* p : list) {
      est.push_back(p->T_M_S);
      gt.push_back(ds.T_W_S.at(p->id));
    }
    const Pose T_W_M = alignPoses(est, gt);
    s.T_W_M[comp] = T_W_M;
    const Residuals r = residuals(est, gt, T_W_M);
    s.component[comp] = r.score();
    std::map<std::string, Residuals> per_robot;
    for (size_t i = 0; i < list.size(); ++i) {
      per_robot[list[i]->robot].pos.push_back(r.pos[i]);
      per_robot[list[i]->robot].rot_deg.push_back(r.rot_deg[i]);
    }
    for (const auto& [robot, rr] : per_robot) s.robot[robot] = rr.score();
  }
  // Baseline: each robot's odometry aligned on its own.
  std::map<std::string, std::vector<const SubmapRecord*>> by_robot;
  for (const SubmapRecord& rec : ds.submaps) by_robot[rec.robot].push_back(&rec);
  Residuals all;
  for (const auto& [robot, list] : by_robot) {
    std::vector<Pose> est, gt;
    for (const SubmapRecord* rec : list) {
      est.push_back(rec->T_O_S);
      gt.push_back(ds.T_W_S.at(rec->id));
    }
    const Residuals r = residuals(est, gt, alignPoses(est, gt));
    s.odometry[robot] = r.score();
    all.add(r);
  }
  s.odometry_all = all.score();
  if (!ds.stems.empty()) s.stems = scoreStems(ds, stems, s.T_W_M, match_radius_m);
  return s;
}

namespace {

nlohmann::json trajectoryJson(const TrajectoryScore& t) {
  return {{"submaps", t.submaps}, {"ate_m", t.ate_m}, {"rot_rms_deg", t.rot_rms_deg}};
}

nlohmann::json scoreJson(const MergeScore& s) {
  nlohmann::json j;
  for (const auto& [c, t] : s.component) j["component"][std::to_string(c)] = trajectoryJson(t);
  for (const auto& [r, t] : s.robot) j["robot"][r] = trajectoryJson(t);
  for (const auto& [r, t] : s.odometry) j["odometry_only"][r] = trajectoryJson(t);
  j["odometry_only_all"] = trajectoryJson(s.odometry_all);
  const StemScore& st = s.stems;
  j["stems"] = {{"listed", st.listed},
                {"matched", st.matched},
                {"true_in_range", st.true_in_range},
                {"found", st.found},
                {"duplicates", st.duplicates},
                {"precision", st.precision},
                {"recall", st.recall},
                {"duplicate_rate", st.duplicate_rate},
                {"mean_pos_err_m", st.mean_pos_err_m},
                {"median_dbh_err_m", st.median_dbh_err_m}};
  return j;
}

}  // namespace

void writeMergeSummaryJson(const std::string& path, const MergeSummary& s) {
  nlohmann::json j;
  j["dataset"] = s.dataset;
  j["submaps"] = s.submaps;
  j["robots"] = s.robots;
  j["components"] = s.components;
  j["robot_component"] = s.robot_component;
  j["loops_accepted"] = s.loops_accepted;
  j["loops_used"] = s.loops_used;
  j["loops_rejected"] = s.loops_rejected;
  j["inter_robot_loops_used"] = s.inter_robot_used;
  j["inter_robot_loops_rejected"] = s.inter_robot_rejected;
  j["stems"] = s.stems;
  j["solves"] = s.run.solves;
  j["solve_ms_mean"] = s.run.solves ? s.run.solve_ms_total / s.run.solves : 0.0;
  j["solve_ms_max"] = s.run.solve_ms_max;
  j["solves_iterative"] = s.run.iterative_solves;
  j["landmark_refinement_ms"] = s.run.refine_ms;
  j["landmarks"] = s.run.last.landmarks;
  j["landmark_observations"] = s.run.last.landmark_observations;
  if (s.stem_slices) {
    const StemSliceStats& q = *s.stem_slices;
    j["stem_dbh_from_points"] = {{"stems", q.stems},
                                 {"refitted", q.refitted},
                                 {"too_few", q.too_few},
                                 {"one_sided", q.one_sided},
                                 {"no_fit", q.no_fit},
                                 {"shrunk", q.shrunk},
                                 {"blended", q.blended},
                                 {"enclosing", q.enclosing},
                                 {"points", q.points},
                                 {"submap_views", q.submap_views},
                                 {"aligned_submaps", q.alignment.views},
                                 {"aligned_on_stems", q.alignment.stems},
                                 {"alignment_max_shift_m", q.alignment.max_shift_m},
                                 {"ms", s.stem_slices_ms}};
  }
  j["false_loop_injected"] = s.false_loop_injected;
  if (s.false_loop_injected) {
    j["false_loop_used"] = s.false_loop_used;
    j["false_loop_added"] = s.false_loop_added;
  }
  j["score"] = s.score ? scoreJson(*s.score) : nlohmann::json(nullptr);
  if (s.score_clean) j["score_without_false_loop"] = scoreJson(*s.score_clean);
  if (s.stem_map) {
    const StemMapRegistration& r = *s.stem_map;
    j["stem_map"] = {{"field_stems", s.stem_map_field_stems},
                     {"registered", r.ok},
                     {"reason", r.reason},
                     {"pairs", r.pairs.size()},
                     {"rms_m", r.rms_m},
                     {"median_m", r.median_m}};
  }
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << j.dump(2) << "\n";
    out.flush();
    if (!out) {
      std::remove(tmp.c_str());
      throw DatasetError(path + ": cannot write " + tmp);
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw DatasetError(path + ": cannot rename " + tmp + " to it");
  }
}

std::string formatMergeTable(const MergeScore& s) {
  std::ostringstream os;
  os << std::fixed;
  os << "component  submaps  ATE [m]  rot [deg]\n";
  for (const auto& [c, t] : s.component) {
    os << std::setw(9) << c << std::setw(9) << t.submaps << std::setprecision(3) << std::setw(9)
       << t.ate_m << std::setprecision(2) << std::setw(11) << t.rot_rms_deg << '\n';
  }
  os << "robot        submaps  ATE [m]  rot [deg]  odometry-only ATE [m]  rot [deg]\n";
  for (const auto& [r, t] : s.robot) {
    const TrajectoryScore& o = s.odometry.at(r);
    os << std::left << std::setw(12) << r << std::right << std::setw(8) << t.submaps
       << std::setprecision(3) << std::setw(9) << t.ate_m << std::setprecision(2) << std::setw(11)
       << t.rot_rms_deg << std::setprecision(3) << std::setw(23) << o.ate_m << std::setprecision(2)
       << std::setw(11) << o.rot_rms_deg << '\n';
  }
  os << std::setprecision(3) << "odometry only, all robots (each aligned alone): ATE "
     << s.odometry_all.ate_m << " m, rot " << std::setprecision(2) << s.odometry_all.rot_rms_deg
     << " deg\n";
  const StemScore& st = s.stems;
  if (st.listed || st.true_in_range) {
    os << std::setprecision(3) << "stems: listed " << st.listed << ", matched " << st.matched
       << ", precision " << st.precision << ", recall " << st.recall << " (" << st.found << "/"
       << st.true_in_range << "), duplicates " << st.duplicates << " (" << std::setprecision(1)
       << 100.0 * st.duplicate_rate << " %), mean position error " << std::setprecision(3)
       << st.mean_pos_err_m << " m, median DBH error " << std::setprecision(1)
       << 100.0 * st.median_dbh_err_m << " cm\n";
  }
  return os.str();
}

}  // namespace dtif
