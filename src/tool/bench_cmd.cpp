// dtif bench <dataset_dir>... --out <dir> [--config params.yaml] [--back-ends a,b,...]
//            [--no-front-ends] [--no-scaling] [--no-pr] [--no-scan-context]
//            [--scaling-sizes 10,20,...] [--speed | --speed-only] [--before-probe <file>]
//            [--speed-sizes 1000,5000,...] [--speed-every n]
// Issue #5: dtif against the paper's baselines on the protocol of DATASET.md. Writes
// summary.csv (one row per scene and method), tables.md (front ends, back ends and place
// recognition, per scene and over all scenes), pr.csv, place_recognition.csv, submaps.csv,
// scaling.csv, each method's results.csv and scan context's answers (<scene>/scan_context.csv);
// with --speed, issue #18's speed tables (speed.md, bench_speed.h).
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>

#include "bench_speed.h"
#include "commands.h"
#include "dtif/baselines/bench.h"

namespace dtif::tool {
namespace {

/// A dataset folder `<scene>/dataset` is named after <scene>, any other after itself.
std::string sceneName(const std::string& dir) {
  std::filesystem::path p = std::filesystem::path(dir).lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  if (p.filename() == "dataset" && p.has_parent_path()) return p.parent_path().filename().string();
  return p.filename().string();
}

std::string slug(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (std::isalnum(static_cast<unsigned char>(c))) {
      out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    } else if (!out.empty() && out.back() != '_') {
      out += '_';
    }
  }
  while (!out.empty() && out.back() == '_') out.pop_back();
  return out;
}

void summaryCsvRow(std::ostream& os, const std::string& scene, const std::string& table,
                   const std::string& method, const EvalSummary& s) {
  auto opt = [&](const std::optional<double>& v) {
    if (v) os << *v;
    os << ',';
  };
  os << scene << ',' << table << ",\"" << method << "\",";
  const auto& e = s.mean_err_all;
  for (double PoseError::*m :
       {&PoseError::roll_deg, &PoseError::pitch_deg, &PoseError::yaw_deg, &PoseError::rot_deg,
        &PoseError::x_m, &PoseError::y_m, &PoseError::z_m, &PoseError::trans_m}) {
    if (e) os << (*e).*m;
    os << ',';
  }
  opt(s.rmse_rot_deg);
  opt(s.rmse_trans_m);
  os << s.t_desc_ms << ',' << s.t_loop_ms << ',' << s.t_total_ms << ',' << s.t_solver_ms << ',';
  opt(s.precision);
  opt(s.recall);
  os << s.true_positives << ',' << s.accepted << ',' << s.queries_with_loop << ','
     << s.descriptor_bytes_mean << '\n';
}

/// One place-recognition summary as a place_recognition.csv row.
void placeCsvRow(std::ostream& place, const std::string& scene, const std::string& method,
                 const baselines::PlaceRecognitionSummary& s) {
  place << scene << ",\"" << method << "\",";
  auto opt = [&](const std::optional<double>& v) {
    if (v) place << *v;
    place << ',';
  };
  opt(s.precision);
  opt(s.recall);
  place << s.correct << ',' << s.answers << ',' << s.queries_with_loop << ',';
  opt(s.yaw_err_deg);
  opt(s.yaw_err_median_deg);
  place << s.t_desc_ms << ',' << s.t_query_ms << ',' << s.bytes_mean << '\n';
}

/// The CSV files that gather every scene's rows (and the "all" rows), headers written on
/// opening so that each scene appends its rows as soon as it has run.
struct BenchCsvs {
  explicit BenchCsvs(const std::filesystem::path& dir)
      : summary(dir / "summary.csv"),
        pr(dir / "pr.csv"),
        subs(dir / "submaps.csv"),
        place(dir / "place_recognition.csv") {
    summary << std::setprecision(6)
            << "scene,table,method,roll_deg,pitch_deg,yaw_deg,rot_deg,x_m,y_m,z_m,trans_m,"
               "rmse_rot_deg,rmse_trans_m,desc_ms,loop_ms,total_ms,solver_ms,precision,recall,"
               "true_positives,accepted,queries_with_loop,bytes\n";
    pr << "scene,method,threshold,accepted,true_positives,precision,recall\n";
    subs << "scene,id,points,trunks,bytes,t_extract_ms,t_desc_ms,t_loop_ms,fpfh_points,t_fpfh_ms,"
            "t_scan_context_ms\n";
    place << std::setprecision(6)
          << "scene,method,precision,recall,correct,answers,queries_with_loop,yaw_err_deg,"
             "yaw_err_median_deg,desc_ms,query_ms,bytes\n";
  }
  bool good() const { return summary && pr && subs && place; }

  std::ofstream summary, pr, subs, place;
};

/// A scene's submaps.csv rows: sizes and stage times per submap.
void writeSubmapRows(std::ostream& subs, const std::string& scene,
                     const baselines::SceneBench& sb) {
  // dtif's own loop time per submap is the "dtif (weighted) + dtif refinement" run's.
  const baselines::MethodRun* dtif_run = nullptr;
  for (const auto& run : sb.runs) {
    if (run.method == "dtif (weighted) + dtif refinement") dtif_run = &run;
  }
  for (size_t i = 0; i < sb.submaps.size(); ++i) {
    const auto& st = sb.submaps[i];
    subs << scene << ',' << st.id << ',' << st.points << ',' << st.trunks << ',' << st.bytes << ','
         << st.t_extract_ms << ',' << st.t_desc_ms << ','
         << (dtif_run ? dtif_run->rows[i].t_loop_ms : 0.0) << ',' << st.fpfh_points << ','
         << st.t_fpfh_ms << ',' << st.t_scan_context_ms << '\n';
  }
}

/// A scene's rows in the shared CSVs, and its own files in <out>/<scene>/: each method's
/// results and scan context's answers.
void writeSceneOutputs(BenchCsvs* csvs, const std::filesystem::path& dir, const std::string& scene,
                       const baselines::SceneBench& sb) {
  const std::filesystem::path sdir = dir / scene;
  std::filesystem::create_directories(sdir);
  for (const auto& run : sb.runs) {
    summaryCsvRow(csvs->summary, scene, run.table, run.method, run.summary);
    writeResultsCsv((sdir / ("results_" + run.table + "_" + slug(run.method) + ".csv")).string(),
                    run.rows);
  }
  for (const auto& p : sb.pr) {
    csvs->pr << scene << ",\"" << p.method << "\"," << p.threshold << ',' << p.accepted << ','
             << p.true_positives << ',' << p.precision << ',' << p.recall << '\n';
  }
  writeSubmapRows(csvs->subs, scene, sb);
  for (const auto& run : sb.place) {
    placeCsvRow(csvs->place, scene, run.method,
                baselines::summarizePlaceRecognition(run.rows, run.bytes_sum));
    if (run.method == "scan context") {
      writeResultsCsv((sdir / "scan_context.csv").string(), run.rows);
    }
  }
}

/// Runs the bench on one dataset folder, with its progress on one terminal line, and writes
/// its outputs.
baselines::SceneBench benchScene(const std::string& path, const DtifParams& params,
                                 const baselines::BenchOptions& opt,
                                 const std::filesystem::path& dir, BenchCsvs* csvs) {
  const Dataset ds = readDataset(path);
  const std::string scene = sceneName(path);
  baselines::SceneBench sb =
      baselines::runSceneBench(ds, scene, params, opt, [&](const std::string& s) {
        std::cerr << "\rdtif bench " << scene << ": " << s << "\033[K";
      });
  std::cerr << "\n";
  writeSceneOutputs(csvs, dir, scene, sb);
  return sb;
}

/// One method's rows and weighted times over all scenes, summarised once for "all scenes".
struct MethodTotals {
  std::vector<EvalRow> rows;
  double bytes = 0.0, loop_w = 0.0, solver_w = 0.0, evaluated = 0.0;
};

EvalSummary allScenesSummary(const MethodTotals& t) {
  EvalSummary s = summarizeRows(t.rows, "all", t.bytes);
  if (t.evaluated > 0) {
    s.t_loop_ms = t.loop_w / t.evaluated;
    s.t_solver_ms = t.solver_w / t.evaluated;
    s.t_total_ms = s.t_desc_ms + s.t_loop_ms;
  }
  return s;
}

/// The front-end or back-end table (`table`): per scene, then all scenes together (rows
/// concatenated, summarised once; also summary.csv's "all" rows).
void appendRegistrationTable(std::ostream& md, std::ostream& summary,
                             const std::vector<baselines::SceneBench>& scenes,
                             const std::string& table) {
  const bool front_end = table == "front_end";
  md << (front_end
             ? "### Front ends (same pairs: each query with a loop vs its most and least "
               "overlapping eligible submap)\n\n"
             : "### Back ends on dtif's correspondences (sequential protocol, DATASET.md)\n\n");
  std::vector<std::string> order;
  std::map<std::string, MethodTotals> totals;
  md << baselines::tableHeader("Scene / method");
  for (const auto& sb : scenes) {
    for (const auto& run : sb.runs) {
      if (run.table != table) continue;
      md << baselines::tableRow(run.summary, sb.scene + ": " + run.method);
      if (!totals.count(run.method)) order.push_back(run.method);
      MethodTotals& t = totals[run.method];
      t.rows.insert(t.rows.end(), run.rows.begin(), run.rows.end());
      t.bytes += run.summary.descriptor_bytes_mean * run.summary.submaps;
      // Front ends time per registered query (queries with a loop).
      const double w = front_end ? run.summary.queries_with_loop : run.summary.submaps;
      t.loop_w += run.summary.t_loop_ms * w;
      t.solver_w += run.summary.t_solver_ms * w;
      t.evaluated += w;
    }
  }
  for (const auto& method : order) {
    const EvalSummary s = allScenesSummary(totals[method]);
    md << baselines::tableRow(s, "**all scenes: " + method + "**");
    summaryCsvRow(summary, "all", table, method, s);
  }
  md << "\n";
}

/// The place-recognition table: per scene, then all scenes together (also
/// place_recognition.csv's "all" rows).
void appendPlaceRecognitionTable(std::ostream& md, std::ostream& place,
                                 const std::vector<baselines::SceneBench>& scenes) {
  md << "### Place recognition (sequential protocol; an answer is correct when its pair is a "
        "true loop, whatever its pose error)\n\n"
     << baselines::placeRecognitionHeader("Scene / method");
  std::vector<std::string> order;
  std::map<std::string, std::vector<EvalRow>> all_rows;
  std::map<std::string, double> all_bytes;
  for (const auto& sb : scenes) {
    for (const auto& run : sb.place) {
      md << baselines::placeRecognitionRow(
          baselines::summarizePlaceRecognition(run.rows, run.bytes_sum),
          sb.scene + ": " + run.method);
      if (!all_rows.count(run.method)) order.push_back(run.method);
      all_rows[run.method].insert(all_rows[run.method].end(), run.rows.begin(), run.rows.end());
      all_bytes[run.method] += run.bytes_sum;
    }
  }
  for (const auto& method : order) {
    const auto s = baselines::summarizePlaceRecognition(all_rows[method], all_bytes[method]);
    md << baselines::placeRecognitionRow(s, "**all scenes: " + method + "**");
    placeCsvRow(place, "all", method, s);
  }
  md << "\n";
}

/// Query time vs database size: scaling.csv and its table. The queries are about 24
/// descriptors spread over the pool, so that the run stays short whatever the scenes.
void appendScaling(std::ostream& md, const std::filesystem::path& dir,
                   const std::vector<std::shared_ptr<const Descriptor>>& pool,
                   const DtifParams& params, const std::vector<size_t>& sizes) {
  std::cerr << "dtif bench: query time vs database size\n";
  std::vector<std::shared_ptr<const Descriptor>> queries;
  const size_t step = std::max<size_t>(1, pool.size() / 24);
  for (size_t i = 0; i < pool.size(); i += step) queries.push_back(pool[i]);
  const auto pts = baselines::runScaling(pool, queries, params, sizes);
  std::ofstream sc(dir / "scaling.csv");
  sc << "db_size,indexed,query_ms,screen_ms,match_ms,solver_ms,screened_in\n";
  md << "### Query time vs database size (" << queries.size()
     << " queries; database of perturbed copies of all scenes' descriptors)\n\n"
     << "| Database | Query ms | Screening ms | Correspondences ms | Solver ms | Screened in |\n"
     << "|---|---|---|---|---|---|\n"
     << std::fixed << std::setprecision(3);
  for (const auto& p : pts) {
    sc << p.db_size << ',' << p.indexed << ',' << p.query_ms << ',' << p.screen_ms << ','
       << p.match_ms << ',' << p.solver_ms << ',' << p.screened_in << '\n';
    md << "| " << p.db_size << " | " << p.query_ms << " | " << p.screen_ms << " | " << p.match_ms
       << " | " << p.solver_ms << " | " << std::setprecision(1) << p.screened_in
       << std::setprecision(3) << " |\n";
  }
  md << "\n";
}

baselines::BenchOptions benchOptions(const BenchArgs& a) {
  baselines::BenchOptions opt;
  opt.back_ends = a.back_ends;
  opt.front_ends = !a.no_front_ends;
  opt.pr_curve = !a.no_pr;
  opt.place_recognition = !a.no_scan_context;
  return opt;
}

}  // namespace

/// The speed section into <dir>/speed.md (and md).
void benchSpeed(const BenchArgs& a, const std::filesystem::path& dir, std::ostream& md) {
  SpeedOptions o;
  o.after_probe = siblingProbe();
  o.before_probe = a.before_probe;
  o.sizes = a.speed_sizes;
  o.every = a.speed_every;
  const std::string section = appendSpeed(md, dir, a.datasets, o);
  std::ofstream(dir / "speed.md") << section;
}

int runBench(const BenchArgs& a) {
  const std::filesystem::path dir(a.out);
  std::filesystem::create_directories(dir);
  if (a.speed_only) {
    std::ostringstream md;
    benchSpeed(a, dir, md);
    std::cout << md.str();
    return 0;
  }
  const DtifParams params = loadParams(a.configs);
  const baselines::BenchOptions opt = benchOptions(a);
  BenchCsvs csvs(dir);

  std::vector<baselines::SceneBench> scenes;
  std::vector<std::shared_ptr<const Descriptor>> pool;  // every scene's valid descriptors
  for (const std::string& path : a.datasets) {
    baselines::SceneBench sb = benchScene(path, params, opt, dir, &csvs);
    pool.insert(pool.end(), sb.descriptors.begin(), sb.descriptors.end());
    scenes.push_back(std::move(sb));
  }

  // The tables come after every scene has run: their "all scenes" rows need all of them.
  std::ostringstream md;
  for (const std::string table : {"front_end", "back_end"}) {
    appendRegistrationTable(md, csvs.summary, scenes, table);
  }
  if (opt.place_recognition) appendPlaceRecognitionTable(md, csvs.place, scenes);
  if (!a.no_scaling && !pool.empty()) appendScaling(md, dir, pool, params, a.scaling_sizes);
  if (a.speed) benchSpeed(a, dir, md);
  std::ofstream(dir / "tables.md") << md.str();
  std::cout << md.str();
  if (!csvs.good()) throw DatasetError(a.out + ": write failed");
  return 0;
}

}  // namespace dtif::tool
