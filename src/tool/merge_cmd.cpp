// dtif merge <dataset_dir> --out <dir> [--config params.yaml] [--inject-false-loop] [--no-pcm]
//            [--stem-map stems.csv [--stem-map-plot id]]
// Eval's sequential loop closure, then the map merger (core/merge): DATASET.md's "Merged map"
// (merged_poses.csv, merged_stems.csv, summary.json) plus the pose graph (pose_graph.g2o) and
// the component events (events.txt); scored against the ground truth when it exists.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>

#include "commands.h"
#include "dtif/eval/merge_eval.h"
#include "dtif/io/merge_files.h"

namespace dtif::tool {
namespace {

void countLoops(const MapMerger& merger, MergeSummary* s) {
  for (const LoopVerdict& v : merger.loops()) {
    (v.used ? s->loops_used : s->loops_rejected)++;
    if (v.inter_robot) (v.used ? s->inter_robot_used : s->inter_robot_rejected)++;
  }
}

void writeEvents(const std::string& path, const std::vector<MergeEvent>& events) {
  std::ofstream f(path);
  for (const MergeEvent& e : events) f << e.text << "\n";
  if (!f) throw DatasetError(path + ": write failed");
}

void printStemMap(const StemMapRegistration& r, size_t field_stems) {
  std::cout << std::fixed << std::setprecision(3) << "stem map (" << field_stems
            << " field stems): ";
  if (!r.ok) {
    std::cout << "not registered: " << r.reason << "\n";
    return;
  }
  const double yaw = std::atan2(r.T_P_M.linear()(1, 0), r.T_P_M.linear()(0, 0)) * 180.0 / M_PI;
  std::cout << "registered, " << r.pairs.size() << " stems paired, residual RMS " << r.rms_m
            << " m, median " << r.median_m << " m; map -> plot yaw " << std::setprecision(2) << yaw
            << " deg, t (" << r.T_P_M.translation().x() << ", " << r.T_P_M.translation().y()
            << ") m\n";
}

// The false loop of --inject-false-loop, or none. With --false-loop-weakest the two robots share
// no true loop: the false one is their only loop.
std::optional<Loop> falseLoopOf(const MergeArgs& a, const Dataset& ds, MergeInput* in) {
  if (!a.inject_false_loop) return std::nullopt;
  std::optional<Loop> l = makeFalseLoop(
      ds, *in, a.false_loop_weakest ? FalseLoopPair::kWeakest : FalseLoopPair::kFirstLinked);
  if (!l) throw DatasetError(ds.root + ": a false loop needs at least two robots");
  if (a.false_loop_weakest) dropLoopsBetween(in, l->query_robot, l->candidate_robot);
  return l;
}

// The inventory as written: with the DBH refitted on the merged points where configured.
std::vector<MergedStem> finalStems(const Dataset& ds, const MergeParams& mp,
                                   const std::vector<MergedPose>& poses,
                                   std::vector<MergedStem> stems, StemSliceStats* st) {
  if (mp.stems.dbh_from_points) stems = refitStemDbh(ds, poses, stems, mp.stems, st);
  return stems;
}

// What the merger did with the loops and robots (the false loop's fate among them).
void recordVerdicts(const MapMerger& merger, const std::optional<Loop>& false_loop,
                    MergeSummary* sum) {
  countLoops(merger, sum);
  if (false_loop) {
    for (const LoopVerdict& v : merger.loops()) {
      if (v.query_id == false_loop->query_id && v.candidate_id == false_loop->candidate_id) {
        sum->false_loop_used = v.used;
        sum->false_loop_added = true;
      }
    }
  }
  sum->components = merger.componentCount();
  for (const std::string& r : merger.robots()) sum->robot_component[r] = merger.component(r);
  sum->robots = sum->robot_component.size();
}

// DATASET.md's merged-map files, the graph and the events, into folder out.
void writeOutputs(const std::string& out, const std::vector<MergedPose>& poses,
                  const std::vector<MergedStem>& stems, const MapMerger& merger,
                  const std::vector<MergeEvent>& events, const MergeSummary& sum) {
  std::error_code ec;
  std::filesystem::create_directories(out, ec);
  if (ec) throw DatasetError(out + ": cannot create output folder: " + ec.message());
  const std::filesystem::path dir(out);
  writeMergedPosesCsv((dir / "merged_poses.csv").string(), poses);
  writeMergedStemsCsv((dir / "merged_stems.csv").string(), stems);
  writeG2o((dir / "pose_graph.g2o").string(), poses, merger.graphEdges());
  writeEvents((dir / "events.txt").string(), events);
  writeMergeSummaryJson((dir / "summary.json").string(), sum);
}

void printLoops(const MergeSummary& sum, const MergeInput& in) {
  std::cout << "dataset " << sum.dataset << ": " << sum.submaps << " submaps, " << sum.robots
            << " robots, " << sum.components << " component(s); loops: " << sum.loops_accepted
            << " accepted by loop closure (" << in.inter_robot_extra
            << " inter-robot beside an own-robot best loop), " << sum.loops_used << " used, "
            << sum.loops_rejected
            << " rejected by the back end (inter-robot: " << sum.inter_robot_used << " used, "
            << sum.inter_robot_rejected << " rejected); " << sum.stems << " stems\n";
  if (in.eval && in.inter_robot_extra > 0) {
    std::cout << "inter-robot loops beside an own-robot best loop: " << in.inter_robot_extra << ", "
              << in.eval->summary.inter_robot_extra_true << " true positives (ground truth)\n";
  }
}

void printGraphAndStems(const MergeSummary& sum) {
  std::cout << std::fixed << std::setprecision(1) << "graph: " << sum.run.solves
            << " incremental solves, mean "
            << (sum.run.solves ? sum.run.solve_ms_total / sum.run.solves : 0.0) << " ms, max "
            << sum.run.solve_ms_max << " ms (" << sum.run.iterative_solves
            << " with conjugate gradients: the factor would be dense)\n";
  if (sum.stem_slices) {
    const StemSliceStats& q = *sum.stem_slices;
    std::cout << std::setprecision(0) << "stem DBH from the points: " << q.refitted << " of "
              << q.stems << " stems refitted, " << q.blended
              << " half-way to the median (kept the median: " << q.too_few << " too few points, "
              << q.one_sided << " one-sided, " << q.shrunk << " well inside it, " << q.enclosing
              << " around clutter, " << q.no_fit << " no fit), " << q.points
              << " slice points from " << q.submap_views << " stem views, " << sum.stem_slices_ms
              << " ms\n";
    const SliceAlignmentStats& a = q.alignment;
    if (a.views > 0) {
      std::cout << std::setprecision(1) << "  submaps aligned on the bark first: " << a.views
                << " submaps on " << a.stems << " stems (" << a.points << " points), largest shift "
                << 100.0 * a.max_shift_m << " cm\n";
    }
  }
}

void printFalseLoop(const Loop& l, const MergeSummary& sum) {
  std::cout << "false loop " << l.query_robot << "/" << l.query_id << " -> " << l.candidate_robot
            << "/" << l.candidate_id << ": "
            << (!sum.false_loop_added ? "NOT ADDED"
                : sum.false_loop_used ? "USED"
                                      : "rejected");
  if (sum.score && sum.score_clean && sum.score->component.count(0) &&
      sum.score_clean->component.count(0)) {
    const double d = sum.score->component.at(0).ate_m - sum.score_clean->component.at(0).ate_m;
    std::cout << std::setprecision(4) << "; component 0 ATE change " << d << " m";
  }
  std::cout << "\n";
}

void printReport(const MergeSummary& sum, const MergeInput& in,
                 const std::vector<MergeEvent>& events, const std::optional<Loop>& false_loop) {
  printLoops(sum, in);
  for (const MergeEvent& e : events) std::cout << "  " << e.text << "\n";
  printGraphAndStems(sum);
  if (sum.score) std::cout << formatMergeTable(*sum.score);
  if (false_loop) printFalseLoop(*false_loop, sum);
  if (sum.stem_map) printStemMap(*sum.stem_map, sum.stem_map_field_stems);
}

MergeInput closeLoops(const Dataset& ds, const DtifParams& params, bool quiet) {
  return collectMergeInput(ds, params, EvalParams{}, [&](size_t i, size_t n) {
    if (!quiet && (i % 10 == 0 || i == n)) {
      std::cerr << "\rdtif merge: loop closure " << i << "/" << n << " submaps" << std::flush;
      if (i == n) std::cerr << "\n";
    }
  });
}

}  // namespace

int runMerge(const MergeArgs& a) {
  const DtifParams params = loadParams(a.configs);
  MergeParams mp = params.merge;  // --config: sections merge and stems
  if (a.no_pcm) mp.pcm = false;
  const Dataset ds = readDataset(a.dataset);
  std::vector<FieldStem> field;
  if (!a.stem_map.empty()) field = readStemMapCsv(a.stem_map, a.stem_map_plot);

  MergeInput in = closeLoops(ds, params, a.quiet);
  const std::optional<Loop> false_loop = falseLoopOf(a, ds, &in);
  MergeSummary sum;
  sum.dataset = ds.root;
  sum.submaps = in.submaps.size();
  sum.loops_accepted = in.loops.size();
  sum.false_loop_injected = false_loop.has_value();
  if (false_loop && in.eval) {  // the ATE change needs the merge without it
    const MapMerger clean = runMerger(in, mp, std::nullopt, field);
    const std::vector<MergedPose> poses = clean.poses();
    StemSliceStats st;
    sum.score_clean = scoreMerge(ds, poses, finalStems(ds, mp, poses, clean.stems(), &st));
  }
  std::vector<MergeEvent> events;
  const MapMerger merger =
      runMerger(in, mp, false_loop, field, &events, &sum.run, a.false_loop_weakest);
  recordVerdicts(merger, false_loop, &sum);
  const std::vector<MergedPose> poses = merger.poses();
  const auto t0 = std::chrono::steady_clock::now();
  StemSliceStats slice_stats;
  const std::vector<MergedStem> stems = finalStems(ds, mp, poses, merger.stems(), &slice_stats);
  if (mp.stems.dbh_from_points) {
    sum.stem_slices = slice_stats;
    sum.stem_slices_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  sum.stems = stems.size();
  if (!field.empty()) {
    sum.stem_map = merger.stemMapRegistration();
    sum.stem_map_field_stems = field.size();
  }
  if (in.eval) sum.score = scoreMerge(ds, poses, stems);

  writeOutputs(a.out, poses, stems, merger, events, sum);  // only once everything succeeded
  printReport(sum, in, events, false_loop);
  return 0;
}

}  // namespace dtif::tool
