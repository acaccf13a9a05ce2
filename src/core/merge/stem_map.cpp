#include "dtif/core/merge/stem_map.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/pose/rigid2d.h"

namespace dtif {
namespace {

/// Only yaw and the horizontal translation: M and P are both z up, and P has no elevation.
Pose planar(const Pose& T) {
  const double yaw = std::atan2(T.linear()(1, 0), T.linear()(0, 0));
  Pose out = Pose::Identity();
  out.linear() = rotZ(yaw);
  out.translation() << T.translation().x(), T.translation().y(), 0.0;
  return out;
}

/// Each stem's nearest field stem within `radius` under T_P_M, one stem per field stem (the
/// closer wins).
std::vector<std::pair<size_t, size_t>> nearestPairs(const Trunks& stems, const Trunks& field,
                                                    const Pose& T_P_M, double radius,
                                                    std::vector<double>* residuals) {
  std::vector<int> owner(field.size(), -1);
  std::vector<double> dist(field.size(), std::numeric_limits<double>::infinity());
  for (size_t i = 0; i < stems.size(); ++i) {
    const Eigen::Vector3d p = T_P_M * Eigen::Vector3d(stems[i].x, stems[i].y, 0.0);
    size_t best = field.size();
    double best_d = radius;
    for (size_t j = 0; j < field.size(); ++j) {
      const double d = std::hypot(p.x() - field[j].x, p.y() - field[j].y);
      if (d < best_d) {
        best_d = d;
        best = j;
      }
    }
    if (best < field.size() && best_d < dist[best]) {
      dist[best] = best_d;
      owner[best] = static_cast<int>(i);
    }
  }
  std::vector<std::pair<size_t, size_t>> pairs;
  residuals->clear();
  for (size_t j = 0; j < field.size(); ++j) {
    if (owner[j] < 0) continue;
    pairs.emplace_back(static_cast<size_t>(owner[j]), j);
    residuals->push_back(dist[j]);
  }
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

}  // namespace

LoopDetectorParams fieldStemMapLoopParams() {
  LoopDetectorParams p;
  p.matcher.edge_rel_tol = 0.05;
  p.matcher.edge_abs_tol_m = 0.3;
  p.matcher.radius_abs_tol_m = 0.05;
  p.pose.beta_yaw_m = 0.5;
  p.pose.beta_xy_m = 0.5;
  p.verification.match_radius_m = 0.6;
  p.verification.max_rms_xy_m = 0.35;
  return p;
}

StemMapParams::StemMapParams() : loop(fieldStemMapLoopParams()) {}

Trunks fieldStemsAsTrunks(const std::vector<FieldStem>& field, const StemMapParams& params) {
  Trunks out;
  out.reserve(field.size());
  for (const FieldStem& f : field) {
    TrunkLandmark t;
    t.x = f.x;
    t.y = f.y;
    t.z = 0.0;
    t.r = f.dbh > 0.0 ? f.dbh / 2.0 : params.default_radius_m;
    t.base_seen = true;  // the plot's plane: P has no elevation, z = 0 by definition
    out.push_back(t);
  }
  return out;
}

StemMapRegistration registerStemMap(const Trunks& stems, const std::vector<FieldStem>& field,
                                    const StemMapParams& params) {
  StemMapRegistration reg;
  Trunks flat = stems;  // P has no elevation: match on the horizontal layout only
  for (TrunkLandmark& t : flat) {
    t.z = 0.0;  // both on one plane: verification sees t_z = 0 from every pair
    t.base_seen = true;
  }
  const Trunks ftrunks = fieldStemsAsTrunks(field, params);
  const Descriptor q = buildDescriptor(flat, params.descriptor);
  const Descriptor c = buildDescriptor(ftrunks, params.descriptor);
  if (!q.valid || !c.valid) {
    reg.reason = "too few stems: " + (q.valid ? c.invalid_reason : q.invalid_reason);
    return reg;
  }
  Verification ver;
  const std::optional<Loop> loop = matchPair(q, c, params.loop, nullptr, &ver);
  if (!loop) {
    reg.reason = "descriptor match rejected: " + ver.reason();
    return reg;
  }
  // Planar refinement on nearest-neighbour pairs (the matcher pairs only triangle vertices).
  Pose T = planar(loop->T_c_q);
  std::vector<double> res;
  for (int it = 0; it < 5; ++it) {
    reg.pairs = nearestPairs(flat, ftrunks, T, params.pair_radius_m, &res);
    if (reg.pairs.size() < 2) break;
    std::vector<PointPair2d> pp;
    for (const auto& [i, j] : reg.pairs) {
      pp.emplace_back(Eigen::Vector2d(flat[i].x, flat[i].y),
                      Eigen::Vector2d(ftrunks[j].x, ftrunks[j].y));
    }
    T = planar(rigid2d(pp, 0.0));
  }
  reg.pairs = nearestPairs(flat, ftrunks, T, params.pair_radius_m, &res);
  if (static_cast<int>(reg.pairs.size()) < params.min_pairs) {
    reg.reason = "only " + std::to_string(reg.pairs.size()) + " stems pair with the field map";
    return reg;
  }
  double ss = 0.0;
  for (double r : res) ss += r * r;
  reg.rms_m = std::sqrt(ss / res.size());
  std::nth_element(res.begin(), res.begin() + res.size() / 2, res.end());
  reg.median_m = res[res.size() / 2];
  reg.T_P_M = T;
  reg.ok = true;
  return reg;
}

}  // namespace dtif
