// dtif simulate <scene.yaml> --out <dataset_dir> [--seed N] [--png <file>] [--threads N]
//               [--bag <file.bag>] [--bag-voxel <m>] [--bag-max-points N]
// Simulates a forest survey (config/scenes/*.yaml) and writes it as a dataset (DATASET.md),
// optionally also as a rosbag of the raw frames (sim_bag.h) for replay into the nodelets.
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <stdexcept>

#include "commands.h"
#include "dtif/bag/sim_bag.h"
#include "dtif/sim/simulator.h"
#include "options.h"

namespace dtif::tool {
namespace {

uint64_t parseCount(const std::string& opt, const std::string& v) {
  size_t used = 0;
  unsigned long long n = 0;
  try {
    n = std::stoull(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v.size() || v.empty() || v[0] == '-') {
    throw UsageError{"--" + opt + " needs a non-negative integer, got '" + v + "'"};
  }
  return n;
}

double parseLength(const std::string& opt, const std::string& v) {
  size_t used = 0;
  double x = -1.0;
  try {
    x = std::stod(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v.size() || v.empty() || !(x >= 0.0) || x > 100.0) {
    throw UsageError{"--" + opt + " needs a length in [0, 100] m, got '" + v + "'"};
  }
  return x;
}

}  // namespace

int runSimulate(const Args& args) {
  const Options o = parseOptions(
      args, {"out", "seed", "png", "threads", "bag", "bag-voxel", "bag-max-points"}, {"quiet"});
  if (o.positional.size() != 1) throw UsageError{"expected one scene.yaml"};
  const auto out = o.get("out");
  if (!out) throw UsageError{"--out <dataset_dir> is required"};
  const uint64_t seed = o.get("seed") ? parseCount("seed", *o.get("seed")) : 1;
  const int threads =
      o.get("threads") ? static_cast<int>(parseCount("threads", *o.get("threads"))) : 0;
  sim::BagParams bag_params;
  if (o.get("bag-voxel")) {
    if (!o.get("bag")) throw UsageError{"--bag-voxel needs --bag"};
    bag_params.voxel_m = parseLength("bag-voxel", *o.get("bag-voxel"));
  }
  if (o.get("bag-max-points")) {
    if (!o.get("bag")) throw UsageError{"--bag-max-points needs --bag"};
    const uint64_t n = parseCount("bag-max-points", *o.get("bag-max-points"));
    if (n > 10000000) throw UsageError{"--bag-max-points: at most 10000000"};
    bag_params.max_points = static_cast<uint32_t>(n);
  }
  const sim::SceneParams scene = sim::loadSceneYaml(o.positional[0]);
  std::unique_ptr<sim::BagFrameSink> bag;
  if (const auto path = o.get("bag")) {
    // Like --out, the bag's folder is created when missing.
    const std::filesystem::path parent = std::filesystem::path(*path).parent_path();
    std::error_code ec;
    if (!parent.empty()) std::filesystem::create_directories(parent, ec);
    if (ec) throw std::runtime_error(parent.string() + ": cannot create folder: " + ec.message());
    bag = std::make_unique<sim::BagFrameSink>(*path, bag_params);
  }
  const sim::DatasetRunResult r =
      sim::simulateDataset(scene, seed, *out, bag.get(), o.get("png").value_or(""), threads);
  if (bag) bag->close();
  if (!o.has("quiet")) {
    const auto& s = r.stats;
    std::cout << "scene " << scene.name << " (seed " << seed << ") -> " << *out << "\n"
              << "  stems " << s.stems << ", saplings " << s.saplings << ", shrubs " << s.shrubs
              << ", logs " << s.logs << ", branches " << s.branches << "\n"
              << "  robots " << scene.robots.size() << ", frames " << s.frames << ", rays "
              << s.rays << ", returns " << s.returns << "\n"
              << "  submaps " << s.submaps << ", mean points per submap "
              << static_cast<long>(s.mean_submap_points) << "\n"
              << "  true loops: " << r.loops.inter_robot_loops << " between robots, "
              << r.loops.intra_robot_loops << " within a robot; " << r.loops.disjoint_pairs
              << " disjoint pairs of " << r.loops.pairs << "\n"
              << "  simulation " << s.seconds << " s\n";
    if (o.get("png")) std::cout << "  picture " << *o.get("png") << "\n";
    if (bag) {
      const auto& b = bag->stats();
      std::ostringstream reduction;
      if (bag_params.voxel_m > 0) {
        reduction << bag_params.voxel_m << " m voxels, ";
      } else {
        reduction << "no voxels, ";
      }
      if (bag_params.max_points > 0) {
        reduction << "at most " << bag_params.max_points << " points";
      } else {
        reduction << "no point limit";
      }
      std::cout << "  bag " << *o.get("bag") << ": " << b.messages << " messages, " << b.bytes / 1e6
                << " MB; cloud_registered (" << reduction.str() << ") kept " << b.points_out
                << " of " << b.points_in << " points; written in " << b.write_seconds << " s\n";
    }
  }
  return 0;
}

}  // namespace dtif::tool
