// Trunk centres in a grid of square cells, each cell listing the trunks near it: the
// verification's nearest-trunk lookups (lattice search, guided refinement) read one short run
// per lookup instead of searching 3 x 3 cells.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace dtif {

class TrunkGrid {
 public:
  /// The trunks within `reach` [m] of a cell's square, in the order a scan of its 3 x 3 cells
  /// would meet them (rows, then columns, then descending trunk index within a cell). Cells
  /// are never smaller than reach, so those 3 x 3 cells hold every such trunk.
  struct Run {
    const Eigen::Vector2d* xy = nullptr;
    const int* index = nullptr;
    int size = 0;
  };

  /// xy: trunk centres, indexed as given; reach > 0: the largest lookup radius [m], and the
  /// cell side. cells_per_trunk > 0 coarsens the cells to about that many per trunk over the
  /// trunks' extent (never below reach): a grid for a few hundred lookups then costs less to
  /// build than its lookups, at a few more trunks per run. 0: cells of side reach, for the
  /// ~10^5 lookups of a lattice search.
  TrunkGrid(std::vector<Eigen::Vector2d> xy, double reach, double cells_per_trunk = 0.0);

  /// Every trunk within `reach` of p, and possibly some farther ones.
  Run near(const Eigen::Vector2d& p) const {
    // In the grid, truncation is the floor; outside it (or NaN) no trunk is within reach.
    const double fx = (p.x() - origin_.x()) * inv_cell_, fy = (p.y() - origin_.y()) * inv_cell_;
    if (!(fx >= 0.0 && fy >= 0.0 && fx < static_cast<double>(w_) && fy < static_cast<double>(h_)))
      return {};
    const size_t k = static_cast<size_t>(fy) * static_cast<size_t>(w_) + static_cast<size_t>(fx);
    const int from = start_[k];
    return {xy_.data() + from, index_.data() + from, start_[k + 1] - from};
  }

  /// Squared distance from p to the nearest trunk within radius (<= reach), its index in
  /// *index; -1 and -1 when there is none. Of equal distances, the one later in near()'s run.
  double nearest2(const Eigen::Vector2d& p, double radius, int* index) const {
    *index = -1;
    const Run run = near(p);
    double best = radius * radius;
    int found = -1;
    for (int m = 0; m < run.size; ++m) {
      const double d = (run.xy[m] - p).squaredNorm();
      if (d <= best) best = d, found = m;
    }
    if (found < 0) return -1.0;
    *index = run.index[found];
    return best;
  }

  const Eigen::Vector2d& at(int j) const { return by_index_[static_cast<size_t>(j)]; }
  size_t size() const { return by_index_.size(); }

 private:
  int64_t cellOf(double v) const;
  std::vector<int> scanOrder() const;
  void listNeighbours(const std::vector<int>& order);

  double reach_, cell_, inv_cell_;
  Eigen::Vector2d origin_ = Eigen::Vector2d::Zero();
  int64_t w_ = 0, h_ = 0;
  std::vector<int> start_;                 // per cell its first run entry; one more for the end
  std::vector<Eigen::Vector2d> xy_;        // the runs' trunk centres
  std::vector<int> index_;                 // the runs' trunk indices
  std::vector<Eigen::Vector2d> by_index_;  // trunk centres by index
};

}  // namespace dtif
