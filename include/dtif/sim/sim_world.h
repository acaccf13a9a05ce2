// The simulated forest: terrain height field, trees, understory, and a ray caster with true
// occlusion (2-D uniform grid walked by DDA over all objects, terrain by sphere tracing).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <random>
#include <vector>

#include "dtif/sim/simulator.h"

namespace dtif::sim {

/// What a ray hit (drives the return's intensity and the range limit of low returns).
enum class Material : uint8_t { kNone = 0, kGround, kBark, kBranch, kFoliage, kLog };

/// A stem: leaning tapered cone with a non-circular, rough section and a root flare.
struct Stem {
  int64_t id = -1;
  Eigen::Vector2d base_xy{0, 0};  ///< axis at the base [m]
  double z_base = 0.0;            ///< terrain height at the axis [m]
  Eigen::Vector2d lean{0, 0};     ///< horizontal axis offset per metre of height [m/m]
  double r_bh = 0.0;              ///< mean radius at 1.3 m [m]
  double taper = 0.0;             ///< radius decrease per metre [m/m]
  double height = 0.0;            ///< top above the base [m]
  // Section shape r(theta) = r * (1 + sum a_n cos(n theta) + b_n sin(n theta)), relative:
  // n = 2 ellipticity, n = 3 lobes, n = 7 bark roughness (also modulated along the height).
  Eigen::Vector2d ell{0, 0};    ///< (a_2, b_2)
  Eigen::Vector2d lobe{0, 0};   ///< (a_3, b_3)
  Eigen::Vector2d rough{0, 0};  ///< (a_7, b_7)
  double rough_phase = 0.0;     ///< phase of the roughness along the height [m]
  bool dead = false;
  bool sapling = false;
  /// Axis position at height h above the base.
  Eigen::Vector2d axisAt(double h) const { return base_xy + lean * h; }
  /// Local radius at height h, section angle theta (the shape the ray caster sees).
  double radiusAt(double h, double theta) const;
  /// Same, with the section direction given as (cos theta, sin theta) (no trigonometry).
  double radiusAtDir(double h, double c, double s) const;
  double maxRadius() const;  ///< bound of radiusAt over the stem
};

/// Finite cylinder (branches, logs).
struct Cylinder {
  Eigen::Vector3d a{0, 0, 0};     ///< one end [m]
  Eigen::Vector3d axis{0, 0, 1};  ///< unit
  double length = 0.0, radius = 0.0;
  Material material = Material::kBranch;
};

/// Porous ellipsoid (crowns, shrubs): a ray crossing a chord of length L returns with
/// probability 1 - exp(-density * L), at an exponentially distributed depth.
struct Foliage {
  Eigen::Vector3d centre{0, 0, 0};
  Eigen::Vector3d radii{1, 1, 1};
  double density = 1.0;  ///< [1/m]
};

struct RayHit {
  double range = 0.0;  ///< along the unit direction [m]; meaningless when kNone
  Material material = Material::kNone;
  int64_t stem_id = -1;  ///< when a stem (trunk or sapling) was hit
};

/// Thread-safety: const methods may be called concurrently with distinct RayScratch objects.
class World {
 public:
  /// Per-thread state of the ray caster (mailboxes, random stream of foliage hits).
  struct RayScratch {
    std::vector<uint32_t> mailbox;
    uint32_t ray = 0;
    std::mt19937_64 rng;
  };

  /// Generates everything from the scene parameters (stems from `scene.stems.stem_map` if set).
  World(const SceneParams& scene, uint64_t seed);
  /// A world holding exactly the given objects (tests); flat terrain at z = 0 when terrain
  /// parameters are all zero.
  World(const SceneParams& scene, std::vector<Stem> stems, std::vector<Cylinder> cylinders,
        std::vector<Foliage> foliage);

  double terrainHeight(double x, double y) const;
  /// First hit along o + t d (d unit), t in [t_min, t_max]; kNone when nothing.
  RayHit castRay(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max,
                 RayScratch* scratch) const;
  RayScratch makeScratch(uint64_t seed) const;

  const std::vector<Stem>& stems() const { return stems_; }  ///< trunks and saplings
  const std::vector<Cylinder>& cylinders() const { return cylinders_; }
  const std::vector<Foliage>& foliage() const { return foliage_; }
  size_t numShrubs() const { return num_shrubs_; }
  size_t numLogs() const { return num_logs_; }
  Eigen::Vector2d minXy() const { return min_xy_; }  ///< extent of the terrain grid [m]
  Eigen::Vector2d maxXy() const { return max_xy_; }
  Eigen::Vector2d plotSize() const { return plot_size_; }  ///< stems live in [0, size]

 private:
  struct Ray;

  // Generation, in the order the constructor draws from its random stream.
  void buildTerrain(const TerrainParams& p, std::mt19937_64& rng);
  /// A trunk of the given DBH [m] standing at xy_bh [m] (at breast height), with its branches
  /// and crown.
  void addTrunk(const Eigen::Vector2d& xy_bh, double dbh, const StemParams& sp,
                const TreeParams& tp, std::mt19937_64& rng);
  void addBranches(const Stem& s, double dbh, double branch_top, const TreeParams& tp,
                   std::mt19937_64& rng);
  void addSaplings(const UnderstoryParams& up, const StemParams& sp, double area_ha,
                   std::mt19937_64& rng);
  void addShrubs(const UnderstoryParams& up, double area_ha, std::mt19937_64& rng);
  void addLogs(const UnderstoryParams& up, double area_ha, std::mt19937_64& rng);
  void buildIndex();
  void boundTerrainPerCell();

  // Ray casting.
  void testCell(size_t cell, double t_cell, double t_out, Ray* ray) const;
  void testItem(uint32_t item, Ray* ray) const;
  double traceTerrain(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t0, double t1,
                      double lip) const;
  bool hitStem(const Stem& s, double bound, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
               double t_max, double* t) const;

  Eigen::Vector2d plot_size_{0, 0};
  Eigen::Vector2d min_xy_{0, 0}, max_xy_{0, 0};
  // Terrain height grid (bilinear), with its largest slope for conservative sphere tracing.
  double terrain_cell_ = 0.25;
  int terrain_nx_ = 0, terrain_ny_ = 0;
  std::vector<float> terrain_;
  double terrain_lipschitz_ = 0.0;
  double terrain_max_z_ = 0.0;
  double object_max_z_ = 0.0;

  std::vector<Stem> stems_;
  std::vector<double> stem_bound_;  ///< maxRadius() of each stem, looked up per ray
  std::vector<Cylinder> cylinders_;
  std::vector<Foliage> foliage_;
  size_t num_shrubs_ = 0, num_logs_ = 0;

  // Uniform 2-D grid over all objects: cell_start_[c]..cell_start_[c+1] index cell_items_;
  // an item is (kind << 30) | index, with its height range so that rays passing above or below
  // it skip the exact test.
  struct CellItem {
    uint32_t item;
    float z_min, z_max;
  };
  void flattenCells(std::vector<std::vector<CellItem>>* cells);
  double grid_cell_ = 2.0;
  int grid_nx_ = 0, grid_ny_ = 0;
  std::vector<uint32_t> cell_start_;
  std::vector<CellItem> cell_items_;
  std::vector<float> cell_top_;         ///< highest object point per cell [m]
  std::vector<float> cell_ground_max_;  ///< highest terrain point per cell [m]
  std::vector<float> cell_ground_lip_;  ///< terrain slope bound per cell [m/m]
  size_t num_items_ = 0;
};

/// The MID-360's non-repetitive scan: 4 emitters, each sweeping azimuth while a triangle-wave
/// elevation with slowly precessing phase fills (-7..52 deg) ever more densely over time.
class ScanPattern {
 public:
  explicit ScanPattern(const SensorParams& p);
  /// Direction (unit, sensor frame: x forward, z up) of point `k` of the whole point stream;
  /// its time is k / points_per_s.
  Eigen::Vector3d direction(uint64_t k) const;
  double pointTime(uint64_t k) const { return static_cast<double>(k) / rate_; }

 private:
  double rate_;
  double el_min_, el_max_;
};

}  // namespace dtif::sim
