// Lattice search for repetitive stands (see lattice.h).
#include "dtif/core/verification/lattice.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <utility>

#include "dtif/core/pose/rigid2d.h"
#include "dtif/core/robust.h"
#include "dtif/core/verification/trunk_grid.h"

namespace dtif {
namespace {

using P2 = Eigen::Vector2d;

/// Votes of every (query, candidate) trunk pair for a translation, in square bins with one
/// empty bin of margin on each side (the 3 x 3 neighbourhoods stay inside the array).
/// The buffers are kept from one vote to the next (threadVotes): ~1 MB, four times a search.
struct TranslationVotes {
  static constexpr double kBin = 0.5;  ///< bin side [m]
  double x0 = 0.0, y0 = 0.0;           ///< lower corner [m]
  size_t w = 0, h = 0;                 ///< bins per row, rows
  std::vector<int> n;                  ///< votes per bin
  std::vector<Eigen::Vector2d> sum;    ///< sum of the voted translations per bin [m]
  std::vector<int> around;             ///< votes per 3 x 3 neighbourhood (neighbourhoodVotes)
  std::vector<int> row3;               ///< votes per 1 x 3 neighbourhood (neighbourhoodVotes)
};

/// This thread's vote buffers: a lattice search votes four times, a query up to
/// max_lattice_searches times. Out of line, so that the votes' loops do not look the
/// thread-local up again at every vote.
[[gnu::noinline]] TranslationVotes& threadVotes() {
  thread_local TranslationVotes v;
  return v;
}

/// Votes c_j - rq_i; false when the bins would exceed a bound on memory.
bool voteTranslations(const std::vector<Eigen::Vector2d>& rq, const Descriptor& c,
                      TranslationVotes* v) {
  constexpr double kBin = TranslationVotes::kBin;
  constexpr size_t kMaxBins = size_t{1} << 22;  // 1 km x 1 km of translations: a bound on memory
  // The votes' bounds: candidate extent minus rotated query extent.
  constexpr double kInf = std::numeric_limits<double>::infinity();
  Eigen::Vector2d c_lo(kInf, kInf), q_lo(kInf, kInf);
  Eigen::Vector2d c_hi = -c_lo, q_hi = -q_lo;
  for (const TrunkLandmark& b : c.trunks) {
    c_lo = c_lo.cwiseMin(Eigen::Vector2d(b.x, b.y));
    c_hi = c_hi.cwiseMax(Eigen::Vector2d(b.x, b.y));
  }
  for (const Eigen::Vector2d& p : rq) {
    q_lo = q_lo.cwiseMin(p);
    q_hi = q_hi.cwiseMax(p);
  }
  const Eigen::Vector2d lo = c_lo - q_hi, hi = c_hi - q_lo;
  const double x0 = std::floor(lo.x() / kBin) * kBin - kBin,
               y0 = std::floor(lo.y() / kBin) * kBin - kBin;
  const size_t w = static_cast<size_t>((hi.x() - x0) / kBin) + 2;
  const size_t h = static_cast<size_t>((hi.y() - y0) / kBin) + 2;
  if (w * h > kMaxBins) return false;
  v->x0 = x0, v->y0 = y0, v->w = w, v->h = h;
  v->n.assign(w * h, 0);
  v->sum.assign(w * h, Eigen::Vector2d::Zero());
  int* n = v->n.data();
  Eigen::Vector2d* sum = v->sum.data();
  for (const TrunkLandmark& b : c.trunks) {
    for (const Eigen::Vector2d& p : rq) {
      const Eigen::Vector2d t = Eigen::Vector2d(b.x, b.y) - p;
      const size_t k =
          static_cast<size_t>((t.y() - y0) / kBin) * w + static_cast<size_t>((t.x() - x0) / kBin);
      ++n[k];
      sum[k] += t;
    }
  }
  return true;
}

/// Votes in each bin's 3 x 3 neighbourhood into v->around (0 on the margin), as a sum of
/// three rows of three; `top` receives the highest.
void neighbourhoodVotes(TranslationVotes* v, int* top) {
  const size_t w = v->w, h = v->h;
  const int* n = v->n.data();
  v->around.assign(w * h, 0);
  v->row3.resize(w * h);  // only the inner columns are read
  int* around = v->around.data();
  int* row3 = v->row3.data();
  for (size_t y = 0; y < h; ++y)
    for (size_t x = 1; x + 1 < w; ++x)
      row3[y * w + x] = n[y * w + x - 1] + n[y * w + x] + n[y * w + x + 1];
  *top = 0;
  for (size_t y = 1; y + 1 < h; ++y) {
    for (size_t x = 1; x + 1 < w; ++x) {
      const int a = row3[(y - 1) * w + x] + row3[y * w + x] + row3[(y + 1) * w + x];
      around[y * w + x] = a;
      *top = std::max(*top, a);
    }
  }
}

/// (votes, bin) of the local maxima of `around` with at least floor_votes (ties: first bin).
std::vector<std::pair<int, size_t>> localMaxima(const std::vector<int>& around, size_t w, size_t h,
                                                int floor_votes) {
  std::vector<std::pair<int, size_t>> peaks;
  for (size_t y = 1; y + 1 < h; ++y) {
    for (size_t x = 1; x + 1 < w; ++x) {
      const size_t k = y * w + x;
      if (around[k] < floor_votes) continue;
      bool peak = true;
      for (size_t yy = y - 1; yy <= y + 1 && peak; ++yy) {
        for (size_t xx = x - 1; xx <= x + 1 && peak; ++xx) {
          const size_t m = yy * w + xx;
          if (m != k && (around[m] > around[k] || (around[m] == around[k] && m < k))) peak = false;
        }
      }
      if (peak) peaks.emplace_back(around[k], k);
    }
  }
  return peaks;
}

/// Pairs each trunk of `sample`, placed at place(i), with its nearest candidate trunk within
/// `radius` (not mutual) into `pairs`, then refits T0 by one round of 2-D Procrustes on them
/// (>= 2 pairs; T0 as it is otherwise).
template <class Place>
Pose pairAndRefit(const std::vector<Eigen::Vector2d>& sample, const Place& place,
                  const TrunkGrid& grid, const Pose& T0, double radius,
                  std::vector<std::pair<P2, P2>>* pairs) {
  pairs->clear();
  for (size_t i = 0; i < sample.size(); ++i) {
    int j = -1;
    grid.nearest2(place(i), radius, &j);
    if (j >= 0) pairs->emplace_back(sample[i], grid.at(j));
  }
  return pairs->size() >= 2 ? rigid2d(*pairs, T0.translation().z()) : T0;
}

/// A cheap fitPose for ranking lattice poses: pairAndRefit, then the same Tukey score of the
/// nearest trunks under the refitted pose; on `sample`, an even subset of the query trunks.
/// The best few are refined by fitPose anyway: a second Procrustes round (until 2026-11-25)
/// cost a third more and gave the same loops on the built-in scenes, seeds 1-3.
/// `scratch` is reused by the caller across the poses of a search.
std::pair<double, Pose> quickFit(const std::vector<Eigen::Vector2d>& sample, const TrunkGrid& grid,
                                 const Pose& T0, double radius, double score_radius,
                                 std::vector<std::pair<P2, P2>>* scratch) {
  const auto placed = [&](size_t i) {
    return (T0 * Eigen::Vector3d(sample[i].x(), sample[i].y(), 0.0)).head<2>().eval();
  };
  const Pose T = pairAndRefit(sample, placed, grid, T0, radius, scratch);
  double score = 0.0;
  for (const Eigen::Vector2d& t : sample) {
    int j = -1;
    const double d2 = grid.nearest2((T * Eigen::Vector3d(t.x(), t.y(), 0.0)).head<2>(), radius, &j);
    if (j >= 0) score += tukeyWeightOfSquare(d2, score_radius);
  }
  return {score, T};
}

/// quickFit's first half, for a first ranking of all lattice poses: the Tukey score of the
/// pairs that the refit used, under the refitted pose, instead of a second nearest-trunk
/// lookup per sample trunk (about half of quickFit's cost). The two differ only where the refit
/// moves a trunk onto another nearest one; on the plantation replay (seeds 1-3, 204 searches)
/// quickFit's best pose ranked first here in 95 % of the searches and 167th at worst.
/// `turned`: the sample under T0's rotation alone, the same for every peak of a quarter turn.
double coarseFit(const std::vector<Eigen::Vector2d>& sample, const std::vector<P2>& turned,
                 const TrunkGrid& grid, const Pose& T0, double radius, double score_radius,
                 std::vector<std::pair<P2, P2>>* scratch) {
  const P2 shift = T0.translation().head<2>();
  const auto placed = [&](size_t i) { return (turned[i] + shift).eval(); };
  const Pose T = pairAndRefit(sample, placed, grid, T0, radius, scratch);
  double score = 0.0;
  for (const auto& [a, b] : *scratch)
    score += tukeyWeightOfSquare(
        ((T * Eigen::Vector3d(a.x(), a.y(), 0.0)).head<2>() - b).squaredNorm(), score_radius);
  return score;
}

/// The best poses of every lattice-consistent candidate (T0's yaw turned by 0, 90, 180 and
/// 270 deg, each with its translationPeaks), coarse to fine: all ranked by coarseFit, the best
/// params.lattice_refined_poses of them by quickFit (0: all by quickFit, in peak order), on an
/// even sample of the query trunks. Returns the best `full` of those, (quickFit score, pose),
/// best first.
std::vector<std::pair<double, Pose>> rankLatticePoses(const Descriptor& q, const Descriptor& c,
                                                      const Pose& T0, const VerifierParams& params,
                                                      size_t* full) {
  constexpr size_t kPeaksPerTurn = 2000;  // a bound on the work, far above a submap's sites
  constexpr size_t kFullFits = 8;
  constexpr size_t kSample = 80;
  const double radius = params.match_radius_m;
  const double score_radius = params.fit_score_radius_m;
  const double yaw0 = std::atan2(T0.linear()(1, 0), T0.linear()(0, 0));
  std::vector<Eigen::Vector2d> c_xy;
  c_xy.reserve(c.trunks.size());
  for (const TrunkLandmark& t : c.trunks) c_xy.emplace_back(t.x, t.y);
  const TrunkGrid grid(std::move(c_xy), radius);
  std::vector<Eigen::Vector2d> sample;  // at most kSample query trunks, evenly over the list
  const size_t stride = (q.trunks.size() + kSample - 1) / kSample;
  for (size_t i = 0; i < q.trunks.size(); i += stride)
    sample.emplace_back(q.trunks[i].x, q.trunks[i].y);
  const bool refine_all = params.lattice_refined_poses == 0;
  std::vector<std::pair<double, Pose>> coarse;  // (coarseFit score, unrefitted pose)
  std::vector<std::pair<P2, P2>> pairs;
  pairs.reserve(sample.size());
  for (int turn = 0; turn < 4; ++turn) {
    const double yaw = yaw0 + turn * M_PI / 2.0;
    const Eigen::Matrix2d R = Eigen::Rotation2Dd(yaw).toRotationMatrix();
    Pose turn_only = Pose::Identity();
    turn_only.linear() = rotZ(yaw);
    std::vector<P2> turned;
    for (const P2& s : sample)
      turned.push_back((turn_only * Eigen::Vector3d(s.x(), s.y(), 0.0)).head<2>());
    for (const Eigen::Vector2d& t : translationPeaks(q, c, R, params.min_inliers, kPeaksPerTurn)) {
      Pose T = turn_only;
      T.translation() = Eigen::Vector3d(t.x(), t.y(), T0.translation().z());
      coarse.emplace_back(
          refine_all ? 0.0 : coarseFit(sample, turned, grid, T, radius, score_radius, &pairs), T);
    }
  }
  // The best `refine` by coarseFit; equal scores in the order of the peaks (turn, then votes).
  const size_t refine =
      refine_all ? coarse.size()
                 : std::min(static_cast<size_t>(params.lattice_refined_poses), coarse.size());
  std::vector<size_t> order(coarse.size());
  std::iota(order.begin(), order.end(), size_t{0});
  if (!refine_all) {
    std::partial_sort(order.begin(), order.begin() + refine, order.end(), [&](size_t a, size_t b) {
      return coarse[a].first > coarse[b].first || (coarse[a].first == coarse[b].first && a < b);
    });
  }
  std::vector<std::pair<double, Pose>> ranked;
  for (size_t k = 0; k < refine; ++k)
    ranked.push_back(quickFit(sample, grid, coarse[order[k]].second, radius, score_radius, &pairs));
  *full = std::min(kFullFits, ranked.size());
  std::partial_sort(ranked.begin(), ranked.begin() + *full, ranked.end(),
                    [](const auto& x, const auto& y) { return x.first > y.first; });
  return ranked;
}

}  // namespace

Fit fitPose(const Descriptor& q, const Descriptor& c, const RefineTargets& targets, const Pose& T0,
            double score_radius) {
  Fit f;
  const Refined r = guidedRefine(q, targets, T0);
  f.T = r.T;
  f.pairs = r.pairs;
  std::vector<double> residual;
  for (const auto& [i, j] : r.pairs) {
    const Eigen::Vector2d d = (r.T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, 0.0)).head<2>() -
                              Eigen::Vector2d(c.trunks[j].x, c.trunks[j].y);
    f.score += tukeyWeightOfSquare(d.squaredNorm(), score_radius);
    residual.push_back(d.norm());
  }
  if (!residual.empty()) {
    const auto mid = residual.begin() + residual.size() / 2;
    std::nth_element(residual.begin(), mid, residual.end());
    f.median_xy = *mid;
  }
  return f;
}

std::vector<Eigen::Vector2d> translationPeaks(const Descriptor& q, const Descriptor& c,
                                              const Eigen::Matrix2d& R, int min_votes,
                                              size_t max_peaks) {
  std::vector<Eigen::Vector2d> rq;
  for (const TrunkLandmark& a : q.trunks) rq.push_back(R * Eigen::Vector2d(a.x, a.y));
  if (rq.empty() || c.trunks.empty()) return {};
  TranslationVotes& v = threadVotes();
  if (!voteTranslations(rq, c, &v)) return {};
  int top = 0;
  neighbourhoodVotes(&v, &top);
  const std::vector<int>& around = v.around;
  // A site pairing under a third of the trunks that the best-paired site pairs cannot beat it
  // by the margin that verification demands (max_fit_ambiguity): a true site scores up to ~0.9
  // per pair, a wrong one ~0.2 (fit_score_radius_m 0.2 m, 0.15 m jitter).
  const int floor_votes = std::max(min_votes, top / 3);
  std::vector<std::pair<int, size_t>> peaks = localMaxima(around, v.w, v.h, floor_votes);
  std::stable_sort(peaks.begin(), peaks.end(),
                   [](const auto& u, const auto& w) { return u.first > w.first; });
  if (peaks.size() > max_peaks) peaks.resize(max_peaks);
  const size_t w = v.w;
  std::vector<Eigen::Vector2d> out;
  for (const auto& [votes, k] : peaks) {
    Eigen::Vector2d t = Eigen::Vector2d::Zero();
    for (size_t yy = k / w - 1; yy <= k / w + 1; ++yy)
      for (size_t xx = k % w - 1; xx <= k % w + 1; ++xx) t += v.sum[yy * w + xx];
    out.push_back(t / static_cast<double>(votes));
  }
  // Submap pairs vote into ~10^5 bins; an outsized pair's buffers are not held on to.
  constexpr size_t kKeptBins = size_t{1} << 20;
  if (v.n.capacity() > kKeptBins) v = TranslationVotes{};
  return out;
}

std::pair<Fit, double> resolveByFit(const Descriptor& q, const Descriptor& c, const Pose& T0,
                                    const VerifierParams& params) {
  const double radius = params.match_radius_m;
  const double score_radius = params.fit_score_radius_m;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  for (const TrunkLandmark& t : q.trunks) centroid += Eigen::Vector2d(t.x, t.y);
  centroid /= static_cast<double>(q.trunks.size());
  // Every lattice pose ranked by quickFit; the best few are fitted exactly.
  size_t full = 0;
  const std::vector<std::pair<double, Pose>> ranked = rankLatticePoses(q, c, T0, params, &full);
  const RefineTargets targets(c, radius);  // one grid for the fits below
  std::vector<Fit> fits{fitPose(q, c, targets, T0, score_radius)};
  for (size_t k = 0; k < full; ++k)
    fits.push_back(fitPose(q, c, targets, ranked[k].second, score_radius));
  std::stable_sort(fits.begin(), fits.end(),
                   [](const Fit& x, const Fit& y) { return x.score > y.score; });
  const Fit& best = fits.front();
  // The runner-up must be another pose, not the winner reached from a second start.
  double runner = 0.0;
  for (size_t i = 1; i < fits.size(); ++i) {
    const Pose D = best.T.inverse() * fits[i].T;
    const Eigen::Vector3d p = fits[i].T * Eigen::Vector3d(centroid.x(), centroid.y(), 0.0);
    const Eigen::Vector3d pb = best.T * Eigen::Vector3d(centroid.x(), centroid.y(), 0.0);
    const double dyaw = std::abs(std::atan2(D.linear()(1, 0), D.linear()(0, 0)));
    if ((p - pb).head<2>().norm() > radius || dyaw > 5.0 * M_PI / 180.0) {
      runner = fits[i].score;
      break;
    }
  }
  return {best, best.score > 0.0 ? runner / best.score : 1.0};
}

}  // namespace dtif
