// Baseline pose solvers (see solvers.h): SVD-RANSAC, Quatro-like, FGR.
#include "dtif/baselines/solvers.h"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>

namespace dtif::baselines {
namespace {

/// Rigid transform minimising sum_i w_i ||c_i - (R q_i + t)||^2 (Umeyama 1991, no scale):
/// SVD of the weighted cross-covariance, with the reflection fixed by the determinant sign.
Pose weightedRigid(const std::vector<Correspondence>& corrs, const std::vector<int>& idx,
                   const std::vector<double>& w) {
  Eigen::Vector3d mq = Eigen::Vector3d::Zero(), mc = Eigen::Vector3d::Zero();
  double ws = 0.0;
  for (size_t k = 0; k < idx.size(); ++k) {
    mq += w[k] * corrs[idx[k]].pq;
    mc += w[k] * corrs[idx[k]].pc;
    ws += w[k];
  }
  Pose T = Pose::Identity();
  if (ws <= 0.0) return T;
  mq /= ws;
  mc /= ws;
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();  // sum w (q - mq)(c - mc)^T
  for (size_t k = 0; k < idx.size(); ++k) {
    H += w[k] * (corrs[idx[k]].pq - mq) * (corrs[idx[k]].pc - mc).transpose();
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  T.linear() = svd.matrixV() * D * svd.matrixU().transpose();
  T.translation() = mc - T.linear() * mq;
  return T;
}

/// Fills the fields verification reads from a solver's pose (see solvers.h).
PoseEstimate finish(const std::vector<Correspondence>& corrs, const Pose& T, double inlier_m) {
  PoseEstimate est;
  est.T_c_q = T;
  const Eigen::Matrix3d& R = T.linear();
  est.yaw_rad = std::atan2(R(1, 0), R(0, 0));
  double sxy = 0.0, sz = 0.0;
  for (size_t i = 0; i < corrs.size(); ++i) {
    const Eigen::Vector3d r = corrs[i].pc - T * corrs[i].pq;
    if (r.head<2>().norm() > inlier_m) continue;
    est.inliers_T.push_back(static_cast<int>(i));
    est.inlier_weight += corrs[i].w;
    sxy += r.head<2>().squaredNorm();
    sz += r.z() * r.z();
  }
  est.inliers_R = est.inliers_T;
  const double n = static_cast<double>(est.inliers_T.size());
  if (n > 0) {
    est.rms_xy_m = std::sqrt(sxy / n);
    est.rms_z_m = std::sqrt(sz / n);
  }
  est.yaw_consensus = est.translation_consensus = est.inlier_weight;
  est.ok = true;
  return est;
}

}  // namespace

PoseEstimate svdRansac(const std::vector<Correspondence>& corrs, const RansacParams& params) {
  const int k = static_cast<int>(corrs.size());
  if (k < 3) return PoseEstimate{};
  std::mt19937 rng(params.seed);
  std::uniform_int_distribution<int> pick(0, k - 1);
  const double b2 = params.inlier_m * params.inlier_m;
  const std::vector<double> ones(3, 1.0);
  std::vector<int> best;
  int needed = params.max_iterations;
  for (int it = 0; it < needed; ++it) {
    std::vector<int> s{pick(rng), pick(rng), pick(rng)};
    if (s[0] == s[1] || s[0] == s[2] || s[1] == s[2]) continue;
    // A degenerate (near-collinear) sample fixes no rotation about its line.
    const Eigen::Vector3d a = corrs[s[1]].pq - corrs[s[0]].pq, b = corrs[s[2]].pq - corrs[s[0]].pq;
    if (a.cross(b).norm() < 0.5) continue;
    const Pose T = weightedRigid(corrs, s, ones);
    std::vector<int> inl;
    for (int i = 0; i < k; ++i) {
      if ((corrs[i].pc - T * corrs[i].pq).squaredNorm() <= b2) inl.push_back(i);
    }
    if (inl.size() <= best.size()) continue;
    best = std::move(inl);
    // Adaptive stop: samples needed to draw an all-inlier triple with the given confidence.
    const double ratio = static_cast<double>(best.size()) / k;
    const double p_good = ratio * ratio * ratio;
    if (p_good >= 1.0) break;
    const double n = std::log(1.0 - params.confidence) / std::log(1.0 - p_good);
    needed = std::min(params.max_iterations, static_cast<int>(std::ceil(n)));
  }
  if (best.size() < 3) return PoseEstimate{};
  // Least-squares refit on the consensus set, twice (the set can grow once).
  Pose T = weightedRigid(corrs, best, std::vector<double>(best.size(), 1.0));
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<int> inl;
    for (int i = 0; i < k; ++i) {
      if ((corrs[i].pc - T * corrs[i].pq).squaredNorm() <= b2) inl.push_back(i);
    }
    if (inl.size() < 3) break;
    T = weightedRigid(corrs, inl, std::vector<double>(inl.size(), 1.0));
  }
  return finish(corrs, T, params.inlier_m);
}

namespace {

/// A 2-D translation-invariant measurement of two correspondences (Quatro's TIM, z dropped
/// after gravity alignment).
struct Tim2 {
  int a, b;
  Eigen::Vector2d dq, dc;
};

double yawOf(const std::vector<Tim2>& tims, const std::vector<double>& u) {
  double dot = 0.0, crs = 0.0;
  for (size_t i = 0; i < tims.size(); ++i) {
    dot += u[i] * tims[i].dq.dot(tims[i].dc);
    crs += u[i] * (tims[i].dq.x() * tims[i].dc.y() - tims[i].dq.y() * tims[i].dc.x());
  }
  return std::atan2(crs, dot);
}

double timR2(const Tim2& m, const Eigen::Matrix2d& R) { return (m.dc - R * m.dq).squaredNorm(); }

/// One axis of TEASER's component-wise translation (COTE): every observation v_i is an
/// interval [v_i - beta, v_i + beta]; within each elementary segment of the sorted interval
/// ends the consensus set S is fixed, its TLS optimum is mean(S) at cost
/// sum_S (v - mean)^2 + (n - |S|) beta^2; the smallest cost wins.
double adaptiveVoting(const std::vector<double>& v, double beta) {
  const size_t n = v.size();
  std::vector<std::pair<double, int>> ends;  // (position, +1 opens / -1 closes)
  for (double x : v) {
    ends.emplace_back(x - beta, 1);
    ends.emplace_back(x + beta, -1);
  }
  std::sort(ends.begin(), ends.end(), [](const auto& p, const auto& q) {
    return p.first < q.first || (p.first == q.first && p.second > q.second);
  });
  double best = 0.0, best_cost = static_cast<double>(n) * beta * beta + 1.0;
  for (size_t e = 0; e + 1 < ends.size(); ++e) {
    const double mid = 0.5 * (ends[e].first + ends[e + 1].first);
    double sum = 0.0, sum2 = 0.0;
    size_t m = 0;
    for (double x : v) {
      if (std::fabs(x - mid) <= beta) sum += x, sum2 += x * x, ++m;
    }
    if (m == 0) continue;
    const double mean = sum / m;
    const double cost = (sum2 - m * mean * mean) + static_cast<double>(n - m) * beta * beta;
    if (cost < best_cost) best_cost = cost, best = mean;
  }
  return best;
}

}  // namespace

PoseEstimate quatroLike(const std::vector<Correspondence>& corrs, const QuatroParams& params) {
  const int k = static_cast<int>(corrs.size());
  if (k < 2) return PoseEstimate{};
  std::vector<Tim2> tims;
  forEachSampledPair(k, params.max_tim_pairs, [&](int a, int b) {
    tims.push_back(
        {a, b, (corrs[a].pq - corrs[b].pq).head<2>(), (corrs[a].pc - corrs[b].pc).head<2>()});
  });
  // GNC-TLS (Yang et al. 2020) on yaw: mu from the largest residual of the least-squares start
  // up to the truncated cost, each step the closed-form weighted 2-D rotation.
  const double c2 = params.beta_m * params.beta_m;
  std::vector<double> u(tims.size(), 1.0);
  double yaw = yawOf(tims, u);
  Eigen::Matrix2d R = Eigen::Rotation2Dd(yaw).toRotationMatrix();
  double r2max = 0.0;
  for (const Tim2& m : tims) r2max = std::max(r2max, timR2(m, R));
  double mu = r2max > c2 ? c2 / (2.0 * r2max - c2) : 0.0;
  for (int it = 0; mu > 0.0 && it < params.gnc_max_iterations; ++it) {
    bool settled = true;
    for (size_t i = 0; i < tims.size(); ++i) {
      const double r2 = timR2(tims[i], R);
      const double upper = (mu + 1.0) / mu * c2, lower = mu / (mu + 1.0) * c2;
      const double ui = r2 >= upper   ? 0.0
                        : r2 <= lower ? 1.0
                                      : params.beta_m * std::sqrt(mu * (mu + 1.0) / r2) - mu;
      settled = settled && (ui == 0.0 || ui == 1.0);
      u[i] = ui;
    }
    const double prev = yaw;
    yaw = yawOf(tims, u);
    R = Eigen::Rotation2Dd(yaw).toRotationMatrix();
    if (settled && std::fabs(std::remainder(yaw - prev, 2.0 * M_PI)) < 1e-9) break;
    mu *= params.gnc_factor;
  }
  // Rotation inliers: every correspondence of an inlier TIM.
  std::vector<char> rot_inlier(k, 0);
  for (const Tim2& m : tims) {
    if (timR2(m, R) <= c2) rot_inlier[m.a] = rot_inlier[m.b] = 1;
  }
  Eigen::Matrix3d R3 = Eigen::Matrix3d::Identity();
  R3.topLeftCorner<2, 2>() = R;
  std::vector<double> vx, vy, vz;
  for (int i = 0; i < k; ++i) {
    if (!rot_inlier[i]) continue;
    const Eigen::Vector3d v = corrs[i].pc - R3 * corrs[i].pq;
    vx.push_back(v.x());
    vy.push_back(v.y());
    vz.push_back(v.z());
  }
  if (vx.empty()) return PoseEstimate{};
  Pose T = Pose::Identity();
  T.linear() = R3;
  T.translation() =
      Eigen::Vector3d(adaptiveVoting(vx, params.beta_m), adaptiveVoting(vy, params.beta_m),
                      adaptiveVoting(vz, params.beta_m));
  return finish(corrs, T, params.beta_m);
}

PoseEstimate fastGlobalRegistration(const std::vector<Correspondence>& corrs,
                                    const FgrParams& params) {
  const int k = static_cast<int>(corrs.size());
  if (k < 3) return PoseEstimate{};
  // mu starts at the squared diameter of the correspondences (the paper's D^2).
  Eigen::Vector3d lo = corrs[0].pq, hi = corrs[0].pq;
  for (const Correspondence& c : corrs) {
    lo = lo.cwiseMin(c.pq).cwiseMin(c.pc);
    hi = hi.cwiseMax(c.pq).cwiseMax(c.pc);
  }
  double mu = (hi - lo).squaredNorm();
  const double mu_min = params.final_scale_m * params.final_scale_m;
  std::vector<int> all(k);
  std::iota(all.begin(), all.end(), 0);
  std::vector<double> l(k, 1.0);
  Pose T = Pose::Identity();
  for (int it = 0; it < params.iterations; ++it) {
    if (it > 0 && it % 4 == 0 && mu > mu_min) mu = std::max(mu / params.div_factor, mu_min);
    for (int i = 0; i < k; ++i) {
      const double r2 = (corrs[i].pc - T * corrs[i].pq).squaredNorm();
      const double s = mu / (mu + r2);
      l[i] = s * s;  // optimal line process of the Geman-McClure penalty
    }
    T = weightedRigid(corrs, all, l);
  }
  return finish(corrs, T, params.final_scale_m);
}

std::vector<int> greedyConsistentSet(const std::vector<Correspondence>& corrs, double eps) {
  const int k = static_cast<int>(corrs.size());
  std::vector<int> all(k);
  std::iota(all.begin(), all.end(), 0);
  if (k < 3) return all;
  std::vector<uint8_t> agree(static_cast<size_t>(k) * k, 0);
  std::vector<int> degree(k, 0);
  for (int i = 0; i < k; ++i) {
    for (int j = i + 1; j < k; ++j) {
      const double lq = (corrs[i].pq - corrs[j].pq).norm(), lc = (corrs[i].pc - corrs[j].pc).norm();
      if (std::fabs(lq - lc) > eps) continue;
      agree[static_cast<size_t>(i) * k + j] = agree[static_cast<size_t>(j) * k + i] = 1;
      ++degree[i];
      ++degree[j];
    }
  }
  std::stable_sort(all.begin(), all.end(), [&](int a, int b) { return degree[a] > degree[b]; });
  std::vector<int> clique;
  for (int i : all) {
    if (degree[i] < static_cast<int>(clique.size())) break;  // cannot join a clique this big
    bool ok = true;
    for (int m : clique) {
      if (!agree[static_cast<size_t>(i) * k + m]) {
        ok = false;
        break;
      }
    }
    if (ok) clique.push_back(i);
  }
  std::sort(clique.begin(), clique.end());
  return clique;
}

}  // namespace dtif::baselines
