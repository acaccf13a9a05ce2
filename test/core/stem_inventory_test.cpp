// The merged stem inventory: one entry per tree from many noisy observations.
#include "dtif/core/merge/stem_inventory.h"

#include <gtest/gtest.h>

#include <random>

namespace dtif {
namespace {

struct Tree {
  double x, y, z, r;
};

std::vector<Tree> forest(std::mt19937* rng) {
  // A jittered 3 m grid: trees at least ~1.5 m apart, as in the built-in scenes.
  std::uniform_real_distribution<double> j(-0.7, 0.7), r(0.08, 0.25);
  std::vector<Tree> t;
  for (int i = 0; i < 8; ++i) {
    for (int k = 0; k < 6; ++k)
      t.push_back({3.0 * i + j(*rng), 3.0 * k + j(*rng), 0.1 * i, r(*rng)});
  }
  return t;
}

/// Ten submaps along x, each seeing the trees within 7 m: 3 cm position noise, radius noise of
/// 1 cm with one in six fits far off (partial arcs), bases hidden one time in three.
std::vector<StemObservation> observe(const std::vector<Tree>& trees, std::mt19937* rng) {
  std::normal_distribution<double> np(0.0, 0.03), nr(0.0, 0.01);
  std::vector<StemObservation> obs;
  int n = 0;
  for (int s = 0; s < 10; ++s) {
    const double cx = 2.5 * s, cy = 7.5;
    for (const Tree& t : trees) {
      if (std::hypot(t.x - cx, t.y - cy) > 7.0) continue;
      StemObservation o;
      o.submap = s;
      o.x = t.x + np(*rng);
      o.y = t.y + np(*rng);
      ++n;
      o.base_seen = n % 3 != 0;
      o.z = t.z + (o.base_seen ? np(*rng) : 0.8);  // a hidden base is extrapolated, off
      o.r = n % 6 == 5 ? t.r * 0.5 : t.r + nr(*rng);
      obs.push_back(o);
    }
  }
  return obs;
}

TEST(StemInventory, OneEntryPerTreeFusedRobustly) {
  std::mt19937 rng(3);
  const std::vector<Tree> trees = forest(&rng);
  const std::vector<StemObservation> obs = observe(trees, &rng);
  const std::vector<MergedStem> stems = fuseStems(obs, StemFusionParams{});
  std::vector<int> hits(trees.size(), 0);
  size_t seen_trees = 0;
  for (size_t i = 0; i < trees.size(); ++i) {
    int n_obs = 0;
    for (const auto& o : obs) {
      n_obs += std::hypot(o.x - trees[i].x, o.y - trees[i].y) < 0.3;
    }
    seen_trees += n_obs > 0;
  }
  double err_sum = 0.0;
  int err_n = 0;
  for (const MergedStem& s : stems) {
    size_t best = 0;
    for (size_t i = 1; i < trees.size(); ++i) {
      if (std::hypot(s.x - trees[i].x, s.y - trees[i].y) <
          std::hypot(s.x - trees[best].x, s.y - trees[best].y)) {
        best = i;
      }
    }
    const Tree& t = trees[best];
    ++hits[best];
    // 3 cm noise per axis (4.2 cm horizontally): every stem within 3.5 sigma; on average the
    // medians of three or more observations are closer than one observation.
    const double e = std::hypot(s.x - t.x, s.y - t.y);
    EXPECT_LT(e, 0.15);
    if (s.observations >= 3) err_sum += e, ++err_n;
    // One fit has 2 cm of dbh noise and one in six is far off: the median of five is robust.
    if (s.observations >= 5) EXPECT_NEAR(s.dbh, 2.0 * t.r, 0.02);
    if (s.observations >= 3) EXPECT_NEAR(s.z_base, t.z, 0.06);
    EXPECT_GE(s.observations, 1);
  }
  ASSERT_GT(err_n, 10);
  EXPECT_LT(err_sum / err_n, 0.03);
  EXPECT_EQ(stems.size(), seen_trees);
  for (int h : hits) EXPECT_LE(h, 1);
  for (size_t i = 0; i < stems.size(); ++i) EXPECT_EQ(stems[i].stem_id, static_cast<int64_t>(i));
}

TEST(StemInventory, ComponentsAreKeptApartAndMinObservationsFilters) {
  std::vector<StemObservation> obs;
  for (int s = 0; s < 3; ++s) obs.push_back({s, 0, 1.0, 1.0, 0.0, 0.1, true});
  obs.push_back({7, 1, 1.0, 1.0, 0.0, 0.1, true});  // same place, other component
  obs.push_back({8, 0, 9.0, 9.0, 0.0, 0.1, true});  // seen once
  StemFusionParams p;
  EXPECT_EQ(fuseStems(obs, p).size(), 3u);
  p.min_observations = 2;
  const auto stems = fuseStems(obs, p);
  ASSERT_EQ(stems.size(), 1u);
  EXPECT_EQ(stems[0].observations, 3);
  EXPECT_EQ(stems[0].component, 0);
}

TEST(StemInventory, OneSubmapNeverContributesTwiceToATree) {
  // Two trunks 0.3 m apart in one submap are two trees to the clustering. (Seen by that submap
  // only, their bark 0.1 m apart, the inventory lists the larger: OfTwoCirclesSeenOnce... below.)
  std::vector<StemObservation> obs{{1, 0, 0.0, 0.0, 0.0, 0.1, true},
                                   {1, 0, 0.3, 0.0, 0.0, 0.1, true}};
  StemFusionParams p;
  p.single_pair_margin_m = -1.0;
  EXPECT_EQ(fuseStems(obs, p).size(), 2u);
  obs.push_back({2, 0, 0.0, 0.0, 0.0, 0.1, true});
  obs.push_back({2, 0, 0.3, 0.0, 0.0, 0.1, true});
  EXPECT_EQ(fuseStems(obs, StemFusionParams{}).size(), 2u);
}

/// Trees on a 3 m grid on a 20 % slope with 1.2 cm of taper per metre and a 5 % lean along x,
/// each seen by six submaps: two saw the base and fitted at breast height, four guessed a base
/// 1.2-2.9 m too high (the ground by the stem hidden) and fitted there, where the stem is thinner
/// and its centre has moved along the lean. Every fifth tree's base nobody saw.
std::vector<StemObservation> observeOnSlope(std::vector<Tree>* trees) {
  constexpr double kTaper = 0.012, kLean = 0.05;
  const double offsets[] = {0.0, 0.0, 1.2, 1.8, 2.4, 2.9};
  std::vector<StemObservation> obs;
  for (int i = 0; i < 8; ++i) {
    for (int k = 0; k < 6; ++k) {
      const double x = 3.0 * i + 0.3 * (k % 2);
      const Tree t{x, 3.0 * k, 0.2 * x, 0.08 + 0.02 * ((i + k) % 9)};
      const bool base_hidden = trees->size() % 5 == 4;
      for (int s = 0; s < 6; ++s) {
        const double dz = base_hidden ? offsets[2 + s % 4] : offsets[s];
        StemObservation o;
        o.submap = s;
        o.x = t.x + kLean * dz;
        o.y = t.y;
        o.z = t.z + dz;
        o.r = t.r - kTaper * dz + 0.002 * ((s * 7 + i) % 3 - 1);  // +-2 mm of fit noise
        o.base_seen = dz == 0.0;
        obs.push_back(o);
      }
      trees->push_back(t);
    }
  }
  return obs;
}

TEST(StemInventory, RadiiFittedAboveBreastHeightAreCorrectedByTheStandsTaper) {
  std::vector<Tree> trees;
  const std::vector<StemObservation> obs = observeOnSlope(&trees);
  const std::vector<MergedStem> stems = fuseStems(obs, StemFusionParams{});
  ASSERT_EQ(stems.size(), trees.size());
  for (const Tree& t : trees) {
    const MergedStem* s = nullptr;
    for (const MergedStem& m : stems) {
      if (std::hypot(m.x - t.x, m.y - t.y) < 0.5) s = &m;
    }
    ASSERT_NE(s, nullptr) << t.x << " " << t.y;
    // The median of the raw radii would be 1.2 cm x 1.5-2.4 m too thin: 3.6-5.8 cm of DBH.
    EXPECT_NEAR(s->dbh, 2.0 * t.r, 0.005) << t.x << " " << t.y;
    // The base from the seen ones, or from the plane through the neighbours' (a 20 % slope,
    // evaluated where the tree was fitted: 9 cm up the lean, 1.8 cm higher).
    EXPECT_NEAR(s->z_base, t.z, 0.025) << t.x << " " << t.y;
    // The centre at breast height, not moved up the lean by the guessed bases (where some
    // observation fitted there).
    const bool base_seen = (&t - trees.data()) % 5 != 4;
    if (base_seen) EXPECT_NEAR(s->x, t.x, 0.02) << t.x << " " << t.y;
    EXPECT_EQ(s->observations, 6);
  }
}

/// observeOnSlope's stand, and one more tree at x = 50 whose base nobody saw and whose six
/// observations were all fitted 4 m up (a downhill stem above the understory): 29 m from the
/// nearest seen base, farther than terrain_far_radius_m.
std::vector<StemObservation> observeWithAFarTree(std::vector<Tree>* trees) {
  std::vector<StemObservation> obs = observeOnSlope(trees);
  const Tree far{50.0, 7.5, 10.0, 0.15};
  for (int s = 0; s < 6; ++s)
    obs.push_back({s, 0, far.x, far.y, far.z + 4.0, far.r - 0.048, false});
  trees->push_back(far);
  return obs;
}

/// A helmet 1.7 m above observeOnSlope's ground (z = 0.2 x), from x = 0 to 48, weaving 3 m
/// either side of y = 7.5 (a straight path would leave the slope across it unknown).
std::vector<SensorPosition> helmetPath(double bob_m) {
  std::vector<SensorPosition> path;
  for (int i = 0; i <= 16; ++i) {
    const double x = 3.0 * i;
    path.push_back({0, 7, x, 7.5 + 3.0 * (i % 3 - 1), 0.2 * x + 1.7 + (i % 2 ? bob_m : -bob_m)});
  }
  return path;
}

TEST(StemInventory, AHiddenBaseFarFromSeenOnesTakesTheGroundUnderTheRobotsPath) {
  std::vector<Tree> trees;
  const std::vector<StemObservation> obs = observeWithAFarTree(&trees);
  const Tree& far = trees.back();
  auto farStem = [&](const std::vector<MergedStem>& stems) {
    for (const MergedStem& m : stems) {
      if (std::hypot(m.x - far.x, m.y - far.y) < 0.5) return m;
    }
    ADD_FAILURE() << "the far tree is missing";
    return MergedStem{};
  };
  // Without the path: no ground around it, so the base is its guesses' and the DBH the raw
  // radius 4 m up (9.6 cm thin).
  const MergedStem alone = farStem(fuseStems(obs, StemFusionParams{}));
  EXPECT_NEAR(alone.z_base, far.z + 4.0, 1e-9);
  EXPECT_NEAR(alone.dbh, 2.0 * far.r - 0.096, 1e-9);
  // The helmet's height comes from the positions over the stand (their seen bases' plane),
  // the ground under the rest of the path gives the far tree its base, and the stand's taper
  // brings its radius down to breast height.
  const MergedStem with_path = farStem(fuseStems(obs, StemFusionParams{}, helmetPath(0.02)));
  EXPECT_NEAR(with_path.z_base, far.z, 0.05);
  EXPECT_NEAR(with_path.dbh, 2.0 * far.r, 0.005);
  // A sensor whose height above the ground swings by a metre (a drone) gives no ground.
  const MergedStem drone = farStem(fuseStems(obs, StemFusionParams{}, helmetPath(1.0)));
  EXPECT_NEAR(drone.z_base, far.z + 4.0, 1e-9);
  StemFusionParams off;
  off.path_min_samples = 0;
  EXPECT_NEAR(farStem(fuseStems(obs, off, helmetPath(0.02))).z_base, far.z + 4.0, 1e-9);
}

TEST(StemInventory, AHiddenBaseTakesTheFartherSeenBasesWhenNoneAreNear) {
  // observeOnSlope's stand ends at x = 21; a tree at x = 36 has no seen base within 12 m but
  // the stand's within 24 m.
  std::vector<Tree> trees;
  std::vector<StemObservation> obs = observeOnSlope(&trees);
  for (int s = 0; s < 6; ++s) obs.push_back({s, 0, 36.0, 7.5, 7.2 + 2.0, 0.2 - 0.024, false});
  auto baseAt36 = [](const std::vector<MergedStem>& stems) {
    for (const MergedStem& m : stems) {
      if (std::fabs(m.x - 36.0) < 0.5) return m.z_base;
    }
    return -1.0;
  };
  EXPECT_NEAR(baseAt36(fuseStems(obs, StemFusionParams{})), 7.2, 0.05);
  StemFusionParams near_only;
  near_only.terrain_far_radius_m = 0.0;
  EXPECT_NEAR(baseAt36(fuseStems(obs, near_only)), 9.2, 1e-9);
}

/// Rolling ground (hills as dense_slope's, 1.5 m deep and 25 m apart, here on a 20 % grade): seen
/// bases on a 3 m grid, and a tree at the bottom of a hollow whose base nobody saw (its guesses
/// 2 m up).
TEST(StemInventory, AHiddenBaseInAHollowFollowsTheRollingGround) {
  constexpr double kPi = 3.14159265358979323846, kX = 12.5, kY = 12.5;
  auto ground = [](double x, double y) {
    return 0.2 * y + 0.75 * (std::cos(2.0 * kPi * x / 25.0) + std::cos(2.0 * kPi * y / 25.0));
  };
  std::vector<StemObservation> obs;
  int64_t submap = 0;
  for (int i = -4; i <= 4; ++i) {
    for (int k = -4; k <= 4; ++k) {
      const double x = kX + 3.0 * i + 0.4 * (k % 2), y = kY + 3.0 * k + 0.4 * (i % 2);
      if (std::hypot(x - kX, y - kY) < 2.0) continue;  // the hidden tree's place
      for (int s = 0; s < 2; ++s) obs.push_back({submap++, 0, x, y, ground(x, y), 0.15, true});
    }
  }
  for (int s = 0; s < 4; ++s)
    obs.push_back({submap++, 0, kX, kY, ground(kX, kY) + 2.0, 0.15, false});
  auto hiddenBase = [&](const StemFusionParams& p) {
    for (const MergedStem& m : fuseStems(obs, p)) {
      if (std::hypot(m.x - kX, m.y - kY) < 0.1) return m.z_base;
    }
    ADD_FAILURE() << "the hidden tree is missing";
    return 0.0;
  };
  StemFusionParams plane;
  plane.terrain_sigma_m = 0.0;
  // A plane through the seen bases within 12 m sits 1.4 m above the hollow's bottom; the
  // distance-weighted quadratic 0.1 m (a cosine is not quite a quadratic over 8 m).
  EXPECT_GT(hiddenBase(plane) - ground(kX, kY), 1.0);
  EXPECT_NEAR(hiddenBase(StemFusionParams{}), ground(kX, kY), 0.15);
}

TEST(StemInventory, TaperNeedsEnoughObservationsAboveBreastHeight) {
  StemFusionParams p;
  std::vector<TaperPair> pairs;
  for (int i = 0; i < 29; ++i) pairs.push_back({1.5 + 0.05 * i, -0.01 * (1.5 + 0.05 * i)});
  pairs.push_back({0.3, 0.05});                     // at breast height: not a taper pair
  pairs.push_back({4.0, -0.2});                     // beyond max_base_offset_m
  EXPECT_EQ(taperFromObservations(pairs, p), 0.0);  // 29 < taper_min_pairs
  pairs.push_back({2.0, -0.02});
  EXPECT_NEAR(taperFromObservations(pairs, p), 0.01, 1e-9);
  p.taper_min_pairs = 0;
  EXPECT_EQ(taperFromObservations(pairs, p), 0.0);
  // A stem cannot widen upwards: clamped to 0.
  p.taper_min_pairs = 1;
  EXPECT_EQ(taperFromObservations({{2.0, 0.03}}, p), 0.0);
}

TEST(StemInventory, ASecondFitOverlappingAWellSeenStemIsDropped) {
  // A stem of r = 0.15 m seen by six submaps; submap 1 also fitted a 0.2 m circle 0.36 m away
  // (a branch with part of the bark: its circle misses the stem's by 1 cm, so extraction kept
  // both, and the two cannot share a tree). Twin stems 0.32 m apart, each seen by six submaps,
  // and a thin stem 0.6 m from the first, seen once, are trees.
  std::vector<StemObservation> obs;
  for (int s = 0; s < 6; ++s) {
    obs.push_back({s, 0, 0.0, 0.0, 0.0, 0.15, true});
    obs.push_back({s, 0, 10.0, 0.0, 0.0, 0.15, true});
    obs.push_back({s, 0, 10.32, 0.0, 0.0, 0.15, true});
  }
  obs.push_back({1, 0, 0.36, 0.0, 0.0, 0.2, true});
  obs.push_back({2, 0, 0.0, 0.6, 0.0, 0.05, true});
  StemFusionParams p;
  const std::vector<MergedStem> stems = fuseStems(obs, p);
  ASSERT_EQ(stems.size(), 4u);
  for (const MergedStem& s : stems) EXPECT_NE(s.x, 0.36);
  p.overlap_margin_m = -1.0;
  EXPECT_EQ(fuseStems(obs, p).size(), 5u);
}

TEST(StemInventory, ACircleSeenOnceBesideAWellSeenStemIsDropped) {
  // A stem of r = 0.2 m seen by five submaps; submap 3 also fitted a 7 cm circle whose edge lies
  // 0.25 m from the stem's (a sapling under its crown, a branch): dropped, as a circle that close
  // seen by two submaps is not. One seen once 0.35 m from it is kept.
  auto survey = [](double gap, int seen_by) {
    std::vector<StemObservation> obs;
    for (int s = 0; s < 5; ++s) obs.push_back({s, 0, 0.0, 0.0, 0.0, 0.2, true});
    for (int s = 0; s < seen_by; ++s) obs.push_back({3 + s, 0, 0.27 + gap, 0.0, 0.0, 0.07, true});
    return fuseStems(obs, StemFusionParams{}).size();
  };
  EXPECT_EQ(survey(0.25, 1), 1u);
  EXPECT_EQ(survey(0.25, 2), 2u);
  EXPECT_EQ(survey(0.35, 1), 2u);
  StemFusionParams p;
  p.single_overlap_margin_m = 0.0;  // below overlap_margin_m: that applies
  std::vector<StemObservation> obs;
  for (int s = 0; s < 5; ++s) obs.push_back({s, 0, 0.0, 0.0, 0.0, 0.2, true});
  obs.push_back({3, 0, 0.52, 0.0, 0.0, 0.07, true});
  EXPECT_EQ(fuseStems(obs, p).size(), 2u);
  obs.back().x = 0.33;  // 6 cm apart: a second fit of the stem
  EXPECT_EQ(fuseStems(obs, p).size(), 1u);
}

TEST(StemInventory, ACircleSeenOnceBesideAStemManySubmapsSawIsDropped) {
  // A 0.3 m stem seen by n submaps; one of them also fitted a 17 cm circle whose edge lies 0.45 m
  // from the stem's. Beside a stem seen by 8 (well seen) it goes; by 7, or with the rule off, it
  // stays, as does one 0.7 m away.
  auto survey = [](double gap, int seen_by, const StemFusionParams& p) {
    std::vector<StemObservation> obs;
    for (int s = 0; s < seen_by; ++s) obs.push_back({s, 0, 0.0, 0.0, 0.0, 0.15, true});
    obs.push_back({0, 0, 0.15 + 0.085 + gap, 0.0, 0.0, 0.085, true});
    return fuseStems(obs, p).size();
  };
  const StemFusionParams p;
  EXPECT_EQ(survey(0.45, 8, p), 1u);
  EXPECT_EQ(survey(0.45, 7, p), 2u);
  EXPECT_EQ(survey(0.7, 8, p), 2u);
  StemFusionParams off;
  off.well_seen_observations = 0;
  EXPECT_EQ(survey(0.45, 8, off), 2u);
}

TEST(StemInventory, OfTwoCirclesSeenOnceThatCloseTheSmallerIsDropped) {
  // One submap fitted a stem of r = 0.14 m and a 7 cm circle whose edge lies 0.12 m from it (part
  // of the bark with clutter beside): no other submap saw either, so the larger stays, whichever
  // came first. 0.2 m apart both stay, as do two such circles that a second submap saw too.
  auto survey = [](double gap, int seen_by, bool small_first) {
    std::vector<StemObservation> obs;
    for (int s = 0; s < seen_by; ++s) {
      const StemObservation big{s, 0, 0.0, 0.0, 0.0, 0.14, true};
      const StemObservation small{s, 0, 0.21 + gap, 0.0, 0.0, 0.07, true};
      obs.push_back(small_first ? small : big);
      obs.push_back(small_first ? big : small);
    }
    return fuseStems(obs, StemFusionParams{});
  };
  for (bool small_first : {false, true}) {
    const auto kept = survey(0.12, 1, small_first);
    ASSERT_EQ(kept.size(), 1u);
    EXPECT_NEAR(kept[0].dbh, 0.28, 1e-9);
    EXPECT_EQ(survey(0.2, 1, small_first).size(), 2u);
    EXPECT_EQ(survey(0.12, 2, small_first).size(), 2u);
  }
  StemFusionParams off;
  off.single_pair_margin_m = -1.0;
  const std::vector<StemObservation> pair{{0, 0, 0.0, 0.0, 0.0, 0.14, true},
                                          {0, 0, 0.33, 0.0, 0.0, 0.07, true}};
  EXPECT_EQ(fuseStems(pair, off).size(), 2u);
}

TEST(StemInventory, NewParametersAreValidated) {
  StemFusionParams p;
  EXPECT_EQ(p.validate(), "");
  p.max_base_offset_m = 0.5 * p.base_tol_m;
  EXPECT_NE(p.validate().find("max_base_offset_m"), std::string::npos);
  p = StemFusionParams{};
  p.terrain_radius_m = -1.0;
  EXPECT_NE(p.validate().find("terrain_radius_m"), std::string::npos);
  p = StemFusionParams{};
  p.taper_min_pairs = -1;
  EXPECT_NE(p.validate().find("taper_min_pairs"), std::string::npos);
  p = StemFusionParams{};
  p.terrain_far_radius_m = 5.0 * p.terrain_radius_m;
  EXPECT_NE(p.validate().find("terrain_far_radius_m"), std::string::npos);
  p = StemFusionParams{};
  p.terrain_sigma_m = -1.0;
  EXPECT_NE(p.validate().find("terrain_sigma_m"), std::string::npos);
  p = StemFusionParams{};
  p.path_min_samples = -1;
  EXPECT_NE(p.validate().find("path_min_samples"), std::string::npos);
  p = StemFusionParams{};
  p.path_max_spread_m = -0.1;
  EXPECT_NE(p.validate().find("path_max_spread_m"), std::string::npos);
  p = StemFusionParams{};
  p.overlap_margin_m = 2.0;
  EXPECT_NE(p.validate().find("overlap_margin_m"), std::string::npos);
  p = StemFusionParams{};
  p.single_overlap_margin_m = 1.5;
  EXPECT_NE(p.validate().find("single_overlap_margin_m"), std::string::npos);
  p = StemFusionParams{};
  p.single_pair_margin_m = 1.5;
  EXPECT_NE(p.validate().find("single_pair_margin_m"), std::string::npos);
  p = StemFusionParams{};
  p.well_seen_observations = -1;
  EXPECT_NE(p.validate().find("well_seen_observations"), std::string::npos);
  p = StemFusionParams{};
  p.single_well_seen_margin_m = 2.5;
  EXPECT_NE(p.validate().find("single_well_seen_margin_m"), std::string::npos);
}

}  // namespace
}  // namespace dtif
