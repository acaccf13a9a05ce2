// Submap assembly from registered clouds + odometry, without a master.
#include "dtif/ros/submap_assembler.h"

#include <gtest/gtest.h>

#include <cmath>
#include <optional>

#include "test_utils.h"

namespace dtif {
namespace ros_glue {
namespace {

using Status = SubmapAssembler::Status;

using test::makePose;

Cloud cloudOf(std::initializer_list<Eigen::Vector3f> pts) {
  Cloud c;
  for (const auto& p : pts) c.push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  return c;
}

TEST(GravityAlignedPose, KeepsPositionAndYawDropsRollPitch) {
  const Pose T_O_S = gravityAlignedPose(makePose(3, 4, 1, 0.1, -0.05, 0.8));
  EXPECT_TRUE(T_O_S.translation().isApprox(Eigen::Vector3d(3, 4, 1)));
  EXPECT_NEAR(T_O_S.rotation()(2, 2), 1.0, 1e-12);  // z up
  const Eigen::Vector3d x = T_O_S.rotation().col(0);
  EXPECT_NEAR(std::atan2(x.y(), x.x()), 0.8, 0.01);
}

// Every point kept (no voxel filter): these tests count and place single points.
SubmapAssemblerParams unfiltered(double window_s) {
  SubmapAssemblerParams p;
  p.window_s = window_s;
  p.voxel_m = 0.0;
  return p;
}

// Odometry every 0.05 s over [t0, t1]: moving along +x at 1 m/s from x0, facing +y.
void addTrack(SubmapAssembler* a, double t0, double t1, double x0) {
  for (double t = t0; t <= t1 + 1e-9; t += 0.05) {
    ASSERT_EQ(a->addOdometry(t, makePose(x0 + (t - t0), 0, 0, 0, 0, M_PI / 2)), Status::kOk);
  }
}

TEST(SubmapAssembler, AnchorsEachWindowAtItsCentre) {
  // cloud_period_s 0.1: the first cloud (10.1) covers (10.0, 10.1]
  SubmapAssemblerParams p = unfiltered(1.0);
  SubmapAssembler a(p, 5);
  addTrack(&a, 10.0, 13.0, 2.0);  // sensor at x = 2 + (t - 10)
  std::optional<AssembledSubmap> done;
  // Window 0 = (10.0, 11.0], centre 10.5: sensor at (2.5, 0, 0) facing +y. A point at O
  // (2.5, 1, 0.5) is 1 m ahead of it.
  EXPECT_EQ(a.addCloud(10.1, cloudOf({{2.5f, 1, 0.5f}}), &done), Status::kOk);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(10.6, cloudOf({{2.5f, 3, 0}, {NAN, 0, 0}}), &done), Status::kOk);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(11.0, cloudOf({{0, 0, 0}}), &done), Status::kOk);  // the window's last
  ASSERT_TRUE(done);
  EXPECT_EQ(done->id, 5);
  EXPECT_DOUBLE_EQ(done->stamp, 10.5);
  EXPECT_DOUBLE_EQ(done->end_stamp, 11.0);
  EXPECT_TRUE(done->T_O_S.translation().isApprox(Eigen::Vector3d(2.5, 0, 0), 1e-9));
  EXPECT_NEAR(std::atan2(done->T_O_S.rotation()(1, 0), done->T_O_S.rotation()(0, 0)), M_PI / 2,
              1e-9);
  ASSERT_EQ(done->cloud->size(), 3u);
  EXPECT_NEAR((*done->cloud)[0].x, 1.0, 1e-5);  // 1 m ahead = +x of S
  EXPECT_NEAR((*done->cloud)[0].y, 0.0, 1e-5);
  EXPECT_NEAR((*done->cloud)[0].z, 0.5, 1e-5);
  EXPECT_NEAR((*done->cloud)[1].x, 3.0, 1e-5);
  EXPECT_NEAR((*done->cloud)[2].x, 0.0, 1e-5);  // O's origin, 2.5 m to the left of S
  EXPECT_NEAR((*done->cloud)[2].y, 2.5, 1e-5);

  // Window 1 = (11.0, 12.0] loses its last cloud: the first cloud of window 2 finishes it.
  EXPECT_EQ(a.addCloud(11.1, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(11.7, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(12.3, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  ASSERT_TRUE(done);
  EXPECT_EQ(done->id, 6);
  EXPECT_DOUBLE_EQ(done->stamp, 11.5);
  EXPECT_DOUBLE_EQ(done->end_stamp, 11.7);
  EXPECT_NEAR(done->T_O_S.translation().x(), 3.5, 1e-9);
  EXPECT_EQ(done->cloud->size(), 2u);
  // Window 2 = (12.0, 13.0] is open with one cloud; its centre 12.5 has odometry.
  const auto last = a.flush();
  ASSERT_TRUE(last);
  EXPECT_EQ(last->id, 7);
  EXPECT_DOUBLE_EQ(last->stamp, 12.5);
  EXPECT_EQ(last->cloud->size(), 1u);
}

// Stamps as a bag keeps them (whole nanoseconds of an epoch ~1.7e9 s): 10 Hz clouds starting
// 0.1 s after the robot's start cut into 10 s windows at the simulator's boundaries, the last
// cloud of each window (its end) included, each stamped at its centre.
TEST(SubmapAssembler, PartitionsTimeLikeTheSimulator) {
  SubmapAssembler a{unfiltered(10.0)};
  const int64_t start_ns = 1700000123LL * 1000000000LL + 400000000LL;  // robot start
  auto stampOf = [&](int i) { return static_cast<double>(start_ns + i * 100000000LL) * 1e-9; };
  std::vector<AssembledSubmap> out;
  std::vector<int> closing;
  for (int i = 0; i <= 250; ++i) {
    ASSERT_EQ(a.addOdometry(stampOf(i), makePose(0.1 * i, 0, 0, 0, 0, 0)), Status::kOk);
    if (i == 0) continue;  // sensors publish a cloud at the end of each 0.1 s frame
    std::optional<AssembledSubmap> done;
    ASSERT_EQ(a.addCloud(stampOf(i), cloudOf({{0, 0, 0}}), &done), Status::kOk);
    if (done) {
      out.push_back(std::move(*done));
      closing.push_back(i);
    }
  }
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(closing, (std::vector<int>{100, 200}));
  EXPECT_NEAR(out[0].stamp, stampOf(50), 1e-6);
  EXPECT_NEAR(out[1].stamp, stampOf(150), 1e-6);
  EXPECT_NEAR(out[1].end_stamp, stampOf(200), 1e-6);
  EXPECT_EQ(out[0].cloud->size(), 100u);  // clouds 1..100
  EXPECT_EQ(out[1].cloud->size(), 100u);  // clouds 101..200
  EXPECT_NEAR(out[1].T_O_S.translation().x(), 15.0, 1e-6);
}

TEST(SubmapAssembler, DropsDuplicateAndOutOfOrderStamps) {
  SubmapAssemblerParams p = unfiltered(1.0);
  SubmapAssembler a(p);
  EXPECT_EQ(a.addOdometry(1.0, Pose::Identity()), Status::kOk);
  EXPECT_EQ(a.addOdometry(1.0, Pose::Identity()), Status::kDuplicateStamp);
  EXPECT_EQ(a.addOdometry(0.9, Pose::Identity()), Status::kOutOfOrder);
  addTrack(&a, 1.1, 1.6, 0.0);
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addCloud(1.05, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addCloud(1.05, cloudOf({{1, 1, 1}}), &done), Status::kDuplicateStamp);
  EXPECT_EQ(a.addCloud(1.00, cloudOf({{1, 1, 1}}), &done), Status::kOutOfOrder);
  EXPECT_EQ(a.addCloud(1.08, Cloud(), &done), Status::kEmptyCloud);
  const auto s = a.flush();
  ASSERT_TRUE(s);
  EXPECT_EQ(s->cloud->size(), 1u);
}

TEST(SubmapAssembler, NeedsOdometryAtTheAnchorOnly) {
  SubmapAssemblerParams p = unfiltered(1.0);
  SubmapAssembler a(p);
  std::optional<AssembledSubmap> done;
  // Clouds are in O already: one that arrives before any odometry is kept. Window (0.9, 1.9].
  EXPECT_EQ(a.addCloud(1.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addOdometry(1.35, makePose(0, 0, 0, 0, 0, 0)), Status::kOk);
  EXPECT_EQ(a.addOdometry(1.45, makePose(1, 0, 0, 0, 0, 0)), Status::kOk);
  EXPECT_EQ(a.addCloud(1.9, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  ASSERT_TRUE(done);
  EXPECT_DOUBLE_EQ(done->stamp, 1.4);
  EXPECT_NEAR(done->T_O_S.translation().x(), 0.5, 1e-9);
  EXPECT_EQ(done->cloud->size(), 2u);
  // The front end stopped at 1.45: window (1.9, 2.9] has no pose at its centre and is dropped.
  EXPECT_EQ(a.addCloud(2.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addCloud(2.9, cloudOf({{1, 1, 1}}), &done), Status::kNoAnchorPose);
  EXPECT_FALSE(done);
  EXPECT_EQ(a.addCloud(3.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_FALSE(a.flush());
}

TEST(SubmapAssembler, OdometryGapDiscardsTheOpenSubmap) {
  SubmapAssemblerParams p = unfiltered(1.0);
  SubmapAssembler a(p);
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addOdometry(1.0, Pose::Identity()), Status::kOk);
  EXPECT_EQ(a.addCloud(1.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addOdometry(5.0, Pose::Identity()), Status::kOdometryGap);
  EXPECT_FALSE(a.flush());
  // A new stream: windows restart at its first cloud, (4.9, 5.9], centre 5.4.
  addTrack(&a, 5.05, 5.5, 0.0);
  EXPECT_EQ(a.addCloud(5.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  const auto s = a.flush();
  ASSERT_TRUE(s);
  EXPECT_DOUBLE_EQ(s->stamp, 5.4);
}

TEST(SubmapAssembler, CapsPointsAndSkipsNaN) {
  SubmapAssemblerParams p = unfiltered(1.0);
  p.max_submap_points = 2;
  SubmapAssembler a(p);
  std::optional<AssembledSubmap> done;
  addTrack(&a, 0.9, 1.5, 0.0);
  Cloud c = cloudOf({{1, 0, 0}, {NAN, 0, 0}, {2, 0, 0}, {3, 0, 0}});
  EXPECT_EQ(a.addCloud(1.0, c, &done), Status::kTruncated);
  const auto s = a.flush();
  ASSERT_TRUE(s);
  ASSERT_EQ(s->cloud->size(), 2u);
  // makePose faces +y: a point 2 m along O's x lies 2 m to the right (-y) of S.
  EXPECT_NEAR((*s->cloud)[1].y, -(2.0 - s->T_O_S.translation().x()), 1e-5);
}

// The default voxel filter: the mean of the points of each voxel of S (on the grid floor(p /
// voxel_m), as dtif simulate downsamples the dataset's submaps), in voxel key order; one voxel per
// point when they are apart.
TEST(SubmapAssembler, VoxelFilterAveragesEachVoxelOfS) {
  SubmapAssemblerParams p;
  p.window_s = 1.0;
  ASSERT_DOUBLE_EQ(p.voxel_m, 0.05);
  SubmapAssembler a(p);
  std::optional<AssembledSubmap> done;
  addTrack(&a, 0.9, 2.0, 0.0);  // anchor at 1.4: sensor at O (0.5, 0, 0) facing +y
  // S = O shifted by -0.5 in x and turned by -90 deg: O (x, y) -> S (y, 0.5 - x).
  // Two clouds of the window hit S voxel (20, 20, 20) = [1.0, 1.05)^3 three times, two clouds
  // voxel (-41, 0, 0) twice; the last point is alone.
  EXPECT_EQ(a.addCloud(1.0, cloudOf({{-0.51f, 1.01f, 1.01f}, {0.49f, -2.01f, 0.02f}}), &done),
            Status::kOk);
  EXPECT_EQ(a.addCloud(1.5, cloudOf({{-0.53f, 1.03f, 1.04f}, {-0.52f, 1.02f, 1.03f}}), &done),
            Status::kOk);
  EXPECT_EQ(a.addCloud(1.9, cloudOf({{0.48f, -2.04f, 0.01f}, {0.49f, 0.0f, 0.0f}}), &done),
            Status::kOk);
  ASSERT_TRUE(done);
  ASSERT_EQ(done->cloud->size(), 3u);
  // Key order: x index first (-41 < 0 < 20).
  EXPECT_NEAR((*done->cloud)[0].x, -2.025, 1e-5);  // O y -2.01, -2.04
  EXPECT_NEAR((*done->cloud)[0].y, 0.015, 1e-5);   // 0.5 - O x 0.49, 0.48
  EXPECT_NEAR((*done->cloud)[0].z, 0.015, 1e-5);
  EXPECT_NEAR((*done->cloud)[1].x, 0.0, 1e-5);
  EXPECT_NEAR((*done->cloud)[1].y, 0.01, 1e-5);
  EXPECT_NEAR((*done->cloud)[2].x, 1.02, 1e-5);  // O y 1.01, 1.03, 1.02
  EXPECT_NEAR((*done->cloud)[2].y, 1.02, 1e-5);  // 0.5 - O x -0.51, -0.53, -0.52
  EXPECT_NEAR((*done->cloud)[2].z, (1.01 + 1.04 + 1.03) / 3, 1e-5);
  const Cloud filtered = *done->cloud;

  // voxel_m 0 keeps all six points; a negative or NaN voxel is rejected.
  p.voxel_m = 0.0;
  EXPECT_EQ(p.validate(), "");
  SubmapAssembler b(p);
  addTrack(&b, 0.9, 2.0, 0.0);
  b.addCloud(1.0, cloudOf({{-0.51f, 1.01f, 1.01f}, {0.49f, -2.01f, 0.02f}}), &done);
  b.addCloud(1.5, cloudOf({{-0.53f, 1.03f, 1.04f}, {-0.52f, 1.02f, 1.03f}}), &done);
  b.addCloud(1.9, cloudOf({{0.48f, -2.04f, 0.01f}, {0.49f, 0.0f, 0.0f}}), &done);
  ASSERT_TRUE(done);
  EXPECT_EQ(done->cloud->size(), 6u);
  // Filtering afterwards (as TrunkExtractionNodelet does, on its worker) gives the same points.
  VoxelCentroidSorter voxels(0.05);
  voxelFilterSubmap(&voxels, done->cloud.get());
  ASSERT_EQ(done->cloud->size(), filtered.size());
  for (size_t i = 0; i < filtered.size(); ++i) {
    EXPECT_EQ((*done->cloud)[i].getVector3fMap(), filtered[i].getVector3fMap()) << i;
  }
  p.voxel_m = -0.05;
  EXPECT_NE(p.validate(), "");
  p.voxel_m = NAN;
  EXPECT_NE(p.validate(), "");
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif

namespace dtif {
namespace ros_glue {
namespace {

// Feeds odometry and one cloud every 0.1 s over [t0, t1); returns the submaps finished.
std::vector<AssembledSubmap> feed(SubmapAssembler* a, double t0, double t1,
                                  std::vector<Status>* statuses) {
  std::vector<AssembledSubmap> out;
  for (double t = t0; t < t1 - 1e-9; t += 0.1) {
    statuses->push_back(a->addOdometry(t, test::makePose(t - t0, 0, 0, 0, 0, 0)));
    std::optional<AssembledSubmap> done;
    statuses->push_back(a->addCloud(t, cloudOf({{1, 1, 1}}), &done));
    if (done) out.push_back(std::move(*done));
  }
  return out;
}

size_t countOf(const std::vector<Status>& s, Status x) {
  return static_cast<size_t>(std::count(s.begin(), s.end(), x));
}

// Issue #17: one future-stamped cloud and odometry message made every later message "out of
// order": 0 of 15 descriptors afterwards. Now the stream resynchronises (kClockJump) and the
// robot's submaps keep coming.
TEST(SubmapAssembler, FutureStampDoesNotSilenceTheRobot) {
  SubmapAssembler a{unfiltered(2.0)};
  std::vector<Status> st;
  const size_t before = feed(&a, 100.05, 104.05, &st).size();
  EXPECT_EQ(before, 2u);
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addOdometry(5e8, test::makePose(0, 0, 0, 0, 0, 0)), Status::kOk);
  a.addCloud(5e8, cloudOf({{1, 1, 1}}), &done);  // may finish the open window
  st.clear();
  const auto after = feed(&a, 104.05, 120.05, &st);
  EXPECT_EQ(countOf(st, Status::kClockJump), 2u);  // the odometry's and the clouds' stream
  EXPECT_EQ(countOf(st, Status::kOutOfOrder), 0u);
  EXPECT_GE(after.size(), 7u);  // 16 s of 2 s windows, the first one after the jump partial
}

// A bag replayed a second time: its stamps jump back by the bag's length.
TEST(SubmapAssembler, BagReplayedTwiceIsAssembledTwice) {
  SubmapAssembler a{unfiltered(2.0)};
  std::vector<Status> st;
  const auto first = feed(&a, 100.05, 110.05, &st);
  const auto second = feed(&a, 100.05, 110.05, &st);
  EXPECT_EQ(first.size(), 5u);
  EXPECT_EQ(second.size(), 5u);
  EXPECT_EQ(countOf(st, Status::kClockJump), 2u);
  EXPECT_GT(second.front().id, first.back().id);  // ids stay unique
}

TEST(SubmapAssembler, SmallBackwardStepsAreStillOutOfOrder) {
  SubmapAssembler a{unfiltered(2.0)};
  std::optional<AssembledSubmap> done;
  EXPECT_EQ(a.addCloud(10.0, cloudOf({{1, 1, 1}}), &done), Status::kOk);
  EXPECT_EQ(a.addCloud(9.0, cloudOf({{1, 1, 1}}), &done), Status::kOutOfOrder);
  EXPECT_EQ(a.addCloud(NAN, cloudOf({{1, 1, 1}}), &done), Status::kOutOfOrder);
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
