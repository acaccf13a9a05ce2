// False-loop verification of a pose hypothesis (see verification.h).
#include "dtif/core/verification/verification.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <sstream>

#include "dtif/core/extraction/footprint.h"
#include "dtif/core/pose/rigid2d.h"
#include "dtif/core/verification/elevation.h"
#include "dtif/core/verification/lattice.h"
#include "dtif/core/verification/trunk_grid.h"

namespace dtif {
namespace {

using P2 = Eigen::Vector2d;

double cross(const P2& o, const P2& a, const P2& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

/// Convex hull, counter-clockwise (Andrew's monotone chain). CGAL stays in descriptor.cpp.
std::vector<P2> convexHull(std::vector<P2> p) {
  std::sort(p.begin(), p.end(), [](const P2& a, const P2& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  if (p.size() < 3) return p;
  std::vector<P2> h(2 * p.size());
  size_t k = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (size_t i = p.size() - 1, t = k + 1; i > 0; --i) {
    while (k >= t && cross(h[k - 2], h[k - 1], p[i - 1]) <= 0) --k;
    h[k++] = p[i - 1];
  }
  h.resize(k - 1);
  return h;
}

bool insideHull(const std::vector<P2>& hull, const P2& p) {
  if (hull.size() < 3) return false;
  for (size_t i = 0; i < hull.size(); ++i) {
    if (cross(hull[i], hull[(i + 1) % hull.size()], p) < 0) return false;
  }
  return true;
}

/// Of the points of `a` inside the hull of `b`, how many have a partner in `b` within radius.
void coLocated(const std::vector<P2>& a, const std::vector<P2>& b, double radius, int* inside,
               int* matched) {
  const std::vector<P2> hull = convexHull(b);
  const double r2 = radius * radius;
  for (const P2& p : a) {
    if (!insideHull(hull, p)) continue;
    ++*inside;
    for (const P2& q : b) {
      if ((p - q).squaredNorm() <= r2) {
        ++*matched;
        break;
      }
    }
  }
}

/// A refinement looks up each query trunk at most five times: a grid of about as many cells
/// as trunks costs less to build than a fine one, at a few more trunks per lookup.
constexpr double kRefineCellsPerTrunk = 4.0;

/// Mutually nearest trunk pairs within `radius` (<= the grid's reach) of the placed query
/// trunks pq and the candidate trunks in `grid`. Ties go as in a scan of every (i, j) in index
/// order that takes the later of equal distances: to the larger index (the order in which a
/// run lists the candidates does not matter).
std::vector<std::pair<int, int>> mutualPairs(const std::vector<P2>& pq, const TrunkGrid& grid,
                                             double radius) {
  const double r2 = radius * radius;
  std::vector<int> nq(pq.size(), -1), nc(grid.size(), -1);
  std::vector<double> dc(grid.size(), r2);
  for (size_t i = 0; i < pq.size(); ++i) {
    const TrunkGrid::Run run = grid.near(pq[i]);
    double best = r2;
    for (int m = 0; m < run.size; ++m) {
      const int j = run.index[m];
      const double d = (pq[i] - run.xy[m]).squaredNorm();
      if (d < best || (d == best && j > nq[i])) best = d, nq[i] = j;
      if (d <= dc[j]) dc[j] = d, nc[j] = static_cast<int>(i);
    }
  }
  std::vector<std::pair<int, int>> out;
  for (size_t i = 0; i < pq.size(); ++i) {
    if (nq[i] >= 0 && nc[nq[i]] == static_cast<int>(i)) out.emplace_back(i, nq[i]);
  }
  return out;
}

/// The trunks' centres, horizontally.
std::vector<P2> xyOf(const Trunks& trunks) {
  std::vector<P2> out;
  out.reserve(trunks.size());
  for (const TrunkLandmark& t : trunks) out.emplace_back(t.x, t.y);
  return out;
}

/// The trunks' centres placed by T, horizontally.
std::vector<P2> placedXy(const Trunks& trunks, const Pose& T) {
  std::vector<P2> out;
  out.reserve(trunks.size());
  for (const TrunkLandmark& t : trunks)
    out.push_back((T * Eigen::Vector3d(t.x, t.y, t.z)).head<2>());
  return out;
}

/// RMS horizontal distance of the (query, candidate) pairs, the query's trunks placed by T.
double planarRms(const Trunks& tq, const std::vector<P2>& pc, const Pose& T,
                 const std::vector<std::pair<int, int>>& pairs) {
  double sxy = 0.0;
  for (const auto& [i, j] : pairs) {
    sxy += ((T * Eigen::Vector3d(tq[i].x, tq[i].y, tq[i].z)).head<2>() - pc[j]).squaredNorm();
  }
  return std::sqrt(sxy / pairs.size());
}

/// Repetitive stands (plantation grids) support several poses almost equally; a loop is only
/// trusted when the chosen hypothesis clearly dominates the runner-up in yaw and translation.
double hypothesisAmbiguity(const PoseEstimate& est) {
  const double amb_yaw = est.yaw_consensus > 0 ? est.yaw_runner_up / est.yaw_consensus : 1.0;
  const double amb_t =
      est.translation_consensus > 0 ? est.translation_runner_up / est.translation_consensus : 1.0;
  return std::max(amb_yaw, amb_t);
}

/// Rejects on the solver's hypothesis alone (pose, inliers, weight, and ambiguity the lattice
/// fit cannot resolve). Otherwise sets v->ambiguity (and fit_ambiguity) and T_hyp, the pose to
/// refine: the solver's, or the lattice fit's when the stand is repetitive.
Rejection checkHypothesis(const Descriptor& q, const Descriptor& c, const PoseEstimate& est,
                          const VerifierParams& params, Verification* v, Pose* T_hyp) {
  const Rejection none = hypothesisRejection(est, params);
  if (none != Rejection::kNone) return none;

  v->ambiguity = hypothesisAmbiguity(est);
  *T_hyp = est.T_c_q;
  if (v->ambiguity > params.max_ambiguity) {
    // The correspondences alone cannot tell the lattice sites apart; the fit of all trunks can
    // when the stand's irregularity exceeds the trunk-centre noise.
    if (params.max_fit_ambiguity <= 0.0) return Rejection::kAmbiguous;
    const auto [fit, ratio] = resolveByFit(q, c, est.T_c_q, params);
    v->fit_ambiguity = ratio;
    if (ratio > params.max_fit_ambiguity) return Rejection::kAmbiguous;
    // A wrong site of a jittered lattice pairs every trunk too, but only to the jitter. The
    // median, not the RMS: the right site's few false or shifted trunks paired up to
    // match_radius_m away would push its RMS above a wrong site's.
    if (fit.median_xy > params.max_fit_median_m) return Rejection::kAmbiguous;
    *T_hyp = fit.T;
  }
  return Rejection::kNone;
}

/// The refinement must stay near the hypothesis: a jump means it locked onto other trunks,
/// which moves the paired trunks' centroid by about a tree spacing or turns them by degrees.
/// Measured at that centroid, where the submaps overlap and the correspondences lie (the raw
/// translation swings with the yaw when the coordinates are far from the origin, e.g. UTM,
/// and a rough hypothesis' yaw, corrected, moves trunks 30 m out by decimetres: 0.7 deg,
/// 0.37 m).
bool refinementDiverged(const Descriptor& q, const Refined& ref, const Pose& T_hyp,
                        const VerifierParams& params) {
  constexpr double kMaxRefineYawRad = 3.0 * M_PI / 180.0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& [i, j] : ref.pairs)
    centroid += Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, 0.0);
  if (!ref.pairs.empty()) centroid /= static_cast<double>(ref.pairs.size());
  const double shift = ((ref.T * centroid) - (T_hyp * centroid)).head<2>().norm();
  const Eigen::Matrix3d dR = T_hyp.linear().transpose() * ref.T.linear();
  if (std::abs(std::atan2(dR(1, 0), dR(0, 0))) > kMaxRefineYawRad) return true;
  return shift > params.match_radius_m;
}

/// Co-visibility: after alignment, trunks of one submap inside the other's footprint (convex
/// hull) must mostly have a partner. A false loop explains its inliers but not the rest.
/// Sets v's covisible fields.
Rejection checkCovisibility(const Descriptor& q, const Descriptor& c, const Pose& T,
                            const VerifierParams& params, Verification* v) {
  const std::vector<P2> pq = placedXy(q.trunks, T), pc = xyOf(c.trunks);
  int inside = 0, matched = 0;
  coLocated(pq, pc, params.match_radius_m, &inside, &matched);
  coLocated(pc, pq, params.match_radius_m, &inside, &matched);
  v->covisible = matched;
  v->covisible_ratio = inside > 0 ? static_cast<double>(matched) / inside : 0.0;
  if (matched < params.min_covisible) return Rejection::kFewCovisible;
  if (v->covisible_ratio < params.min_covisible_ratio) return Rejection::kLowCovisibility;
  return Rejection::kNone;
}

}  // namespace

const char* toString(Rejection r) {
  switch (r) {
    case Rejection::kNone:
      return "none";
    case Rejection::kFewCorrespondences:
      return "few correspondences";
    case Rejection::kNoPose:
      return "no pose";
    case Rejection::kFewHypothesisInliers:
      return "few hypothesis inliers";
    case Rejection::kLowInlierWeight:
      return "low inlier weight";
    case Rejection::kAmbiguous:
      return "ambiguous";
    case Rejection::kRefinementDiverged:
      return "refinement diverged";
    case Rejection::kFewInliers:
      return "few inliers";
    case Rejection::kElevationUnobserved:
      return "elevation unobserved";
    case Rejection::kElevationAmbiguous:
      return "elevation ambiguous";
    case Rejection::kLargeResidual:
      return "large residual";
    case Rejection::kFewCovisible:
      return "few co-visible trunks";
    case Rejection::kLowCovisibility:
      return "low co-visibility";
    case Rejection::kSmallOverlap:
      return "small overlap";
    case Rejection::kNoVotedPose:
      return "no voted pose";
    case Rejection::kAmbiguousVotes:
      return "ambiguous votes";
    case Rejection::kFewVotedPairs:
      return "few voted pairs";
  }
  return "unknown";
}

bool isNoHypothesis(Rejection r) {
  return r == Rejection::kFewCorrespondences || r == Rejection::kNoPose ||
         r == Rejection::kFewHypothesisInliers || r == Rejection::kLowInlierWeight;
}

std::string Verification::reason() const {
  if (rejection == Rejection::kNone) return std::string();
  std::string out = toString(rejection);
  if (vote_rejection != Rejection::kNone)
    out += std::string("; votes: ") + toString(vote_rejection);
  return out;
}

std::string VerifierParams::validate() const {
  std::ostringstream err;
  if (min_hypothesis_inliers < 3) err << "min_hypothesis_inliers must be >= 3; ";
  if (min_inliers < 3) err << "min_inliers must be >= 3; ";
  if (!(min_inlier_weight >= 0.0)) err << "min_inlier_weight must be >= 0; ";
  if (!(max_rms_xy_m > 0.0)) err << "max_rms_xy_m must be > 0; ";
  if (!(match_radius_m > 0.0 && std::isfinite(match_radius_m))) {
    err << "match_radius_m must be > 0; ";
  }
  if (!(min_covisible_ratio >= 0.0 && min_covisible_ratio <= 1.0)) {
    err << "min_covisible_ratio must be in [0, 1]; ";
  }
  if (min_covisible < 0) err << "min_covisible must be >= 0; ";
  if (!(max_ambiguity >= 0.0 && max_ambiguity <= 1.0)) err << "max_ambiguity must be in [0, 1]; ";
  if (tilt_min_pairs < 0) err << "tilt_min_pairs must be >= 0 (0: no tilt); ";
  if (tilt_min_pairs > 0 && tilt_min_pairs < 4) err << "tilt_min_pairs must be 0 or >= 4; ";
  if (!(tilt_min_spread_m >= 0.0)) err << "tilt_min_spread_m must be >= 0; ";
  if (!(max_tilt_deg > 0.0 && max_tilt_deg <= 10.0)) err << "max_tilt_deg must be in (0, 10]; ";
  if (!(tilt_prior_deg >= 0.0 && tilt_prior_deg <= 10.0))
    err << "tilt_prior_deg must be in [0, 10] (0: no prior); ";
  if (!(base_sigma_m > 0.0)) err << "base_sigma_m must be > 0; ";
  if (tilt_min_ground_cells < 0) err << "tilt_min_ground_cells must be >= 0 (0: bases only); ";
  if (!(ground_cell_sigma_m > 0.0 && std::isfinite(ground_cell_sigma_m)))
    err << "ground_cell_sigma_m must be > 0; ";
  if (!(ground_tilt_floor_deg >= 0.0 && ground_tilt_floor_deg <= 10.0))
    err << "ground_tilt_floor_deg must be in [0, 10]; ";
  if (!(min_overlap >= 0.0 && min_overlap <= 1.0)) err << "min_overlap must be in [0, 1]; ";
  if (!(max_fit_median_m > 0.0)) err << "max_fit_median_m must be > 0; ";
  if (lattice_refined_poses < 0) err << "lattice_refined_poses must be >= 0 (0: all); ";
  if (!(fit_score_radius_m > 0.0 && std::isfinite(fit_score_radius_m))) {
    err << "fit_score_radius_m must be > 0; ";
  }
  if (min_z_pairs < 0) err << "min_z_pairs must be >= 0; ";
  if (!(max_z_ambiguity >= 0.0)) err << "max_z_ambiguity must be >= 0; ";
  if (min_ground_cells < 0) err << "min_ground_cells must be >= 0; ";
  if (!(ground_window_m > 0.0 && ground_window_m <= 1.0))
    err << "ground_window_m must be in (0, 1]; ";
  if (!(max_ground_ambiguity >= 0.0 && max_ground_ambiguity <= 1.0))
    err << "max_ground_ambiguity must be in [0, 1]; ";
  if (!(ground_tilt_search_deg >= 0.0 && ground_tilt_search_deg <= 5.0))
    err << "ground_tilt_search_deg must be in [0, 5] (0: no search); ";
  if (!(own_match_radius_m >= 0.0 && std::isfinite(own_match_radius_m))) {
    err << "own_match_radius_m must be >= 0 (0: off); ";
  }
  if (own_min_pairs < 2) err << "own_min_pairs must be >= 2; ";
  if (!(max_fit_ambiguity >= 0.0 && max_fit_ambiguity < 1.0)) {
    err << "max_fit_ambiguity must be in [0, 1) (0: ambiguous hypotheses are rejected); ";
  }
  return err.str();
}

Rejection hypothesisRejection(const PoseEstimate& est, const VerifierParams& params) {
  if (!est.ok) return Rejection::kNoPose;
  if (static_cast<int>(est.inliers_T.size()) < params.min_hypothesis_inliers) {
    return Rejection::kFewHypothesisInliers;
  }
  if (est.inlier_weight < params.min_inlier_weight) return Rejection::kLowInlierWeight;
  return Rejection::kNone;
}

bool needsLatticeSearch(const PoseEstimate& est, const VerifierParams& params) {
  return hypothesisRejection(est, params) == Rejection::kNone &&
         hypothesisAmbiguity(est) > params.max_ambiguity && params.max_fit_ambiguity > 0.0;
}

double inlierWeightShare(const std::vector<Correspondence>& corrs, const PoseEstimate& est) {
  double total_w = 0.0;
  for (const Correspondence& k : corrs) total_w += k.w;
  double inlier_w = 0.0;  // in omega units even with unit_weights, so scores stay comparable
  for (int i : est.inliers_T) inlier_w += corrs[i].w;
  return total_w > 0 ? inlier_w / total_w : 0.0;
}

RefineTargets::RefineTargets(const Descriptor& c, double r)
    : xy(xyOf(c.trunks)), radius(r), grid(xy, r, kRefineCellsPerTrunk) {}

Refined guidedRefine(const Descriptor& q, const Descriptor& c, const Pose& T0, double radius) {
  return guidedRefine(q, RefineTargets(c, radius), T0);
}

Refined guidedRefine(const Descriptor& q, const RefineTargets& c, const Pose& T0) {
  Refined out;
  out.T = T0;
  const std::vector<P2>& pc = c.xy;
  const TrunkGrid& grid = c.grid;
  const double radius = c.radius;
  for (int it = 0; it < 5; ++it) {
    const std::vector<P2> pq = placedXy(q.trunks, out.T);
    std::vector<std::pair<int, int>> pairs = mutualPairs(pq, grid, radius);
    if (pairs.size() < 2) break;
    if (pairs == out.pairs) break;
    out.pairs = pairs;
    std::vector<std::pair<P2, P2>> points;
    for (const auto& [i, j] : pairs) points.emplace_back(P2(q.trunks[i].x, q.trunks[i].y), pc[j]);
    out.T = rigid2d(points, out.T.translation().z());  // refineElevation fixes t_z
  }
  if (!out.pairs.empty()) out.rms_xy = planarRms(q.trunks, pc, out.T, out.pairs);
  return out;
}

bool refineOnOwnTrunks(const Descriptor& q, const Descriptor& c, const VerifierParams& params,
                       Verification* v) {
  if (!(params.own_match_radius_m > 0.0) || (!q.accumulated && !c.accumulated)) return false;
  const Trunks& tq = q.observedTrunks();
  const Trunks& tc = c.observedTrunks();
  const std::vector<P2> pc = xyOf(tc);
  const TrunkGrid grid(pc, params.own_match_radius_m, kRefineCellsPerTrunk);
  Pose T = v->T_c_q;
  std::vector<std::pair<int, int>> pairs;
  std::vector<PointPair2d> pts;
  for (int it = 0; it < 5; ++it) {
    const std::vector<P2> pq = placedXy(tq, T);
    std::vector<std::pair<int, int>> now = mutualPairs(pq, grid, params.own_match_radius_m);
    if (static_cast<int>(now.size()) < params.own_min_pairs) return false;
    if (now == pairs) break;
    pairs = std::move(now);
    pts.clear();
    for (const auto& [i, j] : pairs) pts.emplace_back(pq[i], pc[j]);
    T = rigid2d(pts, 0.0) * T;  // a planar correction on top of the full pose
  }
  if (planarRms(tq, pc, T, pairs) > params.max_rms_xy_m) return false;
  v->T_c_q = T;
  return true;
}

Verification verifyLoop(const Descriptor& q, const Descriptor& c,
                        const std::vector<Correspondence>& corrs, const PoseEstimate& est,
                        const VerifierParams& params) {
  Verification v;
  auto reject = [&](Rejection why) {
    v.accepted = false;
    v.rejection = why;
    return v;
  };
  Pose T_hyp = est.T_c_q;
  Rejection why = checkHypothesis(q, c, est, params, &v, &T_hyp);
  if (why != Rejection::kNone) return reject(why);

  Refined ref = guidedRefine(q, c, T_hyp, params.match_radius_m);
  v.rms_z_m = refineElevation(q, c, ref.pairs, params, &ref.T, &v);
  v.T_c_q = ref.T;
  v.pairs = ref.pairs;
  v.rms_xy_m = ref.rms_xy;
  if (refinementDiverged(q, ref, T_hyp, params)) return reject(Rejection::kRefinementDiverged);
  if (static_cast<int>(ref.pairs.size()) < params.min_inliers) {
    return reject(Rejection::kFewInliers);
  }
  why = checkElevation(q, c, params, &ref.T, &v);
  if (why != Rejection::kNone) return reject(why);
  if (ref.rms_xy > params.max_rms_xy_m) return reject(Rejection::kLargeResidual);
  why = checkCovisibility(q, c, ref.T, params, &v);
  if (why != Rejection::kNone) return reject(why);
  // A correct alignment of two submaps that barely overlap is not a loop worth closing (and
  // not one by the evaluation protocol): measure the overlap as DATASET.md defines it.
  v.overlap = footprintOverlap(q.footprint, c.footprint, v.T_c_q);
  if (v.overlap >= 0.0 && v.overlap < params.min_overlap) return reject(Rejection::kSmallOverlap);

  v.score = v.covisible_ratio * inlierWeightShare(corrs, est);
  v.accepted = true;
  refineOnOwnTrunks(q, c, params, &v);
  return v;
}

}  // namespace dtif
