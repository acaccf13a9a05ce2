#include "dtif/core/merge/stem_inventory.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>
#include <unordered_map>

#include "dtif/core/cells.h"

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

MergedStem fuse(const std::vector<StemObservation>& obs, const Cluster& cl, int component) {
  std::vector<double> xs, ys, zs_seen, zs_all, rs;
  for (size_t i : cl.members) {
    const StemObservation& o = obs[i];
    xs.push_back(o.x);
    ys.push_back(o.y);
    rs.push_back(o.r);
    zs_all.push_back(o.z);
    if (o.base_seen) zs_seen.push_back(o.z);
  }
  MergedStem s;
  s.component = component;
  s.x = median(xs);
  s.y = median(ys);
  s.z_base = median(zs_seen.empty() ? zs_all : zs_seen);
  s.dbh = 2.0 * median(rs);
  s.observations = static_cast<int>(cl.submaps.size());
  return s;
}

}  // namespace

std::string StemFusionParams::validate() const {
  std::ostringstream e;
  if (!(cluster_radius_m > 0)) e << "stems.cluster_radius_m must be > 0; ";
  if (!(radius_rel_tol >= 0)) e << "stems.radius_rel_tol must be >= 0; ";
  if (!(radius_abs_tol_m >= 0)) e << "stems.radius_abs_tol_m must be >= 0; ";
  if (min_observations < 1) e << "stems.min_observations must be >= 1; ";
  return e.str();
}

std::vector<MergedStem> fuseStems(const std::vector<StemObservation>& observations,
                                  const StemFusionParams& params) {
  std::map<int, std::vector<size_t>> by_component;
  for (size_t i = 0; i < observations.size(); ++i) {
    const StemObservation& o = observations[i];
    if (std::isfinite(o.x) && std::isfinite(o.y) && std::isfinite(o.z) && std::isfinite(o.r)) {
      by_component[o.component].push_back(i);
    }
  }
  std::vector<MergedStem> out;
  for (const auto& [component, idx] : by_component) {
    Clusterer clusterer(observations, params);
    for (size_t i : idx) clusterer.add(i);
    clusterer.joinClose();
    std::vector<MergedStem> stems;
    for (const Cluster& cl : clusterer.clusters()) {
      if (static_cast<int>(cl.submaps.size()) < params.min_observations) continue;
      stems.push_back(fuse(observations, cl, component));
    }
    std::sort(stems.begin(), stems.end(), [](const MergedStem& a, const MergedStem& b) {
      return a.x != b.x ? a.x < b.x : a.y < b.y;
    });
    out.insert(out.end(), stems.begin(), stems.end());
  }
  for (size_t i = 0; i < out.size(); ++i) out[i].stem_id = static_cast<int64_t>(i);
  return out;
}

}  // namespace dtif
