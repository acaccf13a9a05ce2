#include "dtif/core/merge/landmarks.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <unordered_map>

namespace dtif {
namespace {

struct Landmark {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double r_sum = 0.0;
  size_t last_submap = std::numeric_limits<size_t>::max();
  std::vector<size_t> members;
  Eigen::Vector2d centre() const { return sum.head<2>() / static_cast<double>(members.size()); }
  double radius() const { return r_sum / static_cast<double>(members.size()); }
};

/// Landmarks hashed by the grid cell (of the gate's size) of their first member: a centre moves
/// less than a cell, so the 3 x 3 cells around a query hold every landmark within the gate.
class LandmarkGrid {
 public:
  explicit LandmarkGrid(double cell) : cell_(cell) {}

  void insert(const Eigen::Vector2d& p, size_t landmark) {
    cells_[key(p, 0, 0)].push_back(landmark);
  }

  template <class F>
  void forNear(const Eigen::Vector2d& p, F&& f) const {
    for (int dx = -1; dx <= 1; ++dx) {
      for (int dy = -1; dy <= 1; ++dy) {
        auto it = cells_.find(key(p, dx, dy));
        if (it == cells_.end()) continue;
        for (size_t l : it->second) f(l);
      }
    }
  }

 private:
  int64_t key(const Eigen::Vector2d& p, int dx, int dy) const {
    const int64_t ix = static_cast<int64_t>(std::floor(p.x() / cell_)) + dx;
    const int64_t iy = static_cast<int64_t>(std::floor(p.y() / cell_)) + dy;
    return ix * 73856093LL ^ iy * 19349663LL;
  }

  double cell_;
  std::unordered_map<int64_t, std::vector<size_t>> cells_;
};

/// The nearest landmark to an observation within the gate, or none when there is none or a
/// second one within the gate too (ambiguous).
struct Nearest {
  size_t landmark = std::numeric_limits<size_t>::max();
  double distance = std::numeric_limits<double>::infinity();
  int within = 0;  ///< landmarks within the gate, of any radius
  bool ambiguous = false;
};

bool similarRadius(double r, double r_landmark, const LandmarkAssociationParams& p) {
  return std::fabs(r - r_landmark) <= std::max(p.radius_abs_tol_m, p.radius_rel_tol * r_landmark);
}

Nearest nearestLandmark(const LandmarkObservation& o, const std::vector<Landmark>& landmarks,
                        const LandmarkGrid& grid, const LandmarkAssociationParams& p) {
  Nearest best;
  const double gate = o.open_stand ? p.open_gate_m : p.gate_m;
  grid.forNear(o.p_M.head<2>(), [&](size_t l) {
    const double d = (landmarks[l].centre() - o.p_M.head<2>()).norm();
    if (d > gate) return;
    ++best.within;
    if (!similarRadius(o.r, landmarks[l].radius(), p)) return;
    if (d < best.distance || (d == best.distance && l < best.landmark)) {
      best.distance = d;
      best.landmark = l;
    }
  });
  best.ambiguous = best.within > 1;
  return best;
}

void addMember(Landmark* l, const LandmarkObservation& o, size_t index) {
  l->sum += o.p_M;
  l->r_sum += o.r;
  l->last_submap = o.submap;
  l->members.push_back(index);
}

/// Associates the observations [begin, end) of one submap with the landmarks so far.
void associateSubmap(const std::vector<LandmarkObservation>& obs, size_t begin, size_t end,
                     const LandmarkAssociationParams& p, std::vector<Landmark>* landmarks,
                     LandmarkGrid* grid) {
  std::vector<Nearest> near(end - begin);
  for (size_t i = begin; i < end; ++i)
    near[i - begin] = nearestLandmark(obs[i], *landmarks, *grid, p);
  // Mutual: the landmark's nearest observation of this submap.
  std::unordered_map<size_t, size_t> closest;  // landmark -> observation index
  for (size_t i = begin; i < end; ++i) {
    const Nearest& n = near[i - begin];
    if (n.ambiguous || n.landmark == std::numeric_limits<size_t>::max()) continue;
    auto [it, is_new] = closest.try_emplace(n.landmark, i);
    if (!is_new && n.distance < near[it->second - begin].distance) it->second = i;
  }
  for (size_t i = begin; i < end; ++i) {
    const Nearest& n = near[i - begin];
    if (n.ambiguous) continue;
    const bool matched = n.landmark != std::numeric_limits<size_t>::max();
    if (matched && closest.at(n.landmark) != i) continue;  // another of this submap's is nearer
    if (matched && (*landmarks)[n.landmark].last_submap != obs[i].submap) {
      addMember(&(*landmarks)[n.landmark], obs[i], i);
      continue;
    }
    // A landmark within the gate that did not match (another radius): not a new tree either.
    if (matched || n.within > 0) continue;
    landmarks->emplace_back();
    addMember(&landmarks->back(), obs[i], i);
    grid->insert(obs[i].p_M.head<2>(), landmarks->size() - 1);
  }
}

}  // namespace

std::vector<std::vector<size_t>> associateLandmarks(
    const std::vector<LandmarkObservation>& observations, const LandmarkAssociationParams& params) {
  std::vector<Landmark> landmarks;
  double cell = params.gate_m;  // the widest gate any observation uses
  for (const LandmarkObservation& o : observations) {
    if (o.open_stand) cell = std::max(cell, params.open_gate_m);
  }
  LandmarkGrid grid(cell);
  for (size_t begin = 0; begin < observations.size();) {
    size_t end = begin + 1;
    while (end < observations.size() && observations[end].submap == observations[begin].submap) {
      ++end;
    }
    associateSubmap(observations, begin, end, params, &landmarks, &grid);
    begin = end;
  }
  std::vector<std::vector<size_t>> out;
  for (Landmark& l : landmarks) {
    if (static_cast<int>(l.members.size()) >= params.min_observations) {
      out.push_back(std::move(l.members));
    }
  }
  return out;
}

}  // namespace dtif
