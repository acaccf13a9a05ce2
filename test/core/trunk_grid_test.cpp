// The verification's nearest-trunk lookups: every cell's run holds each trunk within reach,
// also on cell borders and for trunks spread too wide for fine cells.
#include "dtif/core/verification/trunk_grid.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <vector>

namespace dtif {
namespace {

using P2 = Eigen::Vector2d;

std::vector<P2> randomTrunks(std::mt19937* rng, int n, double side) {
  std::uniform_real_distribution<double> u(-0.5 * side, 0.5 * side);
  std::vector<P2> xy;
  for (int i = 0; i < n; ++i) {
    const double x = u(*rng);
    xy.emplace_back(x, u(*rng));
  }
  return xy;
}

/// The indices in p's run; fails the test if a trunk within `reach` of p is missing.
void expectRunHoldsAllWithin(const TrunkGrid& grid, const std::vector<P2>& xy, const P2& p,
                             double reach) {
  const TrunkGrid::Run run = grid.near(p);
  std::set<int> listed;
  for (int m = 0; m < run.size; ++m) {
    listed.insert(run.index[m]);
    EXPECT_EQ(run.xy[m], xy[static_cast<size_t>(run.index[m])]);
  }
  for (size_t j = 0; j < xy.size(); ++j) {
    if ((xy[j] - p).norm() <= reach) {
      EXPECT_TRUE(listed.count(static_cast<int>(j)))
          << "trunk " << j << " missing near " << p.transpose();
    }
  }
}

/// Brute-force nearest trunk within radius (-1: none).
int nearestByScan(const std::vector<P2>& xy, const P2& p, double radius) {
  int best = -1;
  double d_best = radius * radius;
  for (size_t j = 0; j < xy.size(); ++j) {
    const double d = (xy[j] - p).squaredNorm();
    if (d <= d_best) d_best = d, best = static_cast<int>(j);
  }
  return best;
}

TEST(TrunkGrid, RunsHoldEveryTrunkWithinReachAndNearestMatchesAScan) {
  std::mt19937 rng(7);
  const double reach = 0.4;
  const std::vector<P2> xy = randomTrunks(&rng, 400, 40.0);
  std::uniform_real_distribution<double> u(-21.0, 21.0), near(-0.45, 0.45);
  // Cells of side reach (lattice search), and coarser ones (~4 per trunk: 1 m here).
  for (const double cells_per_trunk : {0.0, 4.0}) {
    const TrunkGrid grid(xy, reach, cells_per_trunk);
    ASSERT_EQ(grid.size(), xy.size());
    for (int k = 0; k < 4000; ++k) {
      // Half the probes close to a trunk, so that most lookups find one.
      const P2 p = k % 2 ? P2(u(rng), u(rng))
                         : xy[static_cast<size_t>(k) % xy.size()] + P2(near(rng), near(rng));
      expectRunHoldsAllWithin(grid, xy, p, reach);
      for (const double radius : {reach, 0.25}) {
        int j = -2;
        const double d2 = grid.nearest2(p, radius, &j);
        ASSERT_EQ(j, nearestByScan(xy, p, radius));
        EXPECT_EQ(d2, j >= 0 ? (xy[static_cast<size_t>(j)] - p).squaredNorm() : -1.0);
      }
    }
  }
}

TEST(TrunkGrid, ProbesOnCellBordersFindTrunksAtTheReach) {
  // Trunks and probes on multiples of the cell side, and one float step either side of them:
  // where a product by the cell's inverse may round a point into the neighbouring cell.
  const double reach = 0.4;
  std::vector<P2> xy;
  for (int i = 0; i < 6; ++i)
    for (int k = 0; k < 6; ++k) xy.emplace_back(i * reach, k * 1.3 * reach);
  for (const double cells_per_trunk : {0.0, 1.0}) {
    const TrunkGrid grid(xy, reach, cells_per_trunk);
    for (const P2& t : xy) {
      for (const double dx : {-reach, -0.5 * reach, 0.0, 0.5 * reach, reach}) {
        for (const double dir : {-1.0, 0.0, 1.0}) {
          P2 p = t + P2(dx, 0.0);
          p.x() = std::nextafter(p.x(), p.x() + dir);
          expectRunHoldsAllWithin(grid, xy, p, reach);
          p = t + P2(0.0, dx);
          p.y() = std::nextafter(p.y(), p.y() + dir);
          expectRunHoldsAllWithin(grid, xy, p, reach);
        }
      }
    }
  }
}

TEST(TrunkGrid, TrunksSpreadFarApartGetCoarserCellsAndAreStillFound) {
  // 10^7 m across at 0.4 m would be 6e14 cells: the grid coarsens instead.
  const std::vector<P2> xy = {P2(-5e6, 0.0), P2(5e6, 1.0), P2(5e6 + 0.3, 1.0), P2(0.0, -5e6)};
  const TrunkGrid grid(xy, 0.4);
  for (size_t j = 0; j < xy.size(); ++j) {
    int found = -1;
    grid.nearest2(xy[j] + P2(0.01, 0.0), 0.4, &found);
    EXPECT_EQ(found, static_cast<int>(j));
    expectRunHoldsAllWithin(grid, xy, xy[j] + P2(0.2, 0.0), 0.4);
  }
}

TEST(TrunkGrid, NoTrunksOrNonFiniteProbesFindNothing) {
  int j = 0;
  const TrunkGrid empty({}, 0.4);
  EXPECT_EQ(empty.nearest2(P2(0.0, 0.0), 0.4, &j), -1.0);
  EXPECT_EQ(j, -1);
  EXPECT_EQ(empty.near(P2(0.0, 0.0)).size, 0);
  const TrunkGrid grid({P2(1.0, 1.0)}, 0.4);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const P2& p : {P2(nan, 1.0), P2(1.0, nan), P2(inf, 1.0), P2(-inf, 1.0), P2(1e300, -1e300)}) {
    EXPECT_EQ(grid.nearest2(p, 0.4, &j), -1.0);
    EXPECT_EQ(j, -1);
  }
  EXPECT_EQ(grid.nearest2(P2(1.25, 1.0), 0.4, &j), 0.25 * 0.25);
  EXPECT_EQ(j, 0);
  // Trunks whose spread overflows a double: no grid can hold them, so none is found (a
  // received descriptor's trunks are finite, but nothing bounds their spread).
  const TrunkGrid overflow({P2(-1e308, 0.0), P2(1e308, 0.0)}, 0.4);
  EXPECT_EQ(overflow.nearest2(P2(1e308, 0.0), 0.4, &j), -1.0);
}

}  // namespace
}  // namespace dtif
