// dtif_merge_bench [N ...]: re-solve time of the map merger's pose graph (core/merge) at N
// submaps (default 1000 and 5000): four robots on square circuits with drifting odometry and a
// loop every fourth submap; after the graph is built and solved once, loops arrive one at a
// time and each is followed by a warm-started solve (PCM + Ceres), as online. One thread; the
// times are the process's CPU time, so that a busy machine does not inflate them.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <random>
#include <string>
#include <vector>

#include "dtif/core/merge/map_merger.h"

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

}  // namespace

int main(int argc, char** argv) {
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
