// Scene YAML: strict loading (unknown keys are errors), validation, and dumping.
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <regex>
#include <set>
#include <sstream>

#include "dtif/core/file_io.h"
#include "dtif/core/params.h"
#include "dtif/sim/simulator.h"

namespace dtif::sim {
namespace {

// Reads the fields of one params struct from a YAML map; unknown keys and wrong types throw.
class SectionReader {
 public:
  SectionReader(const YAML::Node& node, const std::string& where) : node_(node), where_(where) {}

  template <class T>
  void operator()(const char* name, T& value) {
    known_.insert(name);
    const YAML::Node v = node_[name];
    if (!v) return;
    try {
      value = v.as<T>();
    } catch (const YAML::Exception&) {
      throw ParamError(where_ + "." + name + ": wrong type");
    }
  }

  void checkUnknown() const {
    for (const auto& kv : node_) {
      if (!kv.first.IsScalar()) throw ParamError(where_ + ": a key is not a name");
      const std::string key = kv.first.as<std::string>();
      if (!known_.count(key)) throw ParamError(where_ + ": unknown key '" + key + "'");
    }
  }

 private:
  YAML::Node node_;
  std::string where_;
  std::set<std::string> known_;
};

template <class Params>
void readSection(const YAML::Node& root, const char* name, const std::string& file, Params* p) {
  const YAML::Node node = root[name];
  if (!node) return;
  const std::string where = file + ": " + name;
  if (!node.IsMap()) throw ParamError(where + ": must be a map");
  SectionReader reader(node, where);
  p->visit(reader);
  reader.checkUnknown();
}

// Writes the fields of one params struct as YAML.
class SectionWriter {
 public:
  explicit SectionWriter(YAML::Emitter* out) : out_(out) {}
  template <class T>
  void operator()(const char* name, T& value) {
    *out_ << YAML::Key << name << YAML::Value << value;
  }

 private:
  YAML::Emitter* out_;
};

template <class Params>
void writeSection(YAML::Emitter* out, const char* name, Params p) {
  *out << YAML::Key << name << YAML::Value << YAML::BeginMap;
  SectionWriter w(out);
  p.visit(w);
  *out << YAML::EndMap;
}

void check(bool ok, const std::string& what, std::ostringstream* errors) {
  if (!ok) *errors << what << "\n";
}

// Each section checks its own fields; the messages keep their order (loadSceneYaml reports the
// first one).
void checkPlot(const PlotParams& plot, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(plot.size_x_m >= 5 && plot.size_y_m >= 5, "plot: size_x_m and size_y_m must be >= 5", &e);
  check(plot.size_x_m <= 2000 && plot.size_y_m <= 2000, "plot: sizes must be <= 2000 m", &e);
  check(plot.margin_m >= 0, "plot.margin_m must be >= 0", &e);
}

void checkTerrain(const TerrainParams& terrain, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(terrain.slope_deg >= 0 && terrain.slope_deg <= 35, "terrain.slope_deg must be 0..35", &e);
  check(terrain.hill_amplitude_m >= 0, "terrain.hill_amplitude_m must be >= 0", &e);
  check(terrain.hill_wavelength_m > 1, "terrain.hill_wavelength_m must be > 1", &e);
  check(terrain.roughness_m >= 0 && terrain.roughness_m <= 0.5,
        "terrain.roughness_m must be 0..0.5", &e);
}

void checkStems(const StemParams& stems, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(stems.density_per_ha >= 0 && stems.density_per_ha <= 5000,
        "stems.density_per_ha must be 0..5000", &e);
  check(stems.pattern == "random" || stems.pattern == "clustered" || stems.pattern == "grid",
        "stems.pattern must be random, clustered or grid", &e);
  check(stems.min_spacing_m >= 0, "stems.min_spacing_m must be >= 0", &e);
  check(stems.cluster_radius_m > 0, "stems.cluster_radius_m must be > 0", &e);
  check(stems.cluster_fraction >= 0 && stems.cluster_fraction <= 1,
        "stems.cluster_fraction must be 0..1", &e);
  check(stems.clusters_per_ha > 0, "stems.clusters_per_ha must be > 0", &e);
  check(stems.grid_spacing_x_m > 0.5 && stems.grid_spacing_y_m > 0.5,
        "stems.grid_spacing_*_m must be > 0.5", &e);
  check(stems.grid_jitter_m >= 0, "stems.grid_jitter_m must be >= 0", &e);
  check(stems.grid_missing >= 0 && stems.grid_missing < 1, "stems.grid_missing must be 0..1", &e);
  check(stems.dbh_min_m > 0.02 && stems.dbh_min_m <= stems.dbh_max_m && stems.dbh_max_m <= 2.0,
        "stems: need 0.02 < dbh_min_m <= dbh_max_m <= 2", &e);
  check(stems.dbh_mean_m > 0 && stems.dbh_sd_m >= 0, "stems: dbh_mean_m > 0, dbh_sd_m >= 0", &e);
  check(stems.dead_fraction >= 0 && stems.dead_fraction <= 1, "stems.dead_fraction must be 0..1",
        &e);
  check(stems.lean_max_deg >= 0 && stems.lean_max_deg <= 20, "stems.lean_max_deg must be 0..20",
        &e);
  check(stems.ellipticity >= 0 && stems.ellipticity < 0.5, "stems.ellipticity must be 0..0.5", &e);
  check(stems.bark_roughness >= 0 && stems.bark_roughness < 0.3,
        "stems.bark_roughness must be 0..0.3", &e);
}

void checkTrees(const TreeParams& trees, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(trees.height_at_30cm_m >= 2 && trees.height_at_30cm_m <= 60,
        "trees.height_at_30cm_m must be 2..60", &e);
  check(trees.height_exponent >= 0 && trees.height_exponent <= 2,
        "trees.height_exponent must be 0..2", &e);
  check(trees.crown_base_frac > 0 && trees.crown_base_frac < 1,
        "trees.crown_base_frac must be in (0, 1)", &e);
  check(trees.crown_radius_per_dbh >= 0, "trees.crown_radius_per_dbh must be >= 0", &e);
  check(trees.crown_density >= 0, "trees.crown_density must be >= 0", &e);
  check(trees.taper >= 0 && trees.taper < 0.05, "trees.taper must be 0..0.05", &e);
  check(trees.branches_per_m >= 0 && trees.branches_per_m <= 20,
        "trees.branches_per_m must be 0..20", &e);
  check(trees.branch_min_h_m >= 0, "trees.branch_min_h_m must be >= 0", &e);
  check(trees.branch_length_m > 0, "trees.branch_length_m must be > 0", &e);
}

void checkUnderstory(const UnderstoryParams& understory, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(understory.saplings_per_ha >= 0 && understory.shrubs_per_ha >= 0 &&
            understory.logs_per_ha >= 0,
        "understory: densities must be >= 0", &e);
  // Upper bounds (docs/limits.md): 1e9 saplings per ha ended in bad_alloc after 4 GB.
  check(understory.saplings_per_ha <= 20000, "understory.saplings_per_ha must be <= 20000", &e);
  check(understory.shrubs_per_ha <= 20000, "understory.shrubs_per_ha must be <= 20000", &e);
  check(understory.logs_per_ha <= 2000, "understory.logs_per_ha must be <= 2000", &e);
  check(understory.shrub_radius_m > 0, "understory.shrub_radius_m must be > 0", &e);
  check(understory.shrub_density > 0, "understory.shrub_density must be > 0", &e);
  check(understory.sapling_dbh_min_m > 0 &&
            understory.sapling_dbh_min_m <= understory.sapling_dbh_max_m,
        "understory: sapling_dbh_min_m must be > 0 and <= sapling_dbh_max_m", &e);
  check(understory.sapling_height_min_m > 0 &&
            understory.sapling_height_min_m <= understory.sapling_height_max_m &&
            understory.sapling_height_max_m <= 20,
        "understory: sapling heights must be 0 < min <= max <= 20 m", &e);
}

void checkSensor(const SensorParams& sensor, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(sensor.points_per_s >= 1000 && sensor.points_per_s <= 2e6,
        "sensor.points_per_s must be 1e3..2e6", &e);
  check(sensor.frame_rate_hz >= 1 && sensor.frame_rate_hz <= 100,
        "sensor.frame_rate_hz must be 1..100", &e);
  check(std::fmod(kTrajectoryRateHz, sensor.frame_rate_hz) == 0,
        "sensor.frame_rate_hz must divide 100", &e);
  check(sensor.fov_min_deg >= -90 && sensor.fov_min_deg < sensor.fov_max_deg &&
            sensor.fov_max_deg <= 90,
        "sensor: need -90 <= fov_min_deg < fov_max_deg <= 90", &e);
  check(sensor.min_range_m >= 0 && sensor.min_range_m < sensor.max_range_m &&
            sensor.max_range_m <= 200,
        "sensor: need 0 <= min_range_m < max_range_m <= 200", &e);
  check(sensor.range_noise_m >= 0 && sensor.range_noise_m < 1, "sensor.range_noise_m: 0..1", &e);
  check(sensor.divergence_deg >= 0 && sensor.divergence_deg < 5, "sensor.divergence_deg: 0..5", &e);
  check(sensor.dropout >= 0 && sensor.dropout < 1, "sensor.dropout must be 0..1", &e);
}

void checkMotion(const MotionParams& motion, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(motion.speed_min_mps > 0.05 && motion.speed_min_mps <= motion.speed_max_mps &&
            motion.speed_max_mps <= 5,
        "motion: need 0.05 < speed_min_mps <= speed_max_mps <= 5", &e);
  check(motion.head_height_m > 0.2 && motion.head_height_m < 5, "motion.head_height_m: 0.2..5", &e);
  check(motion.bob_amplitude_m >= 0 && motion.step_frequency_hz > 0,
        "motion: bob_amplitude_m >= 0, step_frequency_hz > 0", &e);
  check(motion.look_around_deg >= 0 && motion.look_around_deg <= 90,
        "motion.look_around_deg must be 0..90", &e);
  check(motion.sway_deg >= 0 && motion.sway_deg <= 10, "motion.sway_deg must be 0..10", &e);
  check(motion.clearance_m >= 0.1 && motion.clearance_m <= 3, "motion.clearance_m: 0.1..3", &e);
}

void checkOdometry(const OdometryParams& odometry, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(odometry.trans_drift_min >= 0 && odometry.trans_drift_min <= odometry.trans_drift_max &&
            odometry.trans_drift_max <= 0.2,
        "odometry: need 0 <= trans_drift_min <= trans_drift_max <= 0.2", &e);
  check(odometry.yaw_drift_min_deg_per_m >= 0 &&
            odometry.yaw_drift_min_deg_per_m <= odometry.yaw_drift_max_deg_per_m &&
            odometry.yaw_drift_max_deg_per_m <= 1,
        "odometry: need 0 <= yaw_drift_min_deg_per_m <= yaw_drift_max_deg_per_m <= 1", &e);
  check(odometry.tilt_sd_deg >= 0 && odometry.tilt_sd_deg <= 5, "odometry.tilt_sd_deg: 0..5", &e);
  check(odometry.tilt_time_s > 0, "odometry.tilt_time_s must be > 0", &e);
}

void checkFastLio(const FastLioParams& f, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(f.init_tilt_min_deg >= 0 && f.init_tilt_min_deg <= f.init_tilt_max_deg &&
            f.init_tilt_max_deg <= 30,
        "fastlio: need 0 <= init_tilt_min_deg <= init_tilt_max_deg <= 30", &e);
  check(f.point_filter_num >= 1 && f.point_filter_num <= 100, "fastlio.point_filter_num: 1..100",
        &e);
}

// A submap is a whole number of frames.
void checkSubmap(const SubmapParams& submap, const SensorParams& sensor,
                 std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(submap.duration_s >= 0.5 && submap.duration_s <= 600, "submap.duration_s: 0.5..600", &e);
  const double frames_per_submap = submap.duration_s * sensor.frame_rate_hz;
  check(std::abs(frames_per_submap - std::round(frames_per_submap)) < 1e-6,
        "submap.duration_s must be a whole number of frames (1 / sensor.frame_rate_hz)", &e);
  check(submap.voxel_m >= 0.005 && submap.voxel_m <= 1, "submap.voxel_m: 0.005..1", &e);
}

constexpr size_t kMaxSceneRobots = 64;
constexpr size_t kMaxRouteWaypoints = 1000;
constexpr double kMaxRouteLengthM = 20000.0;

// Straight-line length of a route through its waypoints [m] (NaN waypoints give NaN).
double routeLength(const RobotRoute& r) {
  double len = 0.0;
  for (size_t i = 1; i < r.waypoints.size(); ++i)
    len += (r.waypoints[i] - r.waypoints[i - 1]).norm();
  return len;
}

constexpr uint64_t kMaxYamlBytes = uint64_t{16} << 20;

// Waypoints are checked against the plot only for generated stands: a stem map sets its own
// plot extent.
void checkRobots(const std::vector<RobotRoute>& robots, const PlotParams& plot,
                 const StemParams& stems, std::ostringstream* errors) {
  std::ostringstream& e = *errors;
  check(!robots.empty(), "robots: at least one robot", &e);
  // Bounds (docs/limits.md): 10,000 robots or waypoints ran on for gigabytes.
  check(robots.size() <= kMaxSceneRobots,
        "robots: at most " + std::to_string(kMaxSceneRobots) + " robots", &e);
  const std::regex name_re("[A-Za-z0-9_]+");
  std::set<std::string> names;
  for (const auto& r : robots) {
    check(std::regex_match(r.name, name_re), "robots: bad name '" + r.name + "'", &e);
    check(names.insert(r.name).second, "robots: duplicate name '" + r.name + "'", &e);
    check(r.waypoints.size() >= 2, "robots." + r.name + ": at least 2 waypoints", &e);
    check(r.start_s >= 0 && r.start_s <= 86400, "robots." + r.name + ".start_s must be 0..86400",
          &e);
    check(r.waypoints.size() <= kMaxRouteWaypoints,
          "robots." + r.name + ": at most " + std::to_string(kMaxRouteWaypoints) + " waypoints",
          &e);
    check(
        routeLength(r) <= kMaxRouteLengthM,
        "robots." + r.name + ": route longer than " + std::to_string(int(kMaxRouteLengthM)) + " m",
        &e);
    // A route of coinciding waypoints has no length: the walk overran its one-point path.
    check(r.waypoints.size() < 2 || routeLength(r) >= 1.0,
          "robots." + r.name + ": waypoints coincide (the route is shorter than 1 m)", &e);
    check(!r.tilt_deg || (*r.tilt_deg >= 0 && *r.tilt_deg <= 30),
          "robots." + r.name + ".tilt_deg must be 0..30", &e);
    check(!r.tilt_azimuth_deg || std::isfinite(*r.tilt_azimuth_deg),
          "robots." + r.name + ".tilt_azimuth_deg must be a number", &e);
    if (stems.stem_map.empty()) {
      for (const auto& w : r.waypoints) {
        check(w.x() >= 0 && w.y() >= 0 && w.x() <= plot.size_x_m && w.y() <= plot.size_y_m,
              "robots." + r.name + ": waypoint outside the plot", &e);
      }
    }
  }
}

}  // namespace

double Trajectory::duration() const {
  return T_W_B.empty() ? 0.0 : static_cast<double>(T_W_B.size() - 1) / kTrajectoryRateHz;
}

std::string SceneParams::validate() const {
  std::ostringstream e;
  // Stamps are ROS times (uint32 seconds): a NaN or 1e300 epoch gave NaN or equal stamps.
  check(std::isfinite(epoch_s) && epoch_s >= 0 && epoch_s <= 4e9, "epoch_s must be 0..4e9", &e);
  checkPlot(plot, &e);
  checkTerrain(terrain, &e);
  checkStems(stems, &e);
  checkTrees(trees, &e);
  checkUnderstory(understory, &e);
  checkSensor(sensor, &e);
  checkMotion(motion, &e);
  checkOdometry(odometry, &e);
  checkFastLio(fastlio, &e);
  checkSubmap(submap, sensor, &e);
  checkRobots(robots, plot, stems, &e);
  check(bag_layout == "namespaced" || bag_layout == "fastlio",
        "bag_layout must be namespaced or fastlio", &e);
  return e.str();
}

namespace {

// Parses the file and checks its top-level keys; YAML errors name the file and line.
YAML::Node loadSceneRoot(const std::string& path) {
  YAML::Node root;
  // A folder read as "basic_filebuf::underflow", a FIFO blocked: checked before opening.
  const std::string problem = regularFileProblem(path, kMaxYamlBytes);
  if (!problem.empty()) throw ParamError(path + ": " + problem);
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw ParamError(path + ": cannot read the file");
  } catch (const YAML::Exception& ex) {
    throw ParamError(path + ": YAML error at line " + std::to_string(ex.mark.line + 1) + ": " +
                     ex.msg);
  } catch (const std::exception& ex) {
    throw ParamError(path + ": cannot read the file: " + ex.what());
  }
  if (!root.IsMap()) throw ParamError(path + ": the scene must be a YAML map");
  static const std::set<std::string> kTop = {"name",    "description", "epoch_s",   "plot",
                                             "terrain", "stems",       "trees",     "understory",
                                             "sensor",  "motion",      "odometry",  "fastlio",
                                             "submap",  "robots",      "bag_layout"};
  for (const auto& kv : root) {
    // A map or list as a key (found by fuzz_scene) would throw yaml-cpp's conversion error.
    if (!kv.first.IsScalar()) throw ParamError(path + ": a top-level key is not a name");
    const std::string key = kv.first.as<std::string>();
    if (!kTop.count(key)) throw ParamError(path + ": unknown key '" + key + "'");
  }
  return root;
}

// One entry of `robots`; `where` names it in errors.
RobotRoute readRobot(const YAML::Node& r, const std::string& where) {
  if (!r.IsMap()) throw ParamError(where + ": must be a map");
  for (const auto& kv : r) {
    if (!kv.first.IsScalar()) throw ParamError(where + ": a key is not a name");
    const std::string key = kv.first.as<std::string>();
    if (key != "name" && key != "waypoints" && key != "start_s" && key != "tilt_deg" &&
        key != "tilt_azimuth_deg") {
      throw ParamError(where + ": unknown key '" + key + "'");
    }
  }
  RobotRoute route;
  try {
    route.name = r["name"].as<std::string>("");
    route.start_s = r["start_s"].as<double>(0.0);
    if (r["tilt_deg"]) route.tilt_deg = r["tilt_deg"].as<double>();
    if (r["tilt_azimuth_deg"]) route.tilt_azimuth_deg = r["tilt_azimuth_deg"].as<double>();
    for (const auto& w : r["waypoints"]) {
      const auto xy = w.as<std::vector<double>>();
      if (xy.size() != 2) throw ParamError(where + ": a waypoint must be [x, y]");
      route.waypoints.emplace_back(xy[0], xy[1]);
    }
  } catch (const YAML::Exception&) {
    throw ParamError(where +
                     ": wrong type (name: string, start_s, tilt_deg, tilt_azimuth_deg: "
                     "number, waypoints: [[x, y], ...])");
  }
  return route;
}

std::vector<RobotRoute> readRobots(const YAML::Node& root, const std::string& path) {
  std::vector<RobotRoute> routes;
  const YAML::Node robots = root["robots"];
  if (!robots) return routes;
  if (!robots.IsSequence()) throw ParamError(path + ": robots: must be a list");
  for (size_t i = 0; i < robots.size(); ++i) {
    routes.push_back(readRobot(robots[i], path + ": robots[" + std::to_string(i) + "]"));
  }
  return routes;
}

}  // namespace

SceneParams loadSceneYaml(const std::string& path) {
  const YAML::Node root = loadSceneRoot(path);
  SceneParams s;
  try {
    if (root["name"]) s.name = root["name"].as<std::string>();
    if (root["description"]) s.description = root["description"].as<std::string>();
    if (root["epoch_s"]) s.epoch_s = root["epoch_s"].as<double>();
    if (root["bag_layout"]) s.bag_layout = root["bag_layout"].as<std::string>();
  } catch (const YAML::Exception&) {
    throw ParamError(path + ": name/description/epoch_s/bag_layout: wrong type");
  }
  readSection(root, "plot", path, &s.plot);
  readSection(root, "terrain", path, &s.terrain);
  readSection(root, "stems", path, &s.stems);
  readSection(root, "trees", path, &s.trees);
  readSection(root, "understory", path, &s.understory);
  readSection(root, "sensor", path, &s.sensor);
  readSection(root, "motion", path, &s.motion);
  readSection(root, "odometry", path, &s.odometry);
  readSection(root, "fastlio", path, &s.fastlio);
  readSection(root, "submap", path, &s.submap);
  s.robots = readRobots(root, path);
  // The stem map travels with the scene: relative to the YAML's folder, not the working one.
  if (!s.stems.stem_map.empty() && std::filesystem::path(s.stems.stem_map).is_relative()) {
    const auto dir = std::filesystem::path(path).parent_path();
    s.stems.stem_map = (dir / s.stems.stem_map).lexically_normal().string();
  }
  const std::string problems = s.validate();
  if (!problems.empty()) {
    std::string first = problems.substr(0, problems.find('\n'));
    throw ParamError(path + ": " + first);
  }
  return s;
}

std::string sceneToYaml(const SceneParams& s) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << s.name;
  out << YAML::Key << "description" << YAML::Value << s.description;
  out << YAML::Key << "epoch_s" << YAML::Value << s.epoch_s;
  writeSection(&out, "plot", s.plot);
  writeSection(&out, "terrain", s.terrain);
  writeSection(&out, "stems", s.stems);
  writeSection(&out, "trees", s.trees);
  writeSection(&out, "understory", s.understory);
  writeSection(&out, "sensor", s.sensor);
  writeSection(&out, "motion", s.motion);
  writeSection(&out, "odometry", s.odometry);
  // Only when used, so that the description of a levelled scene stays as it was.
  if (!s.fastlio.isDefault()) writeSection(&out, "fastlio", s.fastlio);
  writeSection(&out, "submap", s.submap);
  out << YAML::Key << "robots" << YAML::Value << YAML::BeginSeq;
  for (const auto& r : s.robots) {
    out << YAML::BeginMap << YAML::Key << "name" << YAML::Value << r.name;
    out << YAML::Key << "start_s" << YAML::Value << r.start_s;
    if (r.tilt_deg) out << YAML::Key << "tilt_deg" << YAML::Value << *r.tilt_deg;
    if (r.tilt_azimuth_deg) {
      out << YAML::Key << "tilt_azimuth_deg" << YAML::Value << *r.tilt_azimuth_deg;
    }
    out << YAML::Key << "waypoints" << YAML::Value << YAML::Flow << YAML::BeginSeq;
    for (const auto& w : r.waypoints) {
      out << YAML::Flow << YAML::BeginSeq << w.x() << w.y() << YAML::EndSeq;
    }
    out << YAML::EndSeq << YAML::EndMap;
  }
  out << YAML::EndSeq;
  // Only when set: a dataset of the default layout is written as before.
  if (s.bag_layout != "namespaced") out << YAML::Key << "bag_layout" << YAML::Value << s.bag_layout;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace dtif::sim
