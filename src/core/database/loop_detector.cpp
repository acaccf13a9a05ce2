// Descriptor database and sequential loop query (paper Alg. 1): screening, then matchPair
// (correspondences, pose, verification) on the best candidates.
#include "dtif/core/database/loop_detector.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "dtif/core/database/loop_pair.h"
#include "dtif/core/database/vote_fallback.h"
#include "dtif/core/timing.h"

namespace dtif {
namespace {

/// Roll and pitch come from the gravity-aligned front end (FAST-LIO2), not from the match:
/// their uncertainty is the IMU levelling error, taken as (0.5 deg)^2.
constexpr double kRollPitchVar = (0.5 * M_PI / 180.0) * (0.5 * M_PI / 180.0);
/// Floors on the reported variances: a handful of inliers with tiny residuals must not claim
/// millimetre certainty (trunk centres are only fitted to ~1-2 cm).
constexpr double kMinXyVar = 0.02 * 0.02;
constexpr double kMinZVar = 0.03 * 0.03;
/// t_z with no seen stem base on both sides: a guess of a few metres [m^2].
constexpr double kUnobservedZVar = 3.0 * 3.0;
/// t_z from a single pair of seen bases (min_z_pairs 1): a base flagged seen still sits on a
/// shrub or log, 0.45-1.6 m high, for 6 % of the trunks in the dense understory scene and 2 %
/// in the mixed one, so one pair gets a decimetre-level variance, not its own zero residual.
constexpr double kSinglePairZVar = 0.3 * 0.3;
/// t_z from the ground maps: hundreds of agreeing cells, but 5 cm steps and the cells' slope
/// (a 0.5 m cell spans 0.18 m of a 20 deg slope) bound it at a few centimetres.
constexpr double kGroundZVar = 0.05 * 0.05;
constexpr double kMinYawVar = (0.1 * M_PI / 180.0) * (0.1 * M_PI / 180.0);

/// The solver on corrs (timed into stats).
PoseEstimate solve(const std::vector<Correspondence>& corrs, const LoopDetectorParams& params,
                   const PoseSolver* solver, QueryStats* stats) {
  if (stats) ++stats->matched;
  const auto t0 = std::chrono::steady_clock::now();
  PoseEstimate est = solver && *solver ? (*solver)(corrs) : estimatePose(corrs, params.pose);
  if (stats) stats->solver_ms += msSince(t0);
  return est;
}

/// A candidate's pose hypothesis, what matchPair solves before verification: from the
/// triangles or, when they give none, from the vote fallback.
struct Hypothesis {
  std::vector<Correspondence> corrs;
  PoseEstimate est;
  Rejection triangles = Rejection::kNone;  ///< why the triangles gave no hypothesis
  Rejection votes = Rejection::kNone;      ///< why the vote fallback gave none, when it ran
  bool voted = false;                      ///< corrs and est are the vote fallback's
  bool ok() const { return voted ? votes == Rejection::kNone : triangles == Rejection::kNone; }
};

/// Whether the vote fallback runs after the triangles gave `corrs` correspondences but no
/// hypothesis. Not when they gave vote_max_correspondences or more: the triangles of a
/// repetitive stand match plentifully yet support no single pose, and its trunk pairs vote just
/// as ambiguously, at the highest cost (every pair of a grid is length-consistent with many).
bool votesFor(size_t corrs, const MatcherParams& params) {
  const int cap = params.vote_max_correspondences;
  return params.vote_fallback && (cap <= 0 || corrs < static_cast<size_t>(cap));
}

/// Correspondences and pose (matching and solver timed into stats); the vote fallback once
/// the triangles gave no hypothesis (its voted pairs replace corrs).
Hypothesis hypothesize(const Descriptor& q, const Descriptor& c, const LoopDetectorParams& params,
                       const PoseSolver* solver, QueryStats* stats,
                       const std::vector<MatchTriangle>* tq, const std::vector<MatchTriangle>* tc,
                       const std::vector<ConsistencyBounds>* bq = nullptr) {
  Hypothesis h;
  auto t0 = std::chrono::steady_clock::now();
  h.corrs = buildCorrespondences(q, c, params.matcher, nullptr, tq, tc, bq);
  if (stats) stats->match_ms += msSince(t0);
  if (static_cast<int>(h.corrs.size()) >= params.verification.min_hypothesis_inliers) {
    h.est = solve(h.corrs, params, solver, stats);
    h.triangles = hypothesisRejection(h.est, params.verification);
  } else {
    h.triangles = Rejection::kFewCorrespondences;
  }
  if (h.triangles == Rejection::kNone || !votesFor(h.corrs.size(), params.matcher)) return h;
  t0 = std::chrono::steady_clock::now();
  std::vector<Correspondence> voted = voteCorrespondences(q, c, params, &h.votes);
  if (stats) stats->match_ms += msSince(t0);
  if (voted.empty()) return h;
  h.voted = true;
  h.corrs.swap(voted);
  h.est = solve(h.corrs, params, solver, stats);
  h.votes = hypothesisRejection(h.est, params.verification);
  return h;
}

/// Verification of a hypothesis (timed into stats). Without one, or when the voted one
/// fails, the rejection is the triangles' and vote_rejection the votes'.
Verification verifyHypothesis(const Descriptor& q, const Descriptor& c, const Hypothesis& h,
                              const LoopDetectorParams& params, QueryStats* stats) {
  Verification ver;
  if (!h.ok()) {
    ver.rejection = h.triangles;
    ver.vote_rejection = h.votes;
    return ver;
  }
  const auto t0 = std::chrono::steady_clock::now();
  ver = verifyLoop(q, c, h.corrs, h.est, params.verification);
  if (stats) stats->verify_ms += msSince(t0);
  if (h.voted && !ver.accepted) {
    ver.vote_rejection = ver.rejection;
    ver.rejection = h.triangles;
  }
  return ver;
}

/// A levelled pair's loop (estimated between the levelled frames) in the submaps' frames; the
/// covariance's translation and rotation blocks turn with the candidate's frame.
void toSubmapFrames(const Descriptor& q, const Descriptor& c, Loop* lc) {
  if (!q.levelled() && !c.levelled()) return;
  lc->T_c_q = submapFramePose(q, c, lc->T_c_q);
  lc->T_hypothesis = submapFramePose(q, c, lc->T_hypothesis);
  const Eigen::Matrix3d R = c.level_rotation.conjugate().toRotationMatrix();
  Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Zero();
  J.topLeftCorner<3, 3>() = R;
  J.bottomRightCorner<3, 3>() = R;
  lc->covariance = J * lc->covariance * J.transpose();
}

/// The accepted loop of a verification, with its covariance.
Loop makeLoop(const Descriptor& q, const Descriptor& c, const std::vector<Correspondence>& corrs,
              const PoseEstimate& est, const Verification& ver) {
  Loop lc;
  lc.query_robot = q.robot;
  lc.query_id = q.submap_id;
  lc.candidate_robot = c.robot;
  lc.candidate_id = c.submap_id;
  lc.T_c_q = ver.T_c_q;
  lc.T_hypothesis = est.T_c_q;
  lc.inliers = static_cast<int>(ver.pairs.size());
  lc.score = ver.score;
  lc.inlier_pairs = ver.pairs;
  for (const Correspondence& k : corrs) lc.all_pairs.emplace_back(k.iq, k.ic);

  // Covariance from the inlier residuals: per-axis residual variance sigma^2 = rms_xy^2 / 2
  // (each residual mixes two trunk errors, hence the mean of n residuals has sigma^2 / n);
  // yaw from the lever arms of the inliers about their centroid.
  const double n = static_cast<double>(lc.inliers);
  const double s2 = ver.rms_xy_m * ver.rms_xy_m / 2.0;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& pr : ver.pairs)
    mean += Eigen::Vector2d(q.trunks[pr.first].x, q.trunks[pr.first].y);
  mean /= n;
  double lever2 = 0.0;
  for (const auto& pr : ver.pairs) {
    lever2 += (Eigen::Vector2d(q.trunks[pr.first].x, q.trunks[pr.first].y) - mean).squaredNorm();
  }
  lc.covariance.setZero();
  lc.covariance(0, 0) = lc.covariance(1, 1) = std::max(s2 / n, kMinXyVar);
  // t_z from the ground maps (no seen-base pair, or disagreeing ones), from seen-base pairs,
  // or, with none, extrapolated terrain, not a measurement.
  lc.covariance(2, 2) =
      ver.ground_cells > 0
          ? std::max(ver.ground_sigma_m * ver.ground_sigma_m / ver.ground_cells, kGroundZVar)
      : ver.z_pairs > 1  ? std::max(ver.rms_z_m * ver.rms_z_m / ver.z_pairs, kMinZVar)
      : ver.z_pairs == 1 ? kSinglePairZVar
                         : kUnobservedZVar;
  lc.covariance(3, 3) = ver.tilt_fitted ? ver.roll_var : kRollPitchVar;
  lc.covariance(4, 4) = ver.tilt_fitted ? ver.pitch_var : kRollPitchVar;
  lc.covariance(5, 5) = std::max(lever2 > 0 ? s2 / lever2 : 1.0, kMinYawVar);
  toSubmapFrames(q, c, &lc);
  return lc;
}

/// Whether a hypothesis of score bound `bound` at screening rank `rank` can still beat `loop`
/// (found at `loop_rank`): ties go to the better screened.
bool canBeat(double bound, size_t rank, const std::optional<Loop>& loop, size_t loop_rank) {
  return !loop || bound > loop->score || (bound == loop->score && rank < loop_rank);
}

struct BestLoops {
  std::optional<Loop> best;
  std::optional<Loop> inter_robot;  ///< only when `best` is with q's own robot
};

/// The loop of the best-scoring accepted hypothesis (ties: the first, i.e. best screened), as
/// if every one were verified in screening order. Verification is the costly part (lattice
/// searches in repetitive stands), so the hypotheses are verified in order of their score
/// bound (inlierWeightShare: a loop scores its co-visible ratio, at most 1, times it), and
/// those whose bound cannot beat the best loop found are not verified at all. While the best
/// loop is with q's own robot, other robots' hypotheses past that point are verified on, at
/// most `extra_budget` of them, for the best inter-robot loop as well; the best loop stays the
/// same. At most database.max_lattice_searches verifications search the lattice; hypotheses
/// that would search it beyond that are skipped like rejected ones. `verified` holds the
/// verifications already made (by rank; endsMatching's), used instead of verifying again.
BestLoops verifyBest(const Descriptor& q, const std::vector<const Descriptor*>& cands,
                     const std::vector<Hypothesis>& hyps,
                     const std::vector<std::optional<Verification>>& verified,
                     const LoopDetectorParams& params, int extra_budget, QueryStats* stats) {
  std::vector<std::pair<double, size_t>> order;  // (bound, rank)
  for (size_t rank = 0; rank < hyps.size(); ++rank) {
    if (hyps[rank].ok())
      order.emplace_back(inlierWeightShare(hyps[rank].corrs, hyps[rank].est), rank);
  }
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  BestLoops out;
  size_t best_rank = 0, inter_rank = 0, attempted = 0, skipped = 0;
  const int max_searches = params.database.max_lattice_searches;
  int64_t lattice_budget = max_searches > 0 ? max_searches : -1;
  for (const auto& [bound, rank] : order) {
    const bool other_robot = cands[rank]->robot != q.robot;
    const bool for_best = canBeat(bound, rank, out.best, best_rank);
    if (!for_best) {
      // Sorted: no later hypothesis can beat the best either, nor an inter-robot loop the best
      // inter-robot one (or the best is inter-robot already).
      const bool own_best = out.best->candidate_robot == q.robot;
      if (extra_budget <= 0 || !own_best || !canBeat(bound, rank, out.inter_robot, inter_rank))
        break;
      if (!other_robot) continue;
      --extra_budget;
    }
    if (needsLatticeSearch(hyps[rank].est, params.verification)) {
      if (lattice_budget == 0) {
        ++skipped;
        continue;
      }
      --lattice_budget;  // a negative budget (no limit) never reaches 0
      if (stats) ++stats->lattice_searches;
    }
    ++attempted;
    const Verification ver = verified[rank]
                                 ? *verified[rank]
                                 : verifyHypothesis(q, *cands[rank], hyps[rank], params, stats);
    if (!ver.accepted) continue;
    if (stats) {
      ++stats->verified;
      if (!for_best) ++stats->inter_robot_verified;
    }
    const bool better = for_best && canBeat(ver.score, rank, out.best, best_rank);
    const bool better_inter = other_robot && canBeat(ver.score, rank, out.inter_robot, inter_rank);
    if (!better && !better_inter) continue;
    const Loop loop = makeLoop(q, *cands[rank], hyps[rank].corrs, hyps[rank].est, ver);
    if (better) {
      out.best = loop;
      best_rank = rank;
    }
    if (better_inter) {
      out.inter_robot = loop;
      inter_rank = rank;
    }
  }
  if (stats) {
    stats->unverified += order.size() - attempted - skipped;
    stats->lattice_skipped += skipped;
  }
  if (!out.best || out.best->candidate_robot != q.robot) out.inter_robot.reset();
  return out;
}

/// Whether a query may stop matching after this candidate (database.decisive_score): its
/// hypothesis' score bound reaches the decisive score, so it is verified now (into `ver`, for
/// verifyBest), and its loop scores at least that, with another robot than q's or without an
/// inter-robot loop asked for. Hypotheses that would search the lattice are left to
/// verifyBest, which holds the budget of searches.
bool endsMatching(const Descriptor& q, const Descriptor& c, const Hypothesis& h,
                  const LoopDetectorParams& params, bool inter_robot,
                  std::optional<Verification>* ver, QueryStats* stats) {
  const double decisive = params.database.decisive_score;
  if (decisive <= 0.0 || !h.ok() || needsLatticeSearch(h.est, params.verification) ||
      inlierWeightShare(h.corrs, h.est) < decisive) {
    return false;
  }
  *ver = verifyHypothesis(q, c, h, params, stats);
  return (*ver)->accepted && (*ver)->score >= decisive && (!inter_robot || c.robot != q.robot);
}

}  // namespace

Pose submapFramePose(const Descriptor& q, const Descriptor& c, const Pose& T_Lc_Lq) {
  Pose R_Lq_Sq = Pose::Identity(), R_Lc_Sc = Pose::Identity();
  R_Lq_Sq.linear() = q.level_rotation.normalized().toRotationMatrix();
  R_Lc_Sc.linear() = c.level_rotation.normalized().toRotationMatrix();
  return R_Lc_Sc.inverse() * T_Lc_Lq * R_Lq_Sq;
}

std::optional<Loop> matchPair(const Descriptor& q, const Descriptor& c,
                              const LoopDetectorParams& params, PoseEstimate* est_out,
                              Verification* ver_out, QueryStats* stats, const PoseSolver* solver,
                              const std::vector<MatchTriangle>* tq,
                              const std::vector<MatchTriangle>* tc) {
  const Hypothesis h = hypothesize(q, c, params, solver, stats, tq, tc);
  const Verification ver = verifyHypothesis(q, c, h, params, stats);
  if (est_out) *est_out = h.est;
  if (ver_out) *ver_out = ver;
  if (!ver.accepted) return std::nullopt;
  if (stats) ++stats->verified;
  return makeLoop(q, c, h.corrs, h.est, ver);
}

std::string DatabaseParams::validate() const {
  std::ostringstream err;
  if (!(exclude_recent_s >= 0.0)) err << "exclude_recent_s must be >= 0; ";
  if (max_candidates < 1) err << "max_candidates must be >= 1; ";
  if (max_vote_candidates < 0) err << "max_vote_candidates must be >= 0; ";
  if (inter_robot_verifications < 0) err << "inter_robot_verifications must be >= 0; ";
  if (max_lattice_searches < 0) err << "max_lattice_searches must be >= 0 (0: no limit); ";
  if (!(decisive_score >= 0.0 && decisive_score <= 1.0))
    err << "decisive_score must be in [0, 1] (0: match every candidate); ";
  return err.str();
}

std::string LoopDetectorParams::validate() const {
  std::string out;
  auto add = [&](const char* section, const std::string& e) {
    if (!e.empty()) out += std::string(section) + ": " + e;
  };
  add("matcher", matcher.validate());
  add("pose", pose.validate());
  add("verification", verification.validate());
  add("database", database.validate());
  return out;
}

LoopDetector::LoopDetector(const LoopDetectorParams& params) : params_(params) {
  const std::string err = params_.validate();
  if (!err.empty()) throw std::invalid_argument("bad loop detector params: " + err);
}

bool LoopDetector::insert(std::shared_ptr<const Descriptor> d, const EntryOdometry& odometry) {
  if (!d || !d->valid || entries_.size() >= kMaxDatabaseEntries) return false;
  indexEntry(*d);
  entries_.push_back(std::move(d));
  odometry_.push_back(odometry);
  return true;
}

bool LoopDetector::replace(std::shared_ptr<const Descriptor> d) {
  if (!d || !d->valid) return false;
  // Newest first: the entries described again are the robot's recent ones.
  size_t i = entries_.size();
  while (i-- > 0) {
    if (entries_[i]->submap_id == d->submap_id && entries_[i]->robot == d->robot) break;
  }
  if (i == static_cast<size_t>(-1)) return false;
  ScreenRow& row = screen_[i];
  const size_t n = d->edge_hist.size() + d->radius_hist.size();
  if (n != row.edge_n + row.radius_n) {
    row.offset = hists_.size();  // the old histograms stay behind, unread
    hists_.resize(hists_.size() + n);
  }
  std::copy(d->edge_hist.begin(), d->edge_hist.end(), hists_.begin() + row.offset);
  std::copy(d->radius_hist.begin(), d->radius_hist.end(),
            hists_.begin() + row.offset + d->edge_hist.size());
  row.edge_n = static_cast<uint32_t>(d->edge_hist.size());
  row.radius_n = static_cast<uint32_t>(d->radius_hist.size());
  row.stamp = d->stamp;
  triangles_[i] = matchTriangles(*d, params_.matcher.neighbour_triangles);
  triangles_[i].shrink_to_fit();
  entries_[i] = std::move(d);
  return true;
}

void LoopDetector::indexEntry(const Descriptor& d, std::vector<MatchTriangle>* triangles) {
  ScreenRow row;
  const auto it = robot_ids_.emplace(d.robot, static_cast<uint32_t>(robots_.size())).first;
  if (it->second == robots_.size()) robots_.push_back(d.robot);
  row.robot = it->second;
  row.edge_n = static_cast<uint32_t>(d.edge_hist.size());
  row.radius_n = static_cast<uint32_t>(d.radius_hist.size());
  row.offset = hists_.size();
  hists_.insert(hists_.end(), d.edge_hist.begin(), d.edge_hist.end());
  hists_.insert(hists_.end(), d.radius_hist.begin(), d.radius_hist.end());
  row.stamp = d.stamp;
  row.submap_id = d.submap_id;
  screen_.push_back(row);
  triangles_.push_back(triangles ? std::move(*triangles)
                                 : matchTriangles(d, params_.matcher.neighbour_triangles));
  triangles_.back().shrink_to_fit();  // held for the database's lifetime
}

void LoopDetector::rebuildIndex(std::vector<std::vector<MatchTriangle>>* saved) {
  screen_.clear();
  hists_.clear();
  robots_.clear();
  robot_ids_.clear();
  triangles_.clear();
  triangles_.reserve(entries_.size());
  for (size_t i = 0; i < entries_.size(); ++i)
    indexEntry(*entries_[i], saved ? &(*saved)[i] : nullptr);
}

size_t LoopDetector::memoryBytes() const {
  size_t bytes = screen_.capacity() * sizeof(ScreenRow) + hists_.capacity() * sizeof(float);
  for (const auto& d : entries_) {
    bytes += sizeof(Descriptor) + d->trunks.capacity() * sizeof(TrunkLandmark) +
             d->triangles.capacity() * sizeof(Triangle) +
             (d->edge_hist.capacity() + d->radius_hist.capacity()) * sizeof(float) +
             d->footprint.bits.capacity() + d->ground_map.z.capacity() * sizeof(int16_t) +
             d->robot.capacity();
  }
  for (const auto& t : triangles_) bytes += sizeof(t) + t.capacity() * sizeof(MatchTriangle);
  return bytes;
}

std::optional<Loop> LoopDetector::query(const Descriptor& q, QueryStats* stats,
                                        std::optional<Loop>* inter_robot) const {
  if (inter_robot) inter_robot->reset();
  QueryStats local;
  QueryStats& st = stats ? *stats : local;
  st = QueryStats{};
  if (!q.valid) return std::nullopt;
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<size_t> cands = screen(q, &st);
  for (size_t i : cands) st.candidates.push_back(entries_[i]->submap_id);
  st.screen_ms = msSince(t0);
  return matchCandidates(q, cands, &st, inter_robot);
}

std::vector<size_t> LoopDetector::screen(const Descriptor& q, QueryStats* st) const {
  struct Cand {
    double sim;
    size_t index;
  };
  std::vector<Cand> cands;
  const MatcherParams& mp = params_.matcher;
  // The query's robot as an index entry's robot (none of them when it is new).
  const auto q_id = robot_ids_.find(q.robot);
  const uint32_t q_robot =
      q_id == robot_ids_.end() ? static_cast<uint32_t>(robots_.size()) : q_id->second;
  // histogramIntersection on the flat rows: 0 for a different binning or an empty histogram.
  auto intersect = [this](const std::vector<float>& a, size_t offset, uint32_t n) {
    if (a.size() != n || a.empty()) return 0.0;
    const float* b = hists_.data() + offset;
    double s = 0.0;
    for (size_t k = 0; k < n; ++k) s += std::min(a[k], b[k]);
    return s;
  };
  for (size_t i = 0; i < screen_.size(); ++i) {
    const ScreenRow& c = screen_[i];
    // A query's own submap is never its loop, whatever the time window.
    if (!eligibleLoopPair(q_robot, q.stamp, c.robot, c.stamp, params_.database.exclude_recent_s) ||
        (c.robot == q_robot && c.submap_id == q.submap_id)) {
      continue;
    }
    ++st->eligible;
    const double se = intersect(q.edge_hist, c.offset, c.edge_n);
    if (se < mp.min_edge_hist_sim) continue;
    const double sr = intersect(q.radius_hist, c.offset + c.edge_n, c.radius_n);
    if (sr < mp.min_radius_hist_sim) continue;
    cands.push_back({0.5 * (se + sr), i});
  }
  st->screened_in = cands.size();
  const size_t keep = std::min(cands.size(), static_cast<size_t>(params_.database.max_candidates));
  std::partial_sort(cands.begin(), cands.begin() + keep, cands.end(),
                    [](const Cand& a, const Cand& b) {
                      return a.sim > b.sim || (a.sim == b.sim && a.index < b.index);
                    });
  std::vector<size_t> out(keep);
  for (size_t k = 0; k < keep; ++k) out[k] = cands[k].index;
  return out;
}

std::optional<Loop> LoopDetector::matchCandidates(const Descriptor& q,
                                                  const std::vector<size_t>& cands, QueryStats* st,
                                                  std::optional<Loop>* inter_robot) const {
  const MatcherParams& mp = params_.matcher;
  std::vector<MatchTriangle> tq;
  std::vector<ConsistencyBounds> bq;  // the query's, tested against every candidate's
  if (!cands.empty()) {
    tq = matchTriangles(q, mp.neighbour_triangles);
    bq = consistencyBounds(tq, mp);
  }
  // Candidates past the best max_vote_candidates are matched without the vote fallback.
  LoopDetectorParams no_votes = params_;
  no_votes.matcher.vote_fallback = false;
  std::vector<Hypothesis> hyps;
  std::vector<const Descriptor*> matched;
  std::vector<std::optional<Verification>> verified;  // by rank, endsMatching's
  for (size_t rank = 0; rank < cands.size(); ++rank) {
    const size_t index = cands[rank];
    const bool votes = rank < static_cast<size_t>(params_.database.max_vote_candidates);
    matched.push_back(entries_[index].get());
    hyps.push_back(hypothesize(q, *matched.back(), votes ? params_ : no_votes, &solver_, st, &tq,
                               &triangles_[index], &bq));
    verified.emplace_back();
    if (endsMatching(q, *matched.back(), hyps.back(), params_, inter_robot != nullptr,
                     &verified.back(), st)) {
      break;
    }
  }
  st->hypothesized = hyps.size();
  const int budget = inter_robot ? params_.database.inter_robot_verifications : 0;
  BestLoops found = verifyBest(q, matched, hyps, verified, params_, budget, st);
  if (inter_robot) *inter_robot = std::move(found.inter_robot);
  return found.best;
}

std::vector<size_t> entriesInStampOrder(const LoopDetector& db) {
  std::vector<size_t> order(db.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    const Descriptor &da = *db.entries()[a], &dbb = *db.entries()[b];
    return da.stamp != dbb.stamp ? da.stamp < dbb.stamp : da.robot < dbb.robot;
  });
  return order;
}

}  // namespace dtif
