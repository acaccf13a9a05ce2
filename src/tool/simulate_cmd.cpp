// dtif simulate <scene.yaml> --out <dataset_dir> [--seed N] [--png <file>] [--threads N]
//               [--bag <file.bag>] [--bag-voxel <m>] [--bag-max-points N]
//               [--bag-layout namespaced|fastlio]
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

namespace dtif::tool {

int runSimulate(const SimulateArgs& a) {
  const sim::SceneParams scene = sim::loadSceneYaml(a.scene);
  sim::BagParams bag_params = a.bag_params;
  bag_params.layout = a.bag_layout.empty() ? scene.bag_layout : a.bag_layout;
  std::unique_ptr<sim::BagFrameSink> bag;
  if (!a.bag.empty()) {
    // Like --out, the bag's folder is created when missing.
    const std::filesystem::path parent = std::filesystem::path(a.bag).parent_path();
    std::error_code ec;
    if (!parent.empty()) std::filesystem::create_directories(parent, ec);
    if (ec) throw std::runtime_error(parent.string() + ": cannot create folder: " + ec.message());
    bag = std::make_unique<sim::BagFrameSink>(a.bag, bag_params);
  }
  const sim::DatasetRunResult r =
      sim::simulateDataset(scene, a.seed, a.out, bag.get(), a.png, a.threads);
  if (bag) bag->close();
  if (!a.quiet) {
    const auto& s = r.stats;
    std::cout << "scene " << scene.name << " (seed " << a.seed << ") -> " << a.out << "\n"
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
    if (!a.png.empty()) std::cout << "  picture " << a.png << "\n";
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
      std::cout << "  bag " << a.bag << ": " << b.messages << " messages, " << b.bytes / 1e6
                << " MB; cloud_registered (" << reduction.str() << ") kept " << b.points_out
                << " of " << b.points_in << " points; written in " << b.write_seconds << " s\n";
      if (bag_params.layout == sim::kLayoutFastlio) {
        std::cout << "  layout fastlio (a bag per unit: /cloud_registered, /Odometry, /tf; "
                     "frames camera_init, body):\n";
        for (const std::string& p : bag->paths()) std::cout << "    " << p << "\n";
      }
    }
  }
  return 0;
}

}  // namespace dtif::tool
