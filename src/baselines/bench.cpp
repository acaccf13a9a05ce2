// Benchmark against the paper's baselines (see bench.h).
#include "dtif/baselines/bench.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <numeric>
#include <random>
#include <sstream>
#include <stdexcept>
#include <unordered_set>

#include "dtif/baselines/solvers.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/describe.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/timing.h"

namespace dtif::baselines {
namespace {

using Clock = std::chrono::steady_clock;

std::string displayName(const std::string& back_end) {
  if (back_end == "dtif") return "dtif (weighted)";
  if (back_end == "dtif_unit") return "dtif w/o W (unit weights)";
  if (back_end == "quatro") return "Quatro-like";
  if (back_end == "svd_ransac") return "SVD-RANSAC 6-DoF";
  if (back_end == "fgr") return "FGR";
  return back_end;
}

/// A registered pair of a front-end run: which candidate, with how many inliers, where.
struct PairResult {
  size_t j = 0;
  bool accepted = false;
  double rank = 0.0;  ///< the better of two accepted pairs wins (score or inliers)
  int inliers = 0;
  Pose T = Pose::Identity();
};

}  // namespace

PrPoint prPoint(const std::string& method, double threshold, size_t accepted, size_t true_positives,
                size_t loops) {
  PrPoint p{method, threshold, accepted, true_positives};
  p.precision = accepted ? static_cast<double>(true_positives) / accepted : 1.0;
  p.recall = loops ? static_cast<double>(true_positives) / loops : 0.0;
  return p;
}

PoseSolver makeBackEnd(const std::string& name, const PoseEstimatorParams& pose) {
  if (name == "dtif" || name == "dtif_unit") return {};
  if (name == "quatro") {
    QuatroParams p;
    p.beta_m = pose.beta_yaw_m;
    p.gnc_factor = pose.gnc_factor;
    p.gnc_max_iterations = pose.gnc_max_iterations;
    p.max_tim_pairs = pose.max_tim_pairs;
    return [p](const std::vector<Correspondence>& c) { return quatroLike(c, p); };
  }
  if (name == "svd_ransac") {
    RansacParams p;
    p.inlier_m = pose.beta_xy_m;
    return [p](const std::vector<Correspondence>& c) { return svdRansac(c, p); };
  }
  if (name == "fgr") {
    FgrParams p;
    p.final_scale_m = pose.beta_xy_m;
    return [p](const std::vector<Correspondence>& c) { return fastGlobalRegistration(c, p); };
  }
  throw std::invalid_argument("unknown back end '" + name +
                              "' (dtif, dtif_unit, quatro, svd_ransac, fgr)");
}

namespace {

/// A scene described once, with the ground truth of its pairs: what every stage of the bench
/// reads, so that each method runs on the same descriptors, features and pairs. Lives within
/// one runSceneBench call: it refers to that call's arguments.
struct SceneData {
  SceneData(const Dataset& ds, const DtifParams& params, const BenchOptions& options,
            const std::function<void(const std::string&)>& progress)
      : ds(ds),
        params(params),
        options(options),
        progress(progress),
        n(ds.submaps.size()),
        cells(n),
        descs(n),
        feats(n),
        scs(n),
        base(n),
        overlap(n, std::vector<double>(n, -1.0)) {}

  void say(const std::string& s) const {
    if (progress) progress(s);
  }
  /// Ground truth T_c_q of query i against candidate j.
  Pose gtPose(size_t i, size_t j) const {
    return ds.T_W_S.at(ds.submaps[j].id).inverse() * ds.T_W_S.at(ds.submaps[i].id);
  }
  /// The index of a candidate a detector answered, among the submaps before the query.
  size_t indexOf(int64_t id, size_t before) const {
    for (size_t j = 0; j < before; ++j) {
      if (ds.submaps[j].id == id) return j;
    }
    throw std::logic_error("unknown candidate id " + std::to_string(id));
  }

  const Dataset& ds;
  const DtifParams& params;
  const BenchOptions& options;
  const std::function<void(const std::string&)>& progress;
  const size_t n;
  std::vector<std::unordered_set<int64_t>> cells;  ///< ground-truth cells of each submap
  std::vector<std::shared_ptr<Descriptor>> descs;
  std::vector<FpfhFeaturesPtr> feats;
  std::vector<ScanContext> scs;
  std::vector<EvalRow> base;  ///< each method's rows start as these: ground truth, no answer
  std::vector<std::vector<double>> overlap;  ///< [query][candidate]; -1: ineligible pair
  double bytes_sum = 0.0, fpfh_bytes_sum = 0.0, sc_bytes_sum = 0.0;  ///< summed over submaps
};

/// Describes submap i for every method (dtif, and the FPFH and scan-context baselines when
/// they run), timing each front-end stage; the cloud is loaded once for all of them.
void describeSubmap(size_t i, SceneData* d, SceneBench* out) {
  const Dataset& ds = d->ds;
  const BenchOptions& options = d->options;
  const SubmapRecord& rec = ds.submaps[i];
  if (!ds.T_W_S.count(rec.id)) {
    throw DatasetError(ds.root + ": no ground truth for submap " + std::to_string(rec.id));
  }
  d->say("describing " + std::to_string(i + 1) + "/" + std::to_string(d->n));
  const Cloud::Ptr cloud = loadSubmapCloud(ds, rec);
  d->cells[i] = overlapCells(*cloud, ds.T_W_S.at(rec.id));
  SubmapStats st;
  st.id = rec.id;
  st.points = cloud->size();
  TrunkExtractionResult ext;
  DescribeTimings timings;
  d->descs[i] = std::make_shared<Descriptor>(describeCloud(*cloud, {rec.robot, rec.id, rec.stamp},
                                                           d->params.trunk_extraction,
                                                           d->params.descriptor, &timings, &ext));
  st.t_extract_ms = timings.extract_ms;
  st.t_desc_ms = timings.total_ms;
  st.trunks = ext.trunks.size();
  st.bytes = encodeDescriptor(*d->descs[i]).size();
  d->bytes_sum += static_cast<double>(st.bytes);
  if (options.front_ends) {
    const auto t0 = Clock::now();
    d->feats[i] = computeFpfh(*cloud, options.fpfh);
    st.t_fpfh_ms = msSince(t0);
    st.fpfh_points = fpfhPoints(*d->feats[i]);
    d->fpfh_bytes_sum += static_cast<double>(fpfhBytes(*d->feats[i]));
  }
  if (options.place_recognition) {
    const auto t0 = Clock::now();
    d->scs[i] = makeScanContext(*cloud, options.scan_context);
    st.t_scan_context_ms = msSince(t0);
    d->sc_bytes_sum += static_cast<double>(d->scs[i].bytes());
  }
  if (d->descs[i]->valid) out->descriptors.push_back(d->descs[i]);
  EvalRow& row = d->base[i];
  row.query = rec.id;
  row.trunks = st.trunks;
  row.t_desc_ms = st.t_desc_ms;
  row.invalid_reason = d->descs[i]->invalid_reason;
  out->submaps.push_back(st);
}

/// Ground truth of every eligible pair (DATASET.md), and which queries have a true loop.
void scoreGroundTruth(SceneData* d) {
  const double exclude_s = d->params.loop.database.exclude_recent_s;
  for (size_t i = 0; i < d->n; ++i) {
    for (size_t j = 0; j < i; ++j) {
      if (!eligiblePair(d->ds.submaps[i], d->ds.submaps[j], exclude_s)) continue;
      d->overlap[i][j] = cellOverlap(d->cells[i], d->cells[j]);
      d->base[i].has_loop =
          d->base[i].has_loop || d->overlap[i][j] >= d->options.eval.true_loop_overlap;
    }
  }
}

/// One back end on the sequential protocol with dtif's correspondences. The solver's own pose
/// and the pose after dtif's guided refinement are scored separately (two runs).
void runBackEnd(const SceneData& d, const std::string& name, SceneBench* out) {
  d.say("back end " + name);
  LoopDetectorParams lp = d.params.loop;
  if (name == "dtif_unit") lp.pose.unit_weights = true;
  LoopDetector det(lp);
  det.setSolver(makeBackEnd(name, lp.pose));
  std::vector<EvalRow> raw = d.base, refined = d.base;
  for (size_t i = 0; i < d.n; ++i) {
    QueryStats qs;
    const auto t0 = Clock::now();
    const std::optional<Loop> lc = det.query(*d.descs[i], &qs);
    const double t_loop = msSince(t0);
    for (EvalRow* r : {&raw[i], &refined[i]}) {
      r->t_loop_ms = t_loop;
      r->t_solver_ms = qs.solver_ms;
      if (!lc) continue;
      const size_t j = d.indexOf(lc->candidate_id, i);
      r->candidate = lc->candidate_id;
      r->inliers = lc->inliers;
      r->score = lc->score;
      scoreAcceptedLoop(d.gtPose(i, j), r == &raw[i] ? lc->T_hypothesis : lc->T_c_q,
                        d.overlap[i][j], d.options.eval, r);
    }
    det.insert(d.descs[i]);
  }
  out->runs.push_back({displayName(name) + ": solver pose", "back_end", raw,
                       summarizeRows(raw, d.ds.root, d.bytes_sum)});
  out->runs.push_back({displayName(name) + " + dtif refinement", "back_end", refined,
                       summarizeRows(refined, d.ds.root, d.bytes_sum)});
}

/// dtif's sequential run with loose verification, so that the precision-recall sweep can
/// threshold every loop it would accept at any stricter inlier count.
std::vector<EvalRow> looselyVerifiedRows(const SceneData& d) {
  LoopDetectorParams lp = d.params.loop;
  VerifierParams& v = lp.verification;
  v.min_hypothesis_inliers = v.min_inliers = 3;
  v.min_inlier_weight = 0.0;
  v.min_covisible = 0;
  v.min_covisible_ratio = 0.0;
  v.min_overlap = 0.0;
  v.min_z_pairs = 0;
  LoopDetector det(lp);
  std::vector<EvalRow> rows = d.base;
  for (size_t i = 0; i < d.n; ++i) {
    const std::optional<Loop> lc = det.query(*d.descs[i]);
    if (lc) {
      const size_t j = d.indexOf(lc->candidate_id, i);
      rows[i].inliers = lc->inliers;
      scoreAcceptedLoop(d.gtPose(i, j), lc->T_c_q, d.overlap[i][j], d.options.eval, &rows[i]);
    }
    det.insert(d.descs[i]);
  }
  return rows;
}

/// Precision-recall over the acceptance threshold: the loosely verified loops thresholded on
/// their refined inlier count.
void runPrSweep(const SceneData& d, SceneBench* out) {
  d.say("precision-recall sweep");
  const std::vector<EvalRow> rows = looselyVerifiedRows(d);
  size_t loops = 0;
  for (const EvalRow& r : rows) loops += r.has_loop;
  for (int k = 3; k <= 60; ++k) {
    // dtif's TP rule, and place recognition's (a true loop, whatever the pose error).
    size_t accepted = 0, tp = 0, true_loops = 0;
    for (const EvalRow& r : rows) {
      if (!r.accepted || r.inliers < k) continue;
      ++accepted;
      tp += r.true_positive;
      true_loops += r.true_loop;
    }
    out->pr.push_back(prPoint("dtif", k, accepted, tp, loops));
    if (d.options.place_recognition) {
      out->pr.push_back(prPoint("dtif (place recognition)", k, accepted, true_loops, loops));
    }
  }
}

/// Scan context on the sequential protocol: each query against the same eligible database as
/// dtif's, its best entry the answer.
struct ScanContextAnswers {
  std::vector<EvalRow> rows;  ///< scan context's own times; scored by scoreScanContext
  std::vector<ScanContextAnswer> answers;
  std::vector<size_t> answer_j;  ///< the answer's submap index; n: no answer
};

ScanContextAnswers queryScanContexts(const SceneData& d, const SceneBench& out) {
  const double exclude_s = d.params.loop.database.exclude_recent_s;
  ScanContextAnswers a{d.base, std::vector<ScanContextAnswer>(d.n), std::vector<size_t>(d.n, d.n)};
  for (size_t i = 0; i < d.n; ++i) {
    const auto t0 = Clock::now();
    std::vector<const ScanContext*> db;
    std::vector<size_t> db_j;
    for (size_t j = 0; j < i; ++j) {
      if (!eligiblePair(d.ds.submaps[i], d.ds.submaps[j], exclude_s)) continue;
      db.push_back(&d.scs[j]);
      db_j.push_back(j);
    }
    a.answers[i] = queryScanContext(d.scs[i], db, d.options.scan_context);
    a.rows[i].t_loop_ms = msSince(t0);
    a.rows[i].t_desc_ms = out.submaps[i].t_scan_context_ms;
    a.rows[i].t_solver_ms = 0.0;
    a.rows[i].trunks = 0;
    a.rows[i].invalid_reason = d.scs[i].invalid_reason;
    if (a.answers[i].index >= 0) a.answer_j[i] = db_j[a.answers[i].index];
  }
  return a;
}

/// Scores the answers closer than scan context's own distance threshold, with a yaw-only pose.
void scoreScanContext(const SceneData& d, ScanContextAnswers* a) {
  for (size_t i = 0; i < d.n; ++i) {
    const size_t j = a->answer_j[i];
    const ScanContextMatch& match = a->answers[i].match;
    if (j == d.n || !(match.distance < d.options.scan_context.max_distance)) continue;
    Pose T = Pose::Identity();  // yaw only: scan context estimates no translation
    T.linear() = rotZ(match.yaw_rad);
    a->rows[i].candidate = d.ds.submaps[j].id;
    a->rows[i].score = match.distance;
    scoreAcceptedLoop(d.gtPose(i, j), T, d.overlap[i][j], d.options.eval, &a->rows[i]);
  }
}

/// Scan context's precision-recall over its distance threshold: an answer is correct when its
/// pair is a true loop.
void scanContextPrCurve(const SceneData& d, const ScanContextAnswers& a, SceneBench* out) {
  auto isTrueLoop = [&](size_t i) {
    return a.answer_j[i] < d.n && d.overlap[i][a.answer_j[i]] >= d.options.eval.true_loop_overlap;
  };
  size_t loops = 0;
  for (const EvalRow& r : d.base) loops += r.has_loop;
  for (int k = 1; k <= 50; ++k) {
    const double thr = 0.02 * k;
    size_t accepted = 0, correct = 0;
    for (size_t i = 0; i < d.n; ++i) {
      if (a.answer_j[i] == d.n || !(a.answers[i].match.distance < thr)) continue;
      ++accepted;
      correct += isTrueLoop(i);
    }
    out->pr.push_back(prPoint("scan context", thr, accepted, correct, loops));
  }
}

/// Place recognition: scan context on the sequential protocol, then dtif's sequential run
/// (its refined back-end run, when it ran) scored the same way.
void runPlaceRecognition(const SceneData& d, SceneBench* out) {
  d.say("scan context");
  ScanContextAnswers a = queryScanContexts(d, *out);
  scoreScanContext(d, &a);
  scanContextPrCurve(d, a, out);
  out->place.push_back({"scan context", a.rows, d.sc_bytes_sum});
  for (const MethodRun& run : out->runs) {
    if (run.method == displayName("dtif") + " + dtif refinement") {
      out->place.push_back({"dtif", run.rows, d.bytes_sum});
    }
  }
}

/// The pairs every front end registers: each query with a loop against its most overlapping
/// eligible candidate and against its least overlapping one (when that is not a true loop).
/// Retrieval is an oracle for every method (it favours the baselines, whose own retrieval
/// would have to register against every candidate); the second pair tests rejection.
struct FrontEndPairs {
  std::vector<std::vector<size_t>> candidates;  ///< per query, the candidates it registers with
  size_t evaluated = 0;                         ///< queries with at least one pair
};

FrontEndPairs frontEndPairs(const SceneData& d) {
  const size_t n = d.n;
  FrontEndPairs pairs;
  pairs.candidates.resize(n);
  for (size_t i = 0; i < n; ++i) {
    if (!d.base[i].has_loop) continue;
    const std::vector<double>& overlap = d.overlap[i];
    size_t pos = n, neg = n;
    for (size_t j = 0; j < i; ++j) {
      if (overlap[j] < 0.0) continue;
      if (pos == n || overlap[j] > overlap[pos]) pos = j;
      if (neg == n || overlap[j] < overlap[neg]) neg = j;
    }
    pairs.candidates[i].push_back(pos);
    if (neg != n && overlap[neg] < d.options.eval.true_loop_overlap) {
      pairs.candidates[i].push_back(neg);
    }
  }
  for (const auto& p : pairs.candidates) pairs.evaluated += !p.empty();
  return pairs;
}

/// A front end's registrations of the pairs: per query, its accepted pairs and its times
/// summed over its pairs [ms].
struct Registrations {
  explicit Registrations(size_t n) : accepted(n), t_loop_ms(n, 0.0), t_solver_ms(n, 0.0) {}
  std::vector<std::vector<PairResult>> accepted;
  std::vector<double> t_loop_ms, t_solver_ms;
};

/// One stage time of every submap, as a front end's per-query descriptor time.
std::vector<double> submapTimes(const SceneBench& out, double SubmapStats::*t_ms) {
  std::vector<double> t(out.submaps.size());
  for (size_t i = 0; i < t.size(); ++i) t[i] = out.submaps[i].*t_ms;
  return t;
}

/// One front-end run from its registrations, each query answered by its best accepted pair.
/// Loop and solver times are per registered query: a query without pairs costs nothing.
MethodRun frontEndRun(const SceneData& d, const FrontEndPairs& pairs, const std::string& method,
                      const Registrations& reg, const std::vector<double>& t_desc, double bytes) {
  std::vector<EvalRow> rows = d.base;
  double loop_sum = 0.0, solver_sum = 0.0;
  for (size_t i = 0; i < d.n; ++i) {
    rows[i].t_desc_ms = t_desc[i];
    rows[i].t_loop_ms = reg.t_loop_ms[i];
    rows[i].t_solver_ms = reg.t_solver_ms[i];
    loop_sum += reg.t_loop_ms[i];
    solver_sum += reg.t_solver_ms[i];
    const PairResult* best = nullptr;
    for (const PairResult& r : reg.accepted[i]) {
      if (r.accepted && (!best || r.rank > best->rank)) best = &r;
    }
    if (!best) continue;
    rows[i].candidate = d.ds.submaps[best->j].id;
    rows[i].inliers = best->inliers;
    scoreAcceptedLoop(d.gtPose(i, best->j), best->T, d.overlap[i][best->j], d.options.eval,
                      &rows[i]);
  }
  MethodRun run{method, "front_end", rows, summarizeRows(rows, d.ds.root, bytes)};
  if (pairs.evaluated > 0) {
    run.summary.t_loop_ms = loop_sum / pairs.evaluated;
    run.summary.t_solver_ms = solver_sum / pairs.evaluated;
    run.summary.t_total_ms = run.summary.t_desc_ms + run.summary.t_loop_ms;
  }
  return run;
}

/// dtif as a front end: matchPair on each pair, ranked by score.
void runDtifFrontEnd(const SceneData& d, const FrontEndPairs& pairs, SceneBench* out) {
  d.say("front end dtif on the same pairs");
  Registrations reg(d.n);
  for (size_t i = 0; i < d.n; ++i) {
    for (size_t j : pairs.candidates[i]) {
      QueryStats qs;
      const auto t0 = Clock::now();
      const auto lc = matchPair(*d.descs[i], *d.descs[j], d.params.loop, nullptr, nullptr, &qs);
      reg.t_loop_ms[i] += msSince(t0);
      reg.t_solver_ms[i] += qs.solver_ms;
      if (lc) reg.accepted[i].push_back({j, true, lc->score, lc->inliers, lc->T_c_q});
    }
  }
  out->runs.push_back(
      frontEndRun(d, pairs, "dtif", reg, submapTimes(*out, &SubmapStats::t_desc_ms), d.bytes_sum));
}

/// FPFH correspondences of each pair, matched once for every solver.
struct FpfhMatches {
  std::vector<std::vector<std::vector<Correspondence>>> corrs;  ///< [query][pair]
  std::vector<double> t_match_ms;  ///< per query, summed over its pairs [ms]
};

FpfhMatches matchFpfhPairs(const SceneData& d, const FrontEndPairs& pairs) {
  FpfhMatches m{std::vector<std::vector<std::vector<Correspondence>>>(d.n),
                std::vector<double>(d.n, 0.0)};
  for (size_t i = 0; i < d.n; ++i) {
    d.say("FPFH matching " + std::to_string(i + 1) + "/" + std::to_string(d.n));
    for (size_t j : pairs.candidates[i]) {
      const auto t0 = Clock::now();
      m.corrs[i].push_back(matchFpfh(*d.feats[i], *d.feats[j]));
      m.t_match_ms[i] += msSince(t0);
    }
  }
  return m;
}

/// An FPFH front end's precision-recall over the inlier threshold, from all its registrations
/// (accepted or not), each query answered by its pair with the most inliers.
void fpfhPrCurve(const SceneData& d, const std::string& method,
                 const std::vector<std::vector<PairResult>>& all, SceneBench* out) {
  for (int k = 3; k <= 60; ++k) {
    size_t loops = 0, accepted = 0, tp = 0;
    for (size_t i = 0; i < d.n; ++i) {
      loops += d.base[i].has_loop;
      const PairResult* best = nullptr;
      for (const PairResult& r : all[i]) {
        if (r.inliers >= k && (!best || r.inliers > best->inliers)) best = &r;
      }
      if (!best) continue;
      EvalRow row;
      scoreAcceptedLoop(d.gtPose(i, best->j), best->T, d.overlap[i][best->j], d.options.eval, &row);
      ++accepted;
      tp += row.true_positive;
    }
    out->pr.push_back(prPoint(method, k, accepted, tp, loops));
  }
}

/// The FPFH baseline with one solver on the matched pairs, ranked by inliers; its loop time
/// is matching plus solving.
void runFpfhFrontEnd(const SceneData& d, const FrontEndPairs& pairs, const FpfhMatches& matches,
                     const std::string& solver, SceneBench* out) {
  d.say("front end FPFH + " + solver);
  FpfhParams fp = d.options.fpfh;
  fp.solver = solver;
  Registrations reg(d.n);
  reg.t_loop_ms = matches.t_match_ms;
  std::vector<std::vector<PairResult>> all(d.n);
  for (size_t i = 0; i < d.n; ++i) {
    for (size_t p = 0; p < pairs.candidates[i].size(); ++p) {
      const size_t j = pairs.candidates[i][p];
      const FpfhRegistration r = solveFpfh(matches.corrs[i][p], fp);
      reg.t_loop_ms[i] += r.solver_ms;
      reg.t_solver_ms[i] += r.solver_ms;
      all[i].push_back({j, true, static_cast<double>(r.inliers), r.inliers, r.T_c_q});
      if (r.accepted) reg.accepted[i].push_back(all[i].back());
    }
  }
  const std::string method =
      std::string("FPFH + ") + (fp.prune ? "clique + " : "") + displayName(solver);
  out->runs.push_back(frontEndRun(d, pairs, method, reg, submapTimes(*out, &SubmapStats::t_fpfh_ms),
                                  d.fpfh_bytes_sum));
  fpfhPrCurve(d, method, all, out);
}

/// Front ends on the same pairs: dtif, then the FPFH baseline with each solver.
void runFrontEnds(const SceneData& d, SceneBench* out) {
  const FrontEndPairs pairs = frontEndPairs(d);
  runDtifFrontEnd(d, pairs, out);
  if (d.options.fpfh_solvers.empty()) return;
  const FpfhMatches matches = matchFpfhPairs(d, pairs);
  for (const std::string& solver : d.options.fpfh_solvers) {
    runFpfhFrontEnd(d, pairs, matches, solver, out);
  }
}

}  // namespace

SceneBench runSceneBench(const Dataset& ds, const std::string& scene, const DtifParams& params,
                         const BenchOptions& options,
                         const std::function<void(const std::string&)>& progress) {
  for (const auto& name : options.back_ends) makeBackEnd(name, params.loop.pose);  // validate
  SceneBench out;
  out.scene = scene;
  // One pass over the clouds builds every method's descriptors, so all runs share them.
  SceneData d(ds, params, options, progress);
  for (size_t i = 0; i < d.n; ++i) describeSubmap(i, &d, &out);
  scoreGroundTruth(&d);
  for (const std::string& name : options.back_ends) runBackEnd(d, name, &out);
  if (options.pr_curve) runPrSweep(d, &out);
  if (options.place_recognition) runPlaceRecognition(d, &out);
  if (options.front_ends) runFrontEnds(d, &out);
  return out;
}

Descriptor perturbedCopy(const Descriptor& d, uint32_t seed, const DescriptorParams& params) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI), shift(-50.0, 50.0), u01(0.0, 1.0);
  std::normal_distribution<double> jitter(0.0, 0.02);
  Pose T = Pose::Identity();
  T.linear() = rotZ(yaw(rng));
  // One draw per statement, y first: gcc's order for `Vector3d(shift(rng), shift(rng), 0.0)`.
  const double shift_y = shift(rng);
  const double shift_x = shift(rng);
  T.translation() = Eigen::Vector3d(shift_x, shift_y, 0.0);
  Trunks trunks;
  for (const TrunkLandmark& t : d.trunks) {
    if (u01(rng) < 0.1) continue;
    const Eigen::Vector3d p = T * Eigen::Vector3d(t.x, t.y, t.z);
    TrunkLandmark c = t;
    c.x = p.x() + jitter(rng);
    c.y = p.y() + jitter(rng);
    c.z = p.z();
    trunks.push_back(c);
  }
  return buildDescriptor(trunks, params);
}

std::vector<ScalingPoint> runScaling(const std::vector<std::shared_ptr<const Descriptor>>& pool,
                                     const std::vector<std::shared_ptr<const Descriptor>>& queries,
                                     const DtifParams& params, const std::vector<size_t>& sizes) {
  std::vector<ScalingPoint> out;
  if (pool.empty() || queries.empty() || sizes.empty()) return out;
  const size_t max_size = *std::max_element(sizes.begin(), sizes.end());
  // The pool in a fixed random order, so that every database size mixes all scenes.
  std::vector<size_t> order(pool.size());
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), std::mt19937(7));
  std::vector<std::shared_ptr<const Descriptor>> copies;
  for (size_t k = 0; copies.size() < max_size && k < 4 * max_size; ++k) {
    auto d = std::make_shared<Descriptor>(perturbedCopy(
        *pool[order[k % pool.size()]], static_cast<uint32_t>(1000 + k), params.descriptor));
    if (!d->valid) continue;
    d->robot = "db";
    d->submap_id = static_cast<int64_t>(copies.size());
    d->stamp = 1000.0 * static_cast<double>(copies.size());
    copies.push_back(d);
  }
  for (size_t size : sizes) {
    LoopDetector det(params.loop);
    for (size_t k = 0; k < size && k < copies.size(); ++k) det.insert(copies[k]);
    ScalingPoint p;
    p.db_size = det.size();
    for (const auto& q : queries) {
      QueryStats qs;
      const auto t0 = Clock::now();
      det.query(*q, &qs);
      p.query_ms += msSince(t0);
      p.screen_ms += qs.screen_ms;
      p.match_ms += qs.match_ms;
      p.solver_ms += qs.solver_ms;
      p.screened_in += static_cast<double>(qs.screened_in);
    }
    const double k = 1.0 / static_cast<double>(queries.size());
    p.query_ms *= k;
    p.screen_ms *= k;
    p.match_ms *= k;
    p.solver_ms *= k;
    p.screened_in *= k;
    out.push_back(p);
  }
  return out;
}

PlaceRecognitionSummary summarizePlaceRecognition(const std::vector<EvalRow>& rows,
                                                  double bytes_sum) {
  PlaceRecognitionSummary s;
  s.submaps = rows.size();
  std::vector<double> yaw;
  for (const EvalRow& r : rows) {
    s.queries_with_loop += r.has_loop;
    s.t_desc_ms += r.t_desc_ms;
    s.t_query_ms += r.t_loop_ms;
    if (!r.accepted) continue;
    ++s.answers;
    if (!r.true_loop) continue;
    ++s.correct;
    if (r.err) yaw.push_back(r.err->yaw_deg);
  }
  if (s.answers) s.precision = static_cast<double>(s.correct) / s.answers;
  if (s.queries_with_loop) s.recall = static_cast<double>(s.correct) / s.queries_with_loop;
  if (!yaw.empty()) {
    s.yaw_err_deg = std::accumulate(yaw.begin(), yaw.end(), 0.0) / yaw.size();
    std::sort(yaw.begin(), yaw.end());
    const size_t m = yaw.size() / 2;
    s.yaw_err_median_deg = yaw.size() % 2 ? yaw[m] : 0.5 * (yaw[m - 1] + yaw[m]);
  }
  if (s.submaps) {
    const double k = 1.0 / static_cast<double>(s.submaps);
    s.t_desc_ms *= k;
    s.t_query_ms *= k;
    s.bytes_mean = bytes_sum * k;
  }
  return s;
}

std::string placeRecognitionHeader(const std::string& first) {
  return "| " + first +
         " | Precision | Recall | Correct/Ans./Loops | Yaw err. of correct, mean [deg] | Median "
         "[deg] | Desc. ms | Query ms | Bytes |\n|---|---|---|---|---|---|---|---|---|\n";
}

std::string placeRecognitionRow(const PlaceRecognitionSummary& s, const std::string& method) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(3);
  auto opt = [&](const std::optional<double>& v) {
    if (v) {
      os << *v;
    } else {
      os << "-";
    }
    os << " | ";
  };
  os << "| " << method << " | ";
  opt(s.precision);
  opt(s.recall);
  os << s.correct << '/' << s.answers << '/' << s.queries_with_loop << " | ";
  opt(s.yaw_err_deg);
  opt(s.yaw_err_median_deg);
  os << s.t_desc_ms << " | " << s.t_query_ms << " | " << std::setprecision(0) << s.bytes_mean
     << " |\n";
  return os.str();
}

std::string tableRow(const EvalSummary& s, const std::string& method) {
  std::istringstream is(formatTable(s, method));
  std::string line;
  for (int i = 0; i < 3 && std::getline(is, line); ++i) {
  }
  return line + "\n";
}

std::string tableHeader(const std::string& first) {
  std::istringstream is(formatTable(EvalSummary{}, ""));
  std::string head, rule;
  std::getline(is, head);
  std::getline(is, rule);
  return "| " + first + head.substr(head.find(" |")) + "\n" + rule + "\n";
}

}  // namespace dtif::baselines
