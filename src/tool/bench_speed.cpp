// dtif bench --speed: descriptor and query time, before and after, measured by one instrument.
// The instrument is the speed probe dtif_query_bench (src/tool/query_bench.cpp): this build's
// (next to the dtif binary) and, with --before-probe, the same source built against an earlier
// commit (scripts/build_before.sh). Both run the same steps on the same inputs, one after the
// other per step, so that the machine's load falls on both alike; the ratio is after / before.
#include "bench_speed.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <stdexcept>

namespace dtif::tool {
namespace {

namespace fs = std::filesystem;

std::string quoted(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

/// Runs probe with args; returns its stdout lines (its stderr, the progress, goes to ours).
std::vector<std::string> runProbe(const std::string& probe, const std::vector<std::string>& args) {
  std::string cmd = quoted(probe);
  for (const std::string& a : args) cmd += " " + quoted(a);
  std::cerr << "dtif bench --speed: " << cmd << "\n";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) throw std::runtime_error(probe + ": cannot start");
  std::vector<std::string> lines;
  std::string line;
  for (int c; (c = std::fgetc(p)) != EOF;) {
    if (c != '\n') {
      line += static_cast<char>(c);
    } else {
      lines.push_back(line);
      line.clear();
    }
  }
  if (!line.empty()) lines.push_back(line);
  const int status = pclose(p);
  if (status != 0) {
    throw std::runtime_error(probe + " " + (args.empty() ? "" : args[0]) + ": exit status " +
                             std::to_string(status));
  }
  return lines;
}

std::vector<std::string> words(const std::string& line, char sep = ' ') {
  std::vector<std::string> out;
  std::istringstream is(line);
  for (std::string w; std::getline(is, w, sep);) {
    w.erase(0, w.find_first_not_of(' '));
    w.erase(w.find_last_not_of(' ') + 1);
    if (!w.empty()) out.push_back(w);
  }
  return out;
}

/// "describe <tag> <id> <points> <trunks> <min ms> <median ms>" lines of one build.
struct DescribeRow {
  std::string scene;
  long long id = 0;
  double points = 0, trunks = 0, min_ms = 0, median_ms = 0;
};

/// "scene <tag> <queries> <loops> <mean ms> <max ms>" lines, and the loops printed before them.
struct ReplayScene {
  std::string scene;
  double queries = 0, loops = 0, mean_ms = 0, max_ms = 0;
};

/// One row of the probe's scale table, and the process's peak RSS after it.
struct ScaleRow {
  std::vector<std::string> cells;  // as printed: see kScaleColumns
  double peak_mib = 0;
};
const std::vector<std::string> kScaleColumns = {"db_size",
                                                "mean_ms",
                                                "median_ms",
                                                "max_ms",
                                                "screen_ms",
                                                "match_ms",
                                                "solver_ms",
                                                "verify_ms",
                                                "matched",
                                                "loops",
                                                "memory_bytes_per_entry",
                                                "file_bytes_per_entry",
                                                "save_s",
                                                "load_s",
                                                "rss_mib"};

/// What one build measured.
struct BuildSpeed {
  std::string probe;
  std::vector<DescribeRow> describe;
  std::vector<ReplayScene> replay;
  std::vector<std::string> loops;  // the replay's "loop ..." lines, for comparison
  std::vector<ScaleRow> scale;
};

void describeDataset(BuildSpeed* b, const std::string& dataset, const SpeedOptions& o) {
  for (const std::string& l : runProbe(
           b->probe, {"describe", std::to_string(o.every), std::to_string(o.repeat), dataset})) {
    const auto w = words(l);
    if (w.size() != 7 || w[0] != "describe") continue;
    b->describe.push_back({w[1], std::stoll(w[2]), std::stod(w[3]), std::stod(w[4]),
                           std::stod(w[5]), std::stod(w[6])});
  }
}

void replay(BuildSpeed* b, const std::string& db) {
  for (const std::string& l : runProbe(b->probe, {"replay", db})) {
    const auto w = words(l);
    if (!w.empty() && w[0] == "loop") b->loops.push_back(l);
    if (w.size() != 6 || w[0] != "scene") continue;
    b->replay.push_back({w[1], std::stod(w[2]), std::stod(w[3]), std::stod(w[4]), std::stod(w[5])});
  }
}

void scale(BuildSpeed* b, const std::string& db, size_t n) {
  ScaleRow row;
  for (const std::string& l : runProbe(b->probe, {"scale", db, std::to_string(n)})) {
    if (l.rfind("| ", 0) == 0 && l.size() > 2 && std::isdigit(static_cast<unsigned char>(l[2]))) {
      row.cells = words(l, '|');
    } else if (l.rfind("peak RSS (VmHWM) ", 0) == 0) {
      row.peak_mib = std::stod(l.substr(17));
    }
  }
  if (row.cells.size() != kScaleColumns.size()) {
    throw std::runtime_error(b->probe + " scale " + std::to_string(n) + ": no table row");
  }
  b->scale.push_back(row);
}

double cell(const ScaleRow& r, const std::string& column) {
  const auto it = std::find(kScaleColumns.begin(), kScaleColumns.end(), column);
  const std::string& s = r.cells.at(static_cast<size_t>(it - kScaleColumns.begin()));
  return s == "-" ? 0.0 : std::stod(s);
}

/// Per scene: submaps, mean points, mean of the per-submap minimum describe time.
struct SceneDescribe {
  double submaps = 0, points = 0, ms = 0;
};
std::map<std::string, SceneDescribe> byScene(const std::vector<DescribeRow>& rows,
                                             double min_points = 0) {
  std::map<std::string, SceneDescribe> out;
  for (const DescribeRow& r : rows) {
    if (r.points < min_points) continue;
    SceneDescribe& s = out[min_points > 0 ? "all" : r.scene];
    s.submaps += 1, s.points += r.points, s.ms += r.min_ms;
  }
  for (auto& [scene, s] : out) s.points /= s.submaps, s.ms /= s.submaps;
  return out;
}

/// v with p decimals; "-" when there is no measurement (v <= 0).
std::string num(double v, int p) {
  if (!(v > 0)) return "-";
  std::ostringstream os;
  os << std::fixed << std::setprecision(p) << v;
  return os.str();
}

std::string ratio(double after, double before) { return before > 0 ? num(after / before, 2) : "-"; }

void writeDescribeCsv(const fs::path& path, const BuildSpeed& after, const BuildSpeed* before) {
  std::ofstream os(path);
  os << "build,scene,submap,points,trunks,min_ms,median_ms\n";
  for (const BuildSpeed* b : {before, &after}) {
    if (!b) continue;
    for (const DescribeRow& r : b->describe) {
      os << (b == &after ? "after" : "before") << ',' << r.scene << ',' << r.id << ',' << r.points
         << ',' << r.trunks << ',' << r.min_ms << ',' << r.median_ms << '\n';
    }
  }
}

void writeScaleCsv(const fs::path& path, const BuildSpeed& after, const BuildSpeed* before) {
  std::ofstream os(path);
  os << "build";
  for (const std::string& c : kScaleColumns) os << ',' << c;
  os << ",peak_rss_mib\n";
  for (const BuildSpeed* b : {before, &after}) {
    if (!b) continue;
    for (const ScaleRow& r : b->scale) {
      os << (b == &after ? "after" : "before");
      for (const std::string& c : r.cells) os << ',' << (c == "-" ? "" : c);
      os << ',' << r.peak_mib << '\n';
    }
  }
}

void describeTable(std::ostream& md, const BuildSpeed& after, const BuildSpeed* before) {
  md << "### Descriptor (extraction + topology + histograms), thread CPU ms per submap\n\n"
     << "Mean over the submaps of each one's fastest describe. Target: <= 25 ms at ~1 M "
        "points.\n\n"
     << "| Scene | Submaps | Points | Before ms | After ms | After / before |\n"
     << "|---|---|---|---|---|---|\n";
  const auto a = byScene(after.describe), a1 = byScene(after.describe, 9e5);
  const auto b = before ? byScene(before->describe) : decltype(a){};
  const auto b1 = before ? byScene(before->describe, 9e5) : decltype(a){};
  const auto row = [&](const std::string& name, const SceneDescribe& s, const auto& old,
                       const std::string& key) {
    const double bms = old.count(key) ? old.at(key).ms : 0.0;
    md << "| " << name << " | " << s.submaps << " | " << num(s.points, 0) << " | " << num(bms, 1)
       << " | " << num(s.ms, 1) << " | " << ratio(s.ms, bms) << " |\n";
  };
  for (const auto& [scene, s] : a) row(scene, s, b, scene);
  for (const auto& [scene, s] : a1) row("**submaps of >= 0.9 M points**", s, b1, scene);
  md << "\n";
}

void replayTable(std::ostream& md, const BuildSpeed& after, const BuildSpeed* before) {
  md << "### Loop query in the evaluation protocol (each submap against the earlier ones of its "
        "dataset), thread CPU ms per query\n\n"
     << "| Dataset | Queries | Loops before | Loops after | Before mean ms | After mean ms | "
        "After / before | Before max ms | After max ms |\n"
     << "|---|---|---|---|---|---|---|---|---|\n";
  std::map<std::string, ReplayScene> old;
  if (before) {
    for (const ReplayScene& r : before->replay) old[r.scene] = r;
  }
  for (const ReplayScene& r : after.replay) {
    const bool has = old.count(r.scene) > 0;
    const ReplayScene o = has ? old[r.scene] : ReplayScene{};
    md << "| " << r.scene << " | " << r.queries << " | "
       << (has ? std::to_string(int(o.loops)) : "-") << " | " << r.loops << " | "
       << num(o.mean_ms, 2) << " | " << num(r.mean_ms, 2) << " | " << ratio(r.mean_ms, o.mean_ms)
       << " | " << num(o.max_ms, 2) << " | " << num(r.max_ms, 2) << " |\n";
  }
  if (before) {
    md << "\nLoops found: " << (before->loops == after.loops ? "identical" : "**different**")
       << " (" << after.loops.size() << " after, " << before->loops.size()
       << " before; speed_loops_*.txt).\n";
  }
  md << "\n";
}

void scaleTable(std::ostream& md, const BuildSpeed& after, const BuildSpeed* before) {
  md << "### Loop query vs database size (24 queries; the collected entries, then perturbed "
        "copies of them), thread CPU ms\n\n"
     << "Targets: <= 5 ms at 1,000 entries, <= 10 ms at 10,000; load <= 1 s at 10,000.\n\n"
     << "| Entries | Before median | After median | After / before | Before mean | After mean | "
        "After / before | Bytes/entry before | after | Load s before | after | Peak RSS MiB "
        "before | after |\n"
     << "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (size_t i = 0; i < after.scale.size(); ++i) {
    const ScaleRow& a = after.scale[i];
    const ScaleRow* b = before && i < before->scale.size() ? &before->scale[i] : nullptr;
    auto v = [&](const ScaleRow* r, const char* c) { return r ? cell(*r, c) : 0.0; };
    md << "| " << num(cell(a, "db_size"), 0) << " | " << num(v(b, "median_ms"), 2) << " | "
       << num(cell(a, "median_ms"), 2) << " | " << ratio(cell(a, "median_ms"), v(b, "median_ms"))
       << " | " << num(v(b, "mean_ms"), 2) << " | " << num(cell(a, "mean_ms"), 2) << " | "
       << ratio(cell(a, "mean_ms"), v(b, "mean_ms")) << " | "
       << num(v(b, "memory_bytes_per_entry"), 0) << " | "
       << num(cell(a, "memory_bytes_per_entry"), 0) << " | " << num(v(b, "load_s"), 2) << " | "
       << num(cell(a, "load_s"), 2) << " | " << num(b ? b->peak_mib : 0.0, 0) << " | "
       << num(a.peak_mib, 0) << " |\n";
  }
  md << "\n(Bytes/entry \"-\": the build has no LoopDetector::memoryBytes.)\n\n";
}

}  // namespace

std::string appendSpeed(std::ostream& md, const fs::path& dir,
                        const std::vector<std::string>& datasets, const SpeedOptions& o) {
  BuildSpeed after{o.after_probe, {}, {}, {}, {}};
  BuildSpeed before_build{o.before_probe, {}, {}, {}, {}};
  BuildSpeed* before = o.before_probe.empty() ? nullptr : &before_build;
  const fs::path db = dir / "speed_entries.db";
  // Collected by the earlier build when there is one: a build reads the database files of its
  // own and earlier versions only.
  runProbe(before ? before->probe : after.probe, [&] {
    std::vector<std::string> a{"collect", db.string()};
    a.insert(a.end(), datasets.begin(), datasets.end());
    return a;
  }());
  for (const std::string& ds : datasets) {
    describeDataset(&after, ds, o);
    if (before) describeDataset(before, ds, o);
  }
  replay(&after, db.string());
  if (before) replay(before, db.string());
  for (size_t n : o.sizes) {
    scale(&after, db.string(), n);
    if (before) scale(before, db.string(), n);
  }
  writeDescribeCsv(dir / "speed_describe.csv", after, before);
  writeScaleCsv(dir / "speed_scale.csv", after, before);
  for (const BuildSpeed* b : {before, &after}) {
    if (!b) continue;
    std::ofstream os(dir / (b == &after ? "speed_loops_after.txt" : "speed_loops_before.txt"));
    for (const std::string& l : b->loops) os << l << "\n";
  }
  std::ostringstream sec;
  sec << "## Speed (issue #18): before = " << (before ? o.before_probe : "not run")
      << ", after = " << o.after_probe << "\n\n"
      << "For reference, the paper: DTIF 200 ms descriptor + 14 ms query; STD 158 ms.\n\n";
  describeTable(sec, after, before);
  replayTable(sec, after, before);
  scaleTable(sec, after, before);
  md << sec.str();
  return sec.str();
}

std::string siblingProbe() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  const fs::path probe = (ec ? fs::path(".") : self.parent_path()) / "dtif_query_bench";
  if (!fs::exists(probe)) throw std::runtime_error(probe.string() + ": speed probe not built");
  return probe.string();
}

}  // namespace dtif::tool
