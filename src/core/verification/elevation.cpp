// Elevation and residual tilt of a refined loop pose (see elevation.h).
#include "dtif/core/verification/elevation.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "dtif/core/extraction/ground_map.h"
#include "dtif/core/robust.h"

namespace dtif {
namespace {

/// Floor on the variance of a roll/pitch fitted to seen stem bases: (0.05 deg)^2.
constexpr double kMinFittedTiltVar = (0.05 * M_PI / 180.0) * (0.05 * M_PI / 180.0);
/// Mode window of the elevation differences: bases are cm-level, and a residual tilt of
/// 0.5 deg moves pairs 20 m apart by 0.17 m; a wrong base is decimetres off [m].
constexpr double kZWindow = 0.25;

/// The pairs' query trunks in the candidate frame (horizontal) and elevation differences.
struct ElevationSamples {
  std::vector<Eigen::Vector2d> xy;
  std::vector<double> dz;
};

ElevationSamples elevationSamples(const Descriptor& q, const Descriptor& c,
                                  const std::vector<std::pair<int, int>>& use, const Pose& T) {
  ElevationSamples s;
  for (const auto& [i, j] : use) {
    const Eigen::Vector3d p = T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, q.trunks[i].z);
    s.xy.push_back(p.head<2>());
    s.dz.push_back(c.trunks[j].z - p.z());
  }
  return s;
}

double rmsElevation(const Descriptor& q, const Descriptor& c,
                    const std::vector<std::pair<int, int>>& use, const Pose& T) {
  double sz = 0.0;
  for (const auto& [i, j] : use) {
    const Eigen::Vector3d p = T * Eigen::Vector3d(q.trunks[i].x, q.trunks[i].y, q.trunks[i].z);
    sz += (c.trunks[j].z - p.z()) * (c.trunks[j].z - p.z());
  }
  return std::sqrt(sz / static_cast<double>(use.size()));
}

struct ElevationMode {
  double mode = 0.0;    ///< the difference with the largest support [m]
  double z_mode = 0.0;  ///< weighted mean of its supporters, the tilt fit's start [m]
  int agree = 0;        ///< differences within kZWindow of the mode
};

/// Mode: the difference with the largest Tukey-weighted support, refined to the weighted mean
/// of its supporters.
ElevationMode elevationMode(const std::vector<double>& dz) {
  ElevationMode m;
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
  m.mode = mode;
  m.z_mode = swz / sw;
  m.agree = agree;
  return m;
}

/// Runner-up elevation: the largest group of the other pairs that agree among themselves. Two
/// neighbouring stems whose bases both sit on one shrub or log agree on a wrong t_z as well
/// as two good ones agree on the right one.
int elevationRunnerUp(const std::vector<double>& dz, double mode) {
  int second = 0;
  for (double z0 : dz) {
    if (std::abs(z0 - mode) < kZWindow) continue;
    int n = 0;
    for (double z1 : dz) n += std::abs(z1 - mode) >= kZWindow && std::abs(z1 - z0) < kZWindow;
    second = std::max(second, n);
  }
  return second;
}

/// MAP fit of dz = s0 + s1 (x - mean.x) + s2 (y - mean.y) by IRLS with Tukey weights, starting
/// from the mode; false when the system is degenerate. `info` receives the last normal matrix.
bool fitTiltPlane(const ElevationSamples& smp, const Eigen::Vector2d& mean, double z_mode,
                  const VerifierParams& params, Eigen::Vector3d* plane, Eigen::Matrix3d* info) {
  // c = 0.15 m: base estimates are cm-level, a wrong base is decimetres off.
  constexpr double kTukeyC = 0.15;
  Eigen::Vector3d s(z_mode, 0.0, 0.0);
  // Zero-mean prior on the slopes: (sigma_base / sigma_tilt)^2 per slope, in units of a
  // full-weight pair.
  double prior = 0.0;
  if (params.tilt_prior_deg > 0.0) {
    const double sigma_tilt = std::tan(params.tilt_prior_deg * M_PI / 180.0);
    prior = (params.base_sigma_m / sigma_tilt) * (params.base_sigma_m / sigma_tilt);
  }
  *info = Eigen::Matrix3d::Identity();
  for (int it = 0; it < 10; ++it) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    A(1, 1) = A(2, 2) = prior;
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < smp.xy.size(); ++k) {
      const Eigen::Vector3d J(1.0, smp.xy[k].x() - mean.x(), smp.xy[k].y() - mean.y());
      const double r = smp.dz[k] - J.dot(s);
      const double w = tukeyWeight(r, kTukeyC);
      if (w == 0.0) continue;
      A += w * J * J.transpose();
      b += w * J * smp.dz[k];
    }
    if (A.determinant() <= 1e-9) return false;
    *info = A;
    const Eigen::Vector3d next = A.ldlt().solve(b);
    if (!next.allFinite()) return false;
    const bool done = (next - s).norm() < 1e-7;
    s = next;
    if (done) break;
  }
  *plane = s;
  return true;
}

/// Residual roll/pitch from the seen-base pairs when they spread enough and the fitted tilt
/// is plausible (max_tilt_deg): rotates `T` about their centroid and fills v's tilt fields.
void fitTilt(const ElevationSamples& smp, double z_mode, const VerifierParams& params, Pose* T,
             Verification* v) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : smp.xy) mean += p;
  mean /= static_cast<double>(smp.xy.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& p : smp.xy) cov += (p - mean) * (p - mean).transpose();
  cov /= static_cast<double>(smp.xy.size());
  const double spread = std::sqrt(
      std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues().minCoeff()));
  if (spread < params.tilt_min_spread_m) return;
  Eigen::Vector3d s;
  Eigen::Matrix3d info;
  if (!fitTiltPlane(smp, mean, z_mode, params, &s, &info)) return;
  const double max_slope = std::tan(params.max_tilt_deg * M_PI / 180.0);
  if (std::hypot(s(1), s(2)) > max_slope) return;
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
}

}  // namespace

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
  const ElevationSamples smp = elevationSamples(q, c, use, *T);
  const ElevationMode m = elevationMode(smp.dz);
  if (seen) {
    v->z_pairs = m.agree;
    v->z_ambiguity = static_cast<double>(elevationRunnerUp(smp.dz, m.mode)) / std::max(m.agree, 1);
  }
  T->translation().z() += m.z_mode;
  if (seen && params.tilt_min_pairs > 0 && static_cast<int>(use.size()) >= params.tilt_min_pairs)
    fitTilt(smp, m.z_mode, params, T, v);
  return rmsElevation(q, c, use, *T);
}

Rejection checkElevation(const Descriptor& q, const Descriptor& c, const VerifierParams& params,
                         Pose* T, Verification* v) {
  const bool z_unobserved = v->z_pairs < params.min_z_pairs;
  if (!z_unobserved && !(v->z_ambiguity > params.max_z_ambiguity)) return Rejection::kNone;
  // No pair of seen bases, or groups of them agreeing on different t_z (stems on shrubs):
  // where both submaps saw the same lowest surface (ground, a log), their ground maps differ
  // by t_z. A tilt fitted to disagreeing bases is not trusted.
  const Rejection why =
      z_unobserved ? Rejection::kElevationUnobserved : Rejection::kElevationAmbiguous;
  if (params.min_ground_cells <= 0 || q.ground_map.empty() || c.ground_map.empty() ||
      v->tilt_fitted) {
    return why;
  }
  const GroundElevation g = groundElevation(q.ground_map, c.ground_map, *T, params.ground_window_m);
  v->ground_ambiguity = g.ok ? g.ambiguity : -1.0;
  if (!g.ok || g.support < params.min_ground_cells) return why;
  if (g.ambiguity > params.max_ground_ambiguity) return Rejection::kElevationAmbiguous;
  T->translation().z() += g.dz_m;
  v->T_c_q = *T;
  v->ground_cells = g.support;
  v->ground_sigma_m = g.spread_m;
  return Rejection::kNone;
}

}  // namespace dtif
