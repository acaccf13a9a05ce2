// The inventory's DBH from pooled breast-height slices: range noise along the ray shrinks a
// circle fitted to one side of a stem; pooled from several sides it does not.
#include "dtif/core/merge/stem_slices.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>

#include "dtif/core/extraction/trunk_extractor.h"

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kSigma = 0.02;  // MID-360 range noise [m]

struct Stem {
  double x = 3.0, y = 4.0, z_base = 0.5, r = 0.10;
  double ellipticity = 0.0;  // r (1 + e cos 2 theta)
  double radiusAt(double theta) const { return r * (1.0 + ellipticity * std::cos(2.0 * theta)); }
};

/// One submap: a sensor walking 1 m past the stem at `range` in direction `bearing` (from the
/// stem), 1 m above its base; bark points between 0.9 and 1.9 m above the base on the side it
/// faces, with Gaussian noise along the ray. The cloud is in the submap's own frame S (a yawed,
/// shifted pose T_M_S), plus ground and clutter points outside the slice.
struct View {
  Pose T_M_S = Pose::Identity();
  Cloud cloud;
  std::vector<Eigen::Vector2d> slice_M;  // this view's slice alone, in M
};

View scan(const Stem& s, double bearing, double range, std::mt19937* rng) {
  std::normal_distribution<double> noise(0.0, kSigma);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  View v;
  const Eigen::Vector2d dir(std::cos(bearing), std::sin(bearing));
  const Eigen::Vector2d side(-dir.y(), dir.x());
  v.T_M_S = Eigen::Translation3d(s.x + range * dir.x(), s.y + range * dir.y(), s.z_base + 1.0) *
            Eigen::AngleAxisd(bearing + 2.0, Eigen::Vector3d::UnitZ());
  const Pose T_S_M = v.T_M_S.inverse();
  const Eigen::Vector2d c(s.x, s.y);
  for (int k = 0; k < 4000; ++k) {
    // Rays evenly spread in the sensor's azimuth across the stem, as a lidar's are: few hit
    // the flanks, where the noise would run along the bark.
    const Eigen::Vector2d sensor = c + range * dir + (u(*rng) - 0.5) * side;
    const Eigen::Vector2d to_c = c - sensor;
    const double half = std::asin(std::min(1.0, s.r / to_c.norm()));
    const double az = std::atan2(to_c.y(), to_c.x()) + half * (2.0 * u(*rng) - 1.0);
    const Eigen::Vector2d ray(std::cos(az), std::sin(az));
    const double along = ray.dot(to_c), miss2 = to_c.squaredNorm() - along * along;
    if (miss2 >= s.r * s.r) continue;
    const Eigen::Vector2d hit = sensor + (along - std::sqrt(s.r * s.r - miss2)) * ray;
    const double theta = std::atan2(hit.y() - c.y(), hit.x() - c.x());
    const Eigen::Vector2d p = c + s.radiusAt(theta) * (hit - c).normalized();
    const Eigen::Vector2d q = p + noise(*rng) * ray;
    const double z = s.z_base + 0.9 + 1.0 * u(*rng);
    const Eigen::Vector3d q_S = T_S_M * Eigen::Vector3d(q.x(), q.y(), z);
    v.cloud.push_back(pcl::PointXYZ(q_S.x(), q_S.y(), q_S.z()));
    if (z - s.z_base >= 1.1 && z - s.z_base <= 1.5) v.slice_M.push_back(q);
  }
  // Ground under the stem and a shrub beside it: outside the slice (height, distance).
  for (int k = 0; k < 500; ++k) {
    const Eigen::Vector3d g(s.x + 2.0 * u(*rng) - 1.0, s.y + 2.0 * u(*rng) - 1.0, s.z_base);
    const Eigen::Vector3d shrub(s.x + 0.6 + 0.2 * u(*rng), s.y, s.z_base + 1.3);
    for (const Eigen::Vector3d& p : {g, shrub}) {
      const Eigen::Vector3d q_S = T_S_M * p;
      v.cloud.push_back(pcl::PointXYZ(q_S.x(), q_S.y(), q_S.z()));
    }
  }
  return v;
}

/// What one submap's extraction would report: a robust circle fit of its own slice.
double oneSidedRadius(const View& v) {
  const CircleFit f = fitCircleRobust(v.slice_M, CircleFitParams{});
  EXPECT_TRUE(f.ok);
  return f.r;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

MergedStem inventoryEntry(const Stem& s, double dbh) {
  MergedStem m;
  m.x = s.x, m.y = s.y, m.z_base = s.z_base, m.dbh = dbh, m.observations = 6;
  return m;
}

struct Outcome {
  double median_r = 0.0;  // the observations' median (the inventory without points)
  double pooled_r = 0.0;  // after the refit
  StemSliceStats stats;
};

Outcome survey(const Stem& s, const std::vector<double>& bearings, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<View> views;
  std::vector<double> radii;
  for (double b : bearings) {
    views.push_back(scan(s, b, 5.0, &rng));
    radii.push_back(oneSidedRadius(views.back()));
  }
  Outcome o;
  o.median_r = median(radii);
  StemSlices slices({inventoryEntry(s, 2.0 * o.median_r)}, StemFusionParams{});
  for (const View& v : views) slices.addSubmap(0, v.T_M_S, v.cloud);
  o.pooled_r = 0.5 * slices.refit(&o.stats).at(0).dbh;
  return o;
}

std::vector<double> allRound(int n) {
  std::vector<double> b;
  for (int k = 0; k < n; ++k) b.push_back(2.0 * kPi * k / n + 0.3);
  return b;
}

TEST(StemSlices, PooledSidesUndoTheRangeNoiseBias) {
  // 2 sigma^2 / r = 8 mm at r = 10 cm: every one-sided fit is too small, so is their median.
  for (uint32_t seed : {1u, 2u, 3u}) {
    const Stem s;
    const Outcome o = survey(s, allRound(6), seed);
    EXPECT_EQ(o.stats.refitted, 1u);
    EXPECT_LT(o.median_r, s.r - 0.004) << "seed " << seed;
    EXPECT_NEAR(o.pooled_r, s.r, 0.002) << "seed " << seed;
  }
}

TEST(StemSlices, PooledSidesPlaceTheStemOnItsAxis) {
  // The inventory's centre 4 cm off (a median of one-sided fits): the pooled circle's is not.
  const Stem s;
  std::mt19937 rng(4);
  MergedStem entry = inventoryEntry(s, 2.0 * s.r);
  entry.x += 0.03, entry.y -= 0.03;
  StemSlices slices({entry}, StemFusionParams{});
  for (double b : allRound(6)) {
    const View v = scan(s, b, 5.0, &rng);
    slices.addSubmap(0, v.T_M_S, v.cloud);
  }
  StemSliceStats st;
  const MergedStem out = slices.refit(&st).at(0);
  ASSERT_EQ(st.refitted, 1u);
  EXPECT_LT(std::hypot(out.x - s.x, out.y - s.y), 0.005);
}

TEST(StemSlices, PooledSidesAverageAnEllipse) {
  // Axes 10 % off the mean radius: one side's curvature says anything between the two.
  Stem s;
  s.r = 0.25;
  s.ellipticity = 0.1;
  const Outcome o = survey(s, allRound(8), 4);
  EXPECT_EQ(o.stats.refitted, 1u);
  EXPECT_GT(std::fabs(o.median_r - s.r), 0.01);  // the views' median, seed 4: +2.3 cm
  EXPECT_NEAR(o.pooled_r, s.r, 0.004);
}

TEST(StemSlices, OneSidedSliceKeepsTheMedian) {
  // Every submap on the same side: the pooled arc is one side again, no better than the median.
  const Stem s;
  const Outcome o = survey(s, {0.0, 0.2, 0.4}, 5);
  EXPECT_EQ(o.stats.refitted, 0u);
  EXPECT_EQ(o.stats.one_sided, 1u);
  EXPECT_DOUBLE_EQ(o.pooled_r, o.median_r);
}

TEST(StemSlices, TooFewSubmapsOrAnotherComponentKeepTheMedian) {
  const Stem s;
  std::mt19937 rng(6);
  const View a = scan(s, 0.0, 5.0, &rng), b = scan(s, kPi, 5.0, &rng);
  const MergedStem m = inventoryEntry(s, 0.18);
  StemFusionParams p;
  {
    StemSlices slices({m}, p);
    slices.addSubmap(0, a.T_M_S, a.cloud);
    slices.addSubmap(1, b.T_M_S, b.cloud);  // another component's M: not this stem
    StemSliceStats st;
    EXPECT_DOUBLE_EQ(slices.refit(&st).at(0).dbh, 0.18);
    EXPECT_EQ(st.too_few, 1u);
  }
  StemSlices slices({m}, p);
  slices.addSubmap(0, a.T_M_S, a.cloud);
  slices.addSubmap(0, b.T_M_S, b.cloud);
  StemSliceStats st;
  EXPECT_NEAR(slices.refit(&st).at(0).dbh, 2.0 * s.r, 0.006);
  EXPECT_EQ(st.refitted, 1u);
  // Only the slice's points are kept, at most slice_max_points_per_submap per submap.
  EXPECT_LE(slices.slice(0).size(), 2u * static_cast<size_t>(p.slice_max_points_per_submap));
  for (const Eigen::Vector2f& q : slices.slice(0)) EXPECT_LT(q.norm(), 0.5 * 0.18 + 0.15 + 1e-6);
}

TEST(StemSlices, SubmapsOffByTheirPosesKeepTheMedian) {
  // Each submap placed 6 cm towards the stem (poses off, as on very_sparse): their arcs overlap
  // inside the stem, and the pooled fit takes that inner envelope, too small.
  const Stem s;
  std::mt19937 rng(8);
  std::vector<View> views;
  std::vector<double> radii;
  for (double b : allRound(6)) {
    views.push_back(scan(s, b, 5.0, &rng));
    radii.push_back(oneSidedRadius(views.back()));
    views.back().T_M_S.pretranslate(-0.06 * Eigen::Vector3d(std::cos(b), std::sin(b), 0.0));
  }
  const double r_median = median(radii);
  StemFusionParams off;
  off.slice_max_shrink = 1.0;
  StemSlices unchecked({inventoryEntry(s, 2.0 * r_median)}, off);
  StemSlices checked({inventoryEntry(s, 2.0 * r_median)}, StemFusionParams{});
  for (const View& v : views) {
    unchecked.addSubmap(0, v.T_M_S, v.cloud);
    checked.addSubmap(0, v.T_M_S, v.cloud);
  }
  StemSliceStats st;
  EXPECT_LT(0.5 * unchecked.refit(&st).at(0).dbh, 0.9 * r_median);
  EXPECT_EQ(st.refitted, 1u);
  EXPECT_DOUBLE_EQ(checked.refit(&st).at(0).dbh, 2.0 * r_median);
  EXPECT_EQ(st.shrunk, 1u);
}

TEST(StemSlices, PlotCoordinatesKeepMillimetres) {
  // A map registered to a field stem map can sit 500 km from its origin (UTM): floats there
  // would round to 3 cm.
  Stem s;
  s.x = 512345.6, s.y = 5432109.8;
  const Outcome o = survey(s, allRound(6), 7);
  EXPECT_NEAR(o.pooled_r, s.r, 0.002);
}

TEST(StemSlices, EmptyInputs) {
  StemSlices none({}, StemFusionParams{});
  none.addSubmap(0, Pose::Identity(), Cloud());
  EXPECT_TRUE(none.refit().empty());
  Cloud nan_cloud;
  nan_cloud.push_back(pcl::PointXYZ(NAN, 0.0f, 1.3f));
  const Stem s;
  StemSlices one({inventoryEntry(s, 0.2)}, StemFusionParams{});
  one.addSubmap(0, Pose::Identity(), nan_cloud);
  EXPECT_DOUBLE_EQ(one.refit().at(0).dbh, 0.2);
}

TEST(StemSlices, ParamsValidated) {
  StemFusionParams p;
  EXPECT_EQ(p.validate(), "");
  p.slice_max_h_m = p.slice_min_h_m;
  EXPECT_NE(p.validate().find("slice_min_h_m"), std::string::npos);
  p = StemFusionParams{};
  p.slice_min_points = 2;
  EXPECT_NE(p.validate().find("slice_min_points"), std::string::npos);
  p = StemFusionParams{};
  p.slice_min_arc_deg = 400;
  EXPECT_NE(p.validate().find("slice_min_arc_deg"), std::string::npos);
  p = StemFusionParams{};
  p.slice_max_shrink = -0.1;
  EXPECT_NE(p.validate().find("slice_max_shrink"), std::string::npos);
  p = StemFusionParams{};
  p.slice_inlier_m = 0.0;
  EXPECT_NE(p.validate().find("slice_inlier_m"), std::string::npos);
}

}  // namespace
}  // namespace dtif
