// The inventory's DBH from pooled breast-height slices: range noise along the ray shrinks a
// circle fitted to one side of a stem; pooled from several sides it does not.
#include "dtif/core/merge/stem_slices.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>

#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/merge/slice_store.h"

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

/// Bark points of stem s as a sensor walking 1 m along `side` through `walk` sees them, added
/// to v's cloud (in S through v.T_M_S) and, within the slice's heights, to v.slice_M.
void addBark(const Stem& s, const Eigen::Vector2d& walk, const Eigen::Vector2d& side,
             std::mt19937* rng, View* v) {
  std::normal_distribution<double> noise(0.0, kSigma);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Pose T_S_M = v->T_M_S.inverse();
  const Eigen::Vector2d c(s.x, s.y);
  for (int k = 0; k < 4000; ++k) {
    // Rays evenly spread in the sensor's azimuth across the stem, as a lidar's are: few hit
    // the flanks, where the noise would run along the bark.
    const Eigen::Vector2d sensor = walk + (u(*rng) - 0.5) * side;
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
    v->cloud.push_back(pcl::PointXYZ(q_S.x(), q_S.y(), q_S.z()));
    if (z - s.z_base >= 1.1 && z - s.z_base <= 1.5) v->slice_M.push_back(q);
  }
}

View scan(const Stem& s, double bearing, double range, std::mt19937* rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  View v;
  const Eigen::Vector2d dir(std::cos(bearing), std::sin(bearing));
  const Eigen::Vector2d side(-dir.y(), dir.x());
  v.T_M_S = Eigen::Translation3d(s.x + range * dir.x(), s.y + range * dir.y(), s.z_base + 1.0) *
            Eigen::AngleAxisd(bearing + 2.0, Eigen::Vector3d::UnitZ());
  const Pose T_S_M = v.T_M_S.inverse();
  addBark(s, Eigen::Vector2d(s.x, s.y) + range * dir, side, rng, &v);
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

Outcome survey(const Stem& s, const std::vector<double>& bearings, uint32_t seed,
               const StemFusionParams& p = StemFusionParams{}) {
  std::mt19937 rng(seed);
  std::vector<View> views;
  std::vector<double> radii;
  for (double b : bearings) {
    views.push_back(scan(s, b, 5.0, &rng));
    radii.push_back(oneSidedRadius(views.back()));
  }
  Outcome o;
  o.median_r = median(radii);
  StemSlices slices({inventoryEntry(s, 2.0 * o.median_r)}, p);
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
  StemFusionParams p;
  p.slice_blend_min_arc_deg = 361.0;
  const Outcome o = survey(s, {0.0, 0.2, 0.4}, 5, p);
  EXPECT_EQ(o.stats.refitted, 0u);
  EXPECT_EQ(o.stats.one_sided, 1u);
  EXPECT_DOUBLE_EQ(o.pooled_r, o.median_r);
}

TEST(StemSlices, AOneSidedSliceOverHalfTheStemGoesHalfWay) {
  // Views 23 degrees apart: the pooled inliers cover more than half the circle but less than
  // slice_min_arc_deg. The inventory's radius is 15 % too large (a neighbour in a view's fit).
  // DBH is then the mean of the circle's and the inventory's.
  const Stem s;
  std::mt19937 rng(5);
  std::vector<View> views;
  for (double b : {0.0, 0.2, 0.4}) views.push_back(scan(s, b, 5.0, &rng));
  const MergedStem entry = inventoryEntry(s, 2.0 * 1.15 * s.r);
  StemFusionParams accept_any, blend_above_359;
  accept_any.slice_min_arc_deg = 0.0;
  accept_any.slice_max_shrink = 1.0;
  blend_above_359.slice_blend_min_arc_deg = 359.0;
  auto refit = [&](const StemFusionParams& p, StemSliceStats* st) {
    StemSlices slices({entry}, p);
    for (const View& v : views) slices.addSubmap(0, v.T_M_S, v.cloud);
    return slices.refit(st).at(0).dbh;
  };
  StemSliceStats st;
  const double circle = refit(accept_any, &st);
  ASSERT_EQ(st.refitted, 1u);
  EXPECT_LT(circle, entry.dbh - 0.02);
  EXPECT_DOUBLE_EQ(refit(blend_above_359, &st), entry.dbh);
  EXPECT_EQ(st.one_sided, 1u);
  EXPECT_NEAR(refit(StemFusionParams{}, &st), 0.5 * (circle + entry.dbh), 1e-12);
  EXPECT_EQ(st.blended, 1u);
  EXPECT_EQ(st.one_sided, 0u);
}

TEST(StemSlices, ACircleAroundClutterKeepsTheMedian) {
  // Dead branches all round the stem at breast height, denser than its bark (dense_slope's
  // hidden-base stems): the best-supported circle runs through them, 8 cm outside the bark, with
  // the bark inside it. No return comes from inside a stem, so that circle is refused.
  const Stem s;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<View> views;
  for (double b : allRound(6)) {
    View v = scan(s, b, 5.0, &rng);
    const Pose T_S_M = v.T_M_S.inverse();
    for (int k = 0; k < 3000; ++k) {
      const double a = 2.0 * kPi * u(rng), rr = s.r + 0.08 + 0.01 * (u(rng) - 0.5);
      const Eigen::Vector3d q(s.x + rr * std::cos(a), s.y + rr * std::sin(a),
                              s.z_base + 1.1 + 0.4 * u(rng));
      const Eigen::Vector3d q_S = T_S_M * q;
      v.cloud.push_back(pcl::PointXYZ(q_S.x(), q_S.y(), q_S.z()));
    }
    views.push_back(std::move(v));
  }
  const MergedStem entry = inventoryEntry(s, 2.0 * 0.95 * s.r);
  auto refit = [&](const StemFusionParams& p, StemSliceStats* st) {
    StemSlices slices({entry}, p);
    for (const View& v : views) slices.addSubmap(0, v.T_M_S, v.cloud);
    return slices.refit(st).at(0).dbh;
  };
  StemFusionParams any_ratio;
  any_ratio.slice_min_inlier_ratio = 0.0;
  StemSliceStats st;
  EXPECT_NEAR(refit(any_ratio, &st), 2.0 * (s.r + 0.08), 0.01);  // the clutter's circle
  EXPECT_EQ(st.refitted, 1u);
  EXPECT_DOUBLE_EQ(refit(StemFusionParams{}, &st), entry.dbh);
  EXPECT_EQ(st.enclosing, 1u);
  EXPECT_EQ(st.refitted, 0u);
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
  StemFusionParams off, no_blend;
  off.slice_max_shrink = 1.0;
  no_blend.slice_blend_min_arc_deg = 361.0;
  StemSlices unchecked({inventoryEntry(s, 2.0 * r_median)}, off);
  StemSlices checked({inventoryEntry(s, 2.0 * r_median)}, no_blend);
  StemSlices blended({inventoryEntry(s, 2.0 * r_median)}, StemFusionParams{});
  for (const View& v : views) {
    unchecked.addSubmap(0, v.T_M_S, v.cloud);
    checked.addSubmap(0, v.T_M_S, v.cloud);
    blended.addSubmap(0, v.T_M_S, v.cloud);
  }
  StemSliceStats st;
  const double circle_dbh = unchecked.refit(&st).at(0).dbh;
  EXPECT_LT(0.5 * circle_dbh, 0.9 * r_median);
  EXPECT_EQ(st.refitted, 1u);
  EXPECT_DOUBLE_EQ(checked.refit(&st).at(0).dbh, 2.0 * r_median);
  EXPECT_EQ(st.shrunk, 1u);
  // All round, the shrunk circle's arc is wide: by default DBH goes half-way to it.
  EXPECT_NEAR(blended.refit(&st).at(0).dbh, 0.5 * (circle_dbh + 2.0 * r_median), 1e-12);
  EXPECT_EQ(st.blended, 1u);
  EXPECT_EQ(st.shrunk, 0u);
}

/// Nine stems on a 4 m grid seen by eight submaps: four walking among them, each pose off by
/// `shift` (a direction of its own) and `yaw_deg` (merged poses centimetres off each other, as
/// the landmark refinement leaves them), and four outside, in place, that see the stems' far
/// sides. The refit's radius error of each stem, with the alignment as in `p`.
std::vector<double> gridRadiusErrors(double shift, double yaw_deg, const StemFusionParams& p,
                                     StemSliceStats* st) {
  std::vector<Stem> stems;
  std::vector<MergedStem> entries;
  for (int i = 0; i < 9; ++i) {
    Stem s;
    s.x = 4.0 * (i % 3 - 1), s.y = 4.0 * (i / 3 - 1), s.r = 0.08 + 0.02 * (i % 5);
    stems.push_back(s);
    entries.push_back(inventoryEntry(s, 2.0 * s.r));
  }
  std::mt19937 rng(11);
  StemSlices slices(entries, p);
  int k = 0;
  for (double d : {1.0, 6.0}) {
    for (double b : allRound(4)) {
      const Eigen::Vector2d at = d * std::sqrt(2.0) * Eigen::Vector2d(std::cos(b), std::sin(b));
      View v;
      v.T_M_S = Eigen::Translation3d(at.x(), at.y(), 1.0) *
                Eigen::AngleAxisd(b + 2.0, Eigen::Vector3d::UnitZ());
      for (const Stem& s : stems) {
        const Eigen::Vector2d to = (Eigen::Vector2d(s.x, s.y) - at).normalized();
        addBark(s, at, Eigen::Vector2d(-to.y(), to.x()), &rng, &v);
      }
      const double a = 1.1 * k++, inner = d < 2.0 ? 1.0 : 0.0;
      const Pose off =
          Eigen::Translation3d(inner * shift * std::cos(a), inner * shift * std::sin(a), 0.0) *
          Eigen::AngleAxisd(inner * yaw_deg * kPi / 180.0, Eigen::Vector3d::UnitZ());
      slices.addSubmap(0, off * v.T_M_S, v.cloud);
    }
  }
  const std::vector<MergedStem> out = slices.refit(st);
  std::vector<double> err;
  for (size_t j = 0; j < stems.size(); ++j) err.push_back(0.5 * out[j].dbh - stems[j].r);
  return err;
}

TEST(StemSlices, SubmapsAlignedOnTheBarkUndoTheirPoseOffsets) {
  StemFusionParams off = StemFusionParams{}, on = StemFusionParams{};
  off.slice_align_sigma_m = 0.0;
  off.slice_max_shrink = on.slice_max_shrink = 1.0;  // the circles themselves, not the median
  StemSliceStats st_off, st_on;
  const std::vector<double> e_off = gridRadiusErrors(0.03, 0.2, off, &st_off);
  const std::vector<double> e_on = gridRadiusErrors(0.03, 0.2, on, &st_on);
  EXPECT_EQ(st_off.alignment.views, 0u);
  EXPECT_EQ(st_on.alignment.views, 4u);  // the outer four see their stems from one side
  EXPECT_EQ(st_on.alignment.stems, 9u);
  EXPECT_GT(st_on.alignment.max_shift_m, 0.01);
  double worst_off = 0.0;
  for (size_t k = 0; k < e_on.size(); ++k) {
    worst_off = std::max(worst_off, std::fabs(e_off[k]));
    EXPECT_NEAR(e_on[k], 0.0, 0.0025) << "stem " << k;  // seed 11: at most 1.9 mm
  }
  EXPECT_GT(worst_off, 0.005);  // seed 11: +0.3 to +6.8 mm, every stem too large
}

TEST(StemSlices, SubmapsInPlaceStayInPlace) {
  StemSliceStats st;
  for (double e : gridRadiusErrors(0.0, 0.0, StemFusionParams{}, &st)) EXPECT_NEAR(e, 0.0, 0.003);
  EXPECT_EQ(st.alignment.views, 4u);
  EXPECT_LT(st.alignment.max_shift_m, 0.003);
}

TEST(AlignSliceViews, ViewsWithFewStemsOrNoneKeepNoCorrection) {
  // Three noiseless arcs of one circle from three views, each view 1 cm off: one stem cannot
  // tell a view's shift from the radius, so nothing moves; a fourth view has no points.
  std::vector<Eigen::Vector2f> xy;
  std::vector<uint32_t> view;
  for (uint32_t v = 0; v < 3; ++v) {
    for (int k = 0; k < 20; ++k) {
      const double a = 2.0 * kPi * v / 3.0 + 0.05 * (k - 10);
      xy.emplace_back(0.11 * std::cos(a) + 0.01, 0.11 * std::sin(a));
      view.push_back(v);
    }
  }
  AlignedSlice s;
  s.xy = &xy, s.view = &view, s.r = 0.11, s.cx = 0.0, s.cy = 0.0;
  const std::vector<Eigen::Vector2d> origins = {{5, 0}, {-2.5, 4.3}, {-2.5, -4.3}, {0, 9}};
  SliceAlignmentStats st;
  const std::vector<ViewCorrection> c = alignSliceViews(origins, {s}, 0.04, {}, &st);
  ASSERT_EQ(c.size(), 4u);
  for (const ViewCorrection& v : c) EXPECT_TRUE(v.dx == 0.0 && v.dy == 0.0 && v.dyaw == 0.0);
  EXPECT_EQ(st.views, 0u);
  EXPECT_EQ(st.stems, 1u);
  EXPECT_EQ(st.points, 60u);
  EXPECT_TRUE(alignSliceViews(origins, {}, 0.04, {}).at(0).dx == 0.0);
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

// ---- keepSliceCandidates: the nodelet's per-submap keeping. ----

/// The submap's own trunk as its extraction reports it, in S: the stem's base moved by `off`
/// (in M: the one-sided fit's centre, a guessed base) with radius r.
TrunkLandmark ownTrunk(const View& v, const Stem& s, const Eigen::Vector3d& off, double r) {
  const Eigen::Vector3d b = v.T_M_S.inverse() * (Eigen::Vector3d(s.x, s.y, s.z_base) + off);
  TrunkLandmark t;
  t.x = b.x(), t.y = b.y(), t.z = b.z(), t.r = r;
  return t;
}

TEST(KeepSliceCandidates, TheRefitSeesTheSamePointsAsFromTheWholeClouds) {
  const Stem s;
  std::mt19937 rng(9);
  StemFusionParams p;
  p.slice_keep_max_points = 10000;  // this scan's 4000 rays on one side are all near the trunk
  const MergedStem m = inventoryEntry(s, 0.19);
  StemSlices whole({m}, p), kept({m}, p);
  size_t all_points = 0, kept_points = 0;
  int k = 0;
  for (double b : allRound(6)) {
    const View v = scan(s, b, 5.0, &rng);
    // Each submap's trunk off the merged stem by centimetres, its base by decimetres.
    const Eigen::Vector3d off(0.05 * std::cos(k), 0.05 * std::sin(k), 0.3 * ((k % 3) - 1));
    const Cloud::Ptr c =
        keepSliceCandidates(v.cloud, {ownTrunk(v, s, off, 0.08)}, Eigen::Matrix3d::Identity(), p);
    whole.addSubmap(0, v.T_M_S, v.cloud);
    kept.addSubmap(0, v.T_M_S, *c);
    all_points += v.cloud.size(), kept_points += c->size();
    ++k;
  }
  ASSERT_EQ(kept.slice(0).size(), whole.slice(0).size());
  for (size_t i = 0; i < whole.slice(0).size(); ++i)
    EXPECT_EQ(kept.slice(0)[i], whole.slice(0)[i]) << i;
  StemSliceStats a, b;
  EXPECT_DOUBLE_EQ(kept.refit(&a).at(0).dbh, whole.refit(&b).at(0).dbh);
  EXPECT_EQ(a.refitted, 1u);
  // The ground and the shrub (0.55-0.85 m from the trunk's centre), 1000 points a view, are not
  // kept.
  EXPECT_LE(kept_points + 6 * 1000, all_points);
}

TEST(KeepSliceCandidates, ATiltedSubmapIsLevelledFirst) {
  // A stock FAST-LIO2 submap: S tilted 20 deg; its stem runs askew in S. Levelled, the kept
  // points hold the slice; taken along S's z they miss most of it (1.1-1.5 m up the stem is
  // 0.38-0.51 m off S's vertical through its base).
  const Stem s;
  std::mt19937 rng(10);
  View v = scan(s, 0.0, 5.0, &rng);
  const Eigen::Matrix3d R_L_S = Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitX()).matrix();
  // The same points in the tilted S: T_M_S' = T_M_S R_L_S, cloud' = R_L_S^T cloud.
  for (pcl::PointXYZ& q : v.cloud) {
    const Eigen::Vector3d t = R_L_S.transpose() * Eigen::Vector3d(q.x, q.y, q.z);
    q = pcl::PointXYZ(t.x(), t.y(), t.z());
  }
  v.T_M_S = v.T_M_S * Pose(R_L_S);
  const Trunks own = {ownTrunk(v, s, Eigen::Vector3d::Zero(), 0.1)};
  StemFusionParams p;
  p.slice_max_points_per_submap = p.slice_keep_max_points = 10000;  // every point counted
  p.slice_keep_margin_m = 0.05;  // the trunk is exact here: kept within 0.3 m of its axis
  StemSlices whole({inventoryEntry(s, 0.2)}, p), levelled({inventoryEntry(s, 0.2)}, p),
      askew({inventoryEntry(s, 0.2)}, p);
  whole.addSubmap(0, v.T_M_S, v.cloud);
  levelled.addSubmap(0, v.T_M_S, *keepSliceCandidates(v.cloud, own, R_L_S, p));
  askew.addSubmap(0, v.T_M_S, *keepSliceCandidates(v.cloud, own, Eigen::Matrix3d::Identity(), p));
  ASSERT_GT(whole.slice(0).size(), 50u);
  EXPECT_EQ(levelled.slice(0).size(), whole.slice(0).size());
  EXPECT_LT(askew.slice(0).size(), whole.slice(0).size() / 2);
}

TEST(KeepSliceCandidates, CappedPerTrunkAndEmptyInputs) {
  const Stem s;
  std::mt19937 rng(11);
  const View v = scan(s, 0.0, 5.0, &rng);
  StemFusionParams p;
  p.slice_keep_max_points = 100;
  const Trunks own = {ownTrunk(v, s, Eigen::Vector3d::Zero(), 0.1)};
  EXPECT_EQ(keepSliceCandidates(v.cloud, own, Eigen::Matrix3d::Identity(), p)->size(), 100u);
  // The same trunk twice: its points are kept once.
  EXPECT_EQ(keepSliceCandidates(v.cloud, {own[0], own[0]}, Eigen::Matrix3d::Identity(), p)->size(),
            100u);
  EXPECT_TRUE(keepSliceCandidates(v.cloud, {}, Eigen::Matrix3d::Identity(), p)->empty());
  EXPECT_TRUE(keepSliceCandidates(Cloud(), own, Eigen::Matrix3d::Identity(), p)->empty());
}

TEST(SlicePointStore, KeepsTheSlicesOfArrivingCloudsForTheRefit) {
  const Stem s;
  std::mt19937 rng(12);
  StemFusionParams p;
  p.slice_keep_max_points = 10000;
  const MergedStem m = inventoryEntry(s, 0.19);
  SlicePointStore store(p);
  StemSlices whole({m}, p);
  std::vector<MergedPose> poses;
  size_t all_points = 0;
  EXPECT_FALSE(store.addCloud(0, Cloud()));  // no trunks yet: nothing kept
  for (double b : allRound(6)) {
    const View v = scan(s, b, 5.0, &rng);
    const int64_t id = static_cast<int64_t>(poses.size());
    store.addTrunks(id, {ownTrunk(v, s, Eigen::Vector3d(0.03, 0.0, 0.2), 0.09)},
                    Eigen::Matrix3d::Identity());
    EXPECT_TRUE(store.addCloud(id, v.cloud));
    whole.addSubmap(0, v.T_M_S, v.cloud);
    poses.push_back(MergedPose{id, "alpha", 0, v.T_M_S});
    all_points += v.cloud.size();
  }
  EXPECT_EQ(store.submapsWithPoints(), 6u);
  EXPECT_LT(store.points(), all_points);
  EXPECT_GE(store.bytes(), store.points() * sizeof(pcl::PointXYZ));
  StemSliceStats a, b;
  const double dbh = store.refit({m}, poses, &a).at(0).dbh;
  EXPECT_DOUBLE_EQ(dbh, whole.refit(&b).at(0).dbh);
  EXPECT_EQ(a.refitted, 1u);
  EXPECT_EQ(a.points, b.points);
  EXPECT_NE(dbh, 0.19);
  // Submaps without a merged pose add nothing.
  poses.resize(1);
  EXPECT_DOUBLE_EQ(store.refit({m}, poses, &a).at(0).dbh, 0.19);
  EXPECT_EQ(a.too_few, 1u);
  // A cloud sent again replaces the submap's points.
  const size_t before = store.points();
  store.addCloud(0, Cloud());
  EXPECT_LT(store.points(), before);
  EXPECT_EQ(store.submapsWithPoints(), 6u);
}

TEST(SlicePointStore, KeepsThePointsOfKnownStemsTheSubmapDidNotExtract) {
  // Three submaps see the stem; the last extracts no trunk of it, but the inventory so far
  // (the first two's) knows it, and its current pose places it: its points are kept too.
  const Stem s;
  std::mt19937 rng(13);
  StemFusionParams p;
  p.slice_keep_max_points = 10000;
  MergedStem m = inventoryEntry(s, 0.19);
  m.component = 1;
  SlicePointStore store(p);
  StemSlices whole({m}, p);
  std::vector<MergedPose> poses;
  for (double b : allRound(3)) {
    const View v = scan(s, b, 5.0, &rng);
    const int64_t id = static_cast<int64_t>(poses.size());
    const bool last = id == 2;
    store.addTrunks(id, last ? Trunks{} : Trunks{ownTrunk(v, s, Eigen::Vector3d::Zero(), 0.09)},
                    Eigen::Matrix3d::Identity());
    // The current pose 5 cm off the final one.
    const Pose now = Eigen::Translation3d(0.05, 0.0, 0.0) * v.T_M_S;
    if (last) {
      const size_t before = store.points();
      store.addCloud(id, v.cloud, {m}, 0, now);  // the stem of another component: nothing
      EXPECT_EQ(store.points(), before);
    }
    store.addCloud(id, v.cloud, last ? std::vector<MergedStem>{m} : std::vector<MergedStem>{}, 1,
                   now);
    whole.addSubmap(1, v.T_M_S, v.cloud);
    poses.push_back(MergedPose{id, "alpha", 1, v.T_M_S});
  }
  StemSliceStats a, b;
  EXPECT_DOUBLE_EQ(store.refit({m}, poses, &a).at(0).dbh, whole.refit(&b).at(0).dbh);
  EXPECT_EQ(a.submap_views, 3u);
  EXPECT_EQ(a.points, b.points);
}

TEST(KeepSliceBand, DropsWhatNoSliceCanReachAboveTheLowestPointOfItsCell) {
  // A tilted submap frame (stock FAST-LIO2): levelled, the ground is at 0.5 m; a crown point
  // 3.5 m above it goes, one at 2.9 m stays, as does the lowest point of a cell without ground
  // (whatever it is, it may be the ground there).
  StemFusionParams p;  // slice_max_h_m 1.5 + slice_keep_band_m 0.5 + 1 m: 3 m
  const Eigen::Matrix3d R_L_S = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()).matrix();
  const Eigen::Matrix3d R_S_L = R_L_S.transpose();
  auto inS = [&](double x, double y, double z) {
    const Eigen::Vector3d q = R_S_L * Eigen::Vector3d(x, y, z);
    return pcl::PointXYZ(q.x(), q.y(), q.z());
  };
  Cloud c;
  c.push_back(inS(0.2, 0.2, 0.5));   // ground
  c.push_back(inS(0.8, 0.7, 3.4));   // bark, 2.9 m above the ground of its cell
  c.push_back(inS(0.5, 0.5, 4.0));   // crown
  c.push_back(inS(5.5, 0.5, 12.0));  // a crown point alone in its cell
  c.push_back(pcl::PointXYZ(NAN, 0.0, 0.0));
  const Cloud::Ptr kept = keepSliceBand(c, R_L_S, p);
  ASSERT_EQ(kept->size(), 3u);
  EXPECT_EQ((*kept)[1].z, c[1].z);
  EXPECT_EQ((*kept)[2].x, c[3].x);
  // Unlevelled, the same cloud's cells and heights differ: the check does level it.
  EXPECT_NE(keepSliceBand(c, Eigen::Matrix3d::Identity(), p)->size(), 3u);
}

TEST(SlicePointStore, HeldCloudsGiveTheirPointsToStemsExtractedLater) {
  // Three submaps see the stem; only the last extracts it, and no stem was known when the first
  // two clouds came. Cut at arrival, they keep nothing of it and the refit has one view (too
  // few); held, they give their points as the whole clouds give theirs to dtif merge.
  const Stem s;
  StemFusionParams p;
  p.slice_keep_max_points = 10000;
  const MergedStem m = inventoryEntry(s, 0.19);
  auto survey = [&](int defer, StemSliceStats* st) {
    StemFusionParams q = p;
    q.slice_defer_clouds = defer;
    SlicePointStore store(q);
    StemSlices whole({m}, q);
    std::vector<MergedPose> poses;
    std::mt19937 rng(14);
    for (double b : allRound(3)) {
      const View v = scan(s, b, 5.0, &rng);
      const int64_t id = static_cast<int64_t>(poses.size());
      store.addTrunks(id,
                      id == 2 ? Trunks{ownTrunk(v, s, Eigen::Vector3d::Zero(), 0.09)} : Trunks{},
                      Eigen::Matrix3d::Identity());
      if (defer > 0) {
        EXPECT_TRUE(store.holdCloud(id, v.cloud));
        EXPECT_TRUE(store.overdue().empty());
      } else {
        store.addCloud(id, v.cloud);
      }
      whole.addSubmap(0, v.T_M_S, v.cloud);
      poses.push_back(MergedPose{id, "alpha", 0, v.T_M_S});
    }
    StemSliceStats all;
    const double dbh = store.refit({m}, poses, st).at(0).dbh;
    return std::make_pair(dbh, whole.refit(&all).at(0).dbh);
  };
  StemSliceStats cut, held;
  EXPECT_DOUBLE_EQ(survey(0, &cut).first, 0.19);
  EXPECT_EQ(cut.submap_views, 1u);
  EXPECT_EQ(cut.too_few, 1u);
  const auto [dbh, from_whole] = survey(24, &held);
  EXPECT_EQ(held.submap_views, 3u);
  EXPECT_EQ(held.refitted, 1u);
  EXPECT_DOUBLE_EQ(dbh, from_whole);
}

TEST(SlicePointStore, AHeldCloudIsCutDownToTheStemsKnownWhenItFallsDue) {
  // A window of one cloud: each cloud falls due when the next comes and is cut down to the
  // stems known then. Submap 0 fell due before the stem was known: it keeps nothing of it;
  // submap 1 after: it keeps the stem's points.
  const Stem s;
  StemFusionParams p;
  p.slice_keep_max_points = 10000;
  p.slice_defer_clouds = 1;
  const MergedStem m = inventoryEntry(s, 0.19);
  SlicePointStore store(p);
  std::vector<MergedPose> poses;
  std::vector<Cloud> clouds;
  std::mt19937 rng(15);
  for (double b : allRound(3)) {
    const View v = scan(s, b, 5.0, &rng);
    const int64_t id = static_cast<int64_t>(poses.size());
    store.addTrunks(id, Trunks{}, Eigen::Matrix3d::Identity());
    ASSERT_TRUE(store.holdCloud(id, v.cloud));
    const std::vector<int64_t> due = store.overdue();
    ASSERT_EQ(due.size(), id == 0 ? 0u : 1u);
    if (id > 0) {
      EXPECT_EQ(due[0], id - 1);
      const std::vector<MergedStem> known =
          id == 1 ? std::vector<MergedStem>{} : std::vector<MergedStem>{m};
      EXPECT_TRUE(store.settle(due[0], known, 0, poses[due[0]].T_M_S));
      EXPECT_FALSE(store.settle(due[0], known, 0, poses[due[0]].T_M_S));  // no longer held
    }
    poses.push_back(MergedPose{id, "alpha", 0, v.T_M_S});
    clouds.push_back(v.cloud);
  }
  EXPECT_EQ(store.heldClouds(), 1u);
  EXPECT_EQ(store.submapsWithPoints(), 3u);
  StemSliceStats st;
  store.refit({m}, poses, &st);
  EXPECT_EQ(st.submap_views, 2u);  // submaps 1 (settled) and 2 (held)
  // Sent again, a cloud is held anew and its count starts over.
  ASSERT_TRUE(store.holdCloud(1, clouds[1]));
  EXPECT_EQ(store.overdue(), std::vector<int64_t>{2});
  EXPECT_FALSE(store.holdCloud(7, clouds[0]));  // no trunks for submap 7
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
  p.slice_blend_min_arc_deg = -1.0;
  EXPECT_NE(p.validate().find("slice_blend_min_arc_deg"), std::string::npos);
  p = StemFusionParams{};
  p.slice_defer_clouds = -1;
  EXPECT_NE(p.validate().find("slice_defer_clouds"), std::string::npos);
  p = StemFusionParams{};
  p.slice_min_inlier_ratio = 1.5;
  EXPECT_NE(p.validate().find("slice_min_inlier_ratio"), std::string::npos);
  p = StemFusionParams{};
  p.slice_inlier_m = 0.0;
  EXPECT_NE(p.validate().find("slice_inlier_m"), std::string::npos);
  p = StemFusionParams{};
  p.slice_align_sigma_m = NAN;
  EXPECT_NE(p.validate().find("slice_align_sigma_m"), std::string::npos);
  p = StemFusionParams{};
  p.slice_align_sigma_deg = 0.0;
  EXPECT_NE(p.validate().find("slice_align_sigma_deg"), std::string::npos);
  p.slice_align_sigma_m = 0.0;  // off: its yaw sigma is not used
  EXPECT_EQ(p.validate(), "");
  p = StemFusionParams{};
  p.slice_keep_margin_m = -0.1;
  EXPECT_NE(p.validate().find("slice_keep_margin_m"), std::string::npos);
  p = StemFusionParams{};
  p.slice_keep_band_m = NAN;
  EXPECT_NE(p.validate().find("slice_keep_band_m"), std::string::npos);
  p = StemFusionParams{};
  p.slice_keep_max_points = 0;
  EXPECT_NE(p.validate().find("slice_keep_max_points"), std::string::npos);
}

}  // namespace
}  // namespace dtif
