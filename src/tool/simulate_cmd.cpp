// dtif simulate <scene.yaml> --out <dataset_dir> [--seed N] [--png <file>] [--threads N]
// Simulates a forest survey (config/scenes/*.yaml) and writes it as a dataset (DATASET.md).
#include <iostream>

#include "commands.h"
#include "dtif/core/simulator.h"
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

}  // namespace

int runSimulate(const Args& args) {
  const Options o = parseOptions(args, {"out", "seed", "png", "threads"}, {"quiet"});
  if (o.positional.size() != 1) throw UsageError{"expected one scene.yaml"};
  const auto out = o.get("out");
  if (!out) throw UsageError{"--out <dataset_dir> is required"};
  const uint64_t seed = o.get("seed") ? parseCount("seed", *o.get("seed")) : 1;
  const int threads =
      o.get("threads") ? static_cast<int>(parseCount("threads", *o.get("threads"))) : 0;
  const sim::SceneParams scene = sim::loadSceneYaml(o.positional[0]);
  const sim::DatasetRunResult r =
      sim::simulateDataset(scene, seed, *out, nullptr, o.get("png").value_or(""), threads);
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
  }
  return 0;
}

}  // namespace dtif::tool
