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
    // Zeros of both signs: the lowest points' joins must keep the sign the one chain keeps.
    pts.z.push_back(i % 13 == 0 ? (i % 2 ? 0.0f : -0.0f) : static_cast<float>(z));
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

// n points in runs of one of 8 x 8 map cells of 0.5 m (1..9 points, often a cell just left, so a
// change may fall in any lane); a run's first z often above zero, then zeros of both signs among
// a few values, nothing below zero in every other cell, so many cells' lowest point is a zero
// met with both signs after their first point; with nan, NaN z here and there.
LocalPoints runsOfCells(size_t n, uint32_t seed, bool nan) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> step(0, 3), len(1, 9), pick(0, 7);
  const float first[] = {0.25f, 1.5f, 0.0f, -0.0f};
  const float rest[] = {0.0f,  -0.0f, 0.0f,   -0.0f,
                        0.25f, 1.5f,  -0.25f, nan ? std::numeric_limits<float>::quiet_NaN() : 0.0f};
  LocalPoints pts;
  int c = 0;
  while (pts.size() < n) {
    c = (c + step(rng)) % 64;
    const bool low_run = c % 2 == 0;
    const int size = len(rng);
    for (int k = 0; k < size && pts.size() < n; ++k) {
      const int z = pick(rng);
      pts.x.push_back(0.5f * static_cast<float>(c % 8) + 0.1f * static_cast<float>(k % 4));
      pts.y.push_back(0.5f * static_cast<float>(c / 8) + 0.125f);
      pts.z.push_back(k == 0 ? first[z % 4] : low_run && z == 6 ? 0.25f : rest[z]);
    }
  }
  return pts;
}

// heightsAndSlab's map cells over runsOfCells, both forms: the same lowest points bit for bit
// (the sign of a zero too) and counts; with part of the points outside the cells (npos).
TEST(Avx2Paths, MapCellRunsGiveTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  TrunkExtractorParams p;
  p.min_fit_points = 3, p.ground_cell_m = 1.0, p.ground_map_cell_m = 0.5;
  size_t zeros = 0;
  for (bool nan : {false, true}) {
    for (size_t n : {1, 3, 4, 5, 7, 8, 9, 13, 31, 32, 33, 1001, 4099}) {
      SCOPED_TRACE(testing::Message() << "n " << n << " nan " << nan);
      LocalPoints pts = runsOfCells(n, static_cast<uint32_t>(n), nan);
      expectSameHeights(pts, p);
      pts.has_extent = true;  // the cells of x < 2 alone: the others are npos
      pts.minx = 0.0f, pts.maxx = 1.9f, pts.miny = 0.0f, pts.maxy = 4.0f;
      expectSameHeights(pts, p);
      GroundMapCells mc;
      std::vector<float> h;
      std::vector<uint32_t> slab;
      pts.has_extent = false;
      ASSERT_TRUE(mc.init(pts, p.ground_map_cell_m, 100.0));
      heightsAndSlab(pts, estimateLocalGround(pts, p), p, &h, &slab, &mc);
      for (float low : mc.low) zeros += low == 0.0f && std::signbit(low);
    }
  }
  EXPECT_GT(zeros, 20u);  // runs whose lowest point is -0: the sign was tested
}

// n slab points for columnsOfSlab at cells of cs: every other point on a cell's edge (x / cs a
// whole number or a float's step off it), negative coordinates and -0, runs of one column,
// heights on the layers' edges (up to 7 layers above the slab: the last layer's), with far
// (beyond int32 cells of cs) every 37th point; the slab every point but each fifth.
struct SlabInput {
  LocalPoints pts;
  std::vector<float> h;
  std::vector<uint32_t> slab;
};
SlabInput slabInput(size_t n, uint32_t seed, double cs, const TrunkExtractorParams& p, bool far) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-3.0, 3.0), uh(p.slab_min_h_m, p.slab_max_h_m);
  std::uniform_int_distribution<int> kind(0, 5), cell(-20, 20), layer(0, 20);
  SlabInput in;
  float x = 0.0f, y = 0.0f;
  for (size_t i = 0; i < n; ++i) {
    const int k = kind(rng);
    if (k == 0 || k == 1) x = static_cast<float>(u(rng)), y = static_cast<float>(u(rng));
    if (k == 2 || k == 3) {  // on an edge, or a step either side of it
      x = static_cast<float>(cell(rng) * cs), y = static_cast<float>(cell(rng) * cs);
      if (k == 3) x = std::nextafter(x, -1.0f), y = std::nextafter(y, 1.0f);
    }
    if (k == 4) x = -0.0f;
    if (far && i % 37 == 5) x = 4e8f, y = -3e9f;
    in.pts.x.push_back(x), in.pts.y.push_back(y);
    const double edge = p.slab_min_h_m + layer(rng) * p.layer_h_m;
    in.h.push_back(static_cast<float>(k == 5 ? uh(rng) : edge));
    if (i % 5 != 4) in.slab.push_back(static_cast<uint32_t>(i));
  }
  return in;
}

// Returns the columns that pass (the comparison covered something).
size_t expectSameColumns(const SlabInput& in, const TrunkExtractorParams& p) {
  VoxelColumns cols[2];
  bothForms([&](bool avx2) {
    cols[avx2].slab = in.slab;
    columnsOfSlab(in.pts, in.h, p, &cols[avx2]);
  });
  EXPECT_EQ(cols[0].slab_col, cols[1].slab_col);
  EXPECT_EQ(cols[0].ix, cols[1].ix);
  EXPECT_EQ(cols[0].iy, cols[1].iy);
  EXPECT_EQ(cols[0].count, cols[1].count);
  EXPECT_EQ(cols[0].mask, cols[1].mask);
  EXPECT_EQ(cols[0].pass, cols[1].pass);
  EXPECT_EQ(cols[0].passing, cols[1].passing);
  EXPECT_EQ(cols[0].grid, cols[1].grid);
  EXPECT_EQ(cols[0].gx0, cols[1].gx0);
  EXPECT_EQ(cols[0].gy0, cols[1].gy0);
  EXPECT_EQ(cols[0].gw, cols[1].gw);
  EXPECT_EQ(cols[0].gh, cols[1].gh);
  return cols[1].passing;
}

// columnsOfSlab with and without AVX2 (cells and layers four at a time): the same columns, on
// dense grids and on the hash (far points), at three column sizes.
TEST(Avx2Paths, SlabColumnsGiveTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  TrunkExtractorParams p;
  p.min_column_points = 3;
  size_t passing = 0;
  for (double cs : {0.15, 0.125, 0.07}) {
    p.column_cell_m = cs;
    for (bool far : {false, true}) {
      for (size_t n : {1, 3, 4, 5, 6, 7, 9, 13, 1000, 4099}) {
        SCOPED_TRACE(testing::Message() << "cs " << cs << " far " << far << " n " << n);
        passing += expectSameColumns(slabInput(n, static_cast<uint32_t>(n), cs, p, far), p);
      }
    }
  }
  EXPECT_GT(passing, 100u);
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

// n points on a 0.125 m lattice over [0, 3)^2 at heights whose differences are exactly 0.25 m
// and 1.5 m (the open test's bounds in GroundCellsGiveTheBaselineBits).
LocalPoints steppedPoints(size_t n) {
  const float heights[] = {1.0f, 1.25f, 2.5f, 1.5f, 3.0f, 1.0625f};
  LocalPoints pts;
  for (size_t i = 0; i < n; ++i) {
    pts.x.push_back(0.125f * static_cast<float>(i % 24));
    pts.y.push_back(0.125f * static_cast<float>((i / 24) % 24));
    pts.z.push_back(heights[(i * 7) % 6]);
  }
  return pts;
}

void expectSameGroundCells(const LocalPoints& pts, const GroundGrid& grid,
                           const TrunkExtractorParams& p) {
  GroundCells cells[2];
  bothForms([&](bool avx2) { cells[avx2] = openGroundCells(pts, grid, p); });
  EXPECT_TRUE(sameBits(cells[0].low, cells[1].low));
  EXPECT_TRUE(sameBits(cells[0].min, cells[1].min));
  EXPECT_EQ(cells[0].count, cells[1].count);
  EXPECT_EQ(cells[0].any, cells[1].any);
}

// openGroundCells with and without AVX2 (at most 32 sub-columns: 16, 25 and 9; beyond, 100, both
// the baseline): the same cells, bit for bit.
TEST(Avx2Paths, GroundCellsGiveTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  TrunkExtractorParams p;
  const double cells[][2] = {{1.0, 0.25}, {1.0, 0.2}, {0.7, 0.25}, {1.0, 0.1}};
  for (const auto& c : cells) {
    p.ground_cell_m = c[0], p.ground_sub_cell_m = c[1];
    for (size_t n : {1, 3, 4, 5, 9, 1000, 20003}) {
      SCOPED_TRACE(testing::Message() << "cell " << c[0] << " sub " << c[1] << " n " << n);
      const LocalPoints pts = adversarialPoints(n, static_cast<uint32_t>(n + 11), 0.0);
      const GroundGrid grid = binGroundGrid(pts, p);
      expectSameGroundCells(pts, grid, p);
      TrunkExtractorParams q = p;
      q.ground_open_gap_m = 0.25, q.ground_open_top_m = 1.5;  // floats: dz may equal them
      const LocalPoints steps = steppedPoints(n);
      expectSameGroundCells(steps, binGroundGrid(steps, q), q);
    }
  }
}

// A small plot in S: sloped ground, stems, and shrubs, every fifth point on a whole metre (the
// footprint's tiles and cells, the floors' edges), offset to (off_x, off_y); non-finite points
// at the given places; size points in all.
Cloud plotCloud(size_t size, double off_x, double off_y, const std::vector<size_t>& bad) {
  std::mt19937 rng(static_cast<uint32_t>(size));
  std::uniform_real_distribution<double> u(-8.0, 8.0), uh(0.0, 5.0), ua(0.0, 6.2832);
  std::uniform_int_distribution<int> kind(0, 9);
  const double stems[][3] = {
      {-3.0, 2.0, 0.2}, {2.5, -1.5, 0.3}, {4.0, 4.0, 0.15}, {-5.0, -5.0, 0.25}};
  Cloud cloud;
  for (size_t i = 0; i < size; ++i) {
    double x = u(rng), y = u(rng), h = 0.01 * u(rng);
    const int k = kind(rng);
    if (k < 4) {  // bark
      const double a = ua(rng);
      x = stems[k][0] + stems[k][2] * std::cos(a), y = stems[k][1] + stems[k][2] * std::sin(a);
      h = uh(rng);
    } else if (k == 4) {
      x = std::round(x), y = std::round(y), h = std::round(uh(rng) * 4.0) / 4.0;
    } else if (k == 5) {
      h = uh(rng) * 0.5;  // shrubs
    }
    const double z = 0.2 * x - 0.1 * y + h;
    cloud.push_back(pcl::PointXYZ(static_cast<float>(x + off_x), static_cast<float>(y + off_y),
                                  static_cast<float>(z)));
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  for (size_t j = 0; j < bad.size(); ++j) {
    if (bad[j] >= cloud.size()) continue;
    pcl::PointXYZ& q = cloud[bad[j]];
    (j % 3 == 0 ? q.x : j % 3 == 1 ? q.y : q.z) = j % 2 ? nan : -inf;
  }
  return cloud;
}

// Trunks and ground map cells found (the comparison covered something).
size_t expectSameExtraction(const Cloud& cloud, const TrunkExtractorParams& p) {
  TrunkExtractionResult r[2];
  bothForms([&](bool avx2) { r[avx2] = extractTrunks(cloud, p, nullptr); });
  EXPECT_EQ(r[0].trunks.size(), r[1].trunks.size());
  if (r[0].trunks.size() != r[1].trunks.size()) return 0;
  for (size_t t = 0; t < r[0].trunks.size(); ++t) {
    const TrunkLandmark &a = r[0].trunks[t], &b = r[1].trunks[t];
    const double va[] = {a.x, a.y, a.z, a.r}, vb[] = {b.x, b.y, b.z, b.r};
    EXPECT_EQ(std::memcmp(va, vb, sizeof(va)), 0) << "trunk " << t;
    EXPECT_EQ(a.base_seen, b.base_seen) << "trunk " << t;
  }
  EXPECT_EQ(r[0].footprint.cell_m, r[1].footprint.cell_m);
  EXPECT_EQ(r[0].footprint.x0, r[1].footprint.x0);
  EXPECT_EQ(r[0].footprint.y0, r[1].footprint.y0);
  EXPECT_EQ(r[0].footprint.width, r[1].footprint.width);
  EXPECT_EQ(r[0].footprint.bits, r[1].footprint.bits);
  EXPECT_EQ(encodeGroundMap(r[0].ground_map), encodeGroundMap(r[1].ground_map));
  EXPECT_EQ(r[0].stats.finite_points, r[1].stats.finite_points);
  EXPECT_EQ(r[0].stats.candidate_columns, r[1].stats.candidate_columns);
  EXPECT_EQ(r[0].stats.candidates, r[1].stats.candidates);
  return r[1].trunks.size() + r[1].ground_map.count();
}

// firstPass (local points, extent, footprint marks) with and without AVX2, on clouds with
// non-finite and absurd points in and out of eight-point blocks: the same bits.
// Returns the cells marked (the comparison covered something).
size_t expectSameFirstPass(const Cloud& cloud, double cell_m, double range_m) {
  const PointBounds b = pointBounds(cloud, range_m);
  std::vector<float> sx, sy, sz;
  for (size_t i = 0; i < cloud.size(); i += 7) {
    const pcl::PointXYZ& q = cloud[i];
    if (std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z))
      sx.push_back(q.x), sy.push_back(q.y), sz.push_back(q.z);
  }
  const Eigen::Vector2d half = Eigen::Vector2d::Constant(b.half_side_m);
  LocalPoints pts[2];
  HeightCellMarks marks[2];
  bool ok[2], marked[2];
  size_t finite[2];
  bothForms([&](bool avx2) {
    marked[avx2] =
        marks[avx2].init(sx, sy, sz, cell_m, b.centre.head<2>() - half, b.centre.head<2>() + half);
    ok[avx2] =
        firstPass(cloud, b, &pts[avx2], marked[avx2] ? &marks[avx2] : nullptr, &finite[avx2]);
  });
  EXPECT_EQ(ok[0], ok[1]);
  EXPECT_TRUE(ok[0]);
  if (!ok[0] || !ok[1]) return 0;
  EXPECT_EQ(finite[0], finite[1]);
  EXPECT_TRUE(sameBits(pts[0].x, pts[1].x));
  EXPECT_TRUE(sameBits(pts[0].y, pts[1].y));
  EXPECT_TRUE(sameBits(pts[0].z, pts[1].z));
  EXPECT_EQ(pts[0].ox, pts[1].ox);
  EXPECT_EQ(pts[0].oy, pts[1].oy);
  EXPECT_EQ(pts[0].oz, pts[1].oz);
  // The extent's values (the lanes' minima may pick another sign of a zero, as SSE2's do).
  EXPECT_EQ(pts[0].minx, pts[1].minx);
  EXPECT_EQ(pts[0].maxx, pts[1].maxx);
  EXPECT_EQ(pts[0].miny, pts[1].miny);
  EXPECT_EQ(pts[0].maxy, pts[1].maxy);
  EXPECT_EQ(marked[0], marked[1]);
  if (!marked[0] || !marked[1]) return 0;
  EXPECT_EQ(marks[0].complete(), marks[1].complete());
  EXPECT_EQ(marks[0].cells(), marks[1].cells());
  return marks[1].cells().size();
}

TEST(Avx2Paths, FirstPassGivesTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  const std::vector<size_t> none, some = {0, 5, 8, 13, 100, 101, 102, 103, 777, 4095};
  size_t marked = 0;
  for (size_t size : {1, 7, 8, 9, 15, 16, 17, 4000, 30001}) {
    for (double cell : {1.0, 2.0, 0.75}) {
      for (const auto* bad : {&none, &some}) {
        SCOPED_TRACE(testing::Message()
                     << "size " << size << " cell " << cell << " bad " << bad->size());
        Cloud cloud = plotCloud(size, -7.0, 3.0, *bad);
        marked += expectSameFirstPass(cloud, cell, 200.0);
        // An absurd point (|z| > 1e8 m) inside the bounds: no local point (and no marks: the
        // box is too far out for them).
        cloud[size / 2].z = 2e8f;
        expectSameFirstPass(cloud, cell, 3e8);
      }
    }
  }
  EXPECT_GT(marked, 1000u);
}

// The whole extraction with and without AVX2 (the first pass eight points at a time and the
// footprint's marks, the ground grid, the heights, the stem bases' rings): the same trunks,
// footprint and ground map, bit for bit, with non-finite points anywhere and sizes that are no
// multiple of eight.
TEST(Avx2Paths, ExtractionGivesTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  TrunkExtractorParams p;
  p.ground_map_below_seen = 1.01;  // a ground map whenever there are trunks
  const std::vector<size_t> none, some = {0, 5, 8, 13, 100, 101, 102, 103, 777, 4095};
  size_t found = 0;
  for (size_t size : {3, 9, 17, 4000, 30001, 60008}) {
    for (const auto& off :
         {std::make_pair(0.0, 0.0), std::make_pair(-7.0, 3.0), std::make_pair(1234.0, -5678.0)}) {
      for (const auto* bad : {&none, &some}) {
        SCOPED_TRACE(testing::Message()
                     << "size " << size << " off " << off.first << " bad " << bad->size());
        found += expectSameExtraction(plotCloud(size, off.first, off.second, *bad), p);
      }
    }
  }
  p.footprint_cell_m = 0.75;  // footprint cells not of 2^k m: add8 lane by lane
  found += expectSameExtraction(plotCloud(30001, -7.0, 3.0, none), p);
  EXPECT_GT(found, 1000u);
}

// Band points of one stem slice: an arc of `arc` radians of a circle of radius r about (cx, cy),
// with cm noise, plus clutter; some points exactly on the circle's centre and duplicated.
std::vector<Eigen::Vector2d> slicePoints(size_t n, double arc, double r, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> a(0.0, arc), noise(-0.01, 0.01), clutter(-0.6, 0.6);
  const double cx = 3.25, cy = -1.5;
  std::vector<Eigen::Vector2d> xy;
  for (size_t i = 0; i < n; ++i) {
    const double t = a(rng);
    if (i % 7 == 3) {
      xy.emplace_back(cx + clutter(rng), cy + clutter(rng));  // undergrowth
    } else if (i % 29 == 5) {
      xy.emplace_back(cx, cy);  // d = 0: a point the refinement skips
    } else if (i % 31 == 9 && !xy.empty()) {
      xy.push_back(xy.back());  // a repeated return
    } else {
      xy.emplace_back(cx + (r + noise(rng)) * std::cos(t), cy + (r + noise(rng)) * std::sin(t));
    }
  }
  return xy;
}

// The circle fit with and without AVX2 (RANSAC's scoring, the refinement's point terms and its
// gathering of the near points): the same circle, evidence and inliers, bit for bit.
TEST(Avx2Paths, CircleFitGivesTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  CircleFitParams cfp;
  cfp.min_radius_m = 0.03, cfp.max_radius_m = 0.8;
  size_t ok = 0;
  for (size_t n : {3, 5, 7, 33, 130, 401, 1203}) {
    for (double arc : {0.7, 2.0, 6.3}) {
      for (double r : {0.05, 0.2, 0.45}) {
        const std::vector<Eigen::Vector2d> xy = slicePoints(n, arc, r, static_cast<uint32_t>(n));
        cfp.seed = static_cast<uint32_t>(n * 7 + 1);
        CircleFit fit[2];
        bothForms([&](bool avx2) { fit[avx2] = fitCircleRobust(xy, cfp); });
        SCOPED_TRACE(testing::Message() << "n " << n << " arc " << arc << " r " << r);
        EXPECT_EQ(fit[0].ok, fit[1].ok);
        for (const auto& [a, b] :
             {std::make_pair(fit[0].cx, fit[1].cx), std::make_pair(fit[0].cy, fit[1].cy),
              std::make_pair(fit[0].r, fit[1].r), std::make_pair(fit[0].rms_m, fit[1].rms_m),
              std::make_pair(fit[0].arc_deg, fit[1].arc_deg),
              std::make_pair(fit[0].inlier_ratio, fit[1].inlier_ratio)}) {
          EXPECT_EQ(std::memcmp(&a, &b, sizeof(a)), 0) << a << " vs " << b;
        }
        EXPECT_EQ(fit[0].inliers, fit[1].inliers);
        EXPECT_TRUE(sameBits(fit[0].is_inlier, fit[1].is_inlier));
        ok += fit[1].ok;
      }
    }
  }
  EXPECT_GT(ok, 30u);  // most slices give a circle: the refinement ran on them
}

// The robust ground plane with and without AVX2 (its reweighting four points at a time): the
// same plane, bit for bit, with points far above and below it (weight 0), zero and partial
// weights, residuals exactly at the Tukey constants, and sizes that are no multiple of four.
TEST(Avx2Paths, GroundPlaneGivesTheBaselineBits) {
  if (!useAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-3.0, 3.0), noise(-0.05, 0.05);
  std::uniform_int_distribution<int> kind(0, 9);
  size_t fits = 0;
  for (size_t n : {1, 3, 4, 5, 9, 25, 49, 50, 121, 503}) {
    std::vector<double> x, y, z, w0;
    for (size_t i = 0; i < n; ++i) {
      x.push_back(u(rng)), y.push_back(u(rng));
      const int k = kind(rng);
      const double ground = 2.0 + 0.3 * x.back() - 0.1 * y.back();
      double zi = ground + noise(rng);
      if (k == 0) zi = ground + 1.5;  // a shrub: beyond c_up
      if (k == 1) zi = ground - 2.0;  // a pit: beyond c_down
      if (k == 2) zi = ground + 0.3;  // at c_up from the true plane
      z.push_back(zi);
      w0.push_back(k == 3 ? 0.0 : (k == 4 ? 0.3 : 1.0));
    }
    for (int iterations : {0, 1, 5}) {
      GroundPlane pl[2];
      bothForms([&](bool avx2) {
        pl[avx2] = fitGroundPlane(x.data(), y.data(), z.data(), w0.data(), n, 0.25, -0.5, 0.3, 1.0,
                                  iterations);
      });
      SCOPED_TRACE(testing::Message() << "n " << n << " iterations " << iterations);
      EXPECT_EQ(std::memcmp(&pl[0], &pl[1], sizeof(GroundPlane)), 0)
          << pl[0].a << " " << pl[0].b << " " << pl[0].c << " vs " << pl[1].a << " " << pl[1].b
          << " " << pl[1].c;
      fits += pl[1].a != 0.0;
    }
  }
  EXPECT_GT(fits, 20u);
}

}  // namespace
}  // namespace dtif
