// The bag path against the dataset, without a master: a simulated survey's frames, reduced as
// `dtif simulate --bag` writes cloud_registered, fed through a SubmapAssembler per robot (what
// TrunkExtractionNodelet does with the bag), give the dataset's submaps of the same survey.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <map>
#include <mutex>

#include "dtif/bag/sim_bag.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/ros/submap_assembler.h"
#include "dtif/sim/simulator.h"
#include "dtif_test/test_config.h"

namespace dtif {
namespace ros_glue {
namespace {

struct SubmapPair {
  std::vector<Eigen::Vector3f> dataset;  ///< the dataset's submap (S)
  Pose dataset_T_O_S = Pose::Identity();
  std::optional<AssembledSubmap> assembled;
};

// Frames -> cloud_registered -> assembler (per robot); dataset submaps kept beside them, keyed by
// (robot, stamp in ms).
class BagPathSink : public sim::FrameSink, public sim::SubmapSink {
 public:
  BagPathSink(const sim::BagParams& bag, const SubmapAssemblerParams& assembler)
      : bag_(bag), assembler_params_(assembler) {}

  void onFrame(const sim::Frame& f) override {
    auto it = assemblers_.try_emplace(f.robot, assembler_params_).first;
    SubmapAssembler& a = it->second;
    ASSERT_EQ(a.addOdometry(f.stamp, f.T_O_B), SubmapAssembler::Status::kOk);
    std::vector<Eigen::Vector3f> points;
    std::vector<float> intensity;
    sim::cloudRegistered(f, bag_, &points, &intensity);
    Cloud cloud;
    for (const auto& p : points) cloud.push_back({p.x(), p.y(), p.z()});
    std::optional<AssembledSubmap> done;
    a.addCloud(f.stamp, cloud, &done);
    if (done) {
      std::lock_guard<std::mutex> lock(mutex_);
      pairs_[{f.robot, std::llround(done->stamp * 1e3)}].assembled = std::move(done);
    }
  }

  void onSubmap(const sim::Submap& s) override {
    std::lock_guard<std::mutex> lock(mutex_);
    SubmapPair& p = pairs_[{s.robot, std::llround(s.stamp * 1e3)}];
    p.dataset = s.points;
    p.dataset_T_O_S = s.T_O_S;
  }

  const std::map<std::pair<std::string, long long>, SubmapPair>& pairs() const { return pairs_; }

 private:
  sim::BagParams bag_;
  SubmapAssemblerParams assembler_params_;
  std::map<std::string, SubmapAssembler> assemblers_;
  std::mutex mutex_;
  std::map<std::pair<std::string, long long>, SubmapPair> pairs_;
};

Cloud toCloud(const std::vector<Eigen::Vector3f>& pts) {
  Cloud c;
  for (const auto& p : pts) c.push_back({p.x(), p.y(), p.z()});
  return c;
}

// Trunks of `a` with a trunk of `b` within tol_m horizontally.
size_t matchedTrunks(const Trunks& a, const Trunks& b, double tol_m) {
  size_t n = 0;
  for (const TrunkLandmark& t : a) {
    for (const TrunkLandmark& u : b) {
      if (std::hypot(t.x - u.x, t.y - u.y) <= tol_m) {
        ++n;
        break;
      }
    }
  }
  return n;
}

struct Comparison {
  size_t submaps = 0, assembled = 0;
  size_t dataset_points = 0, assembled_points = 0;
  size_t dataset_trunks = 0, assembled_trunks = 0, matched = 0;  ///< matched within 0.05 m
  double max_anchor_error_m = 0.0;
  double max_point_count_error = 0.0;  ///< relative, per submap
};

Comparison compare(const sim::SceneParams& scene, const sim::BagParams& bag,
                   const SubmapAssemblerParams& assembler, bool print = false) {
  sim::Simulator simulator(scene, 1);
  BagPathSink sink(bag, assembler);
  simulator.run(&sink, &sink, 2);
  const TrunkExtractorParams extraction;
  Comparison c;
  for (const auto& [key, p] : sink.pairs()) {
    if (p.dataset.empty()) continue;  // the assembler also closes the partial last window
    ++c.submaps;
    if (!p.assembled) continue;
    ++c.assembled;
    const Trunks td = extractTrunks(toCloud(p.dataset), extraction).trunks;
    const Trunks ta = extractTrunks(*p.assembled->cloud, extraction).trunks;
    c.dataset_points += p.dataset.size();
    c.assembled_points += p.assembled->cloud->size();
    c.dataset_trunks += td.size();
    c.assembled_trunks += ta.size();
    const size_t m = matchedTrunks(td, ta, 0.05);
    c.matched += m;
    c.max_anchor_error_m =
        std::max(c.max_anchor_error_m,
                 (p.assembled->T_O_S.translation() - p.dataset_T_O_S.translation()).norm());
    const double dn = static_cast<double>(p.dataset.size());
    c.max_point_count_error =
        std::max(c.max_point_count_error,
                 std::abs(static_cast<double>(p.assembled->cloud->size()) - dn) / dn);
    if (print) {
      std::cout << key.first << " " << key.second << ": points " << p.dataset.size() << " / "
                << p.assembled->cloud->size() << ", trunks " << td.size() << " / " << ta.size()
                << ", matched " << m << "\n";
    }
  }
  return c;
}

sim::SceneParams scene(const char* name) {
  return sim::loadSceneYaml(std::string(DTIF_SCENES_DIR) + "/" + name + ".yaml");
}

// The default bag (every return) through the default assembler (the dataset's 0.05 m centroid
// voxels in S): the dataset's submaps, up to float rounding at voxel borders (the bag keeps points
// in O as float32, the simulator moves its returns into S in double), so the same trunks.
TEST(BagSubmaps, DefaultBagGivesTheDatasetSubmaps) {
  const Comparison c = compare(scene("tiny"), sim::BagParams{}, SubmapAssemblerParams{}, true);
  ASSERT_EQ(c.submaps, 15u);  // the tiny scene: 7 of alpha, 8 of bravo
  EXPECT_EQ(c.assembled, c.submaps);
  EXPECT_LT(c.max_anchor_error_m, 1e-6);
  EXPECT_LT(c.max_point_count_error, 1e-3);
  ASSERT_GT(c.dataset_trunks, 300u);
  EXPECT_NEAR(static_cast<double>(c.assembled_trunks), static_cast<double>(c.dataset_trunks),
              0.005 * c.dataset_trunks);
  EXPECT_GE(c.matched, c.dataset_trunks - c.dataset_trunks / 200);
}

// Without the assembler's voxel filter the same bag gives other submaps (every return, several
// per voxel), so the test above depends on it.
TEST(BagSubmaps, WithoutTheVoxelFilterSubmapsAreNotTheDatasets) {
  SubmapAssemblerParams unfiltered;
  unfiltered.voxel_m = 0.0;
  const Comparison c = compare(scene("tiny"), sim::BagParams{}, unfiltered);
  EXPECT_EQ(c.assembled, c.submaps);
  EXPECT_GT(c.assembled_points, c.dataset_points + c.dataset_points / 10);
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
