// Writes a simulated survey as a dataset (DATASET.md) and counts ground-truth loop pairs.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <mutex>
#include <sstream>

#include "dtif/core/database/loop_pair.h"
#include "dtif/io/dataset.h"
#include "dtif/sim/sim_world.h"
#include "dtif/sim/simulator.h"

namespace dtif::sim {
namespace {

namespace fs = std::filesystem;

/// Below this overlap a pair sees essentially different ground: it must never be matched.
constexpr double kDisjointOverlap = 0.05;

// Occupied 1 m cells of the points 0.3-3 m above the true terrain, in W (DATASET.md overlap,
// with the true ground instead of the percentile estimate).
std::vector<int64_t> overlapCells(const Submap& sm, const World& world) {
  std::vector<int64_t> cells;
  cells.reserve(sm.points.size() / 4);
  for (const auto& p : sm.points) {
    const Eigen::Vector3d q = sm.T_W_S * p.cast<double>();
    const double h = q.z() - world.terrainHeight(q.x(), q.y());
    if (h < 0.3 || h > 3.0) continue;
    const int64_t cx = static_cast<int64_t>(std::floor(q.x())) + (1 << 20);
    const int64_t cy = static_cast<int64_t>(std::floor(q.y())) + (1 << 20);
    cells.push_back((cx << 22) | cy);
  }
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

double overlap(const std::vector<int64_t>& a, const std::vector<int64_t>& b) {
  if (a.empty() || b.empty()) return 0.0;
  size_t i = 0, j = 0, n = 0;
  while (i < a.size() && j < b.size()) {
    if (a[i] < b[j]) {
      ++i;
    } else if (b[j] < a[i]) {
      ++j;
    } else {
      ++n, ++i, ++j;
    }
  }
  return static_cast<double>(n) / static_cast<double>(std::min(a.size(), b.size()));
}

double percentile(std::vector<float> v, double q) {
  if (v.empty()) return 0.0;
  const size_t k = static_cast<size_t>(q * (v.size() - 1));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

class DatasetWriter : public SubmapSink {
 public:
  DatasetWriter(Dataset* ds, const World& world) : ds_(ds), world_(world) {}

  void onSubmap(const Submap& sm) override {
    SubmapRecord rec;
    rec.id = sm.id;
    rec.robot = sm.robot;
    rec.stamp = sm.stamp;
    std::ostringstream name;
    name << "submaps/" << std::setw(6) << std::setfill('0') << sm.id << ".pcd";
    rec.file = name.str();
    rec.T_O_S = sm.T_O_S;
    Cloud cloud;
    cloud.reserve(sm.points.size());
    std::vector<float> xs, ys;
    for (const auto& p : sm.points) {
      cloud.push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
      xs.push_back(p.x());
      ys.push_back(p.y());
    }
    cloud.width = static_cast<uint32_t>(cloud.size());
    cloud.height = 1;
    // The heavy part (compressing the cloud, the overlap cells) runs in the caller's thread;
    // only the bookkeeping is serialised.
    writeSubmapCloud(*ds_, rec, cloud);
    Entry e;
    e.id = sm.id;
    e.robot = sm.robot_index;
    e.stamp = sm.stamp;
    e.cells = overlapCells(sm, world_);
    SubmapExtent ext;
    ext.robot_index = sm.robot_index;
    ext.T_W_S = sm.T_W_S;
    ext.min_S = Eigen::Vector2d(percentile(xs, 0.02), percentile(ys, 0.02));
    ext.max_S = Eigen::Vector2d(percentile(xs, 0.98), percentile(ys, 0.98));
    std::lock_guard<std::mutex> lock(mutex_);
    records_.push_back(rec);
    T_W_S_[sm.id] = sm.T_W_S;
    entries_.push_back(std::move(e));
    extents_by_id_.emplace_back(sm.id, ext);
  }

  /// After the last submap: everything in id order, whatever order the threads delivered.
  void finish() {
    std::sort(records_.begin(), records_.end(),
              [](const SubmapRecord& a, const SubmapRecord& b) { return a.id < b.id; });
    std::sort(entries_.begin(), entries_.end(),
              [](const Entry& a, const Entry& b) { return a.id < b.id; });
    std::sort(extents_by_id_.begin(), extents_by_id_.end(),
              [](const auto& a, const auto& b) { return a.first < b.first; });
    extents_.clear();
    for (const auto& [id, ext] : extents_by_id_) extents_.push_back(ext);
    ds_->submaps = records_;
    ds_->T_W_S = T_W_S_;
  }

  LoopStats loops(double exclude_recent_s) const {
    LoopStats s;
    for (size_t i = 0; i < entries_.size(); ++i) {
      for (size_t j = i + 1; j < entries_.size(); ++j) {
        const Entry& a = entries_[i];
        const Entry& b = entries_[j];
        const bool same = a.robot == b.robot;
        if (!eligibleLoopPair(a.robot, a.stamp, b.robot, b.stamp, exclude_recent_s)) continue;
        ++s.pairs;
        const double o = overlap(a.cells, b.cells);
        if (o >= 0.3) {
          (same ? s.intra_robot_loops : s.inter_robot_loops)++;
        } else if (o < kDisjointOverlap) {
          ++s.disjoint_pairs;
        }
        s.max_overlap_between_robots =
            same ? s.max_overlap_between_robots : std::max(s.max_overlap_between_robots, o);
      }
    }
    return s;
  }

  const std::vector<SubmapExtent>& extents() const { return extents_; }

 private:
  struct Entry {
    int64_t id;
    int robot;
    double stamp;
    std::vector<int64_t> cells;
  };
  Dataset* ds_;
  const World& world_;
  std::vector<SubmapRecord> records_;
  std::map<int64_t, Pose> T_W_S_;
  std::mutex mutex_;  // guards the containers while submaps arrive
  std::vector<Entry> entries_;
  std::vector<std::pair<int64_t, SubmapExtent>> extents_by_id_;
  std::vector<SubmapExtent> extents_;  // in id order, after finish()
};

void prepareFolder(const std::string& dir) {
  const fs::path root(dir);
  std::error_code ec;
  if (fs::exists(root)) {
    if (!fs::is_directory(root)) throw DatasetError(dir + ": exists and is not a folder");
    const bool is_dataset = fs::exists(root / "submaps.csv");
    if (!is_dataset && !fs::is_empty(root)) {
      throw DatasetError(dir + ": folder is not empty and holds no dataset; refusing to write");
    }
    // Overwriting an earlier dataset: remove its submap clouds so none are left over.
    if (fs::is_directory(root / "submaps")) {
      for (const auto& e : fs::directory_iterator(root / "submaps")) {
        if (e.path().extension() == ".pcd") fs::remove(e.path(), ec);
      }
    }
    for (const char* f : {"submaps.csv", "ground_truth.csv", "stems.csv", "dataset.yaml"}) {
      fs::remove(root / f, ec);
    }
  }
  fs::create_directories(root / "submaps", ec);
  if (ec) throw DatasetError(dir + ": cannot create the folder: " + ec.message());
}

// The tilt of each robot's camera_init (only when some robot's is tilted, so that level
// scenes describe themselves as before).
std::string odometryFramesYaml(const Simulator& sim) {
  bool tilted = false;
  for (const Trajectory& tr : sim.trajectories()) tilted = tilted || tr.tilt_deg != 0.0;
  if (!tilted) return "";
  std::ostringstream y;
  y << "  submap_frame_tilt: S keeps the z of its robot's odometry frame O (camera_init), tilted\n"
    << "    from gravity as below; ground truth T_W_S holds the true attitude\n"
    << "odometry_frames:  # camera_init per robot, as upstream FAST-LIO2 initialises it\n";
  for (const Trajectory& tr : sim.trajectories()) {
    y << "  " << tr.robot << ": {tilt_deg: " << tr.tilt_deg
      << ", tilt_azimuth_deg: " << tr.tilt_azimuth_deg << ", up_in_O: [" << tr.up_O.x() << ", "
      << tr.up_O.y() << ", " << tr.up_O.z() << "]}\n";
  }
  return y.str();
}

}  // namespace

DatasetRunResult simulateDataset(const SceneParams& scene, uint64_t seed, const std::string& dir,
                                 FrameSink* frames, const std::string& png_path, int threads) {
  Simulator sim(scene, seed);
  prepareFolder(dir);
  Dataset ds;
  ds.root = dir;
  DatasetWriter writer(&ds, sim.world());
  DatasetRunResult result;
  result.stats = sim.run(frames, &writer, threads);
  writer.finish();
  for (const Stem& s : sim.world().stems()) {
    if (s.sapling) continue;
    StemRecord r;
    r.stem_id = s.id;
    const Eigen::Vector2d xy = s.axisAt(1.3);
    r.x = xy.x();
    r.y = xy.y();
    r.z_base = s.z_base;
    r.dbh = 2.0 * s.r_bh;
    ds.stems.push_back(r);
  }
  writeDatasetTables(ds);
  result.loops = writer.loops(30.0);

  const std::string yaml_path = (fs::path(dir) / "dataset.yaml").string();
  std::ofstream y(yaml_path);
  y << "# Simulated forest survey written by `dtif simulate` (free-form description).\n"
    << "generator: dtif simulate\n"
    << "seed: " << seed << "\n"
    << "sensor: Livox MID-360 model (non-repetitive scan, FAST-LIO2-like drifting odometry)\n"
    << "conventions:\n"
    << "  submap_anchor: centre of each submap's time window (stamp)\n"
    << "  submap_frame: gravity-aligned yaw of the odometry pose at the anchor; the odometry's\n"
    << "    residual roll/pitch error stays in the points (T_W_S is not yaw-only)\n"
    << "  stems_xy: stem axis at 1.3 m above the base (stems lean); z_base: terrain at the base\n"
    << "  stems: trunks only (saplings, shrubs, logs and branches are clutter)\n"
    << odometryFramesYaml(sim) << "stats:\n"
    << "  stems: " << result.stats.stems << "\n"
    << "  saplings: " << result.stats.saplings << "\n"
    << "  shrubs: " << result.stats.shrubs << "\n"
    << "  logs: " << result.stats.logs << "\n"
    << "  branches: " << result.stats.branches << "\n"
    << "  frames: " << result.stats.frames << "\n"
    << "  rays: " << result.stats.rays << "\n"
    << "  returns: " << result.stats.returns << "\n"
    << "  submaps: " << result.stats.submaps << "\n"
    << "  mean_submap_points: " << result.stats.mean_submap_points << "\n"
    << "  inter_robot_loops: " << result.loops.inter_robot_loops << "\n"
    << "  intra_robot_loops: " << result.loops.intra_robot_loops << "\n"
    << "  disjoint_pairs: " << result.loops.disjoint_pairs << "\n"
    << "scene:\n";
  std::istringstream scene_yaml(sceneToYaml(scene));
  for (std::string line; std::getline(scene_yaml, line);) y << "  " << line << "\n";
  if (!y) throw DatasetError(yaml_path + ": cannot write");
  if (!png_path.empty()) writeScenePng(png_path, sim, writer.extents());
  return result;
}

}  // namespace dtif::sim
