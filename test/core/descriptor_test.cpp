#include "dtif/core/descriptor/descriptor.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>

#include "core/descriptor_test_utils.h"
#include "core/ground_test_utils.h"
#include "core/match_test_utils.h"
#include "dtif/core/descriptor/validation.h"

namespace dtif {
namespace {

TEST(Descriptor, CanonicalTriangleOrderMatchesEq32) {
  // Right triangle with sides 5 (A-B), 4 (B-C), 3 (C-A):
  // A=(0,3), B=(4,0), C=(0,0). e1 = AB (5), e2 = BC (4), e3 = CA (3).
  // I = (e1^e2, e2^e3, e3^e1) = (B, C, A).
  const Trunks t = {{0, 3, 0, 0.1}, {4, 0, 0, 0.2}, {0, 0, 0, 0.3}};
  for (auto perm : {std::array<int, 3>{0, 1, 2}, {1, 2, 0}, {2, 1, 0}, {0, 2, 1}}) {
    const Triangle tri = makeCanonicalTriangle(t, perm[0], perm[1], perm[2]);
    EXPECT_EQ(tri.v, (std::array<int, 3>{1, 2, 0}));
    EXPECT_FLOAT_EQ(tri.len[0], 5.0f);
    EXPECT_FLOAT_EQ(tri.len[1], 4.0f);
    EXPECT_FLOAT_EQ(tri.len[2], 3.0f);
    // Eq. (3.3): radii follow I.
    EXPECT_FLOAT_EQ(tri.r[0], 0.2f);
    EXPECT_FLOAT_EQ(tri.r[1], 0.3f);
    EXPECT_FLOAT_EQ(tri.r[2], 0.1f);
    // kEdgeEnds: e1 joins v[0], v[2] (B, A); e2 joins v[0], v[1] (B, C); e3 v[1], v[2] (C, A).
    for (int a = 0; a < 3; ++a) {
      const TrunkLandmark& p = t[tri.v[kEdgeEnds[a][0]]];
      const TrunkLandmark& q = t[tri.v[kEdgeEnds[a][1]]];
      EXPECT_FLOAT_EQ(static_cast<float>(std::hypot(p.x - q.x, p.y - q.y)), tri.len[a]);
    }
  }
}

TEST(Descriptor, CanonicalTriangleTiesAreDeterministic) {
  // Equilateral: every order is a tie; the result must not depend on the vertex order.
  const Trunks t = {{0, 0, 0, 0.1}, {2, 0, 0, 0.2}, {1, std::sqrt(3.0), 0, 0.3}};
  const Triangle ref = makeCanonicalTriangle(t, 0, 1, 2);
  EXPECT_EQ(makeCanonicalTriangle(t, 2, 0, 1).v, ref.v);
  EXPECT_EQ(makeCanonicalTriangle(t, 1, 0, 2).v, ref.v);
}

TEST(Descriptor, EmptyAndTooFewTrunksAreInvalid) {
  DescriptorParams p;
  Descriptor d = buildDescriptor({}, p);
  EXPECT_FALSE(d.valid);
  EXPECT_NE(d.invalid_reason.find("too few trunks"), std::string::npos);
  d = buildDescriptor({{0, 0, 0, .1}, {1, 0, 0, .1}}, p);
  EXPECT_FALSE(d.valid);
  EXPECT_FALSE(d.invalid_reason.empty());
}

TEST(Descriptor, CollinearIsInvalidWithReason) {
  Trunks t;
  for (int i = 0; i < 8; ++i) t.push_back({1.5 * i, 0.5 * i, 0, 0.1});
  const Descriptor d = buildDescriptor(t, DescriptorParams{});
  EXPECT_FALSE(d.valid);
  EXPECT_NE(d.invalid_reason.find("collinear"), std::string::npos) << d.invalid_reason;
}

TEST(Descriptor, DuplicateAndNanTrunksAreRemoved) {
  Trunks t = {{0, 0, 0, .1}, {5, 0, 0, .2}, {0, 5, 0, .3}, {5, 5.5, 0, .15}};
  Trunks with = t;
  with.push_back({5.004, 0.003, 0, .22});  // same stem seen twice
  with.push_back({std::numeric_limits<double>::quiet_NaN(), 1, 0, .1});
  with.push_back({1, 1, 0, std::numeric_limits<double>::infinity()});
  const Descriptor a = buildDescriptor(t, DescriptorParams{});
  const Descriptor b = buildDescriptor(with, DescriptorParams{});
  ASSERT_TRUE(a.valid) << a.invalid_reason;
  ASSERT_TRUE(b.valid) << b.invalid_reason;
  ASSERT_EQ(b.trunks.size(), 4u);
  EXPECT_NEAR(b.trunks[1].r, 0.21, 1e-9);  // merged: mean radius
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  for (size_t i = 0; i < a.triangles.size(); ++i) {
    EXPECT_EQ(a.triangles[i].v, b.triangles[i].v);
  }
  for (const TrunkLandmark& x : b.trunks) EXPECT_TRUE(std::isfinite(x.x) && std::isfinite(x.r));
}

TEST(Descriptor, TrianglesSortedAndHistogramsNormalised) {
  std::mt19937 rng(7);
  const Trunks world = test::randomStand(rng, 40, 40, 600);
  const Descriptor d = buildDescriptor(world, DescriptorParams{});
  ASSERT_TRUE(d.valid);
  ASSERT_GT(d.triangles.size(), 20u);
  for (size_t i = 1; i < d.triangles.size(); ++i) {
    EXPECT_LE(d.triangles[i - 1].len[0], d.triangles[i].len[0]);
  }
  for (const Triangle& t : d.triangles) {
    EXPECT_GE(t.len[0], t.len[1]);
    EXPECT_GE(t.len[1], t.len[2]);
  }
  EXPECT_NEAR(std::accumulate(d.edge_hist.begin(), d.edge_hist.end(), 0.0), 1.0, 1e-5);
  EXPECT_NEAR(std::accumulate(d.radius_hist.begin(), d.radius_hist.end(), 0.0), 1.0, 1e-5);
  EXPECT_EQ(d.edge_hist.size(), 16u);
  EXPECT_EQ(d.radius_hist.size(), 10u);
  // Delaunay on M points in general position has at most 2M - 5 faces.
  EXPECT_LE(d.triangles.size(), 2 * d.trunks.size() - 5);
}

TEST(Descriptor, MinAngleAndMaxEdgeDropFaces) {
  // A sliver: C almost on AB.
  const Trunks t = {{0, 0, 0, .1}, {10, 0, 0, .1}, {5, 0.2, 0, .1}, {5, 6, 0, .1}};
  DescriptorParams p;
  p.min_trunks = 3;
  p.min_triangles = 1;
  const Descriptor d = buildDescriptor(t, p);
  ASSERT_TRUE(d.valid) << d.invalid_reason;
  EXPECT_EQ(d.triangles.size(), 2u);  // the sliver (0,1,2) is dropped, 2 faces remain
  // Both remaining faces have a 7.81 m edge (A-D, B-D): a 7.5 m limit drops them all.
  for (const Triangle& tri : d.triangles) EXPECT_NEAR(tri.len[0], std::hypot(5.0, 6.0), 1e-5);
  p.max_edge_m = 7.5;
  const Descriptor e = buildDescriptor(t, p);
  EXPECT_TRUE(e.triangles.empty());
  EXPECT_FALSE(e.valid);
  EXPECT_NE(e.invalid_reason.find("too few triangles"), std::string::npos);
}

TEST(Descriptor, InvariantToRigidMotionIncludingHugeOffsetsAnd180Degrees) {
  std::mt19937 rng(11);
  const Trunks local = test::randomStand(rng, 30, 30, 600);
  const Descriptor a = buildDescriptor(local, DescriptorParams{});
  ASSERT_TRUE(a.valid);
  const Pose T = test::poseXyYaw(1e5, -2e5, 300.0, M_PI);
  Trunks moved;
  for (const TrunkLandmark& t : local) {
    const Eigen::Vector3d p = T * Eigen::Vector3d(t.x, t.y, t.z);
    moved.push_back({p.x(), p.y(), p.z(), t.r});
  }
  const Descriptor b = buildDescriptor(moved, DescriptorParams{});
  ASSERT_TRUE(b.valid);
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  for (size_t i = 0; i < a.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(a.triangles[i].len[k], b.triangles[i].len[k], 1e-4);
  }
  EXPECT_EQ(a.edge_hist, b.edge_hist);
}

TEST(Descriptor, WireRoundTripSmallAndExact) {
  std::mt19937 rng(3);
  Trunks t = test::randomStand(rng, 40, 40, 500);
  for (TrunkLandmark& x : t) x.x += 312000.0, x.y += 5096000.0;  // UTM-like offsets
  for (size_t i = 0; i < t.size(); ++i) t[i].base_seen = (i * 7) % 3 != 0;
  Descriptor d = buildDescriptor(t, DescriptorParams{});
  while (d.trunks.size() % 8 == 0) {
    t.pop_back();
    d = buildDescriptor(t, DescriptorParams{});
  }
  ASSERT_TRUE(d.valid);
  ASSERT_NE(d.trunks.size() % 8, 0u);  // the last byte of base_seen bits is partial
  d.robot = "robot_b";
  d.submap_id = 42;
  d.stamp = 1234.5;
  std::vector<std::pair<int64_t, int64_t>> cells;
  for (int64_t k = 0; k < 3000; ++k) cells.emplace_back(312000 + (k * 37) % 80, 5096000 + k % 77);
  d.footprint = makeFootprint(cells, 1.0);
  ASSERT_GT(d.footprint.count(), 1000u);
  const std::vector<uint8_t> bytes = encodeDescriptor(d);
  std::printf("[ info ] %zu trunks, %zu faces -> %zu bytes\n", d.trunks.size(), d.triangles.size(),
              bytes.size());
  EXPECT_LE(bytes.size(), 8192u);
  const Descriptor e = decodeDescriptor(bytes, DescriptorParams{});
  EXPECT_TRUE(e.valid);
  EXPECT_EQ(e.robot, "robot_b");
  EXPECT_EQ(e.submap_id, 42);
  EXPECT_EQ(e.stamp, 1234.5);
  ASSERT_EQ(e.trunks.size(), d.trunks.size());
  for (size_t i = 0; i < d.trunks.size(); ++i) {
    // float32 offsets from the first trunk, under 64 m in a 40 m stand: rounding is at most
    // half a float ULP, 2^-19 m (1.9 um), plus half a double ULP when the origin is added back
    // at up to 5.1e6 m (2^-31 m); radii under 0.5 m: 2^-26 m (15 nm).
    const double tol_m = std::ldexp(1.0, -19) + std::ldexp(1.0, -31);
    EXPECT_NEAR(e.trunks[i].x, d.trunks[i].x, tol_m);
    EXPECT_NEAR(e.trunks[i].y, d.trunks[i].y, tol_m);
    EXPECT_NEAR(e.trunks[i].z, d.trunks[i].z, tol_m);
    EXPECT_NEAR(e.trunks[i].r, d.trunks[i].r, std::ldexp(1.0, -26));
    EXPECT_EQ(e.trunks[i].base_seen, d.trunks[i].base_seen) << "trunk " << i;
  }
  ASSERT_EQ(e.triangles.size(), d.triangles.size());
  for (size_t i = 0; i < d.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(e.triangles[i].len[k], d.triangles[i].len[k], 1e-3);
  }
  ASSERT_EQ(e.edge_hist.size(), d.edge_hist.size());
  for (size_t i = 0; i < d.edge_hist.size(); ++i) EXPECT_NEAR(e.edge_hist[i], d.edge_hist[i], 4e-3);
  EXPECT_EQ(e.footprint.cell_m, d.footprint.cell_m);
  EXPECT_EQ(e.footprint.x0, d.footprint.x0);
  EXPECT_EQ(e.footprint.y0, d.footprint.y0);
  EXPECT_EQ(e.footprint.width, d.footprint.width);
  EXPECT_EQ(e.footprint.height, d.footprint.height);
  EXPECT_EQ(e.footprint.bits, d.footprint.bits);
  // Without a footprint (a trunk map) the descriptor says so in four bytes.
  Descriptor plain = d;
  plain.footprint = Footprint{};
  EXPECT_EQ(encodeDescriptor(plain).size(), bytes.size() - 12 - d.footprint.bits.size());
  EXPECT_TRUE(decodeDescriptor(encodeDescriptor(plain), DescriptorParams{}).footprint.empty());
  // A ground map travels along (encodeGroundMap's bytes after a length).
  Descriptor grounded = d;
  std::mt19937 grng(8);
  grounded.ground_map = test::mapOf(test::hillyGround(grng, Eigen::Vector2d(0, 0), 10.0, false),
                                    Pose::Identity(), 0.5, 0.05);
  ASSERT_GT(grounded.ground_map.count(), 500u);
  const std::vector<uint8_t> gbytes = encodeDescriptor(grounded);
  EXPECT_EQ(gbytes.size(), bytes.size() + encodeGroundMap(grounded.ground_map).size());
  const Descriptor g = decodeDescriptor(gbytes, DescriptorParams{});
  EXPECT_EQ(g.ground_map.z, grounded.ground_map.z);
  EXPECT_EQ(g.ground_map.width, grounded.ground_map.width);
}

TEST(Descriptor, GroundMapCroppedToTheByteBudget) {
  std::mt19937 rng(4);
  const Trunks t = test::randomStand(rng, 40, 40, 500);
  Descriptor d = buildDescriptor(t, DescriptorParams{});
  ASSERT_TRUE(d.valid);
  std::mt19937 grng(9);
  d.ground_map = test::mapOf(test::hillyGround(grng, Eigen::Vector2d(0, 0), 25.0, false),
                             Pose::Identity(), 0.5, 0.05);
  const size_t total = encodeDescriptor(d).size();
  const size_t map = encodeGroundMap(d.ground_map).size();
  ASSERT_GT(map, 2000u);
  // Within budget, or no limit: untouched.
  Descriptor same = d;
  fitDescriptorBytes(&same, static_cast<int>(total));
  EXPECT_EQ(same.ground_map.z, d.ground_map.z);
  fitDescriptorBytes(&same, 0);
  EXPECT_EQ(same.ground_map.z, d.ground_map.z);
  // Over budget: the map gives way until the whole descriptor fits; trunks and faces stay.
  const int budget = static_cast<int>(total - map / 2);
  Descriptor fit = d;
  fitDescriptorBytes(&fit, budget);
  EXPECT_LE(encodeDescriptor(fit).size(), static_cast<size_t>(budget));
  EXPECT_FALSE(fit.ground_map.empty());
  // Coarser heights (twice the step) and, if that was not enough, fewer cells.
  EXPECT_NEAR(fit.ground_map.z_step_m, 2.0 * d.ground_map.z_step_m, 1e-9);
  EXPECT_LE(fit.ground_map.count(), d.ground_map.count());
  EXPECT_EQ(fit.trunks.size(), d.trunks.size());
  EXPECT_EQ(fit.triangles.size(), d.triangles.size());
  // The rest alone over budget: no map at all.
  Descriptor none = d;
  fitDescriptorBytes(&none, static_cast<int>(total - map - 10));
  EXPECT_TRUE(none.ground_map.empty());
}

TEST(Descriptor, DecodeRejectsMalformedBytes) {
  std::mt19937 rng(5);
  const Descriptor d = buildDescriptor(test::randomStand(rng, 30, 30, 600), DescriptorParams{});
  ASSERT_TRUE(d.valid);
  const std::vector<uint8_t> good = encodeDescriptor(d);
  EXPECT_THROW(decodeDescriptor({}, DescriptorParams{}), std::runtime_error);
  std::vector<uint8_t> bad = good;
  bad.resize(good.size() / 2);
  EXPECT_THROW(decodeDescriptor(bad, DescriptorParams{}), std::runtime_error);
  bad = good;
  bad[0] ^= 0xff;  // magic
  EXPECT_THROW(decodeDescriptor(bad, DescriptorParams{}), std::runtime_error);
  bad = good;
  bad[4] = 99;  // version
  EXPECT_THROW(decodeDescriptor(bad, DescriptorParams{}), std::runtime_error);
  bad = good;
  bad[good.size() - 20] ^= 0x10;  // payload bit flip
  EXPECT_THROW(decodeDescriptor(bad, DescriptorParams{}), std::runtime_error);
  bad = good;
  bad.push_back(0);
  EXPECT_THROW(decodeDescriptor(bad, DescriptorParams{}), std::runtime_error);
}

// ---- validation.h: the checks every received descriptor passes (wire bytes, ROS messages) ----

constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();

Descriptor validStand(unsigned seed) {
  std::mt19937 rng(seed);
  Descriptor d = buildDescriptor(test::randomStand(rng, 30, 30, 600), DescriptorParams{});
  d.robot = "alpha";
  d.submap_id = 3;
  return d;
}

/// The FNV-1a of the wire format (core/byte_io.h), so a test can patch a payload and reseal it.
void reseal(std::vector<uint8_t>* bytes) {
  uint32_t h = 2166136261u;
  for (size_t i = 16; i < bytes->size(); ++i) {
    h ^= (*bytes)[i];
    h *= 16777619u;
  }
  std::memcpy(bytes->data() + 12, &h, 4);
}

/// decodeDescriptor's exception text, or "" when it accepts the bytes.
std::string decodeError(const std::vector<uint8_t>& bytes) {
  try {
    decodeDescriptor(bytes, DescriptorParams{});
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(DescriptorValidation, CheckNamesEachProblem) {
  const Descriptor good = validStand(5);
  ASSERT_TRUE(good.valid);
  ASSERT_GT(good.triangles.size(), 5u);
  EXPECT_EQ(checkDescriptor(good), "");
  EXPECT_EQ(checkDescriptor(Descriptor{}), "");  // empty and invalid, yet well formed
  struct Case {
    std::string want;
    std::function<void(Descriptor&)> corrupt;
  };
  const std::vector<Case> cases = {
      {"65536 trunks: more than kMaxDescriptorTrunks (2000)",
       [](Descriptor& d) { d.trunks.resize(65536, d.trunks[0]); }},
      {"trunk 3 is not finite or has a negative radius",
       [](Descriptor& d) { d.trunks[3].r = kNaNf; }},
      {"trunk 1 is not finite or has a negative radius",
       [](Descriptor& d) { d.trunks[1].z = std::numeric_limits<double>::infinity(); }},
      {"trunk 2 is not finite or has a negative radius",
       [](Descriptor& d) { d.trunks[2].r = -0.1; }},
      {"face 4 indexes a missing trunk",
       [](Descriptor& d) { d.triangles[4].v[1] = static_cast<int>(d.trunks.size()); }},
      {"face 0 indexes a missing trunk", [](Descriptor& d) { d.triangles[0].v[2] = -1; }},
      {"face 2 repeats a vertex", [](Descriptor& d) { d.triangles[2].v[2] = d.triangles[2].v[0]; }},
      {"edge histogram has 256 bins: more than kMaxHistogramBins (64)",
       [](Descriptor& d) { d.edge_hist.assign(256, 1.0f / 256); }},
      {"edge histogram is not finite or negative", [](Descriptor& d) { d.edge_hist[1] = kNaNf; }},
      {"radius histogram is not finite or negative",
       [](Descriptor& d) { d.radius_hist[0] = -0.5f; }},
      {"edge histogram has no counts",
       [](Descriptor& d) { std::fill(d.edge_hist.begin(), d.edge_hist.end(), 0.0f); }},
      {"footprint is not well formed (cell size, sides or bitmap size)",
       [](Descriptor& d) {
         d.footprint = makeFootprint({{0, 0}, {3, 4}}, 1.0);
         d.footprint.bits.pop_back();
       }},
      {"footprint is not well formed (cell size, sides or bitmap size)",
       [](Descriptor& d) {
         d.footprint = makeFootprint({{0, 0}, {3, 4}}, 1.0);
         d.footprint.cell_m = -1.0;
       }},
      {"ground map is not well formed (cell size, sides or cell count)",
       [](Descriptor& d) {
         d.ground_map.cell_m = 0.5;
         d.ground_map.width = d.ground_map.height = 2;
         d.ground_map.z.assign(3, 0);
       }},
  };
  for (const Case& c : cases) {
    Descriptor bad = good;
    c.corrupt(bad);
    EXPECT_EQ(checkDescriptor(bad), c.want);
    // acceptReceivedDescriptor refuses with the same words and leaves the descriptor alone.
    Descriptor copy = bad;
    EXPECT_EQ(acceptReceivedDescriptor(&copy, DescriptorParams{}), c.want);
    EXPECT_EQ(copy.trunks.size(), bad.trunks.size());
    EXPECT_EQ(copy.triangles.size(), bad.triangles.size());
  }
}

TEST(DescriptorValidation, DecodeThrowsTheCheckWords) {
  const Descriptor good = validStand(5);
  ASSERT_TRUE(good.valid);
  // What the wire format can carry: encode the bad descriptor, decode must say what the check
  // says about it.
  const auto corruptions = test::descriptorCorruptions();
  for (size_t i = 0; i < corruptions.size(); ++i) {
    Descriptor bad = good;
    corruptions[i](bad);
    const std::string want = checkDescriptor(bad);
    ASSERT_NE(want, "") << "case " << i;
    EXPECT_EQ(decodeError(encodeDescriptor(bad)), want) << "case " << i;
  }
  // A footprint with a negative cell size: the encoder never writes one, so patch the bytes.
  Descriptor framed = good;
  framed.footprint = makeFootprint({{0, 0}, {3, 4}}, 1.0);
  std::vector<uint8_t> bytes = encodeDescriptor(framed);
  ASSERT_EQ(decodeError(bytes), "");
  // Payload tail: f32 cell, i32 x0, y0, u16 w, h, the bits, u32 ground map bytes (0).
  const size_t cell_at = bytes.size() - 4 - framed.footprint.bits.size() - 12 - 4;
  const float minus_one = -1.0f;
  std::memcpy(bytes.data() + cell_at, &minus_one, 4);
  reseal(&bytes);
  framed.footprint.cell_m = -1.0;
  EXPECT_EQ(decodeError(bytes), checkDescriptor(framed));
  EXPECT_NE(decodeError(bytes).find("footprint"), std::string::npos);
  // A ground map that does not decode: the same "ground map: " words as ros_glue::fromMsg.
  Descriptor grounded = good;
  std::mt19937 grng(8);
  grounded.ground_map = test::mapOf(test::hillyGround(grng, Eigen::Vector2d(0, 0), 10.0, false),
                                    Pose::Identity(), 0.5, 0.05);
  bytes = encodeDescriptor(grounded);
  const std::vector<uint8_t> ground = encodeGroundMap(grounded.ground_map);
  std::memset(bytes.data() + bytes.size() - ground.size(), 0, 4);  // its cell size: 0
  reseal(&bytes);
  std::vector<uint8_t> bad_ground = ground;
  std::memset(bad_ground.data(), 0, 4);
  GroundMap unused;
  const std::string want = decodeReceivedGroundMap(bad_ground.data(), bad_ground.size(), &unused);
  EXPECT_EQ(want.rfind("ground map: ", 0), 0u) << want;
  EXPECT_EQ(decodeError(bytes), want);
}

TEST(DescriptorValidation, ReceiverParamsMarkSmallDescriptorsInvalid) {
  const Descriptor good = validStand(5);
  ASSERT_TRUE(good.valid);
  const std::vector<uint8_t> bytes = encodeDescriptor(good);
  const int n = static_cast<int>(good.trunks.size());
  const int m = static_cast<int>(good.triangles.size());
  DescriptorParams strict;
  strict.min_trunks = n + 1;
  Descriptor d = decodeDescriptor(bytes, strict);
  EXPECT_FALSE(d.valid);
  EXPECT_EQ(d.invalid_reason, "too few trunks or triangles for the receiver's descriptor params (" +
                                  std::to_string(n) + " trunks, " + std::to_string(m) +
                                  " triangles; min_trunks " + std::to_string(n + 1) +
                                  ", min_triangles 2)");
  EXPECT_EQ(d.trunks.size(), good.trunks.size());  // kept, only not retrievable
  strict = DescriptorParams{};
  strict.min_triangles = m + 1;
  EXPECT_FALSE(decodeDescriptor(bytes, strict).valid);
  strict.min_triangles = m;
  EXPECT_TRUE(decodeDescriptor(bytes, strict).valid);
  // The loosest params keep the sender's validity, down to the matcher's 3 trunks and 1 face.
  EXPECT_TRUE(decodeDescriptor(bytes, loosestDescriptorParams()).valid);
  Descriptor two = good;
  two.trunks.resize(2);
  two.triangles.clear();
  d = decodeDescriptor(encodeDescriptor(two), loosestDescriptorParams());
  EXPECT_FALSE(d.valid);
  EXPECT_NE(d.invalid_reason.find("too few trunks"), std::string::npos) << d.invalid_reason;
  // An invalid descriptor keeps its sender's reason.
  Descriptor small = buildDescriptor({{0, 0, 0, .1}, {1, 0, 0, .1}}, DescriptorParams{});
  ASSERT_FALSE(small.valid);
  d = decodeDescriptor(encodeDescriptor(small), DescriptorParams{});
  EXPECT_FALSE(d.valid);
  EXPECT_EQ(d.invalid_reason, small.invalid_reason);
}

TEST(DescriptorValidation, AcceptRebuildsFacesInBuildOrder) {
  const Descriptor good = validStand(6);
  ASSERT_TRUE(good.valid);
  // Faces arrive as bare vertex triples, in any order and any vertex rotation.
  Descriptor received = good;
  std::reverse(received.triangles.begin(), received.triangles.end());
  for (Triangle& t : received.triangles) {
    t = Triangle{{t.v[1], t.v[2], t.v[0]}, {}, {}};
  }
  ASSERT_EQ(acceptReceivedDescriptor(&received, DescriptorParams{}), "");
  EXPECT_TRUE(received.valid);
  ASSERT_EQ(received.triangles.size(), good.triangles.size());
  for (size_t i = 0; i < good.triangles.size(); ++i) {
    EXPECT_EQ(received.triangles[i].v, good.triangles[i].v) << "face " << i;
    EXPECT_EQ(received.triangles[i].len, good.triangles[i].len) << "face " << i;
    EXPECT_EQ(received.triangles[i].r, good.triangles[i].r) << "face " << i;
  }
}

TEST(Descriptor, ParamsValidate) {
  EXPECT_EQ(DescriptorParams{}.validate(), "");
  DescriptorParams p;
  p.edge_hist_bins = 0;
  EXPECT_NE(p.validate(), "");
  p = DescriptorParams{};
  p.min_angle_deg = 70;
  EXPECT_NE(p.validate(), "");
  p = DescriptorParams{};
  p.radius_hist_max_m = 0;
  EXPECT_NE(p.validate(), "");
  p = DescriptorParams{};
  p.max_bytes = -1;
  EXPECT_NE(p.validate().find("max_bytes"), std::string::npos);
}

}  // namespace
}  // namespace dtif
