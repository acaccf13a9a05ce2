// The `dtif` tool's command line, run as a process: help and version exit 0, bad usage exits 2
// with one line naming the problem, runtime errors exit 1 naming the file (main.cpp).
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "dtif/io/dataset.h"
#include "dtif_test/test_config.h"
#include "test_utils.h"
#include "tool/tool_run.h"

namespace dtif {
namespace {

using test::runTool;
using test::ToolRun;

size_t lineCount(const std::string& s) {
  size_t n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

std::string packageVersion() {
  std::ifstream f(std::string(DTIF_SOURCE_DIR) + "/package.xml");
  std::stringstream ss;
  ss << f.rdbuf();
  std::smatch m;
  const std::string xml = ss.str();
  return std::regex_search(xml, m, std::regex("<version>([^<]+)</version>")) ? m[1].str() : "";
}

const std::map<std::string, std::vector<std::string>> kCommandOptions{
    {"simulate",
     {"scene", "--out", "--seed", "--png", "--threads", "--bag", "--bag-voxel", "--bag-max-points",
      "--bag-compression", "--quiet"}},
    {"extract", {"cloud", "--out", "--repeat", "--config"}},
    {"register", {"query", "candidate", "--config"}},
    {"eval", {"dataset", "--out", "--config", "--unit-weights", "--quiet", "--method"}},
    {"merge",
     {"dataset", "--out", "--config", "--inject-false-loop", "--no-pcm", "--stem-map",
      "--stem-map-plot", "--quiet"}},
    {"score", {"dataset", "--loops", "--out", "--config", "--eval"}},
    {"bench",
     {"datasets", "--out", "--config", "--back-ends", "--no-front-ends", "--no-pr",
      "--no-scan-context", "--no-scaling", "--scaling-sizes"}},
};

TEST(CliTest, HelpListsEveryCommand) {
  const ToolRun r = runTool("--help");
  EXPECT_EQ(r.status, 0) << r.out;
  for (const auto& [cmd, options] : kCommandOptions) EXPECT_NE(r.out.find(cmd), std::string::npos);
  EXPECT_NE(r.out.find("--version"), std::string::npos) << r.out;
}

TEST(CliTest, EachCommandsHelpListsItsOptions) {
  for (const auto& [cmd, options] : kCommandOptions) {
    const ToolRun r = runTool(cmd + " --help");
    EXPECT_EQ(r.status, 0) << cmd << ":\n" << r.out;
    EXPECT_NE(r.out.find("dtif " + cmd), std::string::npos) << r.out;
    for (const std::string& o : options) {
      EXPECT_NE(r.out.find(o), std::string::npos) << cmd << " --help lacks " << o << ":\n" << r.out;
    }
  }
  // Units and defaults are in the help.
  const ToolRun sim = runTool("simulate --help");
  EXPECT_NE(sim.out.find("[m]"), std::string::npos) << sim.out;
  EXPECT_NE(sim.out.find("--seed N=1"), std::string::npos) << "--seed's default:\n" << sim.out;
}

TEST(CliTest, VersionIsPackageXmls) {
  const std::string version = packageVersion();
  ASSERT_FALSE(version.empty());
  const ToolRun r = runTool("--version");
  EXPECT_EQ(r.status, 0);
  EXPECT_EQ(r.out, "dtif " + version + "\n");
}

/// Exit 2, one line naming the problem (containing `what`), then the usage hint.
void expectUsageError(const std::string& args, const std::string& what) {
  const ToolRun r = runTool(args);
  EXPECT_EQ(r.status, 2) << args << ":\n" << r.out;
  EXPECT_EQ(lineCount(r.out), 2u) << args << ":\n" << r.out;
  EXPECT_NE(r.out.find(what), std::string::npos) << args << ":\n" << r.out;
  EXPECT_NE(r.out.find("--help"), std::string::npos) << args << ":\n" << r.out;
}

TEST(CliTest, BadUsageExits2NamingTheProblem) {
  expectUsageError("", "A subcommand is required");
  expectUsageError("frobnicate", "unknown command 'frobnicate'");
  expectUsageError("--frobnicate", "unknown option '--frobnicate'");
  expectUsageError("eval ds --out o --frobnicate", "dtif eval: ");
  expectUsageError("eval ds --out o --frobnicate", "--frobnicate");
  expectUsageError("eval ds", "--out is required");
  expectUsageError("eval --out o", "dataset is required");
  expectUsageError("score ds --out o", "--loops is required");
  expectUsageError("register a.csv", "candidate is required");
  expectUsageError("bench --out o", "datasets is required");
  expectUsageError("simulate s.yaml --out o extra", "extra");
}

TEST(CliTest, NumbersAreValidated) {
  const std::string sim = "simulate s.yaml --out o ";
  expectUsageError(sim + "--seed -1", "--seed");
  expectUsageError(sim + "--seed 1.5", "non-negative integer");
  expectUsageError(sim + "--seed 0x10", "non-negative integer");
  expectUsageError(sim + "--seed 99999999999999999999", "non-negative integer");
  expectUsageError(sim + "--threads 0", "--threads");
  expectUsageError(sim + "--threads -2", "--threads");
  expectUsageError(sim + "--bag b.bag --bag-voxel -0.1", "--bag-voxel");
  expectUsageError(sim + "--bag b.bag --bag-voxel 101", "--bag-voxel");
  expectUsageError(sim + "--bag b.bag --bag-voxel x", "--bag-voxel");
  expectUsageError(sim + "--bag-voxel 0.1", "--bag");
  expectUsageError(sim + "--bag b.bag --bag-max-points 10000001", "--bag-max-points");
  expectUsageError(sim + "--bag-max-points 100", "--bag");
  expectUsageError(sim + "--bag b.bag --bag-compression zip", "--bag-compression");
  expectUsageError(sim + "--bag-compression lz4", "--bag");
  expectUsageError(sim + "--bag b.bag --bag-layout flat", "--bag-layout");
  expectUsageError(sim + "--bag-layout fastlio", "--bag");
  expectUsageError("bench d --out o --scaling-sizes 10,x", "--scaling-sizes");
  expectUsageError("bench d --out o --back-ends dtif,nope", "nope");
}

TEST(CliTest, MissingFileExits1NamingIt) {
  const std::string missing = "/nonexistent/dtif_cli_test";
  struct Case {
    std::string args, prefix;
  };
  for (const Case& c :
       {Case{"simulate " + missing + ".yaml --out /nonexistent/o", "dtif simulate: "},
        Case{"extract " + missing + ".pcd", "dtif extract: "},
        Case{"register " + missing + ".csv " + missing + ".pcd", "dtif register: "},
        Case{"eval " + missing + " --out /nonexistent/o", "dtif eval: "},
        Case{"score " + missing + " --loops l.csv --out /nonexistent/o", "dtif score: "}}) {
    const ToolRun r = runTool(c.args);
    EXPECT_EQ(r.status, 1) << c.args << ":\n" << r.out;
    EXPECT_EQ(r.out.rfind(c.prefix, 0), 0u) << c.args << ":\n" << r.out;
    EXPECT_NE(r.out.find(missing), std::string::npos) << c.args << ":\n" << r.out;
    EXPECT_EQ(lineCount(r.out), 1u) << c.args << ":\n" << r.out;
  }
}

std::string readText(const std::filesystem::path& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

/// A dataset of 3 submaps of 3 points each (no trunks): eval runs through in no time.
void writeTinyDataset(const std::filesystem::path& dir) {
  Dataset ds;
  ds.root = dir.string();
  Cloud c;
  c.push_back(pcl::PointXYZ(1.f, 2.f, 3.f));
  c.push_back(pcl::PointXYZ(-1.f, 0.5f, 2.f));
  c.push_back(pcl::PointXYZ(0.f, 0.f, 0.f));
  for (int i = 0; i < 3; ++i) {
    SubmapRecord r;
    r.id = i;
    r.robot = "alpha";
    r.stamp = 10.0 * i;
    r.file = "submaps/" + std::to_string(i) + ".pcd";
    r.T_O_S = Pose::Identity();
    ds.submaps.push_back(r);
    ds.T_W_S[r.id] = r.T_O_S;
  }
  writeDatasetTables(ds);
  for (const auto& r : ds.submaps) writeSubmapCloud(ds, r, c);
}

/// eval's options reach the command: --config files apply in the order given (a later file
/// overrides an earlier one key by key), --unit-weights and --method.
TEST(CliTest, EvalAppliesConfigFilesInOrder) {
  namespace fs = std::filesystem;
  const fs::path dir = test::freshTempDir("dtif_cli_test_eval");
  writeTinyDataset(dir / "dataset");
  std::ofstream(dir / "a.yaml") << "descriptor:\n  min_trunks: 5\n  min_triangles: 3\n";
  std::ofstream(dir / "b.yaml") << "descriptor:\n  min_trunks: 7\n";
  const std::string ds = (dir / "dataset").string();
  const std::string a = (dir / "a.yaml").string(), b = (dir / "b.yaml").string();

  ToolRun r = runTool("eval " + ds + " --out " + (dir / "ab").string() + " --config " + a +
                      " --config " + b + " --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  std::string params = readText(dir / "ab" / "params.yaml");
  EXPECT_TRUE(std::regex_search(params, std::regex("min_trunks: 7\\b"))) << params;
  EXPECT_TRUE(std::regex_search(params, std::regex("min_triangles: 3\\b"))) << params;
  EXPECT_TRUE(std::regex_search(params, std::regex("unit_weights: false"))) << params;
  EXPECT_NE(readText(dir / "ab" / "table.md").find("| dtif |"), std::string::npos);

  r = runTool("eval " + ds + " --config " + b + " --out " + (dir / "ba").string() + " --config " +
              a + " --unit-weights --method 'my method' --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  params = readText(dir / "ba" / "params.yaml");
  EXPECT_TRUE(std::regex_search(params, std::regex("min_trunks: 5\\b"))) << params;
  EXPECT_TRUE(std::regex_search(params, std::regex("unit_weights: true"))) << params;
  EXPECT_NE(readText(dir / "ba" / "table.md").find("| my method |"), std::string::npos);

  // A bad parameter file is a runtime error naming it.
  std::ofstream(dir / "bad.yaml") << "descriptor:\n  no_such_key: 1\n";
  r = runTool("eval " + ds + " --out " + (dir / "bad").string() + " --config " + a + " --config " +
              (dir / "bad.yaml").string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("bad.yaml"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir / "bad")) << "no partial output";
  fs::remove_all(dir);
}

/// bench's options reach the command: --back-ends replaces the default list, the --no-* flags
/// switch their parts off.
TEST(CliTest, BenchRunsTheBackEndsGiven) {
  namespace fs = std::filesystem;
  const fs::path dir = test::freshTempDir("dtif_cli_test_bench");
  writeTinyDataset(dir / "tiny" / "dataset");
  const ToolRun r =
      runTool("bench " + (dir / "tiny" / "dataset").string() + " --out " + (dir / "out").string() +
              " --back-ends svd_ransac,fgr --no-front-ends --no-pr "
              "--no-scan-context --no-scaling");
  ASSERT_EQ(r.status, 0) << r.out;
  const std::string summary = readText(dir / "out" / "summary.csv");
  std::vector<std::string> rows;
  std::stringstream ss(summary);
  for (std::string line; std::getline(ss, line);) {
    if (line.rfind("tiny,", 0) == 0) rows.push_back(line);
  }
  // Each back end: its solver's pose, then with dtif's refinement.
  ASSERT_EQ(rows.size(), 4u) << summary;
  for (size_t i = 0; i < rows.size(); ++i) {
    const std::string prefix = i < 2 ? "tiny,back_end,\"SVD-RANSAC" : "tiny,back_end,\"FGR";
    EXPECT_EQ(rows[i].rfind(prefix, 0), 0u) << summary;
  }
  EXPECT_FALSE(fs::exists(dir / "out" / "scaling.csv"));
  fs::remove_all(dir);
}

/// Lines of a CSV file that start with prefix.
size_t countLines(const std::filesystem::path& path, const std::string& prefix) {
  std::stringstream ss(readText(path));
  size_t n = 0;
  for (std::string line; std::getline(ss, line);) n += line.rfind(prefix, 0) == 0;
  return n;
}

/// bench --speed-only with this build's probe as the "before" build too: both builds measure
/// every submap, the protocol's queries and each database size, and the loops they find are
/// the same; a probe that fails stops the bench with its name.
TEST(CliTest, BenchSpeedMeasuresBothBuilds) {
  namespace fs = std::filesystem;
  const fs::path dir = test::freshTempDir("dtif_cli_test_speed");
  ToolRun r = runTool("simulate " + std::string(DTIF_SCENES_DIR) + "/tiny.yaml --out " +
                      (dir / "ds").string() + " --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  const std::string probe = (fs::path(DTIF_TOOL).parent_path() / "dtif_query_bench").string();
  r = runTool("bench " + (dir / "ds").string() + " --out " + (dir / "out").string() +
              " --speed-only --speed-sizes 50,100 --before-probe " + probe);
  ASSERT_EQ(r.status, 0) << r.out;
  const size_t submaps = countLines(dir / "ds" / "submaps.csv", "") - 1;
  EXPECT_EQ(countLines(dir / "out" / "speed_describe.csv", "after,"), submaps);
  EXPECT_EQ(countLines(dir / "out" / "speed_describe.csv", "before,"), submaps);
  EXPECT_EQ(countLines(dir / "out" / "speed_scale.csv", "after,50,"), 1u);
  EXPECT_EQ(countLines(dir / "out" / "speed_scale.csv", "before,100,"), 1u);
  const std::string md = readText(dir / "out" / "speed.md");
  EXPECT_NE(md.find("Loops found: identical"), std::string::npos) << md;
  EXPECT_GT(countLines(dir / "out" / "speed_loops_after.txt", "loop "), 0u);
  EXPECT_EQ(readText(dir / "out" / "speed_loops_after.txt"),
            readText(dir / "out" / "speed_loops_before.txt"));

  r = runTool("bench " + (dir / "ds").string() + " --out " + (dir / "bad").string() +
              " --speed-only --speed-sizes 50 --before-probe /bin/false");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("/bin/false"), std::string::npos) << r.out;
  fs::remove_all(dir);
}

/// A tiny survey whose robots' odometry frames are tilted 9 and 13 deg (upstream FAST-LIO2):
/// eval levels each robot's submaps (on by default), reports the levelling error per robot,
/// and scores the loops in the tilted frames: every accepted loop is a true positive.
TEST(CliTest, EvalLevelsATiltedSurvey) {
  namespace fs = std::filesystem;
  const fs::path dir = test::freshTempDir("dtif_cli_test_tilted");
  std::ofstream(dir / "scene.yaml") << readText(std::string(DTIF_SCENES_DIR) + "/tiny.yaml")
                                    << "fastlio: {init_tilt_min_deg: 9, init_tilt_max_deg: 13}\n";
  ToolRun r = runTool("simulate " + (dir / "scene.yaml").string() + " --out " +
                      (dir / "ds").string() + " --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(readText(dir / "ds" / "dataset.yaml").find("odometry_frames:"), std::string::npos);
  r = runTool("eval " + (dir / "ds").string() + " --out " + (dir / "ev").string() + " --quiet");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("levelling per robot"), std::string::npos) << r.out;
  std::stringstream lev(readText(dir / "ev" / "levelling.csv"));
  std::string line;
  std::getline(lev, line);
  int rows = 0;
  double err_sum = 0.0;
  while (std::getline(lev, line)) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
    ASSERT_GE(f.size(), 5u);
    EXPECT_GT(std::stod(f[2]), 8.0) << line;  // the true tilt
    err_sum += std::stod(f[4]);
    ++rows;
  }
  ASSERT_GT(rows, 10);
  // tiny is a sparse scan (30k points/s): ~1 deg per submap, less once several are in.
  EXPECT_LT(err_sum / rows, 1.5);
  const std::string summary = readText(dir / "ev" / "summary.json");
  EXPECT_NE(summary.find("\"false_positives\": 0"), std::string::npos) << summary;
  EXPECT_EQ(summary.find("\"true_positives\": 0"), std::string::npos) << summary;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace dtif
