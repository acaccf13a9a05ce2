// Trunk centres in a grid of cells listing the trunks near them (see trunk_grid.h).
#include "dtif/core/verification/trunk_grid.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "dtif/core/cells.h"

namespace dtif {

namespace {
/// Cells per side at most: trunks spread wider (a malformed descriptor's trunks km apart) get
/// coarser cells, whose runs hold more trunks but never miss one.
constexpr double kMaxCellsPerSide = 2048.0;
}  // namespace

TrunkGrid::TrunkGrid(std::vector<Eigen::Vector2d> xy, double reach, double cells_per_trunk)
    : reach_(reach), cell_(reach), inv_cell_(1.0 / reach), by_index_(std::move(xy)) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  Eigen::Vector2d lo(kInf, kInf), hi(-kInf, -kInf);
  for (const Eigen::Vector2d& p : by_index_) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  const double span = (hi - lo).maxCoeff();
  if (by_index_.empty() || !std::isfinite(span) || !(reach > 0.0)) {
    by_index_.clear();  // no trunks, or none that a grid can hold: every lookup finds none
    return;
  }
  double cell = reach;
  if (cells_per_trunk > 0.0)
    cell =
        std::max(cell, span / std::sqrt(cells_per_trunk * static_cast<double>(by_index_.size())));
  cell = std::max(cell, span / kMaxCellsPerSide);
  cell_ = cell, inv_cell_ = 1.0 / cell;
  // Two empty margin cells below and above: a point outside the grid is then more than a
  // cell side from every trunk, whichever way the cell borders round.
  origin_ = lo - Eigen::Vector2d(2.0 * cell_, 2.0 * cell_);
  for (const Eigen::Vector2d& p : by_index_) {
    w_ = std::max(w_, cellOf(p.x() - origin_.x()) + 3);
    h_ = std::max(h_, cellOf(p.y() - origin_.y()) + 3);
  }
  listNeighbours(scanOrder());
}

// A product by the inverse may round a point across a cell border; the runs' margin covers
// that, as a trunk within reach of the point is then within reach + ulps of the cell.
int64_t TrunkGrid::cellOf(double v) const { return cellIndex(v * inv_cell_); }

std::vector<int> TrunkGrid::scanOrder() const {
  std::vector<std::pair<int64_t, int>> keyed;  // (cell, -index)
  keyed.reserve(by_index_.size());
  for (size_t j = 0; j < by_index_.size(); ++j) {
    const Eigen::Vector2d& p = by_index_[j];
    keyed.emplace_back(cellOf(p.y() - origin_.y()) * w_ + cellOf(p.x() - origin_.x()),
                       -static_cast<int>(j));
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<int> order;
  order.reserve(keyed.size());
  for (const auto& [cell, minus_j] : keyed) order.push_back(-minus_j);
  return order;
}

/// Lists, per cell, the trunks within reach (plus a margin) of its square, visiting the trunks
/// in scan order so that every run keeps it.
void TrunkGrid::listNeighbours(const std::vector<int>& order) {
  const double reach = reach_ * (1.0 + 1e-9) + 1e-9;
  const auto each_near = [&](const Eigen::Vector2d& p, auto&& visit) {
    const Eigen::Vector2d g = p - origin_;
    const int64_t cx = cellOf(g.x()), cy = cellOf(g.y());
    for (int64_t y = std::max<int64_t>(cy - 1, 0); y <= std::min(cy + 1, h_ - 1); ++y) {
      for (int64_t x = std::max<int64_t>(cx - 1, 0); x <= std::min(cx + 1, w_ - 1); ++x) {
        // Distance from p to the square [x, x + 1) x [y, y + 1) in cell sides.
        const double dx = std::max({x * cell_ - g.x(), g.x() - (x + 1) * cell_, 0.0});
        const double dy = std::max({y * cell_ - g.y(), g.y() - (y + 1) * cell_, 0.0});
        if (dx * dx + dy * dy <= reach * reach) visit(static_cast<size_t>(y * w_ + x));
      }
    }
  };
  // A counting sort: start_[k] counts cell k's run, then holds its end, and placing the
  // trunks backwards from the ends leaves it at the run's start.
  const size_t cells = static_cast<size_t>(w_ * h_);
  start_.assign(cells + 1, 0);
  for (const int j : order)
    each_near(by_index_[static_cast<size_t>(j)], [&](size_t k) { ++start_[k]; });
  for (size_t k = 1; k < cells; ++k) start_[k] += start_[k - 1];
  start_[cells] = start_[cells - 1];
  xy_.resize(static_cast<size_t>(start_[cells]));
  index_.resize(xy_.size());
  for (auto j = order.rbegin(); j != order.rend(); ++j) {
    each_near(by_index_[static_cast<size_t>(*j)], [&](size_t k) {
      const auto m = static_cast<size_t>(--start_[k]);
      xy_[m] = by_index_[static_cast<size_t>(*j)];
      index_[m] = *j;
    });
  }
}

}  // namespace dtif
