// Descriptor database, loop query and false-loop verification.
#include "dtif/core/database/loop_detector.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "core/byte_io.h"
#include "dtif/core/matching/pair_vote.h"
#include "dtif/core/pose/rigid2d.h"
#include "dtif/core/robust.h"

namespace dtif {
namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

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
/// Floor on the variance of a roll/pitch fitted to seen stem bases: (0.05 deg)^2.
constexpr double kMinFittedTiltVar = (0.05 * M_PI / 180.0) * (0.05 * M_PI / 180.0);
constexpr double kMinYawVar = (0.1 * M_PI / 180.0) * (0.1 * M_PI / 180.0);

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

struct Refined {
  Pose T = Pose::Identity();
  std::vector<std::pair<int, int>> pairs;
  double rms_xy = 0.0;  ///< of the pairs [m]; the elevation is refineElevation's
};

/// Mutually nearest trunk pairs within `radius` under T_c_q.
std::vector<std::pair<int, int>> mutualPairs(const std::vector<P2>& pq, const std::vector<P2>& pc,
                                             double radius) {
  const double r2 = radius * radius;
  std::vector<int> nq(pq.size(), -1), nc(pc.size(), -1);
  std::vector<double> dq(pq.size(), r2), dc(pc.size(), r2);
  for (size_t i = 0; i < pq.size(); ++i) {
    for (size_t j = 0; j < pc.size(); ++j) {
      const double d = (pq[i] - pc[j]).squaredNorm();
      if (d <= dq[i]) dq[i] = d, nq[i] = static_cast<int>(j);
      if (d <= dc[j]) dc[j] = d, nc[j] = static_cast<int>(i);
    }
  }
  std::vector<std::pair<int, int>> out;
  for (size_t i = 0; i < pq.size(); ++i) {
    if (nq[i] >= 0 && nc[nq[i]] == static_cast<int>(i)) out.emplace_back(i, nq[i]);
  }
  return out;
}

/// Elevation (and, with enough well-spread pairs, residual roll/pitch) of `T` from the pairs
/// whose stem bases were both seen; all pairs vote only when none was. A robust (Tukey) fit of
/// dz = t_z + a x + b y over the pairs, x, y the query trunk in the candidate frame; the plane's
/// slopes are the small rotation left between the two gravity estimates.
/// t_z starts from the mode of the pairs' elevation differences, not their median: in dense
/// understory a "seen" base can sit on a shrub, decimetres high, and when half of a few pairs are
/// wrong a median picks one of them.
/// Returns the RMS elevation residual over the pairs used [m] and fills v's elevation fields:
/// z_pairs, the seen-base pairs that agree with the mode (0: t_z is a guess); z_ambiguity, the
/// largest group of seen-base pairs agreeing on another t_z over the mode's (left as is when
/// no base pair was seen); tilt_fitted, and then roll_var and pitch_var.
double refineElevation(const Descriptor& q, const Descriptor& c,
                       const std::vector<std::pair<int, int>>& pairs, const VerifierParams& params,
                       Pose* T, Verification* v) {
  std::vector<std::pair<int, int>> use;
  for (const auto& [i, j] : pairs)
    if (q.trunks[i].base_seen && c.trunks[j].base_seen) use.emplace_back(i, j);
  const bool seen = !use.empty();
  v->z_pairs = static_cast<int>(use.size());
  v->tilt_fitted = false;
  if (!seen) use = pairs;
  if (use.empty()) return 0.0;
  const auto rmsZ = [&]() {
    double sz = 0.0;
    for (const auto& [i, j] : use) {
      const Eigen::Vector3d p = *T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, q.trunks[i].z);
      sz += (c.trunks[j].z - p.z()) * (c.trunks[j].z - p.z());
    }
    return std::sqrt(sz / static_cast<double>(use.size()));
  };
  std::vector<Eigen::Vector2d> xy;
  std::vector<double> dz;
  for (const auto& [i, j] : use) {
    const Eigen::Vector3d p = *T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, q.trunks[i].z);
    xy.push_back(p.head<2>());
    dz.push_back(c.trunks[j].z - p.z());
  }
  // Mode: the difference with the largest Tukey-weighted support, refined to the weighted mean
  // of its supporters. Window 0.25 m: bases are cm-level, and a residual tilt of 0.5 deg moves
  // pairs 20 m apart by 0.17 m; a wrong base is decimetres off.
  constexpr double kZWindow = 0.25;
  double mode = dz[0], best_support = -1.0;
  for (double z0 : dz) {
    double support = 0.0;
    for (double z1 : dz) support += tukeyWeight(z1 - z0, kZWindow);
    if (support > best_support + 1e-12) best_support = support, mode = z0;
  }
  double sw = 0.0, swz = 0.0;
  int agree = 0;
  for (double z1 : dz) {
    const double w = tukeyWeight(z1 - mode, kZWindow);
    sw += w;
    swz += w * z1;
    agree += std::abs(z1 - mode) < kZWindow;
  }
  const double z_mode = swz / sw;  // the robust start value of the tilt fit below
  if (seen) v->z_pairs = agree;
  // Runner-up elevation: the largest group of the other pairs that agree among themselves. Two
  // neighbouring stems whose bases both sit on one shrub or log agree on a wrong t_z as well
  // as two good ones agree on the right one.
  if (seen) {
    int second = 0;
    for (double z0 : dz) {
      if (std::abs(z0 - mode) < kZWindow) continue;
      int n = 0;
      for (double z1 : dz) n += std::abs(z1 - mode) >= kZWindow && std::abs(z1 - z0) < kZWindow;
      second = std::max(second, n);
    }
    v->z_ambiguity = static_cast<double>(second) / std::max(agree, 1);
  }
  T->translation().z() += z_mode;

  if (!seen || params.tilt_min_pairs <= 0 || static_cast<int>(use.size()) < params.tilt_min_pairs)
    return rmsZ();
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : xy) mean += p;
  mean /= static_cast<double>(xy.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& p : xy) cov += (p - mean) * (p - mean).transpose();
  cov /= static_cast<double>(xy.size());
  const double spread = std::sqrt(
      std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues().minCoeff()));
  if (spread < params.tilt_min_spread_m) return rmsZ();
  // IRLS with Tukey weights from the mode; c = 0.15 m (base estimates are cm-level,
  // a wrong base is decimetres off).
  constexpr double kTukeyC = 0.15;
  Eigen::Vector3d s(z_mode, 0.0, 0.0);  // dz = s0 + s1 (x - mean.x) + s2 (y - mean.y)
  // Zero-mean prior on the slopes: (sigma_base / sigma_tilt)^2 per slope, in units of a
  // full-weight pair.
  double prior = 0.0;
  if (params.tilt_prior_deg > 0.0) {
    const double sigma_tilt = std::tan(params.tilt_prior_deg * M_PI / 180.0);
    prior = (params.base_sigma_m / sigma_tilt) * (params.base_sigma_m / sigma_tilt);
  }
  Eigen::Matrix3d info = Eigen::Matrix3d::Identity();
  for (int it = 0; it < 10; ++it) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    A(1, 1) = A(2, 2) = prior;
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < xy.size(); ++k) {
      const Eigen::Vector3d J(1.0, xy[k].x() - mean.x(), xy[k].y() - mean.y());
      const double r = dz[k] - J.dot(s);
      const double w = tukeyWeight(r, kTukeyC);
      if (w == 0.0) continue;
      A += w * J * J.transpose();
      b += w * J * dz[k];
    }
    if (A.determinant() <= 1e-9) return rmsZ();
    info = A;
    const Eigen::Vector3d next = A.ldlt().solve(b);
    if (!next.allFinite()) return rmsZ();
    const bool done = (next - s).norm() < 1e-7;
    s = next;
    if (done) break;
  }
  const double max_slope = std::tan(params.max_tilt_deg * M_PI / 180.0);
  if (std::hypot(s(1), s(2)) > max_slope) return rmsZ();
  // z' = z - beta x + alpha y for a small rotation R_x(alpha) R_y(beta) about `mean`.
  const double alpha = std::asin(std::clamp(s(2), -1.0, 1.0));
  const double beta = -std::asin(std::clamp(s(1), -1.0, 1.0));
  const Eigen::Matrix3d R_tilt = (Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitX()) *
                                  Eigen::AngleAxisd(beta, Eigen::Vector3d::UnitY()))
                                     .toRotationMatrix();
  // Rotate about the pairs' centroid at its refined elevation, so t_z stays well conditioned.
  Pose T_tilt = Pose::Identity();
  const Eigen::Vector3d centre(mean.x(), mean.y(), 0.0);
  T_tilt.linear() = R_tilt;
  T_tilt.translation() = centre - R_tilt * centre + Eigen::Vector3d(0, 0, s(0) - z_mode);
  *T = T_tilt * *T;
  v->tilt_fitted = true;
  // Information in units of a full-weight pair of std dev base_sigma_m; s2 is the roll
  // (about x), s1 the pitch.
  const Eigen::Matrix3d post = info.inverse() * params.base_sigma_m * params.base_sigma_m;
  v->roll_var = std::max(post(2, 2), kMinFittedTiltVar);
  v->pitch_var = std::max(post(1, 1), kMinFittedTiltVar);
  return rmsZ();
}

/// Guided matching: re-associate every trunk by mutual nearest neighbour under the current
/// pose, then solve Eq. (3.11) by least squares on those pairs (2-D Procrustes for yaw and
/// t_xy; t_z is refineElevation's); a few rounds until the pairs stop changing.
Refined guidedRefine(const Descriptor& q, const Descriptor& c, const Pose& T0, double radius) {
  Refined out;
  out.T = T0;
  std::vector<P2> pc;
  for (const TrunkLandmark& t : c.trunks) pc.emplace_back(t.x, t.y);
  for (int it = 0; it < 5; ++it) {
    std::vector<P2> pq;
    for (const TrunkLandmark& t : q.trunks)
      pq.push_back((out.T * Eigen::Vector3d(t.x, t.y, t.z)).head<2>());
    std::vector<std::pair<int, int>> pairs = mutualPairs(pq, pc, radius);
    if (pairs.size() < 2) break;
    if (pairs == out.pairs) break;
    out.pairs = pairs;
    std::vector<std::pair<P2, P2>> points;
    for (const auto& [i, j] : pairs) points.emplace_back(P2(q.trunks[i].x, q.trunks[i].y), pc[j]);
    out.T = rigid2d(points, out.T.translation().z());  // refineElevation fixes t_z
  }
  double sxy = 0.0;
  for (const auto& [i, j] : out.pairs) {
    const Eigen::Vector3d r = Eigen::Vector3d(c.trunks[j].x, c.trunks[j].y, c.trunks[j].z) -
                              out.T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, q.trunks[i].z);
    sxy += r.head<2>().squaredNorm();
  }
  if (!out.pairs.empty()) out.rms_xy = std::sqrt(sxy / out.pairs.size());
  return out;
}

/// Fit of a pose to the whole trunk sets: guided refinement from `T0` (pairs within `radius`),
/// then the Tukey-weighted count of the mutual pairs, sum of (1 - (d / score_radius)^2)^2.
/// Trunk centres are fitted to a few cm, so a pose shifted or turned onto another lattice site
/// of a jittered plantation scores clearly lower than the true one even though it pairs as
/// many trunks.
struct Fit {
  Pose T = Pose::Identity();
  double score = 0.0;
  double median_xy = 0.0;                  ///< median horizontal residual of the pairs [m]
  std::vector<std::pair<int, int>> pairs;  ///< the refined mutual pairs under T
};
Fit fitPose(const Descriptor& q, const Descriptor& c, const Pose& T0, double radius,
            double score_radius) {
  Fit f;
  const Refined r = guidedRefine(q, c, T0, radius);
  f.T = r.T;
  f.pairs = r.pairs;
  std::vector<double> residual;
  for (const auto& [i, j] : r.pairs) {
    const Eigen::Vector2d d = (r.T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, 0.0)).head<2>() -
                              Eigen::Vector2d(c.trunks[j].x, c.trunks[j].y);
    const double u = d.squaredNorm() / (score_radius * score_radius);
    if (u < 1.0) f.score += (1.0 - u) * (1.0 - u);
    residual.push_back(d.norm());
  }
  if (!residual.empty()) {
    const auto mid = residual.begin() + residual.size() / 2;
    std::nth_element(residual.begin(), mid, residual.end());
    f.median_xy = *mid;
  }
  return f;
}

/// Lattice-consistent translations for the rotation R: every (query, candidate) trunk pair
/// votes for c_j - R q_i in 0.5 m bins; the bins whose 3 x 3 neighbourhood holds a local
/// maximum of at least `min_votes` votes (the trunks that pair up under that translation) and
/// a third of the highest, strongest first, at most `max_peaks`, each as the mean translation
/// of its neighbourhood.
std::vector<Eigen::Vector2d> translationPeaks(const Descriptor& q, const Descriptor& c,
                                              const Eigen::Matrix2d& R, int min_votes,
                                              size_t max_peaks) {
  constexpr double kBin = 0.5;
  constexpr size_t kMaxBins = size_t{1} << 22;  // 1 km x 1 km of translations: a bound on memory
  std::vector<Eigen::Vector2d> rq;
  for (const TrunkLandmark& a : q.trunks) rq.push_back(R * Eigen::Vector2d(a.x, a.y));
  if (rq.empty() || c.trunks.empty()) return {};
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
  // One empty bin of margin on each side keeps the 3 x 3 neighbourhoods inside the array.
  const double x0 = std::floor(lo.x() / kBin) * kBin - kBin,
               y0 = std::floor(lo.y() / kBin) * kBin - kBin;
  const size_t w = static_cast<size_t>((hi.x() - x0) / kBin) + 2;
  const size_t h = static_cast<size_t>((hi.y() - y0) / kBin) + 2;
  if (w * h > kMaxBins) return {};
  std::vector<int> n(w * h, 0);
  std::vector<Eigen::Vector2d> sum(w * h, Eigen::Vector2d::Zero());
  for (const TrunkLandmark& b : c.trunks) {
    for (const Eigen::Vector2d& p : rq) {
      const Eigen::Vector2d t = Eigen::Vector2d(b.x, b.y) - p;
      const size_t k =
          static_cast<size_t>((t.y() - y0) / kBin) * w + static_cast<size_t>((t.x() - x0) / kBin);
      ++n[k];
      sum[k] += t;
    }
  }
  std::vector<int> around(w * h, 0);  // votes in the 3 x 3 neighbourhood
  int top = 0;
  for (size_t y = 1; y + 1 < h; ++y) {
    for (size_t x = 1; x + 1 < w; ++x) {
      int a = 0;
      for (size_t yy = y - 1; yy <= y + 1; ++yy)
        for (size_t xx = x - 1; xx <= x + 1; ++xx) a += n[yy * w + xx];
      around[y * w + x] = a;
      top = std::max(top, a);
    }
  }
  // A site pairing under a third of the trunks that the best-paired site pairs cannot beat it
  // by the margin that verification demands (max_fit_ambiguity): a true site scores up to ~0.9
  // per pair, a wrong one ~0.2 (fit_score_radius_m 0.2 m, 0.15 m jitter).
  const int floor_votes = std::max(min_votes, top / 3);
  std::vector<std::pair<int, size_t>> peaks;  // (votes, bin), local maxima (ties: first bin)
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
  std::stable_sort(peaks.begin(), peaks.end(),
                   [](const auto& u, const auto& v) { return u.first > v.first; });
  if (peaks.size() > max_peaks) peaks.resize(max_peaks);
  std::vector<Eigen::Vector2d> out;
  for (const auto& [votes, k] : peaks) {
    Eigen::Vector2d t = Eigen::Vector2d::Zero();
    for (size_t yy = k / w - 1; yy <= k / w + 1; ++yy)
      for (size_t xx = k % w - 1; xx <= k % w + 1; ++xx) t += sum[yy * w + xx];
    out.push_back(t / static_cast<double>(votes));
  }
  return out;
}

/// Candidate trunk centres in a dense grid of square cells, for nearest-trunk lookups within a
/// cell side.
class TrunkGrid {
 public:
  TrunkGrid(const Descriptor& c, double cell) : cell_(cell) {
    Eigen::Vector2d lo(std::numeric_limits<double>::infinity(),
                       std::numeric_limits<double>::infinity());
    for (const TrunkLandmark& t : c.trunks) {
      xy_.emplace_back(t.x, t.y);
      lo = lo.cwiseMin(xy_.back());
    }
    if (xy_.empty()) return;
    origin_ = lo - Eigen::Vector2d(cell, cell);  // a margin cell below
    int64_t w = 0, h = 0;
    for (const Eigen::Vector2d& p : xy_) {
      w = std::max(w, cellOf(p.x() - origin_.x()) + 2);
      h = std::max(h, cellOf(p.y() - origin_.y()) + 2);
    }
    w_ = w, h_ = h;
    head_.assign(static_cast<size_t>(w_ * h_), -1);
    next_.assign(xy_.size(), -1);
    for (size_t j = 0; j < xy_.size(); ++j) {
      const int64_t k = cellOf(xy_[j].y() - origin_.y()) * w_ + cellOf(xy_[j].x() - origin_.x());
      next_[j] = head_[k];
      head_[k] = static_cast<int>(j);
    }
  }
  /// Squared distance from p to the nearest trunk within radius (<= the cell side); -1: none.
  double nearest2(const Eigen::Vector2d& p, double radius, int* index) const {
    *index = -1;
    if (xy_.empty()) return -1.0;
    const int64_t ix = cellOf(p.x() - origin_.x()), iy = cellOf(p.y() - origin_.y());
    double best = radius * radius;
    for (int64_t y = std::max<int64_t>(iy - 1, 0); y <= std::min(iy + 1, h_ - 1); ++y) {
      for (int64_t x = std::max<int64_t>(ix - 1, 0); x <= std::min(ix + 1, w_ - 1); ++x) {
        for (int j = head_[y * w_ + x]; j >= 0; j = next_[j]) {
          const double d = (xy_[j] - p).squaredNorm();
          if (d <= best) best = d, *index = j;
        }
      }
    }
    return *index >= 0 ? best : -1.0;
  }
  const Eigen::Vector2d& at(int j) const { return xy_[j]; }

 private:
  int64_t cellOf(double v) const { return static_cast<int64_t>(std::floor(v / cell_)); }
  double cell_;
  Eigen::Vector2d origin_ = Eigen::Vector2d::Zero();
  int64_t w_ = 0, h_ = 0;
  std::vector<Eigen::Vector2d> xy_;
  std::vector<int> head_, next_;  // per cell its first trunk, per trunk the next in its cell
};

/// A cheap fitPose for ranking many lattice poses: two rounds of 2-D Procrustes on each query
/// trunk's nearest candidate trunk within `radius` (not mutual), then the same Tukey score; on
/// `sample`, an even subset of the query trunks.
std::pair<double, Pose> quickFit(const std::vector<Eigen::Vector2d>& sample, const TrunkGrid& grid,
                                 Pose T, double radius, double score_radius) {
  double score = 0.0;
  std::vector<std::pair<P2, P2>> pairs;
  for (int it = 0; it <= 2; ++it) {
    pairs.clear();
    score = 0.0;
    for (const Eigen::Vector2d& t : sample) {
      const Eigen::Vector2d p = (T * Eigen::Vector3d(t.x(), t.y(), 0.0)).head<2>();
      int j = -1;
      const double d2 = grid.nearest2(p, radius, &j);
      if (j < 0) continue;
      const double u = d2 / (score_radius * score_radius);
      if (u < 1.0) score += (1.0 - u) * (1.0 - u);
      pairs.emplace_back(t, grid.at(j));
    }
    if (it == 2 || pairs.size() < 2) break;
    T = rigid2d(pairs, T.translation().z());
  }
  return {score, T};
}

/// Repetitive stands: the hypothesis may sit on any site of the lattice, several spacings
/// from the true one. Every lattice-consistent pose is tried: T0's yaw turned by 0, 90, 180
/// and 270 deg, each with the translations where many trunks pair up (translationPeaks); all
/// are fitted to the full trunk sets and the best fit wins.
/// Returns the winner and the runner-up's share of its score.
std::pair<Fit, double> resolveByFit(const Descriptor& q, const Descriptor& c, const Pose& T0,
                                    const VerifierParams& params) {
  constexpr size_t kPeaksPerTurn = 2000;  // a bound on the work, far above a submap's sites
  constexpr size_t kFullFits = 8;
  constexpr size_t kSample = 80;
  const double radius = params.match_radius_m;
  const double score_radius = params.fit_score_radius_m;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  for (const TrunkLandmark& t : q.trunks) centroid += Eigen::Vector2d(t.x, t.y);
  centroid /= static_cast<double>(q.trunks.size());
  const double yaw0 = std::atan2(T0.linear()(1, 0), T0.linear()(0, 0));

  // Every lattice pose ranked by quickFit; the best kFullFits are fitted exactly.
  const TrunkGrid grid(c, radius);
  std::vector<Eigen::Vector2d> sample;  // at most kSample query trunks, evenly over the list
  const size_t stride = (q.trunks.size() + kSample - 1) / kSample;
  for (size_t i = 0; i < q.trunks.size(); i += stride)
    sample.emplace_back(q.trunks[i].x, q.trunks[i].y);
  std::vector<std::pair<double, Pose>> ranked;
  for (int turn = 0; turn < 4; ++turn) {
    const double yaw = yaw0 + turn * M_PI / 2.0;
    const Eigen::Matrix2d R = Eigen::Rotation2Dd(yaw).toRotationMatrix();
    for (const Eigen::Vector2d& t : translationPeaks(q, c, R, params.min_inliers, kPeaksPerTurn)) {
      Pose T = Pose::Identity();
      T.linear() = rotZ(yaw);
      T.translation() = Eigen::Vector3d(t.x(), t.y(), T0.translation().z());
      ranked.push_back(quickFit(sample, grid, T, radius, score_radius));
    }
  }
  const size_t full = std::min(kFullFits, ranked.size());
  std::partial_sort(ranked.begin(), ranked.begin() + full, ranked.end(),
                    [](const auto& x, const auto& y) { return x.first > y.first; });
  std::vector<Fit> fits{fitPose(q, c, T0, radius, score_radius)};
  for (size_t k = 0; k < full; ++k)
    fits.push_back(fitPose(q, c, ranked[k].second, radius, score_radius));
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

// ---- database file ----------------------------------------------------------------------------

constexpr char kDbMagic[8] = {'D', 'T', 'I', 'F', 'D', 'B', '\0', '\0'};
constexpr uint32_t kDbVersion = 1;

using detail::fnv1a;

}  // namespace

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
  if (!(min_overlap >= 0.0 && min_overlap <= 1.0)) err << "min_overlap must be in [0, 1]; ";
  if (!(max_fit_median_m > 0.0)) err << "max_fit_median_m must be > 0; ";
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
  if (!(max_fit_ambiguity >= 0.0 && max_fit_ambiguity < 1.0)) {
    err << "max_fit_ambiguity must be in [0, 1) (0: ambiguous hypotheses are rejected); ";
  }
  return err.str();
}

std::string DatabaseParams::validate() const {
  std::ostringstream err;
  if (!(exclude_recent_s >= 0.0)) err << "exclude_recent_s must be >= 0; ";
  if (max_candidates < 1) err << "max_candidates must be >= 1; ";
  if (max_vote_candidates < 0) err << "max_vote_candidates must be >= 0; ";
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

Verification verifyLoop(const Descriptor& q, const Descriptor& c,
                        const std::vector<Correspondence>& corrs, const PoseEstimate& est,
                        const VerifierParams& params) {
  Verification v;
  auto reject = [&](const std::string& why) {
    v.accepted = false;
    v.reason = why;
    return v;
  };
  if (!est.ok) return reject("no pose");
  if (static_cast<int>(est.inliers_T.size()) < params.min_hypothesis_inliers) {
    return reject("few hypothesis inliers");
  }
  if (est.inlier_weight < params.min_inlier_weight) return reject("low inlier weight");

  // Repetitive stands (plantation grids) support several poses almost equally; a loop is only
  // trusted when the chosen hypothesis clearly dominates the runner-up in yaw and translation.
  const double amb_yaw = est.yaw_consensus > 0 ? est.yaw_runner_up / est.yaw_consensus : 1.0;
  const double amb_t =
      est.translation_consensus > 0 ? est.translation_runner_up / est.translation_consensus : 1.0;
  v.ambiguity = std::max(amb_yaw, amb_t);
  Pose T_hyp = est.T_c_q;
  if (v.ambiguity > params.max_ambiguity) {
    // The correspondences alone cannot tell the lattice sites apart; the fit of all trunks can
    // when the stand's irregularity exceeds the trunk-centre noise.
    if (params.max_fit_ambiguity <= 0.0) return reject("ambiguous");
    const auto [fit, ratio] = resolveByFit(q, c, est.T_c_q, params);
    v.fit_ambiguity = ratio;
    if (ratio > params.max_fit_ambiguity) return reject("ambiguous");
    // A wrong site of a jittered lattice pairs every trunk too, but only to the jitter. The
    // median, not the RMS: the right site's few false or shifted trunks paired up to
    // match_radius_m away would push its RMS above a wrong site's.
    if (fit.median_xy > params.max_fit_median_m) return reject("ambiguous");
    T_hyp = fit.T;
  }

  Refined ref = guidedRefine(q, c, T_hyp, params.match_radius_m);
  v.rms_z_m = refineElevation(q, c, ref.pairs, params, &ref.T, &v);
  v.T_c_q = ref.T;
  v.pairs = ref.pairs;
  v.rms_xy_m = ref.rms_xy;
  // The refinement must stay near the hypothesis: a jump means it locked onto other trunks,
  // which moves the paired trunks' centroid by about a tree spacing or turns them by degrees.
  // Measured at that centroid, where the submaps overlap and the correspondences lie (the raw
  // translation swings with the yaw when the coordinates are far from the origin, e.g. UTM,
  // and a rough hypothesis' yaw, corrected, moves trunks 30 m out by decimetres: 0.7 deg,
  // 0.37 m).
  constexpr double kMaxRefineYawRad = 3.0 * M_PI / 180.0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& [i, j] : ref.pairs)
    centroid += Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, 0.0);
  if (!ref.pairs.empty()) centroid /= static_cast<double>(ref.pairs.size());
  const double shift = ((ref.T * centroid) - (T_hyp * centroid)).head<2>().norm();
  const Eigen::Matrix3d dR = T_hyp.linear().transpose() * ref.T.linear();
  if (std::abs(std::atan2(dR(1, 0), dR(0, 0))) > kMaxRefineYawRad) {
    return reject("refinement diverged");
  }
  if (shift > params.match_radius_m) return reject("refinement diverged");
  if (static_cast<int>(ref.pairs.size()) < params.min_inliers) return reject("few inliers");
  const bool z_unobserved = v.z_pairs < params.min_z_pairs;
  if (z_unobserved || v.z_ambiguity > params.max_z_ambiguity) {
    // No pair of seen bases, or groups of them agreeing on different t_z (stems on shrubs):
    // where both submaps saw the same lowest surface (ground, a log), their ground maps differ
    // by t_z. A tilt fitted to disagreeing bases is not trusted.
    const std::string why = z_unobserved ? "elevation unobserved" : "elevation ambiguous";
    if (params.min_ground_cells <= 0 || q.ground_map.empty() || c.ground_map.empty() ||
        v.tilt_fitted) {
      return reject(why);
    }
    const GroundElevation g =
        groundElevation(q.ground_map, c.ground_map, ref.T, params.ground_window_m);
    v.ground_ambiguity = g.ok ? g.ambiguity : -1.0;
    if (!g.ok || g.support < params.min_ground_cells) return reject(why);
    if (g.ambiguity > params.max_ground_ambiguity) return reject("elevation ambiguous");
    ref.T.translation().z() += g.dz_m;
    v.T_c_q = ref.T;
    v.ground_cells = g.support;
    v.ground_sigma_m = g.spread_m;
  }
  if (ref.rms_xy > params.max_rms_xy_m) return reject("large residual");

  // Co-visibility: after alignment, trunks of one submap inside the other's footprint (convex
  // hull) must mostly have a partner. A false loop explains its inliers but not the rest.
  std::vector<P2> pq, pc;
  for (const TrunkLandmark& t : q.trunks) {
    pq.push_back((ref.T * Eigen::Vector3d(t.x, t.y, t.z)).head<2>());
  }
  for (const TrunkLandmark& t : c.trunks) pc.emplace_back(t.x, t.y);
  int inside = 0, matched = 0;
  coLocated(pq, pc, params.match_radius_m, &inside, &matched);
  coLocated(pc, pq, params.match_radius_m, &inside, &matched);
  v.covisible = matched;
  v.covisible_ratio = inside > 0 ? static_cast<double>(matched) / inside : 0.0;
  if (matched < params.min_covisible) return reject("few co-visible trunks");
  if (v.covisible_ratio < params.min_covisible_ratio) return reject("low co-visibility");
  // A correct alignment of two submaps that barely overlap is not a loop worth closing (and
  // not one by the evaluation protocol): measure the overlap as DATASET.md defines it.
  v.overlap = footprintOverlap(q.footprint, c.footprint, v.T_c_q);
  if (v.overlap >= 0.0 && v.overlap < params.min_overlap) return reject("small overlap");

  double total_w = 0.0;
  for (const Correspondence& k : corrs) total_w += k.w;
  double inlier_w = 0.0;  // in omega units even with unit_weights, so scores stay comparable
  for (int i : est.inliers_T) inlier_w += corrs[i].w;
  v.score = v.covisible_ratio * (total_w > 0 ? inlier_w / total_w : 0.0);
  v.accepted = true;
  return v;
}

namespace {

/// The triangles gave no pose hypothesis at all (as opposed to a hypothesis that failed a check).
bool noHypothesis(const std::string& reason) {
  return reason == "few correspondences" || reason == "no pose" ||
         reason == "few hypothesis inliers" || reason == "low inlier weight";
}

/// The vote fallback (MatcherParams::vote_fallback): the voted peaks are fitted to all trunks
/// (fitPose), the best fit must clearly beat every distinct runner-up (repetitive stands give
/// several), and its mutual trunk pairs (unit weights) become the
/// correspondences that the solver and verifyLoop see. Empty with `reason` set when none.
std::vector<Correspondence> voteCorrespondences(const Descriptor& q, const Descriptor& c,
                                                const LoopDetectorParams& params,
                                                std::string* reason) {
  constexpr int kPeaks = 4;
  const std::vector<VotePeak> peaks = votePoses(q, c, params.matcher, kPeaks);
  const double radius = params.verification.match_radius_m;
  std::vector<Fit> fits;
  for (const VotePeak& pk : peaks) {
    Pose T = Pose::Identity();
    T.linear() = rotZ(pk.yaw);
    T.translation() = Eigen::Vector3d(pk.t.x(), pk.t.y(), 0.0);
    fits.push_back(fitPose(q, c, T, radius, radius));
  }
  size_t best = 0;
  for (size_t k = 1; k < fits.size(); ++k)
    if (fits[k].score > fits[best].score) best = k;
  if (fits.empty() || fits[best].score <= 0.0) {
    *reason = "no voted pose";
    return {};
  }
  // Distinct: some query trunk lands more than two match radii away from where the best puts it.
  double runner_up = 0.0;
  for (size_t k = 0; k < fits.size(); ++k) {
    if (k == best) continue;
    double moved = 0.0;
    for (const TrunkLandmark& t : q.trunks) {
      const Eigen::Vector3d p(t.x, t.y, 0.0);
      moved = std::max(moved, ((fits[k].T * p) - (fits[best].T * p)).head<2>().norm());
    }
    if (moved > 2.0 * radius) runner_up = std::max(runner_up, fits[k].score);
  }
  if (runner_up > params.verification.max_ambiguity * fits[best].score) {
    *reason = "ambiguous votes";
    return {};
  }
  // The best fit's own refined pairs (fitPose already ran the guided refinement). Radii are not
  // compared (see votePoses): the pairs' geometry carries the evidence.
  std::vector<Correspondence> corrs;
  for (const auto& [i, j] : fits[best].pairs) {
    const TrunkLandmark &a = q.trunks[i], &b = c.trunks[j];
    Correspondence k;
    k.iq = i, k.ic = j;
    k.pq = Eigen::Vector3d(a.x, a.y, a.z);
    k.pc = Eigen::Vector3d(b.x, b.y, b.z);
    k.z_ok = a.base_seen && b.base_seen;
    corrs.push_back(k);
  }
  if (static_cast<int>(corrs.size()) < params.verification.min_hypothesis_inliers) {
    *reason = "few voted pairs";
    return {};
  }
  return corrs;
}

}  // namespace

std::optional<Loop> matchPair(const Descriptor& q, const Descriptor& c,
                              const LoopDetectorParams& params, PoseEstimate* est_out,
                              Verification* ver_out, QueryStats* stats, const PoseSolver* solver,
                              const std::vector<MatchTriangle>* tq,
                              const std::vector<MatchTriangle>* tc) {
  auto t0 = Clock::now();
  std::vector<Correspondence> corrs = buildCorrespondences(q, c, params.matcher, nullptr, tq, tc);
  if (stats) stats->match_ms += msSince(t0);
  PoseEstimate est;
  Verification ver;
  // Pose from correspondences, then verification (both timed).
  auto solveAndVerify = [&]() {
    if (stats) ++stats->matched;
    t0 = Clock::now();
    est = solver && *solver ? (*solver)(corrs) : estimatePose(corrs, params.pose);
    if (stats) stats->solver_ms += msSince(t0);
    t0 = Clock::now();
    ver = verifyLoop(q, c, corrs, est, params.verification);
    if (stats) stats->verify_ms += msSince(t0);
  };
  if (static_cast<int>(corrs.size()) >= params.verification.min_hypothesis_inliers) {
    solveAndVerify();
  } else {
    ver.reason = "few correspondences";
  }
  if (!ver.accepted && params.matcher.vote_fallback && noHypothesis(ver.reason)) {
    const std::string triangle_reason = ver.reason;
    t0 = Clock::now();
    std::string vote_reason;
    std::vector<Correspondence> voted = voteCorrespondences(q, c, params, &vote_reason);
    if (stats) stats->match_ms += msSince(t0);
    if (!voted.empty()) {
      corrs.swap(voted);
      solveAndVerify();
      vote_reason = ver.reason;
    }
    if (!ver.accepted) ver.reason = triangle_reason + "; votes: " + vote_reason;
  }
  if (est_out) *est_out = est;
  if (ver_out) *ver_out = ver;
  if (!ver.accepted) return std::nullopt;
  if (stats) ++stats->verified;

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
  return lc;
}

LoopDetector::LoopDetector(const LoopDetectorParams& params) : params_(params) {
  const std::string err = params_.validate();
  if (!err.empty()) throw std::invalid_argument("bad loop detector params: " + err);
}

bool LoopDetector::insert(std::shared_ptr<const Descriptor> d) {
  if (!d || !d->valid) return false;
  entries_.push_back(std::move(d));
  triangles_.push_back(nullptr);
  return true;
}

std::optional<Loop> LoopDetector::query(const Descriptor& q, QueryStats* stats) const {
  QueryStats local;
  QueryStats& st = stats ? *stats : local;
  st = QueryStats{};
  if (!q.valid) return std::nullopt;

  // Screening: histogram similarity of every eligible entry, best max_candidates kept.
  auto t0 = Clock::now();
  struct Cand {
    double sim;
    size_t index;
  };
  std::vector<Cand> cands;
  const MatcherParams& mp = params_.matcher;
  for (size_t i = 0; i < entries_.size(); ++i) {
    const Descriptor& c = *entries_[i];
    if (c.robot == q.robot && (c.submap_id == q.submap_id ||
                               std::fabs(c.stamp - q.stamp) < params_.database.exclude_recent_s)) {
      continue;
    }
    ++st.eligible;
    const double se = histogramIntersection(q.edge_hist, c.edge_hist);
    if (se < mp.min_edge_hist_sim) continue;
    const double sr = histogramIntersection(q.radius_hist, c.radius_hist);
    if (sr < mp.min_radius_hist_sim) continue;
    cands.push_back({0.5 * (se + sr), i});
  }
  st.screened_in = cands.size();
  const size_t keep = std::min(cands.size(), static_cast<size_t>(params_.database.max_candidates));
  std::partial_sort(cands.begin(), cands.begin() + keep, cands.end(),
                    [](const Cand& a, const Cand& b) {
                      return a.sim > b.sim || (a.sim == b.sim && a.index < b.index);
                    });
  cands.resize(keep);
  for (const Cand& cd : cands) st.candidates.push_back(entries_[cd.index]->submap_id);
  st.screen_ms = msSince(t0);

  std::optional<Loop> best;
  std::vector<MatchTriangle> tq;
  if (!cands.empty()) tq = matchTriangles(q, mp.neighbour_triangles);
  // Candidates past the best max_vote_candidates are matched without the vote fallback.
  LoopDetectorParams no_votes = params_;
  no_votes.matcher.vote_fallback = false;
  for (size_t rank = 0; rank < cands.size(); ++rank) {
    const Cand& cd = cands[rank];
    auto& tc = triangles_[cd.index];
    if (!tc) {
      tc = std::make_shared<const std::vector<MatchTriangle>>(
          matchTriangles(*entries_[cd.index], mp.neighbour_triangles));
    }
    const bool votes = rank < static_cast<size_t>(params_.database.max_vote_candidates);
    auto lc = matchPair(q, *entries_[cd.index], votes ? params_ : no_votes, nullptr, nullptr, &st,
                        &solver_, &tq, tc.get());
    if (lc && (!best || lc->score > best->score)) best = std::move(lc);
  }
  return best;
}

// File layout: 8-byte magic, u32 version, u64 entry count, entries (u32 size + encoded
// descriptor), u32 FNV-1a of everything before it.
void LoopDetector::save(const std::string& path) const {
  detail::ByteWriter w;
  w.bytes.assign(kDbMagic, kDbMagic + 8);
  w.put<uint32_t>(kDbVersion);
  w.put<uint64_t>(entries_.size());
  for (const auto& d : entries_) {
    const std::vector<uint8_t> e = encodeDescriptor(*d);
    w.put<uint32_t>(static_cast<uint32_t>(e.size()));
    w.putBytes(e);
  }
  w.put<uint32_t>(fnv1a(w.bytes.data(), w.bytes.size()));
  const std::vector<uint8_t>& buf = w.bytes;

  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw std::runtime_error(tmp + ": cannot open for writing");
    f.write(reinterpret_cast<const char*>(buf.data()), static_cast<std::streamsize>(buf.size()));
    f.flush();
    if (!f) {
      std::remove(tmp.c_str());
      throw std::runtime_error(tmp + ": write failed");
    }
  }
  // rename() is atomic on POSIX: readers see the old or the new database, never half of one.
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot rename " + tmp + " into place");
  }
}

void LoopDetector::load(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error(path + ": cannot open database file");
  const std::vector<uint8_t> buf((std::istreambuf_iterator<char>(f)),
                                 std::istreambuf_iterator<char>());
  auto fail = [&](const std::string& why) {
    throw std::runtime_error(path + ": not a valid dtif database: " + why);
  };
  if (buf.size() < 8 + 4 + 8 + 4 || std::memcmp(buf.data(), kDbMagic, 8) != 0) fail("bad magic");
  // The body: everything between the magic and the checksum.
  detail::ByteReader r(buf.data() + 8, buf.size() - 8 - 4, "truncated");
  const uint32_t version = r.get<uint32_t>();
  if (version != kDbVersion) {
    fail("version " + std::to_string(version) + ", expected " + std::to_string(kDbVersion));
  }
  uint32_t stored_sum;
  std::memcpy(&stored_sum, buf.data() + buf.size() - 4, 4);
  if (fnv1a(buf.data(), buf.size() - 4) != stored_sum) fail("checksum mismatch");
  // Decode everything into a new list first; the database changes only when all of it is good.
  std::vector<std::shared_ptr<const Descriptor>> loaded;
  try {
    const uint64_t n = r.get<uint64_t>();
    // The loosest params: keep each descriptor's saved validity.
    DescriptorParams loose;
    loose.min_trunks = 3;
    loose.min_triangles = 1;
    for (uint64_t i = 0; i < n; ++i) {
      const uint32_t sz = r.get<uint32_t>();
      if (r.remaining() < sz) throw std::runtime_error("entry truncated");
      const uint8_t* at = r.take(sz);
      const std::vector<uint8_t> e(at, at + sz);
      auto d = std::make_shared<Descriptor>(decodeDescriptor(e, loose));
      if (!d->valid) throw std::runtime_error("entry " + std::to_string(i) + " is not valid");
      loaded.push_back(std::move(d));
    }
    if (r.remaining() != 0) throw std::runtime_error("trailing bytes");
  } catch (const std::runtime_error& e) {
    fail(e.what());
  }
  entries_ = std::move(loaded);
  triangles_.assign(entries_.size(), nullptr);
}

}  // namespace dtif
