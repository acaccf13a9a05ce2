// Gravity from upright structure (bark normals, thin stem axes), ground as a fallback; a robust
// running estimate per robot in its odometry frame (see gravity.h).
#include "dtif/core/extraction/gravity.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <unordered_set>

#include "dtif/core/robust.h"

namespace dtif {
namespace {

constexpr double kDeg = M_PI / 180.0;
/// A cell whose shape is a thin plate: lambda1 >= kPlanar * lambda0 (and not a line).
constexpr double kPlanar = 4.0;
/// A cell whose shape is a line (a thin stem): lambda2 >= kLinear * lambda1.
constexpr double kLinear = 8.0;
/// Upright structure is counted per 2 m cell (about one stem each) for the uncertainty.
constexpr double kSupportCellM = 2.0;
/// Ground fallback: plate normals within this of the current up [deg].
constexpr double kGroundBandDeg = 40.0;
/// Nothing is known to better than this from one submap (bark, lean) [deg].
constexpr double kMinSigmaDeg = 0.05;

int64_t packKey(int64_t x, int64_t y, int64_t z) {
  constexpr int64_t kOff = 1 << 20, kMask = (1 << 21) - 1;
  return ((x + kOff) & kMask) << 42 | ((y + kOff) & kMask) << 21 | ((z + kOff) & kMask);
}

// The local shape of one cell: a plate (normal), a line (direction) or neither.
struct Shape {
  enum Kind { kPlate, kLine } kind;
  Eigen::Vector3d v;  // plate: normal; line: direction
  int64_t support;    // 2 m column of the cell
  double h;           // height above the lowest cell of that column [m]
};

struct Moments {
  int n = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sxx = Eigen::Matrix3d::Zero();
};

// floor(v) as an int64 without libm's call (not inlined on baseline x86-64; three per point and
// cut): the same value as static_cast<int64_t>(std::floor(v)) wherever that is defined.
int64_t floorIndex(double v) {
  if (!(v > -4.5e15 && v < 4.5e15)) return static_cast<int64_t>(std::floor(v));
  const int64_t i = static_cast<int64_t>(v);  // truncates towards zero
  return i - (v < static_cast<double>(i));
}

// Cell key -> dense index, open addressing with key and index side by side (one cache miss a
// lookup), doubling at half load.
class KeyIndex {
 public:
  explicit KeyIndex(size_t expected) {
    size_t cap = 64;
    while (cap < 2 * expected) cap <<= 1;
    slots_.assign(cap, Slot{kEmpty, -1});
  }
  // Index of key; next (inserted) when absent.
  int findOrInsert(int64_t key, int next, bool* fresh) {
    for (size_t h = hash(key) & (slots_.size() - 1);; h = (h + 1) & (slots_.size() - 1)) {
      if (slots_[h].key == key) {
        *fresh = false;
        return slots_[h].index;
      }
      if (slots_[h].key == kEmpty) {
        slots_[h] = Slot{key, next};
        *fresh = true;
        if (2 * ++size_ > slots_.size()) grow();
        return next;
      }
    }
  }

 private:
  static constexpr int64_t kEmpty = -1;  // packKey is never negative
  struct Slot {
    int64_t key;
    int index;
  };
  static size_t hash(int64_t k) {
    uint64_t x = static_cast<uint64_t>(k);
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdULL;
    x ^= x >> 33;
    return static_cast<size_t>(x);
  }
  void grow() {
    std::vector<Slot> old(slots_.size() * 2, Slot{kEmpty, -1});
    old.swap(slots_);
    for (const Slot& s : old) {
      if (s.key == kEmpty) continue;
      size_t h = hash(s.key) & (slots_.size() - 1);
      while (slots_[h].key != kEmpty) h = (h + 1) & (slots_.size() - 1);
      slots_[h] = s;
    }
  }
  std::vector<Slot> slots_;
  size_t size_ = 0;
};

// The evenly strided finite points the shape analysis uses (every cut re-reads them: a compact
// copy instead of a stride through the whole cloud each time).
std::vector<Eigen::Vector3f> shapeSamples(const Cloud& cloud, const LevellingParams& p) {
  const size_t stride =
      std::max<size_t>(1, cloud.size() / static_cast<size_t>(std::max(1, p.max_points)));
  std::vector<Eigen::Vector3f> out;
  out.reserve(cloud.size() / stride + 1);
  for (size_t i = 0; i < cloud.size(); i += stride) {
    const auto& q = cloud[i];
    if (!std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z)) continue;
    out.emplace_back(q.x, q.y, q.z);
  }
  return out;
}

// Shapes of the cells of the samples rotated by R (cells on R's axes: a cell cut obliquely
// through a stem biases its shape towards the cell's axes, so the caller re-cuts them along
// the current estimate). Cells are accumulated in sample order and returned in key order, so
// the result depends on neither a hash nor its iteration order.
std::vector<Shape> cellShapes(const std::vector<Eigen::Vector3f>& samples, const Eigen::Matrix3d& R,
                              const LevellingParams& p, bool slab_only) {
  KeyIndex index(samples.size() / 8);
  std::vector<int64_t> keys;
  std::vector<Moments> cells;
  const double inv = 1.0 / p.voxel_m;
  int64_t last_key = -1;  // packKey is never negative; consecutive samples often share a cell
  int id = -1;
  for (const Eigen::Vector3f& q : samples) {
    const Eigen::Vector3d x = R * q.cast<double>();
    const int64_t key =
        packKey(floorIndex(x.x() * inv), floorIndex(x.y() * inv), floorIndex(x.z() * inv));
    if (key != last_key) {
      bool fresh;
      id = index.findOrInsert(key, static_cast<int>(cells.size()), &fresh);
      if (fresh) cells.emplace_back(), keys.push_back(key);
      last_key = key;
    }
    Moments& m = cells[id];
    ++m.n;
    m.sum += x;
    // x x^T, its upper triangle mirrored: the same products, half the work.
    const double xx = x.x() * x.x(), xy = x.x() * x.y(), xz = x.x() * x.z();
    const double yy = x.y() * x.y(), yz = x.y() * x.z(), zz = x.z() * x.z();
    m.sxx(0, 0) += xx, m.sxx(0, 1) += xy, m.sxx(0, 2) += xz;
    m.sxx(1, 1) += yy, m.sxx(1, 2) += yz, m.sxx(2, 2) += zz;
  }
  for (Moments& m : cells) {
    m.sxx(1, 0) = m.sxx(0, 1), m.sxx(2, 0) = m.sxx(0, 2), m.sxx(2, 1) = m.sxx(1, 2);
  }
  // The lowest populated cell of each 2 m column: heights above it tell stems from canopy.
  auto columnOf = [](const Eigen::Vector3d& mean) {
    return packKey(floorIndex(mean.x() / kSupportCellM), floorIndex(mean.y() / kSupportCellM), 0);
  };
  KeyIndex column_index(cells.size() / 16);
  std::vector<double> lowest;
  std::vector<int> column(cells.size(), -1);
  for (size_t c = 0; c < cells.size(); ++c) {
    const Moments& m = cells[c];
    if (m.n < p.min_voxel_points) continue;
    const Eigen::Vector3d mean = m.sum / m.n;
    bool fresh;
    const int col =
        column_index.findOrInsert(columnOf(mean), static_cast<int>(lowest.size()), &fresh);
    if (fresh) lowest.push_back(mean.z());
    lowest[col] = std::min(lowest[col], mean.z());
    column[c] = col;
  }
  std::vector<std::pair<int64_t, Shape>> keyed;
  for (size_t c = 0; c < cells.size(); ++c) {
    const Moments& m = cells[c];
    if (m.n < p.min_voxel_points) continue;
    const Eigen::Vector3d mean = m.sum / m.n;
    const double h = mean.z() - lowest[column[c]];
    // The upright fit reads only the slab's cells: no eigen-decomposition for the others.
    if (slab_only && (h < p.slab_min_h_m || h > p.slab_max_h_m)) continue;
    const Eigen::Matrix3d cov = m.sxx / m.n - mean * mean.transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
    const Eigen::Vector3d l = es.eigenvalues();  // ascending
    const int64_t support = columnOf(mean);
    if (l(2) >= kLinear * std::max(l(1), 1e-12)) {
      keyed.push_back({keys[c], {Shape::kLine, es.eigenvectors().col(2), support, h}});
    } else if (l(1) >= kPlanar * std::max(l(0), 1e-12)) {
      keyed.push_back({keys[c], {Shape::kPlate, es.eigenvectors().col(0), support, h}});
    }
  }
  // Key order: the result does not depend on the order cells were first seen.
  std::sort(keyed.begin(), keyed.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<Shape> shapes;
  shapes.reserve(keyed.size());
  for (auto& k : keyed) shapes.push_back(k.second);
  return shapes;
}

// Angle of a cell's shape to being upright under `up`: a plate's normal from the horizontal, a
// line from the vertical [rad].
double uprightAngle(const Shape& s, const Eigen::Vector3d& up) {
  const double c = std::min(1.0, std::abs(s.v.dot(up)));
  return s.kind == Shape::kPlate ? std::asin(c) : std::acos(c);
}

// Up minimising sum w (n.g)^2 over plates + w (1 - (d.g)^2) over lines: the smallest
// eigenvector of their scatter, signed like `prior`.
Eigen::Vector3d smallestAxis(const Eigen::Matrix3d& M, const Eigen::Vector3d& prior) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(M);
  Eigen::Vector3d g = es.eigenvectors().col(0);
  return g.dot(prior) < 0 ? Eigen::Vector3d(-g) : g;
}

struct UprightFit {
  Eigen::Vector3d up;
  double rms_rad = 0.0;
  int support = 0;
};

// Re-selects the upright cells around the current up, with a Tukey constant that narrows from
// the band (a 15 deg tilt puts every stem far from S's z) to tukey_deg.
UprightFit fitUpright(const std::vector<Shape>& shapes, Eigen::Vector3d up,
                      const LevellingParams& p) {
  UprightFit fit;
  const double band = p.band_deg * kDeg;
  for (int it = 0; it < std::max(1, p.iterations); ++it) {
    const double c = std::max(p.tukey_deg, p.band_deg / std::pow(2.0, it)) * kDeg;
    Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
    double sw = 0.0;
    for (const Shape& s : shapes) {
      const double a = uprightAngle(s, up);
      if (a >= band || s.h < p.slab_min_h_m || s.h > p.slab_max_h_m) continue;
      const double w = tukeyWeight(a, c);
      M += w * (s.kind == Shape::kPlate
                    ? Eigen::Matrix3d(s.v * s.v.transpose())
                    : Eigen::Matrix3d(Eigen::Matrix3d::Identity() - s.v * s.v.transpose()));
      sw += w;
    }
    if (sw <= 0.0) break;
    up = smallestAxis(M, up);
  }
  std::unordered_set<int64_t> support;
  double sw = 0.0, swa2 = 0.0;
  for (const Shape& s : shapes) {
    if (s.h < p.slab_min_h_m || s.h > p.slab_max_h_m) continue;
    const double a = uprightAngle(s, up);
    const double w = a < band ? tukeyWeight(a, p.tukey_deg * kDeg) : 0.0;
    if (w <= 0.0) continue;
    support.insert(s.support);
    sw += w;
    swa2 += w * a * a;
  }
  fit.up = up;
  fit.support = static_cast<int>(support.size());
  fit.rms_rad = sw > 0.0 ? std::sqrt(swa2 / sw) : M_PI;
  return fit;
}

// Ground fallback: the robust mean of the plate normals near the current up (slope-biased).
UprightFit fitGround(const std::vector<Shape>& shapes, Eigen::Vector3d up) {
  UprightFit fit;
  for (int it = 0; it < 3; ++it) {
    const double c = (it == 0 ? kGroundBandDeg : 10.0) * kDeg;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const Shape& s : shapes) {
      if (s.kind != Shape::kPlate) continue;
      const Eigen::Vector3d n = s.v.dot(up) < 0 ? Eigen::Vector3d(-s.v) : s.v;
      sum += tukeyWeight(std::acos(std::min(1.0, n.dot(up))), c) * n;
    }
    if (sum.norm() <= 0.0) return fit;
    up = sum.normalized();
  }
  std::unordered_set<int64_t> support;
  for (const Shape& s : shapes) {
    if (s.kind == Shape::kPlate && std::abs(s.v.dot(up)) > std::cos(10.0 * kDeg)) {
      support.insert(s.support);
    }
  }
  fit.up = up;
  fit.support = static_cast<int>(support.size());
  return fit;
}

double angleBetween(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

// Cells cut along the current estimate `up` (in S), fitted by `fitter` (in the cut's frame), and
// re-cut until the estimate moves less than kConvergedDeg: a cell cut obliquely through a stem
// or the ground biases its shape towards the cell's own axes, a bias that shrinks with the
// angle between them and gravity. Returns the fit with its up in S.
template <class Fitter>
UprightFit cutAndFit(const std::vector<Eigen::Vector3f>& samples_S, Eigen::Vector3d up,
                     const LevellingParams& params, bool slab_only, const Fitter& fitter) {
  constexpr int kMaxRecuts = 3;
  constexpr double kConvergedDeg = 0.3;
  UprightFit fit;
  for (int cut = 0; cut < kMaxRecuts; ++cut) {
    const Eigen::Matrix3d R_cut = levelRotation(up).toRotationMatrix();
    fit = fitter(cellShapes(samples_S, R_cut, params, slab_only));
    const Eigen::Vector3d next = R_cut.transpose() * fit.up;
    const double moved = angleBetween(next, up);
    up = next;
    if (fit.support < params.min_support_cells || moved < kConvergedDeg * kDeg) break;
  }
  fit.up = up;
  return fit;
}

}  // namespace

std::string LevellingParams::validate() const {
  std::ostringstream e;
  if (!(voxel_m > 0.0)) e << "voxel_m must be > 0; ";
  if (min_voxel_points < 4) e << "min_voxel_points must be >= 4; ";
  if (!(band_deg > 0.0 && band_deg < 45.0)) e << "band_deg must be in (0, 45); ";
  if (!(tukey_deg > 0.0)) e << "tukey_deg must be > 0; ";
  if (iterations < 1) e << "iterations must be >= 1; ";
  if (min_support_cells < 1) e << "min_support_cells must be >= 1; ";
  if (!(ground_sigma_deg > 0.0)) e << "ground_sigma_deg must be > 0; ";
  if (!(max_tilt_deg > 0.0 && max_tilt_deg <= 60.0)) e << "max_tilt_deg must be in (0, 60]; ";
  if (!(overlap_factor >= 1.0)) e << "overlap_factor must be >= 1; ";
  if (!(imu_sigma_deg > 0.0)) e << "imu_sigma_deg must be > 0; ";
  if (max_points < 1000) e << "max_points must be >= 1000; ";
  if (!(min_tilt_deg >= 0.0)) e << "min_tilt_deg must be >= 0; ";
  if (warmup_submaps < 1) e << "warmup_submaps must be >= 1; ";
  if (observe_every < 1) e << "observe_every must be >= 1; ";
  if (!(slab_min_h_m >= 0.0 && slab_min_h_m < slab_max_h_m)) {
    e << "need 0 <= slab_min_h_m < slab_max_h_m; ";
  }
  return e.str();
}

GravityObservation observeGravity(const Cloud& cloud_S, const Eigen::Vector3d& prior_S,
                                  const LevellingParams& params) {
  GravityObservation obs;
  const Eigen::Vector3d z = Eigen::Vector3d::UnitZ();
  const std::vector<Eigen::Vector3f> samples = shapeSamples(cloud_S, params);
  UprightFit fit = cutAndFit(samples, prior_S.normalized(), params, /*slab_only=*/true,
                             [&](const std::vector<Shape>& s) { return fitUpright(s, z, params); });
  if (fit.support >= params.min_support_cells) {
    obs.sigma_deg = std::max(kMinSigmaDeg, fit.rms_rad / std::sqrt(fit.support) / kDeg);
  } else {
    fit = cutAndFit(samples, prior_S.normalized(), params, /*slab_only=*/false,
                    [&](const std::vector<Shape>& s) { return fitGround(s, z); });
    if (fit.support < params.min_support_cells) return obs;
    obs.from_ground = true;
    obs.sigma_deg = params.ground_sigma_deg;
  }
  if (angleBetween(fit.up, z) > params.max_tilt_deg * kDeg) return obs;
  obs.ok = true;
  obs.up_S = fit.up;
  obs.support_cells = fit.support;
  return obs;
}

Eigen::Quaterniond levelRotation(const Eigen::Vector3d& up_S) {
  return Eigen::Quaterniond::FromTwoVectors(up_S.normalized(), Eigen::Vector3d::UnitZ());
}

GravityObservation GravityEstimator::addSubmap(const Cloud& cloud_S,
                                               const Eigen::Quaterniond& R_O_S) {
  const int seen = estimate_.seen++;
  const bool settled =
      estimate_.valid && estimate_.sigma_deg < 1.0 && estimate_.submaps >= params_.warmup_submaps;
  if (settled && seen % std::max(1, params_.observe_every) != 0) return GravityObservation();
  const GravityObservation o = observeGravity(cloud_S, upInSubmap(R_O_S), params_);
  if (o.ok) {
    obs_.push_back({(R_O_S * o.up_S).normalized(), o.sigma_deg * kDeg, false});
    update();
  }
  return o;
}

void GravityEstimator::addImu(const Eigen::Vector3d& accel_O, double sigma_deg) {
  if (!(accel_O.norm() > 0.0) || !accel_O.allFinite()) return;
  const double s = sigma_deg > 0.0 ? sigma_deg : params_.imu_sigma_deg;
  obs_.push_back({accel_O.normalized(), s * kDeg, true});
  update();
}

std::string ImuGravityParams::validate() const {
  std::ostringstream e;
  if (!(max_gyro_rad_s > 0.0)) e << "imu max_gyro_rad_s must be > 0; ";
  if (!(max_norm_dev > 0.0 && max_norm_dev < 1.0)) e << "imu max_norm_dev must be in (0, 1); ";
  if (min_samples < 1) e << "imu min_samples must be >= 1; ";
  return e.str();
}

bool ImuGravityWindow::addImu(double stamp, const Eigen::Vector3d& accel_B,
                              const Eigen::Vector3d& gyro_B) {
  if (!std::isfinite(stamp) || !accel_B.allFinite() || !gyro_B.allFinite()) return false;
  if (!(accel_B.norm() > 0.0)) return false;
  // A bound on what waits: odometry that never comes must not grow it (a few s at 200 Hz).
  constexpr size_t kMaxWaiting = 4000;
  if (waiting_.size() >= kMaxWaiting) waiting_.erase(waiting_.begin());
  waiting_.push_back({stamp, accel_B, gyro_B.norm()});
  return true;
}

void ImuGravityWindow::addOdometry(double stamp, const Eigen::Quaterniond& R_O_B) {
  if (!std::isfinite(stamp) || !R_O_B.coeffs().allFinite()) return;
  const Eigen::Quaterniond R = R_O_B.normalized();
  size_t used = 0;
  for (const Sample& s : waiting_) {
    if (s.stamp > stamp) break;
    ++used;
    if (prev_stamp_ < 0.0 || s.stamp < prev_stamp_ || s.gyro > params_.max_gyro_rad_s) continue;
    const double span = stamp - prev_stamp_;
    constexpr double kMaxOdomGapS = 0.5;  // no attitude to interpolate across a longer gap
    if (span > kMaxOdomGapS) continue;
    const double t = span > 0.0 ? (s.stamp - prev_stamp_) / span : 1.0;
    rotated_.push_back(prev_R_O_B_.slerp(t, R) * s.accel_B);
    norms_.push_back(s.accel_B.norm());
  }
  waiting_.erase(waiting_.begin(), waiting_.begin() + static_cast<std::ptrdiff_t>(used));
  if (stamp >= prev_stamp_) {
    prev_stamp_ = stamp;
    prev_R_O_B_ = R;
  }
}

ImuGravityWindow::Reading ImuGravityWindow::take() {
  Reading r;
  std::vector<double> sorted = norms_;
  double median = 0.0;
  if (!sorted.empty()) {
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    median = sorted[sorted.size() / 2];
  }
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> used;
  for (size_t i = 0; i < rotated_.size(); ++i) {
    if (std::abs(norms_[i] / median - 1.0) > params_.max_norm_dev) continue;
    sum += rotated_[i];
    used.push_back(rotated_[i].normalized());
  }
  rotated_.clear();
  norms_.clear();
  r.samples = static_cast<int>(used.size());
  if (r.samples < params_.min_samples || !(sum.norm() > 0.0)) return r;
  r.ok = true;
  r.up_O = sum.normalized();
  double a2 = 0.0;
  for (const Eigen::Vector3d& u : used) a2 += std::pow(angleBetween(u, r.up_O), 2);
  r.spread_deg = std::sqrt(a2 / used.size()) / kDeg;
  return r;
}

Eigen::Vector3d GravityEstimator::upInSubmap(const Eigen::Quaterniond& R_O_S) const {
  if (!estimate_.valid) return Eigen::Vector3d::UnitZ();
  return (R_O_S.conjugate() * estimate_.up_O).normalized();
}

Eigen::Quaterniond GravityEstimator::levelRotationOf(const Eigen::Quaterniond& R_O_S) const {
  if (!estimate_.applied) return Eigen::Quaterniond::Identity();
  return levelRotation(upInSubmap(R_O_S));
}

// Robust weighted mean of the observations (Tukey on each one's angle to the mean, at four
// sigmas, at least 2 deg). Submaps share stems with their neighbours: overlap_factor inflates
// their variance; the scatter of the observations bounds the uncertainty from below.
void GravityEstimator::update() {
  auto variance = [&](const Obs& o) {
    return o.sigma_rad * o.sigma_rad * (o.imu ? 1.0 : params_.overlap_factor);
  };
  Eigen::Vector3d g = Eigen::Vector3d::Zero();
  for (const Obs& o : obs_) g += o.up_O / variance(o);
  g.normalize();
  double sw = 0.0, swa2 = 0.0, n_used = 0.0;
  for (int it = 0; it < 4; ++it) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    sw = swa2 = n_used = 0.0;
    for (const Obs& o : obs_) {
      const double a = angleBetween(o.up_O, g);
      const double w = tukeyWeight(a, std::max(4.0 * o.sigma_rad, 2.0 * kDeg)) / variance(o);
      sum += w * o.up_O;
      sw += w;
      swa2 += w * a * a;
      n_used += w > 0.0 ? 1.0 : 0.0;
    }
    if (!(sum.norm() > 0.0)) break;
    g = sum.normalized();
  }
  GravityEstimate& e = estimate_;
  e.valid = sw > 0.0;
  if (!e.valid) return;
  e.up_O = g;
  const double internal = 1.0 / std::sqrt(sw);
  const double n_eff = std::max(1.0, n_used / params_.overlap_factor);
  const double scatter = n_used > 1 ? std::sqrt(swa2 / sw / n_eff) : 0.0;
  e.sigma_deg = std::max(internal, scatter) / kDeg;
  e.tilt_deg = angleBetween(g, Eigen::Vector3d::UnitZ()) / kDeg;
  e.applied = e.tilt_deg >= params_.min_tilt_deg;
  e.submaps = e.imu = 0;
  for (const Obs& o : obs_) (o.imu ? e.imu : e.submaps)++;
}

GravityEstimator& Leveller::of(const std::string& robot) {
  for (auto& [name, est] : robots_) {
    if (name == robot) return est;
  }
  robots_.emplace_back(robot, GravityEstimator(params_));
  return robots_.back().second;
}

Leveller::Result Leveller::level(const std::string& robot, const Cloud& cloud_S,
                                 const Eigen::Quaterniond& R_O_S) {
  Result r;
  if (!params_.enable) return r;
  GravityEstimator& est = of(robot);
  r.observation = est.addSubmap(cloud_S, R_O_S);
  r.estimate = est.estimate();
  r.R_L_S = est.levelRotationOf(R_O_S);
  return r;
}

void Leveller::addImu(const std::string& robot, const Eigen::Vector3d& accel_O, double sigma_deg) {
  if (params_.enable) of(robot).addImu(accel_O, sigma_deg);
}

GravityEstimate Leveller::estimate(const std::string& robot) const {
  for (const auto& [name, est] : robots_) {
    if (name == robot) return est.estimate();
  }
  return GravityEstimate();
}

}  // namespace dtif
