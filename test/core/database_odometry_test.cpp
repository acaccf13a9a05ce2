// The database file keeps each entry's odometry pose and frame and the accepted loops (version
// 2) and still reads version-1 files, whose entries come back with an unknown odometry pose.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <vector>

#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/matching/matcher.h"

namespace dtif {
namespace {

using test::overlappingPairs;
using test::PairCase;
using test::poseXyYaw;

std::vector<char> readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<char>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void writeBytes(const std::string& path, const std::vector<uint8_t>& b) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

// FNV-1a, as the file format specifies it (written out here so the test checks the format).
uint32_t fnv1a(const std::vector<uint8_t>& b) {
  uint32_t h = 2166136261u;
  for (uint8_t c : b) {
    h ^= c;
    h *= 16777619u;
  }
  return h;
}

template <class T>
void put(std::vector<uint8_t>* b, T v) {
  uint8_t x[sizeof(T)];
  std::memcpy(x, &v, sizeof(T));
  b->insert(b->end(), x, x + sizeof(T));
}

TEST(DatabaseOdometry, RoundTripKeepsPoseFrameAndLoops) {
  const std::vector<PairCase> cases = overlappingPairs(3, 4);
  LoopDetector db{LoopDetectorParams{}};
  for (size_t i = 0; i < cases.size(); ++i) {
    EntryOdometry o;
    o.odom_frame = "robot" + std::to_string(i) + "/camera_init";
    o.T_O_S = poseXyYaw(10.0 * i - 3.25, 4.5, 0.75, 0.3 * i - 2.0);
    db.insert(std::make_shared<Descriptor>(cases[i].c), o);
  }
  db.insert(std::make_shared<Descriptor>(cases[0].q));  // odometry not given
  Loop loop;
  loop.query_robot = cases[0].q.robot;
  loop.query_id = cases[0].q.submap_id;
  loop.candidate_robot = cases[0].c.robot;
  loop.candidate_id = cases[0].c.submap_id;
  loop.T_c_q = cases[0].T_c_q;
  loop.covariance(0, 1) = loop.covariance(1, 0) = 0.25;
  loop.inliers = 9;
  loop.score = 0.75;
  db.recordLoop(loop);
  const std::string path = ::testing::TempDir() + "/dtif_db_odom.bin";
  db.save(path);
  LoopDetector other{LoopDetectorParams{}};
  other.load(path);
  ASSERT_EQ(other.size(), db.size());
  for (size_t i = 0; i < db.size(); ++i) {
    EXPECT_EQ(other.odometry(i).odom_frame, db.odometry(i).odom_frame);
    EXPECT_EQ(other.odometry(i).known(), i < cases.size());
    EXPECT_LT((other.odometry(i).T_O_S.matrix() - db.odometry(i).T_O_S.matrix()).norm(), 1e-12);
  }
  ASSERT_EQ(other.loops().size(), 1u);
  const Loop& l = other.loops()[0];
  EXPECT_EQ(l.query_robot, loop.query_robot);
  EXPECT_EQ(l.query_id, loop.query_id);
  EXPECT_EQ(l.candidate_robot, loop.candidate_robot);
  EXPECT_EQ(l.candidate_id, loop.candidate_id);
  EXPECT_LT((l.T_c_q.matrix() - loop.T_c_q.matrix()).norm(), 1e-12);
  EXPECT_EQ(l.covariance, loop.covariance);
  EXPECT_EQ(l.inliers, 9);
  EXPECT_EQ(l.score, 0.75);
}

TEST(DatabaseOdometry, BadOdometryRecordIsRejectedAndLeavesDbUnchanged) {
  const std::vector<PairCase> cases = overlappingPairs(1, 5);
  LoopDetector db{LoopDetectorParams{}};
  EntryOdometry o;
  o.odom_frame = "a/odom";
  db.insert(std::make_shared<Descriptor>(cases[0].c), o);
  const std::string path = ::testing::TempDir() + "/dtif_db_odom_bad.bin";
  db.save(path);
  std::vector<char> c = readBytes(path);
  std::vector<uint8_t> b(c.begin(), c.end());
  // The last odometry value (quaternion w = 1, before the entry's match triangles and the
  // loop count 0) becomes 3: not a rotation. Re-checksummed, so only the record's own check can
  // refuse it.
  b.resize(b.size() - 4);
  const double three = 3.0;
  const size_t triangles = 4 + 7 * db.matchTrianglesOf(0).size();
  std::memcpy(b.data() + b.size() - 8 - triangles - 8, &three, 8);
  put<uint32_t>(&b, fnv1a(b));
  writeBytes(path, b);
  LoopDetector target{LoopDetectorParams{}};
  target.insert(std::make_shared<Descriptor>(cases[0].q));
  try {
    target.load(path);
    ADD_FAILURE() << "a non-unit rotation was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("rotation"), std::string::npos) << e.what();
  }
  ASSERT_EQ(target.size(), 1u);
  EXPECT_EQ(target.entries()[0]->submap_id, cases[0].q.submap_id);
}

TEST(DatabaseOdometry, VersionOneFileLoadsWithUnknownOdometry) {
  const std::vector<PairCase> cases = overlappingPairs(2, 6);
  // A version-1 file written by hand: magic, version, count, (size, descriptor)..., checksum.
  std::vector<uint8_t> b = {'D', 'T', 'I', 'F', 'D', 'B', 0, 0};
  put<uint32_t>(&b, 1);
  put<uint64_t>(&b, cases.size());
  for (const PairCase& pc : cases) {
    const std::vector<uint8_t> e = encodeDescriptor(pc.c);
    put<uint32_t>(&b, static_cast<uint32_t>(e.size()));
    b.insert(b.end(), e.begin(), e.end());
  }
  put<uint32_t>(&b, fnv1a(b));
  const std::string path = ::testing::TempDir() + "/dtif_db_v1.bin";
  writeBytes(path, b);
  LoopDetector db{LoopDetectorParams{}};
  db.load(path);
  ASSERT_EQ(db.size(), cases.size());
  for (size_t i = 0; i < cases.size(); ++i) {
    EXPECT_EQ(db.entries()[i]->submap_id, cases[i].c.submap_id);
    EXPECT_FALSE(db.odometry(i).known());
  }
  // The loaded entries still answer queries.
  EXPECT_TRUE(db.query(cases[1].q).has_value());
}

/// Exactly equal triangles, in order.
void expectSameTriangles(const std::vector<MatchTriangle>& a, const std::vector<MatchTriangle>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].t.v, b[i].t.v) << i;
    EXPECT_EQ(a[i].t.len, b[i].t.len) << i;
    EXPECT_EQ(a[i].t.r, b[i].t.r) << i;
    EXPECT_EQ(a[i].delaunay, b[i].delaunay) << i;
  }
}

// A version-2 file (no match triangles) loads, and its entries' match triangles are computed.
TEST(DatabaseOdometry, VersionTwoFileLoadsAndComputesMatchTriangles) {
  const std::vector<PairCase> cases = overlappingPairs(2, 7);
  std::vector<uint8_t> b = {'D', 'T', 'I', 'F', 'D', 'B', 0, 0};
  put<uint32_t>(&b, 2);
  put<uint64_t>(&b, cases.size());
  for (const PairCase& pc : cases) {
    const std::vector<uint8_t> e = encodeDescriptor(pc.c);
    put<uint32_t>(&b, static_cast<uint32_t>(e.size()));
    b.insert(b.end(), e.begin(), e.end());
    put<uint16_t>(&b, 0);  // odometry frame: unknown
    for (double v : {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0}) put<double>(&b, v);
  }
  put<uint64_t>(&b, 0);  // loops
  put<uint32_t>(&b, fnv1a(b));
  const std::string path = ::testing::TempDir() + "/dtif_db_v2.bin";
  writeBytes(path, b);
  const LoopDetectorParams p;
  LoopDetector db(p);
  db.load(path);
  ASSERT_EQ(db.size(), cases.size());
  for (size_t i = 0; i < db.size(); ++i) {
    expectSameTriangles(db.matchTrianglesOf(i),
                        matchTriangles(*db.entries()[i], p.matcher.neighbour_triangles));
  }
  EXPECT_TRUE(db.query(cases[1].q).has_value());
}

// A version-3 file holds each entry's match triangles: a load reads them (a bad one is
// refused, naming the entry), with the saving detector's trunk triples; a detector whose
// matcher takes another number of neighbours computes its own instead.
TEST(DatabaseOdometry, SavedMatchTrianglesAreReadBack) {
  const std::vector<PairCase> cases = overlappingPairs(3, 8);
  const LoopDetectorParams p;
  LoopDetector live(p);
  for (const PairCase& pc : cases) ASSERT_TRUE(live.insert(std::make_shared<Descriptor>(pc.c)));
  const std::string path = ::testing::TempDir() + "/dtif_db_v3.bin";
  live.save(path);
  LoopDetector loaded(p);
  loaded.load(path);
  ASSERT_EQ(loaded.size(), live.size());
  size_t triangles = 0;
  for (size_t i = 0; i < live.size(); ++i) {
    const auto sorted = [](const std::vector<MatchTriangle>& t) {
      std::vector<std::array<int, 4>> v;
      for (const MatchTriangle& m : t) {
        std::array<int, 4> k{m.t.v[0], m.t.v[1], m.t.v[2], m.delaunay};
        std::sort(k.begin(), k.begin() + 3);
        v.push_back(k);
      }
      std::sort(v.begin(), v.end());
      return v;
    };
    EXPECT_EQ(sorted(loaded.matchTrianglesOf(i)), sorted(live.matchTrianglesOf(i))) << i;
    const auto& t = loaded.matchTrianglesOf(i);
    for (size_t j = 1; j < t.size(); ++j) EXPECT_LE(t[j - 1].t.len[0], t[j].t.len[0]);
    triangles += t.size();
  }
  EXPECT_GT(triangles, 0u);

  LoopDetectorParams two = p;
  two.matcher.neighbour_triangles = 2;
  LoopDetector other(two);
  other.load(path);
  for (size_t i = 0; i < other.size(); ++i) {
    expectSameTriangles(other.matchTrianglesOf(i), matchTriangles(*other.entries()[i], 2));
  }

  // The last entry's first triangle names a trunk the entry does not have.
  std::vector<char> c = readBytes(path);
  std::vector<uint8_t> b(c.begin(), c.end());
  b.resize(b.size() - 4);
  const size_t first = b.size() - 8 - 7 * live.matchTrianglesOf(live.size() - 1).size();
  const uint16_t beyond = static_cast<uint16_t>(live.entries().back()->trunks.size());
  std::memcpy(b.data() + first, &beyond, 2);
  put<uint32_t>(&b, fnv1a(b));
  writeBytes(path, b);
  LoopDetector target(p);
  try {
    target.load(path);
    ADD_FAILURE() << "a triangle with a trunk out of range was accepted";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("entry " + std::to_string(live.size() - 1)), std::string::npos) << what;
    EXPECT_NE(what.find("match triangle out of range"), std::string::npos) << what;
  }
  EXPECT_EQ(target.size(), 0u);
}

}  // namespace
}  // namespace dtif
