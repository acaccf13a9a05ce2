// dtif_merge_bench [N ...]: re-solve time of the map merger's pose graph (core/merge) at N
// submaps (default 1000 and 5000): four robots on square circuits with drifting odometry and a
// loop every fourth submap; after the graph is built and solved once, loops arrive one at a
// time and each is followed by a warm-started solve (PCM + Ceres), as online. One thread; the
// times are the process's CPU time, so that a busy machine does not inflate them.
// dtif_merge_bench --database FILE [EVERY]: a saved database (e.g. the soak test's) replayed as
// the map-merge nodelet meets it: submaps in stamp order, each loop once both its submaps are
// in, a solve after every EVERY submaps (default 6); prints the solve CPU time and the resident
// memory as the graph grows.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/merge/map_merger.h"
#include "proc_status.h"

namespace {

using dtif::Pose;

double cpuMs(std::clock_t t0) {
  return 1000.0 * static_cast<double>(std::clock() - t0) / CLOCKS_PER_SEC;
}

Pose onSquare(double s, double side) {
  s = std::fmod(s, 4.0 * side);
  Pose T = Pose::Identity();
  const int leg = static_cast<int>(s / side);
  const double u = s - leg * side;
  const double xs[4] = {u, side, side - u, 0.0}, ys[4] = {0.0, u, side, side - u};
  T.linear() = dtif::rotZ(leg * M_PI / 2);
  T.translation() << xs[leg], ys[leg], 0.0;
  return T;
}

void bench(int n) {
  constexpr int kRobots = 4;
  const int per = n / kRobots;
  const double side = 100.0, step = 5.0;
  std::mt19937 rng(1);
  std::normal_distribution<double> nt(0.0, 0.01), nr(0.0, 0.001);
  auto noise = [&] {
    Pose T = Pose::Identity();
    T.linear() = dtif::rotZ(nr(rng) + 0.001);
    T.translation() << nt(rng), nt(rng), nt(rng);
    return T;
  };
  dtif::MapMerger merger;
  std::vector<std::vector<Pose>> gt(kRobots);
  for (int r = 0; r < kRobots; ++r) {
    Pose odo = Pose::Identity();
    for (int k = 0; k < per; ++k) {
      gt[r].push_back(onSquare(step * k + 37.0 * r, side));
      if (k > 0) odo = odo * gt[r][k - 1].inverse() * gt[r][k] * noise();
      merger.addSubmap({"r" + std::to_string(r), r * per + k, 10.0 * k, odo, {}});
    }
  }
  // Loops: each robot's submap k with the robot before it where it was (same place on the
  // square), every fourth submap.
  std::vector<dtif::Loop> loops;
  const int shift = static_cast<int>(37.0 / step);
  for (int r = 1; r < kRobots; ++r) {
    for (int k = 0; k + shift * r < per; k += 4) {
      const int kc = k + shift * r;  // the earlier robot... any robot 0 submap at that place
      dtif::Loop l;
      l.query_robot = "r" + std::to_string(r);
      l.query_id = r * per + k;
      l.candidate_robot = "r0";
      l.candidate_id = kc;
      l.T_c_q = gt[0][kc].inverse() * gt[r][k];
      l.covariance = dtif::Matrix6d::Identity() * 1e-4;
      loops.push_back(l);
    }
  }
  const size_t warm = loops.size() - 10;
  for (size_t i = 0; i < warm; ++i) merger.addLoop(loops[i]);
  std::clock_t t0 = std::clock();
  const dtif::MergeSolveStats first = merger.solve();
  const double first_ms = cpuMs(t0);
  double sum = 0.0, worst = 0.0;
  for (size_t i = warm; i < loops.size(); ++i) {
    merger.addLoop(loops[i]);
    t0 = std::clock();
    merger.solve();
    const double ms = cpuMs(t0);
    sum += ms;
    worst = std::max(worst, ms);
  }
  std::printf("| %d | %zu | %.0f (%d iterations) | %.0f | %.0f |\n", n, loops.size(), first_ms,
              first.iterations, sum / 10.0, worst);
}

struct Replay {
  std::vector<size_t> order;  // entries in (stamp, robot) order; a submap's merger id: its position
  // per position: the loops whose submaps are both in by then, ids as merger ids
  std::vector<std::vector<dtif::Loop>> due;
};

Replay replayOrder(const dtif::LoopDetector& db) {
  Replay r;
  for (size_t i : dtif::entriesInStampOrder(db)) {
    if (db.odometry(i).known()) r.order.push_back(i);
  }
  std::map<std::pair<std::string, int64_t>, size_t> at;
  for (size_t k = 0; k < r.order.size(); ++k) {
    const dtif::Descriptor& d = *db.entries()[r.order[k]];
    at[{d.robot, d.submap_id}] = k;
  }
  r.due.resize(r.order.size());
  for (size_t l = 0; l < db.loops().size(); ++l) {
    const dtif::Loop& lc = db.loops()[l];
    auto q = at.find({lc.query_robot, lc.query_id}),
         c = at.find({lc.candidate_robot, lc.candidate_id});
    if (q == at.end() || c == at.end()) continue;
    dtif::Loop renumbered = lc;
    renumbered.query_id = static_cast<int64_t>(q->second);
    renumbered.candidate_id = static_cast<int64_t>(c->second);
    r.due[std::max(q->second, c->second)].push_back(renumbered);
  }
  return r;
}

int benchDatabase(const std::string& path, int every) {
  dtif::LoopDetector db{dtif::LoopDetectorParams{}};
  db.load(path);
  const Replay rp = replayOrder(db);
  dtif::MapMerger merger;
  std::printf(
      "| submaps | loops used / rejected | solve [ms CPU] | iterations | linear solver | RSS [MB] "
      "| peak [MB] |\n"
      "|---|---|---|---|---|---|---|\n");
  double total = 0.0, worst = 0.0;
  int solves = 0;
  for (size_t k = 0; k < rp.order.size(); ++k) {
    const dtif::Descriptor& d = *db.entries()[rp.order[k]];
    dtif::MergeSubmap sub = dtif::mergeSubmapOf(d, db.odometry(rp.order[k]).T_O_S);
    sub.id = static_cast<int64_t>(k);  // the merger ids of Replay
    merger.addSubmap(sub);
    for (const dtif::Loop& l : rp.due[k]) merger.addLoop(l);
    const bool last = k + 1 == rp.order.size();
    if ((k + 1) % every != 0 && !last) continue;
    const std::clock_t t0 = std::clock();
    const dtif::MergeSolveStats st = merger.solve();
    const double ms = cpuMs(t0);
    total += ms;
    worst = std::max(worst, ms);
    ++solves;
    const size_t quarter = std::max<size_t>(1, rp.order.size() / 4);
    if ((k + 1) % quarter < static_cast<size_t>(every) || last) {
      std::printf("| %zu | %zu / %zu | %.0f | %d | %s | %.0f | %.0f |\n", k + 1, st.loops_used,
                  st.loops_rejected, ms, st.iterations, st.iterative ? "CG" : "Cholesky",
                  dtif::procMiB("VmRSS"), dtif::procMiB("VmHWM"));
    }
  }
  std::printf("%d solves: %.0f ms CPU in all, mean %.0f, max %.0f\n", solves, total,
              total / std::max(1, solves), worst);
  // The final map's landmark refinement (dtif merge, save_map), once.
  const std::clock_t t0 = std::clock();
  const dtif::MergeSolveStats st = merger.refine();
  std::printf(
      "landmark refinement of the final map: %.0f ms CPU, %zu landmarks, %zu observations\n",
      cpuMs(t0), st.landmarks, st.landmark_observations);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 3 && std::string(argv[1]) == "--database") {
    try {
      return benchDatabase(argv[2], argc >= 4 ? std::max(1, std::atoi(argv[3])) : 6);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "dtif_merge_bench: %s: %s\n", argv[2], e.what());
      return 1;
    }
  }
  std::vector<int> sizes;
  for (int i = 1; i < argc; ++i) sizes.push_back(std::atoi(argv[i]));
  if (sizes.empty()) sizes = {1000, 5000};
  std::printf(
      "| submaps | loops | first solve [ms CPU] | re-solve after one loop, mean [ms CPU] | max [ms "
      "CPU] |\n"
      "|---|---|---|---|---|\n");
  for (int n : sizes) {
    if (n < 40) {
      std::fprintf(stderr, "dtif_merge_bench: %d submaps is too few (at least 40)\n", n);
      return 2;
    }
    bench(n);
  }
  return 0;
}
