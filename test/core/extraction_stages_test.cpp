// The stages of trunk extraction on their own, on small fixed-seed synthetic inputs: the local
// ground grid, the voxel columns and candidates, the circle fit, the stem base, duplicates and
// the ground map, and the tuning knobs that moved into TrunkExtractorParams.
#include "dtif/core/extraction/extraction_stages.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "dtif/core/extraction/lazy_mt19937.h"

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;

void push(LocalPoints* pts, double x, double y, double z) {
  pts->x.push_back(static_cast<float>(x));
  pts->y.push_back(static_cast<float>(y));
  pts->z.push_back(static_cast<float>(z));
}

using Terrain = double (*)(double x, double y);
double slopeZ(double x, double y) { return 2.0 + 0.3 * x - 0.2 * y; }
double flatZ(double, double) { return 0.0; }

// Noisy ground on the terrain over [0, size)^2, a point every `step`, none under the stems
// (within `hole_m` of a centre in `holes`: bark hides the ground next to it).
void addGround(LocalPoints* pts, Terrain terrain, double size, double step, std::mt19937* rng,
               const std::vector<Eigen::Vector2d>& holes = {}, double hole_m = 0.35) {
  std::normal_distribution<double> nz(0.0, 0.01);
  for (int i = 0; i * step < size; ++i) {
    for (int j = 0; j * step < size; ++j) {
      const double x = i * step, y = j * step;
      bool hidden = false;
      for (const auto& c : holes) hidden = hidden || std::hypot(x - c.x(), y - c.y()) < hole_m;
      if (!hidden) push(pts, x, y, terrain(x, y) + nz(*rng));
    }
  }
}

// Vertical cylinder surface standing on the terrain, from h0 to h1 above it.
void addCylinder(LocalPoints* pts, Terrain terrain, double cx, double cy, double r, double h0,
                 double h1, std::mt19937* rng) {
  std::normal_distribution<double> nz(0.0, 0.005);
  const double g = terrain(cx, cy);
  for (double th = 0.0; th < 2.0 * kPi; th += 0.03 / r)
    for (double h = h0; h < h1; h += 0.03) {
      const double rr = r + nz(*rng);
      push(pts, cx + rr * std::cos(th), cy + rr * std::sin(th), g + h);
    }
}

TEST(ExtractionStages, LocalPointsDropNonFiniteAndKeepPrecision) {
  Cloud cloud;
  cloud.push_back(pcl::PointXYZ(500000.25f, 6000000.5f, 120.75f));
  cloud.push_back(pcl::PointXYZ(NAN, 0.0f, 0.0f));
  cloud.push_back(pcl::PointXYZ(1e9f, 0.0f, 0.0f));  // beyond any survey
  cloud.push_back(pcl::PointXYZ(500001.0f, 6000002.0f, 121.0f));
  const LocalPoints pts = toLocalPoints(cloud);
  ASSERT_EQ(pts.size(), 2u);
  EXPECT_EQ(pts.ox, 500000.0);
  EXPECT_EQ(pts.oy, 6000000.0);
  EXPECT_EQ(pts.oz, 120.0);
  EXPECT_FLOAT_EQ(pts.x[0], 0.25f);
  EXPECT_FLOAT_EQ(pts.y[1], 2.0f);
  EXPECT_FLOAT_EQ(pts.z[1], 1.0f);
}

TEST(ExtractionStages, RobustPlaneIgnoresClutterAbove) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  std::vector<double> x, y, z, w;
  for (int i = 0; i < 200; ++i) {
    x.push_back(u(rng)), y.push_back(u(rng));
    z.push_back(1.0 + 0.2 * x.back() - 0.1 * y.back() + (i % 5 == 0 ? 1.5 : 0.0));  // shrubs
    w.push_back(1.0);
  }
  const GroundPlane p =
      fitGroundPlane(x.data(), y.data(), z.data(), w.data(), x.size(), 0.0, 0.0, 0.3, 1.0, 5);
  EXPECT_NEAR(p.a, 1.0, 0.01);
  EXPECT_NEAR(p.b, 0.2, 0.01);
  EXPECT_NEAR(p.c, -0.1, 0.01);
  EXPECT_NEAR(p.at(1.0, 1.0), 1.1, 0.02);
}

TEST(ExtractionStages, GroundGridFollowsASlopedPlane) {
  std::mt19937 rng(5);
  LocalPoints pts;
  addGround(&pts, slopeZ, 20.0, 0.1, &rng, {{10.2, 9.7}});
  addCylinder(&pts, slopeZ, 10.2, 9.7, 0.2, 0.0, 4.0, &rng);
  const TrunkExtractorParams p;
  const GroundGrid grid = estimateLocalGround(pts, p);
  EXPECT_EQ(grid.cell_m, p.ground_cell_m);
  EXPECT_EQ(grid.nx, 20);
  EXPECT_EQ(grid.ny, 20);
  ASSERT_EQ(grid.plane.size(), grid.cells());
  // The planes follow the slope; the low percentile of a tilted cell puts them a constant
  // amount below it (17 cm for this slope, from the 5th percentile of z over a 1 m cell).
  double lo = 1e9, hi = -1e9;
  for (double x = 1.5; x < 19.0; x += 2.3) {
    for (double y = 1.5; y < 19.0; y += 2.9) {
      const double off = grid.groundAt(x, y) - slopeZ(x, y);
      lo = std::min(lo, off), hi = std::max(hi, off);
      int gx, gy;
      grid.cellOf(x, y, &gx, &gy);
      EXPECT_TRUE(grid.seen[static_cast<size_t>(gy) * grid.nx + gx]);
      const GroundPlane& pl = grid.plane[static_cast<size_t>(gy) * grid.nx + gx];
      EXPECT_NEAR(pl.b, 0.3, 0.02) << x << "," << y;
      EXPECT_NEAR(pl.c, -0.2, 0.02) << x << "," << y;
    }
  }
  EXPECT_NEAR(lo, -0.17, 0.04);
  EXPECT_LT(hi - lo, 0.04);
  // Heights are above the point's own cell plane, the stem's up to its top.
  const std::vector<float> h = heightsAboveGround(pts, grid);
  ASSERT_EQ(h.size(), pts.size());
  for (size_t i = 0; i < pts.size(); i += 997)
    EXPECT_NEAR(h[i], pts.z[i] - grid.groundAt(pts.x[i], pts.y[i]), 1e-4) << i;
  // The last stem point: 3.99 m up the stem at (cx + r, cy), where the plane is 0.3 r higher.
  const size_t top = pts.size() - 1;
  EXPECT_NEAR(h[top], 3.99 + 0.17 - 0.3 * 0.2, 0.04);
}

TEST(ExtractionStages, GroundCellsNeedOpenSubColumns) {
  // One 1 m cell of flat ground (4 x 4 sub-columns of 0.25 m), then poles filling 5 of the 16
  // sub-columns: 11/16 open is below the default 0.75.
  LocalPoints pts;
  for (double x = 0.01; x < 1.0; x += 0.05)
    for (double y = 0.01; y < 1.0; y += 0.05) push(&pts, x, y, 0.0);
  TrunkExtractorParams p;
  GroundGrid grid = binGroundGrid(pts, p);
  GroundCells cells = openGroundCells(pts, grid, p);
  ASSERT_EQ(cells.count.size(), 1u);
  EXPECT_GT(cells.count[0], 0u);
  EXPECT_NEAR(cells.low[0], 0.0, 1e-6);
  const double poles[5][2] = {{0.1, 0.1}, {0.35, 0.1}, {0.6, 0.1}, {0.85, 0.1}, {0.1, 0.35}};
  for (const auto& xy : poles)
    for (int k = 0; k < 19; ++k) push(&pts, xy[0], xy[1], 0.1 * k);  // up to 1.8 m
  grid = binGroundGrid(pts, p);
  cells = openGroundCells(pts, grid, p);
  EXPECT_EQ(cells.count[0], 0u);
  EXPECT_EQ(cells.any[0], 1);
  p.ground_min_open_fraction = 0.5;
  cells = openGroundCells(pts, grid, p);
  EXPECT_GT(cells.count[0], 0u);
  // A taller gap: the poles (up to 1.8 m) no longer close a sub-column.
  p = TrunkExtractorParams();
  p.ground_open_gap_m = 1.9;
  p.ground_open_top_m = 3.0;
  cells = openGroundCells(pts, grid, p);
  EXPECT_GT(cells.count[0], 0u);
}

TEST(ExtractionStages, RaisedGroundCellIsDropped) {
  GroundGrid grid;
  grid.nx = 3, grid.ny = 1, grid.cell_m = 1.0;
  GroundCells cells;
  cells.low = {0.0f, 2.0f, 1.5f};
  cells.count = {10, 10, 10};
  cells.any = {1, 1, 1};
  cells.min = {0.0f, 2.0f, 1.5f};
  TrunkExtractorParams p;  // at most 1 m per 1 m cell
  GroundCells c = cells;
  dropRaisedGroundCells(grid, p, &c);
  EXPECT_EQ(c.count[0], 10u);
  EXPECT_EQ(c.count[1], 0u);   // 2 m above its left neighbour's lowest point
  EXPECT_EQ(c.count[2], 10u);  // 1.5 m above cell 0, but only direct neighbours count
  p.ground_max_step = 2.5;
  c = cells;
  dropRaisedGroundCells(grid, p, &c);
  EXPECT_EQ(c.count[1], 10u);
}

TEST(ExtractionStages, ColumnsAndCandidatesOfTwoCylinders) {
  std::mt19937 rng(7);
  LocalPoints pts;
  addCylinder(&pts, slopeZ, 2.0, 2.0, 0.2, 0.0, 3.5, &rng);
  addCylinder(&pts, slopeZ, 3.2, 2.0, 0.15, 0.0, 3.5, &rng);
  // A shrub column: points only in its lowest two layers fails vertical continuity.
  for (int i = 0; i < 30; ++i) push(&pts, 8.05, 2.05, slopeZ(8.05, 2.05) + 0.45 + 0.01 * i);
  std::vector<float> h(pts.size());
  for (size_t i = 0; i < pts.size(); ++i)
    h[i] = static_cast<float>(pts.z[i] - slopeZ(pts.x[i], pts.y[i]));
  const TrunkExtractorParams p;
  const VoxelColumns cols = slabColumns(pts, h, p);
  ASSERT_FALSE(cols.slab.empty());
  EXPECT_GT(cols.passing, 8u);
  for (size_t c = 0; c < cols.size(); ++c) {
    const double x = (cols.ix[c] + 0.5) * p.column_cell_m, y = (cols.iy[c] + 0.5) * p.column_cell_m;
    if (std::hypot(x - 8.05, y - 2.05) < 0.2) {
      EXPECT_FALSE(cols.pass[c]);
      EXPECT_EQ(cols.count[c], 30u);
    }
  }
  const TrunkCandidates cand = clusterColumns(cols, p);
  ASSERT_EQ(cand.count, 2);
  for (int l = 0; l < cand.count; ++l) {
    double mx = 0.0;
    for (uint32_t k = cand.start[l]; k < cand.start[l + 1]; ++k) mx += pts.x[cand.points[k]];
    mx /= cand.start[l + 1] - cand.start[l];
    EXPECT_NEAR(mx, l == 0 ? 2.0 : 3.2, 0.05);  // numbered by first column
  }
  // A wide merge gap joins the two stems.
  TrunkExtractorParams wide;
  wide.cluster_gap_m = 1.4;
  EXPECT_EQ(clusterColumns(slabColumns(pts, h, wide), wide).count, 1);
}

// A failing column joins the candidate of its first passing neighbour in the order (dy, dx) =
// (-1, -1), (-1, 0), ..., (1, 1), whichever candidate is numbered first; through the dense grid
// and through the hash.
TEST(ExtractionStages, FailingColumnJoinsItsFirstPassingNeighbour) {
  // Columns 0 and 1 pass, two cells apart (separate candidates at a one-cell gap); 2 fails and
  // touches both, 1 at (dx, dy) = (1, -1), 0 at (-1, 0); 3 fails and touches only 0; 4 fails,
  // alone.
  const std::vector<std::pair<int64_t, int64_t>> cells = {{1, 1}, {3, 0}, {2, 1}, {0, 2}, {6, 2}};
  TrunkExtractorParams p;
  p.cluster_gap_m = 0.1;
  for (const bool dense : {true, false}) {
    VoxelColumns cols;
    if (dense) cols.gw = 7, cols.gh = 3, cols.grid.assign(21, -1);
    cols.index = CellHash(cells.size());
    for (size_t c = 0; c < cells.size(); ++c) {
      cols.ix.push_back(cells[c].first), cols.iy.push_back(cells[c].second);
      cols.pass.push_back(c < 2);
      cols.slab.push_back(static_cast<uint32_t>(10 + c));
      cols.slab_col.push_back(static_cast<int>(c));
      if (dense) cols.grid[cells[c].second * 7 + cells[c].first] = static_cast<int>(c);
      bool inserted;
      if (!dense)
        cols.index.findOrInsert(cellKey(cells[c].first, cells[c].second), static_cast<int>(c),
                                &inserted);
    }
    const TrunkCandidates cand = clusterColumns(cols, p);
    ASSERT_EQ(cand.count, 2);
    EXPECT_EQ(cand.start, (std::vector<uint32_t>{0, 2, 4}));
    EXPECT_EQ(cand.points, (std::vector<uint32_t>{10, 13, 11, 12})) << "dense " << dense;
  }
}

// The heights pass that also selects the slab gives the heights and the slab (in point order)
// of the separate stages, and its columns are slabColumns'.
TEST(ExtractionStages, HeightsAndSlabInOnePassMatchTheSeparateStages) {
  std::mt19937 rng(13);
  LocalPoints pts;
  addGround(&pts, slopeZ, 12.0, 0.08, &rng, {{4.0, 4.0}});
  addCylinder(&pts, slopeZ, 4.0, 4.0, 0.2, 0.0, 3.5, &rng);
  const TrunkExtractorParams p;
  const GroundGrid grid = estimateLocalGround(pts, p);
  const std::vector<float> h = heightsAboveGround(pts, grid);
  const VoxelColumns cols = slabColumns(pts, h, p);
  std::vector<float> h1 = {1.0f};  // storage reused
  VoxelColumns one;
  heightsAndSlab(pts, grid, p, &h1, &one.slab);
  EXPECT_EQ(h1, h);
  EXPECT_EQ(one.slab, cols.slab);
  EXPECT_GT(one.slab.size(), 100u);
  EXPECT_LT(one.slab.size(), pts.size() / 2);
  columnsOfSlab(pts, h1, p, &one);
  EXPECT_EQ(one.slab_col, cols.slab_col);
  EXPECT_EQ(one.ix, cols.ix);
  EXPECT_EQ(one.iy, cols.iy);
  EXPECT_EQ(one.pass, cols.pass);
  EXPECT_EQ(one.passing, cols.passing);
}

TEST(ExtractionStages, CircleFitOnANoisyHalfArc) {
  std::mt19937 rng(21);
  std::normal_distribution<double> nz(0.0, 0.004);
  std::vector<Eigen::Vector2d> xy;
  for (double th = -0.5 * kPi; th < 0.5 * kPi; th += 0.02) {
    // One draw per statement, in the order gcc evaluated these arguments (last first), so the
    // data are the same whatever the compiler.
    const double ry = 0.18 + nz(rng);
    const double rx = 0.18 + nz(rng);
    xy.emplace_back(-3.0 + rx * std::cos(th), 4.0 + ry * std::sin(th));
  }
  CircleFitParams cp;
  const CircleFit f = fitCircleRobust(xy, cp);
  ASSERT_TRUE(f.ok);
  EXPECT_NEAR(f.cx, -3.0, 0.01);
  EXPECT_NEAR(f.cy, 4.0, 0.01);
  EXPECT_NEAR(f.r, 0.18, 0.006);
  EXPECT_NEAR(f.arc_deg, 180.0, 25.0);
  EXPECT_GT(f.inlier_ratio, 0.95);
  // Scoring on few points still ranks the hypotheses on this clean arc.
  cp.score_points = 20;
  const CircleFit coarse = fitCircleRobust(xy, cp);
  ASSERT_TRUE(coarse.ok);
  EXPECT_NEAR(coarse.r, 0.18, 0.006);
  cp.score_points = 0;  // invalid: no fit rather than a division by zero
  EXPECT_FALSE(fitCircleRobust(xy, cp).ok);
}

TEST(ExtractionStages, LazyMt19937GivesStdMt19937sNumbers) {
  // Seeds of the extraction's form and the edges of the range; 1500 draws cross the first
  // block (624 words, seeded and twisted lazily) and the next two (twisted whole).
  for (const uint32_t seed : {0u, 1u, 5489u, 0x9e3779b9u ^ 131u, 0xffffffffu}) {
    std::mt19937 ref(seed);
    LazyMt19937 lazy(seed);
    for (int i = 0; i < 1500; ++i) ASSERT_EQ(lazy(), ref()) << "seed " << seed << " draw " << i;
  }
  // Through a distribution, as ransacCircle draws: the same indices.
  std::mt19937 ref(77);
  LazyMt19937 lazy(77);
  std::uniform_int_distribution<size_t> a(0, 36), b(0, 36);
  for (int i = 0; i < 500; ++i) ASSERT_EQ(a(lazy), b(ref)) << "draw " << i;
}

TEST(ExtractionStages, LazyMt19937BelowDrawsAsTheDistribution) {
  // below(n) as std::uniform_int_distribution<size_t>(0, n - 1) on the same numbers: small
  // ranges, band sizes, and ranges above 2^31 where most draws are rejected and drawn again.
  for (const uint32_t n : {1u, 2u, 3u, 37u, 400u, 4097u, 0x80000001u, 0xfffffffeu, 0xffffffffu}) {
    LazyMt19937 ours(n), theirs(n);
    std::uniform_int_distribution<size_t> d(0, n - 1);
    for (int i = 0; i < 2000; ++i)
      ASSERT_EQ(ours.below(n), d(theirs)) << "n " << n << " draw " << i;
    EXPECT_EQ(ours(), theirs());  // the same count of numbers drawn
  }
}

TEST(ExtractionStages, CircleFitParamsComeFromTheExtractorsParams) {
  TrunkExtractorParams p;
  p.ransac_iterations = 77, p.ransac_min_iterations = 9, p.ransac_score_points = 123;
  p.ransac_inlier_m = 0.02, p.min_radius_m = 0.05, p.max_radius_m = 0.5;
  const CircleFitParams c = circleFitParams(p);
  EXPECT_EQ(c.iterations, 77);
  EXPECT_EQ(c.min_iterations, 9);
  EXPECT_EQ(c.score_points, 123);
  EXPECT_EQ(c.inlier_m, 0.02);
  EXPECT_EQ(c.min_radius_m, 0.05);
  EXPECT_EQ(c.max_radius_m, 0.5);
  // The defaults agree.
  const CircleFitParams d = circleFitParams(TrunkExtractorParams());
  EXPECT_EQ(d.iterations, CircleFitParams().iterations);
  EXPECT_EQ(d.min_iterations, CircleFitParams().min_iterations);
  EXPECT_EQ(d.score_points, CircleFitParams().score_points);
  EXPECT_EQ(d.inlier_m, CircleFitParams().inlier_m);
}

TEST(ExtractionStages, StemBaseSeenOnlyWhenTheFootIsVisible) {
  std::mt19937 rng(9);
  LocalPoints pts;
  addGround(&pts, slopeZ, 12.0, 0.08, &rng, {{4.0, 4.0}, {8.0, 8.0}});
  addCylinder(&pts, slopeZ, 4.0, 4.0, 0.2, 0.0, 3.0, &rng);  // visible down to the ground
  addCylinder(&pts, slopeZ, 8.0, 8.0, 0.2, 0.8, 3.0, &rng);  // foot hidden below 0.8 m
  TrunkExtractorParams p;
  const GroundGrid grid = estimateLocalGround(pts, p);
  const std::vector<float> h = heightsAboveGround(pts, grid);
  const StemBase a = stemBase(pts, h, grid, 4.0, 4.0, 0.2, p);
  EXPECT_TRUE(a.ring_seen);
  EXPECT_TRUE(a.seen);
  EXPECT_NEAR(a.z, slopeZ(4.0, 4.0), 0.03);
  const StemBase b = stemBase(pts, h, grid, 8.0, 8.0, 0.2, p);
  EXPECT_TRUE(b.ring_seen);
  EXPECT_NEAR(b.z, slopeZ(8.0, 8.0), 0.03);
  EXPECT_FALSE(b.seen);  // 0.8 m gap > base_max_gap_m
  p.base_max_gap_m = 1.0;
  EXPECT_TRUE(stemBase(pts, h, grid, 8.0, 8.0, 0.2, p).seen);
}

TEST(ExtractionStages, DuplicatesKeepTheBetterFitAndSortByX) {
  auto found = [](double x, double y, double r, size_t inliers) {
    FoundTrunk f;
    f.trunk.x = x, f.trunk.y = y, f.trunk.r = r, f.inliers = inliers;
    return f;
  };
  TrunkExtractionStats st;
  const Trunks t = keepDistinctTrunks(
      {found(5.0, 0.0, 0.2, 40), found(1.0, 0.0, 0.2, 50), found(5.1, 0.1, 0.15, 90)},
      TrunkExtractorParams(), &st);
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(st.duplicates, 1u);
  EXPECT_EQ(t[0].x, 1.0);
  EXPECT_EQ(t[1].x, 5.1);  // 90 inliers beat 40
}

TEST(ExtractionStages, GroundMapOnlyWhenFewBasesSeen) {
  std::mt19937 rng(11);
  LocalPoints pts;
  addGround(&pts, slopeZ, 10.0, 0.1, &rng);
  Trunks trunks(3);
  for (size_t i = 0; i < trunks.size(); ++i) trunks[i].x = 2.0 + 3.0 * i, trunks[i].y = 5.0;
  TrunkExtractorParams p;
  for (auto& t : trunks) t.base_seen = true;
  // The default (1.01): every submap carries one, all bases seen or not.
  EXPECT_FALSE(groundMapIfFewBasesSeen(trunks, pts, p).empty());
  p.ground_map_below_seen = 0.4;
  EXPECT_TRUE(groundMapIfFewBasesSeen(trunks, pts, p).empty());
  trunks[0].base_seen = trunks[1].base_seen = false;  // 1/3 seen < 0.4
  const GroundMap m = groundMapIfFewBasesSeen(trunks, pts, p);
  ASSERT_FALSE(m.empty());
  double z;
  ASSERT_TRUE(m.at(5.0, 5.0, &z));
  // The lowest point of the cell [5, 5.5)^2: x = 5.0, y = 5.4 on the plane.
  EXPECT_NEAR(z, slopeZ(5.0, 5.4), 0.07);
  TrunkExtractorParams none = p;
  none.ground_map_cell_m = 0.0;
  EXPECT_TRUE(groundMapIfFewBasesSeen(trunks, pts, none).empty());
}

bool sameMap(const GroundMap& a, const GroundMap& b) {
  return a.cell_m == b.cell_m && a.z_step_m == b.z_step_m && a.z0_m == b.z0_m && a.x0 == b.x0 &&
         a.y0 == b.y0 && a.width == b.width && a.height == b.height && a.z == b.z;
}

// The ground map from the cells gathered in the heights pass equals makeGroundMap's over the
// same points, for boxes that cut cells anywhere, cover everything or nothing, with points on
// the box's edges and on cell boundaries, at a cell size that is no power of two, and with an
// origin that makes local coordinates round.
TEST(ExtractionStages, GroundMapOfCellsEqualsMakeGroundMap) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int compared = 0, nonempty = 0;
  for (const double cell : {0.5, 0.3, 1.0}) {
    for (const double ox : {0.0, -3.0, 101.0}) {
      LocalPoints pts;
      pts.ox = ox, pts.oy = 2.0 * ox, pts.oz = -7.0;
      addGround(&pts, slopeZ, 14.0, 0.09, &rng);
      addCylinder(&pts, slopeZ, 6.0, 5.0, 0.2, 0.0, 3.0, &rng);
      for (int k = 0; k < 200; ++k)  // on cell boundaries of S (local + origin)
        push(&pts, std::round(u(rng) * 20) * cell - ox, std::round(u(rng) * 20) * cell - 2 * ox,
             -1.0 + u(rng));
      push(&pts, 1e-9, 13.5, -2.0);  // rounds when the origin is added
      TrunkExtractorParams p;
      p.ground_map_cell_m = cell;
      p.ground_map_min_points = 2;
      const GroundGrid grid = estimateLocalGround(pts, p);
      GroundMapCells mc;
      ASSERT_TRUE(mc.init(pts, cell, 1000.0));
      std::vector<float> h;
      std::vector<uint32_t> slab;
      heightsAndSlab(pts, grid, p, &h, &slab, &mc);
      ASSERT_TRUE(mc.used);
      const Eigen::Vector3d origin(pts.ox, pts.oy, pts.oz);
      std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> boxes;
      for (int k = 0; k < 30; ++k) {
        const Eigen::Vector2d a(u(rng) * 18 - 2 + ox, u(rng) * 18 - 2 + 2 * ox);
        boxes.emplace_back(a, a + Eigen::Vector2d(u(rng) * 12, u(rng) * 12));
      }
      boxes.emplace_back(Eigen::Vector2d(-100 + ox, -100 + 2 * ox),
                         Eigen::Vector2d(100 + ox, 100 + 2 * ox));                   // everything
      boxes.emplace_back(Eigen::Vector2d(50 + ox, 0), Eigen::Vector2d(60 + ox, 5));  // nothing
      // Edges exactly on points and on cell boundaries.
      boxes.emplace_back(Eigen::Vector2d(pts.x[5] + ox, pts.y[5] + 2 * ox),
                         Eigen::Vector2d(pts.x[900] + ox, pts.y[900] + 2 * ox));
      boxes.emplace_back(Eigen::Vector2d(4 * cell + ox, 3 * cell + 2 * ox),
                         Eigen::Vector2d(9 * cell + ox, 11 * cell + 2 * ox));
      for (const auto& [lo, hi] : boxes) {
        const GroundMap ref = makeGroundMap(pts.x.data(), pts.y.data(), pts.z.data(), pts.size(),
                                            origin, lo, hi, cell, p.ground_map_z_step_m, 2);
        GroundMap m;
        m.width = 77;  // overwritten
        ASSERT_TRUE(groundMapOfCells(mc, grid, lo, hi, p, &m));
        EXPECT_TRUE(sameMap(m, ref)) << "cell " << cell << " ox " << ox << " box " << lo.transpose()
                                     << " .. " << hi.transpose();
        ++compared;
        nonempty += !ref.empty();
      }
    }
  }
  EXPECT_EQ(compared, 9 * 34);
  EXPECT_GT(nonempty, 9 * 25);
}

// A map that would need a coarser z step or cell than asked is left to makeGroundMap.
TEST(ExtractionStages, GroundMapOfCellsDeclinesWhatItCannotMake) {
  std::mt19937 rng(19);
  LocalPoints pts;
  addGround(&pts, flatZ, 10.0, 0.1, &rng);
  TrunkExtractorParams p;
  const GroundGrid grid = estimateLocalGround(pts, p);
  GroundMapCells mc;
  std::vector<float> h;
  std::vector<uint32_t> slab;
  GroundMap m;
  const Eigen::Vector2d lo(1, 1), hi(8, 8);
  EXPECT_FALSE(groundMapOfCells(mc, grid, lo, hi, p, &m));  // not gathered
  ASSERT_TRUE(mc.init(pts, p.ground_map_cell_m, 1e5));      // points might lie 1e5 m up
  heightsAndSlab(pts, grid, p, &h, &slab, &mc);
  EXPECT_FALSE(groundMapOfCells(mc, grid, lo, hi, p, &m));
  EXPECT_EQ(m.width, 0);  // untouched
  ASSERT_TRUE(mc.init(pts, p.ground_map_cell_m, 10.0));
  heightsAndSlab(pts, grid, p, &h, &slab, &mc);
  TrunkExtractorParams fine = p;
  fine.ground_map_cell_m = 0.01;  // 700 cells a side: more than kMaxGroundMapSide
  GroundMapCells mf;
  ASSERT_TRUE(mf.init(pts, 0.01, 10.0));
  heightsAndSlab(pts, grid, fine, &h, &slab, &mf);
  EXPECT_FALSE(groundMapOfCells(mf, grid, lo, hi, fine, &m));
  EXPECT_FALSE(groundMapOfCells(mc, grid, lo, hi, fine, &m));  // gathered at another cell size
  ASSERT_TRUE(groundMapOfCells(mc, grid, lo, hi, p, &m));
  EXPECT_TRUE(sameMap(m, makeGroundMap(pts.x.data(), pts.y.data(), pts.z.data(), pts.size(),
                                       Eigen::Vector3d::Zero(), lo, hi, p.ground_map_cell_m,
                                       p.ground_map_z_step_m, p.ground_map_min_points)));
}

TEST(ExtractionStages, ValidateRejectsBadTuningKnobs) {
  auto error = [](void (*set)(TrunkExtractorParams*)) {
    TrunkExtractorParams p;
    set(&p);
    return p.validate();
  };
  EXPECT_NE(
      error([](TrunkExtractorParams* p) { p->max_ground_cells = 0.5; }).find("max_ground_cells"),
      std::string::npos);
  EXPECT_NE(
      error([](TrunkExtractorParams* p) { p->ground_sub_cell_m = 0.0; }).find("ground_sub_cell_m"),
      std::string::npos);
  EXPECT_NE(
      error([](TrunkExtractorParams* p) { p->ground_open_top_m = 0.2; }).find("ground_open_top_m"),
      std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) {
              p->ground_min_open_fraction = 1.2;
            }).find("ground_min_open_fraction"),
            std::string::npos);
  EXPECT_NE(
      error([](TrunkExtractorParams* p) { p->ground_min_cells = 0; }).find("ground_min_cells"),
      std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) {
              p->ransac_score_points = 0;
            }).find("ransac_score_points"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) {
              p->ransac_min_iterations = 0;
            }).find("ransac_min_iterations"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) { p->stem_shell_m = -0.1; }).find("stem_shell_m"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) { p->base_max_gap_m = 0.0; }).find("base_max_gap_m"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) {
              p->footprint_max_samples = -1;
            }).find("footprint_max_samples"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) {
              p->ground_plane_c_up_m = 0.0;
            }).find("ground_plane_c_up_m"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) {
              p->base_plane_c_down_m = -1.0;
            }).find("base_plane_c_down_m"),
            std::string::npos);
  EXPECT_NE(error([](TrunkExtractorParams* p) { p->lean_shell_m = -0.1; }).find("lean_shell_m"),
            std::string::npos);
  // An invalid set extracts nothing.
  TrunkExtractorParams bad;
  bad.ground_max_step = -1.0;
  EXPECT_NE(bad.validate().find("ground_max_step"), std::string::npos);
  std::mt19937 rng(13);
  LocalPoints pts;
  addCylinder(&pts, flatZ, 1.0, 1.0, 0.2, 0.0, 3.0, &rng);
  Cloud cloud;
  for (size_t i = 0; i < pts.size(); ++i)
    cloud.push_back(pcl::PointXYZ(pts.x[i], pts.y[i], pts.z[i]));
  EXPECT_EQ(extractTrunks(cloud, bad).stats.finite_points, 0u);
}

TEST(ExtractionStages, FootprintUsesItsCellAndCanBeOff) {
  std::mt19937 rng(17);
  LocalPoints pts;
  addGround(&pts, flatZ, 10.0, 0.1, &rng, {{3.5, 3.5}});
  addCylinder(&pts, flatZ, 3.5, 3.5, 0.2, 0.0, 3.0, &rng);
  Cloud cloud;
  for (size_t i = 0; i < pts.size(); ++i)
    cloud.push_back(pcl::PointXYZ(pts.x[i], pts.y[i], pts.z[i]));
  TrunkExtractorParams p;
  const Footprint f = trunkFootprint(cloud, p);
  ASSERT_FALSE(f.empty());
  EXPECT_TRUE(f.occupied(3, 3));   // the stem, 0.3-3 m above the ground
  EXPECT_FALSE(f.occupied(8, 8));  // bare ground
  p.footprint_max_samples = 0;     // every point: the same cells here
  EXPECT_EQ(trunkFootprint(cloud, p).bits, f.bits);
  p.footprint_cell_m = 0.0;
  EXPECT_TRUE(trunkFootprint(cloud, p).empty());
}

}  // namespace
}  // namespace dtif
