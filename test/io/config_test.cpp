#include "dtif/io/config.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "dtif_test/test_config.h"
#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

std::string writeTemp(const std::string& name, const std::string& text) {
  const fs::path p = fs::temp_directory_path() / ("dtif_config_test_" + name + ".yaml");
  std::ofstream(p) << text;
  return p.string();
}

/// Expects loading to throw a ParamError whose message contains every fragment.
void expectParamError(const std::string& path, std::initializer_list<const char*> fragments) {
  DtifParams p;
  try {
    loadParamsYaml(path, &p);
    FAIL() << "expected a ParamError for " << path;
  } catch (const ParamError& e) {
    for (const char* f : fragments) {
      EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << e.what();
    }
  }
}

TEST(Config, DefaultsValidate) { EXPECT_EQ(DtifParams().validate(), ""); }

TEST(Config, OverridesOnlyGivenKeys) {
  const std::string f = writeTemp("override",
                                  "descriptor:\n  min_trunks: 7\n"
                                  "pose:\n  unit_weights: true\n  beta_xy_m: 0.5\n");
  DtifParams p;
  loadParamsYaml(f, &p);
  EXPECT_EQ(p.descriptor.min_trunks, 7);
  EXPECT_TRUE(p.loop.pose.unit_weights);
  EXPECT_DOUBLE_EQ(p.loop.pose.beta_xy_m, 0.5);
  EXPECT_EQ(p.descriptor.edge_hist_bins, DescriptorParams().edge_hist_bins);
  EXPECT_DOUBLE_EQ(p.loop.pose.beta_z_m, PoseEstimatorParams().beta_z_m);
}

TEST(Config, UnknownKeysAndSectionsAreErrors) {
  expectParamError(writeTemp("unknown_key", "matcher:\n  edge_rel_tolerance: 0.1\n"),
                   {"unknown parameter 'edge_rel_tolerance'", "matcher", "unknown_key"});
  expectParamError(writeTemp("unknown_section", "matching:\n  edge_rel_tol: 0.1\n"),
                   {"unknown section 'matching'"});
}

TEST(Config, WrongTypesAndInvalidValuesAreErrors) {
  expectParamError(writeTemp("type", "descriptor:\n  min_trunks: many\n"),
                   {"descriptor.min_trunks", "integer"});
  expectParamError(writeTemp("fraction", "descriptor:\n  min_trunks: 2.5\n"),
                   {"descriptor.min_trunks"});
  expectParamError(writeTemp("nested", "pose:\n  beta_z_m: [1, 2]\n"), {"pose.beta_z_m"});
  expectParamError(writeTemp("malformed", "pose: {beta_z_m: 1\n"), {"malformed YAML"});
  expectParamError(writeTemp("negative", "pose:\n  beta_xy_m: -1\n"), {"invalid", "beta_xy_m"});
  expectParamError("/nonexistent/dtif.yaml", {"/nonexistent/dtif.yaml", "cannot open"});
}

// Issue #17: ground_window_m: 1e9 hung and ground_cell_m: 0.01 was 1000 times slower; a folder
// given as the file read "basic_filebuf::underflow error reading the file: Is a directory".
TEST(Config, ValuesBeyondTheBoundsAndFoldersAreRefusedByName) {
  expectParamError(writeTemp("window", "trunk_extraction:\n  ground_window_m: 1e9\n"),
                   {"ground_window_m", "config_test_window"});
  expectParamError(writeTemp("cell", "trunk_extraction:\n  ground_cell_m: 0.01\n"),
                   {"ground_cell_m"});
  expectParamError(writeTemp("bins", "descriptor:\n  edge_hist_bins: 300\n"), {"edge_hist_bins"});
  // fuzz_config: an integer key of 2e34 was cast to int (undefined behaviour).
  expectParamError(writeTemp("huge_int", "descriptor:\n  min_trunks: 2e34\n"),
                   {"descriptor.min_trunks", "integer"});
  const fs::path folder = fs::temp_directory_path() / "dtif_config_test_folder.yaml";
  fs::create_directories(folder);
  expectParamError(folder.string(), {folder.string().c_str(), "is a directory"});
}

TEST(Config, FailedLoadLeavesParametersUnchanged) {
  DtifParams p;
  p.descriptor.min_trunks = 9;
  EXPECT_THROW(
      loadParamsYaml(writeTemp("partial", "descriptor:\n  min_trunks: 5\n  bogus: 1\n"), &p),
      ParamError);
  EXPECT_EQ(p.descriptor.min_trunks, 9);
}

TEST(Config, YamlDumpRoundTrips) {
  DtifParams p;
  p.descriptor.max_edge_m = 12.5;
  p.loop.verification.min_inliers = 11;
  const std::string f = writeTemp("dump", paramsToYaml(p));
  DtifParams q;
  loadParamsYaml(f, &q);
  EXPECT_DOUBLE_EQ(q.descriptor.max_edge_m, 12.5);
  EXPECT_EQ(q.loop.verification.min_inliers, 11);
  EXPECT_EQ(paramsToYaml(p), paramsToYaml(q));
}

// Every shipped component YAML loads, validates and states exactly the compiled-in defaults,
// so the documented values and the code cannot drift apart.
TEST(Config, ShippedYamlsLoadAndMatchDefaults) {
  int files = 0;
  for (const auto& entry : fs::directory_iterator(DTIF_CONFIG_DIR)) {
    if (entry.path().extension() != ".yaml") continue;
    const std::string name = entry.path().filename().string();
    if (name == "ros.yaml") continue;  // node-level settings, checked by the glue tests
    SCOPED_TRACE(name);
    DtifParams p;
    ASSERT_NO_THROW(loadParamsYaml(entry.path().string(), &p));
    EXPECT_EQ(paramsToYaml(p), paramsToYaml(DtifParams()));
    ++files;
  }
  EXPECT_GE(files, 3);
}

// The shipped trunk_extraction.yaml names every extraction parameter, the tuning knobs of
// the ground, circle fit and stem base included, so each is documented where it is set.
TEST(Config, ShippedTrunkExtractionYamlNamesEveryField) {
  std::ifstream in(fs::path(DTIF_CONFIG_DIR) / "trunk_extraction.yaml");
  ASSERT_TRUE(in.good());
  std::stringstream text;
  text << in.rdbuf();
  TrunkExtractorParams p;
  int fields = 0;
  auto named = [&](const char* key, auto&) {
    ++fields;
    EXPECT_NE(text.str().find("\n  " + std::string(key) + ":"), std::string::npos) << key;
  };
  p.visit(named);
  EXPECT_EQ(fields, 60);
}

// rosparam loads the shipped files with YAML 1.1, where a float needs a sign in its exponent:
// `1.0e6` is the string "1.0e6" there (the map-merge nodelet then refused to start), while
// dtif's own loader reads it as a number. Every exponent in a shipped file carries its sign.
TEST(Config, ShippedYamlsHaveNoUnsignedExponents) {
  const std::regex unsigned_exponent(R"(:\s*[-+]?[0-9]*\.?[0-9]+[eE][0-9]+\s*(#.*)?$)");
  int files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(DTIF_CONFIG_DIR)) {
    if (entry.path().extension() != ".yaml") continue;
    ++files;
    std::ifstream in(entry.path());
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
      EXPECT_FALSE(std::regex_search(line, unsigned_exponent))
          << entry.path() << ":" << n << ": " << line;
    }
  }
  EXPECT_GT(files, 3);
}

// The shipped merge.yaml names every parameter of the map merger and the stem inventory.
TEST(Config, ShippedMergeYamlNamesEveryField) {
  std::ifstream in(fs::path(DTIF_CONFIG_DIR) / "merge.yaml");
  ASSERT_TRUE(in.good());
  std::stringstream text;
  text << in.rdbuf();
  int fields = 0;
  auto named = [&](const char* key, auto&) {
    ++fields;
    EXPECT_NE(text.str().find("\n  " + std::string(key) + ":"), std::string::npos) << key;
  };
  MergeParams p;
  p.visit(named);
  p.stems.visit(named);
  EXPECT_EQ(fields, 74);
}

// A merge section reaches the merger's parameters; an invalid value is refused by name.
TEST(Config, MergeSectionsOverrideTheMergerAndValidate) {
  const fs::path dir = test::freshTempDir("dtif_config_merge");
  std::ofstream(dir / "m.yaml") << "merge:\n  pcm: false\n  odom_sigma_xy_per_m: 0.02\n"
                                   "stems:\n  min_observations: 2\n";
  DtifParams p;
  loadParamsYaml((dir / "m.yaml").string(), &p);
  EXPECT_FALSE(p.merge.pcm);
  EXPECT_DOUBLE_EQ(p.merge.odom_sigma_xy_per_m, 0.02);
  EXPECT_EQ(p.merge.stems.min_observations, 2);
  std::ofstream(dir / "bad.yaml") << "merge:\n  pcm_sigmas: -1\n";
  try {
    loadParamsYaml((dir / "bad.yaml").string(), &p);
    FAIL() << "pcm_sigmas -1 was accepted";
  } catch (const ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("pcm_sigmas"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(p.merge.pcm);  // unchanged by the failed load
}

}  // namespace
}  // namespace dtif
