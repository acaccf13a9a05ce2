// Trunk landmark extraction (paper Sec. 3.B, "Trunk landmark extraction", after Zhang et al.):
// no explicit ground segmentation; a local ground from a low z percentile, vertical-continuity
// voxel columns in a low slab above it, connected columns as trunk candidates, a robust circle
// fit at breast height, and the stem-base elevation z_m from the ground ring around the stem.
//
// The main pass uses flat arrays, counting sorts and an open-addressing hash instead of PCL
// kd-trees: the whole descriptor must take <= 40 ms per submap on one core (DESIGN.md).
#include "dtif/core/extraction/trunk_extractor.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <sstream>

#include "dtif/core/extraction/footprint.h"
#include "dtif/core/extraction/ground_map.h"
#include "dtif/core/robust.h"

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kArcBins = 72;  // 5 degree bins for the arc coverage

// std::hypot is exact but slow; the coordinates here are small and well scaled.
inline double dist(double dx, double dy) { return std::sqrt(dx * dx + dy * dy); }

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

// Robust centre of a circle of known radius (Tukey-weighted Gauss-Newton from a start
// centre); false when too few points support it.
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

// Robust plane z = a + b (x - x0) + c (y - y0) by IRLS. Asymmetric Tukey weights: points far
// above the plane are clutter (shrubs, stems, logs), points slightly below are ground noise.
// Slopes are mildly ridge-regularised so a collinear support (a narrow path) stays defined.
struct Plane {
  double a = 0.0, b = 0.0, c = 0.0;
  /// Height at an offset (dx, dy) from the point the plane was fitted about.
  double at(double dx, double dy) const { return a + b * dx + c * dy; }
};
Plane fitGroundPlane(const double* x, const double* y, const double* z, const double* w0, size_t n,
                     double x0, double y0, double c_up, double c_down, int iterations) {
  Plane p;
  std::vector<double> w(w0, w0 + n);
  for (int it = 0; it <= iterations; ++it) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
    double sw = 0.0;
    double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0, sz = 0, sxz = 0, syz = 0;
    for (size_t i = 0; i < n; ++i) {
      const double wi = w[i];
      if (wi <= 0.0) continue;
      const double dx = x[i] - x0, dy = y[i] - y0;
      sw += wi, sx += wi * dx, sy += wi * dy;
      sxx += wi * dx * dx, sxy += wi * dx * dy, syy += wi * dy * dy;
      sz += wi * z[i], sxz += wi * dx * z[i], syz += wi * dy * z[i];
    }
    A << sw, sx, sy, sx, sxx, sxy, sy, sxy, syy;
    rhs << sz, sxz, syz;
    if (sw <= 0.0) break;
    A(1, 1) += 1e-3 * sw;
    A(2, 2) += 1e-3 * sw;
    const Eigen::Vector3d s = A.ldlt().solve(rhs);
    if (!s.allFinite()) break;
    p.a = s(0), p.b = s(1), p.c = s(2);
    if (it == iterations) break;
    for (size_t i = 0; i < n; ++i) {
      const double r = z[i] - (p.a + p.b * (x[i] - x0) + p.c * (y[i] - y0));
      w[i] = w0[i] * tukeyWeight(r, r > 0.0 ? c_up : c_down);
    }
  }
  return p;
}

// Minimal open-addressing hash map from a 64-bit cell key to a dense index.
class CellHash {
 public:
  explicit CellHash(size_t expected) {
    size_t cap = 16;
    while (cap < 2 * expected + 1) cap <<= 1;
    keys_.assign(cap, kEmpty);
    vals_.assign(cap, -1);
    mask_ = cap - 1;
  }
  // Returns the index for key, inserting next_index when absent.
  int findOrInsert(uint64_t key, int next_index, bool* inserted) {
    size_t h = hash(key) & mask_;
    while (true) {
      if (keys_[h] == key) {
        *inserted = false;
        return vals_[h];
      }
      if (keys_[h] == kEmpty) {
        keys_[h] = key;
        vals_[h] = next_index;
        *inserted = true;
        return next_index;
      }
      h = (h + 1) & mask_;
    }
  }
  int find(uint64_t key) const {
    size_t h = hash(key) & mask_;
    while (true) {
      if (keys_[h] == key) return vals_[h];
      if (keys_[h] == kEmpty) return -1;
      h = (h + 1) & mask_;
    }
  }

 private:
  static constexpr uint64_t kEmpty = ~uint64_t{0};
  static size_t hash(uint64_t k) {
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    return static_cast<size_t>(k);
  }
  std::vector<uint64_t> keys_;
  std::vector<int> vals_;
  size_t mask_ = 0;
};

inline uint64_t cellKey(int64_t ix, int64_t iy) {
  return (static_cast<uint64_t>(ix + (int64_t{1} << 31)) << 32) |
         static_cast<uint64_t>(iy + (int64_t{1} << 31));
}

int findRoot(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

}  // namespace

std::string TrunkExtractorParams::validate() const {
  std::ostringstream err;
  auto positive = [&](const char* name, double v) {
    if (!(v > 0.0) || !std::isfinite(v)) err << name << " must be > 0 (got " << v << "); ";
  };
  auto unit = [&](const char* name, double v) {
    if (!(v >= 0.0 && v <= 1.0)) err << name << " must be in [0, 1] (got " << v << "); ";
  };
  positive("ground_cell_m", ground_cell_m);
  positive("ground_window_m", ground_window_m);
  unit("ground_percentile", ground_percentile);
  if (!(slab_min_h_m >= 0.0)) err << "slab_min_h_m must be >= 0; ";
  if (!(slab_max_h_m > slab_min_h_m)) err << "slab_max_h_m must exceed slab_min_h_m; ";
  positive("column_cell_m", column_cell_m);
  positive("layer_h_m", layer_h_m);
  if (layer_h_m > 0.0 && (slab_max_h_m - slab_min_h_m) / layer_h_m > 64.0)
    err << "layer_h_m too small: at most 64 layers fit in the slab; ";
  if (min_column_points < 1) err << "min_column_points must be >= 1; ";
  unit("min_continuity", min_continuity);
  if (!(cluster_gap_m >= 0.0)) err << "cluster_gap_m must be >= 0; ";
  if (column_cell_m > 0.0 && cluster_gap_m / column_cell_m > 10.0)
    err << "cluster_gap_m must be <= 10 column cells; ";
  if (!(fit_max_h_m > fit_min_h_m)) err << "fit_max_h_m must exceed fit_min_h_m; ";
  if (!(fit_min_h_m >= slab_min_h_m && fit_max_h_m <= slab_max_h_m))
    err << "fit band [fit_min_h_m, fit_max_h_m] must lie inside the slab; ";
  if (min_fit_points < 3) err << "min_fit_points must be >= 3; ";
  positive("min_radius_m", min_radius_m);
  if (!(max_radius_m > min_radius_m)) err << "max_radius_m must exceed min_radius_m; ";
  if (ransac_iterations < 1) err << "ransac_iterations must be >= 1; ";
  positive("ransac_inlier_m", ransac_inlier_m);
  unit("min_inlier_ratio", min_inlier_ratio);
  unit("min_shell_ratio", min_shell_ratio);
  if (!(min_arc_deg >= 0.0 && min_arc_deg <= 360.0)) err << "min_arc_deg must be in [0, 360]; ";
  if (!(max_lean_deg > 0.0 && max_lean_deg < 90.0)) err << "max_lean_deg must be in (0, 90); ";
  if (!(base_ring_inner_m >= 0.0)) err << "base_ring_inner_m must be >= 0; ";
  if (!(base_ring_outer_m > base_ring_inner_m))
    err << "base_ring_outer_m must exceed base_ring_inner_m; ";
  if (!(min_trunk_separation_m >= 0.0)) err << "min_trunk_separation_m must be >= 0; ";
  positive("max_fit_rms_m", max_fit_rms_m);
  positive("base_max_dh_m", base_max_dh_m);
  if (min_base_points < 3) err << "min_base_points must be >= 3; ";
  positive("base_below_m", base_below_m);
  if (max_base_below_points < 0) err << "max_base_below_points must be >= 0; ";
  if (max_fits_per_candidate < 1) err << "max_fits_per_candidate must be >= 1; ";
  if (!(footprint_cell_m >= 0.0 && footprint_cell_m <= 20.0))
    err << "footprint_cell_m must be in [0, 20] (0: no footprint); ";
  if (!(ground_map_cell_m >= 0.0 && ground_map_cell_m <= 20.0))
    err << "ground_map_cell_m must be in [0, 20] (0: no ground map); ";
  if (!(ground_map_z_step_m >= 0.001 && ground_map_z_step_m <= 1.0))
    err << "ground_map_z_step_m must be in [0.001, 1]; ";
  if (ground_map_min_points < 1) err << "ground_map_min_points must be >= 1; ";
  if (!(ground_map_margin_m >= 0.0)) err << "ground_map_margin_m must be >= 0; ";
  if (!(ground_map_below_seen >= 0.0 && ground_map_below_seen <= 1.01))
    err << "ground_map_below_seen must be in [0, 1.01]; ";
  std::string s = err.str();
  if (s.size() >= 2) s.resize(s.size() - 2);
  return s;
}

CircleFit fitCircleRobust(const std::vector<Eigen::Vector2d>& xy, const CircleFitParams& params) {
  CircleFit fit;
  const size_t n = xy.size();
  fit.is_inlier.assign(n, 0);
  if (n < 3 || params.iterations < 1 || !(params.inlier_m > 0.0)) return fit;

  // RANSAC hypotheses are scored on at most kScore points (evenly strided, deterministic):
  // enough to rank circles, and it bounds the cost on dense slices.
  constexpr size_t kScore = 400;
  const size_t stride = std::max<size_t>(1, n / kScore);
  std::mt19937 rng(params.seed);
  std::uniform_int_distribution<size_t> pick(0, n - 1);
  const double tol = params.inlier_m;
  double best_cx = 0, best_cy = 0, best_r = 0;
  long best_score = -1;
  // Adaptive stop (99 % confidence of one all-inlier sample), at least kMinIterations so
  // an early lucky sample on a branch does not end the search.
  constexpr int kMinIterations = 25;
  size_t scored = 0;
  for (size_t m = 0; m < n; m += stride) ++scored;
  int needed = params.iterations;
  for (int it = 0; it < std::min(needed, params.iterations); ++it) {
    const size_t i = pick(rng), j = pick(rng), k = pick(rng);
    if (i == j || j == k || i == k) continue;
    double cx, cy, r;
    if (!circleFrom3(xy[i], xy[j], xy[k], &cx, &cy, &r)) continue;
    if (r < params.min_radius_m || r > params.max_radius_m) continue;
    // Score: inliers minus points well inside the circle (a stem is opaque).
    // Squared distances: no square root in the hot loop.
    const double in_lo = r > tol ? (r - tol) * (r - tol) : 0.0, in_hi = (r + tol) * (r + tol);
    const double inside = r > 2.0 * tol ? (r - 2.0 * tol) * (r - 2.0 * tol) : -1.0;
    long score = 0;
    for (size_t m = 0; m < n; m += stride) {
      const double dx = xy[m].x() - cx, dy = xy[m].y() - cy;
      const double d2 = dx * dx + dy * dy;
      if (d2 > in_lo && d2 < in_hi)
        ++score;
      else if (d2 < inside)
        --score;
    }
    if (score > best_score) {
      best_score = score;
      best_cx = cx, best_cy = cy, best_r = r;
      const double w = std::min(0.999, static_cast<double>(score) / static_cast<double>(scored));
      if (w > 0.0)
        needed = std::max(kMinIterations,
                          static_cast<int>(std::ceil(std::log(0.01) / std::log(1.0 - w * w * w))));
    }
  }
  if (best_score <= 0) return fit;

  // Kasa on the RANSAC inliers, then Tukey-weighted geometric refinement (Gauss-Newton).
  std::vector<char> use(n, 0);
  for (size_t m = 0; m < n; ++m)
    use[m] = std::abs(dist(xy[m].x() - best_cx, xy[m].y() - best_cy) - best_r) < tol;
  double cx = best_cx, cy = best_cy, r = best_r;
  double kx, ky, kr;
  if (kasaFit(xy, use, &kx, &ky, &kr) && kr >= 0.5 * params.min_radius_m &&
      kr <= 2.0 * params.max_radius_m && dist(kx - cx, ky - cy) < std::max(r, 0.05)) {
    cx = kx, cy = ky, r = kr;
  }
  const double c_tukey = 2.0 * tol;
  for (int it = 0; it < 15; ++it) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    for (size_t m = 0; m < n; ++m) {
      const double dx = xy[m].x() - cx, dy = xy[m].y() - cy;
      const double d = dist(dx, dy);
      if (d < 1e-9) continue;
      const double e = d - r;
      const double w = tukeyWeight(e, c_tukey);
      if (w <= 0.0) continue;
      const Eigen::Vector3d J(-dx / d, -dy / d, -1.0);
      A += w * J * J.transpose();
      g += w * J * e;
    }
    if (A.trace() <= 0.0) break;
    A.diagonal() *= 1.0 + 1e-6;  // damping keeps a near-singular arc well posed
    const Eigen::Vector3d step = -A.ldlt().solve(g);
    if (!step.allFinite()) break;
    cx += step(0), cy += step(1), r += step(2);
    if (step.norm() < 1e-7) break;
  }
  if (!std::isfinite(cx) || !std::isfinite(cy) || !(r >= params.min_radius_m) ||
      r > params.max_radius_m)
    return fit;

  size_t inliers = 0, inside = 0, shell = 0;
  double sq = 0.0;
  for (size_t m = 0; m < n; ++m) {
    const double e = dist(xy[m].x() - cx, xy[m].y() - cy) - r;
    const bool in = std::abs(e) < tol;
    fit.is_inlier[m] = in;
    if (in) ++inliers, sq += e * e;
    if (e <= -tol) ++inside;
    if (std::abs(e) < 3.0 * tol) ++shell;
  }
  if (inliers < 3) return fit;
  fit.ok = true;
  fit.cx = cx, fit.cy = cy, fit.r = r;
  fit.inliers = inliers;
  fit.inlier_ratio = static_cast<double>(inliers) / static_cast<double>(inliers + inside);
  fit.shell_ratio = static_cast<double>(inliers) / static_cast<double>(shell);
  fit.rms_m = std::sqrt(sq / static_cast<double>(inliers));
  // Gap threshold: 20 deg, or the angle of 10 cm of bark on thin stems (sparse points).
  const double max_gap = std::max(20.0, 0.1 / r * 180.0 / kPi);
  fit.arc_deg = arcCoverageDeg(xy, fit.is_inlier, cx, cy, max_gap);
  return fit;
}

TrunkExtractionResult extractTrunks(const Cloud& cloud, const TrunkExtractorParams& p) {
  TrunkExtractionResult result;
  TrunkExtractionStats& st = result.stats;
  st.input_points = cloud.size();
  if (!p.validate().empty()) return result;

  // --- Finite points, relative to a local origin: keeps float precision with UTM-sized
  // coordinates (1e5 m and more).
  double ox = 0, oy = 0, oz = 0;
  bool have_origin = false;
  std::vector<float> X, Y, Z;
  X.reserve(cloud.size()), Y.reserve(cloud.size()), Z.reserve(cloud.size());
  for (const auto& pt : cloud.points) {
    if (!std::isfinite(pt.x) || !std::isfinite(pt.y) || !std::isfinite(pt.z)) continue;
    // Absurd magnitudes would overflow the cell indices below; they are not survey points.
    if (std::abs(pt.x) > 1e8f || std::abs(pt.y) > 1e8f || std::abs(pt.z) > 1e8f) continue;
    if (!have_origin) {
      ox = std::floor(pt.x), oy = std::floor(pt.y), oz = std::floor(pt.z);
      have_origin = true;
    }
    X.push_back(static_cast<float>(pt.x - ox));
    Y.push_back(static_cast<float>(pt.y - oy));
    Z.push_back(static_cast<float>(pt.z - oz));
  }
  const size_t n = X.size();
  st.finite_points = n;
  if (n < static_cast<size_t>(p.min_fit_points)) return result;

  // --- Local ground (Zhang et al.; no ground segmentation): per ground cell a low z
  // percentile, then per cell a robust plane through the cell values of the surrounding
  // window. A plane, not the window minimum, so slopes up to ~25 deg do not bias the height.
  float minx = X[0], maxx = X[0], miny = Y[0], maxy = Y[0];
  for (size_t i = 1; i < n; ++i) {
    minx = std::min(minx, X[i]), maxx = std::max(maxx, X[i]);
    miny = std::min(miny, Y[i]), maxy = std::max(maxy, Y[i]);
  }
  double g = p.ground_cell_m;
  // Guard against a few far outliers blowing up the dense ground grid.
  constexpr double kMaxGroundCells = 4e6;
  const double area_cells = (maxx - minx) / g * ((maxy - miny) / g);
  if (area_cells > kMaxGroundCells) g *= std::sqrt(area_cells / kMaxGroundCells);
  const int gnx = static_cast<int>(std::floor((maxx - minx) / g)) + 1;
  const int gny = static_cast<int>(std::floor((maxy - miny) / g)) + 1;
  const size_t gcells = static_cast<size_t>(gnx) * static_cast<size_t>(gny);
  auto gcellOf = [&](double x, double y, int* gx, int* gy) {
    *gx = std::clamp(static_cast<int>(std::floor((x - minx) / g)), 0, gnx - 1);
    *gy = std::clamp(static_cast<int>(std::floor((y - miny) / g)), 0, gny - 1);
  };
  // Counting sort of the points by ground cell.
  std::vector<uint32_t> gstart(gcells + 1, 0);
  std::vector<uint32_t> pcell(n);
  for (size_t i = 0; i < n; ++i) {
    int gx, gy;
    gcellOf(X[i], Y[i], &gx, &gy);
    pcell[i] = static_cast<uint32_t>(gy) * gnx + gx;
    ++gstart[pcell[i] + 1];
  }
  for (size_t c = 0; c < gcells; ++c) gstart[c + 1] += gstart[c];
  std::vector<uint32_t> gorder(n);
  {
    std::vector<uint32_t> fill(gstart.begin(), gstart.end() - 1);
    for (size_t i = 0; i < n; ++i) gorder[fill[pcell[i]]++] = static_cast<uint32_t>(i);
  }
  // Ground points of each cell. The MID-360 looks no lower than -7 deg, so near the path and
  // downhill the ground is often not seen at all, and the lowest points of a cell are then the
  // lowest hits on a stem or a shrub. A point counts as ground only in an "open" sub-column:
  // one with nothing between kOpenGap and kOpenTop above its lowest point (a stem, a shrub or
  // a log fills that space). The cell value is a low percentile of those points.
  constexpr double kSubCellM = 0.25, kGroundBand = 0.3, kOpenGap = 0.3, kOpenTop = 1.5;
  // A ground cell is mostly open: the cone-shaped cut of the lower field-of-view limit through
  // stems, shrubs and saplings leaves scattered open sub-columns, seen ground fills the cell.
  constexpr double kMinOpenFraction = 0.75;
  // Steepest terrain step between neighbouring cells (25 deg slopes plus roughness) [m/m].
  constexpr double kMaxGroundStepPerCell = 1.0;
  // Stem points: within this of the fitted circle [m]. A seen base: the stem's lowest point
  // within kMaxBaseGapM of the ground estimate [m].
  constexpr double kStemShellM = 0.08, kMaxBaseGapM = 0.5;
  const int ns = std::max(1, static_cast<int>(std::lround(g / kSubCellM)));
  const double sub = g / ns;
  std::vector<float> cell_low(gcells, std::numeric_limits<float>::quiet_NaN());
  std::vector<uint32_t> cell_count(gcells, 0);  // ground points of the cell
  std::vector<char> cell_any(gcells, 0);        // the cell holds any point
  std::vector<float> cell_min(gcells, std::numeric_limits<float>::infinity());  // lowest point
  {
    std::vector<float> zs, smin(static_cast<size_t>(ns) * ns);
    std::vector<char> sopen(smin.size());
    std::vector<int> sidx;
    for (size_t c = 0; c < gcells; ++c) {
      const uint32_t b = gstart[c], e = gstart[c + 1];
      if (b == e) continue;
      cell_any[c] = 1;
      const double x0 = minx + static_cast<double>(c % gnx) * g;
      const double y0 = miny + static_cast<double>(c / gnx) * g;
      std::fill(smin.begin(), smin.end(), std::numeric_limits<float>::infinity());
      std::fill(sopen.begin(), sopen.end(), 1);
      sidx.resize(e - b);
      for (uint32_t k = b; k < e; ++k) {
        const uint32_t i = gorder[k];
        const int sx = std::clamp(static_cast<int>((X[i] - x0) / sub), 0, ns - 1);
        const int sy = std::clamp(static_cast<int>((Y[i] - y0) / sub), 0, ns - 1);
        const int s = sy * ns + sx;
        sidx[k - b] = s;
        smin[s] = std::min(smin[s], Z[i]);
      }
      for (uint32_t k = b; k < e; ++k) {
        const int s = sidx[k - b];
        const float dz = Z[gorder[k]] - smin[s];
        if (dz > kOpenGap && dz <= kOpenTop) sopen[s] = 0;
      }
      zs.clear();
      for (uint32_t k = b; k < e; ++k) {
        const int s = sidx[k - b];
        const float z = Z[gorder[k]];
        if (sopen[s] && z - smin[s] <= kGroundBand) zs.push_back(z);
      }
      int nopen = 0;
      for (size_t s = 0; s < smin.size(); ++s) {
        nopen += sopen[s] && std::isfinite(smin[s]);
        cell_min[c] = std::min(cell_min[c], smin[s]);
      }
      if (zs.size() < 3 || nopen < kMinOpenFraction * static_cast<double>(ns * ns)) continue;
      const size_t q = static_cast<size_t>(p.ground_percentile * (zs.size() - 1));
      std::nth_element(zs.begin(), zs.begin() + q, zs.end());
      cell_low[c] = zs[q];
      cell_count[c] = static_cast<uint32_t>(zs.size());
    }
  }
  // Ground lies below everything: a "ground" cell higher than points next to it (a branch or a
  // log top above a slope or hollow whose real ground was not seen) is no ground cell.
  {
    const float max_step = static_cast<float>(kMaxGroundStepPerCell * g);
    std::vector<uint32_t> keep = cell_count;
    for (int cy = 0; cy < gny; ++cy) {
      for (int cx = 0; cx < gnx; ++cx) {
        const size_t c = static_cast<size_t>(cy) * gnx + cx;
        if (cell_count[c] == 0) continue;
        for (int dy = -1; dy <= 1 && keep[c]; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = cx + dx, yy = cy + dy;
            if (xx < 0 || yy < 0 || xx >= gnx || yy >= gny) continue;
            if (cell_low[c] - cell_min[static_cast<size_t>(yy) * gnx + xx] > max_step) {
              keep[c] = 0;
              break;
            }
          }
        }
      }
    }
    cell_count.swap(keep);
  }
  // Plane per occupied cell from the ground cells of the surrounding window. Where the window
  // holds too few ground cells, a three times wider one extrapolates the terrain; the cell's
  // ground then counts as not observed, and so does the base of a stem standing there.
  const int half = std::max(1, static_cast<int>(std::lround(0.5 * p.ground_window_m / g)));
  std::vector<Plane> cell_plane(gcells);
  std::vector<char> cell_seen(gcells, 0);
  {
    std::vector<double> wx, wy, wz, ww;
    auto gather = [&](int cx, int cy, int h) {
      wx.clear(), wy.clear(), wz.clear(), ww.clear();
      for (int dy = -h; dy <= h; ++dy) {
        const int yy = cy + dy;
        if (yy < 0 || yy >= gny) continue;
        for (int dx = -h; dx <= h; ++dx) {
          const int xx = cx + dx;
          if (xx < 0 || xx >= gnx) continue;
          const size_t cc = static_cast<size_t>(yy) * gnx + xx;
          if (cell_count[cc] == 0) continue;
          wx.push_back(dx * g), wy.push_back(dy * g), wz.push_back(cell_low[cc]);
          // Sparse cells give a poor percentile; they count less.
          ww.push_back(cell_count[cc] >= 5 ? 1.0 : 0.3);
        }
      }
    };
    constexpr size_t kMinGroundCells = 3;
    for (int cy = 0; cy < gny; ++cy) {
      for (int cx = 0; cx < gnx; ++cx) {
        const size_t c = static_cast<size_t>(cy) * gnx + cx;
        if (!cell_any[c]) continue;
        gather(cx, cy, half);
        cell_seen[c] = wx.size() >= kMinGroundCells;
        if (!cell_seen[c]) gather(cx, cy, 3 * half);
        if (wx.size() < kMinGroundCells) {
          // No ground anywhere near: the lowest point of the cell is the best guess left.
          cell_plane[c].a = cell_min[c];
          continue;
        }
        // Downweight cells above the plane: what is left of vegetation fills cells from above.
        cell_plane[c] =
            fitGroundPlane(wx.data(), wy.data(), wz.data(), ww.data(), wx.size(), 0.0, 0.0,
                           /*c_up=*/0.3, /*c_down=*/1.0, /*iterations=*/5);
      }
    }
  }
  // Cell centre in relative coordinates, for evaluating a cell's plane.
  auto groundAt = [&](double x, double y) {
    int gx, gy;
    gcellOf(x, y, &gx, &gy);
    const Plane& pl = cell_plane[static_cast<size_t>(gy) * gnx + gx];
    const double x0 = minx + (gx + 0.5) * g, y0 = miny + (gy + 0.5) * g;
    return pl.at(x - x0, y - y0);
  };
  std::vector<float> H(n);
  for (size_t i = 0; i < n; ++i) {
    const uint32_t c = pcell[i];
    const Plane& pl = cell_plane[c];
    const double x0 = minx + ((c % gnx) + 0.5) * g, y0 = miny + ((c / gnx) + 0.5) * g;
    H[i] = static_cast<float>(Z[i] - pl.at(X[i] - x0, Y[i] - y0));
  }

  // --- Footprint: DATASET.md's overlap cells of this submap in S, so verification measures
  // an aligned pair's overlap as the protocol does (percentiles on a subsample: it is timed).
  if (p.footprint_cell_m > 0.0) {
    constexpr size_t kFootSamples = 200000;
    result.footprint =
        makeFootprint(trunkHeightCells(cloud, Pose::Identity(), p.footprint_cell_m, kFootSamples),
                      p.footprint_cell_m);
  }

  // --- Vertical-continuity voxel columns in the slab (paper Sec. 3.B: "high-density voxel
  // columns with sufficient vertical continuity and plausible lower elevations").
  const double cs = p.column_cell_m;
  const int nlayers =
      std::max(1, static_cast<int>(std::ceil((p.slab_max_h_m - p.slab_min_h_m) / p.layer_h_m)));
  std::vector<uint32_t> slab;  // indices of slab points
  for (size_t i = 0; i < n; ++i)
    if (H[i] >= p.slab_min_h_m && H[i] < p.slab_max_h_m) slab.push_back(static_cast<uint32_t>(i));
  if (slab.empty()) return result;
  CellHash colhash(slab.size());
  std::vector<int64_t> col_ix, col_iy;
  std::vector<uint32_t> col_count;
  std::vector<uint64_t> col_mask;
  std::vector<int> slab_col(slab.size());
  for (size_t k = 0; k < slab.size(); ++k) {
    const uint32_t i = slab[k];
    const int64_t ix = static_cast<int64_t>(std::floor(X[i] / cs));
    const int64_t iy = static_cast<int64_t>(std::floor(Y[i] / cs));
    bool inserted;
    const int id =
        colhash.findOrInsert(cellKey(ix, iy), static_cast<int>(col_ix.size()), &inserted);
    if (inserted) {
      col_ix.push_back(ix), col_iy.push_back(iy), col_count.push_back(0), col_mask.push_back(0);
    }
    slab_col[k] = id;
    ++col_count[id];
    const int layer =
        std::min(nlayers - 1, static_cast<int>((H[i] - p.slab_min_h_m) / p.layer_h_m));
    col_mask[id] |= uint64_t{1} << layer;
  }
  const size_t ncol = col_ix.size();
  std::vector<char> col_pass(ncol, 0);
  for (size_t c = 0; c < ncol; ++c) {
    const int occupied = __builtin_popcountll(col_mask[c]);
    col_pass[c] = col_count[c] >= static_cast<uint32_t>(p.min_column_points) &&
                  occupied >= p.min_continuity * nlayers;
    st.candidate_columns += col_pass[c];
  }

  // --- Merge passing columns into candidates (connected components within cluster_gap_m).
  std::vector<int> parent(ncol);
  std::iota(parent.begin(), parent.end(), 0);
  const int reach = std::max(1, static_cast<int>(std::ceil(p.cluster_gap_m / cs)));
  for (size_t c = 0; c < ncol; ++c) {
    if (!col_pass[c]) continue;
    for (int dy = -reach; dy <= reach; ++dy) {
      for (int dx = -reach; dx <= reach; ++dx) {
        if (dy < 0 || (dy == 0 && dx <= 0)) continue;  // each pair once
        const int o = colhash.find(cellKey(col_ix[c] + dx, col_iy[c] + dy));
        if (o < 0 || !col_pass[o]) continue;
        const int ra = findRoot(parent, static_cast<int>(c)), rb = findRoot(parent, o);
        if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
      }
    }
  }
  // Dense candidate labels; failing columns touching a candidate join it, so bark columns at
  // the edge of a stem (too few points to pass on their own) still feed the circle fit.
  std::vector<int> root_label(ncol, -1), col_label(ncol, -1);
  int ncand = 0;
  for (size_t c = 0; c < ncol; ++c) {
    if (!col_pass[c]) continue;
    const int r = findRoot(parent, static_cast<int>(c));
    if (root_label[r] < 0) root_label[r] = ncand++;
    col_label[c] = root_label[r];
  }
  st.candidates = static_cast<size_t>(ncand);
  if (ncand == 0) return result;
  for (size_t c = 0; c < ncol; ++c) {
    if (col_pass[c]) continue;
    for (int dy = -1; dy <= 1 && col_label[c] < 0; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        const int o = colhash.find(cellKey(col_ix[c] + dx, col_iy[c] + dy));
        if (o >= 0 && col_pass[o]) {
          col_label[c] = col_label[o];
          break;
        }
      }
    }
  }
  // Bucket slab points by candidate.
  std::vector<uint32_t> cstart(ncand + 1, 0);
  for (size_t k = 0; k < slab.size(); ++k) {
    const int l = col_label[slab_col[k]];
    if (l >= 0) ++cstart[l + 1];
  }
  for (int l = 0; l < ncand; ++l) cstart[l + 1] += cstart[l];
  std::vector<uint32_t> corder(cstart[ncand]);
  {
    std::vector<uint32_t> fill(cstart.begin(), cstart.end() - 1);
    for (size_t k = 0; k < slab.size(); ++k) {
      const int l = col_label[slab_col[k]];
      if (l >= 0) corder[fill[l]++] = slab[k];
    }
  }

  // --- Per candidate: robust circle fit in the breast-height band, lean check, stem base.
  struct Found {
    TrunkLandmark t;
    size_t inliers;
  };
  std::vector<Found> found;
  CircleFitParams cfp;
  cfp.iterations = p.ransac_iterations;
  cfp.inlier_m = p.ransac_inlier_m;
  cfp.min_radius_m = p.min_radius_m;
  cfp.max_radius_m = p.max_radius_m;
  std::vector<Eigen::Vector2d> band;
  std::vector<uint32_t> band_idx;
  for (int l = 0; l < ncand; ++l) {
    band.clear(), band_idx.clear();
    for (uint32_t k = cstart[l]; k < cstart[l + 1]; ++k) {
      const uint32_t i = corder[k];
      const double h = H[i];
      if (h >= p.fit_min_h_m && h <= p.fit_max_h_m) {
        band.emplace_back(X[i], Y[i]);
        band_idx.push_back(i);
      }
    }
    // Several circles per candidate: close stems or undergrowth can merge columns.
    for (int attempt = 0; attempt < p.max_fits_per_candidate; ++attempt) {
      if (band.size() < static_cast<size_t>(p.min_fit_points)) break;
      cfp.seed = 0x9e3779b9u ^ static_cast<uint32_t>(l * 131 + attempt);
      const CircleFit fit = fitCircleRobust(band, cfp);
      if (!fit.ok || fit.inliers < static_cast<size_t>(p.min_fit_points)) {
        ++st.rejected_fit;
        break;
      }
      // Remove this circle's inliers before the next attempt.
      auto removeInliers = [&]() {
        size_t w = 0;
        for (size_t m = 0; m < band.size(); ++m)
          if (!fit.is_inlier[m]) band[w] = band[m], band_idx[w] = band_idx[m], ++w;
        band.resize(w), band_idx.resize(w);
      };
      // Plausibility: bark is an opaque thin surface, so few points inside the circle and few
      // in a thin shell around it (foliage and shrubs fill both), a smooth surface, and enough
      // arc that the radius is determined (partial arcs give absurd radii).
#ifdef DTIF_EXTRACT_DEBUG
      fprintf(stderr, "FIT %.2f %.2f r %.3f inl %zu ratio %.2f arc %.0f rms %.4f band %zu\n",
              fit.cx + ox, fit.cy + oy, fit.r, fit.inliers, fit.inlier_ratio, fit.arc_deg,
              fit.rms_m, band.size());
      fprintf(stderr, "  shell %.2f\n", fit.shell_ratio);
#endif
      if (fit.inlier_ratio < p.min_inlier_ratio || fit.shell_ratio < p.min_shell_ratio ||
          fit.rms_m > p.max_fit_rms_m) {
        ++st.rejected_fit;
        removeInliers();
        continue;
      }
      if (fit.arc_deg < p.min_arc_deg) {
        ++st.rejected_fit, ++st.rejected_arc;
        removeInliers();
        continue;
      }
      // Lean (paper: "outlier removal"; leaning clutter such as fallen or hung-up stems):
      // centres of the lower and upper half of the fit band, radius held at the band's, from
      // the points on or near this circle only, so a close neighbour stem cannot pull them.
      bool leaning = false;
      {
        const double h_mid = 0.5 * (p.fit_min_h_m + p.fit_max_h_m);
        std::vector<Eigen::Vector2d> lo, hi;
        double h_lo = 0.0, h_hi = 0.0;
        for (size_t m = 0; m < band.size(); ++m) {
          if (dist(band[m].x() - fit.cx, band[m].y() - fit.cy) > fit.r + 0.15) continue;
          const double h = H[band_idx[m]];
          if (h < h_mid)
            lo.push_back(band[m]), h_lo += h;
          else
            hi.push_back(band[m]), h_hi += h;
        }
        const size_t need = static_cast<size_t>(p.min_fit_points) / 2 + 3;
        Eigen::Vector2d c_lo(fit.cx, fit.cy), c_hi(fit.cx, fit.cy);
        if (lo.size() >= need && hi.size() >= need &&
            fitCentreFixedRadius(lo, fit.r, 2.0 * p.ransac_inlier_m, &c_lo, need) &&
            fitCentreFixedRadius(hi, fit.r, 2.0 * p.ransac_inlier_m, &c_hi, need)) {
          const double dh = h_hi / hi.size() - h_lo / lo.size();
          const double lean = std::atan2((c_hi - c_lo).norm(), std::max(dh, 1e-3));
          leaning = lean > p.max_lean_deg * kPi / 180.0;
        }
      }
      if (leaning) {
        ++st.rejected_lean;
        removeInliers();
        continue;
      }

      // Stem base z_m: robust plane through the ground points in a ring around the stem,
      // evaluated at the centre. The grid ground only gates which points count as ground.
      // (The paper's 0.44 m z error comes from a weaker base estimate, Sec. 4.B.)
      const double r_in = fit.r + p.base_ring_inner_m, r_out = fit.r + p.base_ring_outer_m;
      std::vector<double> bx, by, bz;
      // Lowest point on the stem itself: a base counts as seen only if the stem is visible
      // down to the ground (not hidden by shrubs or below the sensor's field of view).
      const double r_stem2 = (fit.r + kStemShellM) * (fit.r + kStemShellM);
      double stem_low = std::numeric_limits<double>::infinity();
      std::vector<uint32_t> ring;  // every point over the ring, for the check below the base
      int gx0, gy0, gx1, gy1;
      gcellOf(fit.cx - r_out, fit.cy - r_out, &gx0, &gy0);
      gcellOf(fit.cx + r_out, fit.cy + r_out, &gx1, &gy1);
      for (int gy = gy0; gy <= gy1; ++gy) {
        for (int gx = gx0; gx <= gx1; ++gx) {
          const size_t c = static_cast<size_t>(gy) * gnx + gx;
          for (uint32_t k = gstart[c]; k < gstart[c + 1]; ++k) {
            const uint32_t i = gorder[k];
            const double dx = X[i] - fit.cx, dy = Y[i] - fit.cy;
            const double d2 = dx * dx + dy * dy;
            if (d2 < r_stem2) stem_low = std::min(stem_low, static_cast<double>(Z[i]));
            if (d2 < r_in * r_in || d2 > r_out * r_out) continue;
            ring.push_back(i);
            if (std::abs(H[i]) > p.base_max_dh_m) continue;
            bx.push_back(X[i]), by.push_back(Y[i]), bz.push_back(Z[i]);
          }
        }
      }
      double z_base;
      int cgx, cgy;
      gcellOf(fit.cx, fit.cy, &cgx, &cgy);
      const bool ground_seen = cell_seen[static_cast<size_t>(cgy) * gnx + cgx];
      const bool ring_seen = bx.size() >= static_cast<size_t>(p.min_base_points);
      bool ground_below = false;
      if (ring_seen) {
        const std::vector<double> w(bx.size(), 1.0);
        // Tighter than the grid: litter and grass sit on the ground surface, noise is cm.
        const Plane pl = fitGroundPlane(bx.data(), by.data(), bz.data(), w.data(), bx.size(),
                                        fit.cx, fit.cy, /*c_up=*/0.12, /*c_down=*/0.25, 6);
        z_base = pl.a;
        // Ground is the lowest surface: returns well below the fitted plane around the stem
        // mean the plane lies on a shrub or log and the real base is lower. In the dense_slope
        // scene this flags 26 of the 66 seen bases that are 0.45-1.6 m too high, and 9 of the
        // 673 good ones.
        int below = 0;
        for (const uint32_t i : ring) {
          below += Z[i] < pl.at(X[i] - fit.cx, Y[i] - fit.cy) - p.base_below_m;
        }
        ground_below = below > p.max_base_below_points;
      } else {
        z_base = groundAt(fit.cx, fit.cy);
        ++st.ground_fallbacks;
      }
      const bool base_seen = ground_seen && ring_seen && !ground_below &&
                             stem_low - z_base < kMaxBaseGapM && z_base - stem_low < kMaxBaseGapM;
      if (!base_seen) ++st.unseen_bases;
#ifdef DTIF_EXTRACT_DEBUG
      fprintf(stderr, "ACC %.2f %.2f r %.3f inl %zu ratio %.2f arc %.0f rms %.4f band %zu\n",
              fit.cx + ox, fit.cy + oy, fit.r, fit.inliers, fit.inlier_ratio, fit.arc_deg,
              fit.rms_m, band.size());
#endif
      Found f;
      f.t.x = fit.cx + ox;
      f.t.y = fit.cy + oy;
      f.t.z = z_base + oz;
      f.t.r = fit.r;
      f.t.base_seen = base_seen;
      f.inliers = fit.inliers;
      found.push_back(f);
      removeInliers();
    }
  }

  // --- Duplicates: two stems cannot overlap; keep the better supported fit.
  std::stable_sort(found.begin(), found.end(),
                   [](const Found& a, const Found& b) { return a.inliers > b.inliers; });
  for (const Found& f : found) {
    bool dup = false;
    for (const TrunkLandmark& k : result.trunks) {
      const double d = dist(f.t.x - k.x, f.t.y - k.y);
      if (d < p.min_trunk_separation_m || d < f.t.r + k.r) {
        dup = true;
        break;
      }
    }
    if (dup)
      ++st.duplicates;
    else
      result.trunks.push_back(f.t);
  }
  // Stable output order, independent of the candidate numbering.
  std::sort(result.trunks.begin(), result.trunks.end(),
            [](const TrunkLandmark& a, const TrunkLandmark& b) {
              return a.x != b.x ? a.x < b.x : a.y < b.y;
            });

  // --- Ground map: when too few stem bases were seen to fix a loop's elevation (steep slopes
  // seen from a helmet), the lowest surface of the whole submap has to.
  const size_t seen =
      static_cast<size_t>(std::count_if(result.trunks.begin(), result.trunks.end(),
                                        [](const TrunkLandmark& t) { return t.base_seen; }));
  if (p.ground_map_cell_m > 0.0 && !result.trunks.empty() &&
      static_cast<double>(seen) < p.ground_map_below_seen * result.trunks.size()) {
    // Only around the trunks: loops align trunks, so only there can two maps overlap.
    Eigen::Vector2d lo(result.trunks[0].x, result.trunks[0].y), hi = lo;
    for (const TrunkLandmark& t : result.trunks) {
      lo = lo.cwiseMin(Eigen::Vector2d(t.x, t.y));
      hi = hi.cwiseMax(Eigen::Vector2d(t.x, t.y));
    }
    const Eigen::Vector2d margin = Eigen::Vector2d::Constant(p.ground_map_margin_m);
    result.ground_map = makeGroundMap(
        X.data(), Y.data(), Z.data(), n, Eigen::Vector3d(ox, oy, oz), lo - margin, hi + margin,
        p.ground_map_cell_m, p.ground_map_z_step_m, static_cast<uint32_t>(p.ground_map_min_points));
  }
  return result;
}

}  // namespace dtif
