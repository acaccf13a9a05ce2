// `dtif merge` as a process on a simulated scene: DATASET.md's merged-map files, the scores
// against ground truth, the false-loop check, and a dataset without ground truth.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "dtif/io/dataset.h"
#include "dtif/io/merge_files.h"
#include "dtif_test/test_config.h"
#include "test_utils.h"
#include "tool/tool_run.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

using test::runTool;
using test::ToolRun;

std::string firstLine(const fs::path& p) {
  std::ifstream f(p);
  std::string line;
  std::getline(f, line);
  return line;
}

/// The tiny scene (seed 1), simulated once. Other seeds: docs/results.md, Merged map.
const fs::path& tinyDataset() {
  static const fs::path dir = [] {
    const fs::path d = test::freshTempDir("dtif_merge_cmd_test") / "dataset";
    const ToolRun r = runTool("simulate " + std::string(DTIF_SCENES_DIR) + "/tiny.yaml --out " +
                              d.string() + " --seed 1 --quiet");
    EXPECT_EQ(r.status, 0) << r.out;
    return d;
  }();
  return dir;
}

TEST(MergeCmd, WritesTheMergedMapAndScoresIt) {
  const fs::path out = tinyDataset().parent_path() / "merge";
  const ToolRun r = runTool("merge " + tinyDataset().string() + " --out " + out.string() +
                            " --inject-false-loop --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  std::printf("%s", r.out.c_str());
  EXPECT_EQ(firstLine(out / "merged_poses.csv"), "id,robot,component,tx,ty,tz,qx,qy,qz,qw");
  EXPECT_EQ(firstLine(out / "merged_stems.csv"), "stem_id,component,x,y,z_base,dbh,observations");
  EXPECT_TRUE(fs::exists(out / "pose_graph.g2o"));
  EXPECT_TRUE(fs::exists(out / "events.txt"));
  const Dataset ds = readDataset(tinyDataset().string());
  const auto poses = readMergedPosesCsv((out / "merged_poses.csv").string());
  ASSERT_EQ(poses.size(), ds.submaps.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(poses[i].id, ds.submaps[i].id);
    EXPECT_EQ(poses[i].robot, ds.submaps[i].robot);
    EXPECT_EQ(poses[i].component, 0);  // both robots close loops with each other
  }
  EXPECT_FALSE(readMergedStemsCsv((out / "merged_stems.csv").string()).empty());

  std::ifstream f(out / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(f);
  EXPECT_EQ(j.at("components").get<int>(), 1);
  EXPECT_GT(j.at("loops_used").get<int>(), 0);
  EXPECT_TRUE(j.contains("loops_rejected"));
  EXPECT_TRUE(j.at("false_loop_injected").get<bool>());
  EXPECT_TRUE(j.at("false_loop_added").get<bool>()) << "the merger never saw it: nothing tested";
  EXPECT_FALSE(j.at("false_loop_used").get<bool>());
  const auto& score = j.at("score");
  const double ate = score.at("component").at("0").at("ate_m").get<double>();
  const double clean =
      j.at("score_without_false_loop").at("component").at("0").at("ate_m").get<double>();
  EXPECT_LE(ate, 0.10);
  EXPECT_LT(ate, score.at("odometry_only_all").at("ate_m").get<double>());
  EXPECT_LT(std::fabs(ate - clean), 0.02);
  const auto& stems = score.at("stems");
  EXPECT_LE(stems.at("mean_pos_err_m").get<double>(), 0.10);
  EXPECT_LE(stems.at("median_dbh_err_m").get<double>(), 0.02);
  EXPECT_LE(stems.at("duplicate_rate").get<double>(), 0.02);
  // The DBH from the pooled slices: most of the inventory refitted (tiny seed 1: 53 of 89).
  const auto& slices = j.at("stem_dbh_from_points");
  EXPECT_GT(slices.at("refitted").get<int>(), j.at("stems").get<int>() / 2);
  EXPECT_NE(r.out.find("stem DBH from the points"), std::string::npos);
  EXPECT_NE(r.out.find("odometry-only ATE"), std::string::npos);
  EXPECT_NE(r.out.find("rejected"), std::string::npos);
}

TEST(MergeCmd, MergesWithoutGroundTruth) {
  const fs::path copy = tinyDataset().parent_path() / "no_gt";
  fs::remove_all(copy);
  fs::copy(tinyDataset(), copy, fs::copy_options::recursive);
  fs::remove(copy / "ground_truth.csv");
  fs::remove(copy / "stems.csv");
  const fs::path out = tinyDataset().parent_path() / "merge_no_gt";
  const ToolRun r = runTool("merge " + copy.string() + " --out " + out.string() + " --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  std::ifstream f(out / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(f);
  EXPECT_TRUE(j.at("score").is_null());
  EXPECT_EQ(readMergedPosesCsv((out / "merged_poses.csv").string()).size(),
            readDataset(copy.string()).submaps.size());
}

std::string fileText(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// A team's own bags have no ground truth, and stock FAST-LIO2 units are tilted: without ground
// truth the merge must still level and accumulate as the scored run does (it once ran a
// front end of its own without either: no loop closed on this dataset, two components).
TEST(MergeCmd, WithoutGroundTruthTiltedUnitsAreLevelledAsWithIt) {
  const fs::path dir = test::freshTempDir("dtif_merge_cmd_tilted");
  std::ofstream(dir / "scene.yaml")
      << fileText(fs::path(DTIF_SCENES_DIR) / "tiny.yaml")
      << "fastlio:\n  init_tilt_min_deg: 5\n  init_tilt_max_deg: 15\n  point_filter_num: 3\n";
  const fs::path gt = dir / "gt";
  ToolRun r = runTool("simulate " + (dir / "scene.yaml").string() + " --out " + gt.string() +
                      " --seed 1 --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  const fs::path no_gt = dir / "no_gt";
  fs::copy(gt, no_gt, fs::copy_options::recursive);
  fs::remove(no_gt / "ground_truth.csv");
  fs::remove(no_gt / "stems.csv");
  for (const fs::path& d : {gt, no_gt}) {
    r = runTool("merge " + d.string() + " --out " + (d.string() + "_merge") + " --quiet");
    ASSERT_EQ(r.status, 0) << r.out;
  }
  const nlohmann::json j = nlohmann::json::parse(fileText(dir / "no_gt_merge" / "summary.json"));
  EXPECT_GT(j.at("loops_accepted").get<int>(), 0) << j.dump();
  EXPECT_EQ(j.at("components").get<int>(), 1) << j.dump();
  EXPECT_EQ(fileText(dir / "no_gt_merge" / "merged_poses.csv"),
            fileText(dir / "gt_merge" / "merged_poses.csv"));
  EXPECT_EQ(fileText(dir / "no_gt_merge" / "merged_stems.csv"),
            fileText(dir / "gt_merge" / "merged_stems.csv"));
}

TEST(MergeCmd, ABadStemMapExits1NamingIt) {
  const fs::path dir = test::freshTempDir("dtif_merge_cmd_bad");
  const fs::path bad = dir / "stems.csv";
  std::ofstream(bad) << "x,y\n1,oops\n";
  const ToolRun r = runTool("merge " + tinyDataset().string() + " --out " + (dir / "o").string() +
                            " --stem-map " + bad.string() + " --quiet");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find(bad.string()), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir / "o" / "merged_poses.csv"));
}

}  // namespace
}  // namespace dtif
