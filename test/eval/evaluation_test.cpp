#include "dtif/eval/evaluation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "dtif/io/dataset.h"
#include "test_utils.h"

namespace dtif {
namespace {

constexpr double kDeg = M_PI / 180.0;

using test::makePose;

TEST(PoseError, ZeroForIdenticalPoses) {
  const Pose T = makePose(1, 2, 3, 0.1, -0.2, 2.5);
  const PoseError e = poseError(T, T);
  EXPECT_NEAR(e.rot_deg, 0.0, 1e-6);
  EXPECT_NEAR(e.trans_m, 0.0, 1e-12);
}

TEST(PoseError, SeparatesEulerComponentsAndTranslation) {
  const Pose gt = makePose(10, -5, 1, 0, 0, 1.0);
  // Residual R_gt^T R_est = Rz(2 deg) Ry(-1 deg) Rx(0.5 deg).
  Pose est = gt;
  est.linear() = gt.rotation() * makePose(0, 0, 0, 0.5 * kDeg, -1.0 * kDeg, 2.0 * kDeg).rotation();
  est.translation() += Eigen::Vector3d(0.3, -0.4, 0.12);
  const PoseError e = poseError(gt, est);
  EXPECT_NEAR(e.yaw_deg, 2.0, 1e-9);
  EXPECT_NEAR(e.pitch_deg, 1.0, 1e-9);
  EXPECT_NEAR(e.roll_deg, 0.5, 1e-9);
  EXPECT_NEAR(e.x_m, 0.3, 1e-12);
  EXPECT_NEAR(e.y_m, 0.4, 1e-12);
  EXPECT_NEAR(e.z_m, 0.12, 1e-12);
  EXPECT_NEAR(e.trans_m, std::sqrt(0.09 + 0.16 + 0.0144), 1e-12);
  // Geodesic angle of the composed residual is not the sum of its Euler angles.
  const Eigen::AngleAxisd aa(gt.rotation().transpose() * est.rotation());
  EXPECT_NEAR(e.rot_deg, aa.angle() / kDeg, 1e-9);
}

TEST(PoseError, HalfTurnDoesNotProduceNan) {
  const PoseError e = poseError(Pose::Identity(), makePose(0, 0, 0, 0, 0, M_PI));
  EXPECT_NEAR(e.rot_deg, 180.0, 1e-6);
  EXPECT_NEAR(e.yaw_deg, 180.0, 1e-6);
}

/// Flat ground at z = g, plus a wall of points from 0 to 5 m over a square of side `side` m.
Cloud squareScene(double side, double g) {
  Cloud c;
  for (double x = 0.05; x < side; x += 0.25) {
    for (double y = 0.05; y < side; y += 0.25) {
      c.push_back(pcl::PointXYZ(x, y, g));
      for (double h = 0.5; h < 5.0; h += 0.5) c.push_back(pcl::PointXYZ(x, y, g + h));
    }
  }
  return c;
}

TEST(Detection, CountsVisibleStemsFoundTrunksAndTheirErrors) {
  // Flat ground at z = -1.7 in S; S is W shifted by (100, 50) and turned by 90 deg.
  Pose T_W_S = Pose::Identity();
  T_W_S.linear() = rotZ(M_PI / 2);
  T_W_S.translation() = Eigen::Vector3d(100.0, 50.0, 0.0);
  Cloud c = squareScene(12.0, -1.7);
  // Stems in S: (2, 1) r 0.2 and (-3, 4) r 0.15 visible; (4, -4) r 0.1 has no points.
  auto ring = [&](double x, double y, double r) {
    for (double h = 0.0; h < 3.0; h += 0.05)
      for (double a = 0.0; a < 2 * M_PI; a += 0.2)
        c.push_back(pcl::PointXYZ(x + r * std::cos(a), y + r * std::sin(a), -1.7 + h));
  };
  ring(2.0, 1.0, 0.2);
  ring(-3.0, 4.0, 0.15);
  std::vector<StemRecord> stems;
  for (const auto& [x, y, r] : std::vector<std::array<double, 3>>{
           {2.0, 1.0, 0.2}, {-3.0, 4.0, 0.15}, {4.0, -4.0, 0.1}, {40.0, 40.0, 0.3}}) {
    const Eigen::Vector3d w = T_W_S * Eigen::Vector3d(x, y, -1.7);
    stems.push_back({static_cast<int64_t>(stems.size()), w.x(), w.y(), w.z(), 2.0 * r});
  }
  Trunks trunks = {{2.05, 1.0, -1.6, 0.22, true},   // on stem 0: dr 0.02, dz 0.1
                   {-3.0, 4.1, -1.0, 0.15, false},  // on stem 1, base not seen
                   {0.0, -5.0, -1.7, 0.2, true}};   // no stem there: a false trunk
  const DetectionRow d = trunkDetection(c, T_W_S, trunks, stems);
  EXPECT_EQ(d.points, c.size());
  EXPECT_EQ(d.visible_stems, 2u);  // the point-less and the far stem are not visible
  EXPECT_EQ(d.trunks, 3u);
  EXPECT_EQ(d.trunks_on_stems, 2u);
  EXPECT_EQ(d.visible_found, 2u);
  EXPECT_EQ(d.bases_seen, 1u);
  EXPECT_NEAR(d.radius_mae_m, 0.01, 1e-9);
  EXPECT_NEAR(d.base_mae_m, 0.1, 1e-9);
}

TEST(Overlap, CountsOnlyTheBandAboveTheLocalGround) {
  // 10 m x 10 m area: ground plus returns up to 5 m; only 0.3-3 m count, so all 100 cells.
  const Cloud c = squareScene(10.0, -1.7);
  const auto cells = overlapCells(c, Pose::Identity());
  EXPECT_EQ(cells.size(), 100u);

  // Points only at the ground or only in the canopy give no cells.
  Cloud canopy;
  for (double x = 0.1; x < 10; x += 0.5) {
    canopy.push_back(pcl::PointXYZ(x, 1, 0));
    canopy.push_back(pcl::PointXYZ(x, 1, 8));
  }
  EXPECT_TRUE(overlapCells(canopy, Pose::Identity()).empty());
}

TEST(Overlap, FollowsGroundTruthPose) {
  const Cloud c = squareScene(10.0, 0.0);
  const auto a = overlapCells(c, Pose::Identity());
  const auto b = overlapCells(c, makePose(5.0, 0.0, 3.0, 0, 0, 0));  // half shifted
  EXPECT_NEAR(cellOverlap(a, b), 0.5, 1e-9);
  const auto far = overlapCells(c, makePose(100.0, 0.0, 0.0, 0, 0, 0));
  EXPECT_EQ(cellOverlap(a, far), 0.0);
  EXPECT_EQ(cellOverlap(a, {}), 0.0);
  EXPECT_NEAR(cellOverlap(a, a), 1.0, 1e-12);
}

TEST(Overlap, IgnoresNonFinitePoints) {
  Cloud c = squareScene(4.0, 0.0);
  const size_t before = overlapCells(c, Pose::Identity()).size();
  c.push_back(pcl::PointXYZ(std::nanf(""), 1.f, 1.f));
  c.push_back(pcl::PointXYZ(1.f, INFINITY, 1.f));
  EXPECT_EQ(overlapCells(c, Pose::Identity()).size(), before);
}

TEST(Overlap, SlopedGroundUsesLocalPercentile) {
  // Ground rising 0.4 m per m (about 22 deg) with a 1.5 m high stem line every 2 m: a global
  // ground level would drop the uphill stems; the local 6 m window keeps every one of them.
  Cloud c;
  for (double x = 0.05; x < 20; x += 0.1) {
    for (double y = 0.05; y < 4; y += 0.1) c.push_back(pcl::PointXYZ(x, y, 0.4 * x));
  }
  for (int k = 0; k < 10; ++k) {
    const double x = 2.0 * k + 0.5;
    for (double h = 0.4; h < 2.0; h += 0.1) c.push_back(pcl::PointXYZ(x, 2.5, 0.4 * x + h));
  }
  const auto cells = overlapCells(c, Pose::Identity());
  for (int k = 0; k < 10; ++k) {
    const int64_t ix = static_cast<int64_t>(std::floor(2.0 * k + 0.5));
    EXPECT_TRUE(cells.count((ix << 32) ^ 2)) << "stem " << k;
  }
}

TEST(SummaryOutput, JsonHasExactKeysAndNullsWhenUndefined) {
  EvalSummary s;
  s.dataset = "d";
  s.submaps = 4;
  const auto path = test::freshTempDir("dtif_eval_summary_test") / "summary.json";
  writeSummaryJson(path.string(), s);
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  const nlohmann::json j = nlohmann::json::parse(ss.str());
  const auto keysOf = [](const nlohmann::json& o) {
    std::set<std::string> k;
    for (const auto& kv : o.items()) k.insert(kv.key());
    return k;
  };
  // Exactly these keys, no more, no fewer (the summary is a contract: docs/dataset.md).
  EXPECT_EQ(keysOf(j), (std::set<std::string>{
                           "dataset", "submaps", "queries_with_loop", "accepted", "true_positives",
                           "false_positives", "precision", "recall", "mean_err_all", "mean_err_tp",
                           "rmse_rot_deg", "rmse_trans_m", "time_ms", "descriptor_bytes_mean"}));
  const std::set<std::string> err_keys{"roll_deg", "pitch_deg", "yaw_deg", "rot_deg",
                                       "x_m",      "y_m",       "z_m",     "trans_m"};
  EXPECT_EQ(keysOf(j.at("mean_err_all")), err_keys);
  EXPECT_EQ(keysOf(j.at("mean_err_tp")), err_keys);
  EXPECT_EQ(keysOf(j.at("time_ms")), (std::set<std::string>{"desc", "loop", "solver", "total"}));
  EXPECT_EQ(j.at("dataset"), "d");
  EXPECT_EQ(j.at("submaps"), 4);
  // No query had a loop and none was accepted: the ratios, RMSEs and mean errors are undefined.
  for (const char* k : {"precision", "recall", "rmse_rot_deg", "rmse_trans_m"}) {
    EXPECT_TRUE(j.at(k).is_null()) << k;
  }
  for (const std::string& k : err_keys) {
    EXPECT_TRUE(j.at("mean_err_all").at(k).is_null()) << k;
    EXPECT_TRUE(j.at("mean_err_tp").at(k).is_null()) << k;
  }
  std::filesystem::remove_all(path.parent_path());
}

// A 10 m x 10 m patch of ground with vegetation 1 m above it, in S.
Cloud patchCloud() {
  Cloud c;
  for (int i = 0; i < 20; ++i) {
    for (int j = 0; j < 20; ++j) {
      c.push_back(pcl::PointXYZ(0.5f * i + 0.25f, 0.5f * j + 0.25f, 0.0f));
      c.push_back(pcl::PointXYZ(0.5f * i + 0.25f, 0.5f * j + 0.25f, 1.0f));
    }
  }
  return c;
}

/// A dataset of trunk-less patches (patchCloud) in `dir`: one submap per (robot, stamp, x of
/// its frame in W), ids in order.
Dataset patchDataset(const std::filesystem::path& dir,
                     const std::vector<std::tuple<std::string, double, double>>& rows) {
  Dataset ds;
  ds.root = dir.string();
  for (int64_t id = 0; id < static_cast<int64_t>(rows.size()); ++id) {
    SubmapRecord r;
    r.id = id;
    std::tie(r.robot, r.stamp, std::ignore) = rows[id];
    r.file = "submaps/" + std::to_string(id) + ".pcd";
    ds.submaps.push_back(r);
    ds.T_W_S[id] = makePose(std::get<2>(rows[id]), 0, 0, 0, 0, 0);
    writeSubmapCloud(ds, r, patchCloud());
  }
  writeDatasetTables(ds);
  return readDataset(ds.root);
}

TEST(LoopLog, RowsRoundTripAndScoreAgainstGroundTruth) {
  // alpha at 100 s and 200 s, 2 m apart (overlap 0.8); bravo at 150 s, 50 m away.
  const auto dir = test::freshTempDir("dtif_loop_log_test");
  const Dataset read =
      patchDataset(dir, {{"alpha", 100.0, 0.0}, {"bravo", 150.0, 50.0}, {"alpha", 200.0, 2.0}});

  std::vector<LoopLogRow> log(4);
  log[0].query_robot = "alpha", log[0].query_id = 0, log[0].query_stamp = 100.0;
  log[1].query_robot = "bravo", log[1].query_id = 0, log[1].query_stamp = 150.0004;
  log[1].accepted = true, log[1].candidate_robot = "alpha", log[1].candidate_stamp = 100.0;
  log[1].T_c_q = makePose(1, 0, 0, 0, 0, 0);  // no overlap: a false positive
  log[2].query_robot = "alpha", log[2].query_id = 1, log[2].query_stamp = 200.0;
  log[2].accepted = true, log[2].candidate_robot = "alpha", log[2].candidate_id = 0;
  log[2].candidate_stamp = 100.0, log[2].T_c_q = makePose(2.1, 0, 0, 0, 0, 0.5 * kDeg);
  log[2].inliers = 12, log[2].score = 0.75, log[2].t_loop_ms = 3.0, log[2].ros_time = 205.25;
  log[2].query_data_end = 205.0, log[2].wall_time = 1.7e9;
  log[3].query_robot = "alpha", log[3].query_id = 2, log[3].query_stamp = 300.0;  // not there
  const auto path = dir / "loops.csv";
  {
    std::ofstream os(path);
    os << loopLogHeader() << "\n";
    for (const auto& r : log) os << formatLoopLogRow(r) << "\n";
  }
  const std::vector<LoopLogRow> back = readLoopLog(path.string());
  ASSERT_EQ(back.size(), 4u);
  EXPECT_EQ(back[2].candidate_robot, "alpha");
  EXPECT_EQ(back[2].inliers, 12);
  EXPECT_DOUBLE_EQ(back[2].ros_time, 205.25);
  EXPECT_DOUBLE_EQ(back[2].wall_time, 1.7e9);
  EXPECT_NEAR(back[2].T_c_q.translation().x(), 2.1, 1e-9);
  EXPECT_FALSE(back[0].accepted);

  std::vector<std::string> unmatched;
  const EvalResult res = scoreLoopLog(read, back, 30.0, EvalParams{}, &unmatched);
  ASSERT_EQ(res.rows.size(), 3u);
  EXPECT_FALSE(res.rows[0].accepted);
  EXPECT_TRUE(res.rows[1].accepted);
  EXPECT_FALSE(res.rows[1].true_positive);
  EXPECT_TRUE(res.rows[2].has_loop);
  EXPECT_TRUE(res.rows[2].true_positive);
  EXPECT_EQ(*res.rows[2].candidate, 0);
  EXPECT_NEAR(res.rows[2].overlap, 0.8, 1e-9);
  EXPECT_NEAR(res.rows[2].err->trans_m, 0.1, 1e-6);
  EXPECT_NEAR(res.rows[2].err->rot_deg, 0.5, 1e-6);
  EXPECT_EQ(res.summary.accepted, 2u);
  EXPECT_EQ(res.summary.true_positives, 1u);
  EXPECT_EQ(res.summary.queries_with_loop, 1u);
  EXPECT_TRUE(res.summary.online);
  EXPECT_DOUBLE_EQ(res.summary.t_loop_ms, 1.0);  // 3 ms over the three queried submaps
  ASSERT_EQ(unmatched.size(), 1u);
  EXPECT_NE(unmatched[0].find("alpha/2"), std::string::npos) << unmatched[0];
  EXPECT_NE(formatTable(res.summary).find("| - |"), std::string::npos);  // no descriptor times
  std::filesystem::remove_all(dir);
}

TEST(Misses, NameTheBestTrueCandidateAndWhyItWasMissed) {
  // alpha at 100 s and 200 s, 2 m apart (overlap 0.8), bravo at 150 s 1 m from the first
  // (overlap 0.9): flat patches without a trunk, so every descriptor is invalid and the one
  // query with true loops misses them.
  const auto dir = test::freshTempDir("dtif_misses_test");
  const Dataset ds =
      patchDataset(dir, {{"alpha", 100.0, 0.0}, {"bravo", 150.0, 1.0}, {"alpha", 200.0, 2.0}});
  const EvalResult res = runEvaluation(ds, DtifParams{}, EvalParams{});
  // bravo/1 overlaps alpha/0 too (other robot: eligible at once); alpha/2 has both.
  ASSERT_EQ(res.misses.size(), 2u);
  EXPECT_EQ(res.misses[0].query, 1);
  EXPECT_EQ(res.misses[0].candidate, 0);
  EXPECT_EQ(res.misses[1].query, 2);
  EXPECT_EQ(res.misses[1].candidate, 1);  // 0.9 overlap beats alpha/0's 0.8
  EXPECT_NEAR(res.misses[1].overlap, 0.9, 1e-9);
  EXPECT_EQ(res.misses[1].rank, 0);  // an invalid query screens nothing
  EXPECT_EQ(res.misses[1].outcome.rfind("invalid descriptor: ", 0), 0u) << res.misses[1].outcome;
  EXPECT_FALSE(res.misses[1].hypothesis_err.has_value());

  const auto path = dir / "misses.csv";
  writeMissesCsv(path.string(), res.misses);
  std::ifstream is(path);
  std::string header, line;
  std::getline(is, header);
  EXPECT_EQ(header.rfind("query,candidate,overlap,rank,hypothesis_inliers,outcome,", 0), 0u);
  int lines = 0;
  while (std::getline(is, line)) {
    ++lines;
    EXPECT_EQ(std::count(line.begin(), line.end(), ','),
              std::count(header.begin(), header.end(), ','))
        << line;
  }
  EXPECT_EQ(lines, 2);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace dtif

namespace dtif {
namespace {

// Issue #17 (UBSan): negative cells were packed by a left shift of a negative value, and 1e30 m
// coordinates were cast to int64 (both undefined). The keys of ordinary cells are unchanged and
// far points give saturated cells instead; scripts/sanitize.sh runs this under UBSan.
TEST(Overlap, NegativeAndHugeCoordinatesAreDefined) {
  const Cloud c = squareScene(10.0, -1.7);
  const auto base = overlapCells(c, makePose(-20.0, -30.0, 0, 0, 0, 0));  // negative cells
  EXPECT_EQ(base.size(), 100u);
  // Cell (-20, -30) has the key the old shift gave it.
  const uint64_t hi = static_cast<uint64_t>(int64_t{-20}) << 32;
  const uint64_t lo = static_cast<uint64_t>(int64_t{-30}) & 0xffffffffu;
  EXPECT_EQ(base.count(static_cast<int64_t>(hi ^ lo)), 1u);
  Cloud far = c;
  for (const float v : {1e30f, -1e30f, 3e38f}) {
    far.push_back(pcl::PointXYZ(v, v, 0.0f));
    far.push_back(pcl::PointXYZ(v, v, 1.0f));
  }
  const auto cells = overlapCells(far, makePose(-20.0, -30.0, 0, 0, 0, 0));
  EXPECT_GE(cells.size(), base.size());
  for (const int64_t k : base) EXPECT_EQ(cells.count(k), 1u);
  std::vector<StemRecord> stems = {{0, 1e30, -1e30, 0.0, 0.3}, {1, 2.0, 3.0, 0.0, 0.3}};
  const DetectionRow d = trunkDetection(far, Pose::Identity(), Trunks(), stems);
  EXPECT_EQ(d.points, far.size());
}

}  // namespace
}  // namespace dtif
