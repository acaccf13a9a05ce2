#include "dtif/io/merge_files.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <set>
#include <sstream>

#include "dtif/core/file_io.h"
#include "dtif/io/csv.h"
#include "dtif/io/dataset.h"

namespace dtif {
namespace {

[[noreturn]] void fail(const std::string& file, const std::string& what) {
  throw DatasetError(file + ": " + what);
}

bool parseNumber(const std::string& s, double* v) {
  if (s.empty()) return false;
  char* end = nullptr;
  *v = std::strtod(s.c_str(), &end);
  return end == s.c_str() + s.size() && std::isfinite(*v);
}

/// Lines of a CSV file (blank lines dropped) with their 1-based line numbers.
std::vector<std::pair<size_t, std::vector<std::string>>> readRows(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail(path, "cannot open file");
  std::vector<std::pair<size_t, std::vector<std::string>>> rows;
  std::string line;
  size_t n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    rows.emplace_back(n, splitCsvLine(line));
  }
  if (in.bad()) fail(path, "read error");
  return rows;
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

int column(const std::vector<std::string>& header, std::initializer_list<const char*> names) {
  for (size_t i = 0; i < header.size(); ++i) {
    for (const char* n : names) {
      if (lower(header[i]) == n) return static_cast<int>(i);
    }
  }
  return -1;
}

struct StemMapColumns {
  int x = 0, y = 1, dbh = 2, id = -1, plot = -1;
  bool header = false;
};

StemMapColumns stemMapColumns(const std::string& path, const std::vector<std::string>& first) {
  StemMapColumns c;
  double v = 0.0;
  if (parseNumber(first.at(0), &v)) return c;  // no header: x,y[,dbh]
  c.header = true;
  c.x = column(first, {"x", "x_m"});
  c.y = column(first, {"y", "y_m"});
  c.dbh = column(first, {"dbh", "dbh_m"});
  c.id = column(first, {"tree", "id", "stem_id", "tree_id"});
  c.plot = column(first, {"plot_id", "plot"});
  if (c.x < 0 || c.y < 0) fail(path, "header has no x/x_m and y/y_m columns");
  return c;
}

/// writeFileAtomically, its failure as a DatasetError.
void writeAtomically(const std::string& path, const std::string& text) {
  try {
    writeFileAtomically(path, text);
  } catch (const std::runtime_error& e) {
    throw DatasetError(e.what());
  }
}

void writeQuatPose(std::ostream& os, const Pose& T, char sep) {
  const Eigen::Quaterniond q(T.rotation());
  const Eigen::Vector3d t = T.translation();
  os << t.x() << sep << t.y() << sep << t.z() << sep << q.x() << sep << q.y() << sep << q.z() << sep
     << q.w();
}

}  // namespace

std::vector<FieldStem> readStemMapCsv(const std::string& path, const std::string& plot) {
  const auto rows = readRows(path);
  if (rows.empty()) fail(path, "empty file (expected rows x,y[,dbh])");
  const StemMapColumns c = stemMapColumns(path, rows.front().second);
  std::vector<FieldStem> out;
  for (size_t i = c.header ? 1 : 0; i < rows.size(); ++i) {
    // Not a structured binding: clang (the sanitizer build, C++17) refuses lambdas capturing one.
    const size_t line = rows[i].first;
    const auto& cells = rows[i].second;
    const std::string where = "line " + std::to_string(line);
    auto cellAt = [&](int col) -> const std::string& {
      if (col >= static_cast<int>(cells.size())) fail(path, where + ": too few columns");
      return cells[col];
    };
    if (!plot.empty() && c.plot >= 0 && cellAt(c.plot) != plot) continue;
    FieldStem f;
    if (!parseNumber(cellAt(c.x), &f.x) || !parseNumber(cellAt(c.y), &f.y)) {
      fail(path, where + ": x and y must be finite numbers");
    }
    if (c.dbh >= 0 && c.dbh < static_cast<int>(cells.size())) {
      const std::string& d = cells[c.dbh];
      if (!parseNumber(d, &f.dbh)) {
        if (!d.empty() && lower(d) != "na" && lower(d) != "nan") {
          fail(path, where + ": dbh must be a number or NA: '" + d + "'");
        }
        f.dbh = 0.0;
      }
      if (f.dbh < 0.0) fail(path, where + ": negative dbh");
    }
    f.id = c.id >= 0 ? cellAt(c.id) : std::to_string(out.size() + 1);
    out.push_back(f);
  }
  if (out.empty()) fail(path, plot.empty() ? "no stems" : "no stems in plot " + plot);
  return out;
}

std::vector<std::string> stemMapPlots(const std::string& path) {
  const auto rows = readRows(path);
  if (rows.empty()) fail(path, "empty file (expected rows x,y[,dbh])");
  const StemMapColumns c = stemMapColumns(path, rows.front().second);
  std::vector<std::string> plots;
  if (c.plot < 0) return plots;
  std::set<std::string> seen;
  for (size_t i = 1; i < rows.size(); ++i) {
    const auto& cells = rows[i].second;
    if (c.plot < static_cast<int>(cells.size()) && seen.insert(cells[c.plot]).second) {
      plots.push_back(cells[c.plot]);
    }
  }
  return plots;
}

void writeMergedPosesCsv(const std::string& path, const std::vector<MergedPose>& poses) {
  std::ostringstream os;
  os << std::setprecision(10) << "id,robot,component,tx,ty,tz,qx,qy,qz,qw\n";
  for (const MergedPose& p : poses) {
    os << p.id << ',' << p.robot << ',' << p.component << ',';
    writeQuatPose(os, p.T_M_S, ',');
    os << '\n';
  }
  writeAtomically(path, os.str());
}

void writeMergedStemsCsv(const std::string& path, const std::vector<MergedStem>& stems) {
  const bool ids = std::any_of(stems.begin(), stems.end(),
                               [](const MergedStem& s) { return !s.field_id.empty(); });
  std::ostringstream os;
  os << std::setprecision(10) << "stem_id,component,x,y,z_base,dbh,observations"
     << (ids ? ",field_id" : "") << '\n';
  for (const MergedStem& s : stems) {
    os << s.stem_id << ',' << s.component << ',' << s.x << ',' << s.y << ',' << s.z_base << ','
       << s.dbh << ',' << s.observations;
    if (ids) os << ',' << s.field_id;
    os << '\n';
  }
  writeAtomically(path, os.str());
}

void writeG2o(const std::string& path, const std::vector<MergedPose>& poses,
              const std::vector<MergeGraphEdge>& edges) {
  std::ostringstream os;
  os << std::setprecision(10);
  for (const MergedPose& p : poses) {
    os << "VERTEX_SE3:QUAT " << p.id << ' ';
    writeQuatPose(os, p.T_M_S, ' ');
    os << '\n';
  }
  for (const MergeGraphEdge& e : edges) {
    os << "EDGE_SE3:QUAT " << e.from << ' ' << e.to << ' ';
    writeQuatPose(os, e.T_from_to, ' ');
    for (int i = 0; i < 6; ++i) {
      for (int j = i; j < 6; ++j) os << ' ' << e.information(i, j);
    }
    os << '\n';
  }
  writeAtomically(path, os.str());
}

std::vector<MergedPose> readMergedPosesCsv(const std::string& path) {
  const auto rows = readRows(path);
  if (rows.empty() || rows.front().second.size() < 10 || rows.front().second[0] != "id") {
    fail(path, "expected the header id,robot,component,tx,ty,tz,qx,qy,qz,qw");
  }
  std::vector<MergedPose> out;
  for (size_t i = 1; i < rows.size(); ++i) {
    const auto& [line, c] = rows[i];
    double v[10];
    bool ok = c.size() >= 10;
    for (int k = 0; ok && k < 10; ++k) ok = k == 1 || parseNumber(c[k], &v[k]);
    if (!ok) fail(path, "line " + std::to_string(line) + ": malformed row");
    MergedPose p;
    p.id = static_cast<int64_t>(v[0]);
    p.robot = c[1];
    p.component = static_cast<int>(v[2]);
    const Eigen::Quaterniond q(v[9], v[6], v[7], v[8]);
    if (std::fabs(q.norm() - 1.0) > 1e-3)
      fail(path, "line " + std::to_string(line) + ": quaternion not normalised");
    p.T_M_S.linear() = q.normalized().toRotationMatrix();
    p.T_M_S.translation() << v[3], v[4], v[5];
    out.push_back(p);
  }
  return out;
}

std::vector<MergedStem> readMergedStemsCsv(const std::string& path) {
  const auto rows = readRows(path);
  if (rows.empty() || rows.front().second.size() < 7 || rows.front().second[0] != "stem_id") {
    fail(path, "expected the header stem_id,component,x,y,z_base,dbh,observations");
  }
  std::vector<MergedStem> out;
  for (size_t i = 1; i < rows.size(); ++i) {
    const auto& [line, c] = rows[i];
    double v[7];
    bool ok = c.size() >= 7;
    for (int k = 0; ok && k < 7; ++k) ok = parseNumber(c[k], &v[k]);
    if (!ok) fail(path, "line " + std::to_string(line) + ": malformed row");
    MergedStem s;
    s.stem_id = static_cast<int64_t>(v[0]);
    s.component = static_cast<int>(v[1]);
    s.x = v[2];
    s.y = v[3];
    s.z_base = v[4];
    s.dbh = v[5];
    s.observations = static_cast<int>(v[6]);
    if (c.size() >= 8) s.field_id = c[7];
    out.push_back(s);
  }
  return out;
}

}  // namespace dtif
