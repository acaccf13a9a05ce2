// describeCloud: extract -> describe -> stamp in one call, on a fixed-seed synthetic plot.
#include "dtif/core/descriptor/describe.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "dtif/core/descriptor/trunk_accumulator.h"
#include "dtif/core/descriptor/validation.h"

namespace dtif {
namespace {

/// Flat noisy ground over [-10, 10]^2 and full stems of radius r at the given centres.
Cloud plot(const std::vector<Eigen::Vector3d>& stems, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 0.01);
  Cloud cloud;
  auto push = [&](double x, double y, double z) {
    cloud.push_back(
        pcl::PointXYZ(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)));
  };
  for (double x = -10.0; x <= 10.0; x += 0.1)
    for (double y = -10.0; y <= 10.0; y += 0.1) push(x, y, n(rng));
  for (const Eigen::Vector3d& s : stems) {  // (x, y, radius)
    for (double th = 0.0; th < 2.0 * M_PI; th += 0.04 / s.z())
      for (double h = 0.0; h < 6.0; h += 0.04) {
        const double r = s.z() + n(rng);
        push(s.x() + r * std::cos(th), s.y() + r * std::sin(th), h + n(rng));
      }
  }
  return cloud;
}

const std::vector<Eigen::Vector3d> kStems{{-6.0, -5.0, 0.12}, {-2.0, 4.0, 0.20}, {3.0, -3.0, 0.30},
                                          {6.0, 5.0, 0.16},   {-7.0, 6.0, 0.25}, {1.0, 0.5, 0.09}};

TEST(DescribeCloud, EqualsExtractThenDescribeThenStamp) {
  const Cloud cloud = plot(kStems, 1);
  const TrunkExtractorParams ep;
  const DescriptorParams dp;
  const SubmapKey key{"robot_b", 42, 123.25};
  DescribeTimings timings;
  TrunkExtractionResult ext;
  const Descriptor d = describeCloud(cloud, key, ep, dp, &timings, &ext);

  const TrunkExtractionResult ref_ext = extractTrunks(cloud, ep);
  Descriptor ref = describeSubmap(ref_ext, dp);
  ref.robot = "robot_b";
  ref.submap_id = 42;
  ref.stamp = 123.25;

  ASSERT_EQ(ext.trunks.size(), kStems.size());
  ASSERT_TRUE(d.valid) << d.invalid_reason;
  EXPECT_EQ(d.robot, "robot_b");
  EXPECT_EQ(d.submap_id, 42);
  EXPECT_EQ(d.stamp, 123.25);
  EXPECT_EQ(encodeDescriptor(d), encodeDescriptor(ref));  // identity, trunks, faces, histograms
  ASSERT_EQ(d.trunks.size(), ref.trunks.size());
  for (size_t i = 0; i < d.trunks.size(); ++i) {
    EXPECT_EQ(d.trunks[i].x, ref.trunks[i].x);
    EXPECT_EQ(d.trunks[i].y, ref.trunks[i].y);
    EXPECT_EQ(d.trunks[i].z, ref.trunks[i].z);
    EXPECT_EQ(d.trunks[i].r, ref.trunks[i].r);
  }
  // The extraction result handed back is the one described.
  ASSERT_EQ(ext.trunks.size(), ref_ext.trunks.size());
  for (size_t i = 0; i < ext.trunks.size(); ++i) EXPECT_EQ(ext.trunks[i].x, ref_ext.trunks[i].x);
  // total covers extraction and description from the same start.
  EXPECT_GE(timings.extract_ms, 0.0);
  EXPECT_GE(timings.total_ms, timings.extract_ms);
}

TEST(DescribeCloud, OptionalOutputsAndEmptyCloud) {
  const Cloud cloud = plot(kStems, 2);
  const Descriptor d =
      describeCloud(cloud, {"a", 7, 1.5}, TrunkExtractorParams{}, DescriptorParams{});
  EXPECT_TRUE(d.valid);
  EXPECT_EQ(d.submap_id, 7);
  // An empty cloud still gives a stamped (invalid) descriptor, never an exception.
  TrunkExtractionResult ext;
  ext.trunks.resize(3);  // overwritten
  const Descriptor e = describeCloud(Cloud{}, {"a", 8, 2.5}, TrunkExtractorParams{},
                                     DescriptorParams{}, nullptr, &ext);
  EXPECT_FALSE(e.valid);
  EXPECT_FALSE(e.invalid_reason.empty());
  EXPECT_EQ(e.robot, "a");
  EXPECT_EQ(e.submap_id, 8);
  EXPECT_EQ(e.stamp, 2.5);
  EXPECT_TRUE(ext.trunks.empty());
}

// The ground map is decided before it is built: describeCloud, with any byte budget, gives the
// bytes of extract -> describe -> stamp -> fitDescriptorBytes, and a map the budget drops is
// never built (the extraction handed back has none).
TEST(DescribeCloud, GroundMapOnlyBuiltWhenTheBudgetKeepsIt) {
  const Cloud cloud = plot(kStems, 3);
  TrunkExtractorParams ep;
  ep.ground_map_below_seen = 1.01;  // a map on every submap
  const SubmapKey key{"robot_c", 9, 77.5};
  const TrunkExtractionResult full = extractTrunks(cloud, ep);
  ASSERT_FALSE(full.ground_map.empty());
  Descriptor ref = describeSubmap(full, DescriptorParams{});
  ref.robot = key.robot, ref.submap_id = key.submap_id, ref.stamp = key.stamp;
  const size_t total = encodeDescriptor(ref).size();
  Descriptor rest = ref;
  rest.ground_map = GroundMap();
  const size_t rest_bytes = encodeDescriptor(rest).size();
  ASSERT_LT(rest_bytes + 100, total);
  int cases_without_map = 0;
  for (const size_t budget : {size_t{0}, total + 10, (total + rest_bytes) / 2, rest_bytes + 1,
                              rest_bytes, rest_bytes - 1, size_t{100}}) {
    DescriptorParams dp;
    dp.max_bytes = static_cast<int>(budget);
    Descriptor expected = ref;
    fitDescriptorBytes(&expected, dp.max_bytes);
    TrunkExtractionResult ext;
    const Descriptor d = describeCloud(cloud, key, ep, dp, nullptr, &ext);
    EXPECT_EQ(encodeDescriptor(d), encodeDescriptor(expected)) << "budget " << budget;
    // Not built only when the budget drops it whole (a map may be built and cropped to nothing).
    const bool fits = groundMapFits(ref, dp.max_bytes);
    if (!fits) EXPECT_TRUE(expected.ground_map.empty()) << "budget " << budget;
    EXPECT_EQ(ext.ground_map.empty(), !fits) << "budget " << budget;
    cases_without_map += !fits;
  }
  EXPECT_EQ(cases_without_map, 3);  // budgets rest_bytes, rest_bytes - 1, 100
}

bool sameTrunks(const Trunks& a, const Trunks& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (a[i].x != b[i].x || a[i].y != b[i].y || a[i].z != b[i].z || a[i].r != b[i].r ||
        a[i].base_seen != b[i].base_seen) {
      return false;
    }
  }
  return true;
}

bool holds(const Trunks& trunks, const Eigen::Vector3d& stem) {
  for (const TrunkLandmark& t : trunks) {
    if (std::hypot(t.x - stem.x(), t.y - stem.y()) < 0.1) return true;
  }
  return false;
}

// A descriptor of accumulated trunks keeps the submap's own beside them, through the wire
// format too: a back end must not take a predecessor's stem, carried in by odometry, for this
// submap's sighting (as a landmark it would tie the two submaps along the odometry's drift).
TEST(DescribeCloudAccumulated, ExtendedDescriptorsKeepTheSubmapsOwnTrunks) {
  MultiSubmapParams mp;
  mp.min_trunks = 100;  // every submap with a predecessor is extended
  mp.open_stand_share = 0.0;
  mp.forward_submaps = 1;
  TrunkAccumulator acc(mp);
  const TrunkExtractorParams ep;
  const DescriptorParams dp;
  // Submaps 0 and 1 see the six stems; submap 2 the first four and a new one. One frame.
  std::vector<Eigen::Vector3d> third(kStems.begin(), kStems.begin() + 4);
  const Eigen::Vector3d fresh(7.0, -7.0, 0.2);
  third.push_back(fresh);
  const std::vector<Cloud> clouds{plot(kStems, 11), plot(kStems, 12), plot(third, 13)};
  std::vector<Descriptor> d, updates;
  std::vector<TrunkExtractionResult> ext(3);
  for (int k = 0; k < 3; ++k) {
    std::vector<Descriptor> u;
    d.push_back(describeCloudAccumulated(clouds[k], {"a", k, 10.0 * k}, Pose::Identity(), &acc, ep,
                                         dp, nullptr, &ext[k], nullptr, &u));
    updates.insert(updates.end(), u.begin(), u.end());
  }
  // The first submap has no predecessor: its own trunks, nothing beside them.
  EXPECT_FALSE(d[0].accumulated);
  EXPECT_TRUE(d[0].own_trunks.empty());
  EXPECT_TRUE(sameTrunks(d[0].observedTrunks(), d[0].trunks));
  // The third: the stems of 0 and 1 it did not see are carried in, its new one (seen once) is
  // left out; what it observed is exactly its extraction.
  ASSERT_EQ(ext[2].trunks.size(), 5u);
  ASSERT_TRUE(d[2].accumulated);
  EXPECT_TRUE(holds(d[2].trunks, kStems[5]));
  EXPECT_FALSE(holds(d[2].trunks, fresh));
  EXPECT_TRUE(sameTrunks(d[2].own_trunks, ext[2].trunks));
  EXPECT_TRUE(sameTrunks(d[2].observedTrunks(), ext[2].trunks));
  // Forward updates of submaps 0 and 1 carry their own trunks too.
  ASSERT_FALSE(updates.empty());
  for (const Descriptor& u : updates) {
    ASSERT_TRUE(u.accumulated) << u.submap_id;
    EXPECT_TRUE(sameTrunks(u.own_trunks, ext.at(u.submap_id).trunks)) << u.submap_id;
  }
  // The wire format keeps both sets and the flag.
  const Descriptor back = decodeDescriptor(encodeDescriptor(d[2]), dp);
  EXPECT_TRUE(back.accumulated);
  ASSERT_EQ(back.own_trunks.size(), d[2].own_trunks.size());
  ASSERT_EQ(back.trunks.size(), d[2].trunks.size());
  for (size_t i = 0; i < back.own_trunks.size(); ++i) {
    EXPECT_NEAR(back.own_trunks[i].x, d[2].own_trunks[i].x, 1e-5);
    EXPECT_NEAR(back.own_trunks[i].r, d[2].own_trunks[i].r, 1e-6);
    EXPECT_EQ(back.own_trunks[i].base_seen, d[2].own_trunks[i].base_seen);
  }
  EXPECT_FALSE(decodeDescriptor(encodeDescriptor(d[0]), dp).accumulated);
  // A non-finite own trunk is refused like a non-finite trunk.
  Descriptor bad = d[2];
  bad.own_trunks[1].y = std::nan("");
  EXPECT_NE(checkDescriptor(bad).find("own trunks"), std::string::npos) << checkDescriptor(bad);
}

// extractTrunks asks `wanted` once, with the trunks and footprint found, before the map.
TEST(ExtractTrunks, GroundMapWantedSeesTheTrunksAndCanSkipTheMap) {
  const Cloud cloud = plot(kStems, 4);
  TrunkExtractorParams ep;
  ep.ground_map_below_seen = 1.01;
  const TrunkExtractionResult full = extractTrunks(cloud, ep);
  ASSERT_FALSE(full.ground_map.empty());
  for (const bool want : {false, true}) {
    int asked = 0;
    const TrunkExtractionResult r =
        extractTrunks(cloud, ep, [&](const TrunkExtractionResult& without_map) {
          ++asked;
          EXPECT_TRUE(without_map.ground_map.empty());
          EXPECT_EQ(without_map.trunks.size(), full.trunks.size());
          EXPECT_EQ(without_map.footprint.bits, full.footprint.bits);
          return want;
        });
    EXPECT_EQ(asked, 1);
    EXPECT_EQ(r.ground_map.empty(), !want);
    if (want) EXPECT_EQ(r.ground_map.z, full.ground_map.z);
    ASSERT_EQ(r.trunks.size(), full.trunks.size());
    for (size_t i = 0; i < r.trunks.size(); ++i) EXPECT_EQ(r.trunks[i].z, full.trunks[i].z);
  }
  // No map to build (ground_map_below_seen 0): never asked.
  ep.ground_map_below_seen = 0.0;
  int asked = 0;
  extractTrunks(cloud, ep, [&](const TrunkExtractionResult&) { return ++asked > 0; });
  EXPECT_EQ(asked, 0);
}

}  // namespace
}  // namespace dtif
