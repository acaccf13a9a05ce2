// The options of each `dtif` subcommand, as parsed from the command line (options.cpp, CLI11);
// the commands (commands.h) see only these structs.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "dtif/bag/sim_bag.h"
#include "dtif/io/config.h"

namespace CLI {
class App;
}

namespace dtif::tool {

/// dtif simulate <scene.yaml> --out <dataset_dir> ...
struct SimulateArgs {
  std::string scene;          ///< scene YAML (config/scenes/*.yaml)
  std::string out;            ///< dataset folder (created when missing)
  uint64_t seed = 1;          ///< random seed of the simulation
  std::string png;            ///< top view of the scene ("": none)
  int threads = 0;            ///< simulation threads (0: all cores)
  std::string bag;            ///< rosbag of the raw frames ("": none)
  sim::BagParams bag_params;  ///< what the bag holds (--bag-voxel, --bag-max-points)
  std::string bag_layout;     ///< --bag-layout ("": the scene's bag_layout)
  bool quiet = false;         ///< no summary on stdout
};

/// dtif extract <cloud.pcd> [--out trunks.csv] [--repeat n] [--config params.yaml]...
struct ExtractArgs {
  std::string cloud;                 ///< PCD submap
  std::string out;                   ///< trunk map CSV to write ("": none)
  int repeat = 0;                    ///< describe this many more times, for the CPU time
  std::vector<std::string> configs;  ///< parameter files, applied in order
};

/// dtif register <query> <candidate> [--config params.yaml]...
struct RegisterArgs {
  std::string query;                 ///< PCD submap or x,y,z,r CSV
  std::string candidate;             ///< PCD submap or x,y,z,r CSV
  std::vector<std::string> configs;  ///< parameter files, applied in order
};

/// dtif eval <dataset_dir> --out <dir> ...
struct EvalArgs {
  std::string dataset;               ///< dataset folder (DATASET.md)
  std::string out;                   ///< output folder (created when missing)
  std::vector<std::string> configs;  ///< parameter files, applied in order
  bool unit_weights = false;         ///< pose estimation with unit weights
  bool quiet = false;                ///< no progress on stderr
  std::string method;                ///< method name in table.md ("": from the parameters)
};

/// dtif merge <dataset_dir> --out <dir> ...
struct MergeArgs {
  std::string dataset;               ///< dataset folder (DATASET.md)
  std::string out;                   ///< output folder (created when missing)
  std::vector<std::string> configs;  ///< parameter files, applied in order
  bool inject_false_loop = false;    ///< add one false loop (robustness check)
  bool false_loop_weakest = false;   ///< ... between the weakest-linked robots, first
  bool no_pcm = false;               ///< keep every loop (ablation: robust loss only)
  std::string stem_map;              ///< field stem map CSV x,y[,dbh] ("": none)
  std::string stem_map_plot;         ///< its plot_id to use ("": all rows)
  bool quiet = false;                ///< no progress on stderr
};

/// dtif score <dataset_dir> --loops <loop_log.csv> --out <dir> ...
struct ScoreArgs {
  std::string dataset;               ///< dataset folder the nodelets ran on (its bag)
  std::string loops;                 ///< the LoopClosureNodelet's ~loop_log
  std::string out;                   ///< output folder (created when missing)
  std::vector<std::string> configs;  ///< parameter files, applied in order
  std::string eval;                  ///< output folder of a dtif eval run to compare ("": none)
};

/// dtif bench <dataset_dir>... --out <dir> ...
struct BenchArgs {
  std::vector<std::string> datasets;   ///< dataset folders, one scene each
  std::string out;                     ///< output folder (created when missing)
  std::vector<std::string> configs;    ///< parameter files, applied in order
  std::vector<std::string> back_ends;  ///< back ends to run (options.cpp: all by default)
  bool no_front_ends = false;          ///< skip the FPFH front end comparison
  bool no_pr = false;                  ///< skip the precision-recall curves
  bool no_scan_context = false;        ///< skip place recognition (scan context)
  bool no_scaling = false;             ///< skip query time vs database size
  std::vector<size_t> scaling_sizes{10, 20, 50, 100, 200, 500, 1000, 2000};  ///< database sizes
  bool speed = false;        ///< the speed section (bench_speed.h)
  bool speed_only = false;   ///< only the speed section
  std::string before_probe;  ///< an earlier build's speed probe, for before / after
  std::vector<size_t> speed_sizes{1000, 5000, 10000, 20000};  ///< database sizes [entries]
  size_t speed_every = 1;                                     ///< describe every n-th submap
};

/// The options of every subcommand; the one the command line names is filled in.
struct CommandLine {
  SimulateArgs simulate;
  ExtractArgs extract;
  RegisterArgs reg;
  EvalArgs eval;
  ScoreArgs score;
  BenchArgs bench;
  MergeArgs merge;
};

/// Adds the subcommands (simulate, extract, register, eval, merge, score, bench) to dtif, each
/// option bound to its field of *cl, and requires exactly one of them.
void addCommands(CLI::App* dtif, CommandLine* cl);

/// Default parameters overridden by every `--config` file given, in order.
DtifParams loadParams(const std::vector<std::string>& configs);

}  // namespace dtif::tool
