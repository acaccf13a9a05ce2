// dtif eval <dataset_dir> --out <dir> [--config params.yaml] [--unit-weights]
// The evaluation protocol of DATASET.md; writes results.csv, summary.json, table.md and the
// effective parameters (params.yaml) into the output folder.
#include <filesystem>
#include <fstream>
#include <iostream>

#include "commands.h"
#include "dtif/core/evaluation.h"
#include "options.h"

namespace dtif::tool {

int runEval(const Args& args) {
  const Options o = parseOptions(args, {"out", "config", "method"}, {"unit-weights", "quiet"});
  if (o.positional.size() != 1) throw UsageError{"expected one dataset folder"};
  const auto out = o.get("out");
  if (!out) throw UsageError{"--out <dir> is required"};
  DtifParams params = loadParams(o);
  if (o.has("unit-weights")) params.loop.pose.unit_weights = true;

  const Dataset ds = readDataset(o.positional[0]);
  const bool quiet = o.has("quiet");
  const EvalResult res = runEvaluation(ds, params, EvalParams{}, [&](size_t i, size_t n) {
    if (!quiet && (i % 10 == 0 || i == n)) {
      std::cerr << "\rdtif eval: " << i << "/" << n << " submaps" << std::flush;
      if (i == n) std::cerr << "\n";
    }
  });

  // Results are written only once the whole run succeeded: no partial output.
  std::error_code ec;
  std::filesystem::create_directories(*out, ec);
  if (ec) throw DatasetError(*out + ": cannot create output folder: " + ec.message());
  const std::filesystem::path dir(*out);
  writeResultsCsv((dir / "results.csv").string(), res.rows);
  writeSummaryJson((dir / "summary.json").string(), res.summary);
  const std::string method =
      o.get("method").value_or(params.loop.pose.unit_weights ? "dtif (unit weights)" : "dtif");
  const std::string table = formatTable(res.summary, method);
  {
    std::ofstream t(dir / "table.md");
    t << table;
    std::ofstream p(dir / "params.yaml");
    p << paramsToYaml(params);
    if (!t || !p) throw DatasetError(*out + ": write failed");
  }
  std::cout << "dataset " << ds.root << ": " << res.summary.submaps << " submaps\n" << table;
  return 0;
}

}  // namespace dtif::tool
