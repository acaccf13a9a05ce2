// Decoupled robust pose, paper Sec. 3.D, Eqs. (3.11)-(3.17).
#include "dtif/core/pose/pose_estimator.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <sstream>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "dtif/core/pose/pose_estimator_stages.h"
#include "dtif/core/pose/rigid2d.h"

namespace dtif {
namespace {

using pose_stages::Tim;

double wrapAngle(double a) { return std::atan2(std::sin(a), std::cos(a)); }

/// Squared TIM residual ||d^c - R(theta) d^q||^2.
inline double timResidual2(const Tim& m, double c, double s) {
  const double rx = m.cx - (c * m.qx - s * m.qy);
  const double ry = m.cy - (s * m.qx + c * m.qy);
  return rx * rx + ry * ry;
}

/// Weighted least squares 2-D rotation: argmin sum w ||d^c - R d^q||^2 has the closed form
/// theta = atan2(sum w (d^q x d^c), sum w (d^q . d^c)). No small-angle assumption. The weight
/// of TIM i is weight(m_i), computed in the same pass (the TIMs are read once per step).
template <class Weight>
double weightedYaw(const std::vector<Tim>& tims, Weight&& weight) {
  double sc = 0.0, ss = 0.0;
  for (const Tim& m : tims) {
    const double u = weight(m);
    sc += u * m.w * (m.qx * m.cx + m.qy * m.cy);
    ss += u * m.w * (m.qx * m.cy - m.qy * m.cx);
  }
  return std::atan2(ss, sc);
}

double tlsCost(const std::vector<Tim>& tims, double theta, double beta2) {
  const double c = std::cos(theta), s = std::sin(theta);
  double cost = 0.0;
  for (const Tim& m : tims) cost += m.w * std::min(timResidual2(m, c, s), beta2);
  return cost;
}

/// GNC's weight of a TIM of squared residual r2 (Yang et al.: 0 beyond hi, 1 below lo, else
/// beta sqrt(mu (mu + 1) / r2) - mu); *binary false when it is none of 0 and 1.
inline double gncWeight(double r2, double lo, double hi, double beta, double mu, bool* binary) {
  if (r2 >= hi) return 0.0;
  if (r2 <= lo) return 1.0;
  *binary = false;
  return beta * std::sqrt(mu * (mu + 1.0) / r2) - mu;
}

/// The TIMs' values that a GNC step reads, as columns; dot and cross are weightedYaw's d^q . d^c
/// and d^q x d^c, the same for every step.
struct TimColumns {
  std::vector<double> qx, qy, cx, cy, w, dot, cross;
  explicit TimColumns(const std::vector<Tim>& tims) {
    for (std::vector<double>* v : {&qx, &qy, &cx, &cy, &w, &dot, &cross}) v->resize(tims.size());
    for (size_t i = 0; i < tims.size(); ++i) {
      const Tim& m = tims[i];
      qx[i] = m.qx, qy[i] = m.qy, cx[i] = m.cx, cy[i] = m.cy, w[i] = m.w;
      dot[i] = m.qx * m.cx + m.qy * m.cy;
      cross[i] = m.qx * m.cy - m.qy * m.cx;
    }
  }
};

/// One GNC step: weightedYaw with GNC's weights at the yaw of (c, s). The weights of two TIMs at
/// a time (SSE2: the same operations, so the same values, as gncWeight and timResidual2), their
/// terms summed one by one in TIM order as weightedYaw sums them: a mispredicted branch per
/// weight and the square root and division one at a time made most of a step.
double gncStep(const TimColumns& t, double c, double s, double lo, double hi, double beta,
               double mu, bool* binary) {
  const size_t n = t.w.size();
  double sc = 0.0, ss = 0.0;
  size_t i = 0;
#ifdef __SSE2__
  const __m128d C = _mm_set1_pd(c), S = _mm_set1_pd(s), LO = _mm_set1_pd(lo), HI = _mm_set1_pd(hi),
                B = _mm_set1_pd(beta), MU = _mm_set1_pd(mu), K = _mm_set1_pd(mu * (mu + 1.0)),
                ONE = _mm_set1_pd(1.0);
  int middle = 0;
  for (; i + 2 <= n; i += 2) {
    const __m128d qx = _mm_loadu_pd(&t.qx[i]), qy = _mm_loadu_pd(&t.qy[i]);
    const __m128d rx =
        _mm_sub_pd(_mm_loadu_pd(&t.cx[i]), _mm_sub_pd(_mm_mul_pd(C, qx), _mm_mul_pd(S, qy)));
    const __m128d ry =
        _mm_sub_pd(_mm_loadu_pd(&t.cy[i]), _mm_add_pd(_mm_mul_pd(S, qx), _mm_mul_pd(C, qy)));
    const __m128d r2 = _mm_add_pd(_mm_mul_pd(rx, rx), _mm_mul_pd(ry, ry));
    const __m128d high = _mm_cmpge_pd(r2, HI), low = _mm_cmple_pd(r2, LO);
    const __m128d mid = _mm_sub_pd(_mm_mul_pd(B, _mm_sqrt_pd(_mm_div_pd(K, r2))), MU);
    // 0 where high, else 1 where low, else mid.
    const __m128d u = _mm_andnot_pd(high, _mm_or_pd(_mm_and_pd(low, ONE), _mm_andnot_pd(low, mid)));
    middle |= _mm_movemask_pd(_mm_or_pd(high, low)) ^ 3;
    const __m128d uw = _mm_mul_pd(u, _mm_loadu_pd(&t.w[i]));
    double a[2], b[2];
    _mm_storeu_pd(a, _mm_mul_pd(uw, _mm_loadu_pd(&t.dot[i])));
    _mm_storeu_pd(b, _mm_mul_pd(uw, _mm_loadu_pd(&t.cross[i])));
    sc += a[0], sc += a[1];
    ss += b[0], ss += b[1];
  }
  if (middle) *binary = false;
#endif
  for (; i < n; ++i) {
    const double rx = t.cx[i] - (c * t.qx[i] - s * t.qy[i]);
    const double ry = t.cy[i] - (s * t.qx[i] + c * t.qy[i]);
    const double u = gncWeight(rx * rx + ry * ry, lo, hi, beta, mu, binary);
    sc += u * t.w[i] * t.dot[i];
    ss += u * t.w[i] * t.cross[i];
  }
  return std::atan2(ss, sc);
}

/// Global maximiser of the weighted TIM consensus over the circle. Every TIM is an inlier
/// (residual <= beta) on an arc of theta; sweeping the arc ends finds the densest yaw exactly.
/// This guards GNC, which can converge to a local minimum above ~70-80% outliers.
/// Returns (best yaw, best consensus weight, runner-up consensus weight at least
/// kSeparation away from the best).
struct ArcSweep {
  double theta = 0.0;
  double best = 0.0;
  double runner_up = 0.0;
};

/// a in [-pi, pi] for a in [-3 pi, 3 pi], by one turn at most: within rounding (~1e-15) of
/// wrapAngle's value without its three libm calls (atan2 of sine and cosine). The arc ends of
/// consensusYaw (phi -+ half, both in [-pi, pi]): there wrapAngle cost a twentieth of a query,
/// and the two differ by an ulp or so in a few per cent of the ends, which moves the sweep's yaw
/// by as much (refineYaw starts from it) and leaves its sums alone.
double wrapOnce(double a) { return a > M_PI ? a - 2.0 * M_PI : a < -M_PI ? a + 2.0 * M_PI : a; }

/// |wrapAngle(d)| > sep for d in [-3 pi, 3 pi], by wrapOnce unless d lies within a hair of the
/// boundary: both are within rounding of the exact wrap (at +-pi they may differ in sign only),
/// so the comparison decides the same.
bool farFromZero(double d, double sep) {
  const double w = wrapOnce(d);
  if (std::fabs(std::fabs(w) - sep) > 1e-9) return std::fabs(w) > sep;
  return std::fabs(wrapAngle(d)) > sep;
}

/// An arc end of the yaw sweep: its angle and the weight it adds (opens) or removes (closes).
struct Event {
  double angle;
  double dw;
};

/// The events by angle, opening before closing at equal angles (the sweep's order): a radix
/// sort on the angles' bits (stable, 8 bits a pass, passes where all share the byte skipped),
/// then each run of equal angles by weight. Elements equal in both are equal in every bit
/// except for an angle of +0 against -0, so this is the order std::sort gives by the same
/// comparison; a yaw sweep over ~10^4 TIMs spent a sixth of a query sorting.
void sortEvents(std::vector<Event>* ev) {
  const auto before = [](const Event& x, const Event& y) {
    return x.angle < y.angle || (x.angle == y.angle && x.dw > y.dw);  // open before close
  };
  const size_t n = ev->size();
  if (n < 256) {
    std::sort(ev->begin(), ev->end(), before);
    return;
  }
  // Keys in the order of the angles (+0 and -0 alike): negative ones with every bit flipped,
  // others with the sign bit set.
  std::vector<uint64_t> key(n), key_tmp(n);
  for (size_t i = 0; i < n; ++i) {
    uint64_t b = 0;
    const double a = (*ev)[i].angle + 0.0;  // -0 becomes +0
    std::memcpy(&b, &a, sizeof b);
    key[i] = (b >> 63) ? ~b : b | (uint64_t{1} << 63);
  }
  std::vector<Event> tmp(n);
  for (int shift = 0; shift < 64; shift += 8) {
    std::array<size_t, 257> start{};
    for (size_t i = 0; i < n; ++i) ++start[((key[i] >> shift) & 0xff) + 1];
    if (std::find(start.begin() + 1, start.end(), n) != start.end()) continue;  // one bucket
    for (size_t d = 1; d < start.size(); ++d) start[d] += start[d - 1];
    for (size_t i = 0; i < n; ++i) {
      const size_t to = start[(key[i] >> shift) & 0xff]++;
      tmp[to] = (*ev)[i];
      key_tmp[to] = key[i];
    }
    ev->swap(tmp);
    key.swap(key_tmp);
  }
  for (size_t i = 0; i < n;) {
    size_t j = i + 1;
    while (j < n && key[j] == key[i]) ++j;
    if (j - i > 1) std::sort(ev->begin() + i, ev->begin() + j, before);
    i = j;
  }
}

ArcSweep consensusYaw(const std::vector<Tim>& tims, double beta) {
  constexpr double kSeparation = 10.0 * M_PI / 180.0;
  std::vector<Event> ev;
  ev.reserve(tims.size() * 2);
  double wrap_start = 0.0;  // weight of arcs covering angle -pi
  for (const Tim& m : tims) {
    const double a = m.lq >= 0.0 ? m.lq : std::hypot(m.qx, m.qy);
    const double b = m.lc >= 0.0 ? m.lc : std::hypot(m.cx, m.cy);
    // r^2(theta) = a^2 + b^2 - 2ab cos(theta - phi) <= beta^2
    const double cosd = (a * a + b * b - beta * beta) / (2.0 * a * b);
    if (cosd > 1.0) continue;
    const double half = cosd <= -1.0 ? M_PI : std::acos(cosd);
    const double phi = std::atan2(m.qx * m.cy - m.qy * m.cx, m.qx * m.cx + m.qy * m.cy);
    if (half >= M_PI) {
      wrap_start += m.w;
      continue;
    }
    double s = wrapOnce(phi - half), e = wrapOnce(phi + half);
    ev.push_back({s, m.w});
    ev.push_back({e, -m.w});
    if (s > e) wrap_start += m.w;  // the arc covers -pi
  }
  sortEvents(&ev);
  ArcSweep out;
  double cur = wrap_start;
  out.best = cur;
  out.theta = -M_PI;
  for (size_t i = 0; i < ev.size(); ++i) {
    cur += ev[i].dw;
    if (cur > out.best + 1e-12) {
      out.best = cur;
      // Middle of the interval up to the next event.
      const double next = i + 1 < ev.size() ? ev[i + 1].angle : M_PI;
      out.theta = 0.5 * (ev[i].angle + next);
    }
  }
  // Runner-up: the same sweep restricted to yaws far from the best one.
  double cur2 = wrap_start;
  auto far = [&](double ang) { return farFromZero(ang - out.theta, kSeparation); };
  if (far(-M_PI)) out.runner_up = cur2;
  for (size_t i = 0; i < ev.size(); ++i) {
    cur2 += ev[i].dw;
    const double next = i + 1 < ev.size() ? ev[i + 1].angle : M_PI;
    if (far(0.5 * (ev[i].angle + next))) out.runner_up = std::max(out.runner_up, cur2);
  }
  return out;
}

/// Truncated least squares refinement by alternation: inliers at theta, then their LS yaw.
double refineYaw(const std::vector<Tim>& tims, double theta, double beta2) {
  for (int it = 0; it < 20; ++it) {
    const double c = std::cos(theta), s = std::sin(theta);
    const double next =
        weightedYaw(tims, [&](const Tim& m) { return timResidual2(m, c, s) <= beta2 ? 1.0 : 0.0; });
    if (std::fabs(wrapAngle(next - theta)) < 1e-10) return next;
    theta = next;
  }
  return theta;
}

}  // namespace

namespace pose_stages {

double gncTlsYaw(const std::vector<Tim>& tims, double beta, const PoseEstimatorParams& p) {
  const double c2 = beta * beta;
  double theta = weightedYaw(tims, [](const Tim&) { return 1.0; });
  double max_r2 = 0.0;
  {
    const double c = std::cos(theta), s = std::sin(theta);
    for (const Tim& m : tims) max_r2 = std::max(max_r2, timResidual2(m, c, s));
  }
  if (max_r2 <= c2) return theta;  // every measurement is already an inlier
  double mu = c2 / std::max(2.0 * max_r2 - c2, 1e-12);
  const TimColumns columns(tims);
  for (int it = 0; it < p.gnc_max_iterations; ++it) {
    const double c = std::cos(theta), s = std::sin(theta);
    const double lo = mu / (mu + 1.0) * c2, hi = (mu + 1.0) / mu * c2;
    bool binary = true;
    const double next = gncStep(columns, c, s, lo, hi, beta, mu, &binary);
    const double step = std::fabs(wrapAngle(next - theta));
    theta = next;
    if (binary && step < 1e-9) break;
    mu *= p.gnc_factor;
  }
  return theta;
}

Location tlsLocation(const std::vector<Eigen::Vector2d>& obs, const std::vector<double>& w,
                     double beta) {
  const double b2 = beta * beta;
  Location out;
  const size_t n = obs.size();
  if (n == 0) return out;
  std::vector<double> support(n, 0.0);
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < n; ++j) {
      if ((obs[i] - obs[j]).squaredNorm() <= b2) support[i] += w[j];
    }
  }
  size_t seed = 0;
  for (size_t i = 1; i < n; ++i) {
    if (support[i] > support[seed]) seed = i;
  }
  Eigen::Vector2d t = obs[seed];
  for (int it = 0; it < 20; ++it) {
    Eigen::Vector2d sum = Eigen::Vector2d::Zero();
    double ws = 0.0;
    for (size_t i = 0; i < n; ++i) {
      if ((obs[i] - t).squaredNorm() <= b2) {
        sum += w[i] * obs[i];
        ws += w[i];
      }
    }
    if (ws <= 0.0) break;
    const Eigen::Vector2d next = sum / ws;
    const bool done = (next - t).norm() < 1e-10;
    t = next;
    if (done) break;
  }
  out.t = t;
  for (size_t i = 0; i < n; ++i) {
    if ((obs[i] - t).squaredNorm() <= b2) out.best += w[i];
  }
  for (size_t i = 0; i < n; ++i) {
    if ((obs[i] - t).squaredNorm() > 4.0 * b2) out.runner_up = std::max(out.runner_up, support[i]);
  }
  return out;
}

std::vector<Tim> translationInvariantMeasurements(const std::vector<Correspondence>& corrs,
                                                  const std::vector<double>& w,
                                                  const PoseEstimatorParams& params) {
  const int k = static_cast<int>(corrs.size());
  const double beta_r = params.beta_yaw_m;
  const double far2 = 2.0 * (beta_r + 1e-6) * (beta_r + 1e-6);  // see the length test below
  const int64_t total_pairs = static_cast<int64_t>(k) * (k - 1) / 2;
  std::vector<Tim> tims;
  tims.reserve(std::min<int64_t>(total_pairs, params.max_tim_pairs));
  forEachSampledPair(k, params.max_tim_pairs, [&](int a, int b) {
    // Two correspondences sharing a trunk are alternatives (one of them is wrong), never
    // independent evidence.
    if (corrs[a].iq == corrs[b].iq || corrs[a].ic == corrs[b].ic) return;
    const double qx = corrs[a].pq.x() - corrs[b].pq.x(), qy = corrs[a].pq.y() - corrs[b].pq.y();
    const double cx = corrs[a].pc.x() - corrs[b].pc.x(), cy = corrs[a].pc.y() - corrs[b].pc.y();
    // Most TIMs fail the length test below by far: decided on sqrt, which is within a few
    // ulps of hypot (the margin), before the costlier hypot that the kept ones are measured by
    // (and before their weight's sqrt). Before that, without a square root: |√Q - √C| is at
    // least |Q - C| / √(2 (Q + C)), so beyond `far` the sqrt test fails too. Its 1e-6 m of
    // margin covers that test's 1e-12 (1 + √Q + √C) for lengths below 10^5 m and the rounding.
    const double qq = qx * qx + qy * qy, cc = cx * cx + cy * cy;
    if (qq + cc < 1e10 && (qq - cc) * (qq - cc) > far2 * (qq + cc)) return;
    const double sq = std::sqrt(qq), sc = std::sqrt(cc);
    if (std::fabs(sq - sc) > beta_r + 1e-12 * (1.0 + sq + sc)) return;
    const double lq = std::hypot(qx, qy), lc = std::hypot(cx, cy);
    if (lq < 1e-9 || lc < 1e-9) return;
    // A rotation preserves length: a TIM with | |d^q| - |d^c| | > beta_R has residual
    // > beta_R at every theta, so it adds the constant beta_R^2 to Eq. (3.14) and cannot
    // move the minimiser. Dropping it is exact and removes most outliers before GNC.
    if (std::fabs(lq - lc) > beta_r) return;
    Tim m{a, b, qx, qy, cx, cy, std::sqrt(w[a] * w[b])};  // omega_ab of Eq. (3.13)
    m.lq = lq;
    m.lc = lc;
    tims.push_back(m);
  });
  return tims;
}

YawEstimate estimateYaw(const std::vector<Tim>& tims, const PoseEstimatorParams& params) {
  const double beta_r = params.beta_yaw_m, beta_r2 = beta_r * beta_r;
  const double theta_gnc = refineYaw(tims, gncTlsYaw(tims, beta_r, params), beta_r2);
  const ArcSweep sweep = consensusYaw(tims, beta_r);
  const double theta_sweep = refineYaw(tims, sweep.theta, beta_r2);
  const double cost_gnc = tlsCost(tims, theta_gnc, beta_r2);
  const double cost_sweep = tlsCost(tims, theta_sweep, beta_r2);
  YawEstimate out;
  out.theta = cost_sweep < cost_gnc ? theta_sweep : theta_gnc;
  out.consensus = sweep.best;
  out.runner_up = sweep.runner_up;
  return out;
}

std::vector<int> rotationInliers(const std::vector<Tim>& tims, int k, double theta, double beta_r) {
  // One lucky TIM is not enough: an outlier b agrees with an inlier a exactly when b happens to
  // satisfy the translation too; requiring a share of the best vote count filters singletons.
  const double beta_r2 = beta_r * beta_r;
  std::vector<int> votes(k, 0);
  const double c = std::cos(theta), s = std::sin(theta);
  for (const Tim& m : tims) {
    if (timResidual2(m, c, s) <= beta_r2) {
      ++votes[m.a];
      ++votes[m.b];
    }
  }
  const int max_votes = *std::max_element(votes.begin(), votes.end());
  const int min_votes = std::max(1, static_cast<int>(std::ceil(0.2 * max_votes)));
  std::vector<int> inliers;
  for (int i = 0; i < k; ++i) {
    if (votes[i] >= min_votes) inliers.push_back(i);
  }
  return inliers;
}

std::vector<int> solveTranslation(const std::vector<Correspondence>& corrs,
                                  const std::vector<double>& w, double yaw,
                                  const std::vector<int>& set, double beta_xy, Location* loc) {
  const Eigen::Matrix2d r = Eigen::Rotation2Dd(yaw).toRotationMatrix();
  std::vector<Eigen::Vector2d> obs;  // Eq. (3.15)
  std::vector<double> ow;
  for (int i : set) {
    obs.push_back(corrs[i].pc.head<2>() - r * corrs[i].pq.head<2>());
    ow.push_back(w[i]);
  }
  *loc = tlsLocation(obs, ow, beta_xy);  // Eq. (3.16)
  std::vector<int> inl;
  for (size_t j = 0; j < set.size(); ++j) {
    if ((obs[j] - loc->t).squaredNorm() <= beta_xy * beta_xy) inl.push_back(set[j]);
  }
  return inl;
}

void refineJointly(const std::vector<Correspondence>& corrs, const std::vector<double>& w,
                   const std::vector<int>& inliers_r, double beta_xy, double* theta, Location* loc,
                   std::vector<int>* inliers_t) {
  // Removes the small bias of estimating yaw from TIMs alone (each TIM mixes two noisy trunks).
  for (int it = 0; it < 3 && inliers_t->size() >= 2; ++it) {
    std::vector<PointPair2d> pairs;
    std::vector<double> pw;
    for (int i : *inliers_t) {
      pairs.emplace_back(corrs[i].pq.head<2>(), corrs[i].pc.head<2>());
      pw.push_back(w[i]);
    }
    Eigen::Vector2d mq, mc;
    const double yaw = procrustesYaw(pairs, &pw, &mq, &mc);
    Location l2;
    std::vector<int> inl2 = solveTranslation(corrs, w, yaw, inliers_r, beta_xy, &l2);
    if (inl2.size() < inliers_t->size()) break;
    const bool same = inl2 == *inliers_t;
    *theta = yaw;
    *loc = l2;
    *inliers_t = inl2;
    if (same) break;
  }
}

double estimateElevation(const std::vector<Correspondence>& corrs, const std::vector<double>& w,
                         const std::vector<int>& inliers_t, double beta_z) {
  // A hidden base is extrapolated terrain, so it measures nothing while seen ones exist.
  std::vector<Eigen::Vector2d> dz;
  std::vector<double> wz;
  for (int pass = 0; pass < 2 && dz.empty(); ++pass) {
    for (int i : inliers_t) {
      if (pass == 0 && !corrs[i].z_ok) continue;
      dz.emplace_back(corrs[i].pc.z() - corrs[i].pq.z(), 0.0);
      wz.push_back(w[i]);
    }
  }
  return tlsLocation(dz, wz, beta_z).t.x();
}

void addResiduals(const std::vector<Correspondence>& corrs, const std::vector<double>& w,
                  PoseEstimate* est) {
  double sxy = 0.0, sz = 0.0, nz = 0.0;
  const bool any_z_ok = std::any_of(est->inliers_T.begin(), est->inliers_T.end(),
                                    [&](int i) { return corrs[i].z_ok; });
  for (int i : est->inliers_T) {
    const Eigen::Vector3d r = corrs[i].pc - est->T_c_q * corrs[i].pq;
    sxy += r.head<2>().squaredNorm();
    if (corrs[i].z_ok || !any_z_ok) sz += r.z() * r.z(), nz += 1.0;
    est->inlier_weight += w[i];
  }
  const double n = static_cast<double>(est->inliers_T.size());
  est->rms_xy_m = std::sqrt(sxy / n);
  est->rms_z_m = std::sqrt(sz / nz);
}
}  // namespace pose_stages

std::string PoseEstimatorParams::validate() const {
  std::ostringstream err;
  if (!(beta_yaw_m > 0.0 && std::isfinite(beta_yaw_m))) err << "beta_yaw_m must be > 0; ";
  if (!(beta_xy_m > 0.0 && std::isfinite(beta_xy_m))) err << "beta_xy_m must be > 0; ";
  if (!(beta_z_m > 0.0 && std::isfinite(beta_z_m))) err << "beta_z_m must be > 0; ";
  if (!(gnc_factor > 1.0 && std::isfinite(gnc_factor))) err << "gnc_factor must be > 1; ";
  if (gnc_max_iterations < 1) err << "gnc_max_iterations must be >= 1; ";
  if (max_tim_pairs < 1) err << "max_tim_pairs must be >= 1; ";
  return err.str();
}

PoseEstimate estimatePose(const std::vector<Correspondence>& corrs,
                          const PoseEstimatorParams& params) {
  using pose_stages::Location;
  using pose_stages::Tim;
  using pose_stages::YawEstimate;
  PoseEstimate est;
  const int k = static_cast<int>(corrs.size());
  if (k < 2) return est;
  std::vector<double> w(k);
  for (int i = 0; i < k; ++i) w[i] = params.unit_weights ? 1.0 : corrs[i].w;

  // Eq. (3.13): translation-invariant measurements.
  const std::vector<Tim> tims = pose_stages::translationInvariantMeasurements(corrs, w, params);
  if (tims.empty()) return est;

  // Eq. (3.14): robust yaw; I_R: the rotation-consistent correspondences.
  const YawEstimate yaw = pose_stages::estimateYaw(tims, params);
  double theta = yaw.theta;
  est.yaw_consensus = yaw.consensus;
  est.yaw_runner_up = yaw.runner_up;
  est.inliers_R = pose_stages::rotationInliers(tims, k, theta, params.beta_yaw_m);
  if (est.inliers_R.size() < 2) return est;

  // Eqs. (3.15)-(3.16): weighted TLS translation, then the joint refinement of Eq. (3.11).
  Location loc;
  std::vector<int> inl_t =
      pose_stages::solveTranslation(corrs, w, theta, est.inliers_R, params.beta_xy_m, &loc);
  est.translation_runner_up = loc.runner_up;
  est.translation_consensus = loc.best;
  pose_stages::refineJointly(corrs, w, est.inliers_R, params.beta_xy_m, &theta, &loc, &inl_t);
  est.inliers_T = inl_t;
  if (est.inliers_T.empty()) return est;

  // Eq. (3.17): weighted TLS elevation over I_T.
  const double t_z = pose_stages::estimateElevation(corrs, w, est.inliers_T, params.beta_z_m);

  est.yaw_rad = wrapAngle(theta);
  est.T_c_q = Pose::Identity();
  est.T_c_q.linear() = rotZ(est.yaw_rad);
  est.T_c_q.translation() = Eigen::Vector3d(loc.t.x(), loc.t.y(), t_z);
  pose_stages::addResiduals(corrs, w, &est);
  est.ok = true;
  return est;
}

}  // namespace dtif
