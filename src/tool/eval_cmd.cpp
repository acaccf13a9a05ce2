// dtif eval <dataset_dir> --out <dir> [--config params.yaml] [--unit-weights]
// The evaluation protocol of DATASET.md; writes results.csv, summary.json, table.md and the
// effective parameters (params.yaml) into the output folder; misses.csv says why each query
// with a true loop missed it (its best ground-truth candidate matched alone).
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>

#include "commands.h"
#include "dtif/eval/evaluation.h"

namespace dtif::tool {

void writeEvalFiles(const std::string& out, const EvalResult& res, const std::string& table,
                    const DtifParams& params) {
  std::error_code ec;
  std::filesystem::create_directories(out, ec);
  if (ec) throw DatasetError(out + ": cannot create output folder: " + ec.message());
  const std::filesystem::path dir(out);
  writeResultsCsv((dir / "results.csv").string(), res.rows);
  writeSummaryJson((dir / "summary.json").string(), res.summary);
  std::ofstream t(dir / "table.md");
  t << table;
  std::ofstream p(dir / "params.yaml");
  p << paramsToYaml(params);
  t.close();
  p.close();
  if (!t || !p) throw DatasetError(out + ": write failed");
}

// Levelling (when enabled): levelling.csv, and the per-robot errors on stdout and in table.md.
void printLevelling(const std::filesystem::path& dir, const EvalResult& res) {
  if (res.levelling.empty()) return;
  writeLevellingCsv((dir / "levelling.csv").string(), res.levelling);
  const std::string table = formatLevelling(summarizeLevelling(res.levelling));
  std::cout << "levelling per robot (levelling.csv):\n" << table;
  std::ofstream t(dir / "table.md", std::ios::app);
  t << "\n" << table;
  if (!t) throw DatasetError((dir / "table.md").string() + ": write failed");
}

// How many submaps multi_submap described with their predecessors' stems (very sparse stands).
void printMultiSubmap(const std::vector<EvalRow>& rows) {
  size_t n = 0, trunks = 0, submaps = 0, updates = 0;
  for (const EvalRow& r : rows) {
    updates += r.forward_updates;
    if (r.described_submaps <= 1) continue;
    ++n, trunks += r.described_trunks, submaps += static_cast<size_t>(r.described_submaps);
  }
  if (n == 0) return;
  const double k = 1.0 / static_cast<double>(n);
  std::cout << std::fixed << std::setprecision(1) << "multi_submap: " << n << " of " << rows.size()
            << " submaps described with earlier submaps' stems, " << static_cast<double>(trunks) * k
            << " trunks from " << static_cast<double>(submaps) * k << " submaps on average";
  if (updates > 0) std::cout << "; " << updates << " database entries described again forward";
  std::cout << "\n";
}

int runEval(const EvalArgs& a) {
  DtifParams params = loadParams(a.configs);
  if (a.unit_weights) params.loop.pose.unit_weights = true;

  const Dataset ds = readDataset(a.dataset);
  const bool quiet = a.quiet;
  const EvalResult res = runEvaluation(ds, params, EvalParams{}, [&](size_t i, size_t n) {
    if (!quiet && (i % 10 == 0 || i == n)) {
      std::cerr << "\rdtif eval: " << i << "/" << n << " submaps" << std::flush;
      if (i == n) std::cerr << "\n";
    }
  });

  // Results are written only once the whole run succeeded: no partial output.
  const std::string method = !a.method.empty()               ? a.method
                             : params.loop.pose.unit_weights ? "dtif (unit weights)"
                                                             : "dtif";
  const std::string table = formatTable(res.summary, method);
  writeEvalFiles(a.out, res, table, params);
  const std::filesystem::path dir(a.out);
  writeMissesCsv((dir / "misses.csv").string(), res.misses);
  std::cout << "dataset " << ds.root << ": " << res.summary.submaps << " submaps\n" << table;
  std::cout << "descriptor bytes: mean " << std::lround(res.summary.descriptor_bytes_mean)
            << ", max " << res.summary.descriptor_bytes_max << " (encoded; budget "
            << params.descriptor.max_bytes << ", descriptor/max_bytes)\n";
  if (res.summary.inter_robot_extra > 0) {
    std::cout << "inter-robot loops beside an own-robot best loop (for the map merge, not scored "
                 "above): "
              << res.summary.inter_robot_extra << ", " << res.summary.inter_robot_extra_true
              << " true positives\n";
  }
  printLevelling(dir, res);
  printMultiSubmap(res.rows);
  if (!res.detection.empty()) {
    writeDetectionCsv((dir / "detection.csv").string(), res.detection);
    double pts = 0, vis = 0, tr = 0, on = 0, found = 0, seen = 0, r_sum = 0, z_sum = 0;
    for (const DetectionRow& d : res.detection) {
      pts += d.points, vis += d.visible_stems, tr += d.trunks, on += d.trunks_on_stems;
      found += d.visible_found, seen += d.bases_seen;
      r_sum += d.radius_mae_m * d.trunks_on_stems, z_sum += d.base_mae_m * d.bases_seen;
    }
    const double n = static_cast<double>(res.detection.size());
    std::cout << std::fixed << std::setprecision(1)
              << "trunks vs stems.csv, per submap: " << pts / n << " points, " << vis / n
              << " visible stems, " << tr / n << " trunks (" << on / n << " on stems), "
              << (vis > 0 ? 100.0 * found / vis : 0.0) << " % of visible stems found; radius MAE "
              << std::setprecision(3) << (on > 0 ? r_sum / on : 0.0) << " m; "
              << std::setprecision(1) << (on > 0 ? 100.0 * seen / on : 0.0)
              << " % bases seen, their z MAE " << std::setprecision(3)
              << (seen > 0 ? z_sum / seen : 0.0) << " m (detection.csv)\n";
  }
  return 0;
}

}  // namespace dtif::tool
