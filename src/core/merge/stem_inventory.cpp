#include "dtif/core/merge/stem_inventory.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>
#include <unordered_map>

#include "dtif/core/cells.h"
#include "dtif/core/robust.h"

namespace dtif {
namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const size_t h = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + h, v.end());
  if (v.size() % 2 == 1) return v[h];
  const double hi = v[h];
  return 0.5 * (hi + *std::max_element(v.begin(), v.begin() + h));
}

struct Cluster {
  double sx = 0.0, sy = 0.0, sr = 0.0;  // running sums for the centre
  std::vector<size_t> members;
  std::set<int64_t> submaps;
  double cx() const { return sx / members.size(); }
  double cy() const { return sy / members.size(); }
  double cr() const { return sr / members.size(); }
};

/// Clusters of one component, with a 1 m grid over their centres.
class Clusterer {
 public:
  Clusterer(const std::vector<StemObservation>& obs, const StemFusionParams& p)
      : obs_(obs), p_(p) {}

  void add(size_t i) {
    const StemObservation& o = obs_[i];
    int best = -1;
    double best_d = p_.cluster_radius_m;
    const int64_t gx = cell(o.x), gy = cell(o.y);
    for (int64_t dx = -1; dx <= 1; ++dx) {
      for (int64_t dy = -1; dy <= 1; ++dy) {
        auto it = grid_.find(key(gx + dx, gy + dy));
        if (it == grid_.end()) continue;
        for (int c : it->second) {
          const Cluster& cl = clusters_[c];
          if (cl.submaps.count(o.submap)) continue;
          const double tol = std::max(p_.radius_abs_tol_m, p_.radius_rel_tol * cl.cr());
          if (std::fabs(o.r - cl.cr()) > tol) continue;
          const double d = std::hypot(o.x - cl.cx(), o.y - cl.cy());
          if (d < best_d || (d == best_d && c < best)) {
            best_d = d;
            best = c;
          }
        }
      }
    }
    if (best < 0) {
      best = static_cast<int>(clusters_.size());
      clusters_.emplace_back();
    } else {
      unindex(best);
    }
    Cluster& cl = clusters_[best];
    cl.sx += o.x;
    cl.sy += o.y;
    cl.sr += o.r;
    cl.members.push_back(i);
    cl.submaps.insert(o.submap);
    grid_[key(cell(cl.cx()), cell(cl.cy()))].push_back(best);
  }

  /// Joins clusters whose centres are within the radius and that share no submap: one tree
  /// split in two when its first observations came from poses a few decimetres apart.
  void joinClose() {
    bool changed = true;
    while (changed) {
      changed = false;
      for (size_t c = 0; c < clusters_.size(); ++c) {
        if (clusters_[c].members.empty()) continue;
        const int d = closestDisjoint(static_cast<int>(c));
        if (d < 0) continue;
        unindex(static_cast<int>(c));
        unindex(d);
        Cluster& a = clusters_[c];
        Cluster& b = clusters_[d];
        a.sx += b.sx, a.sy += b.sy, a.sr += b.sr;
        a.members.insert(a.members.end(), b.members.begin(), b.members.end());
        a.submaps.insert(b.submaps.begin(), b.submaps.end());
        b = Cluster{};
        grid_[key(cell(a.cx()), cell(a.cy()))].push_back(static_cast<int>(c));
        changed = true;
      }
    }
  }

  std::vector<Cluster> clusters() const {
    std::vector<Cluster> out;
    for (const Cluster& c : clusters_) {
      if (!c.members.empty()) out.push_back(c);
    }
    return out;
  }

 private:
  // Saturated and packed without UB (cells.h): UBSan found `x << 32` of a negative index here.
  int64_t cell(double v) const { return cellIndex(v / p_.cluster_radius_m); }
  static int64_t key(int64_t x, int64_t y) { return packCell(x, y); }
  int closestDisjoint(int c) const {
    const Cluster& a = clusters_[c];
    int best = -1;
    double best_d = p_.cluster_radius_m;
    const int64_t gx = cell(a.cx()), gy = cell(a.cy());
    for (int64_t dx = -1; dx <= 1; ++dx) {
      for (int64_t dy = -1; dy <= 1; ++dy) {
        auto it = grid_.find(key(gx + dx, gy + dy));
        if (it == grid_.end()) continue;
        for (int d : it->second) {
          if (d == c) continue;
          const Cluster& b = clusters_[d];
          const double tol = std::max(p_.radius_abs_tol_m, p_.radius_rel_tol * a.cr());
          if (std::fabs(a.cr() - b.cr()) > tol) continue;
          const double dist = std::hypot(a.cx() - b.cx(), a.cy() - b.cy());
          if (dist >= best_d) continue;
          if (std::any_of(b.submaps.begin(), b.submaps.end(),
                          [&](int64_t s) { return a.submaps.count(s) > 0; })) {
            continue;
          }
          best_d = dist;
          best = d;
        }
      }
    }
    return best;
  }

  void unindex(int c) {
    auto& v = grid_[key(cell(clusters_[c].cx()), cell(clusters_[c].cy()))];
    v.erase(std::find(v.begin(), v.end(), c));
  }

  const std::vector<StemObservation>& obs_;
  const StemFusionParams& p_;
  std::vector<Cluster> clusters_;
  std::unordered_map<int64_t, std::vector<int>> grid_;
};

/// One tree: a cluster of observations and the base they are referred to.
struct Tree {
  int component = 0;
  std::vector<size_t> members;
  int observations = 0;
  double x = 0.0, y = 0.0;  // median of all observations [m]
  bool base_seen = false;   // some observation saw the base
  bool has_base = false;    // z_base is known (seen, or from the neighbours' terrain)
  double z_base = 0.0;      // [m]
};

Tree treeOf(const std::vector<StemObservation>& obs, const Cluster& cl, int component,
            const StemFusionParams& p) {
  Tree t;
  t.component = component;
  t.members = cl.members;
  t.observations = static_cast<int>(cl.submaps.size());
  std::vector<double> zs_seen;
  for (size_t i : cl.members) {
    if (obs[i].base_seen) zs_seen.push_back(obs[i].z);
  }
  t.base_seen = t.has_base = !zs_seen.empty();
  t.z_base = median(zs_seen);
  // Where the neighbours look for this tree's ground: its position at breast height when known.
  std::vector<double> xs, ys, xs_bh, ys_bh;
  for (size_t i : cl.members) {
    xs.push_back(obs[i].x), ys.push_back(obs[i].y);
    if (t.base_seen && std::fabs(obs[i].z - t.z_base) <= p.base_tol_m)
      xs_bh.push_back(obs[i].x), ys_bh.push_back(obs[i].y);
  }
  t.x = median(xs_bh.empty() ? xs : xs_bh);
  t.y = median(ys_bh.empty() ? ys : ys_bh);
  return t;
}

std::vector<Tree> clusterTrees(const std::vector<StemObservation>& observations,
                               const StemFusionParams& params) {
  std::map<int, std::vector<size_t>> by_component;
  for (size_t i = 0; i < observations.size(); ++i) {
    const StemObservation& o = observations[i];
    if (std::isfinite(o.x) && std::isfinite(o.y) && std::isfinite(o.z) && std::isfinite(o.r)) {
      by_component[o.component].push_back(i);
    }
  }
  std::vector<Tree> trees;
  for (const auto& [component, idx] : by_component) {
    Clusterer clusterer(observations, params);
    for (size_t i : idx) clusterer.add(i);
    clusterer.joinClose();
    for (const Cluster& cl : clusterer.clusters()) {
      if (static_cast<int>(cl.submaps.size()) < params.min_observations) continue;
      trees.push_back(treeOf(observations, cl, component, params));
    }
  }
  return trees;
}

// The Tukey-weighted least-squares surface through the ground points, each also weighted by
// near[i]: a plane (N = 3) or a quadratic (N = 6) in (x, y) about the point asked for, whose
// height there is the first coefficient. false when the system is singular.
template <int N>
bool fitSurface(double x, double y, const std::vector<Eigen::Vector3d>& pts,
                const std::vector<double>& near, double z0, double* z) {
  constexpr double kTukeyM = 0.5;
  using Vec = Eigen::Matrix<double, N, 1>;
  Vec surf = Vec::Zero();
  surf(0) = z0;
  for (int it = 0; it < 4; ++it) {
    Eigen::Matrix<double, N, N> A = Eigen::Matrix<double, N, N>::Zero();
    Vec g = Vec::Zero();
    for (size_t i = 0; i < pts.size(); ++i) {
      const double dx = pts[i].x() - x, dy = pts[i].y() - y;
      Vec row;
      if constexpr (N == 6)
        row << 1.0, dx, dy, dx * dx, dx * dy, dy * dy;
      else
        row << 1.0, dx, dy;
      const double w = near[i] * tukeyWeight(pts[i].z() - row.dot(surf), it == 0 ? 1e9 : kTukeyM);
      A += w * row * row.transpose();
      g += w * row * pts[i].z();
    }
    const Eigen::LDLT<Eigen::Matrix<double, N, N>> ldlt(A);
    const Vec next = ldlt.solve(g);
    if (!next.allFinite() || !(ldlt.rcond() >= 1e-12)) return false;
    surf = next;
  }
  *z = surf(0);
  return true;
}

// Smallest eigenvalue of the (weighted) covariance of the points' horizontal positions [m^2].
double horizontalSpread(const std::vector<Eigen::Vector3d>& pts, const std::vector<double>& w) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  double sum = 0.0;
  for (size_t i = 0; i < pts.size(); ++i) mean += w[i] * pts[i].head<2>(), sum += w[i];
  if (!(sum > 0.0)) return 0.0;
  mean /= sum;
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (size_t i = 0; i < pts.size(); ++i)
    cov += w[i] * (pts[i].head<2>() - mean) * (pts[i].head<2>() - mean).transpose();
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov / sum).eigenvalues()(0);
}

// Ground at (x, y) from a surface through the given ground points (seen bases, the ground under
// the paths), Tukey-weighted (a seen base can be a shrub's top); false when fewer than 4 or all
// within about a metre of a line. sigma > 0: each point is weighted by its distance as well
// (Gaussian), and where that weight adds up to kMinQuadWeight points spread over sigma / 2 both
// ways the surface is quadratic: a plane across 24 m of rolling ground sits high over every
// hollow and low on every crest (held-out seen bases of the built-in scenes: median error
// 0.08-0.48 m for the plane, 0.01-0.12 m for sigma 4 m; docs/results.md).
bool terrainAt(double x, double y, const std::vector<Eigen::Vector3d>& bases, double sigma,
               double* z) {
  constexpr double kMinSpreadM2 = 1.0, kMinQuadWeight = 6.0;
  if (bases.size() < 4) return false;
  std::vector<double> near(bases.size(), 1.0);
  if (!(horizontalSpread(bases, near) >= kMinSpreadM2)) return false;
  double weight = 0.0;  // of the distance weights; only sigma > 0 has them
  if (sigma > 0.0) {
    for (size_t i = 0; i < bases.size(); ++i) {
      const double d2 = (bases[i].head<2>() - Eigen::Vector2d(x, y)).squaredNorm();
      near[i] = std::exp(-0.5 * d2 / (sigma * sigma));
      weight += near[i];
    }
  }
  std::vector<double> zs;
  for (const Eigen::Vector3d& b : bases) zs.push_back(b.z());
  const double z0 = median(zs);
  if (sigma > 0.0 && weight >= kMinQuadWeight &&
      horizontalSpread(bases, near) >= 0.25 * sigma * sigma &&
      fitSurface<6>(x, y, bases, near, z0, z))
    return true;
  return fitSurface<3>(x, y, bases, near, z0, z);
}

/// The ground of each component: the seen bases of its trees and, once addPathGround ran, the
/// ground under its robots' sensor positions; a surface through those around a point.
class Terrain {
 public:
  Terrain(const std::vector<Tree>& trees, const StemFusionParams& p) : p_(p) {
    for (const Tree& t : trees) {
      if (t.base_seen) add(t.component, Eigen::Vector3d(t.x, t.y, t.z_base));
    }
  }

  /// The surface through the ground points within terrain_radius_m, else within
  /// terrain_far_radius_m (a downhill stem seen only from afar, its crown above the understory).
  bool at(int component, double x, double y, double* z) const {
    const double sigma = p_.terrain_sigma_m;
    return terrainAt(x, y, around(component, x, y, p_.terrain_radius_m), sigma, z) ||
           (p_.terrain_far_radius_m > p_.terrain_radius_m &&
            terrainAt(x, y, around(component, x, y, p_.terrain_far_radius_m), sigma, z));
  }

  /// Each robot's sensor height above the seen bases' surface (the median over its positions,
  /// when enough agree), then the ground under every position of those robots.
  void addPathGround(const std::vector<SensorPosition>& sensors) {
    if (p_.path_min_samples < 1) return;
    std::map<int, std::vector<double>> heights;
    for (const SensorPosition& s : sensors) {
      double z = 0.0;
      if (finite(s) && at(s.component, s.x, s.y, &z)) heights[s.robot].push_back(s.z - z);
    }
    std::map<int, double> height;
    for (const auto& [robot, hs] : heights) {
      if (static_cast<int>(hs.size()) < p_.path_min_samples) continue;
      const double h = median(hs);
      std::vector<double> dev;
      for (double v : hs) dev.push_back(std::fabs(v - h));
      if (median(dev) <= p_.path_max_spread_m) height[robot] = h;
    }
    for (const SensorPosition& s : sensors) {
      auto it = height.find(s.robot);
      if (it != height.end() && finite(s))
        add(s.component, Eigen::Vector3d(s.x, s.y, s.z - it->second));
    }
  }

 private:
  static bool finite(const SensorPosition& s) {
    return std::isfinite(s.x) && std::isfinite(s.y) && std::isfinite(s.z);
  }
  int64_t cell(double v) const { return cellIndex(v / p_.terrain_radius_m); }

  void add(int component, const Eigen::Vector3d& g) {
    grid_[packCell(cell(g.x()), cell(g.y()))].emplace_back(component, g);
  }

  std::vector<Eigen::Vector3d> around(int component, double x, double y, double radius) const {
    std::vector<Eigen::Vector3d> out;
    const int64_t reach = static_cast<int64_t>(std::ceil(radius / p_.terrain_radius_m));
    for (int64_t dx = -reach; dx <= reach; ++dx) {
      for (int64_t dy = -reach; dy <= reach; ++dy) {
        auto it = grid_.find(packCell(cell(x) + dx, cell(y) + dy));
        if (it == grid_.end()) continue;
        for (const auto& [c, g] : it->second) {
          if (c == component && std::hypot(g.x() - x, g.y() - y) <= radius) out.push_back(g);
        }
      }
    }
    return out;
  }

  const StemFusionParams& p_;
  std::unordered_map<int64_t, std::vector<std::pair<int, Eigen::Vector3d>>> grid_;
};

/// Trees whose base nobody saw take the ground around them (Terrain).
void terrainBases(const StemFusionParams& p, const std::vector<SensorPosition>& sensors,
                  std::vector<Tree>* trees) {
  if (!(p.terrain_radius_m > 0.0)) return;
  Terrain terrain(*trees, p);
  terrain.addPathGround(sensors);
  for (Tree& t : *trees) {
    if (!t.has_base) t.has_base = terrain.at(t.component, t.x, t.y, &t.z_base);
  }
}

// Radii of a tree's observations at breast height (base within base_tol_m of the tree's).
std::vector<double> breastHeightRadii(const std::vector<StemObservation>& obs, const Tree& t,
                                      const StemFusionParams& p) {
  std::vector<double> rs;
  for (size_t i : t.members) {
    if (std::fabs(obs[i].z - t.z_base) <= p.base_tol_m) rs.push_back(obs[i].r);
  }
  return rs;
}

std::vector<TaperPair> taperPairs(const std::vector<StemObservation>& obs,
                                  const std::vector<Tree>& trees, const StemFusionParams& p) {
  std::vector<TaperPair> pairs;
  for (const Tree& t : trees) {
    if (!t.base_seen) continue;
    const std::vector<double> at_bh = breastHeightRadii(obs, t, p);
    if (at_bh.empty()) continue;
    const double r_bh = median(at_bh);
    for (size_t i : t.members) pairs.push_back({obs[i].z - t.z_base, obs[i].r - r_bh});
  }
  return pairs;
}

MergedStem fuse(const std::vector<StemObservation>& obs, const Tree& t, double taper,
                const StemFusionParams& p) {
  std::vector<double> xs_all, ys_all, zs_all, rs_all, xs, ys, rs;
  for (size_t i : t.members) {
    const StemObservation& o = obs[i];
    xs_all.push_back(o.x), ys_all.push_back(o.y), zs_all.push_back(o.z);
    if (!t.has_base) {
      rs_all.push_back(o.r);
      continue;
    }
    // Fitted dz above breast height: the taper brings every radius down there, the farther
    // ones too (a downhill stem seen only above the understory: its crown side from afar).
    const double dz = o.z - t.z_base;
    rs_all.push_back(o.r + taper * dz);
    if (std::fabs(dz) <= p.base_tol_m) xs.push_back(o.x), ys.push_back(o.y);
    if (std::fabs(dz) <= p.max_base_offset_m) rs.push_back(o.r + taper * dz);
  }
  MergedStem s;
  s.component = t.component;
  s.x = median(xs.empty() ? xs_all : xs);
  s.y = median(ys.empty() ? ys_all : ys);
  s.z_base = t.has_base ? t.z_base : median(zs_all);
  s.dbh = 2.0 * median(rs.empty() ? rs_all : rs);
  s.observations = t.observations;
  return s;
}

// Drops the entries whose circle comes within overlap_margin_m of the circle of an entry seen
// by at least twice as many submaps: two trunks cannot overlap, so the weaker one is a second
// fit of the same stem (a branch or the root flare with part of the bark, which extraction keeps
// beside the stem's own fit when their circles just miss each other). Of two entries seen once
// each, within single_pair_margin_m, the smaller goes: mostly one submap's two circles on one
// stem (its bark, and part of it with clutter beside), which clustering cannot join since one
// submap holds both; two real stems that close are rarely each seen by one submap only. Beside
// a stem that many submaps saw (well_seen_observations), an entry seen once gets a wider margin
// still: those submaps had that spot in clear view, and a tree there would be seen by more.
double overlapMargin(const MergedStem& kept, const MergedStem& b, const StemFusionParams& p) {
  if (kept.observations == 1 && b.observations == 1) return p.single_pair_margin_m;
  if (kept.observations < 2 * b.observations) return -1.0;
  if (b.observations > 1) return p.overlap_margin_m;
  const double single = std::max(p.overlap_margin_m, p.single_overlap_margin_m);
  if (p.well_seen_observations > 0 && kept.observations >= p.well_seen_observations)
    return std::max(single, p.single_well_seen_margin_m);
  return single;
}

std::vector<MergedStem> dropOverlapping(std::vector<MergedStem> stems, const StemFusionParams& p) {
  if (!(p.overlap_margin_m >= 0.0) || stems.empty()) return stems;
  std::vector<size_t> order(stems.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    if (stems[a].observations != stems[b].observations)
      return stems[a].observations > stems[b].observations;
    return stems[a].dbh > stems[b].dbh;
  });
  double reach = 0.0;  // largest centre distance of two overlapping entries
  for (const MergedStem& s : stems) reach = std::max(reach, s.dbh);
  reach += std::max({p.overlap_margin_m, p.single_overlap_margin_m, p.single_pair_margin_m,
                     p.single_well_seen_margin_m});
  auto cell = [&](double v) { return cellIndex(v / std::max(reach, 1e-3)); };
  std::unordered_map<int64_t, std::vector<size_t>> kept_grid;
  std::vector<char> keep(stems.size(), 1);
  for (size_t i : order) {
    const MergedStem& b = stems[i];
    const int64_t gx = cell(b.x), gy = cell(b.y);
    for (int64_t dx = -1; dx <= 1 && keep[i]; ++dx) {
      for (int64_t dy = -1; dy <= 1 && keep[i]; ++dy) {
        auto it = kept_grid.find(packCell(gx + dx, gy + dy));
        if (it == kept_grid.end()) continue;
        for (size_t k : it->second) {
          const MergedStem& a = stems[k];
          const double margin = overlapMargin(a, b, p);
          if (a.component != b.component || margin < 0.0) continue;
          if (std::hypot(a.x - b.x, a.y - b.y) < 0.5 * (a.dbh + b.dbh) + margin) {
            keep[i] = 0;
            break;
          }
        }
      }
    }
    if (keep[i]) kept_grid[packCell(gx, gy)].push_back(i);
  }
  std::vector<MergedStem> out;
  for (size_t i = 0; i < stems.size(); ++i) {
    if (keep[i]) out.push_back(stems[i]);
  }
  return out;
}

}  // namespace

std::string StemFusionParams::validate() const {
  std::ostringstream e;
  if (!(cluster_radius_m > 0)) e << "stems.cluster_radius_m must be > 0; ";
  if (!(radius_rel_tol >= 0)) e << "stems.radius_rel_tol must be >= 0; ";
  if (!(radius_abs_tol_m >= 0)) e << "stems.radius_abs_tol_m must be >= 0; ";
  if (min_observations < 1) e << "stems.min_observations must be >= 1; ";
  if (!(base_tol_m >= 0)) e << "stems.base_tol_m must be >= 0; ";
  if (!(max_base_offset_m >= base_tol_m)) e << "stems.max_base_offset_m must be >= base_tol_m; ";
  if (!(terrain_radius_m >= 0 && terrain_radius_m <= 1000))
    e << "stems.terrain_radius_m must be in [0, 1000]; ";
  if (!(terrain_far_radius_m >= 0 && terrain_far_radius_m <= 4 * terrain_radius_m))
    e << "stems.terrain_far_radius_m must be in [0, 4 x terrain_radius_m]; ";
  if (!(terrain_sigma_m >= 0 && terrain_sigma_m <= 1000))
    e << "stems.terrain_sigma_m must be in [0, 1000]; ";
  if (path_min_samples < 0) e << "stems.path_min_samples must be >= 0; ";
  if (!(path_max_spread_m >= 0)) e << "stems.path_max_spread_m must be >= 0; ";
  if (taper_min_pairs < 0) e << "stems.taper_min_pairs must be >= 0; ";
  if (!(overlap_margin_m <= 1.0)) e << "stems.overlap_margin_m must be <= 1 (< 0: off); ";
  if (!(single_overlap_margin_m <= 1.0)) e << "stems.single_overlap_margin_m must be <= 1; ";
  if (!(single_pair_margin_m <= 1.0)) e << "stems.single_pair_margin_m must be <= 1 (< 0: off); ";
  if (well_seen_observations < 0) e << "stems.well_seen_observations must be >= 0; ";
  if (!(single_well_seen_margin_m <= 2.0)) e << "stems.single_well_seen_margin_m must be <= 2; ";
  if (!(slice_min_h_m >= 0 && slice_max_h_m > slice_min_h_m && slice_max_h_m <= 5))
    e << "stems.slice_min_h_m must be >= 0 and < slice_max_h_m <= 5; ";
  if (!(slice_margin_m >= 0 && slice_margin_m <= 1))
    e << "stems.slice_margin_m must be in [0, 1]; ";
  if (slice_max_points_per_submap < 1) e << "stems.slice_max_points_per_submap must be >= 1; ";
  if (slice_min_points < 3) e << "stems.slice_min_points must be >= 3; ";
  if (slice_min_submaps < 1) e << "stems.slice_min_submaps must be >= 1; ";
  if (!(slice_min_arc_deg >= 0 && slice_min_arc_deg <= 360))
    e << "stems.slice_min_arc_deg must be in [0, 360]; ";
  if (!(slice_max_shrink >= 0 && slice_max_shrink <= 1))
    e << "stems.slice_max_shrink must be in [0, 1]; ";
  if (!std::isfinite(slice_align_sigma_m))
    e << "stems.slice_align_sigma_m must be finite (<= 0: off); ";
  if (slice_align_sigma_m > 0 && !(slice_align_sigma_deg > 0 && slice_align_sigma_deg < 90))
    e << "stems.slice_align_sigma_deg must be in (0, 90) when slice_align_sigma_m > 0; ";
  if (!(slice_blend_min_arc_deg >= 0))
    e << "stems.slice_blend_min_arc_deg must be >= 0 (> 360: never); ";
  if (!(slice_min_inlier_ratio >= 0 && slice_min_inlier_ratio <= 1))
    e << "stems.slice_min_inlier_ratio must be in [0, 1]; ";
  if (!(slice_inlier_m > 0 && slice_inlier_m <= 0.5))
    e << "stems.slice_inlier_m must be in (0, 0.5]; ";
  if (!(slice_keep_margin_m >= 0 && slice_keep_margin_m <= 2))
    e << "stems.slice_keep_margin_m must be in [0, 2]; ";
  if (!(slice_keep_band_m >= 0 && slice_keep_band_m <= 3))
    e << "stems.slice_keep_band_m must be in [0, 3]; ";
  if (slice_keep_max_points < 1) e << "stems.slice_keep_max_points must be >= 1; ";
  if (!(slice_defer_clouds >= 0 && slice_defer_clouds <= 10000))
    e << "stems.slice_defer_clouds must be in [0, 10000]; ";
  return e.str();
}

double taperFromObservations(const std::vector<TaperPair>& pairs, const StemFusionParams& params) {
  constexpr double kMaxTaper = 0.05;  // steeper than any stem between 1 and 4 m [m/m]
  if (params.taper_min_pairs < 1) return 0.0;
  double sxy = 0.0, sxx = 0.0;
  int n = 0;
  for (const TaperPair& q : pairs) {
    if (!(q.dz > params.base_tol_m && q.dz <= params.max_base_offset_m) || !std::isfinite(q.dr))
      continue;
    sxy -= q.dz * q.dr;
    sxx += q.dz * q.dz;
    ++n;
  }
  if (n < params.taper_min_pairs) return 0.0;
  return std::clamp(sxy / sxx, 0.0, kMaxTaper);
}

std::vector<MergedStem> fuseStems(const std::vector<StemObservation>& observations,
                                  const StemFusionParams& params,
                                  const std::vector<SensorPosition>& sensors) {
  std::vector<Tree> trees = clusterTrees(observations, params);
  terrainBases(params, sensors, &trees);
  const double taper = taperFromObservations(taperPairs(observations, trees, params), params);
  std::vector<MergedStem> out;
  for (const Tree& t : trees) out.push_back(fuse(observations, t, taper, params));
  out = dropOverlapping(std::move(out), params);
  std::stable_sort(out.begin(), out.end(), [](const MergedStem& a, const MergedStem& b) {
    if (a.component != b.component) return a.component < b.component;
    return a.x != b.x ? a.x < b.x : a.y < b.y;
  });
  for (size_t i = 0; i < out.size(); ++i) out[i].stem_id = static_cast<int64_t>(i);
  return out;
}

}  // namespace dtif
