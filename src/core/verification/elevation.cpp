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

/// Elevation differences the residual tilt is fitted to, under one pose: seen-base pairs and
/// ground-map cells, each group with its own offset (a cell's lowest point is not a stem base:
/// on a slope it lies at the cell's downhill edge, in both maps alike) and its start (the
/// group's mode).
struct TiltSamples {
  ElevationSamples bases, ground;
  double bases_start = 0.0, ground_start = 0.0;
};

/// MAP fit of dz = o_g + a (x - centre.x) + b (y - centre.y), o_g the offset of the sample's
/// group (bases, ground), by IRLS with Tukey weights, starting from the groups' modes; false
/// when the system is degenerate. In units of a full-weight base pair (std dev base_sigma_m):
/// a ground cell weighs (base_sigma_m / ground_cell_sigma_m)^2. `info` receives the last normal
/// matrix, `kept` the ground cells of nonzero weight.
bool fitTiltPlane(const TiltSamples& smp, const Eigen::Vector2d& centre,
                  const VerifierParams& params, Eigen::Vector4d* plane, Eigen::Matrix4d* info,
                  int* kept) {
  // c = 0.15 m: base estimates are cm-level, a wrong base is decimetres off. Ground cells
  // start wider: a residual tilt of 0.5 deg lifts cells 20 m from the centre by 0.17 m.
  constexpr double kTukeyC = 0.15, kGroundStartC = 0.4;
  constexpr int kGroundStartIts = 4;
  Eigen::Vector4d s(smp.bases_start, smp.ground_start, 0.0, 0.0);
  // Zero-mean prior on the slopes: (sigma_base / sigma_tilt)^2 per slope, in units of a
  // full-weight pair.
  double prior = 0.0;
  if (params.tilt_prior_deg > 0.0) {
    const double sigma_tilt = std::tan(params.tilt_prior_deg * M_PI / 180.0);
    prior = (params.base_sigma_m / sigma_tilt) * (params.base_sigma_m / sigma_tilt);
  }
  const double ground_w = (params.base_sigma_m / params.ground_cell_sigma_m) *
                          (params.base_sigma_m / params.ground_cell_sigma_m);
  *info = Eigen::Matrix4d::Identity();
  for (int it = 0; it < 20; ++it) {
    Eigen::Matrix4d A = Eigen::Matrix4d::Zero();
    A(2, 2) = A(3, 3) = prior;
    // A group without samples keeps its offset at 0.
    if (smp.bases.dz.empty()) A(0, 0) = 1.0;
    if (smp.ground.dz.empty()) A(1, 1) = 1.0;
    Eigen::Vector4d b = Eigen::Vector4d::Zero();
    int n_kept = 0;
    const auto add = [&](const ElevationSamples& g, int group, double c, double scale) {
      for (size_t k = 0; k < g.xy.size(); ++k) {
        Eigen::Vector4d J(0.0, 0.0, g.xy[k].x() - centre.x(), g.xy[k].y() - centre.y());
        J(group) = 1.0;
        const double w = scale * tukeyWeight(g.dz[k] - J.dot(s), c);
        if (w == 0.0) continue;
        n_kept += group == 1;
        // A += w J J^T and b += w J dz as Eigen's outer product computes them, entry (i, j)
        // as J_j (w J_i), over J's three nonzero entries only: the others add zeros.
        const int o = group;
        const double x = J(2), y = J(3), wx = w * x, wy = w * y;
        A(o, o) += w, A(2, o) += wx, A(3, o) += wy;
        A(o, 2) += x * w, A(2, 2) += x * wx, A(3, 2) += x * wy;
        A(o, 3) += y * w, A(2, 3) += y * wx, A(3, 3) += y * wy;
        b(o) += w * g.dz[k], b(2) += wx * g.dz[k], b(3) += wy * g.dz[k];
      }
    };
    add(smp.bases, 0, kTukeyC, 1.0);
    add(smp.ground, 1, it < kGroundStartIts ? kGroundStartC : kTukeyC, ground_w);
    if (A.determinant() <= 1e-9) return false;
    *info = A;
    *kept = n_kept;
    const Eigen::Vector4d next = A.ldlt().solve(b);
    if (!next.allFinite()) return false;
    const bool done = it >= kGroundStartIts && (next - s).norm() < 1e-7;
    s = next;
    if (done) break;
  }
  *plane = s;
  return true;
}

/// Smaller std dev of the samples' horizontal spread (bases and ground cells) and their centre:
/// the bases' centroid, where t_z was measured, else the ground cells'.
double tiltSpread(const TiltSamples& smp, Eigen::Vector2d* centre) {
  const ElevationSamples& anchor = smp.bases.xy.empty() ? smp.ground : smp.bases;
  *centre = Eigen::Vector2d::Zero();
  for (const auto& p : anchor.xy) *centre += p;
  *centre /= static_cast<double>(anchor.xy.size());
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  const size_t n = smp.bases.xy.size() + smp.ground.xy.size();
  for (const auto* g : {&smp.bases, &smp.ground})
    for (const auto& p : g->xy) mean += p / static_cast<double>(n);
  for (const auto* g : {&smp.bases, &smp.ground})
    for (const auto& p : g->xy) cov += (p - mean) * (p - mean).transpose();
  cov /= static_cast<double>(n);
  return std::sqrt(
      std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues().minCoeff()));
}

/// T turned by a small tilt (roll alpha, pitch beta) about `centre` (horizontal, z 0).
Pose tiltedAbout(const Pose& T, double alpha, double beta, const Eigen::Vector2d& centre) {
  Pose R = Pose::Identity();
  R.linear() = (Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(beta, Eigen::Vector3d::UnitY()))
                   .toRotationMatrix();
  const Eigen::Vector3d c3(centre.x(), centre.y(), 0.0);
  R.translation() = c3 - R.linear() * c3;
  return R * T;
}

/// Residual roll/pitch from the samples when they spread enough, the ground cells kept are
/// enough (tilt_min_ground_cells; else the bases alone, when tilt_min_pairs of them) and the
/// fitted tilt is plausible (max_tilt_deg): rotates `T` about their centre and fills v's tilt
/// fields. `z_applied`: the t_z already added to `T` since the samples were taken, from the
/// bases (or, without any, the ground).
void fitTilt(TiltSamples smp, double z_applied, const VerifierParams& params, Pose* T,
             Verification* v) {
  Eigen::Vector4d s;
  Eigen::Matrix4d info;
  Eigen::Vector2d mean;
  int kept = 0;
  for (;;) {
    if (smp.bases.xy.empty() && smp.ground.xy.empty()) return;
    if (tiltSpread(smp, &mean) < params.tilt_min_spread_m) return;
    if (!fitTiltPlane(smp, mean, params, &s, &info, &kept)) return;
    if (smp.ground.xy.empty() || kept >= params.tilt_min_ground_cells) break;
    // Too few cells agree: the bases alone, as without ground maps.
    if (static_cast<int>(smp.bases.xy.size()) < params.tilt_min_pairs) return;
    smp.ground = ElevationSamples();
  }
  const double max_slope = std::tan(params.max_tilt_deg * M_PI / 180.0);
  if (std::hypot(s(2), s(3)) > max_slope) return;
  // z' = z - beta x + alpha y for a small rotation R_x(alpha) R_y(beta) about `mean`.
  const double alpha = std::asin(std::clamp(s(3), -1.0, 1.0));
  const double beta = -std::asin(std::clamp(s(2), -1.0, 1.0));
  // Rotate about the centre at its refined elevation, so t_z stays well conditioned.
  const double offset = smp.bases.xy.empty() ? s(1) : s(0);
  *T = tiltedAbout(*T, alpha, beta, mean);
  T->translation().z() += offset - z_applied;
  v->tilt_fitted = true;
  v->tilt_ground_cells = smp.ground.xy.empty() ? 0 : kept;
  // Information in units of a full-weight pair of std dev base_sigma_m; s3 is the roll
  // (about x), s2 the pitch.
  const Eigen::Matrix4d post = info.inverse() * params.base_sigma_m * params.base_sigma_m;
  v->roll_var = std::max(post(3, 3), kMinFittedTiltVar);
  v->pitch_var = std::max(post(2, 2), kMinFittedTiltVar);
  if (v->tilt_ground_cells > 0) {
    const double floor = params.ground_tilt_floor_deg * M_PI / 180.0;
    v->roll_var += floor * floor;
    v->pitch_var += floor * floor;
  }
}

/// The ground maps' cell differences under `T` for the tilt fit, when both submaps carry a map
/// and their differences have a clear mode with tilt_min_ground_cells agreeing; else none.
void addGroundSamples(const Descriptor& q, const Descriptor& c, const Pose& T,
                      const VerifierParams& params, TiltSamples* smp) {
  if (params.tilt_min_ground_cells <= 0 || q.ground_map.empty() || c.ground_map.empty()) return;
  const GroundDifferences d = groundDifferences(q.ground_map, c.ground_map, T);
  const GroundElevation g = groundElevationOf(d.dz, params.ground_window_m);
  if (!g.ok || g.support < params.tilt_min_ground_cells ||
      g.ambiguity > params.max_ground_ambiguity) {
    return;
  }
  smp->ground.xy = d.xy;
  smp->ground.dz = d.dz;
  smp->ground_start = g.dz_m;
}

/// The ground maps' elevation under `T` turned by the residual tilt that gives their
/// differences the strongest mode, searched within ground_tilt_search_deg per axis when either
/// submap was levelled (Descriptor::levelled). Each robot's
/// levelled frame is off gravity by its levelling error (tenths of a degree, up to ~1 deg for a
/// robot's first submaps), so two maps 20-40 m across differ by a plane, not a constant: at
/// 0.6 deg their cells' differences spread over +-0.2 m and the 15 cm window's mode can look no
/// better than a runner-up (`elevation ambiguous`) although the horizontal pose is right.
/// The search tilts the differences (to first order, a tilt about their centroid adds a plane
/// to them) in steps of 0.2 deg (0.07 m at 20 m, within the window), then 0.05 deg around the
/// best, by the count within the window of the smoothed 5 cm histogram's peak, as
/// groundElevation counts it; the winner is measured exactly with `T` turned by it. `T` is
/// turned when the winner's support beats `flat`'s (the untilted elevation).
GroundElevation tiltedGroundElevation(const Descriptor& q, const Descriptor& c,
                                      const VerifierParams& params, const GroundElevation& flat,
                                      Pose* T) {
  // Only frames dtif levelled (tilted odometry frames) carry a levelling error to search for;
  // between gravity-aligned frames (a few tenths of a degree) the search only adds freedom:
  // on level scenes it moved queries' best loops to worse-fitting ones (very_sparse seeds 1-3).
  if (!(params.ground_tilt_search_deg > 0.0) || !(q.levelled() || c.levelled())) return flat;
  const GroundDifferences d = groundDifferences(q.ground_map, c.ground_map, *T);
  if (d.xy.empty()) return flat;
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  for (const auto& p : d.xy) centre += p;
  centre /= static_cast<double>(d.xy.size());
  std::vector<double> dz(d.dz.size());
  // Support of the mode with the differences tilted by roll a, pitch b (z' = z + a y - b x).
  const auto support = [&](double a, double b) {
    for (size_t k = 0; k < d.dz.size(); ++k) {
      dz[k] = d.dz[k] - a * (d.xy[k].y() - centre.y()) + b * (d.xy[k].x() - centre.x());
    }
    return groundElevationOf(dz, params.ground_window_m).support;
  };
  const double deg = M_PI / 180.0, range = params.ground_tilt_search_deg * deg;
  double best_a = 0.0, best_b = 0.0;
  int best = flat.support;  // the untilted differences are d.dz
  const auto search = [&](double a0, double b0, double half, double step) {
    const int n = static_cast<int>(std::floor(half / step + 1e-9));
    double next_a = best_a, next_b = best_b;
    for (int i = -n; i <= n; ++i) {
      for (int j = -n; j <= n; ++j) {
        const double a = a0 + i * step, b = b0 + j * step;
        if (std::abs(a) > range + 1e-12 || std::abs(b) > range + 1e-12) continue;
        const int s = support(a, b);
        if (s > best) best = s, next_a = a, next_b = b;
      }
    }
    best_a = next_a, best_b = next_b;
  };
  search(0.0, 0.0, range, 0.2 * deg);
  search(best_a, best_b, 0.15 * deg, 0.05 * deg);
  if (best_a == 0.0 && best_b == 0.0) return flat;
  const Pose T_tilted = tiltedAbout(*T, best_a, best_b, centre);
  const GroundElevation g =
      groundElevation(q.ground_map, c.ground_map, T_tilted, params.ground_window_m);
  if (!g.ok || g.support <= flat.support) return flat;
  *T = T_tilted;
  return g;
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
  v->tilt_ground_cells = 0;
  if (!seen) use = pairs;
  if (use.empty()) return 0.0;
  const ElevationSamples smp = elevationSamples(q, c, use, *T);
  const ElevationMode m = elevationMode(smp.dz);
  if (seen) {
    v->z_pairs = m.agree;
    v->z_ambiguity = static_cast<double>(elevationRunnerUp(smp.dz, m.mode)) / std::max(m.agree, 1);
  }
  const Pose T_samples = *T;
  T->translation().z() += m.z_mode;
  if (!seen || params.tilt_min_pairs <= 0) return rmsElevation(q, c, use, *T);
  TiltSamples tilt;
  tilt.bases = smp;
  tilt.bases_start = m.z_mode;
  // Ground cells only with bases that fix t_z (else checkElevation may take it from the ground).
  const bool trusted = m.agree >= params.min_z_pairs && !(v->z_ambiguity > params.max_z_ambiguity);
  if (trusted) addGroundSamples(q, c, T_samples, params, &tilt);
  if (!tilt.ground.xy.empty() || static_cast<int>(use.size()) >= params.tilt_min_pairs)
    fitTilt(tilt, m.z_mode, params, T, v);
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
  GroundElevation g = groundElevation(q.ground_map, c.ground_map, *T, params.ground_window_m);
  if (!g.ok || g.support < params.min_ground_cells || g.ambiguity > params.max_ground_ambiguity) {
    // Perhaps only the two levelled frames' residual tilt smears the mode: search it. Only
    // here, so that every elevation the maps settle untilted stays as it was.
    Pose T_tilted = *T;
    const GroundElevation gt = tiltedGroundElevation(q, c, params, g, &T_tilted);
    if (gt.ok && gt.support >= params.min_ground_cells &&
        gt.ambiguity <= params.max_ground_ambiguity) {
      g = gt;
      *T = T_tilted;
    }
  }
  v->ground_ambiguity = g.ok ? g.ambiguity : -1.0;
  if (!g.ok || g.support < params.min_ground_cells) return why;
  if (g.ambiguity > params.max_ground_ambiguity) return Rejection::kElevationAmbiguous;
  TiltSamples tilt;
  if (params.tilt_min_pairs > 0) addGroundSamples(q, c, *T, params, &tilt);
  T->translation().z() += g.dz_m;
  if (!tilt.ground.xy.empty()) fitTilt(tilt, g.dz_m, params, T, v);
  v->T_c_q = *T;
  v->ground_cells = g.support;
  v->ground_sigma_m = g.spread_m;
  return Rejection::kNone;
}

}  // namespace dtif
