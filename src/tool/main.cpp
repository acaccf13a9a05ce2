// dtif: the offline command-line tool (simulate, extract, register, eval, score, bench).
#include <cstring>
#include <exception>
#include <iostream>

#include "commands.h"

namespace {

constexpr const char* kUsage =
    "usage: dtif <command> [options]\n"
    "  simulate <scene.yaml> --out <dataset_dir> [--seed N] [--png <file>] [--threads N]\n"
    "           [--bag <file.bag> [--bag-voxel <m>] [--bag-max-points N]]\n"
    "           --bag: also a rosbag (/<robot>/cloud_registered, /<robot>/Odometry, /tf) for\n"
    "           roslaunch dtif demo_bag.launch, every return by default (about 3 MB/s per\n"
    "           robot for a 200k points/s scene); each cloud can be voxel-filtered (--bag-voxel\n"
    "           <m>) and thinned evenly to at most N points (--bag-max-points N); 0: off\n"
    "  extract  <cloud.pcd> [--out <trunks.csv>] [--config <params.yaml>]\n"
    "  register <query> <candidate> [--config <params.yaml>]  (PCD submaps or x,y,z,r CSVs)\n"
    "  eval     <dataset_dir> --out <dir> [--config <params.yaml>] [--unit-weights]\n"
    "  score    <dataset_dir> --loops <loop_log.csv> --out <dir> [--config <params.yaml>]\n"
    "           [--eval <eval_out_dir>]: scores the loop log of the ROS nodelets on this\n"
    "           dataset's bag against its ground truth (eval's metrics), lists the loops, "
    "compares\n"
    "           them with a dtif eval run and reports the lag of the results\n"
    "  bench    <dataset_dir>... --out <dir> [--config <params.yaml>] [--back-ends a,b,...]\n"
    "           [--no-front-ends] [--no-pr] [--no-scan-context] [--no-scaling]\n"
    "           [--scaling-sizes 10,20,...]\n"
    "           dtif vs the paper's baselines (back ends: dtif, dtif_unit, quatro,\n"
    "           svd_ransac, fgr; front end: FPFH; place recognition: scan context);\n"
    "           summary.csv, tables.md, pr.csv, place_recognition.csv, ...\n";

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "-h") || !std::strcmp(argv[1], "--help")) {
    std::cout << kUsage;
    return argc < 2 ? 2 : 0;
  }
  const std::string cmd = argv[1];
  const dtif::tool::Args args(argv + 2, argv + argc);
  try {
    if (cmd == "simulate") return dtif::tool::runSimulate(args);
    if (cmd == "extract") return dtif::tool::runExtract(args);
    if (cmd == "register") return dtif::tool::runRegister(args);
    if (cmd == "eval") return dtif::tool::runEval(args);
    if (cmd == "score") return dtif::tool::runScore(args);
    if (cmd == "bench") return dtif::tool::runBench(args);
    std::cerr << "dtif: unknown command '" << cmd << "'\n" << kUsage;
    return 2;
  } catch (const dtif::tool::UsageError& e) {
    std::cerr << "dtif " << cmd << ": " << e.message << "\n" << kUsage;
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "dtif " << cmd << ": " << e.what() << "\n";
    return 1;
  }
}
