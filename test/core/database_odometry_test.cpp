// The database file keeps each entry's odometry pose and frame and the accepted loops (version
// 2) and still reads version-1 files, whose entries come back with an unknown odometry pose.
#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <vector>

#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_detector.h"

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
  // The last odometry value (quaternion w = 1, before the loop count 0) becomes 3: not a
  // rotation. Re-checksummed, so only the record's own check can refuse it.
  b.resize(b.size() - 4);
  const double three = 3.0;
  std::memcpy(b.data() + b.size() - 8 - 8, &three, 8);
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

}  // namespace
}  // namespace dtif
