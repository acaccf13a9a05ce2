// Tests of the forest survey simulator: scenes, scan pattern, occlusion, ground truth vs
// drifting odometry, determinism, dataset output.
#include "dtif/sim/simulator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>

#include "dtif/core/params.h"
#include "dtif/io/dataset.h"
#include "dtif/sim/sim_world.h"
#include "dtif/sim/window_plan.h"
#include "dtif_test/test_config.h"
#include "test_utils.h"

namespace fs = std::filesystem;
using dtif::Pose;
using namespace dtif::sim;

namespace {

constexpr double kDeg = M_PI / 180.0;

fs::path tempDir(const std::string& name) {
  return dtif::test::freshTempDir("dtif_sim_test_" + name);
}

std::string readFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

SceneParams tinyScene() { return loadSceneYaml(std::string(DTIF_SCENES_DIR) + "/tiny.yaml"); }

// The tiny scene at a tenth of its point rate and one robot cut short: fast for repeated runs.
SceneParams liteScene() {
  SceneParams s = tinyScene();
  s.sensor.points_per_s = 8000;
  s.robots[1].waypoints = {{60, 11}, {35, 9}};
  return s;
}

double yawOf(const Eigen::Matrix3d& R) { return std::atan2(R(1, 0), R(0, 0)); }

struct CollectSubmaps : SubmapSink {
  std::mutex mutex;
  std::map<int64_t, Submap> submaps;
  void onSubmap(const Submap& s) override {
    std::lock_guard<std::mutex> lock(mutex);
    submaps[s.id] = s;
  }
};

struct CollectFrames : FrameSink {
  std::vector<Frame> frames;
  void onFrame(const Frame& f) override {
    Frame g = f;
    if (frames.size() > 40) g.points.clear();  // keep memory small
    frames.push_back(g);
  }
};

}  // namespace

TEST(SimulatorScenes, EveryShippedSceneLoadsAndValidates) {
  size_t n = 0;
  for (const auto& e : fs::directory_iterator(DTIF_SCENES_DIR)) {
    if (e.path().extension() != ".yaml") continue;
    SCOPED_TRACE(e.path().string());
    const SceneParams s = loadSceneYaml(e.path().string());
    EXPECT_EQ(s.validate(), "");
    EXPECT_GE(s.robots.size(), 2u);
    ++n;
  }
  EXPECT_GE(n, 6u);
}

TEST(SimulatorScenes, UnknownKeysAndBadValuesAreErrors) {
  const fs::path dir = tempDir("badyaml");
  auto expectError = [&](const std::string& text, const std::string& needle) {
    const fs::path p = dir / "scene.yaml";
    std::ofstream(p) << text;
    try {
      loadSceneYaml(p.string());
      ADD_FAILURE() << "no error for: " << text;
    } catch (const dtif::ParamError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(p.string()), std::string::npos) << e.what();
    }
  };
  const std::string robots = "robots: [{name: a, waypoints: [[1, 1], [5, 5]]}]\n";
  expectError("stems: {densty_per_ha: 100}\n" + robots, "densty_per_ha");
  expectError("sensr: {}\n" + robots, "sensr");
  expectError("stems: {pattern: spiral}\n" + robots, "pattern");
  expectError("sensor: {points_per_s: fast}\n" + robots, "points_per_s");
  expectError("robots: [{name: a, waypoints: [[1, 1], [5, 5]], speed: 3}]\n", "speed");
  expectError("robots: [{name: 'a b', waypoints: [[1, 1], [5, 5]]}]\n", "bad name");
  expectError("submap: {duration_s: 10.05}\n" + robots, "whole number of frames");
  expectError("bag_layout: flat\n" + robots, "bag_layout");
  expectError("bag_layout: [fastlio]\n" + robots, "bag_layout");
}

// bag_layout (dtif simulate --bag's default layout) is read, and written into dataset.yaml only
// when set, so that the datasets of the other scenes stay as they were.
TEST(SimulatorScenes, BagLayoutKey) {
  const fs::path p = tempDir("bag_layout") / "scene.yaml";
  std::ofstream(p) << "bag_layout: fastlio\nrobots: [{name: a, waypoints: [[1, 1], [5, 5]]}]\n";
  const SceneParams s = loadSceneYaml(p.string());
  EXPECT_EQ(s.bag_layout, "fastlio");
  EXPECT_NE(sceneToYaml(s).find("bag_layout: fastlio"), std::string::npos);
  EXPECT_EQ(tinyScene().bag_layout, "namespaced");
  EXPECT_EQ(sceneToYaml(tinyScene()).find("bag_layout"), std::string::npos);
}

namespace {

// A trajectory of `frames` whole frames of 10 samples (plus the closing sample).
Trajectory trajectoryOfFrames(int frames, double start_s) {
  Trajectory tr;
  tr.start_s = start_s;
  tr.T_W_B.assign(static_cast<size_t>(frames) * 10 + 1, Pose::Identity());
  tr.T_O_B = tr.T_W_B;
  return tr;
}

}  // namespace

TEST(SimulatorWindowPlan, WindowsFramesAndSubmapIds) {
  // Frames of 10 samples, windows of 5 frames (5 s). Robot 0: 12 frames (2 windows and a
  // 2-frame tail); robot 1: starts 5 s later, 10 frames (2 windows, no tail); robot 2: 4
  // frames, too short for a submap. Anchors at epoch + start + (w + 0.5) * 5 s: robot 0
  // 102.5 and 107.5, robot 1 107.5 (a tie, broken by the robot index) and 112.5.
  const std::vector<Trajectory> trs = {trajectoryOfFrames(12, 0.0), trajectoryOfFrames(10, 5.0),
                                       trajectoryOfFrames(4, 0.0)};
  const WindowPlan plan = planWindows(trs, 100.0, 5.0, 10, 5);
  EXPECT_EQ(plan.submaps, 4u);
  struct Expected {
    int robot, window, f_begin, f_end;
    int64_t submap_id;
  };
  // Interleaved window by window, robots in order within a window.
  const std::vector<Expected> expected = {{0, 0, 0, 5, 0},  {1, 0, 0, 5, 2},  {2, 0, 0, 4, -1},
                                          {0, 1, 5, 10, 1}, {1, 1, 5, 10, 3}, {0, 2, 10, 12, -1}};
  ASSERT_EQ(plan.tasks.size(), expected.size());
  for (size_t i = 0; i < expected.size(); ++i) {
    SCOPED_TRACE(i);
    EXPECT_EQ(plan.tasks[i].robot, expected[i].robot);
    EXPECT_EQ(plan.tasks[i].window, expected[i].window);
    EXPECT_EQ(plan.tasks[i].f_begin, expected[i].f_begin);
    EXPECT_EQ(plan.tasks[i].f_end, expected[i].f_end);
    EXPECT_EQ(plan.tasks[i].submap_id, expected[i].submap_id);
  }
}

TEST(SimulatorWindowPlan, SubmapIdsMatchTheRun) {
  // The ids a run hands out are the plan's, with the anchor stamps in id order.
  const SceneParams scene = liteScene();
  Simulator sim(scene, 3);
  CollectSubmaps sink;
  sim.run(nullptr, &sink, 2);
  const int spf = static_cast<int>(std::lround(kTrajectoryRateHz / scene.sensor.frame_rate_hz));
  const int fpw =
      static_cast<int>(std::lround(scene.submap.duration_s * scene.sensor.frame_rate_hz));
  const WindowPlan plan =
      planWindows(sim.trajectories(), scene.epoch_s, scene.submap.duration_s, spf, fpw);
  ASSERT_EQ(sink.submaps.size(), plan.submaps);
  for (const WindowTask& t : plan.tasks) {
    if (t.submap_id < 0) continue;
    const Submap& sm = sink.submaps.at(t.submap_id);
    EXPECT_EQ(sm.robot_index, t.robot);
    EXPECT_DOUBLE_EQ(sm.stamp, scene.epoch_s + sim.trajectories()[t.robot].start_s +
                                   (t.window + 0.5) * scene.submap.duration_s);
  }
  double prev = -1.0;
  for (const auto& [id, sm] : sink.submaps) {
    EXPECT_GE(sm.stamp, prev) << id;
    prev = sm.stamp;
  }
}

TEST(SimulatorScan, PointRateAndFieldOfView) {
  SensorParams sp;
  const ScanPattern pattern(sp);
  EXPECT_DOUBLE_EQ(pattern.pointTime(200000), 1.0);  // 200k points per second
  // Elevation bins of 1 deg, azimuth bins of 2 deg: covered after 1 s, not after one frame.
  const int n_el = 59, n_az = 180;
  std::vector<int> first_frame(n_el * n_az, 0), one_second(n_el * n_az, 0);
  double el_min = 1e9, el_max = -1e9;
  for (uint64_t k = 0; k < 200000; ++k) {
    const Eigen::Vector3d d = pattern.direction(k);
    ASSERT_NEAR(d.norm(), 1.0, 1e-9);
    const double el = std::asin(d.z()) / kDeg;
    const double az = std::atan2(d.y(), d.x()) / kDeg + 180.0;
    el_min = std::min(el_min, el);
    el_max = std::max(el_max, el);
    const int bi = std::clamp(static_cast<int>(el + 7.0), 0, n_el - 1);
    const int bj = std::clamp(static_cast<int>(az / 2.0), 0, n_az - 1);
    one_second[bi * n_az + bj]++;
    if (k < 20000) first_frame[bi * n_az + bj]++;
  }
  EXPECT_GE(el_min, -7.0 - 1e-9);
  EXPECT_LE(el_max, 52.0 + 1e-9);
  EXPECT_LT(el_min, -6.8);
  EXPECT_GT(el_max, 51.8);
  const auto covered = [](const std::vector<int>& v) {
    return static_cast<double>(std::count_if(v.begin(), v.end(), [](int c) { return c > 0; })) /
           v.size();
  };
  EXPECT_GT(covered(one_second), 0.97);
  EXPECT_LT(covered(first_frame), covered(one_second) - 0.05);
  // Non-repetitive: the second frame does not retrace the first.
  double same = 0;
  for (uint64_t k = 0; k < 20000; k += 97) {
    same += (pattern.direction(k) - pattern.direction(k + 20000)).norm() < 1e-3;
  }
  EXPECT_LT(same, 5);
}

TEST(SimulatorScan, FramesAtTenHertzWithTheConfiguredRate) {
  SceneParams s = liteScene();
  s.sensor.points_per_s = 20000;
  s.robots.resize(1);
  s.robots[0].waypoints = {{5, 4}, {15, 4}};
  Simulator sim(s, 3);
  CollectFrames frames;
  const SimulationStats st = sim.run(&frames, nullptr, 1);
  ASSERT_GT(frames.frames.size(), 50u);
  EXPECT_EQ(st.rays, st.frames * 2000);  // 20k points/s at 10 Hz
  for (size_t i = 1; i < frames.frames.size(); ++i) {
    EXPECT_NEAR(frames.frames[i].stamp - frames.frames[i - 1].stamp, 0.1, 1e-6);
  }
  // A forest returns a good share of the rays (the sky does not); returns within range limits.
  EXPECT_GT(st.returns, st.rays / 4);
  EXPECT_LT(st.returns, st.rays);
  const Frame& f = frames.frames[10];
  EXPECT_LE(f.points.size(), 2000u);
  EXPECT_EQ(f.points.size(), f.intensity.size());
  for (const auto& p : f.points) {
    const double r = (f.T_O_B.inverse() * p.cast<double>()).norm();
    EXPECT_LE(r, s.sensor.max_range_m + 0.2);
  }
}

TEST(SimulatorWorld, TrunkBehindTrunkGetsNoHits) {
  SceneParams s;
  s.plot.size_x_m = 30;
  s.plot.size_y_m = 30;
  s.terrain.slope_deg = 0;
  s.terrain.hill_amplitude_m = 0;
  s.terrain.roughness_m = 0;
  auto stemAt = [](int64_t id, double x, double y, double r) {
    Stem st;
    st.id = id;
    st.base_xy = Eigen::Vector2d(x, y);
    st.r_bh = r;
    st.height = 15;
    return st;
  };
  const Eigen::Vector3d o(5, 15, 1.5);
  // Near trunk (r 0.3 m at 5 m) hides the far one (r 0.12 m at 12 m) completely.
  const std::vector<Stem> both = {stemAt(0, 10, 15, 0.3), stemAt(1, 17, 15, 0.12)};
  const World occluded(s, both, {}, {});
  const World alone(s, {stemAt(1, 17, 15, 0.12)}, {}, {});
  auto scratch1 = occluded.makeScratch(1);
  auto scratch2 = alone.makeScratch(1);
  int hits_near = 0, hits_far_occluded = 0, hits_far_alone = 0;
  for (int i = -200; i <= 200; ++i) {
    for (int j = -20; j <= 20; ++j) {
      const double az = i * 0.0005, el = j * 0.005;
      const Eigen::Vector3d d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az),
                              std::sin(el));
      const RayHit a = occluded.castRay(o, d, 0.1, 40, &scratch1);
      const RayHit b = alone.castRay(o, d, 0.1, 40, &scratch2);
      hits_near += a.stem_id == 0;
      hits_far_occluded += a.stem_id == 1;
      hits_far_alone += b.stem_id == 1;
      if (a.stem_id == 0) {  // on the near trunk's surface
        EXPECT_NEAR(((o + a.range * d).head<2>() - Eigen::Vector2d(10, 15)).norm(), 0.3, 0.03);
      }
    }
  }
  EXPECT_GT(hits_near, 1000);
  EXPECT_GT(hits_far_alone, 300);
  EXPECT_EQ(hits_far_occluded, 0);
  // Ground is hit below the horizon at the expected range (flat terrain at z = 0).
  const Eigen::Vector3d down = Eigen::Vector3d(1, 1, -0.3).normalized();
  const RayHit g = alone.castRay(o, down, 0.1, 40, &scratch2);
  ASSERT_EQ(g.material, Material::kGround);
  EXPECT_NEAR((o + g.range * down).z(), 0.0, 0.01);
}

TEST(SimulatorOdometry, DriftWithinTheConfiguredRange) {
  const SceneParams s = tinyScene();
  Simulator sim(s, 11);
  for (const Trajectory& tr : sim.trajectories()) {
    SCOPED_TRACE(tr.robot);
    ASSERT_GT(tr.distance.back(), 30.0);
    // The odometry frame starts at the first pose, gravity-aligned: recover T_W_O from it.
    const Pose& A = tr.T_W_B.front();
    Pose T_W_O = Pose::Identity();
    T_W_O.linear() = dtif::rotZ(yawOf(A.linear()));
    T_W_O.translation() = A.translation();
    EXPECT_LT(tr.T_O_B.front().translation().norm(), 1e-9);
    const Pose est = T_W_O * tr.T_O_B.back();  // drifting estimate, seen in W
    const Pose& gt = tr.T_W_B.back();
    const double dist = tr.distance.back();
    const double dz = std::abs(est.translation().z() - gt.translation().z()) / dist;
    EXPECT_GE(dz, s.odometry.trans_drift_min * 0.99);
    EXPECT_LE(dz, s.odometry.trans_drift_max * 1.01);
    double dyaw = std::abs(yawOf(est.linear()) - yawOf(gt.linear()));
    dyaw = std::min(dyaw, 2 * M_PI - dyaw) / kDeg / dist;
    EXPECT_GE(dyaw, s.odometry.yaw_drift_min_deg_per_m * 0.9);
    EXPECT_LE(dyaw, s.odometry.yaw_drift_max_deg_per_m * 1.1);
    const double dxy = (est.translation() - gt.translation()).head<2>().norm() / dist;
    EXPECT_GT(dxy, 0.3 * s.odometry.trans_drift_min);
    EXPECT_LT(dxy, 3.0 * s.odometry.trans_drift_max);
    // Residual roll/pitch error: a few tenths of a degree, never zero everywhere.
    double max_tilt = 0.0;
    for (size_t i = 0; i < tr.T_O_B.size(); i += 50) {
      const Eigen::Matrix3d E = (T_W_O * tr.T_O_B[i]).linear() * tr.T_W_B[i].linear().transpose();
      max_tilt = std::max(max_tilt, std::acos(std::clamp(E(2, 2), -1.0, 1.0)) / kDeg);
    }
    EXPECT_GT(max_tilt, 0.05);
    EXPECT_LT(max_tilt, 2.0);
  }
}

TEST(SimulatorGroundTruth, SubmapPointsLandOnTheTrunksWithTWS) {
  const SceneParams s = liteScene();
  Simulator sim(s, 5);
  CollectSubmaps sink;
  sim.run(nullptr, &sink, 2);
  ASSERT_GE(sink.submaps.size(), 6u);
  const World& w = sim.world();
  for (const auto& [id, sm] : sink.submaps) {
    SCOPED_TRACE(id);
    // S is gravity-aligned up to the odometry's residual tilt.
    const double tilt = std::acos(std::clamp(sm.T_W_S.linear()(2, 2), -1.0, 1.0)) / kDeg;
    EXPECT_LT(tilt, 2.0);
    std::vector<double> residuals, residuals_odom;
    for (const auto& p : sm.points) {
      const Eigen::Vector3d q = sm.T_W_S * p.cast<double>();
      for (const Stem& st : w.stems()) {
        if (st.sapling) continue;
        const double h = q.z() - st.z_base;
        if (h < 0.8 || h > 2.5) continue;
        const Eigen::Vector2d u = q.head<2>() - st.axisAt(h);
        const double n = u.norm();
        if (n > st.r_bh + 0.15) continue;
        residuals.push_back(std::abs(n - st.radiusAtDir(h, u.x() / n, u.y() / n)));
      }
    }
    ASSERT_GT(residuals.size(), 50u);
    std::nth_element(residuals.begin(), residuals.begin() + residuals.size() / 2, residuals.end());
    // Range noise 2 cm, 5 cm voxels, the submap's own drift: well below the trunk radius.
    EXPECT_LT(residuals[residuals.size() / 2], 0.035);
  }
  // The drifting odometry is not the truth: relative poses differ by the accumulated drift,
  // bounded by the configured rates over the distance walked (at most 1.2 m/s).
  const Submap& a = sink.submaps.begin()->second;
  int compared = 0;
  for (const auto& [id, b] : sink.submaps) {
    if (b.robot != a.robot || b.stamp - a.stamp < 30) continue;
    const Pose d_gt = a.T_W_S.inverse() * b.T_W_S;
    const Pose d_odom = a.T_O_S.inverse() * b.T_O_S;
    const double err = (d_gt.translation() - d_odom.translation()).norm();
    const double walked_max = s.motion.speed_max_mps * (b.stamp - a.stamp);
    EXPECT_GT(err, 0.02);
    EXPECT_LT(err, 0.04 * walked_max + 0.2);
    ++compared;
  }
  EXPECT_GT(compared, 0);
}

TEST(SimulatorDeterminism, SameSeedSameBytesAnyThreads) {
  const SceneParams s = liteScene();
  const fs::path a = tempDir("det_a"), b = tempDir("det_b"), c = tempDir("det_c");
  simulateDataset(s, 42, a.string(), nullptr, "", 1);
  simulateDataset(s, 42, b.string(), nullptr, "", 2);
  simulateDataset(s, 43, c.string(), nullptr, "", 2);
  size_t files = 0;
  for (const auto& e : fs::recursive_directory_iterator(a)) {
    if (!e.is_regular_file()) continue;
    const fs::path rel = fs::relative(e.path(), a);
    EXPECT_EQ(readFile(e.path()), readFile(b / rel)) << rel;
    ++files;
  }
  EXPECT_GE(files, 8u);
  EXPECT_NE(readFile(a / "submaps.csv"), readFile(c / "submaps.csv"));
  EXPECT_NE(readFile(a / "stems.csv"), readFile(c / "stems.csv"));
}

// Windows run in parallel, but each robot's frames still arrive in time order, and the
// frames do not depend on the number of threads.
TEST(SimulatorDeterminism, FramesInTimeOrderPerRobotAnyThreads) {
  SceneParams s = liteScene();
  s.sensor.points_per_s = 2000;
  struct Stamps : FrameSink {
    std::map<std::string, std::vector<std::pair<double, size_t>>> per_robot;
    void onFrame(const Frame& f) override {
      size_t h = f.points.size();
      for (const auto& p : f.points) h = h * 31 + std::hash<float>()(p.x() + 2 * p.y() + 3 * p.z());
      per_robot[f.robot].push_back({f.stamp, h});
    }
  };
  Simulator sim(s, 5);
  Stamps one, three;
  sim.run(&one, nullptr, 1);
  sim.run(&three, nullptr, 3);
  ASSERT_EQ(one.per_robot.size(), 2u);
  EXPECT_EQ(one.per_robot, three.per_robot);
  for (const auto& [robot, frames] : three.per_robot) {
    // Several windows, including the frames after the last complete one.
    EXPECT_GT(frames.size(), 2u * static_cast<size_t>(s.submap.duration_s * 10)) << robot;
    for (size_t i = 1; i < frames.size(); ++i) {
      EXPECT_NEAR(frames[i].first - frames[i - 1].first, 0.1, 1e-6) << robot << " frame " << i;
    }
  }
}

// A sink that fails (disk full) in a worker thread: run() throws its error in the caller's
// thread, and stops, instead of terminating the process.
TEST(SimulatorDeterminism, SinkFailureReachesTheCaller) {
  struct Failing : SubmapSink {
    void onSubmap(const Submap&) override { throw std::runtime_error("disk full"); }
  };
  struct Frames : FrameSink {
    void onFrame(const Frame&) override {}
  };
  SceneParams s = liteScene();
  s.sensor.points_per_s = 2000;
  Simulator sim(s, 5);
  Failing failing;
  Frames frames;
  for (int threads : {1, 2, 3}) {
    EXPECT_THROW(sim.run(&frames, &failing, threads), std::runtime_error) << threads;
  }
}

TEST(SimulatorDataset, WrittenEqualsRead) {
  const SceneParams s = liteScene();
  const fs::path dir = tempDir("rw");
  const fs::path png = dir.string() + ".png";
  dtif::test::tempDirs().paths.push_back(png);  // removed at exit with the folders
  Simulator sim(s, 9);
  CollectSubmaps sink;
  sim.run(nullptr, &sink, 1);
  const DatasetRunResult r = simulateDataset(s, 9, dir.string(), nullptr, png.string(), 1);
  EXPECT_GT(fs::file_size(png), 1000u);
  const dtif::Dataset ds = dtif::readDataset(dir.string());
  ASSERT_EQ(ds.submaps.size(), sink.submaps.size());
  ASSERT_EQ(ds.submaps.size(), r.stats.submaps);
  ASSERT_EQ(ds.T_W_S.size(), ds.submaps.size());
  double prev_stamp = -1;
  for (size_t i = 0; i < ds.submaps.size(); ++i) {
    const dtif::SubmapRecord& rec = ds.submaps[i];
    const Submap& sm = sink.submaps.at(rec.id);
    EXPECT_EQ(rec.id, static_cast<int64_t>(i));
    EXPECT_GE(rec.stamp, prev_stamp);  // acquisition order
    prev_stamp = rec.stamp;
    EXPECT_EQ(rec.robot, sm.robot);
    EXPECT_NEAR(rec.stamp, sm.stamp, 1e-6);
    EXPECT_TRUE(rec.T_O_S.isApprox(sm.T_O_S, 1e-6));
    EXPECT_TRUE(ds.T_W_S.at(rec.id).isApprox(sm.T_W_S, 1e-6));
    const auto cloud = dtif::loadSubmapCloud(ds, rec);
    ASSERT_EQ(cloud->size(), sm.points.size());
    for (size_t k = 0; k < cloud->size(); k += 997) {
      EXPECT_NEAR((*cloud)[k].x, sm.points[k].x(), 1e-5);
      EXPECT_NEAR((*cloud)[k].z, sm.points[k].z(), 1e-5);
    }
  }
  size_t trunks = 0;
  for (const Stem& st : sim.world().stems()) trunks += !st.sapling;
  ASSERT_EQ(ds.stems.size(), trunks);
  for (const auto& st : ds.stems) {
    EXPECT_GE(st.dbh, s.stems.dbh_min_m - 1e-9);
    EXPECT_LE(st.dbh, s.stems.dbh_max_m + 1e-9);
    EXPECT_NEAR(st.z_base, sim.world().terrainHeight(st.x, st.y), 0.2);
  }
  EXPECT_TRUE(fs::exists(dir / "dataset.yaml"));
}

TEST(SimulatorDataset, TinySceneHasLoopsAndDisjointPairs) {
  const fs::path dir = tempDir("tiny");
  const DatasetRunResult r = simulateDataset(tinyScene(), 1, dir.string());
  EXPECT_GE(r.stats.submaps, 10u);
  EXPECT_GE(r.loops.inter_robot_loops, 3u);
  EXPECT_GE(r.loops.intra_robot_loops, 3u);
  EXPECT_GE(r.loops.disjoint_pairs, 3u);
  // 30k points/s, 5 cm voxels: a submap holds tens of thousands of points.
  EXPECT_GT(r.stats.mean_submap_points, 20000);
}

TEST(SimulatorStemMap, LoadsACsvStemMap) {
  const fs::path dir = tempDir("stemmap");
  std::ofstream(dir / "plot.csv") << "\"x_m\",\"y_m\",\"dbh_m\",\"species\"\n"
                                  << "974350.5,6581640.0,0.35,PIAB\n"
                                  << "974356.5,6581641.0,0.22,PIAB\n"
                                  << "974353.0,6581648.0,NA,ACPS\n"
                                  << "974360.0,6581652.0,0.41,PIAB\n";
  std::ofstream(dir / "scene.yaml")
      << "stems: {stem_map: plot.csv, lean_max_deg: 0}\n"
      << "plot: {margin_m: 6}\n"
      << "understory: {saplings_per_ha: 0, shrubs_per_ha: 0, logs_per_ha: 0}\n"
      << "robots: [{name: a, waypoints: [[2, 2], [20, 20]]}, {name: b, waypoints: [[20, 2], "
         "[2, 20]]}]\n";
  const SceneParams s = loadSceneYaml((dir / "scene.yaml").string());
  EXPECT_EQ(fs::path(s.stems.stem_map), (dir / "plot.csv").lexically_normal());
  const World w(s, 1);
  ASSERT_EQ(w.stems().size(), 4u);
  EXPECT_NEAR(w.plotSize().x(), 9.5 + 12, 1e-9);
  EXPECT_NEAR(w.plotSize().y(), 12 + 12, 1e-9);
  EXPECT_NEAR(w.stems()[0].axisAt(1.3).x(), 6.0, 1e-6);
  EXPECT_NEAR(w.stems()[0].axisAt(1.3).y(), 6.0, 1e-6);
  EXPECT_NEAR(w.stems()[1].r_bh, 0.11, 1e-12);
  EXPECT_GT(w.stems()[2].r_bh, 0.0);  // NA: drawn from the distribution
  std::ofstream(dir / "plot.csv") << "x_m,y_m,dbh_m\n1,2,0.3\n3,oops,0.2\n";
  try {
    World bad(s, 1);
    ADD_FAILURE() << "bad stem map accepted";
  } catch (const dtif::ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("plot.csv:3"), std::string::npos) << e.what();
  }
}

// Upstream FAST-LIO2: camera_init tilted per robot. S keeps O's tilted z; T_W_S holds it; the
// points still land on the trunks through T_W_S; point_filter_num keeps every Nth return.
TEST(SimulatorFastLio, TiltedOdometryFrameAndPointFilter) {
  SceneParams s = liteScene();
  s.robots[0].tilt_deg = 12.0;
  s.robots[0].tilt_azimuth_deg = 40.0;
  s.fastlio.init_tilt_min_deg = 5.0;  // bravo draws its own
  s.fastlio.init_tilt_max_deg = 15.0;
  Simulator level(liteScene(), 5), tilted(s, 5);
  EXPECT_DOUBLE_EQ(tilted.trajectories()[0].tilt_deg, 12.0);
  const double bravo_tilt = tilted.trajectories()[1].tilt_deg;
  EXPECT_GE(bravo_tilt, 5.0);
  EXPECT_LE(bravo_tilt, 15.0);
  for (const Trajectory& tr : tilted.trajectories()) {
    EXPECT_NEAR(std::acos(tr.up_O.z()) / kDeg, tr.tilt_deg, 1e-9);
  }
  CollectSubmaps a, b;
  level.run(nullptr, &a, 2);
  tilted.run(nullptr, &b, 2);
  ASSERT_EQ(a.submaps.size(), b.submaps.size());
  for (const auto& [id, sm] : b.submaps) {
    SCOPED_TRACE(id);
    const Trajectory& tr = tilted.trajectories()[sm.robot_index];
    // S's up is O's up (S turns about O's z only), up to the odometry's residual tilt.
    const Eigen::Vector3d up_S = sm.T_W_S.linear().transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d up_S_from_O = sm.T_O_S.linear().transpose() * tr.up_O;
    EXPECT_LT(std::acos(std::clamp(up_S.dot(up_S_from_O), -1.0, 1.0)) / kDeg, 1.5);
    EXPECT_NEAR(std::acos(up_S.z()) / kDeg, tr.tilt_deg, 1.5);
    // The same returns in a tilted frame (voxelised along other axes): the same cloud in W.
    const Submap& lv = a.submaps.at(id);
    EXPECT_NEAR(static_cast<double>(sm.points.size()), static_cast<double>(lv.points.size()),
                0.05 * static_cast<double>(lv.points.size()));
    Eigen::Vector3d mean_t = Eigen::Vector3d::Zero(), mean_l = Eigen::Vector3d::Zero();
    for (const auto& p : sm.points) mean_t += sm.T_W_S * p.cast<double>();
    for (const auto& p : lv.points) mean_l += lv.T_W_S * p.cast<double>();
    mean_t /= static_cast<double>(sm.points.size());
    mean_l /= static_cast<double>(lv.points.size());
    EXPECT_LT((mean_t - mean_l).norm(), 0.05);
  }
  // Every third return.
  SceneParams f = liteScene();
  f.fastlio.point_filter_num = 3;
  CollectFrames all, third;
  Simulator(liteScene(), 5).run(&all, nullptr, 1);
  Simulator(f, 5).run(&third, nullptr, 1);
  ASSERT_EQ(all.frames.size(), third.frames.size());
  for (size_t i = 0; i < 40; ++i) {
    EXPECT_EQ(third.frames[i].points.size(), all.frames[i].points.size() / 3);
    if (third.frames[i].points.empty()) continue;
    EXPECT_EQ(third.frames[i].points[0], all.frames[i].points[2]);  // the 3rd, 6th, ...
  }
}

TEST(SimulatorFastLio, LevelScenesDrawNoTiltAndBadValuesAreErrors) {
  const Simulator level(liteScene(), 5);  // named: a temporary's member would dangle in the loop
  for (const Trajectory& tr : level.trajectories()) {
    EXPECT_EQ(tr.tilt_deg, 0.0);
    EXPECT_EQ(tr.up_O, Eigen::Vector3d::UnitZ());
  }
  SceneParams s = liteScene();
  s.fastlio.point_filter_num = 0;
  EXPECT_NE(s.validate().find("point_filter_num"), std::string::npos);
  s = liteScene();
  s.fastlio.init_tilt_min_deg = 10;
  s.fastlio.init_tilt_max_deg = 5;
  EXPECT_NE(s.validate().find("init_tilt"), std::string::npos);
  s = liteScene();
  s.robots[0].tilt_deg = 45;
  EXPECT_NE(s.validate().find("tilt_deg"), std::string::npos);
}

namespace dtif {
namespace {

// Issue #17: scene values that ran out of memory, overran a buffer or gave NaN stamps are
// refused by key.
TEST(SimulatorScenes, ValuesBeyondTheLimitsAreRefusedByKey) {
  const fs::path dir = tempDir("limits");
  auto expectError = [&](const std::string& text, const std::string& needle) {
    const fs::path p = dir / "scene.yaml";
    std::ofstream(p) << text;
    try {
      loadSceneYaml(p.string());
      ADD_FAILURE() << "no error for: " << text;
    } catch (const dtif::ParamError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  const std::string robots = "robots: [{name: a, waypoints: [[1, 1], [5, 5]]}]\n";
  expectError("understory: {saplings_per_ha: 1e9}\n" + robots, "saplings_per_ha");
  expectError("epoch_s: .nan\n" + robots, "epoch_s");
  expectError("epoch_s: 1e300\n" + robots, "epoch_s");
  // fuzz_scene's finding: a map or list as a key threw yaml-cpp's conversion error, uncaught.
  expectError("? [a, b]\n: 1\n" + robots, "key is not a name");
  expectError("plot: {? {x: 1} : 2}\n" + robots, "key is not a name");
  expectError("robots: [{name: a, ? [w] : 1, waypoints: [[1, 1], [5, 5]]}]\n", "key is not a name");
  expectError("robots: [{name: a, waypoints: [[3, 3], [3, 3], [3, 3]]}]\n", "waypoints coincide");
  std::string many = "robots: [{name: a, waypoints: [";
  for (int i = 0; i < 10000; ++i) many += std::string(i ? ", " : "") + "[1, 1], [2, 2]";
  expectError(many + "]}]\n", "waypoints");
  std::string fleet = "robots: [";
  for (int i = 0; i < 10000; ++i) {
    fleet += std::string(i ? ", " : "") + "{name: r" + std::to_string(i) +
             ", waypoints: [[1, 1], [5, 5]]}";
  }
  expectError(fleet + "]\n", "at most 64 robots");
}

}  // namespace
}  // namespace dtif
