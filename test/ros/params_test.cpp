// Glue tests without a master: strict parameter keys and the shipped node-level YAMLs.
#include "dtif/ros/params.h"

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <functional>
#include <set>
#include <string>

#include "dtif/io/config.h"
#include "dtif/ros/merge_params.h"
#include "dtif/ros/node_params.h"
#include "dtif/ros/submap_assembler.h"
#include "dtif_test/test_config.h"

namespace dtif {
namespace ros_glue {
namespace {

std::set<std::string> extractionKeys() {
  std::set<std::string> k;
  for (const auto& s : declaredKeys<TrunkExtractionNodeParams>("")) k.insert(s);
  for (const auto& s : declaredKeys<SubmapAssemblerParams>("")) k.insert(s);
  for (const auto& s : declaredKeys<TrunkExtractorParams>("trunk_extraction")) k.insert(s);
  for (const auto& s : declaredKeys<DescriptorParams>("descriptor")) k.insert(s);
  for (const auto& s : declaredKeys<LevellingParams>("levelling")) k.insert(s);
  for (const auto& s : declaredKeys<MultiSubmapParams>("multi_submap")) k.insert(s);
  return k;
}

std::set<std::string> loopClosureKeys() {
  std::set<std::string> k;
  for (const auto& s : declaredKeys<LoopClosureNodeParams>("")) k.insert(s);
  for (const auto& s : declaredKeys<MatcherParams>("matcher")) k.insert(s);
  for (const auto& s : declaredKeys<PoseEstimatorParams>("pose")) k.insert(s);
  for (const auto& s : declaredKeys<VerifierParams>("verification")) k.insert(s);
  for (const auto& s : declaredKeys<DatabaseParams>("database")) k.insert(s);
  return k;
}

// What the map merge nodelet reads: its node keys and the core's sections merge and stems.
std::set<std::string> mergeKeys() {
  std::set<std::string> k;
  for (const auto& s : declaredKeys<MapMergeNodeParams>("")) k.insert(s);
  for (const auto& s : declaredKeys<MergeParams>("merge")) k.insert(s);
  for (const auto& s : declaredKeys<StemFusionParams>("stems")) k.insert(s);
  return k;
}

// Flattens a YAML map into `a/b/c` keys (what rosparam load puts on the server).
void flatten(const YAML::Node& n, const std::string& prefix, std::vector<std::string>* out) {
  if (n.IsMap()) {
    for (const auto& kv : n) {
      const std::string key = kv.first.as<std::string>();
      flatten(kv.second, prefix.empty() ? key : prefix + "/" + key, out);
    }
  } else {
    out->push_back(prefix);
  }
}

TEST(StrictParams, DeclaredKeysComeFromVisit) {
  const auto keys = declaredKeys<DatabaseParams>("database");
  ASSERT_EQ(keys.size(), 6u);
  EXPECT_EQ(keys[0], "database/exclude_recent_s");
  EXPECT_EQ(keys[1], "database/max_candidates");
  EXPECT_EQ(keys[2], "database/max_vote_candidates");
  EXPECT_EQ(keys[3], "database/inter_robot_verifications");
  EXPECT_EQ(keys[4], "database/max_lattice_searches");
  EXPECT_EQ(keys[5], "database/decisive_score");
}

TEST(StrictParams, UnknownKeyUnderTheNamespaceIsReported) {
  const std::vector<std::string> server = {
      "/alpha/trunk_extraction/window_s",                       // node-level: known
      "/alpha/trunk_extraction/trunk_extraction/slab_min_h_m",  // core section: known
      "/alpha/trunk_extraction/descriptor/max_edge_m",          // core section: known
      "/alpha/trunk_extraction/descriptor/max_edge",            // misspelled
      "/alpha/trunk_extraction/windows_s",                      // misspelled
      "/alpha/trunk_extraction_other/foo",                      // another node: not ours
      "/beta/trunk_extraction/foo",                             // another robot
      "/use_sim_time"};
  const auto unknown = findUnknownKeys(server, "/alpha/trunk_extraction", extractionKeys());
  ASSERT_EQ(unknown.size(), 2u);
  EXPECT_EQ(unknown[0], "descriptor/max_edge");
  EXPECT_EQ(unknown[1], "windows_s");
  EXPECT_TRUE(findUnknownKeys(server, "/gamma", extractionKeys()).empty());
}

TEST(StrictParams, SectionsOfOneNodeAreUnknownToTheOther) {
  const std::vector<std::string> server = {"/loop_closure/robots", "/loop_closure/matcher/alpha_s",
                                           "/loop_closure/trunk_extraction/slab_min_h_m"};
  const auto unknown = findUnknownKeys(server, "/loop_closure/", loopClosureKeys());
  ASSERT_EQ(unknown.size(), 1u);
  EXPECT_EQ(unknown[0], "trunk_extraction/slab_min_h_m");
}

// Every shipped node-level YAML names only declared keys, with values of the declared types.
TEST(ShippedYaml, NodeYamlsUseOnlyDeclaredKeys) {
  const std::string dir = std::string(DTIF_SOURCE_DIR) + "/config/ros/";
  const std::vector<std::pair<std::string, std::set<std::string>>> files = {
      {"trunk_extraction_node.yaml", extractionKeys()},
      {"loop_closure_node.yaml", loopClosureKeys()}};
  for (const auto& f : files) {
    YAML::Node root;
    ASSERT_NO_THROW(root = YAML::LoadFile(dir + f.first)) << f.first;
    std::vector<std::string> keys;
    flatten(root, "", &keys);
    EXPECT_FALSE(keys.empty()) << f.first;
    for (const auto& k : keys) EXPECT_TRUE(f.second.count(k)) << f.first << ": unknown key " << k;
  }
  // Values parse as the struct's types.
  YAML::Node te = YAML::LoadFile(dir + "trunk_extraction_node.yaml");
  SubmapAssemblerParams a;
  a.window_s = te["window_s"].as<double>();
  a.cloud_period_s = te["cloud_period_s"].as<double>();
  a.max_odom_gap_s = te["max_odom_gap_s"].as<double>();
  a.max_odom_age_s = te["max_odom_age_s"].as<double>();
  a.max_submap_points = te["max_submap_points"].as<int>();
  EXPECT_EQ(a.validate(), "");
  EXPECT_EQ(te["input"].as<std::string>(), "odometry");
  YAML::Node lc = YAML::LoadFile(dir + "loop_closure_node.yaml");
  EXPECT_GE(lc["robots"].as<std::vector<std::string>>().size(), 1u);
  EXPECT_GT(lc["tf_rate_hz"].as<double>(), 0.0);
}

// The core's component YAMLs, loaded by the launch files into the nodelets' namespaces, hold only
// keys those nodelets read (else the strict check would stop them at startup).
TEST(ShippedYaml, ComponentYamlsFitTheNodeletsThatLoadThem) {
  const std::string dir = std::string(DTIF_SOURCE_DIR) + "/config/";
  const std::vector<std::pair<std::string, std::set<std::string>>> files = {
      {"trunk_extraction.yaml", extractionKeys()},
      {"descriptor.yaml", extractionKeys()},
      {"loop_closure.yaml", loopClosureKeys()},
      {"merge.yaml", mergeKeys()}};
  for (const auto& f : files) {
    YAML::Node root;
    ASSERT_NO_THROW(root = YAML::LoadFile(dir + f.first)) << f.first;
    std::vector<std::string> keys;
    flatten(root, "", &keys);
    EXPECT_FALSE(keys.empty()) << f.first;
    for (const auto& k : keys) EXPECT_TRUE(f.second.count(k)) << f.first << ": unknown key " << k;
  }
}

// The map merge nodelet's YAML: only its declared keys, and its defaults as the struct's.
TEST(ShippedYaml, MapMergeYamlShowsTheStructsDefaults) {
  const std::string path = std::string(DTIF_SOURCE_DIR) + "/config/ros/map_merge_node.yaml";
  YAML::Node root;
  ASSERT_NO_THROW(root = YAML::LoadFile(path));
  std::vector<std::string> keys;
  flatten(root, "", &keys);
  const std::vector<std::string> declared = declaredKeys<MapMergeNodeParams>("");
  const std::set<std::string> known(declared.begin(), declared.end());
  for (const auto& k : keys) EXPECT_TRUE(known.count(k)) << "unknown key " << k;
  EXPECT_EQ(keys.size(), known.size()) << "a key is not documented in the YAML";
  const MapMergeNodeParams d;
  EXPECT_EQ(root["descriptor_topic"].as<std::string>(), d.descriptor_topic);
  EXPECT_EQ(root["cloud_topic"].as<std::string>(), d.cloud_topic);
  EXPECT_EQ(root["loop_topic"].as<std::string>(), d.loop_topic);
  EXPECT_EQ(root["map_frame"].as<std::string>(), d.map_frame);
  EXPECT_EQ(root["database_file"].as<std::string>(), d.database_file);
  EXPECT_EQ(root["stem_map_file"].as<std::string>(), d.stem_map_file);
  EXPECT_EQ(root["stem_map_plot"].as<std::string>(), d.stem_map_plot);
  EXPECT_EQ(root["solve_period_s"].as<double>(), d.solve_period_s);
  EXPECT_EQ(root["tf_rate_hz"].as<double>(), d.tf_rate_hz);
  EXPECT_EQ(root["cloud_voxel_m"].as<double>(), d.cloud_voxel_m);
  EXPECT_EQ(root["queue_size"].as<int>(), d.queue_size);
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
