// Footprints (occupied cells at trunk height) and their overlap under a pose, which
// verification compares with DATASET.md's overlap threshold.
#include "dtif/core/extraction/footprint.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>

namespace dtif {
namespace {

using Cells = std::vector<std::pair<int64_t, int64_t>>;

Cells rect(int64_t x0, int64_t y0, int64_t w, int64_t h) {
  Cells c;
  for (int64_t y = y0; y < y0 + h; ++y)
    for (int64_t x = x0; x < x0 + w; ++x) c.emplace_back(x, y);
  return c;
}

Pose shifted(double dx, double dy, double yaw = 0.0) {
  Pose T = Pose::Identity();
  T.linear() = rotZ(yaw);
  T.translation() = Eigen::Vector3d(dx, dy, 0.0);
  return T;
}

TEST(Footprint, CellsRoundTripThroughTheBitmap) {
  Cells cells = rect(-3, 5, 7, 4);
  cells.emplace_back(10, -2);  // an isolated cell widens the box
  cells.emplace_back(-3, 5);   // duplicates are fine
  const Footprint f = makeFootprint(cells, 1.0);
  EXPECT_EQ(f.cell_m, 1.0);
  EXPECT_EQ(f.x0, -3);
  EXPECT_EQ(f.y0, -2);
  EXPECT_EQ(f.width, 14);
  EXPECT_EQ(f.height, 11);
  EXPECT_EQ(f.count(), 29u);
  EXPECT_TRUE(f.occupied(10, -2));
  EXPECT_TRUE(f.occupied(3, 8));
  EXPECT_FALSE(f.occupied(4, 8));
  EXPECT_FALSE(f.occupied(-4, 5));     // left of the bitmap
  EXPECT_FALSE(f.occupied(100, 100));  // far outside
}

TEST(Footprint, OverlapIsTheSharedShareOfTheSmallerFootprint) {
  const Footprint c = makeFootprint(rect(0, 0, 20, 10), 1.0);  // 200 cells
  const Footprint q = makeFootprint(rect(0, 0, 10, 10), 1.0);  // 100 cells
  EXPECT_DOUBLE_EQ(footprintOverlap(q, c, Pose::Identity()), 1.0);
  EXPECT_DOUBLE_EQ(footprintOverlap(q, c, shifted(15.0, 0.0)), 0.5);  // q cells 15..24
  EXPECT_DOUBLE_EQ(footprintOverlap(q, c, shifted(0.0, 7.0)), 0.3);   // rows 7..9 shared
  EXPECT_DOUBLE_EQ(footprintOverlap(q, c, shifted(40.0, 0.0)), 0.0);
  // The query frame turned by 180 deg about the origin: cells land at negative x, y.
  EXPECT_DOUBLE_EQ(footprintOverlap(q, c, shifted(10.0, 10.0, M_PI)), 1.0);
  // Symmetric in the sense of the protocol: min(|q|, |c|) in the denominator.
  EXPECT_DOUBLE_EQ(footprintOverlap(c, q, shifted(-15.0, 0.0)), 0.5);
}

TEST(Footprint, EmptyFootprintsAreNotMeasured) {
  const Footprint none;
  const Footprint c = makeFootprint(rect(0, 0, 5, 5), 1.0);
  EXPECT_TRUE(none.empty());
  EXPECT_EQ(footprintOverlap(none, c, Pose::Identity()), -1.0);
  EXPECT_EQ(footprintOverlap(c, none, Pose::Identity()), -1.0);
  EXPECT_TRUE(makeFootprint({}, 1.0).empty());
  EXPECT_TRUE(makeFootprint(rect(0, 0, 2, 2), 0.0).empty());
}

TEST(Footprint, WideExtentsAreCoarsenedToStayWithinTheBudget) {
  // Two clusters 1 km apart (stray points): the bitmap coarsens instead of growing.
  Cells cells = rect(0, 0, 10, 10);
  const Cells far = rect(1000, 0, 3, 3);
  cells.insert(cells.end(), far.begin(), far.end());
  const Footprint f = makeFootprint(cells, 1.0);
  EXPECT_LE(f.width, kMaxFootprintSide);
  EXPECT_LE(f.height, kMaxFootprintSide);
  EXPECT_GT(f.cell_m, 1.0);
  EXPECT_EQ(std::log2(f.cell_m), std::round(std::log2(f.cell_m)));  // powers of two
  EXPECT_TRUE(f.occupied(0, 0));
  EXPECT_TRUE(f.occupied(static_cast<int64_t>(std::floor(1001.0 / f.cell_m)), 0));
  EXPECT_LE(f.bits.size(), static_cast<size_t>(kMaxFootprintSide * kMaxFootprintSide / 8));
  // Negative indices coarsen by floor, so cells stay nested.
  const Footprint g = makeFootprint({{-1, -1}, {-1000, 0}}, 1.0);
  EXPECT_TRUE(g.occupied(static_cast<int64_t>(std::floor(-1.0 / g.cell_m)),
                         static_cast<int64_t>(std::floor(-1.0 / g.cell_m))));
}

// Rolling ground with stems and shrubs at scattered heights: many cells in and out of the
// trunk-height band, around coordinates that are not multiples of the cells.
Cloud bumpyStand(uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Cloud cloud;
  for (int i = 0; i < 40000; ++i) {
    const float x = -13.3f + 31.0f * u(rng), y = 7.9f + 27.0f * u(rng);
    const float ground = 0.8f * std::sin(0.3f * x) + 0.05f * y;
    const float z = u(rng) < 0.7f ? ground + 0.05f * u(rng) : ground + 6.0f * u(rng) * u(rng);
    cloud.push_back(pcl::PointXYZ(x, y, z));
  }
  return cloud;
}

TEST(Footprint, MarksGiveTrunkHeightCells) {
  // Marked point by point from the samples, in any order: trunkHeightCells' cells, at a
  // power-of-two cell size and at one that is not, with and without subsampled percentiles.
  for (const uint32_t seed : {1u, 2u}) {
    Cloud cloud = bumpyStand(seed);
    for (const double cell_m : {1.0, 2.0, 0.5, 0.3}) {
      for (const size_t max_samples : {size_t{0}, size_t{5000}}) {
        const size_t stride = max_samples > 0 ? cloud.size() / max_samples : 1;
        std::vector<float> sx, sy, sz;
        for (size_t i = 0; i < cloud.size(); i += stride)
          sx.push_back(cloud[i].x), sy.push_back(cloud[i].y), sz.push_back(cloud[i].z);
        HeightCellMarks marks;
        ASSERT_TRUE(marks.init(sx, sy, sz, cell_m, Eigen::Vector2d(-20.0, 0.0),
                               Eigen::Vector2d(20.0, 40.0)));
        for (size_t i = cloud.size(); i-- > 0;) marks.add(cloud[i].x, cloud[i].y, cloud[i].z);
        EXPECT_TRUE(marks.complete());
        const Cells expected = trunkHeightCells(cloud, Pose::Identity(), cell_m, max_samples);
        EXPECT_GT(expected.size(), 50u);
        EXPECT_EQ(marks.cells(), expected) << "seed " << seed << ", cell " << cell_m;
      }
    }
  }
}

TEST(Footprint, MarksAtCellAndTileEdgesGiveTrunkHeightCells) {
  // Cells of 2^k m take the cell and the 2 m tile from one floor per coordinate: points on
  // whole and half metres and one float step either side, both signs, fall where
  // trunkHeightCells puts them.
  Cloud cloud;
  for (float x = -9.75f; x < 10.0f; x += 0.5f)
    for (float y = -9.75f; y < 10.0f; y += 0.5f) cloud.push_back(pcl::PointXYZ(x, y, 0.0f));
  for (int i = -16; i <= 16; ++i) {
    const float v = 0.5f * static_cast<float>(i);
    for (const float x : {std::nextafter(v, -1e9f), v, std::nextafter(v, 1e9f)})
      for (const float y : {std::nextafter(-v, -1e9f), 0.0f, std::nextafter(-v, 1e9f)})
        cloud.push_back(pcl::PointXYZ(x, y, 1.0f));
  }
  std::vector<float> sx, sy, sz;
  for (const pcl::PointXYZ& q : cloud) sx.push_back(q.x), sy.push_back(q.y), sz.push_back(q.z);
  for (const double cell_m : {1.0, 2.0, 4.0, 0.5, 0.3}) {
    HeightCellMarks marks;
    ASSERT_TRUE(
        marks.init(sx, sy, sz, cell_m, Eigen::Vector2d(-20.0, -20.0), Eigen::Vector2d(20.0, 20.0)));
    for (const pcl::PointXYZ& q : cloud) marks.add(q.x, q.y, q.z);
    EXPECT_TRUE(marks.complete());
    const Cells expected = trunkHeightCells(cloud, Pose::Identity(), cell_m, 0);
    EXPECT_GT(expected.size(), 10u);
    EXPECT_EQ(marks.cells(), expected) << "cell " << cell_m;
  }
}

TEST(Footprint, MarksOfOnePassEqualMarksPerPoint) {
  // extraction marks through one branch-free Pass: the cells add() gives, and a point of the band
  // outside the box (a box too small here) reported as incomplete, as add() reports it.
  const Cloud cloud = bumpyStand(3);
  std::vector<float> sx, sy, sz;
  for (size_t i = 0; i < cloud.size(); i += 8)
    sx.push_back(cloud[i].x), sy.push_back(cloud[i].y), sz.push_back(cloud[i].z);
  for (const double hi_x : {20.0, 5.0}) {
    HeightCellMarks one, each;
    const Eigen::Vector2d lo(-20.0, 0.0), hi(hi_x, 40.0);
    ASSERT_TRUE(one.init(sx, sy, sz, 0.3, lo, hi));
    ASSERT_TRUE(each.init(sx, sy, sz, 0.3, lo, hi));
    HeightCellMarks::Pass pass = one.pass();
    for (const pcl::PointXYZ& q : cloud) pass.add(q.x, q.y, q.z), each.add(q.x, q.y, q.z);
    one.finish(pass);
    EXPECT_EQ(one.complete(), hi_x > 10.0);
    EXPECT_EQ(each.complete(), one.complete());
    EXPECT_GT(one.cells().size(), 50u);
    EXPECT_EQ(one.cells(), each.cells());
  }
}

#ifdef __SSE2__
TEST(Footprint, MarksOfFourPointsAtATimeEqualMarksPerPoint) {
  // add4 (extraction's first pass, four points per step) against add: the same cells and the
  // same report of a band point outside the box, at cells of 2^k m (the cell from the floors)
  // and not (add lane by lane), on a stand and on points a float step around whole and half
  // metres, with points around both ends of the band.
  Cloud cloud = bumpyStand(4);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (int i = -24; i <= 24; ++i) {
    const float v = 0.5f * static_cast<float>(i);
    for (const float x : {std::nextafter(v, -1e9f), v, std::nextafter(v, 1e9f)}) {
      for (const float y : {std::nextafter(v + 20.0f, -1e9f), v + 20.0f}) {
        const float ground = 0.8f * std::sin(0.3f * x) + 0.05f * y;
        for (const float h : {0.3f, 3.0f, 1.0f})
          cloud.push_back(pcl::PointXYZ(x, y, ground + h + 0.02f * u(rng)));
      }
    }
  }
  std::vector<float> sx, sy, sz;
  for (size_t i = 0; i < cloud.size(); i += 4)
    sx.push_back(cloud[i].x), sy.push_back(cloud[i].y), sz.push_back(cloud[i].z);
  for (const double cell_m : {1.0, 2.0, 4.0, 0.5, 0.3}) {
    for (const double hi_x : {20.0, 5.0}) {
      HeightCellMarks four, each;
      const Eigen::Vector2d lo(-20.0, 0.0), hi(hi_x, 40.0);
      ASSERT_TRUE(four.init(sx, sy, sz, cell_m, lo, hi));
      ASSERT_TRUE(each.init(sx, sy, sz, cell_m, lo, hi));
      HeightCellMarks::Pass pass = four.pass();
      size_t i = 0;
      for (; i + 4 <= cloud.size(); i += 4) {
        const auto lane = [&](float pcl::PointXYZ::*c) {
          return _mm_set_ps(cloud[i + 3].*c, cloud[i + 2].*c, cloud[i + 1].*c, cloud[i].*c);
        };
        pass.add4(lane(&pcl::PointXYZ::x), lane(&pcl::PointXYZ::y), lane(&pcl::PointXYZ::z));
      }
      for (; i < cloud.size(); ++i) pass.add(cloud[i].x, cloud[i].y, cloud[i].z);
      four.finish(pass);
      for (const pcl::PointXYZ& q : cloud) each.add(q.x, q.y, q.z);
      EXPECT_EQ(four.complete(), each.complete()) << "cell " << cell_m << ", box to " << hi_x;
      EXPECT_EQ(four.complete(), hi_x > 10.0);
      EXPECT_GT(each.cells().size(), 20u);
      EXPECT_EQ(four.cells(), each.cells()) << "cell " << cell_m << ", box to " << hi_x;
    }
  }
}
#endif

TEST(Footprint, MarksRefuseFarCoordinates) {
  // Beyond 1e6 m the margins of the tiles lose metres in float: trunkHeightCells is used.
  HeightCellMarks marks;
  const std::vector<float> s = {1.0f, 2.0f};
  EXPECT_FALSE(marks.init(s, s, s, 1.0, Eigen::Vector2d(2e6, 0.0), Eigen::Vector2d(2e6 + 10, 10)));
  EXPECT_FALSE(marks.init({}, {}, {}, 1.0, Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(10, 10)));
}

// The ground of a window's samples by DATASET.md: the k-th smallest z, k = 5 % of them rounded
// down (the window not empty).
float windowGround(std::vector<float> window) {
  const auto k = window.begin() + static_cast<std::ptrdiff_t>(0.05 * (window.size() - 1.0));
  std::nth_element(window.begin(), k, window.end());
  return *k;
}

// DATASET.md's cells by its words, point by point: a tile's ground is the k-th smallest z
// (k = 5 % of them, rounded down) of the samples in the 3 x 3 tiles of 2 m around it, the
// samples being every stride-th point.
Cells cellsByTheDefinition(const Cloud& cloud, size_t stride) {
  using Tile = std::pair<int64_t, int64_t>;
  const auto tile = [](float x, float y) {
    return Tile(static_cast<int64_t>(std::floor(x / 2.0)),
                static_cast<int64_t>(std::floor(y / 2.0)));
  };
  std::map<Tile, std::vector<float>> z_of;
  for (size_t i = 0; i < cloud.size(); i += stride)
    z_of[tile(cloud[i].x, cloud[i].y)].push_back(cloud[i].z);
  std::map<Tile, float> ground;  // NaN: no sample in the window
  const auto groundOf = [&](const Tile& t) {
    const auto known = ground.find(t);
    if (known != ground.end()) return known->second;
    std::vector<float> window;
    for (int64_t dx = -1; dx <= 1; ++dx) {
      for (int64_t dy = -1; dy <= 1; ++dy) {
        const auto it = z_of.find({t.first + dx, t.second + dy});
        if (it != z_of.end()) window.insert(window.end(), it->second.begin(), it->second.end());
      }
    }
    return ground[t] =
               window.empty() ? std::numeric_limits<float>::quiet_NaN() : windowGround(window);
  };
  Cells out;
  for (const pcl::PointXYZ& q : cloud) {
    const float h = q.z - groundOf(tile(q.x, q.y));
    if (h >= 0.3 && h <= 3.0)
      out.emplace_back(static_cast<int64_t>(std::floor(q.x)),
                       static_cast<int64_t>(std::floor(q.y)));
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

// n points over [-15, 17] x [-11, 13] m: ground crossing z = 0 on a slope, and clutter up to 5 m
// above it on a share of them; z in 1 cm steps (ties, -0 and +0 among them) when quantised.
Cloud slopeAcrossZero(uint32_t seed, int n, bool quantised) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Cloud cloud;
  for (int i = 0; i < n; ++i) {
    const float x = -15.0f + 32.0f * u(rng), y = -11.0f + 24.0f * u(rng);
    const float ground = 0.04f * x - 0.3f + 0.3f * std::sin(0.5f * y);
    const float up = u(rng) < 0.6f ? 0.1f * u(rng) : 5.0f * u(rng) * u(rng);
    float z = ground + up;
    if (quantised) z = std::round(z * 100.0f) / 100.0f;
    if (z == 0.0f) z = i % 2 ? -0.0f : 0.0f;
    cloud.push_back(pcl::PointXYZ(x, y, z));
  }
  return cloud;
}

TEST(Footprint, TrunkHeightCellsAreTheWindowPercentilesCells) {
  // The cells of the definition, with every point as the ground samples and with every 7th: on
  // a dense cloud with ties and on a sparse one (~190 samples a window), where the next value
  // of a window lies ~1 cm above its 5th percentile and a wrong rank moves cells.
  for (const auto& [n, quantised] : {std::make_pair(30000, true), std::make_pair(4000, false)}) {
    const Cloud cloud = slopeAcrossZero(41, n, quantised);
    for (const size_t stride : {size_t{1}, size_t{7}}) {
      const Cells expected = cellsByTheDefinition(cloud, stride);
      EXPECT_GT(expected.size(), 200u);
      const size_t max_samples = stride == 1 ? 0 : cloud.size() / stride;
      EXPECT_EQ(trunkHeightCells(cloud, Pose::Identity(), 1.0, max_samples), expected)
          << n << " points, samples every " << stride << " points";
    }
  }
}

TEST(Footprint, TrunkHeightCellsMeasureFromTheExactPercentile) {
  // Ground-level samples (every 2nd point) only, and between them probes 0.01 mm inside and
  // outside both edges of the band above the definition's ground of their tile, one a cell: a
  // ground off by the next value of its window (~0.1 mm here, ~900 samples) moves a probe's
  // cell.
  std::mt19937 rng(43);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Cloud samples;
  for (int i = 0; i < 20000; ++i) {
    const float x = -15.0f + 32.0f * u(rng), y = -11.0f + 24.0f * u(rng);
    samples.push_back(pcl::PointXYZ(x, y, 0.1f * u(rng) - 0.05f));  // level: every tile counts
  }
  Cloud probes;
  Cells inside;
  for (int64_t tx = -7; tx < 8; ++tx) {
    for (int64_t ty = -5; ty < 6; ++ty) {
      std::vector<float> window;  // the definition's ground of tile (tx, ty)
      for (const pcl::PointXYZ& q : samples) {
        if (std::abs(static_cast<int64_t>(std::floor(q.x / 2.0)) - tx) <= 1 &&
            std::abs(static_cast<int64_t>(std::floor(q.y / 2.0)) - ty) <= 1)
          window.push_back(q.z);
      }
      const float ground = windowGround(window);
      constexpr float kEps = 1e-5f;
      const float up[4] = {0.3f + kEps, 0.3f - kEps, 3.0f - kEps, 3.0f + kEps};  // in, out, ...
      for (int c = 0; c < 4; ++c) {
        const int64_t cx = 2 * tx + c % 2, cy = 2 * ty + c / 2;
        probes.push_back(pcl::PointXYZ(cx + 0.5f, cy + 0.5f, ground + up[c]));
        if (c % 2 == 0) inside.emplace_back(cx, cy);
      }
    }
  }
  ASSERT_LE(probes.size(), samples.size());
  Cloud cloud;
  for (size_t i = 0; i < samples.size(); ++i) {
    cloud.push_back(samples[i]);
    cloud.push_back(i < probes.size() ? probes[i] : samples[i]);  // no sample, below the band
  }
  std::sort(inside.begin(), inside.end());
  ASSERT_EQ(cellsByTheDefinition(cloud, 2), inside);
  EXPECT_EQ(trunkHeightCells(cloud, Pose::Identity(), 1.0, cloud.size() / 2), inside);
}

TEST(Footprint, TrunkHeightCellsOfAStemOnFlatGround) {
  // Flat ground over 12 m x 12 m and a 0.2 m stem at (5.5, 6.5) up to 5 m: only the stem's
  // cells hold points 0.3-3 m above the local ground.
  Cloud cloud;
  for (int i = 0; i < 120; ++i)
    for (int j = 0; j < 120; ++j) cloud.push_back(pcl::PointXYZ(0.1f * i, 0.1f * j, 0.0f));
  for (int k = 0; k < 50; ++k)
    for (int a = 0; a < 24; ++a) {
      const double th = a * M_PI / 12.0;
      cloud.push_back(pcl::PointXYZ(static_cast<float>(5.5 + 0.2 * std::cos(th)),
                                    static_cast<float>(6.5 + 0.2 * std::sin(th)), 0.1f * k));
    }
  const Cells cells = trunkHeightCells(cloud, Pose::Identity(), 1.0);
  EXPECT_EQ(cells, Cells({{5, 6}}));
  // In a frame F shifted by (10, -20): the same cell, moved.
  EXPECT_EQ(trunkHeightCells(cloud, shifted(10.0, -20.0), 1.0), Cells({{15, -14}}));
  // Subsampled ground percentiles see the same ground here.
  EXPECT_EQ(trunkHeightCells(cloud, Pose::Identity(), 1.0, 1000), cells);
  // A stray point 100 km away switches the tiles to the sparse index: same cells (the stray
  // point is its own ground).
  cloud.push_back(pcl::PointXYZ(1e5f, 1e5f, 7.0f));
  EXPECT_EQ(trunkHeightCells(cloud, Pose::Identity(), 1.0), cells);
  EXPECT_TRUE(trunkHeightCells(cloud, Pose::Identity(), 0.0).empty());
  EXPECT_TRUE(trunkHeightCells(Cloud(), Pose::Identity(), 1.0).empty());
}

}  // namespace
}  // namespace dtif
