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

SceneBench runSceneBench(const Dataset& ds, const std::string& scene, const DtifParams& params,
                         const BenchOptions& options,
                         const std::function<void(const std::string&)>& progress) {
  auto say = [&](const std::string& s) {
    if (progress) progress(s);
  };
  for (const auto& name : options.back_ends) makeBackEnd(name, params.loop.pose);  // validate
  SceneBench out;
  out.scene = scene;
  const size_t n = ds.submaps.size();
  std::vector<std::unordered_set<int64_t>> cells(n);
  std::vector<std::shared_ptr<Descriptor>> descs(n);
  std::vector<FpfhFeaturesPtr> feats(n);
  std::vector<ScanContext> scs(n);
  std::vector<EvalRow> base(n);
  double bytes_sum = 0.0, fpfh_bytes_sum = 0.0, sc_bytes_sum = 0.0;

  // One pass over the clouds: ground-truth cells, dtif's descriptor, the FPFH features.
  for (size_t i = 0; i < n; ++i) {
    const SubmapRecord& rec = ds.submaps[i];
    if (!ds.T_W_S.count(rec.id)) {
      throw DatasetError(ds.root + ": no ground truth for submap " + std::to_string(rec.id));
    }
    say("describing " + std::to_string(i + 1) + "/" + std::to_string(n));
    const Cloud::Ptr cloud = loadSubmapCloud(ds, rec);
    cells[i] = overlapCells(*cloud, ds.T_W_S.at(rec.id));
    SubmapStats st;
    st.id = rec.id;
    st.points = cloud->size();
    TrunkExtractionResult ext;
    DescribeTimings timings;
    descs[i] = std::make_shared<Descriptor>(describeCloud(*cloud, {rec.robot, rec.id, rec.stamp},
                                                          params.trunk_extraction,
                                                          params.descriptor, &timings, &ext));
    st.t_extract_ms = timings.extract_ms;
    st.t_desc_ms = timings.total_ms;
    st.trunks = ext.trunks.size();
    st.bytes = encodeDescriptor(*descs[i]).size();
    bytes_sum += static_cast<double>(st.bytes);
    if (options.front_ends) {
      const auto t0 = Clock::now();
      feats[i] = computeFpfh(*cloud, options.fpfh);
      st.t_fpfh_ms = msSince(t0);
      st.fpfh_points = fpfhPoints(*feats[i]);
      fpfh_bytes_sum += static_cast<double>(fpfhBytes(*feats[i]));
    }
    if (options.place_recognition) {
      const auto t0 = Clock::now();
      scs[i] = makeScanContext(*cloud, options.scan_context);
      st.t_scan_context_ms = msSince(t0);
      sc_bytes_sum += static_cast<double>(scs[i].bytes());
    }
    if (descs[i]->valid) out.descriptors.push_back(descs[i]);
    base[i].query = rec.id;
    base[i].trunks = st.trunks;
    base[i].t_desc_ms = st.t_desc_ms;
    base[i].invalid_reason = descs[i]->invalid_reason;
    out.submaps.push_back(st);
  }

  // Ground truth of every eligible pair (DATASET.md).
  const double exclude_s = params.loop.database.exclude_recent_s;
  std::vector<std::vector<double>> overlap(n, std::vector<double>(n, -1.0));  // -1: ineligible
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < i; ++j) {
      if (!eligiblePair(ds.submaps[i], ds.submaps[j], exclude_s)) continue;
      overlap[i][j] = cellOverlap(cells[i], cells[j]);
      base[i].has_loop = base[i].has_loop || overlap[i][j] >= options.eval.true_loop_overlap;
    }
  }
  auto gtPose = [&](size_t i, size_t j) {
    return ds.T_W_S.at(ds.submaps[j].id).inverse() * ds.T_W_S.at(ds.submaps[i].id);
  };
  auto indexOf = [&](int64_t id, size_t before) {
    for (size_t j = 0; j < before; ++j) {
      if (ds.submaps[j].id == id) return j;
    }
    throw std::logic_error("unknown candidate id " + std::to_string(id));
  };

  // Back ends: the sequential protocol with each solver on dtif's correspondences. The
  // solver's own pose and the pose after dtif's guided refinement are scored separately.
  for (const std::string& name : options.back_ends) {
    say("back end " + name);
    LoopDetectorParams lp = params.loop;
    if (name == "dtif_unit") lp.pose.unit_weights = true;
    LoopDetector det(lp);
    det.setSolver(makeBackEnd(name, lp.pose));
    std::vector<EvalRow> raw = base, refined = base;
    for (size_t i = 0; i < n; ++i) {
      QueryStats qs;
      const auto t0 = Clock::now();
      const std::optional<Loop> lc = det.query(*descs[i], &qs);
      const double t_loop = msSince(t0);
      for (EvalRow* r : {&raw[i], &refined[i]}) {
        r->t_loop_ms = t_loop;
        r->t_solver_ms = qs.solver_ms;
        if (!lc) continue;
        const size_t j = indexOf(lc->candidate_id, i);
        r->candidate = lc->candidate_id;
        r->inliers = lc->inliers;
        r->score = lc->score;
        scoreAcceptedLoop(gtPose(i, j), r == &raw[i] ? lc->T_hypothesis : lc->T_c_q, overlap[i][j],
                          options.eval, r);
      }
      det.insert(descs[i]);
    }
    out.runs.push_back({displayName(name) + ": solver pose", "back_end", raw,
                        summarizeRows(raw, ds.root, bytes_sum)});
    out.runs.push_back({displayName(name) + " + dtif refinement", "back_end", refined,
                        summarizeRows(refined, ds.root, bytes_sum)});
  }

  // Precision-recall over the acceptance threshold: dtif with loose verification, accepted
  // loops then thresholded on their refined inlier count.
  if (options.pr_curve) {
    say("precision-recall sweep");
    LoopDetectorParams lp = params.loop;
    VerifierParams& v = lp.verification;
    v.min_hypothesis_inliers = v.min_inliers = 3;
    v.min_inlier_weight = 0.0;
    v.min_covisible = 0;
    v.min_covisible_ratio = 0.0;
    v.min_overlap = 0.0;
    v.min_z_pairs = 0;
    LoopDetector det(lp);
    std::vector<EvalRow> rows = base;
    for (size_t i = 0; i < n; ++i) {
      const std::optional<Loop> lc = det.query(*descs[i]);
      if (lc) {
        const size_t j = indexOf(lc->candidate_id, i);
        rows[i].inliers = lc->inliers;
        scoreAcceptedLoop(gtPose(i, j), lc->T_c_q, overlap[i][j], options.eval, &rows[i]);
      }
      det.insert(descs[i]);
    }
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
      out.pr.push_back(prPoint("dtif", k, accepted, tp, loops));
      if (options.place_recognition) {
        out.pr.push_back(prPoint("dtif (place recognition)", k, accepted, true_loops, loops));
      }
    }
  }

  // Place recognition: scan context on the sequential protocol (the same eligible database as
  // dtif's), its best entry per query the answer, correct when the pair is a true loop; then
  // dtif's sequential run scored the same way.
  if (options.place_recognition) {
    say("scan context");
    const ScanContextParams& scp = options.scan_context;
    std::vector<EvalRow> rows = base;
    std::vector<ScanContextAnswer> answers(n);
    std::vector<size_t> answer_j(n, n);
    for (size_t i = 0; i < n; ++i) {
      const auto t0 = Clock::now();
      std::vector<const ScanContext*> db;
      std::vector<size_t> db_j;
      for (size_t j = 0; j < i; ++j) {
        if (!eligiblePair(ds.submaps[i], ds.submaps[j], exclude_s)) continue;
        db.push_back(&scs[j]);
        db_j.push_back(j);
      }
      answers[i] = queryScanContext(scs[i], db, scp);
      rows[i].t_loop_ms = msSince(t0);
      rows[i].t_desc_ms = out.submaps[i].t_scan_context_ms;
      rows[i].t_solver_ms = 0.0;
      rows[i].trunks = 0;
      rows[i].invalid_reason = scs[i].invalid_reason;
      if (answers[i].index >= 0) answer_j[i] = db_j[answers[i].index];
    }
    auto isTrueLoop = [&](size_t i) {
      return answer_j[i] < n && overlap[i][answer_j[i]] >= options.eval.true_loop_overlap;
    };
    for (size_t i = 0; i < n; ++i) {
      if (answer_j[i] == n || !(answers[i].match.distance < scp.max_distance)) continue;
      Pose T = Pose::Identity();  // yaw only: scan context estimates no translation
      T.linear() = rotZ(answers[i].match.yaw_rad);
      rows[i].candidate = ds.submaps[answer_j[i]].id;
      rows[i].score = answers[i].match.distance;
      scoreAcceptedLoop(gtPose(i, answer_j[i]), T, overlap[i][answer_j[i]], options.eval, &rows[i]);
    }
    size_t loops = 0;
    for (const EvalRow& r : base) loops += r.has_loop;
    for (int k = 1; k <= 50; ++k) {
      const double thr = 0.02 * k;
      size_t accepted = 0, correct = 0;
      for (size_t i = 0; i < n; ++i) {
        if (answer_j[i] == n || !(answers[i].match.distance < thr)) continue;
        ++accepted;
        correct += isTrueLoop(i);
      }
      out.pr.push_back(prPoint("scan context", thr, accepted, correct, loops));
    }
    out.place.push_back({"scan context", rows, sc_bytes_sum});
    for (const MethodRun& run : out.runs) {
      if (run.method == displayName("dtif") + " + dtif refinement") {
        out.place.push_back({"dtif", run.rows, bytes_sum});
      }
    }
  }
  if (!options.front_ends) return out;

  // Front ends on the same pairs: each query with a loop registers with its most overlapping
  // eligible candidate and with its least overlapping one (when that is not a true loop).
  // Retrieval is an oracle for every method (it favours the baselines, whose own retrieval
  // would have to register against every candidate); the second pair tests rejection.
  std::vector<std::vector<size_t>> pairs(n);
  for (size_t i = 0; i < n; ++i) {
    if (!base[i].has_loop) continue;
    size_t pos = n, neg = n;
    for (size_t j = 0; j < i; ++j) {
      if (overlap[i][j] < 0.0) continue;
      if (pos == n || overlap[i][j] > overlap[i][pos]) pos = j;
      if (neg == n || overlap[i][j] < overlap[i][neg]) neg = j;
    }
    pairs[i].push_back(pos);
    if (neg != n && overlap[i][neg] < options.eval.true_loop_overlap) pairs[i].push_back(neg);
  }
  size_t evaluated = 0;
  for (const auto& p : pairs) evaluated += !p.empty();
  // One front-end run from its per-pair results; loop/solver times are per registered query.
  auto frontEndRun = [&](const std::string& method, const std::vector<std::vector<PairResult>>& res,
                         const std::vector<double>& t_loop, const std::vector<double>& t_solver,
                         const std::vector<double>& t_desc, double bytes) {
    std::vector<EvalRow> rows = base;
    double loop_sum = 0.0, solver_sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
      rows[i].t_desc_ms = t_desc[i];
      rows[i].t_loop_ms = t_loop[i];
      rows[i].t_solver_ms = t_solver[i];
      loop_sum += t_loop[i];
      solver_sum += t_solver[i];
      const PairResult* best = nullptr;
      for (const PairResult& r : res[i]) {
        if (r.accepted && (!best || r.rank > best->rank)) best = &r;
      }
      if (!best) continue;
      rows[i].candidate = ds.submaps[best->j].id;
      rows[i].inliers = best->inliers;
      scoreAcceptedLoop(gtPose(i, best->j), best->T, overlap[i][best->j], options.eval, &rows[i]);
    }
    MethodRun run{method, "front_end", rows, summarizeRows(rows, ds.root, bytes)};
    if (evaluated > 0) {
      run.summary.t_loop_ms = loop_sum / evaluated;
      run.summary.t_solver_ms = solver_sum / evaluated;
      run.summary.t_total_ms = run.summary.t_desc_ms + run.summary.t_loop_ms;
    }
    return run;
  };

  std::vector<double> t_desc_dtif(n), t_desc_fpfh(n);
  for (size_t i = 0; i < n; ++i) {
    t_desc_dtif[i] = out.submaps[i].t_desc_ms;
    t_desc_fpfh[i] = out.submaps[i].t_fpfh_ms;
  }
  {
    say("front end dtif on the same pairs");
    std::vector<std::vector<PairResult>> res(n);
    std::vector<double> t_loop(n, 0.0), t_solver(n, 0.0);
    for (size_t i = 0; i < n; ++i) {
      for (size_t j : pairs[i]) {
        QueryStats qs;
        const auto t0 = Clock::now();
        const auto lc = matchPair(*descs[i], *descs[j], params.loop, nullptr, nullptr, &qs);
        t_loop[i] += msSince(t0);
        t_solver[i] += qs.solver_ms;
        if (lc) res[i].push_back({j, true, lc->score, lc->inliers, lc->T_c_q});
      }
    }
    out.runs.push_back(frontEndRun("dtif", res, t_loop, t_solver, t_desc_dtif, bytes_sum));
  }
  // FPFH correspondences of each pair, matched once for every solver (timed per query).
  std::vector<std::vector<std::vector<Correspondence>>> fpfh_corrs(n);
  std::vector<double> t_fpfh_match(n, 0.0);
  if (!options.fpfh_solvers.empty()) {
    for (size_t i = 0; i < n; ++i) {
      say("FPFH matching " + std::to_string(i + 1) + "/" + std::to_string(n));
      for (size_t j : pairs[i]) {
        const auto t0 = Clock::now();
        fpfh_corrs[i].push_back(matchFpfh(*feats[i], *feats[j]));
        t_fpfh_match[i] += msSince(t0);
      }
    }
  }
  for (const std::string& solver : options.fpfh_solvers) {
    say("front end FPFH + " + solver);
    FpfhParams fp = options.fpfh;
    fp.solver = solver;
    std::vector<std::vector<PairResult>> res(n), all(n);
    std::vector<double> t_loop(t_fpfh_match), t_solver(n, 0.0);
    for (size_t i = 0; i < n; ++i) {
      for (size_t p = 0; p < pairs[i].size(); ++p) {
        const size_t j = pairs[i][p];
        const FpfhRegistration reg = solveFpfh(fpfh_corrs[i][p], fp);
        t_loop[i] += reg.solver_ms;
        t_solver[i] += reg.solver_ms;
        all[i].push_back({j, true, static_cast<double>(reg.inliers), reg.inliers, reg.T_c_q});
        if (reg.accepted) res[i].push_back(all[i].back());
      }
    }
    const std::string method =
        std::string("FPFH + ") + (fp.prune ? "clique + " : "") + displayName(solver);
    out.runs.push_back(frontEndRun(method, res, t_loop, t_solver, t_desc_fpfh, fpfh_bytes_sum));
    // Its precision-recall over the inlier threshold.
    for (int k = 3; k <= 60; ++k) {
      size_t loops = 0, accepted = 0, tp = 0;
      for (size_t i = 0; i < n; ++i) {
        loops += base[i].has_loop;
        const PairResult* best = nullptr;
        for (const PairResult& r : all[i]) {
          if (r.inliers >= k && (!best || r.inliers > best->inliers)) best = &r;
        }
        if (!best) continue;
        EvalRow row;
        scoreAcceptedLoop(gtPose(i, best->j), best->T, overlap[i][best->j], options.eval, &row);
        ++accepted;
        tp += row.true_positive;
      }
      out.pr.push_back(prPoint(method, k, accepted, tp, loops));
    }
  }
  return out;
}

Descriptor perturbedCopy(const Descriptor& d, uint32_t seed, const DescriptorParams& params) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI), shift(-50.0, 50.0), u01(0.0, 1.0);
  std::normal_distribution<double> jitter(0.0, 0.02);
  Pose T = Pose::Identity();
  T.linear() = rotZ(yaw(rng));
  T.translation() = Eigen::Vector3d(shift(rng), shift(rng), 0.0);
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
