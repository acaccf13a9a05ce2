// The AVX2 forms of extraction's per-point passes (avx2.h) against their baseline forms, bit for
// bit, on fixed-seed adversarial inputs: points on cell edges, negative coordinates, sizes that
// are no multiple of the lane count, tiny clouds, non-finite points. Skipped on a CPU without
// AVX2 (then both runs would take the baseline form).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "dtif/core/extraction/avx2.h"
#include "dtif/core/extraction/extraction_stages.h"
#include "dtif/core/extraction/trunk_extractor.h"

namespace dtif {
namespace {

// Runs f() with the AVX2 forms forbidden, then allowed (restored on exit).
template <class F>
void bothForms(F f) {
  allowAvx2(false);
  f(false);
  allowAvx2(true);
  f(true);
}

template <class T>
bool sameBits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() &&
         (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

// n local points: a sloped, bumpy ground over [0, 9)^2 with stems' worth of points up to 4 m,
// every third point moved onto an edge of the 0.25 m grid (ground cells, sub-columns and map
// cells of 0.5 m all share those edges), in runs of one cell and scattered.
LocalPoints adversarialPoints(size_t n, uint32_t seed, double ox) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 9.0), uh(0.0, 4.0), near(-0.2, 0.2);
  std::uniform_int_distribution<int> kind(0, 5);
  LocalPoints pts;
  pts.ox = ox, pts.oy = -ox, pts.oz = 3.0;
  double x = u(rng), y = u(rng);
  for (size_t i = 0; i < n; ++i) {
    const int k = kind(rng);
    if (k == 0) x = u(rng), y = u(rng);  // anywhere
    if (k == 1 || k == 2)
      x = std::clamp(x + near(rng), 0.0, 9.0), y = std::clamp(y + near(rng), 0.0, 9.0);  // a run
    double px = x, py = y;
    if (k >= 3) px = 0.25 * std::round(x * 4.0), py = 0.25 * std::round(y * 4.0);  // on edges
    const double ground = 0.3 * px - 0.2 * py + 0.05 * std::sin(3.0 * px);
    const double z = ground + (k == 5 ? uh(rng) : 0.02 * near(rng));
    pts.x.push_back(static_cast<float>(px));
    pts.y.push_back(static_cast<float>(py));
    pts.z.push_back(static_cast<float>(z));
  }
  return pts;
}

// heightsAndSlab with and without the map cells, both forms; equal bits everywhere.
void expectSameHeights(const LocalPoints& pts, const TrunkExtractorParams& p) {
  const GroundGrid grid = estimateLocalGround(pts, p);
  std::vector<float> h[2], hm[2];
  std::vector<uint32_t> slab[2], slabm[2];
  GroundMapCells mc[2];
  bothForms([&](bool avx2) {
    heightsAndSlab(pts, grid, p, &h[avx2], &slab[avx2]);
    ASSERT_TRUE(mc[avx2].init(pts, p.ground_map_cell_m, 100.0));
    heightsAndSlab(pts, grid, p, &hm[avx2], &slabm[avx2], &mc[avx2]);
  });
  EXPECT_TRUE(sameBits(h[0], h[1]));
  EXPECT_TRUE(sameBits(hm[0], h[1]));
  EXPECT_TRUE(sameBits(hm[0], hm[1]));
  EXPECT_EQ(slab[0], slab[1]);
  EXPECT_EQ(slabm[0], slabm[1]);
  EXPECT_EQ(mc[0].used, mc[1].used);
  EXPECT_TRUE(sameBits(mc[0].low, mc[1].low));
  EXPECT_EQ(mc[0].hits, mc[1].hits);
}

TEST(Avx2Paths, HeightsAndSlabGiveTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  TrunkExtractorParams p;
  p.min_fit_points = 3;
  // Power-of-two cells (multiplied) and others (divided), map cells in negative coordinates.
  const double cells[][2] = {{1.0, 0.5}, {0.7, 0.3}, {2.0, 0.25}};
  for (const auto& c : cells) {
    p.ground_cell_m = c[0], p.ground_map_cell_m = c[1], p.ground_sub_cell_m = 0.25 * c[0];
    for (size_t n : {1, 2, 3, 4, 5, 7, 8, 9, 15, 17, 1000, 20001}) {
      for (double ox : {0.0, -4.0, 1000.5}) {
        SCOPED_TRACE(testing::Message() << "cell " << c[0] << " n " << n << " ox " << ox);
        expectSameHeights(adversarialPoints(n, static_cast<uint32_t>(n), ox), p);
      }
    }
  }
}

// binGroundGrid with and without AVX2: the same counts and the same points in the same order.
TEST(Avx2Paths, GroundGridBinsGiveTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  TrunkExtractorParams p;
  for (double cell : {1.0, 0.7}) {
    p.ground_cell_m = cell;
    for (size_t n : {1, 7, 8, 9, 16, 23, 1000, 20003}) {
      SCOPED_TRACE(testing::Message() << "cell " << cell << " n " << n);
      const LocalPoints pts = adversarialPoints(n, static_cast<uint32_t>(n + 7), 0.0);
      GroundGrid grid[2];
      bothForms([&](bool avx2) { binGroundGrid(pts, p, &grid[avx2]); });
      EXPECT_EQ(grid[0].start, grid[1].start);
      ASSERT_EQ(grid[0].sorted.size(), grid[1].sorted.size());
      EXPECT_EQ(std::memcmp(grid[0].sorted.data(), grid[1].sorted.data(),
                            grid[0].sorted.size() * sizeof(GroundGrid::SortedPoint)),
                0);
    }
  }
}

}  // namespace
}  // namespace dtif
