// dtif score <dataset_dir> --loops <loop_log.csv> --out <dir> [--config params.yaml]
//            [--eval <eval_out_dir>]
// Scores an online run of the ROS nodelets (the LoopClosureNodelet's ~loop_log, e.g. from
// roslaunch dtif demo_bag.launch on the dataset's bag) with eval's ground truth and metrics,
// lists its loops, compares them with the loops of a dtif eval run on the same dataset, and
// reports the lag from each submap's last cloud to its result.
#include <algorithm>
#include <cstdio>
#include <iostream>
#include <map>
#include <sstream>

#include "commands.h"

namespace dtif::tool {
namespace {

struct Stats {
  size_t n = 0;
  double mean = 0, median = 0, max = 0;
};

Stats statsOf(std::vector<double> v) {
  Stats s;
  s.n = v.size();
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  for (double x : v) s.mean += x;
  s.mean /= static_cast<double>(v.size());
  s.median = v[v.size() / 2];
  s.max = v.back();
  return s;
}

std::string fmtStats(const Stats& s) {
  char buf[160];
  std::snprintf(buf, sizeof(buf), "mean %.2f s, median %.2f s, max %.2f s over %zu", s.mean,
                s.median, s.max, s.n);
  return buf;
}

using Names = std::map<int64_t, std::string>;  // dataset submap id -> robot

// "?" for an id the dataset does not hold (an --eval folder of another dataset).
const char* nameOf(const Names& names, int64_t id) {
  const auto it = names.find(id);
  return it == names.end() ? "?" : it->second.c_str();
}

// One line per online loop, with what dtif eval found for its query when given (`offline`:
// query -> candidate). Returns how many have eval's candidate.
size_t printOnlineLoops(const EvalResult& res, const Names& name, const ScoreArgs& a,
                        const std::map<int64_t, int64_t>& offline) {
  size_t same = 0;
  for (const EvalRow& r : res.rows) {
    if (!r.accepted) continue;
    char buf[256];
    std::snprintf(buf, sizeof(buf),
                  "  %s %ld -> %s %ld: rot %.3f deg, trans %.3f m, overlap %.2f, %s",
                  nameOf(name, r.query), static_cast<long>(r.query), nameOf(name, *r.candidate),
                  static_cast<long>(*r.candidate), r.err->rot_deg, r.err->trans_m, r.overlap,
                  r.true_positive ? "true positive" : "FALSE POSITIVE");
    std::cout << buf;
    if (!a.eval.empty()) {
      const auto it = offline.find(r.query);
      if (it == offline.end()) {
        std::cout << "; eval: no loop";
      } else if (it->second == *r.candidate) {
        std::cout << "; eval: same";
        ++same;
      } else {
        std::cout << "; eval: -> " << it->second;
      }
    }
    std::cout << "\n";
  }
  return same;
}

// eval's loops that the online run did not find.
void printMissedOnline(const EvalResult& res, const Names& name,
                       const std::map<int64_t, int64_t>& offline, size_t same) {
  std::map<int64_t, const EvalRow*> online;
  for (const EvalRow& r : res.rows) online[r.query] = &r;
  std::ostringstream missed;
  size_t n_missed = 0;
  for (const auto& [q, c] : offline) {
    const auto it = online.find(q);
    if (it != online.end() && it->second->accepted) continue;
    missed << (n_missed ? ", " : " ") << nameOf(name, q) << " " << q << " -> " << nameOf(name, c)
           << " " << c;
    ++n_missed;
  }
  std::cout << "same loops as dtif eval: " << same << " of " << res.summary.accepted
            << " online loops have eval's candidate; of eval's " << offline.size() << " loops, "
            << n_missed << " not found online" << (n_missed ? ":" : "") << missed.str() << "\n";
}

// Lag: from a submap's last cloud to its result, in ROS time (the bag's clock in a replay).
void printLag(const std::vector<LoopLogRow>& log) {
  std::vector<double> lag_all, lag_loops;
  for (const LoopLogRow& l : log) {
    lag_all.push_back(l.ros_time - l.query_data_end);
    if (l.accepted) lag_loops.push_back(l.ros_time - l.query_data_end);
  }
  std::cout << "lag from a submap's last cloud to its loop-closure result (ROS time): "
            << fmtStats(statsOf(lag_all)) << " queries; " << fmtStats(statsOf(lag_loops))
            << " accepted loops\n";
  if (log.size() >= 2) {
    const double ros_span = log.back().ros_time - log.front().ros_time;
    const double wall_span = log.back().wall_time - log.front().wall_time;
    if (wall_span > 0) {
      std::printf("ROS time ran at %.2fx wall time between the first and the last result\n",
                  ros_span / wall_span);
    }
  }
}

}  // namespace

int runScore(const ScoreArgs& a) {
  const DtifParams params = loadParams(a.configs);
  const Dataset ds = readDataset(a.dataset);
  const std::vector<LoopLogRow> log = readLoopLog(a.loops);
  std::vector<std::string> unmatched;
  const EvalResult res =
      scoreLoopLog(ds, log, params.loop.database.exclude_recent_s, EvalParams{}, &unmatched);
  const std::string table = formatTable(res.summary, "dtif (ROS nodelets)");
  writeEvalFiles(a.out, res, table, params);

  std::map<int64_t, int64_t> offline;
  if (!a.eval.empty()) offline = readAcceptedLoops(a.eval + "/results.csv");
  Names name;
  for (const SubmapRecord& r : ds.submaps) name[r.id] = r.robot;

  std::cout << "online loop closures (" << a.loops << ") against ground truth of " << ds.root
            << ":\n";
  const size_t same = printOnlineLoops(res, name, a, offline);
  for (const std::string& u : unmatched) std::cout << "  not in the dataset: " << u << "\n";
  std::cout << "(submap ids of the dataset; the nodelets number each robot's submaps apart)\n"
            << table;
  if (!a.eval.empty()) printMissedOnline(res, name, offline, same);
  printLag(log);
  return 0;
}

}  // namespace dtif::tool
