// dtif_query_bench: loop query time of the database (LoopDetector::query) apart from the
// descriptors, on descriptors collected once from simulated datasets.
//   dtif_query_bench collect OUT.db DATASET...  every submap's descriptor (the eval protocol's),
//       robots renamed <scene>/<robot> so that scenes and seeds share one database file
//   dtif_query_bench replay DB [SCENE] [--best-only]  the eval protocol's sequential queries
//       (with the inter-robot loop beside an own-robot best one unless --best-only), scene by
//       scene:
//   each
//       entry queried against the earlier ones of its scene, then inserted (only scenes whose tag
//       starts with SCENE); prints every loop (diff two runs to compare the loops found) and the
//       query times
//   dtif_query_bench scale DB N...  query time against N entries: all of DB's entries, then
//       perturbed copies of them (as other surveys of the same places); bytes per entry, save
//       and load time, resident memory; each query's time on stderr
//   dtif_query_bench describe EVERY REPEAT DATASET...  descriptor time (extraction + topology +
//       histograms, describeCloud) of every EVERY-th submap: min and median of REPEAT describes
//       after one unmeasured describe (which sizes the thread's workspace)
// The same source builds against an earlier commit (scripts/build_before.sh), so that `dtif
// bench --speed` measures before and after with one instrument: it calls only what that commit
// has too (memoryBytes is optional).
// Query times are the thread's CPU time (a busy machine inflates them less than wall clock;
// still compare two builds in the same conditions); the stage times inside QueryStats, save and
// load are wall clock.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "dtif/baselines/bench.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/describe.h"
#include "dtif/eval/evaluation.h"
#include "dtif/io/config.h"
#include "dtif/io/dataset.h"
#include "proc_status.h"

namespace {

using Clock = std::chrono::steady_clock;
using DescPtr = std::shared_ptr<const dtif::Descriptor>;

double ms(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// This thread's CPU time [ms]: a query's cost even when the machine is busy.
double cpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

/// "<scene>" of .../<scene>/dataset, with the seed folder's suffix (scenes-seed2 -> s2).
std::string sceneTag(const std::string& dir) {
  std::filesystem::path p = std::filesystem::absolute(dir).lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  if (p.filename() == "dataset") p = p.parent_path();
  std::string tag = p.filename().string();
  const std::string parent = p.parent_path().filename().string();
  const auto k = parent.find("-seed");
  tag += k == std::string::npos ? "-s1" : "-s" + parent.substr(k + 5);
  return tag;
}

int collect(const std::string& out, const std::vector<std::string>& dirs) {
  dtif::DtifParams params;
  dtif::LoopDetector all(params.loop);
  for (const std::string& dir : dirs) {
    const std::string tag = sceneTag(dir);
    const dtif::Dataset ds = dtif::readDataset(dir);
    size_t n = 0;
    // The observer's loops are ignored; `auto...` takes them as every build since 7bc3e70
    // passes them (one loop, or the best and an inter-robot one), so that
    // scripts/build_before.sh can build this probe against the earlier commits too.
    dtif::runEvaluation(ds, params, dtif::EvalParams{}, {},
                        [&](const dtif::Descriptor& d, const auto&...) {
                          auto c = std::make_shared<dtif::Descriptor>(d);
                          c->robot = tag + "_" + d.robot;
                          n += all.insert(c);
                        });
    std::fprintf(stderr, "%s: %zu descriptors\n", tag.c_str(), n);
  }
  all.save(out);
  return 0;
}

/// The scene tag of a collected robot name, <scene>-s<seed>_<robot> (scene names hold '_').
std::string sceneOf(const std::string& robot) {
  const size_t seed = robot.rfind("-s");
  return robot.substr(0, robot.find('_', seed == std::string::npos ? 0 : seed));
}

/// LoopDetector::query as the loop closure nodelet calls it: with the inter-robot loop beside an
/// own-robot best one (a build without it, e.g. the commit before it: the best loop only).
template <class D>
auto queryAsOnline(const D& det, const dtif::Descriptor& d, std::optional<dtif::Loop>* inter,
                   bool best_only) -> decltype(det.query(d, nullptr, inter)) {
  return det.query(d, nullptr, best_only ? nullptr : inter);
}
template <class D, class... Ignored>
std::optional<dtif::Loop> queryAsOnline(const D& det, const dtif::Descriptor& d, Ignored...) {
  return det.query(d);
}

int replay(const std::string& db, const std::string& only, bool best_only) {
  dtif::DtifParams params;
  dtif::LoopDetector file(params.loop);
  file.load(db);
  std::map<std::string, std::vector<DescPtr>> scenes;
  std::vector<std::string> order;
  for (const DescPtr& d : file.entries()) {
    const std::string s = sceneOf(d->robot);
    if (s.compare(0, only.size(), only) != 0) continue;
    if (!scenes.count(s)) order.push_back(s);
    scenes[s].push_back(d);
  }
  std::printf("# scene queries loops mean_ms max_ms\n");
  for (const std::string& s : order) {
    dtif::LoopDetector det(params.loop);
    double sum = 0.0, worst = 0.0;
    size_t loops = 0, inter_loops = 0;
    for (const DescPtr& d : scenes[s]) {
      const double t0 = cpuMs();
      std::optional<dtif::Loop> inter;  // asked for as the loop closure nodelet does
      const std::optional<dtif::Loop> lc = queryAsOnline(det, *d, &inter, best_only);
      const double t = cpuMs() - t0;
      sum += t;
      worst = std::max(worst, t);
      if (lc) {
        ++loops;
        const Eigen::Vector3d tr = lc->T_c_q.translation();
        std::printf("loop %s %s/%lld -> %s/%lld t %.4f %.4f %.4f inliers %d score %.4f\n",
                    s.c_str(), d->robot.c_str(), static_cast<long long>(d->submap_id),
                    lc->candidate_robot.c_str(), static_cast<long long>(lc->candidate_id), tr.x(),
                    tr.y(), tr.z(), lc->inliers, lc->score);
      }
      if (inter) {
        ++inter_loops;
        std::printf("inter %s %s/%lld -> %s/%lld score %.4f\n", s.c_str(), d->robot.c_str(),
                    static_cast<long long>(d->submap_id), inter->candidate_robot.c_str(),
                    static_cast<long long>(inter->candidate_id), inter->score);
      }
      det.insert(d);
    }
    std::fprintf(stderr,
                 "%-16s %4zu queries %4zu loops (+%zu inter-robot beside)  query mean %8.3f ms  "
                 "max %8.3f ms\n",
                 s.c_str(), scenes[s].size(), loops, inter_loops, sum / scenes[s].size(), worst);
    std::printf("scene %s %zu %zu %.4f %.4f\n", s.c_str(), scenes[s].size(), loops,
                sum / scenes[s].size(), worst);
  }
  return 0;
}

/// Prints "describe <scene tag> <submap id> <points> <trunks> <min ms> <median ms>" for every
/// every-th submap of each dataset.
int describe(size_t every, int repeat, const std::vector<std::string>& dirs) {
  dtif::DtifParams params;
  for (const std::string& dir : dirs) {
    const std::string tag = sceneTag(dir);
    const dtif::Dataset ds = dtif::readDataset(dir);
    for (size_t i = 0; i < ds.submaps.size(); i += every) {
      const dtif::Cloud::Ptr cloud = dtif::loadSubmapCloud(ds, ds.submaps[i]);
      const auto once = [&] {
        return dtif::describeCloud(*cloud, dtif::SubmapKey{}, params.trunk_extraction,
                                   params.descriptor);
      };
      const size_t trunks = once().trunks.size();
      std::vector<double> t;
      for (int k = 0; k < repeat; ++k) {
        const double t0 = cpuMs();
        once();
        t.push_back(cpuMs() - t0);
      }
      std::sort(t.begin(), t.end());
      std::printf("describe %s %lld %zu %zu %.4f %.4f\n", tag.c_str(),
                  static_cast<long long>(ds.submaps[i].id), cloud->size(), trunks, t.front(),
                  t[t.size() / 2]);
      std::fflush(stdout);
    }
  }
  return 0;
}

/// LoopDetector::memoryBytes per entry (a build without it, e.g. the commit before it: "-").
template <class D>
auto memoryPerEntry(const D& det) -> decltype(det.memoryBytes(), std::string()) {
  return std::to_string(det.memoryBytes() / std::max<size_t>(1, det.size()));
}
template <class D, class... Ignored>
std::string memoryPerEntry(const D&, Ignored...) {
  return "-";
}

/// QueryStats::lattice_searches, -1 for a build without it (the "before" probe's).
template <class S>
auto latticeSearches(const S& s) -> decltype(static_cast<long long>(s.lattice_searches)) {
  return static_cast<long long>(s.lattice_searches);
}
template <class S, class... Ignored>
long long latticeSearches(const S&, Ignored...) {
  return -1;
}

/// The database's entries, then perturbed copies of them (other robots) up to n.
std::vector<DescPtr> fill(const std::vector<DescPtr>& real, size_t n,
                          const dtif::DtifParams& params) {
  std::vector<DescPtr> out(real.begin(), real.begin() + std::min(n, real.size()));
  for (size_t k = 0; out.size() < n && k < 4 * n; ++k) {
    auto d = std::make_shared<dtif::Descriptor>(dtif::baselines::perturbedCopy(
        *real[k % real.size()], static_cast<uint32_t>(1000 + k), params.descriptor));
    if (!d->valid) continue;
    const dtif::Descriptor& src = *real[k % real.size()];
    d->robot = "copy" + std::to_string(k / real.size()) + "_" + src.robot;
    d->submap_id = src.submap_id;
    d->stamp = src.stamp;
    out.push_back(d);
  }
  return out;
}

int scale(const std::string& db, const std::vector<size_t>& sizes) {
  dtif::DtifParams params;
  dtif::LoopDetector file(params.loop);
  file.load(db);
  const std::vector<DescPtr>& real = file.entries();
  if (real.empty()) throw std::runtime_error(db + ": no entries to scale from");
  std::vector<DescPtr> queries;  // 24 real entries spread over the file
  const size_t step = std::max<size_t>(1, real.size() / 24);
  for (size_t i = step / 2; i < real.size(); i += step) queries.push_back(real[i]);
  std::printf(
      "| Database | Query ms mean | median | max | Screening ms | Correspondences ms | Solver ms "
      "| Verification ms | Matched | Loops | Memory bytes/entry | File bytes/entry | Save s | Load "
      "s | RSS MiB |\n"
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (size_t size : sizes) {
    const std::vector<DescPtr> entries = fill(real, size, params);
    dtif::LoopDetector det(params.loop);
    for (const DescPtr& d : entries) det.insert(d);
    std::vector<double> t;
    double screen = 0, match = 0, solver = 0, verify = 0, matched = 0;
    size_t loops = 0;
    for (const DescPtr& q : queries) {
      dtif::QueryStats qs;
      const double t0 = cpuMs();
      const bool found = det.query(*q, &qs).has_value();
      loops += found;
      t.push_back(cpuMs() - t0);
      std::fprintf(stderr,
                   "query %zu %s/%lld %.3f ms matched %zu loop %d (correspondences %.3f, solver "
                   "%.3f, verification %.3f ms; %lld lattice searches)\n",
                   size, q->robot.c_str(), static_cast<long long>(q->submap_id), t.back(),
                   qs.matched, static_cast<int>(found), qs.match_ms, qs.solver_ms, qs.verify_ms,
                   latticeSearches(qs));
      screen += qs.screen_ms, match += qs.match_ms, solver += qs.solver_ms;
      verify += qs.verify_ms, matched += static_cast<double>(qs.matched);
    }
    const std::string path = db + ".scale.tmp";
    auto t0 = Clock::now();
    det.save(path);
    const double save_s = ms(t0) / 1000.0;
    const double bytes = static_cast<double>(std::filesystem::file_size(path));
    dtif::LoopDetector back(params.loop);
    t0 = Clock::now();
    back.load(path);
    const double load_s = ms(t0) / 1000.0;
    std::filesystem::remove(path);
    const double k = 1.0 / static_cast<double>(t.size());
    std::vector<double> sorted = t;
    std::sort(sorted.begin(), sorted.end());
    std::printf(
        "| %zu | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.1f | %zu | %s | %.0f | %.3f | "
        "%.3f "
        "| %.0f |\n",
        det.size(), std::accumulate(t.begin(), t.end(), 0.0) * k, sorted[sorted.size() / 2],
        sorted.back(), screen * k, match * k, solver * k, verify * k, matched * k, loops,
        memoryPerEntry(det).c_str(), bytes / det.size(), save_s, load_s, dtif::procMiB("VmRSS"));
    std::fflush(stdout);
  }
  std::printf("peak RSS (VmHWM) %.0f MiB\n", dtif::procMiB("VmHWM"));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string usage =
      "usage: dtif_query_bench collect OUT.db DATASET... | replay DB [SCENE] [--best-only] |\n"
      "       scale DB N... | describe EVERY REPEAT DATASET...\n";
  if (argc < 3) {
    std::fputs(usage.c_str(), stderr);
    return 2;
  }
  const std::string mode = argv[1];
  try {
    if (mode == "collect" && argc >= 4) {
      return collect(argv[2], std::vector<std::string>(argv + 3, argv + argc));
    }
    if (mode == "describe" && argc >= 5) {
      return describe(std::max<size_t>(1, std::stoul(argv[2])), std::max(1, std::stoi(argv[3])),
                      std::vector<std::string>(argv + 4, argv + argc));
    }
    if (mode == "replay" && argc >= 3) {
      // --best-only: without the inter-robot loop beside an own-robot best one (its cost apart)
      std::vector<std::string> rest(argv + 3, argv + argc);
      const auto flag = std::find(rest.begin(), rest.end(), "--best-only");
      const bool best_only = flag != rest.end();
      if (best_only) rest.erase(flag);
      return replay(argv[2], rest.empty() ? "" : rest.front(), best_only);
    }
    if (mode == "scale") {
      std::vector<size_t> sizes;
      for (int i = 3; i < argc; ++i) sizes.push_back(std::stoul(argv[i]));
      if (sizes.empty()) sizes = {1000, 5000, 10000, 20000};
      return scale(argv[2], sizes);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "dtif_query_bench: %s\n", e.what());
    return 1;
  }
  std::fputs(usage.c_str(), stderr);
  return 2;
}
