// Robust circle fit of a breast-height slice (paper Sec. 3.B, "circle fitting"): RANSAC over
// 3-point circles, an algebraic Kasa fit of the inliers, a Tukey-weighted geometric
// Gauss-Newton refinement, and the evidence that the circle is bark.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "dtif/core/extraction/avx2.h"
#include "dtif/core/extraction/extraction_stages.h"
#include "dtif/core/extraction/lazy_mt19937.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/robust.h"

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Circle through three points; false when they are (nearly) collinear.
bool circleFrom3(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                 double* cx, double* cy, double* r) {
  const double bx = b.x() - a.x(), by = b.y() - a.y();
  const double qx = c.x() - a.x(), qy = c.y() - a.y();
  const double d = 2.0 * (bx * qy - by * qx);
  if (std::abs(d) < 1e-12) return false;
  const double b2 = bx * bx + by * by, q2 = qx * qx + qy * qy;
  const double ux = (qy * b2 - by * q2) / d;
  const double uy = (bx * q2 - qx * b2) / d;
  *cx = a.x() + ux;
  *cy = a.y() + uy;
  *r = std::sqrt(ux * ux + uy * uy);
  return std::isfinite(*r);
}

// Algebraic (Kasa) fit: x^2 + y^2 + D x + E y + F = 0 in the least-squares sense.
bool kasaFit(const std::vector<Eigen::Vector2d>& xy, const std::vector<char>& use, double* cx,
             double* cy, double* r) {
  Eigen::Vector2d mean(0, 0);
  size_t n = 0;
  for (size_t i = 0; i < xy.size(); ++i)
    if (use[i]) mean += xy[i], ++n;
  if (n < 3) return false;
  mean /= static_cast<double>(n);
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < xy.size(); ++i) {
    if (!use[i]) continue;
    const Eigen::Vector2d p = xy[i] - mean;  // centred for conditioning
    const Eigen::Vector3d row(p.x(), p.y(), 1.0);
    const double rhs = -(p.x() * p.x() + p.y() * p.y());
    A += row * row.transpose();
    b += row * rhs;
  }
  const Eigen::Vector3d s = A.ldlt().solve(b);
  if (!s.allFinite()) return false;
  const double ux = -0.5 * s(0), uy = -0.5 * s(1);
  const double r2 = ux * ux + uy * uy - s(2);
  if (!(r2 > 0.0)) return false;
  *cx = mean.x() + ux;
  *cy = mean.y() + uy;
  *r = std::sqrt(r2);
  return true;
}

// Angular coverage of the inliers: 360 minus the gaps wider than max_gap_deg between
// consecutive inlier angles. Only wide gaps count, so a few stray inliers in an unseen sector
// do not make a partial arc look complete, and sparse points on a seen sector do not make it
// look empty.
double arcCoverageDeg(const std::vector<Eigen::Vector2d>& xy, const std::vector<char>& inl,
                      double cx, double cy, double max_gap_deg) {
  std::vector<double> ang;
  for (size_t i = 0; i < xy.size(); ++i)
    if (inl[i]) ang.push_back(std::atan2(xy[i].y() - cy, xy[i].x() - cx) * 180.0 / kPi);
  if (ang.size() < 2) return 0.0;
  std::sort(ang.begin(), ang.end());
  double uncovered = 0.0;
  for (size_t i = 0; i < ang.size(); ++i) {
    const double gap = i + 1 < ang.size() ? ang[i + 1] - ang[i] : ang[0] + 360.0 - ang[i];
    if (gap > max_gap_deg) uncovered += gap;
  }
  return std::max(0.0, 360.0 - uncovered);
}

struct Circle {
  double cx = 0.0, cy = 0.0, r = 0.0;  // centre and radius [m]
};

// Inliers minus inside points among the scored points m0..m1-1 of a hypothesis (squared
// distances to its centre against in_lo, in_hi, inside). Two lanes at a time where SSE2 is: the
// same IEEE operations per point (x86-64 has no fused multiply-add here), so the same counts.
// The lanes' counts stay in a register: a comparison's mask is -1 per lane, so adding the
// inside mask and subtracting the inlier mask counts inliers minus inside points.
long scoreBlock(const double* sx, const double* sy, size_t m0, size_t m1, double cx, double cy,
                double in_lo, double in_hi, double inside) {
  int64_t score = 0;
  size_t m = m0;
#ifdef __SSE2__
  const __m128d vcx = _mm_set1_pd(cx), vcy = _mm_set1_pd(cy);
  const __m128d vlo = _mm_set1_pd(in_lo), vhi = _mm_set1_pd(in_hi), vin = _mm_set1_pd(inside);
  __m128i lanes = _mm_setzero_si128();  // inliers minus inside points, per lane
  for (; m + 2 <= m1; m += 2) {
    const __m128d dx = _mm_sub_pd(_mm_loadu_pd(sx + m), vcx);
    const __m128d dy = _mm_sub_pd(_mm_loadu_pd(sy + m), vcy);
    const __m128d d2 = _mm_add_pd(_mm_mul_pd(dx, dx), _mm_mul_pd(dy, dy));
    const __m128d inl = _mm_and_pd(_mm_cmpgt_pd(d2, vlo), _mm_cmplt_pd(d2, vhi));
    const __m128d ins = _mm_cmplt_pd(d2, vin);
    lanes = _mm_add_epi64(lanes, _mm_sub_epi64(_mm_castpd_si128(ins), _mm_castpd_si128(inl)));
  }
  int64_t lane[2];
  _mm_storeu_si128(reinterpret_cast<__m128i*>(lane), lanes);
  score += lane[0] + lane[1];
#endif
  for (; m < m1; ++m) {
    const double dx = sx[m] - cx, dy = sy[m] - cy;
    const double d2 = dx * dx + dy * dy;
    score += static_cast<int64_t>((d2 > in_lo) & (d2 < in_hi));
    score -= static_cast<int64_t>(d2 < inside);
  }
  return static_cast<long>(score);
}

#if DTIF_AVX2_PATHS
// scoreBlock four lanes at a time (the caller checks useAvx2()): the same IEEE operations per
// point, so the same counts.
DTIF_TARGET_AVX2 long scoreBlockAvx2(const double* sx, const double* sy, size_t m0, size_t m1,
                                     double cx, double cy, double in_lo, double in_hi,
                                     double inside) {
  const __m256d vcx = _mm256_set1_pd(cx), vcy = _mm256_set1_pd(cy);
  const __m256d vlo = _mm256_set1_pd(in_lo), vhi = _mm256_set1_pd(in_hi);
  const __m256d vin = _mm256_set1_pd(inside);
  __m256i lanes = _mm256_setzero_si256();  // inliers minus inside points, per lane
  size_t m = m0;
  for (; m + 4 <= m1; m += 4) {
    const __m256d dx = _mm256_sub_pd(_mm256_loadu_pd(sx + m), vcx);
    const __m256d dy = _mm256_sub_pd(_mm256_loadu_pd(sy + m), vcy);
    const __m256d d2 = _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy));
    const __m256d inl =
        _mm256_and_pd(_mm256_cmp_pd(d2, vlo, _CMP_GT_OQ), _mm256_cmp_pd(d2, vhi, _CMP_LT_OQ));
    const __m256d ins = _mm256_cmp_pd(d2, vin, _CMP_LT_OQ);
    lanes = _mm256_add_epi64(lanes,
                             _mm256_sub_epi64(_mm256_castpd_si256(ins), _mm256_castpd_si256(inl)));
  }
  alignas(32) int64_t lane[4];
  _mm256_store_si256(reinterpret_cast<__m256i*>(lane), lanes);
  const long score = static_cast<long>(lane[0] + lane[1] + lane[2] + lane[3]);
  return score + scoreBlock(sx, sy, m, m1, cx, cy, in_lo, in_hi, inside);
}
#endif

// RANSAC over 3-point circles with an adaptive stop. Score: inliers minus points well inside
// the circle (a stem is opaque). Returns the best score; <= 0: no usable hypothesis.
long ransacCircle(const std::vector<Eigen::Vector2d>& xy, const CircleFitParams& params,
                  Circle* best) {
  const size_t n = xy.size();
  const size_t stride = std::max<size_t>(1, n / static_cast<size_t>(params.score_points));
  LazyMt19937 rng(params.seed);                     // std::mt19937(params.seed)'s numbers
  const uint32_t range = static_cast<uint32_t>(n);  // a slice's band: far below 2^32 points
  const double tol = params.inlier_m;
  long best_score = -1;
  // The scored points, contiguous: the scoring loop below runs up to `iterations` times over
  // them and vectorises on a plain array.
  std::vector<double> sx, sy;
  for (size_t m = 0; m < n; m += stride) sx.push_back(xy[m].x()), sy.push_back(xy[m].y());
  const size_t scored = sx.size();
  int needed = params.iterations;
  const bool avx2 = useAvx2();
  for (int it = 0; it < std::min(needed, params.iterations); ++it) {
    const size_t i = rng.below(range), j = rng.below(range), k = rng.below(range);
    if (i == j || j == k || i == k) continue;
    double cx, cy, r;
    if (!circleFrom3(xy[i], xy[j], xy[k], &cx, &cy, &r)) continue;
    if (r < params.min_radius_m || r > params.max_radius_m) continue;
    // Squared distances: no square root in the hot loop.
    const double in_lo = r > tol ? (r - tol) * (r - tol) : 0.0, in_hi = (r + tol) * (r + tol);
    const double inside = r > 2.0 * tol ? (r - 2.0 * tol) * (r - 2.0 * tol) : -1.0;
    long score = 0;
    // In blocks, leaving as soon as the points left cannot lift the score above the best: such
    // a hypothesis changes nothing below.
    constexpr size_t kBlock = 32;
    for (size_t m0 = 0; m0 < scored; m0 += kBlock) {
      if (score + static_cast<long>(scored - m0) <= best_score) break;
      const size_t m1 = std::min(scored, m0 + kBlock);
      // Branch-free counts (inside < in_lo: a point is an inlier, inside, or neither), which the
      // compiler vectorises.
#if DTIF_AVX2_PATHS
      if (avx2) {
        score += scoreBlockAvx2(sx.data(), sy.data(), m0, m1, cx, cy, in_lo, in_hi, inside);
        continue;
      }
#endif
      score += scoreBlock(sx.data(), sy.data(), m0, m1, cx, cy, in_lo, in_hi, inside);
    }
    if (score > best_score) {
      best_score = score;
      best->cx = cx, best->cy = cy, best->r = r;
      const double w = std::min(0.999, static_cast<double>(score) / static_cast<double>(scored));
      if (w > 0.0)
        needed = std::max(params.min_iterations,
                          static_cast<int>(std::ceil(std::log(0.01) / std::log(1.0 - w * w * w))));
    }
  }
  return best_score;
}

// The Gauss-Newton normal equations of a step, A = sum w J J^T and g = sum w J e with
// J = (jx, jy, -1): the lower triangle of A, as Eigen's A += w * J * J.transpose() sums it
// (element (i, j) adds (w J_i) J_j), and g's (w J_i) e. In scalars: Eigen's stores of the
// products to the stack stalled the next point's loads (store forwarding). LDLT reads only the
// lower triangle.
struct NormalSums {
  double a00 = 0.0, a10 = 0.0, a20 = 0.0, a11 = 0.0, a21 = 0.0, a22 = 0.0;
  double g0 = 0.0, g1 = 0.0, g2 = 0.0;

  // One point: residual e, Tukey weight w, Jacobian (jx, jy); a point the step skips comes with
  // all four +0 and adds only zeros, which change no sum (a sum from +0 is never -0).
  void add(double e, double w, double jx, double jy) {
    const double wx = w * jx, wy = w * jy, wz = -w;  // w * J (J_2 = -1: exact)
    a00 += wx * jx, a10 += wy * jx, a20 += wz * jx;
    a11 += wy * jy, a21 += wz * jy, a22 += w;  // wz * -1 = w exactly
    g0 += wx * e, g1 += wy * e, g2 += wz * e;
  }
  Eigen::Matrix3d a() const {
    Eigen::Matrix3d m;
    m << a00, a10, a20, a10, a11, a21, a20, a21, a22;
    return m;
  }
  Eigen::Vector3d g() const { return Eigen::Vector3d(g0, g1, g2); }
};

// Per point of a Gauss-Newton step about the circle (cx, cy, r): residual e = d - r (d: the
// distance to the centre), Tukey weight w (constant c) and the Jacobian's (jx, jy) =
// -(dx, dy) / d; all four +0 for a point the step skips (d < 1e-9 or w <= 0), so that the sums
// need no test (a branch that the weights' pattern defeated).
struct PointTerms {
  std::vector<double> e, w, jx, jy;
};

#if DTIF_AVX2_PATHS
// pointTerms' points m.. four at a time (the caller checks useAvx2()), as its SSE2 loop takes
// them two at a time. Returns the first point not taken.
DTIF_TARGET_AVX2 size_t pointTermsAvx2(const std::vector<Eigen::Vector2d>& xy, double cx, double cy,
                                       double r, double c, PointTerms* t) {
  const size_t n = xy.size();
  const __m256d vcx = _mm256_set1_pd(cx), vcy = _mm256_set1_pd(cy), vr = _mm256_set1_pd(r);
  const __m256d vc = _mm256_set1_pd(c), one = _mm256_set1_pd(1.0), sign = _mm256_set1_pd(-0.0);
  const __m256d tiny = _mm256_set1_pd(1e-9), zero = _mm256_setzero_pd();
  size_t m = 0;
  for (; m + 4 <= n; m += 4) {
    // Four (x, y) pairs: (x0 y0 x1 y1) and (x2 y2 x3 y3), lanes in the order 0 2 1 3 after the
    // unpacks, put back by one permute each.
    const __m256d p01 = _mm256_loadu_pd(xy[m].data()), p23 = _mm256_loadu_pd(xy[m + 2].data());
    const __m256d x = _mm256_permute4x64_pd(_mm256_unpacklo_pd(p01, p23), _MM_SHUFFLE(3, 1, 2, 0));
    const __m256d y = _mm256_permute4x64_pd(_mm256_unpackhi_pd(p01, p23), _MM_SHUFFLE(3, 1, 2, 0));
    const __m256d dx = _mm256_sub_pd(x, vcx), dy = _mm256_sub_pd(y, vcy);
    const __m256d d = _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)));
    const __m256d e = _mm256_sub_pd(d, vr);
    const __m256d u = _mm256_div_pd(e, vc);
    const __m256d tt = _mm256_sub_pd(one, _mm256_mul_pd(u, u));
    const __m256d in = _mm256_cmp_pd(_mm256_andnot_pd(sign, e), vc, _CMP_LT_OQ);  // |e| < c
    const __m256d w = _mm256_and_pd(in, _mm256_mul_pd(tt, tt));
    const __m256d keep =
        _mm256_and_pd(_mm256_cmp_pd(d, tiny, _CMP_NLT_UQ), _mm256_cmp_pd(w, zero, _CMP_NLE_UQ));
    _mm256_storeu_pd(&t->e[m], _mm256_and_pd(keep, e));
    _mm256_storeu_pd(&t->w[m], _mm256_and_pd(keep, w));
    _mm256_storeu_pd(&t->jx[m], _mm256_and_pd(keep, _mm256_div_pd(_mm256_xor_pd(dx, sign), d)));
    _mm256_storeu_pd(&t->jy[m], _mm256_and_pd(keep, _mm256_div_pd(_mm256_xor_pd(dy, sign), d)));
  }
  return m;
}
#endif

// The terms of every point, two at a time where SSE2 is: the same IEEE operations as
// planarDist, tukeyWeight and the divisions (x86-64 has no fused multiply-add here), so the
// same values; the step's sums stay sequential, in point order.
void pointTerms(const std::vector<Eigen::Vector2d>& xy, double cx, double cy, double r, double c,
                PointTerms* t) {
  const size_t n = xy.size();
  t->e.resize(n), t->w.resize(n), t->jx.resize(n), t->jy.resize(n);
  size_t m = 0;
#if DTIF_AVX2_PATHS
  if (useAvx2()) m = pointTermsAvx2(xy, cx, cy, r, c, t);
#endif
#ifdef __SSE2__
  const __m128d vcx = _mm_set1_pd(cx), vcy = _mm_set1_pd(cy), vr = _mm_set1_pd(r);
  const __m128d vc = _mm_set1_pd(c), one = _mm_set1_pd(1.0), sign = _mm_set1_pd(-0.0);
  const __m128d tiny = _mm_set1_pd(1e-9), zero = _mm_setzero_pd();
  for (; m + 2 <= n; m += 2) {
    // xy is an array of (x, y) pairs: two points are four doubles.
    const __m128d p0 = _mm_loadu_pd(xy[m].data()), p1 = _mm_loadu_pd(xy[m + 1].data());
    const __m128d dx = _mm_sub_pd(_mm_unpacklo_pd(p0, p1), vcx);
    const __m128d dy = _mm_sub_pd(_mm_unpackhi_pd(p0, p1), vcy);
    const __m128d d = _mm_sqrt_pd(_mm_add_pd(_mm_mul_pd(dx, dx), _mm_mul_pd(dy, dy)));
    const __m128d e = _mm_sub_pd(d, vr);
    const __m128d u = _mm_div_pd(e, vc);
    const __m128d tt = _mm_sub_pd(one, _mm_mul_pd(u, u));
    const __m128d in = _mm_cmplt_pd(_mm_andnot_pd(sign, e), vc);  // |e| < c
    const __m128d w = _mm_and_pd(in, _mm_mul_pd(tt, tt));
    const __m128d keep = _mm_and_pd(_mm_cmpnlt_pd(d, tiny), _mm_cmpnle_pd(w, zero));
    _mm_storeu_pd(&t->e[m], _mm_and_pd(keep, e));
    _mm_storeu_pd(&t->w[m], _mm_and_pd(keep, w));
    _mm_storeu_pd(&t->jx[m], _mm_and_pd(keep, _mm_div_pd(_mm_xor_pd(dx, sign), d)));
    _mm_storeu_pd(&t->jy[m], _mm_and_pd(keep, _mm_div_pd(_mm_xor_pd(dy, sign), d)));
  }
#endif
  for (; m < n; ++m) {
    const double dx = xy[m].x() - cx, dy = xy[m].y() - cy;
    const double d = planarDist(dx, dy), w = tukeyWeight(d - r, c);
    const bool keep = !(d < 1e-9) && !(w <= 0.0);
    t->e[m] = keep ? d - r : 0.0, t->w[m] = keep ? w : 0.0;
    t->jx[m] = keep ? -dx / d : 0.0, t->jy[m] = keep ? -dy / d : 0.0;
  }
}

// The normal equations of the terms' points, in point order.
NormalSums normalSums(const PointTerms& t, size_t n) {
  NormalSums s;
  const double *e = t.e.data(), *w = t.w.data(), *jx = t.jx.data(), *jy = t.jy.data();
  for (size_t m = 0; m < n; ++m) s.add(e[m], w[m], jx[m], jy[m]);
  return s;
}

// The points a Gauss-Newton step can weigh, in their order: those within c_tukey + kSlack of
// the circle when they were gathered. A point farther than that has |d - r| >= c_tukey, hence
// weight 0, as long as the circle has moved (centre and radius, summed) less than kSlack since:
// skipping it changes no sum. Gathered again from all points once it has moved more.
class NearPoints {
 public:
  std::vector<Eigen::Vector2d> xy;

  void update(const std::vector<Eigen::Vector2d>& all, double cx, double cy, double r,
              double c_tukey) {
    if (gathered_ && moved_ < kSlack - kRounding) return;
    xy.resize(all.size());
    const size_t n = gather(all, cx, cy, r, c_tukey + kSlack);
    xy.resize(n);
    gathered_ = true;
    moved_ = 0.0;
  }
  void moved(const Eigen::Vector3d& step) {
    moved_ += std::abs(step(0)) + std::abs(step(1)) + std::abs(step(2));
  }

 private:
  // The points within reach of the circle into xy (sized for all), their count returned.
  // Branch-free (each point written, the count advanced by its test), two at a time where SSE2
  // is: the same IEEE operations as planarDist.
  size_t gather(const std::vector<Eigen::Vector2d>& all, double cx, double cy, double r,
                double reach) {
    Eigen::Vector2d* out = xy.data();
    size_t n = 0, m = 0;
#if DTIF_AVX2_PATHS
    if (useAvx2()) m = gatherAvx2(all, cx, cy, r, reach, &n);
#endif
#ifdef __SSE2__
    const __m128d vcx = _mm_set1_pd(cx), vcy = _mm_set1_pd(cy), vr = _mm_set1_pd(r);
    const __m128d vreach = _mm_set1_pd(reach), sign = _mm_set1_pd(-0.0);
    for (; m + 2 <= all.size(); m += 2) {
      const __m128d p0 = _mm_loadu_pd(all[m].data()), p1 = _mm_loadu_pd(all[m + 1].data());
      const __m128d dx = _mm_sub_pd(_mm_unpacklo_pd(p0, p1), vcx);
      const __m128d dy = _mm_sub_pd(_mm_unpackhi_pd(p0, p1), vcy);
      const __m128d d = _mm_sqrt_pd(_mm_add_pd(_mm_mul_pd(dx, dx), _mm_mul_pd(dy, dy)));
      const int near =
          _mm_movemask_pd(_mm_cmplt_pd(_mm_andnot_pd(sign, _mm_sub_pd(d, vr)), vreach));
      _mm_storeu_pd(out[n].data(), p0);
      n += near & 1;
      _mm_storeu_pd(out[n].data(), p1);
      n += near >> 1;
    }
#endif
    for (; m < all.size(); ++m) {
      out[n] = all[m];
      n += std::abs(planarDist(all[m].x() - cx, all[m].y() - cy) - r) < reach;
    }
    return n;
  }

#if DTIF_AVX2_PATHS
  // gather's points four at a time (the caller checks useAvx2()), the count into *n. Returns
  // the first point not taken.
  DTIF_TARGET_AVX2 size_t gatherAvx2(const std::vector<Eigen::Vector2d>& all, double cx, double cy,
                                     double r, double reach, size_t* n) {
    Eigen::Vector2d* out = xy.data();
    const __m256d vcx = _mm256_set1_pd(cx), vcy = _mm256_set1_pd(cy), vr = _mm256_set1_pd(r);
    const __m256d vreach = _mm256_set1_pd(reach), sign = _mm256_set1_pd(-0.0);
    size_t k = *n, m = 0;
    for (; m + 4 <= all.size(); m += 4) {
      const __m128d p0 = _mm_loadu_pd(all[m].data()), p1 = _mm_loadu_pd(all[m + 1].data());
      const __m128d p2 = _mm_loadu_pd(all[m + 2].data()), p3 = _mm_loadu_pd(all[m + 3].data());
      // (x0 y0 x2 y2) and (x1 y1 x3 y3): the unpacks give x and y in the order 0 1 2 3.
      const __m256d a = _mm256_set_m128d(p2, p0), b = _mm256_set_m128d(p3, p1);
      const __m256d dx = _mm256_sub_pd(_mm256_unpacklo_pd(a, b), vcx);
      const __m256d dy = _mm256_sub_pd(_mm256_unpackhi_pd(a, b), vcy);
      const __m256d d = _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)));
      const int near = _mm256_movemask_pd(
          _mm256_cmp_pd(_mm256_andnot_pd(sign, _mm256_sub_pd(d, vr)), vreach, _CMP_LT_OQ));
      _mm_storeu_pd(out[k].data(), p0);
      k += near & 1;
      _mm_storeu_pd(out[k].data(), p1);
      k += (near >> 1) & 1;
      _mm_storeu_pd(out[k].data(), p2);
      k += (near >> 2) & 1;
      _mm_storeu_pd(out[k].data(), p3);
      k += near >> 3;
    }
    *n = k;
    return m;
  }
#endif

  static constexpr double kSlack = 0.05;     // [m]
  static constexpr double kRounding = 1e-6;  // far above the rounding of d - r [m]
  bool gathered_ = false;
  double moved_ = 0.0;
};

// Kasa on the inliers of the RANSAC circle (when plausible), then Tukey-weighted geometric
// refinement (Gauss-Newton), which removes the Kasa bias on partial arcs.
Circle refineCircle(const std::vector<Eigen::Vector2d>& xy, const Circle& start,
                    const CircleFitParams& params) {
  const size_t n = xy.size();
  const double tol = params.inlier_m;
  std::vector<char> use(n, 0);
  for (size_t m = 0; m < n; ++m)
    use[m] = std::abs(planarDist(xy[m].x() - start.cx, xy[m].y() - start.cy) - start.r) < tol;
  double cx = start.cx, cy = start.cy, r = start.r;
  double kx, ky, kr;
  if (kasaFit(xy, use, &kx, &ky, &kr) && kr >= 0.5 * params.min_radius_m &&
      kr <= 2.0 * params.max_radius_m && planarDist(kx - cx, ky - cy) < std::max(r, 0.05)) {
    cx = kx, cy = ky, r = kr;
  }
  const double c_tukey = 2.0 * tol;
  PointTerms t;
  NearPoints near;
  for (int it = 0; it < 15; ++it) {
    near.update(xy, cx, cy, r, c_tukey);
    pointTerms(near.xy, cx, cy, r, c_tukey, &t);
    const NormalSums sums = normalSums(t, near.xy.size());
    Eigen::Matrix3d A = sums.a();
    const Eigen::Vector3d g = sums.g();
    if (A.trace() <= 0.0) break;
    A.diagonal() *= 1.0 + 1e-6;  // damping keeps a near-singular arc well posed
    const Eigen::Vector3d step = -A.ldlt().solve(g);
    if (!step.allFinite()) break;
    cx += step(0), cy += step(1), r += step(2);
    near.moved(step);
    if (step.norm() < 1e-7) break;
  }
  Circle c;
  c.cx = cx, c.cy = cy, c.r = r;
  return c;
}

// Inliers, inside / shell ratios, RMS and arc coverage of the final circle.
void circleEvidence(const std::vector<Eigen::Vector2d>& xy, const Circle& c, double tol,
                    CircleFit* fit) {
  size_t inliers = 0, inside = 0, shell = 0;
  double sq = 0.0;
  for (size_t m = 0; m < xy.size(); ++m) {
    const double e = planarDist(xy[m].x() - c.cx, xy[m].y() - c.cy) - c.r;
    const bool in = std::abs(e) < tol;
    fit->is_inlier[m] = in;
    if (in) ++inliers, sq += e * e;
    if (e <= -tol) ++inside;
    if (std::abs(e) < 3.0 * tol) ++shell;
  }
  if (inliers < 3) return;
  fit->ok = true;
  fit->cx = c.cx, fit->cy = c.cy, fit->r = c.r;
  fit->inliers = inliers;
  fit->inlier_ratio = static_cast<double>(inliers) / static_cast<double>(inliers + inside);
  fit->shell_ratio = static_cast<double>(inliers) / static_cast<double>(shell);
  fit->rms_m = std::sqrt(sq / static_cast<double>(inliers));
  // Gap threshold: 20 deg, or the angle of 10 cm of bark on thin stems (sparse points).
  const double max_gap = std::max(20.0, 0.1 / c.r * 180.0 / kPi);
  fit->arc_deg = arcCoverageDeg(xy, fit->is_inlier, c.cx, c.cy, max_gap);
}

}  // namespace

CircleFit fitCircleRobust(const std::vector<Eigen::Vector2d>& xy, const CircleFitParams& params) {
  CircleFit fit;
  fit.is_inlier.assign(xy.size(), 0);
  if (xy.size() < 3 || params.iterations < 1 || params.score_points < 1 || !(params.inlier_m > 0.0))
    return fit;
  Circle best;
  if (ransacCircle(xy, params, &best) <= 0) return fit;
  const Circle c = refineCircle(xy, best, params);
  if (!std::isfinite(c.cx) || !std::isfinite(c.cy) || !(c.r >= params.min_radius_m) ||
      c.r > params.max_radius_m)
    return fit;
  circleEvidence(xy, c, params.inlier_m, &fit);
  return fit;
}

bool fitCentreFixedRadius(const std::vector<Eigen::Vector2d>& xy, double r, double c_tukey,
                          Eigen::Vector2d* c, size_t min_support) {
  for (int it = 0; it < 15; ++it) {
    Eigen::Matrix2d A = Eigen::Matrix2d::Zero();
    Eigen::Vector2d g = Eigen::Vector2d::Zero();
    size_t support = 0;
    for (const auto& q : xy) {
      const Eigen::Vector2d d = q - *c;
      const double dn = d.norm();
      if (dn < 1e-9) continue;
      const double e = dn - r;
      const double w = tukeyWeight(e, c_tukey);
      if (w <= 0.0) continue;
      const Eigen::Vector2d J = -d / dn;
      A += w * J * J.transpose();
      g += w * J * e;
      ++support;
    }
    if (support < min_support || std::abs(A.determinant()) < 1e-12) return false;
    const Eigen::Vector2d step = -A.ldlt().solve(g);
    if (!step.allFinite()) return false;
    *c += step;
    if (step.norm() < 1e-6) break;
  }
  return true;
}

}  // namespace dtif
