// The sparse Cholesky work estimate that picks the map merger's linear solver (core/merge).
#include "dtif/core/merge/factor_cost.h"

#include <gtest/gtest.h>

#include <cmath>

namespace dtif {
namespace {

using Edges = std::vector<std::pair<size_t, size_t>>;

TEST(FactorCost, AChainCostsNextToNothingAndACliqueItsCube) {
  Edges chain;
  for (size_t i = 1; i < 1000; ++i) chain.emplace_back(i - 1, i);
  // Eliminating a chain's end leaves one neighbour: one multiply-subtract per node.
  EXPECT_LE(choleskyMultiplies(1000, chain), 1000.0);
  Edges clique;
  const size_t n = 30;
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j) clique.emplace_back(i, j);
  }
  // Dense LDL': the k-th column updates d(d+1)/2 entries, d = n - 1 - k.
  EXPECT_DOUBLE_EQ(choleskyMultiplies(n, clique), (n - 1) * n * (n + 1) / 6.0);
  EXPECT_EQ(choleskyMultiplies(0, {}), 0.0);
}

// A map's first submap, or submaps joined by nothing yet: a diagonal factor, no work, and no
// error (AMD refuses a pattern without entries).
TEST(FactorCost, NodesWithoutEdgesCostNothing) {
  EXPECT_EQ(choleskyMultiplies(1, {}), 0.0);
  EXPECT_EQ(choleskyMultiplies(5, {{2, 2}}), 0.0);
}

TEST(FactorCost, SelfLoopsRepeatsAndOutOfRangeEdgesAreIgnored) {
  const Edges e{{0, 1}, {1, 0}, {1, 1}, {1, 2}, {2, 7}};
  EXPECT_EQ(choleskyMultiplies(3, e), choleskyMultiplies(3, {{0, 1}, {1, 2}}));
}

/// Six robots walking six laps of one circuit, 60 submaps a lap, every second submap with a
/// loop to one earlier pass at its place (loop closure answers with whichever earlier visit
/// matched best, so any pass: here a fixed pseudo-random one): the soak test's kind of survey.
/// Its factor is dense enough that the merger's default (direct_solver_max_work 1e6) switches
/// to conjugate gradients; the chains alone, or loops to the previous pass only, stay below.
TEST(FactorCost, LapsJoinedByLoopsExceedTheDirectSolversDefault) {
  const size_t per_lap = 60, laps = 6, robots = 6, passes = laps * robots;
  const size_t n = per_lap * passes;
  auto node = [&](size_t pass, size_t k) { return pass * per_lap + k; };
  Edges chains;
  for (size_t p = 0; p < passes; ++p) {
    for (size_t k = 0; k < per_lap; ++k) {
      if (k > 0 || p % laps != 0) chains.emplace_back(node(p, k) - 1, node(p, k));
    }
  }
  Edges previous = chains, any = chains;
  for (size_t p = 1; p < passes; ++p) {
    for (size_t k = 0; k < per_lap; k += 2) {
      previous.emplace_back(node(p, k), node(p - 1, k));
      any.emplace_back(node(p, k), node((7 * p + 3 * k) % p, k));
    }
  }
  EXPECT_LT(choleskyMultiplies(n, chains), 1e4);
  EXPECT_LT(choleskyMultiplies(n, previous), 1e6);
  EXPECT_GT(choleskyMultiplies(n, any), 1e6);
}

}  // namespace
}  // namespace dtif
