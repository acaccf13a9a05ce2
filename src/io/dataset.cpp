// Dataset format of DATASET.md: strict readers (one-line errors naming file and problem) and
// writers used by the simulator.
#include "dtif/io/dataset.h"

#include <pcl/io/pcd_io.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <regex>
#include <set>
#include <sstream>

#include "dtif/core/file_io.h"
#include "dtif/io/csv.h"
#include "dtif/io/pcd_reader.h"

namespace dtif {
namespace fs = std::filesystem;

namespace {
// Bounds of files from outside (docs/limits.md).
constexpr uint64_t kMaxCsvBytes = uint64_t{256} << 20;
constexpr uint64_t kMaxPcdBytes = uint64_t{4} << 30;
}  // namespace

namespace {

[[noreturn]] void fail(const std::string& file, const std::string& what) {
  throw DatasetError(file + ": " + what);
}

/// A CSV table read whole: header names and rows, with the line number of each row.
struct CsvTable {
  std::string file;
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  std::vector<int> line_numbers;

  int column(const std::string& name) const {
    for (size_t i = 0; i < header.size(); ++i) {
      if (header[i] == name) return static_cast<int>(i);
    }
    fail(file, "missing column '" + name + "' in the header");
  }
};

CsvTable readCsv(const std::string& path, bool header_required = true) {
  // Checked before opening: a FIFO would block, a folder reads as an I/O error.
  const std::string problem = regularFileProblem(path, kMaxCsvBytes);
  if (!problem.empty()) fail(path, problem);
  std::ifstream in(path);
  if (!in) fail(path, "cannot open file");
  CsvTable t;
  t.file = path;
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    auto cells = splitCsvLine(line);
    if (t.header.empty() && header_required) {
      t.header = cells;
      continue;
    }
    t.rows.push_back(std::move(cells));
    t.line_numbers.push_back(n);
  }
  if (header_required && t.header.empty()) fail(path, "empty file (a header line is required)");
  return t;
}

double parseDouble(const CsvTable& t, size_t row, int col) {
  const auto& cells = t.rows[row];
  const std::string where = "line " + std::to_string(t.line_numbers[row]);
  if (col >= static_cast<int>(cells.size())) fail(t.file, where + ": too few columns");
  const std::string& s = cells[col];
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || end != s.c_str() + s.size() || errno == ERANGE || !std::isfinite(v)) {
    fail(t.file, where + ": '" + t.header[col] + "' is not a finite number: '" + s + "'");
  }
  return v;
}

int64_t parseId(const CsvTable& t, size_t row, int col) {
  const double v = parseDouble(t, row, col);
  if (v != std::floor(v) || std::fabs(v) > 9e15) {
    fail(t.file, "line " + std::to_string(t.line_numbers[row]) + ": '" + t.header[col] +
                     "' is not an integer");
  }
  return static_cast<int64_t>(v);
}

std::string cell(const CsvTable& t, size_t row, int col) {
  if (col >= static_cast<int>(t.rows[row].size())) {
    fail(t.file, "line " + std::to_string(t.line_numbers[row]) + ": too few columns");
  }
  return t.rows[row][col];
}

/// Pose from 7 columns tx,ty,tz,qx,qy,qz,qw; the quaternion must be normalised (DATASET.md).
Pose parsePose(const CsvTable& t, size_t row, const std::array<int, 7>& cols) {
  double v[7];
  for (int i = 0; i < 7; ++i) v[i] = parseDouble(t, row, cols[i]);
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::fabs(q.norm() - 1.0) > 1e-3) {
    fail(t.file, "line " + std::to_string(t.line_numbers[row]) +
                     ": quaternion is not normalised (norm " + std::to_string(q.norm()) + ")");
  }
  Pose T = Pose::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return T;
}

std::array<int, 7> poseColumns(const CsvTable& t, const std::string& prefix) {
  std::array<int, 7> c{};
  const char* names[7] = {"tx", "ty", "tz", "qx", "qy", "qz", "qw"};
  for (int i = 0; i < 7; ++i) c[i] = t.column(prefix + names[i]);
  return c;
}

void writePose(std::ostream& os, const Pose& T) {
  const Eigen::Quaterniond q(T.rotation());
  const Eigen::Vector3d& t = T.translation();
  os << t.x() << ',' << t.y() << ',' << t.z() << ',' << q.x() << ',' << q.y() << ',' << q.z() << ','
     << q.w();
}

std::ofstream openForWrite(const std::string& path) {
  std::ofstream os(path);
  if (!os) fail(path, "cannot open file for writing");
  os << std::setprecision(10);
  return os;
}

void closeChecked(std::ofstream& os, const std::string& path) {
  os.close();
  if (!os) fail(path, "write failed");
}

// submaps.csv (required): every row checked, its point cloud present.
std::vector<SubmapRecord> readSubmapsCsv(const std::string& dir) {
  const std::string path = (fs::path(dir) / "submaps.csv").string();
  if (!fs::exists(path)) fail(path, "missing (required by DATASET.md)");
  const CsvTable t = readCsv(path);
  const int c_id = t.column("id"), c_robot = t.column("robot"), c_stamp = t.column("stamp"),
            c_file = t.column("file");
  const auto c_pose = poseColumns(t, "odom_");
  static const std::regex kRobotName("[A-Za-z0-9_]+");
  std::set<int64_t> ids;
  std::vector<SubmapRecord> submaps;
  for (size_t i = 0; i < t.rows.size(); ++i) {
    SubmapRecord r;
    r.id = parseId(t, i, c_id);
    r.robot = cell(t, i, c_robot);
    r.stamp = parseDouble(t, i, c_stamp);
    r.file = cell(t, i, c_file);
    r.T_O_S = parsePose(t, i, c_pose);
    const std::string where = "line " + std::to_string(t.line_numbers[i]);
    if (!std::regex_match(r.robot, kRobotName)) {
      fail(path, where + ": robot name '" + r.robot + "' is not [A-Za-z0-9_]+");
    }
    if (!ids.insert(r.id).second) fail(path, where + ": duplicate id " + std::to_string(r.id));
    if (r.file.empty()) fail(path, where + ": empty file name");
    if (!fs::exists(fs::path(dir) / r.file)) {
      fail(path, where + ": point cloud '" + r.file + "' does not exist");
    }
    submaps.push_back(std::move(r));
  }
  if (submaps.empty()) fail(path, "no submaps listed");
  return submaps;
}

// ground_truth.csv (optional) into ds->T_W_S: ids of ds->submaps only, each once.
void readGroundTruthCsv(const std::string& dir, Dataset* ds) {
  const std::string path = (fs::path(dir) / "ground_truth.csv").string();
  if (!fs::exists(path)) return;
  std::set<int64_t> ids;
  for (const SubmapRecord& r : ds->submaps) ids.insert(r.id);
  const CsvTable g = readCsv(path);
  const int c_id = g.column("id");
  const auto c_pose = poseColumns(g, "");
  for (size_t i = 0; i < g.rows.size(); ++i) {
    const int64_t id = parseId(g, i, c_id);
    const std::string where = "line " + std::to_string(g.line_numbers[i]);
    if (!ids.count(id)) fail(path, where + ": id " + std::to_string(id) + " is not in submaps.csv");
    if (!ds->T_W_S.emplace(id, parsePose(g, i, c_pose)).second) {
      fail(path, where + ": duplicate id " + std::to_string(id));
    }
  }
}

// stems.csv (optional).
std::vector<StemRecord> readStemsCsv(const std::string& dir) {
  const std::string path = (fs::path(dir) / "stems.csv").string();
  std::vector<StemRecord> stems;
  if (!fs::exists(path)) return stems;
  const CsvTable s = readCsv(path);
  const int c_sid = s.column("stem_id"), c_x = s.column("x"), c_y = s.column("y"),
            c_z = s.column("z_base"), c_d = s.column("dbh");
  for (size_t i = 0; i < s.rows.size(); ++i) {
    StemRecord st;
    st.stem_id = parseId(s, i, c_sid);
    st.x = parseDouble(s, i, c_x);
    st.y = parseDouble(s, i, c_y);
    st.z_base = parseDouble(s, i, c_z);
    st.dbh = parseDouble(s, i, c_d);
    stems.push_back(st);
  }
  return stems;
}

}  // namespace

Dataset readDataset(const std::string& dir) {
  Dataset ds;
  ds.root = dir;
  if (!fs::is_directory(dir)) fail(dir, "not a dataset folder (no such directory)");
  ds.submaps = readSubmapsCsv(dir);
  readGroundTruthCsv(dir, &ds);
  ds.stems = readStemsCsv(dir);
  return ds;
}

Cloud::Ptr loadPcd(const std::string& path) {
  if (!fs::exists(path)) fail(path, "point cloud does not exist");
  const std::string problem = regularFileProblem(path, kMaxPcdBytes);
  if (!problem.empty()) fail(path, problem);
  try {
    return readPcdFile(path);
  } catch (const DatasetError&) {
    throw;
  } catch (const std::exception& e) {  // the library's (bad_alloc, length_error)
    fail(path, std::string("cannot read the point cloud: ") + e.what());
  }
}

Cloud::Ptr loadSubmapCloud(const Dataset& ds, const SubmapRecord& rec) {
  return loadPcd((fs::path(ds.root) / rec.file).string());
}

void writeDatasetTables(const Dataset& ds) {
  std::error_code ec;
  fs::create_directories(ds.root, ec);
  if (ec) fail(ds.root, "cannot create folder: " + ec.message());

  const std::string submaps_path = (fs::path(ds.root) / "submaps.csv").string();
  auto os = openForWrite(submaps_path);
  os << "id,robot,stamp,file,odom_tx,odom_ty,odom_tz,odom_qx,odom_qy,odom_qz,odom_qw\n";
  for (const auto& r : ds.submaps) {
    os << r.id << ',' << r.robot << ',' << std::fixed << std::setprecision(6) << r.stamp
       << std::defaultfloat << std::setprecision(10) << ',' << r.file << ',';
    writePose(os, r.T_O_S);
    os << '\n';
  }
  closeChecked(os, submaps_path);

  if (!ds.T_W_S.empty()) {
    const std::string gt_path = (fs::path(ds.root) / "ground_truth.csv").string();
    auto g = openForWrite(gt_path);
    g << "id,tx,ty,tz,qx,qy,qz,qw\n";
    for (const auto& r : ds.submaps) {
      const auto it = ds.T_W_S.find(r.id);
      if (it == ds.T_W_S.end()) continue;
      g << r.id << ',';
      writePose(g, it->second);
      g << '\n';
    }
    closeChecked(g, gt_path);
  }

  if (!ds.stems.empty()) {
    const std::string stems_path = (fs::path(ds.root) / "stems.csv").string();
    auto s = openForWrite(stems_path);
    s << "stem_id,x,y,z_base,dbh\n";
    for (const auto& st : ds.stems) {
      s << st.stem_id << ',' << st.x << ',' << st.y << ',' << st.z_base << ',' << st.dbh << '\n';
    }
    closeChecked(s, stems_path);
  }
}

void writeSubmapCloud(const Dataset& ds, const SubmapRecord& rec, const Cloud& cloud) {
  const fs::path path = fs::path(ds.root) / rec.file;
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  if (ec) fail(path.parent_path().string(), "cannot create folder: " + ec.message());
  Cloud c = cloud;
  c.width = static_cast<uint32_t>(c.size());
  c.height = 1;
  if (c.empty()) {
    // PCL refuses to write an empty binary cloud; an ASCII file with zero points is valid PCD.
    if (pcl::io::savePCDFileASCII(path.string(), c) < 0) fail(path.string(), "write failed");
    return;
  }
  if (pcl::io::savePCDFileBinaryCompressed(path.string(), c) < 0) {
    fail(path.string(), "write failed");
  }
}

std::string loopLogHeader() {
  return "query_robot,query_id,query_stamp,query_data_end,accepted,candidate_robot,candidate_id,"
         "candidate_stamp,tx,ty,tz,qx,qy,qz,qw,inliers,score,t_loop_ms,ros_time,wall_time";
}

std::string formatLoopLogRow(const LoopLogRow& r) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(6) << r.query_robot << ',' << r.query_id << ','
     << r.query_stamp << ',' << r.query_data_end << ',' << int(r.accepted) << ','
     << r.candidate_robot << ',' << r.candidate_id << ',' << r.candidate_stamp << ',';
  os << std::defaultfloat << std::setprecision(9);
  writePose(os, r.T_c_q);
  os << ',' << r.inliers << ',' << r.score << ',' << r.t_loop_ms << ',' << std::fixed
     << std::setprecision(6) << r.ros_time << ',' << r.wall_time;
  return os.str();
}

std::vector<LoopLogRow> readLoopLog(const std::string& path) {
  const CsvTable t = readCsv(path);
  const int c_qr = t.column("query_robot"), c_qi = t.column("query_id"),
            c_qs = t.column("query_stamp"), c_qe = t.column("query_data_end"),
            c_acc = t.column("accepted"), c_cr = t.column("candidate_robot"),
            c_ci = t.column("candidate_id"), c_cs = t.column("candidate_stamp"),
            c_in = t.column("inliers"), c_sc = t.column("score"), c_tl = t.column("t_loop_ms"),
            c_rt = t.column("ros_time"), c_wt = t.column("wall_time");
  const auto c_pose = poseColumns(t, "");
  std::vector<LoopLogRow> rows;
  for (size_t i = 0; i < t.rows.size(); ++i) {
    LoopLogRow r;
    r.query_robot = cell(t, i, c_qr);
    r.query_id = parseId(t, i, c_qi);
    r.query_stamp = parseDouble(t, i, c_qs);
    r.query_data_end = parseDouble(t, i, c_qe);
    r.accepted = parseId(t, i, c_acc) != 0;
    r.candidate_robot = cell(t, i, c_cr);
    r.candidate_id = parseId(t, i, c_ci);
    r.candidate_stamp = parseDouble(t, i, c_cs);
    r.T_c_q = parsePose(t, i, c_pose);
    r.inliers = static_cast<int>(parseId(t, i, c_in));
    r.score = parseDouble(t, i, c_sc);
    r.t_loop_ms = parseDouble(t, i, c_tl);
    r.ros_time = parseDouble(t, i, c_rt);
    r.wall_time = parseDouble(t, i, c_wt);
    rows.push_back(std::move(r));
  }
  return rows;
}

std::map<int64_t, int64_t> readAcceptedLoops(const std::string& results_csv) {
  const CsvTable t = readCsv(results_csv);
  const int c_q = t.column("query"), c_c = t.column("candidate"), c_a = t.column("accepted");
  std::map<int64_t, int64_t> out;
  for (size_t i = 0; i < t.rows.size(); ++i) {
    if (parseId(t, i, c_a) != 0) out[parseId(t, i, c_q)] = parseId(t, i, c_c);
  }
  return out;
}

Trunks readTrunkCsv(const std::string& path) {
  const CsvTable raw = readCsv(path, /*header_required=*/false);
  if (raw.rows.empty()) fail(path, "no trunks (expected rows x,y,z,r)");
  // A header is optional: detect one by a non-numeric first cell.
  CsvTable t = raw;
  size_t first = 0;
  {
    char* end = nullptr;
    const std::string& c0 = raw.rows[0].empty() ? std::string() : raw.rows[0][0];
    std::strtod(c0.c_str(), &end);
    if (c0.empty() || end != c0.c_str() + c0.size()) first = 1;
  }
  t.header = first ? raw.rows[0] : std::vector<std::string>{"x", "y", "z", "r"};
  while (t.header.size() < 4) t.header.push_back("column" + std::to_string(t.header.size()));
  // Optional fifth column (dtif extract writes it): was the stem base observed.
  const bool has_base_seen = t.header.size() >= 5 && t.header[4] == "base_seen";
  Trunks trunks;
  for (size_t i = first; i < t.rows.size(); ++i) {
    if (t.rows[i].size() < 4) {
      fail(path, "line " + std::to_string(t.line_numbers[i]) + ": expected x,y,z,r");
    }
    TrunkLandmark tr;
    tr.x = parseDouble(t, i, 0);
    tr.y = parseDouble(t, i, 1);
    tr.z = parseDouble(t, i, 2);
    tr.r = parseDouble(t, i, 3);
    if (tr.r <= 0.0) {
      fail(path, "line " + std::to_string(t.line_numbers[i]) + ": radius must be positive");
    }
    if (has_base_seen) {
      if (t.rows[i].size() < 5) {
        fail(path, "line " + std::to_string(t.line_numbers[i]) + ": expected x,y,z,r,base_seen");
      }
      const std::string& b = t.rows[i][4];
      if (b != "0" && b != "1") {
        fail(path, "line " + std::to_string(t.line_numbers[i]) + ": base_seen must be 0 or 1");
      }
      tr.base_seen = b == "1";
    }
    trunks.push_back(tr);
  }
  if (trunks.empty()) fail(path, "no trunks (expected rows x,y,z,r)");
  return trunks;
}

void writeTrunkCsv(const std::string& path, const Trunks& trunks) {
  auto os = openForWrite(path);
  os << "x,y,z,r,base_seen\n";
  for (const auto& t : trunks) {
    os << t.x << ',' << t.y << ',' << t.z << ',' << t.r << ',' << (t.base_seen ? 1 : 0) << '\n';
  }
  closeChecked(os, path);
}

}  // namespace dtif
