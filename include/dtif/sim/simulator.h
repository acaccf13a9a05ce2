// Forest survey simulator (`dtif simulate`): a forest scene (terrain, trees, understory), several
// walking operators with a Livox MID-360 on a helmet, a FAST-LIO2-like drifting odometry, and
// submaps as the dtif front end would cut them (DATASET.md). Deterministic for a seed.
//
// Data flow: SceneParams (YAML) -> World (sim_world.h) + routes -> per robot, 10 Hz frames
// (FrameSink, e.g. a rosbag writer) -> submaps in their frame S (SubmapSink, e.g. the dataset
// writer). Frames are streamed; no more than one frame and one submap's voxels per robot are
// held in memory.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "dtif/core/types.h"

namespace dtif::sim {

/// Plot extent. Generated stems fill [0, size_x_m] x [0, size_y_m] in W; a stem map is shifted
/// so that its bounding box starts at (margin_m, margin_m) and the plot is enlarged to fit it.
struct PlotParams {
  double size_x_m = 80.0;  ///< plot extent along x [m]
  double size_y_m = 60.0;  ///< plot extent along y [m]
  double margin_m = 5.0;   ///< border around a loaded stem map [m]
  template <class V>
  void visit(V& v) {
    v("size_x_m", size_x_m);
    v("size_y_m", size_y_m);
    v("margin_m", margin_m);
  }
};

/// Terrain: a tilted plane plus smooth hills plus small-scale roughness.
struct TerrainParams {
  double slope_deg = 5.0;           ///< slope of the mean plane [deg]
  double slope_azimuth_deg = 30.0;  ///< direction of steepest ascent, from +x [deg]
  double hill_amplitude_m = 1.0;    ///< amplitude of the smooth hills [m]
  double hill_wavelength_m = 30.0;  ///< typical wavelength of the hills [m]
  double roughness_m = 0.05;        ///< amplitude of small-scale bumps (0.5-2 m scale) [m]
  template <class V>
  void visit(V& v) {
    v("slope_deg", slope_deg);
    v("slope_azimuth_deg", slope_azimuth_deg);
    v("hill_amplitude_m", hill_amplitude_m);
    v("hill_wavelength_m", hill_wavelength_m);
    v("roughness_m", roughness_m);
  }
};

/// Trunks (trees above the sapling size): positions, DBH, shape.
struct StemParams {
  /// CSV stem map `x_m,y_m,dbh_m[,...]` (header optional); relative paths are relative to the
  /// scene YAML's folder. Empty: stems are generated with the fields below.
  std::string stem_map;
  double density_per_ha = 600.0;  ///< generated stems per hectare [1/ha]
  /// Spatial pattern: `random` (hard-core Poisson), `clustered` (Thomas-like), `grid`.
  std::string pattern = "random";
  double min_spacing_m = 0.8;     ///< hard-core distance between generated stems [m]
  double cluster_radius_m = 5.0;  ///< `clustered`: radius of a cluster [m]
  double cluster_fraction = 0.7;  ///< `clustered`: fraction of stems inside clusters [0..1]
  double clusters_per_ha = 10.0;  ///< `clustered`: cluster centres per hectare [1/ha]
  double grid_spacing_x_m = 3.0;  ///< `grid`: row spacing [m]
  double grid_spacing_y_m = 3.0;  ///< `grid`: spacing within a row [m]
  double grid_angle_deg = 10.0;   ///< `grid`: rotation of the rows [deg]
  double grid_jitter_m = 0.15;    ///< `grid`: sigma of the planting error [m]
  double grid_missing = 0.05;     ///< `grid`: fraction of missing trees [0..1]
  double dbh_mean_m = 0.30;       ///< DBH mean (log-normal) [m]
  double dbh_sd_m = 0.10;         ///< DBH standard deviation [m]
  double dbh_min_m = 0.10;        ///< smallest trunk DBH [m]
  double dbh_max_m = 0.80;        ///< largest trunk DBH [m]
  double dead_fraction = 0.08;    ///< snags: dead stems broken at 2-12 m, no crown [0..1]
  double lean_max_deg = 4.0;      ///< largest lean from the vertical [deg]
  double ellipticity = 0.08;      ///< largest relative difference of the section axes [0..1]
  double bark_roughness = 0.03;   ///< relative radial roughness of the bark [0..1]
  template <class V>
  void visit(V& v) {
    v("stem_map", stem_map);
    v("density_per_ha", density_per_ha);
    v("pattern", pattern);
    v("min_spacing_m", min_spacing_m);
    v("cluster_radius_m", cluster_radius_m);
    v("cluster_fraction", cluster_fraction);
    v("clusters_per_ha", clusters_per_ha);
    v("grid_spacing_x_m", grid_spacing_x_m);
    v("grid_spacing_y_m", grid_spacing_y_m);
    v("grid_angle_deg", grid_angle_deg);
    v("grid_jitter_m", grid_jitter_m);
    v("grid_missing", grid_missing);
    v("dbh_mean_m", dbh_mean_m);
    v("dbh_sd_m", dbh_sd_m);
    v("dbh_min_m", dbh_min_m);
    v("dbh_max_m", dbh_max_m);
    v("dead_fraction", dead_fraction);
    v("lean_max_deg", lean_max_deg);
    v("ellipticity", ellipticity);
    v("bark_roughness", bark_roughness);
  }
};

/// Tree architecture (height, crown, branches) as a function of DBH.
struct TreeParams {
  double height_at_30cm_m = 24.0;     ///< height of a tree of DBH 0.30 m [m]
  double height_exponent = 0.6;       ///< height ~ DBH^exponent
  double crown_base_frac = 0.45;      ///< crown base height / tree height [0..1]
  double crown_radius_per_dbh = 8.0;  ///< crown radius = 0.8 m + this * DBH [m/m]
  double crown_density = 0.8;         ///< foliage attenuation inside a crown [1/m]
  double taper = 0.012;               ///< stem radius decrease per metre of height [m/m]
  double branches_per_m = 1.5;        ///< (dead) branches per metre of stem below the crown
  double branch_min_h_m = 1.0;        ///< lowest branch above the base [m]
  double branch_length_m = 1.0;       ///< mean branch length [m]
  template <class V>
  void visit(V& v) {
    v("height_at_30cm_m", height_at_30cm_m);
    v("height_exponent", height_exponent);
    v("crown_base_frac", crown_base_frac);
    v("crown_radius_per_dbh", crown_radius_per_dbh);
    v("crown_density", crown_density);
    v("taper", taper);
    v("branches_per_m", branches_per_m);
    v("branch_min_h_m", branch_min_h_m);
    v("branch_length_m", branch_length_m);
  }
};

/// Clutter near the ground.
struct UnderstoryParams {
  double saplings_per_ha = 300.0;  ///< young trees below trunk size [1/ha]
  /// Sapling DBH is uniform in [sapling_dbh_min_m, min(sapling_dbh_max_m, 0.9 stems.dbh_min_m)]
  /// and height uniform in [sapling_height_min_m, sapling_height_max_m]. Juveniles of open
  /// stands (DBH 3-7 cm, 3-8 m tall) reach the trunk slab and the circle-fit band.
  double sapling_dbh_min_m = 0.01;    ///< [m]
  double sapling_dbh_max_m = 0.07;    ///< [m]
  double sapling_height_min_m = 1.0;  ///< [m]
  double sapling_height_max_m = 5.0;  ///< [m]
  double shrubs_per_ha = 300.0;       ///< shrubs (porous foliage volumes) [1/ha]
  double shrub_radius_m = 0.8;        ///< mean shrub radius [m]
  double shrub_density = 2.5;         ///< foliage attenuation inside a shrub [1/m]
  double logs_per_ha = 20.0;          ///< fallen logs [1/ha]
  template <class V>
  void visit(V& v) {
    v("saplings_per_ha", saplings_per_ha);
    v("sapling_dbh_min_m", sapling_dbh_min_m);
    v("sapling_dbh_max_m", sapling_dbh_max_m);
    v("sapling_height_min_m", sapling_height_min_m);
    v("sapling_height_max_m", sapling_height_max_m);
    v("shrubs_per_ha", shrubs_per_ha);
    v("shrub_radius_m", shrub_radius_m);
    v("shrub_density", shrub_density);
    v("logs_per_ha", logs_per_ha);
  }
};

/// Livox MID-360 model.
struct SensorParams {
  double points_per_s = 200000.0;  ///< point rate [1/s]
  double frame_rate_hz = 10.0;     ///< frames (cloud_registered messages) per second [Hz]
  double fov_min_deg = -7.0;       ///< lowest elevation [deg]
  double fov_max_deg = 52.0;       ///< highest elevation [deg]
  double min_range_m = 0.1;        ///< blind zone [m]
  double max_range_m = 40.0;       ///< range on bright targets (bark) [m]
  double range_noise_m = 0.02;     ///< range noise sigma [m]
  double divergence_deg = 0.2;     ///< beam divergence (full angle) [deg]
  double dropout = 0.02;           ///< probability that a return is lost [0..1]
  template <class V>
  void visit(V& v) {
    v("points_per_s", points_per_s);
    v("frame_rate_hz", frame_rate_hz);
    v("fov_min_deg", fov_min_deg);
    v("fov_max_deg", fov_max_deg);
    v("min_range_m", min_range_m);
    v("max_range_m", max_range_m);
    v("range_noise_m", range_noise_m);
    v("divergence_deg", divergence_deg);
    v("dropout", dropout);
  }
};

/// Walking operator with a helmet-mounted sensor.
struct MotionParams {
  double speed_min_mps = 0.6;      ///< slowest walking speed [m/s]
  double speed_max_mps = 1.2;      ///< fastest walking speed [m/s]
  double head_height_m = 1.7;      ///< sensor height above the ground [m]
  double bob_amplitude_m = 0.03;   ///< vertical bobbing amplitude [m]
  double step_frequency_hz = 1.8;  ///< bobbing frequency [Hz]
  double look_around_deg = 20.0;   ///< amplitude of head yaw around the walking direction [deg]
  double sway_deg = 1.5;           ///< amplitude of head roll/pitch sway [deg]
  double clearance_m = 0.5;        ///< distance kept from stem surfaces and logs [m]
  template <class V>
  void visit(V& v) {
    v("speed_min_mps", speed_min_mps);
    v("speed_max_mps", speed_max_mps);
    v("head_height_m", head_height_m);
    v("bob_amplitude_m", bob_amplitude_m);
    v("step_frequency_hz", step_frequency_hz);
    v("look_around_deg", look_around_deg);
    v("sway_deg", sway_deg);
    v("clearance_m", clearance_m);
  }
};

/// FAST-LIO2 stand-in. Each robot draws, per axis, a drift rate whose magnitude is uniform in
/// [min, max] (random sign), applied per metre walked; yaw drift rotates the integrated path.
struct OdometryParams {
  double trans_drift_min = 0.005;          ///< x/y/z drift, fraction of distance walked [m/m]
  double trans_drift_max = 0.010;          ///< [m/m]
  double yaw_drift_min_deg_per_m = 0.005;  ///< yaw drift per metre walked [deg/m]
  double yaw_drift_max_deg_per_m = 0.010;  ///< [deg/m]
  double tilt_sd_deg = 0.3;   ///< residual roll/pitch error sigma (slowly varying) [deg]
  double tilt_time_s = 30.0;  ///< correlation time of the roll/pitch error [s]
  template <class V>
  void visit(V& v) {
    v("trans_drift_min", trans_drift_min);
    v("trans_drift_max", trans_drift_max);
    v("yaw_drift_min_deg_per_m", yaw_drift_min_deg_per_m);
    v("yaw_drift_max_deg_per_m", yaw_drift_max_deg_per_m);
    v("tilt_sd_deg", tilt_sd_deg);
    v("tilt_time_s", tilt_time_s);
  }
};

/// How an upstream FAST-LIO2 (`mapping_mid360.launch`) differs from a levelled front end.
/// Defaults reproduce the levelled front end exactly (no tilt, every return).
struct FastLioParams {
  /// camera_init = the IMU's attitude at start-up: each robot's odometry frame O is tilted from
  /// gravity by an angle drawn uniformly in [init_tilt_min_deg, init_tilt_max_deg] (own random
  /// stream per robot, so the other draws do not change), towards an azimuth drawn uniformly in
  /// [0, 360) from the robot's initial heading. A robot's `tilt_deg` / `tilt_azimuth_deg`
  /// override the draw. Constant for the run; the submaps' S and T_O_S are in the tilted O,
  /// ground truth T_W_S holds the true attitude.
  double init_tilt_min_deg = 0.0;  ///< [deg], 0..30
  double init_tilt_max_deg = 0.0;  ///< [deg], init_tilt_min_deg..30
  /// FAST-LIO2's preprocess keeps every Nth valid return of each frame (the MID-360 launch: 3),
  /// before cloud_registered: in the bag and in the submaps alike. 1: every return.
  int point_filter_num = 1;
  bool isDefault() const {
    return init_tilt_min_deg == 0.0 && init_tilt_max_deg == 0.0 && point_filter_num == 1;
  }
  template <class V>
  void visit(V& v) {
    v("init_tilt_min_deg", init_tilt_min_deg);
    v("init_tilt_max_deg", init_tilt_max_deg);
    v("point_filter_num", point_filter_num);
  }
};

/// Submap assembly (what the dtif front end does with cloud_registered).
struct SubmapParams {
  double duration_s = 10.0;  ///< time window of one submap [s]
  double voxel_m = 0.05;     ///< voxel size of the centroid downsampling [m]
  template <class V>
  void visit(V& v) {
    v("duration_s", duration_s);
    v("voxel_m", voxel_m);
  }
};

/// One operator: a name and a route of waypoints in W (plot coordinates) walked in order.
struct RobotRoute {
  std::string name;                        ///< `[A-Za-z0-9_]+`
  std::vector<Eigen::Vector2d> waypoints;  ///< [m], at least 2
  double start_s = 0.0;                    ///< start time after the scene epoch [s]
  /// Tilt of this robot's camera_init from gravity [deg] and the direction it leans towards,
  /// from the initial heading, counter-clockwise [deg]; unset: drawn (FastLioParams).
  std::optional<double> tilt_deg, tilt_azimuth_deg;
};

struct SceneParams {
  std::string name = "scene";
  std::string description;
  double epoch_s = 1700000000.0;  ///< stamp of scene time 0 [s]
  PlotParams plot;
  TerrainParams terrain;
  StemParams stems;
  TreeParams trees;
  UnderstoryParams understory;
  SensorParams sensor;
  MotionParams motion;
  OdometryParams odometry;
  FastLioParams fastlio;  ///< YAML section `fastlio`
  SubmapParams submap;
  std::vector<RobotRoute> robots;
  /// Layout of `dtif simulate --bag` when --bag-layout is not given: "namespaced" (one bag,
  /// /<robot>/...) or "fastlio" (a bag per robot with a stock FAST-LIO2 unit's names; sim_bag.h).
  std::string bag_layout = "namespaced";

  /// Empty when valid, else the problems, one per line.
  std::string validate() const;
};

/// Reads a scene YAML (see config/scenes/). Unknown keys, wrong types and invalid values throw
/// ParamError naming the file. A relative `stems.stem_map` is resolved against the YAML's folder.
SceneParams loadSceneYaml(const std::string& path);

/// The YAML text of a scene (for dataset.yaml).
std::string sceneToYaml(const SceneParams& scene);

/// One 10 Hz frame as FAST-LIO2 publishes it. Points are de-skewed into the robot's odometry
/// frame O (`cloud_registered`); poses at the frame's end stamp.
struct Frame {
  std::string robot;
  int robot_index = 0;
  double stamp = 0.0;                   ///< end of the frame [s]
  std::vector<Eigen::Vector3f> points;  ///< in O [m]
  std::vector<float> intensity;         ///< per point, 0-255 (reflectivity-like)
  Pose T_O_B = Pose::Identity();        ///< drifting odometry (body = sensor)
  Pose T_W_B = Pose::Identity();        ///< ground truth
};

/// Receives frames. Calls are serialised (never concurrent); frames of one robot arrive in time
/// order, robots interleave arbitrarily. The frame is only valid during the call.
class FrameSink {
 public:
  virtual ~FrameSink() = default;
  virtual void onFrame(const Frame& frame) = 0;
};

/// A finished submap. Points are in S; valid only during the call.
struct Submap {
  int64_t id = -1;  ///< rank of the anchor stamp over all robots (acquisition order)
  std::string robot;
  int robot_index = 0;
  double stamp = 0.0;                   ///< anchor time = centre of the window [s]
  Pose T_O_S = Pose::Identity();        ///< odometry (drifting)
  Pose T_W_S = Pose::Identity();        ///< ground truth
  std::vector<Eigen::Vector3f> points;  ///< voxel centroids in S [m]
  size_t raw_points = 0;                ///< returns before downsampling
};

/// Receives submaps, in any order and possibly concurrently from several threads (so that
/// writing one overlaps scanning the next): implementations synchronise their own state. The
/// submap is valid only during the call.
class SubmapSink {
 public:
  virtual ~SubmapSink() = default;
  virtual void onSubmap(const Submap& submap) = 0;
};

class World;

/// Per-robot ground-truth and odometry trajectories, sampled at `kTrajectoryRateHz`.
struct Trajectory {
  std::string robot;
  double start_s = 0.0;           ///< scene time of sample 0 [s]
  std::vector<Pose> T_W_B;        ///< ground truth
  std::vector<Pose> T_O_B;        ///< drifting odometry
  std::vector<double> distance;   ///< distance walked at each sample [m]
  double tilt_deg = 0.0;          ///< camera_init's tilt from gravity (FastLioParams) [deg]
  double tilt_azimuth_deg = 0.0;  ///< towards which it leans, from the initial heading [deg]
  /// Gravity's "up" in O (camera_init), unit: (0, 0, 1) when O is level.
  Eigen::Vector3d up_O = Eigen::Vector3d::UnitZ();
  double duration() const;  ///< [s]
};
constexpr double kTrajectoryRateHz = 100.0;

/// Summary of a run (sizes and timing, for the tool's report and dataset.yaml).
struct SimulationStats {
  size_t stems = 0, saplings = 0, shrubs = 0, logs = 0, branches = 0;
  size_t frames = 0, rays = 0, returns = 0, submaps = 0;
  double mean_submap_points = 0.0;
  double seconds = 0.0;  ///< wall-clock time of run() [s]
};

/// Builds the scene and runs the survey. Construction generates the forest and all trajectories
/// (cheap); run() casts the rays. Not thread-safe; run() may use several threads internally.
class Simulator {
 public:
  Simulator(const SceneParams& scene, uint64_t seed);
  ~Simulator();

  const SceneParams& scene() const { return scene_; }
  const World& world() const { return *world_; }
  const std::vector<Trajectory>& trajectories() const { return trajectories_; }

  /// Simulates every robot. `frames` may be null. Work is split into (robot, submap window)
  /// units, each with its own random streams, over `threads` threads (<= 0: the hardware
  /// concurrency). Output does not depend on `threads`.
  SimulationStats run(FrameSink* frames, SubmapSink* submaps, int threads = 0);

 private:
  SceneParams scene_;
  uint64_t seed_;
  std::unique_ptr<World> world_;
  std::vector<Trajectory> trajectories_;
};

/// Pairs of submaps by ground-truth overlap, computed like DATASET.md's (occupied 1 m cells of
/// points 0.3-3 m above ground) but with the true terrain as ground.
struct LoopStats {
  size_t inter_robot_loops = 0;  ///< pairs of different robots with overlap >= 0.3
  size_t intra_robot_loops = 0;  ///< same robot, stamps >= 30 s apart, overlap >= 0.3
  size_t disjoint_pairs = 0;     ///< pairs with overlap < 0.05 (must not match)
  size_t pairs = 0;              ///< pairs considered (same robot: >= 30 s apart)
  double max_overlap_between_robots = 0.0;
};

/// Writes a simulated survey as a dataset (DATASET.md) into `dir`, plus dataset.yaml, and
/// optionally a top-down PNG. `frames` (may be null) also receives every frame.
struct DatasetRunResult {
  SimulationStats stats;
  LoopStats loops;
};
DatasetRunResult simulateDataset(const SceneParams& scene, uint64_t seed, const std::string& dir,
                                 FrameSink* frames = nullptr, const std::string& png_path = "",
                                 int threads = 0);

/// Top-down picture: terrain shading, stems (by DBH), saplings, shrubs, logs, trajectories per
/// robot and the extents of the submaps. `px_per_m` pixels per metre.
struct SubmapExtent {
  int robot_index = 0;
  Pose T_W_S = Pose::Identity();
  Eigen::Vector2d min_S{0, 0}, max_S{0, 0};  ///< robust bounding box in S [m]
};
void writeScenePng(const std::string& path, const Simulator& sim,
                   const std::vector<SubmapExtent>& extents, double px_per_m = 6.0);

}  // namespace dtif::sim
