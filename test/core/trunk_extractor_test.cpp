// Trunk extraction on fixed-seed synthetic forest plots: sloped noisy ground, stems with known
// centres / radii / bases, partial visibility, and clutter that must not become trunks.
#include "dtif/core/extraction/trunk_extractor.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "dtif/core/extraction/extraction_stages.h"

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Stem {
  double x, y, r;
  double arc_deg = 360.0;   // visible arc, centred on facing_deg
  double facing_deg = 0.0;  // direction (from the centre) of the visible side
};

// Synthetic plot: ground z = sx * x + sy * y + bumps, stems as noisy cylinder surfaces that
// start at the local ground under each surface point.
class Plot {
 public:
  Plot(double sx, double sy, uint32_t seed) : sx_(sx), sy_(sy), rng_(seed) {}

  double groundZ(double x, double y) const {
    return sx_ * x + sy_ * y + 0.05 * std::sin(0.7 * x) * std::cos(0.5 * y);
  }

  void addGround(double x0, double x1, double y0, double y1, double step, double noise) {
    std::uniform_real_distribution<double> jit(-0.5 * step, 0.5 * step);
    std::normal_distribution<double> nz(0.0, noise);
    for (double x = x0; x <= x1; x += step)
      for (double y = y0; y <= y1; y += step) {
        const double px = x + jit(rng_), py = y + jit(rng_);
        push(px, py, groundZ(px, py) + nz(rng_));
      }
  }

  // Stem surface from h0 above the ground (h0 > 0: its foot is hidden) up to `height`.
  void addStem(const Stem& s, double height = 6.0, double noise = 0.01, double step = 0.04,
               double h0 = 0.0) {
    std::normal_distribution<double> nz(0.0, noise);
    const double dth = step / s.r;
    const double half = 0.5 * s.arc_deg * kPi / 180.0, face = s.facing_deg * kPi / 180.0;
    for (double th = face - half; th < face + half; th += dth) {
      const double px = s.x + s.r * std::cos(th), py = s.y + s.r * std::sin(th);
      const double gz = groundZ(px, py);
      for (double h = h0; h < height; h += step) {
        const double rr = s.r + nz(rng_);
        push(s.x + rr * std::cos(th), s.y + rr * std::sin(th), gz + h + nz(rng_));
      }
    }
  }

  // Pole of radius r whose axis leans by lean_deg towards +x from its foot (x, y).
  void addLeaningPole(double x, double y, double r, double lean_deg, double length = 5.0) {
    std::normal_distribution<double> nz(0.0, 0.01);
    const double t = lean_deg * kPi / 180.0;
    const Eigen::Vector3d axis(std::sin(t), 0.0, std::cos(t));
    const Eigen::Vector3d u(std::cos(t), 0.0, -std::sin(t)), v(0.0, 1.0, 0.0);
    const Eigen::Vector3d foot(x, y, groundZ(x, y));
    for (double s = 0.0; s < length; s += 0.04)
      for (double th = 0.0; th < 2.0 * kPi; th += 0.04 / r) {
        const Eigen::Vector3d q =
            foot + s * axis + (r + nz(rng_)) * (std::cos(th) * u + std::sin(th) * v);
        push(q.x(), q.y(), q.z());
      }
  }

  // Shrub: points filling an ellipsoid standing on the ground (leaves scatter everywhere).
  void addShrub(double x, double y, double rxy, double height, int points) {
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int made = 0;
    while (made < points) {
      const double a = u(rng_), b = u(rng_), c = u(rng_);
      if (a * a + b * b + c * c > 1.0) continue;
      const double px = x + rxy * a, py = y + rxy * b;
      push(px, py, groundZ(px, py) + 0.5 * height * (c + 1.0));
      ++made;
    }
  }

  // Log lying on the ground along x.
  void addLog(double x, double y, double r, double length) {
    std::normal_distribution<double> nz(0.0, 0.01);
    for (double s = 0.0; s < length; s += 0.04)
      for (double th = 0.0; th < kPi; th += 0.04 / r) {
        const double px = x + s, py = y + r * std::cos(th);
        push(px, py, groundZ(px, y) + r + (r + nz(rng_)) * std::sin(th));
      }
  }

  void push(double x, double y, double z) {
    cloud.push_back(pcl::PointXYZ(static_cast<float>(x + off_x), static_cast<float>(y + off_y),
                                  static_cast<float>(z + off_z)));
  }

  Cloud cloud;
  double off_x = 0.0, off_y = 0.0, off_z = 0.0;

 private:
  double sx_, sy_;
  std::mt19937 rng_;
};

// Index of the extracted trunk nearest to (x, y), or -1 when none is within max_d.
int nearest(const Trunks& trunks, double x, double y, double max_d) {
  int best = -1;
  double bd = max_d;
  for (size_t i = 0; i < trunks.size(); ++i) {
    const double d = std::hypot(trunks[i].x - x, trunks[i].y - y);
    if (d < bd) bd = d, best = static_cast<int>(i);
  }
  return best;
}

const std::vector<Stem> kStems = {
    {-6.0, -5.0, 0.12}, {-2.0, 4.0, 0.20}, {3.0, -3.0, 0.30}, {6.0, 5.0, 0.16},
    {-7.0, 6.0, 0.25},  {1.0, 0.5, 0.09},  {7.5, -7.0, 0.35}, {-3.5, -1.0, 0.18},
};

// Checks every stem is found with the given accuracy and nothing else is reported.
void expectStems(const Plot& plot, const std::vector<Stem>& stems, const Trunks& trunks,
                 double max_centre, double max_radius, double max_base) {
  EXPECT_EQ(trunks.size(), stems.size());
  for (const Stem& s : stems) {
    const double x = s.x + plot.off_x, y = s.y + plot.off_y;
    const int k = nearest(trunks, x, y, 0.5);
    ASSERT_GE(k, 0) << "stem at " << s.x << "," << s.y << " not found";
    const TrunkLandmark& t = trunks[k];
    EXPECT_LT(std::hypot(t.x - x, t.y - y), max_centre) << "stem " << s.x << "," << s.y;
    EXPECT_NEAR(t.r, s.r, max_radius) << "stem " << s.x << "," << s.y;
    EXPECT_NEAR(t.z, plot.groundZ(s.x, s.y) + plot.off_z, max_base) << "stem " << s.x << "," << s.y;
  }
}

TEST(TrunkExtractor, DefaultParamsValidate) { EXPECT_EQ(TrunkExtractorParams().validate(), ""); }

TEST(TrunkExtractor, ValidateNamesTheBadField) {
  TrunkExtractorParams p;
  p.column_cell_m = 0.0;
  EXPECT_NE(p.validate().find("column_cell_m"), std::string::npos);
  p = TrunkExtractorParams();
  p.fit_max_h_m = 0.5;  // below fit_min_h_m
  EXPECT_NE(p.validate().find("fit_max_h_m"), std::string::npos);
  p = TrunkExtractorParams();
  p.ground_percentile = 1.5;
  EXPECT_NE(p.validate().find("ground_percentile"), std::string::npos);
  p = TrunkExtractorParams();
  p.max_radius_m = 0.01;
  EXPECT_NE(p.validate().find("max_radius_m"), std::string::npos);
  p = TrunkExtractorParams();
  p.layer_h_m = 0.01;  // 260 layers do not fit the 64-bit occupancy mask
  EXPECT_NE(p.validate().find("layer_h_m"), std::string::npos);
}

TEST(TrunkExtractor, VisitListsEveryKeyOnce) {
  TrunkExtractorParams p;
  std::vector<std::string> keys;
  auto v = [&](const char* k, auto&) { keys.push_back(k); };
  p.visit(v);
  EXPECT_EQ(keys.size(), 60u);
  std::sort(keys.begin(), keys.end());
  EXPECT_EQ(std::unique(keys.begin(), keys.end()), keys.end());
}

TEST(TrunkExtractor, EmptyAndDegenerateInputs) {
  TrunkExtractorParams p;
  Cloud empty;
  EXPECT_TRUE(extractTrunks(empty, p).trunks.empty());

  Cloud nan_only;
  const float q = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  for (int i = 0; i < 100; ++i) nan_only.push_back(pcl::PointXYZ(q, i, inf));
  auto r = extractTrunks(nan_only, p);
  EXPECT_TRUE(r.trunks.empty());
  EXPECT_EQ(r.stats.input_points, 100u);
  EXPECT_EQ(r.stats.finite_points, 0u);

  Cloud one_point;  // the same point many times
  for (int i = 0; i < 1000; ++i) one_point.push_back(pcl::PointXYZ(1, 2, 3));
  EXPECT_TRUE(extractTrunks(one_point, p).trunks.empty());

  Cloud vertical_line;  // a wire: all points on one vertical line, no circle possible
  for (int i = 0; i < 1000; ++i) vertical_line.push_back(pcl::PointXYZ(1, 2, 0.005f * i));
  EXPECT_TRUE(extractTrunks(vertical_line, p).trunks.empty());

  // Invalid parameters: empty result, no exception.
  TrunkExtractorParams bad;
  bad.column_cell_m = -1.0;
  Plot plot(0.0, 0.0, 3);
  plot.addGround(-3, 3, -3, 3, 0.1, 0.01);
  plot.addStem({0.0, 0.0, 0.2});
  EXPECT_TRUE(extractTrunks(plot.cloud, bad).trunks.empty());
  EXPECT_EQ(extractTrunks(plot.cloud, p).trunks.size(), 1u);
}

TEST(TrunkExtractor, GroundOnlyGivesNoTrunks) {
  Plot plot(0.3, -0.2, 11);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  EXPECT_TRUE(extractTrunks(plot.cloud, TrunkExtractorParams()).trunks.empty());
}

TEST(TrunkExtractor, FindsStemsOnSlopedNoisyGround) {
  Plot plot(0.30, 0.10, 1);  // ~17.5 deg slope
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  expectStems(plot, kStems, res.trunks, 0.02, 0.01, 0.05);
}

TEST(TrunkExtractor, FindsStemsOnSteep25DegreeSlope) {
  const double s = std::tan(25.0 * kPi / 180.0);
  Plot plot(s * std::cos(0.6), s * std::sin(0.6), 2);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& st : kStems) plot.addStem(st);
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  expectStems(plot, kStems, res.trunks, 0.02, 0.01, 0.05);
}

TEST(TrunkExtractor, SeenBasesAreMeasuredHiddenBasesAreFlagged) {
  // A helmet MID-360 sees no lower than -7 deg: on one side of this plot the ground was never
  // hit and the stems show only from 1.0 m above it (as if cut by the field-of-view cone).
  Plot plot(0.12, 0.05, 21);
  plot.addGround(-10, -0.5, -10, 10, 0.1, 0.02);
  const std::vector<Stem> seen = {
      {-6.0, -5.0, 0.12}, {-2.0, 4.0, 0.20}, {-7.0, 6.0, 0.25}, {-3.5, -1.0, 0.18}};
  const std::vector<Stem> hidden = {{3.0, -3.0, 0.30}, {6.0, 5.0, 0.16}, {7.5, -7.0, 0.35}};
  for (const Stem& s : seen) plot.addStem(s);
  for (const Stem& s : hidden) plot.addStem(s, 8.0, 0.01, 0.04, /*h0=*/1.0);
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  for (const Stem& s : seen) {
    const int k = nearest(res.trunks, s.x, s.y, 0.3);
    ASSERT_GE(k, 0) << "stem at " << s.x << "," << s.y << " not found";
    EXPECT_TRUE(res.trunks[k].base_seen) << "stem at " << s.x << "," << s.y;
    EXPECT_NEAR(res.trunks[k].z, plot.groundZ(s.x, s.y), 0.05) << "stem " << s.x << "," << s.y;
  }
  int flagged = 0;
  for (const Stem& s : hidden) {
    const int k = nearest(res.trunks, s.x, s.y, 0.5);
    if (k < 0) continue;  // not finding a stem without its foot is acceptable
    EXPECT_FALSE(res.trunks[k].base_seen) << "stem at " << s.x << "," << s.y;
    ++flagged;
  }
  EXPECT_GE(flagged, 2);  // stems without their foot are still found, but flagged
  EXPECT_EQ(res.stats.unseen_bases, static_cast<size_t>(flagged));
  // Every trunk of the sloped plots above has its base seen.
  Plot full(0.30, 0.10, 1);
  full.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) full.addStem(s);
  const auto all = extractTrunks(full.cloud, TrunkExtractorParams());
  EXPECT_EQ(all.stats.unseen_bases, 0u);
  for (const TrunkLandmark& t : all.trunks) EXPECT_TRUE(t.base_seen);
}

// Dense understory: a mat of low vegetation 0.6 m high hides the ground and the stem's foot,
// and from above it looks like ground. A few returns through gaps in the ring around the stem
// show lower ground, so the base on the mat must not count as seen (it would be 0.6 m high).
TEST(TrunkExtractor, BaseOnAVegetationMatIsNotSeen) {
  auto makePlot = [](bool gaps) {
    Plot plot(0.0, 0.0, 31);
    std::mt19937 rng(32);
    std::uniform_real_distribution<double> u(-0.05, 0.05), ang(-kPi, kPi), rad(0.5, 1.3);
    std::normal_distribution<double> nz(0.0, 0.02);
    for (double x = -10; x <= 10; x += 0.1) {
      for (double y = -10; y <= 10; y += 0.1) {
        const double px = x + u(rng), py = y + u(rng);
        const bool mat = std::abs(px) < 6.0 && std::abs(py) < 6.0;
        if (mat && std::hypot(px, py) < 0.2) continue;  // the stem stands through the mat
        plot.push(px, py, plot.groundZ(px, py) + (mat ? 0.6 : 0.0) + nz(rng));
      }
    }
    if (gaps) {
      for (int k = 0; k < 8; ++k) {
        const double a = ang(rng), r = rad(rng);
        const double px = r * std::cos(a), py = r * std::sin(a);
        plot.push(px, py, plot.groundZ(px, py) + nz(rng));
      }
    }
    plot.addStem({0.0, 0.0, 0.15}, 8.0, 0.01, 0.04, /*h0=*/0.6);
    return plot;
  };
  const Plot with_gaps = makePlot(true);
  const auto res = extractTrunks(with_gaps.cloud, TrunkExtractorParams());
  const int k = nearest(res.trunks, 0.0, 0.0, 0.3);
  ASSERT_GE(k, 0);
  EXPECT_FALSE(res.trunks[k].base_seen);
  // Without the check the base on the mat counts as seen, 0.6 m too high.
  TrunkExtractorParams no_check;
  no_check.max_base_below_points = 1000000;
  const auto unchecked = extractTrunks(with_gaps.cloud, no_check);
  const int ku = nearest(unchecked.trunks, 0.0, 0.0, 0.3);
  ASSERT_GE(ku, 0);
  EXPECT_TRUE(unchecked.trunks[ku].base_seen);
  EXPECT_NEAR(unchecked.trunks[ku].z, with_gaps.groundZ(0.0, 0.0) + 0.6, 0.1);
  // Where nothing shows through the mat there is nothing to contradict it (a known limit).
  const Plot no_gaps = makePlot(false);
  const auto closed = extractTrunks(no_gaps.cloud, TrunkExtractorParams());
  const int kc = nearest(closed.trunks, 0.0, 0.0, 0.3);
  ASSERT_GE(kc, 0);
  EXPECT_TRUE(closed.trunks[kc].base_seen);
}

TEST(TrunkExtractor, FootprintHoldsWhatStandsAboveTheGround) {
  Plot plot(0.0, 0.0, 8);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  TrunkExtractorParams params;
  const auto res = extractTrunks(plot.cloud, params);
  const Footprint& f = res.footprint;
  ASSERT_FALSE(f.empty());
  EXPECT_EQ(f.cell_m, params.footprint_cell_m);
  for (const Stem& s : kStems) {
    EXPECT_TRUE(
        f.occupied(static_cast<int64_t>(std::floor(s.x)), static_cast<int64_t>(std::floor(s.y))))
        << "stem " << s.x << "," << s.y;
  }
  // Bare ground (0-5 cm above its 5th percentile) is no part of it: only the stems' cells.
  EXPECT_GE(f.count(), kStems.size());
  EXPECT_LE(f.count(), 4 * kStems.size());
  params.footprint_cell_m = 0.0;
  EXPECT_TRUE(extractTrunks(plot.cloud, params).footprint.empty());
}

TEST(TrunkExtractor, PartiallyVisibleStemsKeepTheirRadius) {
  Plot plot(0.15, 0.0, 4);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  std::vector<Stem> stems = kStems;
  for (size_t i = 0; i < stems.size(); ++i) {
    stems[i].arc_deg = 150.0;  // seen from one side only (a single MLS pass)
    stems[i].facing_deg = 45.0 * i;
  }
  for (const Stem& s : stems) plot.addStem(s);
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  expectStems(plot, stems, res.trunks, 0.03, 0.015, 0.05);
}

TEST(TrunkExtractor, RejectsClutter) {
  Plot plot(0.2, 0.1, 5);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  plot.addLeaningPole(4.0, 0.0, 0.12, 25.0);
  plot.addLeaningPole(-8.0, 0.0, 0.10, 40.0);
  plot.addShrub(-5.0, 2.0, 0.8, 1.2, 4000);  // low bush
  plot.addShrub(0.0, 6.0, 0.6, 2.8, 8000);   // tall dense shrub, continuous over the slab
  plot.addLog(-1.0, -7.5, 0.25, 5.0);        // fallen log
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  expectStems(plot, kStems, res.trunks, 0.02, 0.01, 0.05);
  EXPECT_LT(nearest(res.trunks, 4.5, 0.0, 1.2), 0) << "leaning pole taken as trunk";
  EXPECT_LT(nearest(res.trunks, -7.0, 0.0, 1.5), 0) << "leaning pole taken as trunk";
  EXPECT_LT(nearest(res.trunks, -5.0, 2.0, 1.0), 0) << "bush taken as trunk";
  EXPECT_LT(nearest(res.trunks, 0.0, 6.0, 1.0), 0) << "shrub taken as trunk";
  EXPECT_LT(nearest(res.trunks, 1.5, -7.5, 2.6), 0) << "log taken as trunk";
}

TEST(TrunkExtractor, SeparatesCloseStems) {
  // Bark 0.15 m apart: their columns merge into one candidate, both must come out.
  Plot plot(0.0, 0.1, 6);
  plot.addGround(-5, 5, -5, 5, 0.1, 0.02);
  const std::vector<Stem> stems = {{0.0, 0.0, 0.2}, {0.55, 0.0, 0.2}};
  for (const Stem& s : stems) plot.addStem(s);
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  expectStems(plot, stems, res.trunks, 0.02, 0.01, 0.05);
}

TEST(TrunkExtractor, NaNsAndHugeOffsetChangeNothing) {
  Plot a(0.2, 0.1, 7);
  a.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) a.addStem(s);
  Plot b(0.2, 0.1, 7);  // same seed: the same plot, shifted and with NaNs
  b.off_x = 1.0e5, b.off_y = 2.0e5, b.off_z = 1.0e3;
  b.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) b.addStem(s);
  const float q = std::numeric_limits<float>::quiet_NaN();
  for (size_t i = 0; i < b.cloud.size(); i += 50)
    b.cloud.points.insert(b.cloud.begin() + i, pcl::PointXYZ(q, q, q));
  const auto ra = extractTrunks(a.cloud, TrunkExtractorParams());
  const auto rb = extractTrunks(b.cloud, TrunkExtractorParams());
  EXPECT_LT(rb.stats.finite_points, rb.stats.input_points);
  ASSERT_EQ(ra.trunks.size(), kStems.size());
  ASSERT_EQ(rb.trunks.size(), ra.trunks.size());
  // float32 steps are ~16 mm at 2e5 m: the results agree to that, not to the bit.
  for (size_t i = 0; i < ra.trunks.size(); ++i) {
    EXPECT_NEAR(rb.trunks[i].x - b.off_x, ra.trunks[i].x, 0.02);
    EXPECT_NEAR(rb.trunks[i].y - b.off_y, ra.trunks[i].y, 0.02);
    EXPECT_NEAR(rb.trunks[i].z - b.off_z, ra.trunks[i].z, 0.02);
    EXPECT_NEAR(rb.trunks[i].r, ra.trunks[i].r, 0.01);
  }
}

TEST(TrunkExtractor, WorksAtUtmLikeOffset) {
  Plot plot(0.2, 0.1, 8);
  plot.off_x = 1.0e5, plot.off_y = -1.0e5, plot.off_z = 500.0;  // float step ~8 mm
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  const float q = std::numeric_limits<float>::quiet_NaN();
  for (size_t i = 0; i < plot.cloud.size(); i += 37) plot.cloud.points[i].y = q;
  const auto res = extractTrunks(plot.cloud, TrunkExtractorParams());
  expectStems(plot, kStems, res.trunks, 0.02, 0.01, 0.05);
}

TEST(TrunkExtractor, IsDeterministic) {
  Plot plot(0.2, 0.1, 9);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  plot.addShrub(0.0, 6.0, 0.6, 2.8, 8000);
  const auto a = extractTrunks(plot.cloud, TrunkExtractorParams());
  const auto b = extractTrunks(plot.cloud, TrunkExtractorParams());
  ASSERT_EQ(a.trunks.size(), b.trunks.size());
  for (size_t i = 0; i < a.trunks.size(); ++i) {
    EXPECT_EQ(a.trunks[i].x, b.trunks[i].x);
    EXPECT_EQ(a.trunks[i].y, b.trunks[i].y);
    EXPECT_EQ(a.trunks[i].z, b.trunks[i].z);
    EXPECT_EQ(a.trunks[i].r, b.trunks[i].r);
  }
}

TEST(CircleFit, RecoversCircleFromArcWithOutliers) {
  std::mt19937 rng(12);
  std::normal_distribution<double> nz(0.0, 0.005);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::Vector2d> xy;
  // One draw per statement, in the order gcc evaluated these arguments (last first), so the
  // data are the same whatever the compiler.
  for (double th = 0.3; th < 0.3 + 2.2; th += 0.01) {  // 126 deg arc
    const double ry = 0.25 + nz(rng);
    const double rx = 0.25 + nz(rng);
    xy.emplace_back(2.0 + rx * std::cos(th), -1.0 + ry * std::sin(th));
  }
  for (int i = 0; i < 80; ++i) {
    const double y = -1.0 + 0.8 * u(rng);
    xy.emplace_back(2.0 + 0.8 * u(rng), y);
  }
  const CircleFit f = fitCircleRobust(xy, CircleFitParams());
  ASSERT_TRUE(f.ok);
  EXPECT_NEAR(f.cx, 2.0, 0.01);
  EXPECT_NEAR(f.cy, -1.0, 0.01);
  EXPECT_NEAR(f.r, 0.25, 0.005);
  // Coverage ignores gaps narrower than 20 deg, so a stray inlier just past an end of the arc
  // may extend it by up to that much on each side.
  EXPECT_GE(f.arc_deg, 120.0);
  EXPECT_LE(f.arc_deg, 126.0 + 2 * 20.0);
  EXPECT_LT(f.rms_m, 0.01);
}

TEST(CircleFit, DegenerateInputsFailCleanly) {
  EXPECT_FALSE(fitCircleRobust({}, CircleFitParams()).ok);
  EXPECT_FALSE(fitCircleRobust({{0, 0}, {1, 1}}, CircleFitParams()).ok);
  std::vector<Eigen::Vector2d> line;
  for (int i = 0; i < 100; ++i) line.emplace_back(0.01 * i, 0.02 * i);
  EXPECT_FALSE(fitCircleRobust(line, CircleFitParams()).ok);
  std::vector<Eigen::Vector2d> same(50, Eigen::Vector2d(1, 1));
  EXPECT_FALSE(fitCircleRobust(same, CircleFitParams()).ok);
}

}  // namespace
}  // namespace dtif

namespace dtif {
namespace {

void expectSameTrunks(const TrunkExtractionResult& a, const TrunkExtractionResult& b) {
  ASSERT_EQ(a.trunks.size(), b.trunks.size());
  for (size_t i = 0; i < a.trunks.size(); ++i) {
    EXPECT_EQ(a.trunks[i].x, b.trunks[i].x);
    EXPECT_EQ(a.trunks[i].y, b.trunks[i].y);
    EXPECT_EQ(a.trunks[i].z, b.trunks[i].z);
    EXPECT_EQ(a.trunks[i].r, b.trunks[i].r);
  }
  EXPECT_EQ(a.footprint.bits, b.footprint.bits);
}

// Issue #17: one stray return far away sized the grids by its distance (2 GB and a lost trunk
// at 1e7 m, bad_alloc at 9e7 m), and as the first point it cost every other point its float
// precision (no trunks at all). It is dropped, counted, and changes nothing else.
TEST(TrunkExtractor, OneStrayFarPointIsDroppedAndChangesNothing) {
  Plot plot(0.2, 0.1, 10);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  const TrunkExtractorParams p;
  const auto clean = extractTrunks(plot.cloud, p);
  ASSERT_EQ(clean.trunks.size(), kStems.size());
  EXPECT_EQ(clean.stats.far_points, 0u);
  for (const pcl::PointXYZ far : {pcl::PointXYZ(1e7f, 0.f, 0.f), pcl::PointXYZ(9e7f, 9e7f, 0.f),
                                  pcl::PointXYZ(0.f, 0.f, 1e7f), pcl::PointXYZ(300.f, 0.f, 0.f)}) {
    for (const bool first : {false, true}) {
      Cloud c = plot.cloud;
      if (first)
        c.points.insert(c.points.begin(), far);
      else
        c.push_back(far);
      const auto res = extractTrunks(c, p);
      SCOPED_TRACE(testing::Message() << far << (first ? " first" : " last"));
      EXPECT_EQ(res.stats.far_points, 1u);
      EXPECT_EQ(res.stats.finite_points, plot.cloud.size() + 1);
      expectSameTrunks(clean, res);
    }
  }
}

TEST(TrunkExtractor, CloudOverMaxPointsIsRefusedWhole) {
  Plot plot(0.2, 0.1, 11);
  plot.addGround(-10, 10, -10, 10, 0.1, 0.02);
  for (const Stem& s : kStems) plot.addStem(s);
  TrunkExtractorParams p;
  p.max_points = static_cast<int>(plot.cloud.size()) - 1;
  const auto res = extractTrunks(plot.cloud, p);
  EXPECT_TRUE(res.stats.over_point_limit);
  EXPECT_TRUE(res.trunks.empty());
  p.max_points = static_cast<int>(plot.cloud.size());
  EXPECT_EQ(extractTrunks(plot.cloud, p).trunks.size(), kStems.size());
}

// Issue #17: ground_window_m: 1e9 hung, ground_cell_m: 0.01 was 1000 times slower.
TEST(TrunkExtractor, BoundsAreValidated) {
  TrunkExtractorParams p;
  p.ground_window_m = 1e9;
  EXPECT_NE(p.validate().find("ground_window_m"), std::string::npos);
  p = TrunkExtractorParams();
  p.ground_cell_m = 0.01;
  EXPECT_NE(p.validate().find("ground_cell_m"), std::string::npos);
  p = TrunkExtractorParams();
  p.max_range_m = 1e9;
  EXPECT_NE(p.validate().find("max_range_m"), std::string::npos);
  p = TrunkExtractorParams();
  p.max_points = 0;
  EXPECT_NE(p.validate().find("max_points"), std::string::npos);
}

// Issue #15 part 3: a unit that keeps every third return. A plot seen from the origin (the
// sensor): five stems 10 m out that any density shows, and thin stems whose breast-height band
// holds ~80 points at full density, ~27 at a third. With min_fit_points 36 (the mechanism
// scales whatever the thresholds are) the thin stems need the adaptation at a third.
Plot densityPlot(double step, std::vector<Stem>* thick, std::vector<Stem>* thin) {
  Plot plot(0.05, 0.0, 31);
  plot.addGround(-13, 13, -13, 13, 0.1, 0.02);
  for (int k = 0; k < 5; ++k) {
    const double a = k * 72.0 * kPi / 180.0;
    thick->push_back({10.0 * std::cos(a), 10.0 * std::sin(a), 0.2, 180.0, k * 72.0 + 180.0});
  }
  for (int k = 0; k < 2; ++k) {
    const double a = (36.0 + k * 144.0) * kPi / 180.0;
    thin->push_back({9.0 * std::cos(a), 9.0 * std::sin(a), 0.08, 180.0, 36.0 + k * 144.0 + 180.0});
  }
  for (const Stem& s : *thick) plot.addStem(s, 4.0, 0.005, step);
  for (const Stem& s : *thin) plot.addStem(s, 4.0, 0.005, step);
  return plot;
}

// A random third of the points, fixed seed (FAST-LIO2 keeps every third return of a scan
// pattern that does not repeat: no pattern on the bark).
Cloud thirdOf(const Cloud& cloud) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> pick(0, 2);
  Cloud out;
  for (const pcl::PointXYZ& q : cloud)
    if (pick(rng) == 0) out.push_back(q);
  return out;
}

void expectSame(const Trunks& a, const Trunks& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].x, b[i].x);
    EXPECT_EQ(a[i].y, b[i].y);
    EXPECT_EQ(a[i].z, b[i].z);
    EXPECT_EQ(a[i].r, b[i].r);
    EXPECT_EQ(a[i].base_seen, b[i].base_seen);
  }
}

TEST(TrunkExtractor, DensityAdaptationFindsThinStemsAtAThirdOfTheReturns) {
  std::vector<Stem> thick, thin;
  const Plot plot = densityPlot(0.05, &thick, &thin);  // bark: 400 points per m^2
  TrunkExtractorParams fixed;
  fixed.min_fit_points = 36;
  fixed.density_reference = 0.0;
  TrunkExtractorParams adaptive = fixed;
  adaptive.density_reference = 300.0;

  // Full density (above the reference): the adaptation changes nothing.
  const auto full = extractTrunks(plot.cloud, adaptive);
  EXPECT_GT(full.stats.density, 300.0);
  EXPECT_EQ(full.stats.density_scale, 1.0);
  expectSame(full.trunks, extractTrunks(plot.cloud, fixed).trunks);
  EXPECT_EQ(full.trunks.size(), thick.size() + thin.size());

  const Cloud third = thirdOf(plot.cloud);
  const auto without = extractTrunks(third, fixed);
  const auto with = extractTrunks(third, adaptive);
  // Measured near a third of the full density; the thresholds halved (density_min_scale).
  EXPECT_NEAR(with.stats.density, full.stats.density / 3.0, 0.1 * full.stats.density);
  EXPECT_EQ(with.stats.density_scale, adaptive.density_min_scale);
  for (const Stem& s : thick) {
    EXPECT_GE(nearest(without.trunks, s.x, s.y, 0.05), 0) << s.x << "," << s.y;
    EXPECT_GE(nearest(with.trunks, s.x, s.y, 0.05), 0) << s.x << "," << s.y;
  }
  for (const Stem& s : thin) {
    EXPECT_LT(nearest(without.trunks, s.x, s.y, 0.5), 0) << s.x << "," << s.y;
    const int k = nearest(with.trunks, s.x, s.y, 0.05);
    ASSERT_GE(k, 0) << "thin stem at " << s.x << "," << s.y << " not found";
    EXPECT_NEAR(with.trunks[k].r, s.r, 0.02);
  }
  // Nothing else became a trunk.
  EXPECT_EQ(with.trunks.size(), thick.size() + thin.size());
}

TEST(TrunkExtractor, DensityParamsAreValidated) {
  TrunkExtractorParams p;
  p.density_min_scale = 0.0;
  EXPECT_NE(p.validate().find("density_min_scale"), std::string::npos);
  p = TrunkExtractorParams();
  p.density_reference = -1.0;
  EXPECT_NE(p.validate().find("density_reference"), std::string::npos);
  p = TrunkExtractorParams();
  p.density_min_trunks = 0;
  EXPECT_NE(p.validate().find("density_min_trunks"), std::string::npos);
  // Scaled thresholds never fall below their floors; the stem-base counts stay.
  p = TrunkExtractorParams();
  const TrunkExtractorParams q = scaledForDensity(p, 0.01);
  EXPECT_EQ(q.validate(), "");
  EXPECT_EQ(q.min_column_points, 2);
  EXPECT_EQ(q.min_fit_points, 5);
  EXPECT_EQ(q.min_base_points, p.min_base_points);
  EXPECT_EQ(q.ground_map_min_points, p.ground_map_min_points);
  EXPECT_EQ(scaledForDensity(p, 0.5).min_fit_points, 6);
  EXPECT_EQ(scaledForDensity(p, 1.0).min_fit_points, p.min_fit_points);
}

}  // namespace
}  // namespace dtif
