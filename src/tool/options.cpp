// The command line of `dtif` on CLI11: one subcommand per command, each option bound to a field
// of that command's struct (options.h) with its default, its unit and its validation.
#include "options.h"

#include <CLI/CLI.hpp>
#include <algorithm>

#include "dtif/baselines/bench.h"

namespace dtif::tool {
namespace {

/// A non-negative decimal integer. CLI11 itself reads integers with strtoull base 0, which
/// takes "-1" as 2^64 - 1 and "010" as octal 8; this keeps decimal digits only and drops
/// leading zeros, so the value is what std::stoull reads.
const CLI::Validator kCount(
    [](std::string& s) -> std::string {
      const std::string bad = "needs a non-negative integer, got '" + s + "'";
      if (s.empty() || s.find_first_not_of("0123456789") != std::string::npos) return bad;
      s.erase(0, std::min(s.find_first_not_of('0'), s.size() - 1));
      try {
        std::stoull(s);
      } catch (const std::out_of_range&) {
        return bad;
      }
      return "";
    },
    "", "COUNT");

/// --config, repeatable: the files are applied in the order given.
void addConfig(CLI::App* cmd, std::vector<std::string>* configs) {
  cmd->add_option("--config", *configs,
                  "parameter YAML (config/*.yaml) over the defaults; repeatable, applied in order")
      ->type_name("<params.yaml>")
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll)
      ->allow_extra_args(false);
}

/// --out, the folder a command writes its results into.
void addOutDir(CLI::App* cmd, std::string* out) {
  cmd->add_option("--out", *out, "output folder (created when missing)")
      ->type_name("<dir>")
      ->required();
}

void addSimulate(CLI::App* dtif, SimulateArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "simulate",
      "Simulates a forest survey by several robots (a scene YAML, config/scenes/) and writes it "
      "as a dataset (DATASET.md), optionally also as a rosbag of the raw frames.");
  cmd->add_option("scene", a->scene, "scene YAML (config/scenes/*.yaml)")
      ->type_name("<scene.yaml>")
      ->required();
  cmd->add_option("--out", a->out, "dataset folder to write (created when missing)")
      ->type_name("<dataset_dir>")
      ->required();
  cmd->add_option("--seed", a->seed, "random seed of the simulation")
      ->type_name("N")
      ->transform(kCount)
      ->capture_default_str();
  cmd->add_option("--png", a->png, "also a top view of the scene (PNG)")->type_name("<file>");
  cmd->add_option("--threads", a->threads,
                  "simulation threads (default: all cores; the output does not depend on it)")
      ->type_name("N")
      ->transform(kCount)
      ->check(CLI::PositiveNumber);
  CLI::Option* bag =
      cmd->add_option("--bag", a->bag,
                      "also a rosbag (/<robot>/cloud_registered, /<robot>/Odometry, /tf) for "
                      "roslaunch dtif demo_bag.launch; every return by default (about 3 MB/s "
                      "per robot for a 200k points/s scene)")
          ->type_name("<file.bag>");
  cmd->add_option("--bag-voxel", a->bag_params.voxel_m,
                  "voxel filter of each cloud in the bag, voxel size [m]; 0: off")
      ->type_name("<m>")
      ->check(CLI::Range(0.0, 100.0))
      ->capture_default_str()
      ->needs(bag);
  cmd->add_option("--bag-max-points", a->bag_params.max_points,
                  "each cloud in the bag then thinned evenly to at most N points; 0: no limit")
      ->type_name("N")
      ->transform(kCount)
      ->check(CLI::Range(0, 10000000))
      ->capture_default_str()
      ->needs(bag);
  cmd->add_option(
         "--bag-layout", a->bag_layout,
         "namespaced: one bag, /<robot>/cloud_registered, /<robot>/Odometry, frames "
         "<robot>/odom, <robot>/base_link; fastlio: one bag per robot as recorded on a "
         "stock FAST-LIO2 unit, <stem>_<robot>.bag with /cloud_registered, /Odometry, /tf, "
         "frames camera_init, body (default: the scene's bag_layout, else namespaced)")
      ->type_name("namespaced|fastlio")
      ->check(CLI::IsMember({"namespaced", "fastlio"}))
      ->needs(bag);
  cmd->add_option("--bag-compression", a->bag_params.compression,
                  "chunk compression of the bag: none, or lz4 (smaller, rosbag play reads it)")
      ->type_name("none|lz4")
      ->check(CLI::IsMember({"none", "lz4"}))
      ->capture_default_str()
      ->needs(bag);
  cmd->add_flag("--quiet", a->quiet, "no summary on stdout");
}

void addExtract(CLI::App* dtif, ExtractArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "extract", "Extracts the trunks of one submap and describes it (counts and timings).");
  cmd->add_option("cloud", a->cloud, "submap point cloud (PCD)")
      ->type_name("<cloud.pcd>")
      ->required();
  cmd->add_option("--out", a->out, "also write the trunks (x,y,z,r CSV)")
      ->type_name("<trunks.csv>");
  cmd->add_option("--repeat", a->repeat,
                  "describe the cloud n more times and print the thread CPU time per describe "
                  "(min, median): a benchmark that a busy machine disturbs less than wall time")
      ->type_name("<n>")
      ->check(CLI::Range(0, 1000));
  addConfig(cmd, &a->configs);
}

void addRegister(CLI::App* dtif, RegisterArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "register",
      "Registers a query submap with a candidate (loop detection and verification); exits 1 "
      "when they do not register.");
  cmd->add_option("query", a->query, "query: PCD submap or trunk map CSV (x,y,z,r [m])")
      ->type_name("<query>")
      ->required();
  cmd->add_option("candidate", a->candidate, "candidate: PCD submap or trunk map CSV (x,y,z,r [m])")
      ->type_name("<candidate>")
      ->required();
  addConfig(cmd, &a->configs);
}

void addEval(CLI::App* dtif, EvalArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "eval",
      "The evaluation protocol of DATASET.md on a dataset: results.csv, summary.json, table.md, "
      "misses.csv, detection.csv and the effective params.yaml in the output folder.");
  cmd->add_option("dataset", a->dataset, "dataset folder (DATASET.md)")
      ->type_name("<dataset_dir>")
      ->required();
  addOutDir(cmd, &a->out);
  addConfig(cmd, &a->configs);
  cmd->add_flag("--unit-weights", a->unit_weights,
                "pose estimation with unit weights (the paper's ablation)");
  cmd->add_flag("--quiet", a->quiet, "no progress on stderr");
  cmd->add_option("--method", a->method,
                  "method name in table.md (default: dtif, or dtif (unit weights))")
      ->type_name("<name>");
}

void addMerge(CLI::App* dtif, MergeArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "merge",
      "Sequential loop closure (eval's protocol), then one merged map (DATASET.md, Merged map): "
      "merged_poses.csv, merged_stems.csv, pose_graph.g2o, events.txt, summary.json; scored "
      "against the ground truth when the dataset has it.");
  cmd->add_option("dataset", a->dataset, "dataset folder (DATASET.md)")
      ->type_name("<dataset_dir>")
      ->required();
  addOutDir(cmd, &a->out);
  addConfig(cmd, &a->configs);
  cmd->add_flag("--inject-false-loop", a->inject_false_loop,
                "add one deliberately false inter-robot loop and report how much it moves the map");
  cmd->add_flag("--false-loop-weakest", a->false_loop_weakest,
                "with --inject-false-loop: put it between the two robots with the fewest "
                "inter-robot loops, with the first loop, and leave out their true loops: two "
                "robots that never met, joined by one false loop, which PCM cannot compare with "
                "another")
      ->needs("--inject-false-loop");
  cmd->add_flag("--no-pcm", a->no_pcm,
                "keep every loop (no pairwise consistency check; the robust loss only)");
  cmd->add_option("--stem-map", a->stem_map,
                  "field stem map CSV (x,y[,dbh] in plot coordinates) to anchor the map to")
      ->type_name("<stems.csv>")
      ->check(CLI::ExistingFile);
  cmd->add_option("--stem-map-plot", a->stem_map_plot,
                  "use only the rows of this plot_id of the stem map")
      ->type_name("<plot_id>");
  cmd->add_flag("--quiet", a->quiet, "no progress on stderr");
}

void addScore(CLI::App* dtif, ScoreArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "score",
      "Scores the loop log of the ROS nodelets on this dataset's bag against its ground truth "
      "(eval's metrics), lists the loops, compares them with a dtif eval run and reports the "
      "lag of the results [s].");
  cmd->add_option("dataset", a->dataset, "dataset folder the bag was simulated with")
      ->type_name("<dataset_dir>")
      ->required();
  cmd->add_option("--loops", a->loops, "loop log of the LoopClosureNodelet (~loop_log)")
      ->type_name("<loop_log.csv>")
      ->required();
  addOutDir(cmd, &a->out);
  addConfig(cmd, &a->configs);
  cmd->add_option("--eval", a->eval, "output folder of dtif eval on the same dataset, to compare")
      ->type_name("<eval_out_dir>");
}

void addBench(CLI::App* dtif, BenchArgs* a) {
  CLI::App* cmd = dtif->add_subcommand(
      "bench",
      "dtif vs the paper's baselines (back ends: dtif, dtif_unit, quatro, svd_ransac, fgr; "
      "front end: FPFH; place recognition: scan context): summary.csv, tables.md, pr.csv, "
      "place_recognition.csv, submaps.csv, scaling.csv, ...");
  cmd->add_option("datasets", a->datasets, "dataset folders, one scene each")
      ->type_name("<dataset_dir>")
      ->required();
  addOutDir(cmd, &a->out);
  addConfig(cmd, &a->configs);
  a->back_ends = baselines::BenchOptions{}.back_ends;
  cmd->add_option("--back-ends", a->back_ends, "back ends on dtif's correspondences")
      ->type_name("a,b,...")
      ->delimiter(',')
      ->check(CLI::IsMember(a->back_ends))
      ->capture_default_str();
  cmd->add_flag("--no-front-ends", a->no_front_ends, "no front end comparison (FPFH)");
  cmd->add_flag("--no-pr", a->no_pr, "no precision-recall curves");
  cmd->add_flag("--no-scan-context", a->no_scan_context, "no place recognition (scan context)");
  cmd->add_flag("--no-scaling", a->no_scaling, "no query time vs database size");
  cmd->add_option("--scaling-sizes", a->scaling_sizes,
                  "database sizes of the query time measurement [descriptors]")
      ->type_name("N,N,...")
      ->delimiter(',')
      ->transform(kCount)
      ->capture_default_str();
  cmd->add_flag("--speed", a->speed,
                "also descriptor and query time (speed.md, speed_*.csv), by the speed probe "
                "dtif_query_bench; before / after with --before-probe");
  cmd->add_flag("--speed-only", a->speed_only, "only the speed section (implies --speed)");
  cmd->add_option("--before-probe", a->before_probe,
                  "dtif_query_bench built against an earlier commit (scripts/build_before.sh)")
      ->type_name("<file>")
      ->check(CLI::ExistingFile);
  cmd->add_option("--speed-sizes", a->speed_sizes, "database sizes of the speed section [entries]")
      ->type_name("N,N,...")
      ->delimiter(',')
      ->transform(kCount)
      ->capture_default_str();
  cmd->add_option("--speed-every", a->speed_every, "describe every n-th submap")
      ->transform(kCount)
      ->capture_default_str();
}

}  // namespace

void addCommands(CLI::App* dtif, CommandLine* cl) {
  // A scalar option given twice keeps its last value, as the tool always did.
  dtif->option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  dtif->require_subcommand(1);
  addSimulate(dtif, &cl->simulate);
  addExtract(dtif, &cl->extract);
  addRegister(dtif, &cl->reg);
  addEval(dtif, &cl->eval);
  addMerge(dtif, &cl->merge);
  addScore(dtif, &cl->score);
  addBench(dtif, &cl->bench);
}

DtifParams loadParams(const std::vector<std::string>& configs) {
  DtifParams p;
  for (const auto& file : configs) loadParamsYaml(file, &p);
  return p;
}

}  // namespace dtif::tool
