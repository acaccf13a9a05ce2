// Forest generation and ray casting.
#include "dtif/sim/sim_world.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include "dtif/core/params.h"

namespace dtif::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kDeg = kPi / 180.0;
/// How far rays may reach beyond the plot: the terrain grid covers the plot plus this [m].
constexpr double kTerrainMargin = 45.0;

enum ItemKind : uint32_t { kItemStem = 0, kItemCylinder = 1, kItemFoliage = 2 };

double uniform(std::mt19937_64& rng, double a, double b) {
  return std::uniform_real_distribution<double>(a, b)(rng);
}
double gauss(std::mt19937_64& rng, double sd) {
  return std::normal_distribution<double>(0.0, sd)(rng);
}
// Two draws for a point or an offset: y first, then x, one draw per statement. That is the order
// gcc evaluated `Eigen::Vector2d(draw_x, draw_y)` in; C++ leaves it open (clang goes left to
// right), so drawing in statements keeps every compiler simulating the same forest.
Eigen::Vector2d uniformIn(std::mt19937_64& rng, const Eigen::Vector2d& size) {
  const double y = uniform(rng, 0, size.y());
  const double x = uniform(rng, 0, size.x());
  return {x, y};
}
Eigen::Vector2d gauss2(std::mt19937_64& rng, double sd) {
  const double y = gauss(rng, sd);
  const double x = gauss(rng, sd);
  return {x, y};
}
int poisson(std::mt19937_64& rng, double mean) {
  return mean <= 0 ? 0 : std::poisson_distribution<int>(mean)(rng);
}

// Log-normal DBH with the given mean and sd, redrawn until inside [min, max].
double drawDbh(std::mt19937_64& rng, const StemParams& p) {
  const double var = p.dbh_sd_m * p.dbh_sd_m;
  const double s2 = std::log(1.0 + var / (p.dbh_mean_m * p.dbh_mean_m));
  const double mu = std::log(p.dbh_mean_m) - 0.5 * s2;
  std::lognormal_distribution<double> dist(mu, std::sqrt(s2));
  for (int i = 0; i < 100; ++i) {
    const double d = dist(rng);
    if (d >= p.dbh_min_m && d <= p.dbh_max_m) return d;
  }
  return std::clamp(p.dbh_mean_m, p.dbh_min_m, p.dbh_max_m);
}

struct StemSeed {
  Eigen::Vector2d xy;
  double dbh;  // <= 0: draw one
};

// Stem map CSV `x_m,y_m,dbh_m[,...]`; header optional; quotes around the header allowed.
std::vector<StemSeed> readStemMap(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ParamError(path + ": cannot read the stem map");
  std::vector<StemSeed> out;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    std::stringstream ss(line);
    std::string f[3];
    int n = 0;
    while (n < 3 && std::getline(ss, f[n], ',')) ++n;
    double v[3] = {0, 0, -1};
    bool ok = n >= 2;
    for (int i = 0; i < n && ok; ++i) {
      char* end = nullptr;
      v[i] = std::strtod(f[i].c_str(), &end);
      if (end == f[i].c_str()) {
        if (i == 2 && (f[i] == "NA" || f[i].empty())) {
          v[i] = -1;  // unknown DBH: drawn from the distribution
        } else {
          ok = false;
        }
      }
    }
    if (!ok) {
      if (out.empty() && line_no == 1) continue;  // header
      throw ParamError(path + ":" + std::to_string(line_no) + ": expected x_m,y_m,dbh_m numbers");
    }
    out.push_back({Eigen::Vector2d(v[0], v[1]), n >= 3 ? v[2] : -1.0});
  }
  if (out.empty()) throw ParamError(path + ": the stem map holds no stems");
  return out;
}

// Hard-core test against already placed stems (small plots: a linear scan is fast enough).
bool farFromAll(const std::vector<StemSeed>& seeds, const Eigen::Vector2d& p, double d) {
  for (const auto& s : seeds) {
    if ((s.xy - p).squaredNorm() < d * d) return false;
  }
  return true;
}

std::vector<StemSeed> generateStems(const StemParams& p, const Eigen::Vector2d& size,
                                    std::mt19937_64& rng) {
  std::vector<StemSeed> seeds;
  const double area_ha = size.x() * size.y() / 1e4;
  const int n = poisson(rng, p.density_per_ha * area_ha);
  auto inside = [&](const Eigen::Vector2d& q) {
    return q.x() >= 0 && q.y() >= 0 && q.x() <= size.x() && q.y() <= size.y();
  };
  if (p.pattern == "grid") {
    const double a = p.grid_angle_deg * kDeg;
    const Eigen::Vector2d ex(std::cos(a), std::sin(a)), ey(-std::sin(a), std::cos(a));
    const Eigen::Vector2d c = 0.5 * size;
    const double reach = size.norm();
    const Eigen::Vector2d offset =
        uniformIn(rng, Eigen::Vector2d(p.grid_spacing_x_m, p.grid_spacing_y_m));
    for (double u = -reach; u <= reach; u += p.grid_spacing_x_m) {
      for (double v = -reach; v <= reach; v += p.grid_spacing_y_m) {
        Eigen::Vector2d q = c + (u + offset.x()) * ex + (v + offset.y()) * ey;
        if (!inside(q)) continue;
        q += gauss2(rng, p.grid_jitter_m);
        if (uniform(rng, 0, 1) < p.grid_missing || !inside(q)) continue;
        seeds.push_back({q, -1});
      }
    }
    return seeds;
  }
  std::vector<Eigen::Vector2d> centres;
  if (p.pattern == "clustered") {
    const int nc = std::max(1, poisson(rng, p.clusters_per_ha * area_ha));
    for (int i = 0; i < nc; ++i) {
      centres.push_back(uniformIn(rng, size));
    }
  }
  for (int i = 0; i < n; ++i) {
    for (int attempt = 0; attempt < 40; ++attempt) {
      Eigen::Vector2d q;
      double spacing = p.min_spacing_m;
      if (!centres.empty() && uniform(rng, 0, 1) < p.cluster_fraction) {
        const auto& c = centres[std::uniform_int_distribution<size_t>(0, centres.size() - 1)(rng)];
        q = c + gauss2(rng, 0.5 * p.cluster_radius_m);
        spacing *= 0.7;  // clusters are tighter
      } else {
        q = uniformIn(rng, size);
      }
      if (inside(q) && farFromAll(seeds, q, spacing)) {
        seeds.push_back({q, -1});
        break;
      }
    }
  }
  return seeds;
}

bool hitCylinder(const Cylinder& cy, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                 double t_min, double* t) {
  const Eigen::Vector3d w = o - cy.a;
  const Eigen::Vector3d dp = d - d.dot(cy.axis) * cy.axis;
  const Eigen::Vector3d wp = w - w.dot(cy.axis) * cy.axis;
  const double a = dp.squaredNorm();
  const double b = dp.dot(wp);
  const double c = wp.squaredNorm() - cy.radius * cy.radius;
  if (a < 1e-12) return false;
  const double disc = b * b - a * c;
  if (disc < 0) return false;
  const double s = std::sqrt(disc);
  for (double r : {(-b - s) / a, (-b + s) / a}) {
    if (r < t_min) continue;
    const double along = (w + r * d).dot(cy.axis);
    if (along >= 0 && along <= cy.length) {
      *t = r;
      return true;
    }
  }
  return false;
}

// Chord of an ellipsoid [t_in, t_out].
bool chordFoliage(const Foliage& f, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                  double* t_in, double* t_out) {
  const Eigen::Vector3d oo = (o - f.centre).cwiseQuotient(f.radii);
  const Eigen::Vector3d dd = d.cwiseQuotient(f.radii);
  const double a = dd.squaredNorm(), b = oo.dot(dd), c = oo.squaredNorm() - 1.0;
  const double disc = b * b - a * c;
  if (disc <= 0) return false;
  const double s = std::sqrt(disc);
  *t_in = (-b - s) / a;
  *t_out = (-b + s) / a;
  return true;
}

}  // namespace

double Stem::radiusAt(double h, double theta) const {
  return radiusAtDir(h, std::cos(theta), std::sin(theta));
}

double Stem::radiusAtDir(double h, double c, double s) const {
  if (h > height) return 0.0;
  double r = std::max(r_bh - taper * (h - 1.3), 0.3 * r_bh);
  // Root flare: stems widen over the lowest half metre (why trunk bases are hard to fit).
  if (h < 2.0) r *= 1.0 + (sapling ? 0.1 : 0.3) * std::exp(-std::max(h, 0.0) / 0.3);
  // cos/sin of n theta by complex powers of (c + i s).
  const double c2 = c * c - s * s, s2 = 2 * c * s;
  const double c3 = c2 * c - s2 * s, s3 = c2 * s + s2 * c;
  const double c4 = c2 * c2 - s2 * s2, s4 = 2 * c2 * s2;
  const double c7 = c4 * c3 - s4 * s3, s7 = c4 * s3 + s4 * c3;
  // Roughness varies along the stem too (triangle wave of period ~0.7 m).
  double ph = 1.4 * h + rough_phase;
  ph -= std::floor(ph);
  const double along = ph < 0.5 ? 4 * ph - 1 : 3 - 4 * ph;
  r *= 1.0 + ell.x() * c2 + ell.y() * s2 + lobe.x() * c3 + lobe.y() * s3 +
       along * (rough.x() * c7 + rough.y() * s7);
  return r;
}

double Stem::maxRadius() const {
  const double r = std::max(r_bh + taper * 1.3, 0.3 * r_bh);
  return r * (sapling ? 1.1 : 1.3) * (1.0 + ell.norm() + lobe.norm() + rough.norm()) + 1e-3;
}

namespace {

// The stems' positions at breast height: from the stem map (shifted to start at the margin,
// the plot grown to fit) or generated over the configured plot. Sets *plot_size.
std::vector<StemSeed> placeStems(const SceneParams& scene, std::mt19937_64& rng,
                                 Eigen::Vector2d* plot_size) {
  *plot_size = Eigen::Vector2d(scene.plot.size_x_m, scene.plot.size_y_m);
  if (scene.stems.stem_map.empty()) return generateStems(scene.stems, *plot_size, rng);
  std::vector<StemSeed> seeds = readStemMap(scene.stems.stem_map);
  Eigen::Vector2d lo = seeds[0].xy, hi = seeds[0].xy;
  for (const auto& s : seeds) {
    lo = lo.cwiseMin(s.xy);
    hi = hi.cwiseMax(s.xy);
  }
  const Eigen::Vector2d m(scene.plot.margin_m, scene.plot.margin_m);
  for (auto& s : seeds) s.xy += m - lo;
  *plot_size = hi - lo + 2 * m;
  return seeds;
}

}  // namespace

// Everything is drawn from one stream, in a fixed order: stems' positions, terrain, trunks
// (each with its branches and crown), saplings, shrubs, logs. Changing the order changes every
// scene.
World::World(const SceneParams& scene, uint64_t seed) {
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ULL + 17);
  const std::vector<StemSeed> seeds = placeStems(scene, rng, &plot_size_);
  min_xy_ = Eigen::Vector2d(-kTerrainMargin, -kTerrainMargin);
  max_xy_ = plot_size_ + Eigen::Vector2d(kTerrainMargin, kTerrainMargin);
  buildTerrain(scene.terrain, rng);
  for (const auto& seed_xy : seeds) {
    const double dbh = seed_xy.dbh > 0 ? seed_xy.dbh : drawDbh(rng, scene.stems);
    addTrunk(seed_xy.xy, dbh, scene.stems, scene.trees, rng);
  }
  const double area_ha = plot_size_.x() * plot_size_.y() / 1e4;
  addSaplings(scene.understory, scene.stems, area_ha, rng);
  addShrubs(scene.understory, area_ha, rng);
  addLogs(scene.understory, area_ha, rng);
  buildIndex();
}

void World::addTrunk(const Eigen::Vector2d& xy_bh, double dbh, const StemParams& sp,
                     const TreeParams& tp, std::mt19937_64& rng) {
  Stem s;
  s.id = static_cast<int64_t>(stems_.size());
  s.r_bh = 0.5 * dbh;
  const double lean = uniform(rng, 0, sp.lean_max_deg) * kDeg;
  const double lean_dir = uniform(rng, -kPi, kPi);
  s.lean = std::tan(lean) * Eigen::Vector2d(std::cos(lean_dir), std::sin(lean_dir));
  // The map gives the position at breast height; the base sits below it along the lean.
  s.base_xy = xy_bh - 1.3 * s.lean;
  s.z_base = terrainHeight(s.base_xy.x(), s.base_xy.y());
  s.taper = tp.taper * uniform(rng, 0.7, 1.3);
  s.height = std::clamp(
      tp.height_at_30cm_m * std::pow(dbh / 0.3, tp.height_exponent) * uniform(rng, 0.85, 1.15), 3.0,
      50.0);
  auto harmonic = [&](double amp) {
    const double ph = uniform(rng, -kPi, kPi);
    return Eigen::Vector2d(amp * std::cos(ph), amp * std::sin(ph));
  };
  s.ell = harmonic(uniform(rng, 0, sp.ellipticity));
  s.lobe = harmonic(uniform(rng, 0, 0.4 * sp.ellipticity));
  s.rough = harmonic(sp.bark_roughness * uniform(rng, 0.5, 1.5));
  s.rough_phase = uniform(rng, 0, 1);
  s.dead = uniform(rng, 0, 1) < sp.dead_fraction;
  if (s.dead) {
    s.height = std::min(s.height, uniform(rng, 2.0, 12.0));  // broken snag
    s.rough *= 1.5;
  }
  const double crown_base =
      std::clamp(tp.crown_base_frac * s.height * uniform(rng, 0.8, 1.2), 2.0, 0.9 * s.height);
  addBranches(s, dbh, s.dead ? s.height : crown_base, tp, rng);
  if (!s.dead && tp.crown_density > 0) {
    Foliage f;
    const double mid = 0.5 * (crown_base + s.height);
    const Eigen::Vector2d cxy = s.axisAt(mid);
    const double cr = (0.8 + tp.crown_radius_per_dbh * dbh) * uniform(rng, 0.8, 1.2);
    f.centre = Eigen::Vector3d(cxy.x(), cxy.y(), s.z_base + mid);
    f.radii = Eigen::Vector3d(cr, cr, 0.5 * (s.height - crown_base));
    f.density = tp.crown_density;
    foliage_.push_back(f);
  }
  stems_.push_back(s);
}

// Branches (mostly dead) between the lowest branch height and `branch_top` (the crown base, or
// the top of a snag): the clutter that sits right in the trunk-extraction slab.
void World::addBranches(const Stem& s, double dbh, double branch_top, const TreeParams& tp,
                        std::mt19937_64& rng) {
  const int nb = poisson(rng, tp.branches_per_m * std::max(0.0, branch_top - tp.branch_min_h_m));
  for (int i = 0; i < nb; ++i) {
    const double h = uniform(rng, tp.branch_min_h_m, branch_top);
    const double az = uniform(rng, -kPi, kPi);
    const double el = uniform(rng, -25, 30) * kDeg;
    Cylinder c;
    c.material = Material::kBranch;
    const Eigen::Vector2d axis_xy = s.axisAt(h);
    c.axis =
        Eigen::Vector3d(std::cos(az) * std::cos(el), std::sin(az) * std::cos(el), std::sin(el));
    const double r0 = std::max(s.r_bh - s.taper * (h - 1.3), 0.3 * s.r_bh);
    c.a = Eigen::Vector3d(axis_xy.x(), axis_xy.y(), s.z_base + h) + 0.8 * r0 * c.axis;
    c.length = tp.branch_length_m * uniform(rng, 0.3, 1.6) * std::sqrt(dbh / 0.3);
    c.radius = uniform(rng, 0.008, 0.025) * std::sqrt(dbh / 0.3);
    cylinders_.push_back(c);
  }
}

// Saplings: thin stems with a small porous crown, anywhere on the plot.
void World::addSaplings(const UnderstoryParams& up, const StemParams& sp, double area_ha,
                        std::mt19937_64& rng) {
  const int n_sap = poisson(rng, up.saplings_per_ha * area_ha);
  for (int i = 0; i < n_sap; ++i) {
    Stem s;
    s.sapling = true;
    s.base_xy = uniformIn(rng, plot_size_);
    s.z_base = terrainHeight(s.base_xy.x(), s.base_xy.y());
    // Saplings stay below the trunks' smallest DBH.
    const double dbh_max = std::min(up.sapling_dbh_max_m, 0.9 * sp.dbh_min_m);
    const double dbh = uniform(rng, std::min(up.sapling_dbh_min_m, dbh_max), dbh_max);
    s.r_bh = 0.5 * dbh;
    s.height = uniform(rng, up.sapling_height_min_m, up.sapling_height_max_m);
    s.taper = 0.3 * s.r_bh / s.height;
    const double lean = uniform(rng, 0, 2 * sp.lean_max_deg + 2) * kDeg;
    const double lean_dir = uniform(rng, -kPi, kPi);
    s.lean = std::tan(lean) * Eigen::Vector2d(std::cos(lean_dir), std::sin(lean_dir));
    s.rough = Eigen::Vector2d(0.02, 0.0);
    stems_.push_back(s);
    Foliage f;
    const double cr = uniform(rng, 0.3, 0.9);
    const Eigen::Vector2d cxy = s.axisAt(0.7 * s.height);
    f.centre = Eigen::Vector3d(cxy.x(), cxy.y(), s.z_base + 0.7 * s.height);
    f.radii = Eigen::Vector3d(cr, cr, 0.3 * s.height);
    f.density = 1.5;
    foliage_.push_back(f);
  }
}

// Shrubs: porous ellipsoids sitting on the ground.
void World::addShrubs(const UnderstoryParams& up, double area_ha, std::mt19937_64& rng) {
  const int n_shrub = poisson(rng, up.shrubs_per_ha * area_ha);
  for (int i = 0; i < n_shrub; ++i) {
    Foliage f;
    const double r = up.shrub_radius_m * uniform(rng, 0.5, 1.5);
    const double x = uniform(rng, 0, plot_size_.x()), y = uniform(rng, 0, plot_size_.y());
    const double rz = r * uniform(rng, 0.5, 1.0);
    f.centre = Eigen::Vector3d(x, y, terrainHeight(x, y) + 0.8 * rz);
    const double ry = r * uniform(rng, 0.8, 1.2);  // y first, as in uniformIn
    const double rx = r * uniform(rng, 0.8, 1.2);
    f.radii = Eigen::Vector3d(rx, ry, rz);
    f.density = up.shrub_density;
    foliage_.push_back(f);
  }
  num_shrubs_ = static_cast<size_t>(n_shrub);
}

// Fallen logs resting on the terrain.
void World::addLogs(const UnderstoryParams& up, double area_ha, std::mt19937_64& rng) {
  const int n_log = poisson(rng, up.logs_per_ha * area_ha);
  for (int i = 0; i < n_log; ++i) {
    const double len = uniform(rng, 2.0, 10.0), r = uniform(rng, 0.08, 0.3);
    const double az = uniform(rng, -kPi, kPi);
    const Eigen::Vector2d c = uniformIn(rng, plot_size_);
    const Eigen::Vector2d u(std::cos(az), std::sin(az));
    const Eigen::Vector2d a2 = c - 0.5 * len * u, b2 = c + 0.5 * len * u;
    const Eigen::Vector3d a(a2.x(), a2.y(), terrainHeight(a2.x(), a2.y()) + 0.7 * r);
    const Eigen::Vector3d b(b2.x(), b2.y(), terrainHeight(b2.x(), b2.y()) + 0.7 * r);
    Cylinder cy;
    cy.material = Material::kLog;
    cy.a = a;
    cy.axis = (b - a).normalized();
    cy.length = (b - a).norm();
    cy.radius = r;
    cylinders_.push_back(cy);
  }
  num_logs_ = static_cast<size_t>(n_log);
}

World::World(const SceneParams& scene, std::vector<Stem> stems, std::vector<Cylinder> cylinders,
             std::vector<Foliage> foliage)
    : stems_(std::move(stems)), cylinders_(std::move(cylinders)), foliage_(std::move(foliage)) {
  plot_size_ = Eigen::Vector2d(scene.plot.size_x_m, scene.plot.size_y_m);
  min_xy_ = Eigen::Vector2d(-kTerrainMargin, -kTerrainMargin);
  max_xy_ = plot_size_ + Eigen::Vector2d(kTerrainMargin, kTerrainMargin);
  std::mt19937_64 rng(1);
  buildTerrain(scene.terrain, rng);
  for (auto& s : stems_) s.z_base = terrainHeight(s.base_xy.x(), s.base_xy.y());
  buildIndex();
}

void World::buildTerrain(const TerrainParams& p, std::mt19937_64& rng) {
  terrain_nx_ = static_cast<int>(std::ceil((max_xy_.x() - min_xy_.x()) / terrain_cell_)) + 1;
  terrain_ny_ = static_cast<int>(std::ceil((max_xy_.y() - min_xy_.y()) / terrain_cell_)) + 1;
  terrain_.assign(static_cast<size_t>(terrain_nx_) * terrain_ny_, 0.0f);
  const double slope = std::tan(p.slope_deg * kDeg);
  const double sa = p.slope_azimuth_deg * kDeg;
  const Eigen::Vector2d centre = 0.5 * plot_size_;
  // Hills: a few plane waves of random direction and wavelength around the configured one.
  struct Wave {
    Eigen::Vector2d k;
    double phase, amp;
  };
  std::vector<Wave> waves;
  for (int i = 0; i < 4; ++i) {
    const double dir = uniform(rng, -kPi, kPi);
    const double lambda = p.hill_wavelength_m * uniform(rng, 0.7, 1.5);
    waves.push_back({2 * kPi / lambda * Eigen::Vector2d(std::cos(dir), std::sin(dir)),
                     uniform(rng, -kPi, kPi), p.hill_amplitude_m * uniform(rng, 0.3, 0.6)});
  }
  // Roughness: random heights on a 1 m lattice, interpolated (bumps of 1-2 m).
  const double lat = 1.0;
  const int lx = static_cast<int>((max_xy_.x() - min_xy_.x()) / lat) + 2;
  const int ly = static_cast<int>((max_xy_.y() - min_xy_.y()) / lat) + 2;
  std::vector<double> bumps(static_cast<size_t>(lx) * ly);
  for (auto& b : bumps) b = p.roughness_m * uniform(rng, -1, 1);
  double max_z = -kInf;
  for (int j = 0; j < terrain_ny_; ++j) {
    for (int i = 0; i < terrain_nx_; ++i) {
      const Eigen::Vector2d q = min_xy_ + terrain_cell_ * Eigen::Vector2d(i, j);
      double z = slope * ((q - centre).dot(Eigen::Vector2d(std::cos(sa), std::sin(sa))));
      for (const auto& w : waves) z += w.amp * std::sin(w.k.dot(q) + w.phase);
      const double fx = (q.x() - min_xy_.x()) / lat, fy = (q.y() - min_xy_.y()) / lat;
      const int bx = std::min(static_cast<int>(fx), lx - 2),
                by = std::min(static_cast<int>(fy), ly - 2);
      const double ux = fx - bx, uy = fy - by;
      auto B = [&](int x, int y) { return bumps[static_cast<size_t>(y) * lx + x]; };
      z += (1 - uy) * ((1 - ux) * B(bx, by) + ux * B(bx + 1, by)) +
           uy * ((1 - ux) * B(bx, by + 1) + ux * B(bx + 1, by + 1));
      terrain_[static_cast<size_t>(j) * terrain_nx_ + i] = static_cast<float>(z);
      max_z = std::max(max_z, z);
    }
  }
  // A bilinear patch's gradient components are convex combinations of its edge differences,
  // so the largest per-cell hypot of the largest edge differences bounds the slope exactly.
  double lip = 0.0;
  for (int j = 0; j + 1 < terrain_ny_; ++j) {
    for (int i = 0; i + 1 < terrain_nx_; ++i) {
      const size_t k = static_cast<size_t>(j) * terrain_nx_ + i;
      const size_t n = k + terrain_nx_;
      const double gx = std::max(std::abs(terrain_[k + 1] - terrain_[k]),
                                 std::abs(terrain_[n + 1] - terrain_[n]));
      const double gy = std::max(std::abs(terrain_[n] - terrain_[k]),
                                 std::abs(terrain_[n + 1] - terrain_[k + 1]));
      lip = std::max(lip, std::hypot(gx, gy) / terrain_cell_);
    }
  }
  terrain_lipschitz_ = lip * 1.01 + 1e-4;
  terrain_max_z_ = max_z;
}

double World::terrainHeight(double x, double y) const {
  double fx = (x - min_xy_.x()) / terrain_cell_, fy = (y - min_xy_.y()) / terrain_cell_;
  fx = std::clamp(fx, 0.0, terrain_nx_ - 1.000001);
  fy = std::clamp(fy, 0.0, terrain_ny_ - 1.000001);
  const int i = static_cast<int>(fx), j = static_cast<int>(fy);
  const double u = fx - i, v = fy - j;
  const float* r0 = &terrain_[static_cast<size_t>(j) * terrain_nx_ + i];
  const float* r1 = r0 + terrain_nx_;
  return (1 - v) * ((1 - u) * r0[0] + u * r0[1]) + v * ((1 - u) * r1[0] + u * r1[1]);
}

void World::buildIndex() {
  grid_nx_ = static_cast<int>(std::ceil((max_xy_.x() - min_xy_.x()) / grid_cell_));
  grid_ny_ = static_cast<int>(std::ceil((max_xy_.y() - min_xy_.y()) / grid_cell_));
  std::vector<std::vector<CellItem>> cells(static_cast<size_t>(grid_nx_) * grid_ny_);
  cell_top_.assign(cells.size(), -1e30f);
  object_max_z_ = terrain_max_z_;
  auto add = [&](uint32_t item, Eigen::Vector2d lo, Eigen::Vector2d hi, double z0, double z1) {
    const int i0 =
        std::clamp(static_cast<int>((lo.x() - min_xy_.x()) / grid_cell_), 0, grid_nx_ - 1);
    const int i1 =
        std::clamp(static_cast<int>((hi.x() - min_xy_.x()) / grid_cell_), 0, grid_nx_ - 1);
    const int j0 =
        std::clamp(static_cast<int>((lo.y() - min_xy_.y()) / grid_cell_), 0, grid_ny_ - 1);
    const int j1 =
        std::clamp(static_cast<int>((hi.y() - min_xy_.y()) / grid_cell_), 0, grid_ny_ - 1);
    for (int j = j0; j <= j1; ++j) {
      for (int i = i0; i <= i1; ++i) {
        const size_t c = static_cast<size_t>(j) * grid_nx_ + i;
        cells[c].push_back({item, static_cast<float>(z0), static_cast<float>(z1)});
        cell_top_[c] = std::max(cell_top_[c], static_cast<float>(z1));
      }
    }
  };
  stem_bound_.resize(stems_.size());
  for (size_t k = 0; k < stems_.size(); ++k) {
    const Stem& s = stems_[k];
    const Eigen::Vector2d a = s.axisAt(-0.5), b = s.axisAt(s.height);
    stem_bound_[k] = s.maxRadius();
    const Eigen::Vector2d r = Eigen::Vector2d::Constant(stem_bound_[k]);
    add((kItemStem << 30) | k, a.cwiseMin(b) - r, a.cwiseMax(b) + r, s.z_base - 0.6,
        s.z_base + s.height + 0.01);
    object_max_z_ = std::max(object_max_z_, s.z_base + s.height);
  }
  for (size_t k = 0; k < cylinders_.size(); ++k) {
    const Cylinder& c = cylinders_[k];
    const Eigen::Vector3d b = c.a + c.length * c.axis;
    const Eigen::Vector2d r = Eigen::Vector2d::Constant(c.radius);
    add((kItemCylinder << 30) | k, c.a.head<2>().cwiseMin(b.head<2>()) - r,
        c.a.head<2>().cwiseMax(b.head<2>()) + r, std::min(c.a.z(), b.z()) - c.radius,
        std::max(c.a.z(), b.z()) + c.radius);
    object_max_z_ = std::max(object_max_z_, std::max(c.a.z(), b.z()) + c.radius);
  }
  for (size_t k = 0; k < foliage_.size(); ++k) {
    const Foliage& f = foliage_[k];
    add((kItemFoliage << 30) | k, f.centre.head<2>() - f.radii.head<2>(),
        f.centre.head<2>() + f.radii.head<2>(), f.centre.z() - f.radii.z(),
        f.centre.z() + f.radii.z());
    object_max_z_ = std::max(object_max_z_, f.centre.z() + f.radii.z());
  }
  num_items_ = stems_.size() + cylinders_.size() + foliage_.size();
  boundTerrainPerCell();
  flattenCells(&cells);
}

// Terrain bounds per cell (highest node and largest slope of the bilinear patches touching
// it), so that rays high above the ground skip it and sphere tracing takes long steps.
void World::boundTerrainPerCell() {
  const size_t n_cells = static_cast<size_t>(grid_nx_) * grid_ny_;
  cell_ground_max_.assign(n_cells, -1e30f);
  cell_ground_lip_.assign(n_cells, 0.0f);
  for (int j = 0; j < grid_ny_; ++j) {
    for (int i = 0; i < grid_nx_; ++i) {
      const size_t c = static_cast<size_t>(j) * grid_nx_ + i;
      const int ti0 = std::max(0, static_cast<int>(i * grid_cell_ / terrain_cell_) - 1);
      const int tj0 = std::max(0, static_cast<int>(j * grid_cell_ / terrain_cell_) - 1);
      const int ti1 =
          std::min(terrain_nx_ - 2, static_cast<int>((i + 1) * grid_cell_ / terrain_cell_) + 1);
      const int tj1 =
          std::min(terrain_ny_ - 2, static_cast<int>((j + 1) * grid_cell_ / terrain_cell_) + 1);
      double zmax = -1e30, lip = 0.0;
      for (int tj = tj0; tj <= tj1; ++tj) {
        for (int ti = ti0; ti <= ti1; ++ti) {
          const size_t k = static_cast<size_t>(tj) * terrain_nx_ + ti;
          const size_t n = k + terrain_nx_;
          zmax = std::max({zmax, double(terrain_[k]), double(terrain_[k + 1]), double(terrain_[n]),
                           double(terrain_[n + 1])});
          const double gx = std::max(std::abs(terrain_[k + 1] - terrain_[k]),
                                     std::abs(terrain_[n + 1] - terrain_[n]));
          const double gy = std::max(std::abs(terrain_[n] - terrain_[k]),
                                     std::abs(terrain_[n + 1] - terrain_[k + 1]));
          lip = std::max(lip, std::hypot(gx, gy) / terrain_cell_);
        }
      }
      cell_ground_max_[c] = static_cast<float>(zmax + 1e-3);
      cell_ground_lip_[c] = static_cast<float>(lip * 1.01 + 1e-4);
    }
  }
}

// Flattens the per-cell lists into cell_start_/cell_items_, each cell's items sorted by their
// lowest point (castRay stops at the first item above the ray).
void World::flattenCells(std::vector<std::vector<CellItem>>* cells_in) {
  std::vector<std::vector<CellItem>>& cells = *cells_in;
  cell_start_.assign(cells.size() + 1, 0);
  cell_items_.clear();
  for (size_t c = 0; c < cells.size(); ++c) {
    std::stable_sort(cells[c].begin(), cells[c].end(),
                     [](const CellItem& a, const CellItem& b) { return a.z_min < b.z_min; });
    cell_start_[c] = static_cast<uint32_t>(cell_items_.size());
    cell_items_.insert(cell_items_.end(), cells[c].begin(), cells[c].end());
  }
  cell_start_[cells.size()] = static_cast<uint32_t>(cell_items_.size());
}

World::RayScratch World::makeScratch(uint64_t seed) const {
  RayScratch s;
  s.mailbox.assign(num_items_ + cylinders_.size() + foliage_.size() + 1, 0);
  s.ray = 0;
  s.rng.seed(seed);
  return s;
}

double World::traceTerrain(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t0, double t1,
                           double lip) const {
  // Sphere tracing: with slope bound `lip`, the height above ground h(t) drops at most s per
  // metre along the ray, so a step of h / s cannot cross the surface.
  const double s = lip * std::hypot(d.x(), d.y()) - d.z();
  auto height = [&](double t) {
    return o.z() + t * d.z() - terrainHeight(o.x() + t * d.x(), o.y() + t * d.y());
  };
  double t = t0, h = height(t0);
  if (h <= 0) return t0;
  if (s <= 0) return kInf;
  for (int it = 0; it < 100; ++it) {
    const double t_next = std::min(t + std::max(h / s, 0.005), t1);
    const double h_next = height(t_next);
    if (h_next <= 0) {
      double lo = t, hi = t_next;  // bisection to ~1 mm
      for (int b = 0; b < 12 && hi - lo > 1e-3; ++b) {
        const double mid = 0.5 * (lo + hi);
        (height(mid) > 0 ? lo : hi) = mid;
      }
      return 0.5 * (lo + hi);
    }
    if (t_next >= t1) return kInf;
    t = t_next;
    h = h_next;
  }
  return kInf;
}

bool World::hitStem(const Stem& s, double bound, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                    double t_max, double* t_hit) const {
  // In the stem's sheared frame the axis is vertical: u(t) = u0 + t u1, h(t) = h0 + t d.z.
  const double h0 = o.z() - s.z_base;
  const Eigen::Vector2d u0 = o.head<2>() - s.base_xy - s.lean * h0;
  const Eigen::Vector2d u1 = d.head<2>() - s.lean * d.z();
  const double R = bound;
  const double a = u1.squaredNorm(), b = u0.dot(u1), c = u0.squaredNorm() - R * R;
  if (a < 1e-12) return false;
  const double disc = b * b - a * c;
  if (disc <= 0) return false;
  const double sq = std::sqrt(disc);
  double t0 = (-b - sq) / a, t1 = (-b + sq) / a;
  // Clip to the stem's height range.
  const double hmin = -0.5, hmax = s.height;
  if (std::abs(d.z()) > 1e-9) {
    double ta = (hmin - h0) / d.z(), tb = (hmax - h0) / d.z();
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  } else if (h0 < hmin || h0 > hmax) {
    return false;
  }
  t0 = std::max(t0, 0.0);
  t1 = std::min(t1, t_max);
  if (t0 >= t1) return false;
  // March the exact (non-circular, rough) surface inside the bounding cylinder, then bisect.
  auto f = [&](double t) {
    const Eigen::Vector2d u = u0 + t * u1;
    const double n = u.norm();
    if (n < 1e-9) return -s.r_bh;
    return n - s.radiusAtDir(h0 + t * d.z(), u.x() / n, u.y() / n);
  };
  const int steps = 12;
  const double dt = (t1 - t0) / steps;
  double prev_t = t0, prev_f = f(t0);
  if (prev_f <= 0) {
    *t_hit = t0;
    return true;
  }
  for (int i = 1; i <= steps; ++i) {
    const double t = t0 + i * dt;
    const double ft = f(t);
    if (ft <= 0) {
      // Steps are at most ~0.1 m long: 7 halvings leave < 1 mm, far below the range noise.
      double lo = prev_t, hi = t;
      for (int k = 0; k < 7; ++k) {
        const double mid = 0.5 * (lo + hi);
        (f(mid) > 0 ? lo : hi) = mid;
      }
      *t_hit = 0.5 * (lo + hi);
      return true;
    }
    prev_t = t;
    prev_f = ft;
  }
  return false;
}

// One ray being cast: its line and limits, and the closest hit so far.
struct World::Ray {
  const Eigen::Vector3d& o;
  const Eigen::Vector3d& d;
  double t_min, t_max;
  uint32_t id;  // mailbox stamp: each object is tested once per ray
  RayScratch* scratch;
  RayHit best;
  double best_t = kInf;
};

RayHit World::castRay(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                      double t_max, RayScratch* scratch) const {
  if (++scratch->ray == 0) {
    std::fill(scratch->mailbox.begin(), scratch->mailbox.end(), 0);
    scratch->ray = 1;
  }
  Ray ray{o, d, t_min, t_max, scratch->ray, scratch, RayHit(), kInf};
  // 2-D DDA over the grid; each cell tests the terrain under it and its objects, in ray order,
  // so the walk stops at the first cell that ends beyond the closest hit.
  const double gx = (o.x() - min_xy_.x()) / grid_cell_, gy = (o.y() - min_xy_.y()) / grid_cell_;
  int ix = static_cast<int>(std::floor(gx)), iy = static_cast<int>(std::floor(gy));
  const int sx = d.x() > 0 ? 1 : -1, sy = d.y() > 0 ? 1 : -1;
  const double tdx = std::abs(d.x()) > 1e-12 ? grid_cell_ / std::abs(d.x()) : kInf;
  const double tdy = std::abs(d.y()) > 1e-12 ? grid_cell_ / std::abs(d.y()) : kInf;
  double tmx = std::abs(d.x()) > 1e-12 ? ((d.x() > 0 ? ix + 1 - gx : gx - ix) * tdx) : kInf;
  double tmy = std::abs(d.y()) > 1e-12 ? ((d.y() > 0 ? iy + 1 - gy : gy - iy) * tdy) : kInf;
  double t_cell = 0.0;
  while (true) {
    if (ix < 0 || iy < 0 || ix >= grid_nx_ || iy >= grid_ny_) break;
    if (d.z() > 0 && o.z() + t_cell * d.z() > object_max_z_) break;
    const size_t cell = static_cast<size_t>(iy) * grid_nx_ + ix;
    const double t_out = std::min({tmx, tmy, t_max});
    testCell(cell, t_cell, t_out, &ray);
    if (t_out >= ray.best_t || t_out >= t_max) break;
    t_cell = t_out;
    if (tmx < tmy) {
      tmx += tdx;
      ix += sx;
    } else {
      tmy += tdy;
      iy += sy;
    }
  }
  RayHit best = ray.best;
  if (ray.best_t <= t_max && best.material != Material::kNone) {
    best.range = ray.best_t;
  } else {
    best.material = Material::kNone;
  }
  return best;
}

// The part [t_cell, t_out] of the ray over one grid cell: the terrain when the ray comes low
// enough, then the cell's objects whose height range the ray crosses.
void World::testCell(size_t cell, double t_cell, double t_out, Ray* ray) const {
  const Eigen::Vector3d& o = ray->o;
  const Eigen::Vector3d& d = ray->d;
  double& best_t = ray->best_t;
  // Height range of the ray inside this cell.
  double t_far = std::min(t_out, best_t);
  double za = o.z() + t_cell * d.z(), zb = o.z() + t_far * d.z();
  float z_lo = static_cast<float>(std::min(za, zb));
  if (z_lo <= cell_ground_max_[cell]) {
    const double tg = traceTerrain(o, d, t_cell, t_far, cell_ground_lip_[cell]);
    if (tg >= ray->t_min && tg < best_t) {
      best_t = tg;
      ray->best.material = Material::kGround;
      ray->best.stem_id = -1;
      t_far = tg;
      zb = o.z() + t_far * d.z();
      z_lo = static_cast<float>(std::min(za, zb));
    }
  }
  const float z_hi = static_cast<float>(std::max(za, zb));
  const uint32_t k_end = z_lo > cell_top_[cell] ? cell_start_[cell] : cell_start_[cell + 1];
  for (uint32_t k = cell_start_[cell]; k < k_end; ++k) {
    const CellItem& ci = cell_items_[k];
    if (ci.z_min > z_hi) break;  // items are sorted by z_min
    if (ci.z_max < z_lo) continue;
    testItem(ci.item, ray);
  }
}

// The exact test of one object (once per ray), keeping the closer hit.
void World::testItem(uint32_t item, Ray* ray) const {
  const Eigen::Vector3d& o = ray->o;
  const Eigen::Vector3d& d = ray->d;
  const double t_min = ray->t_min, t_max = ray->t_max;
  double& best_t = ray->best_t;
  RayHit& best = ray->best;
  const uint32_t kind = item >> 30, idx = item & 0x3FFFFFFFu;
  const size_t mb = kind == kItemStem       ? idx
                    : kind == kItemCylinder ? stems_.size() + idx
                                            : stems_.size() + cylinders_.size() + idx;
  if (ray->scratch->mailbox[mb] == ray->id) return;
  ray->scratch->mailbox[mb] = ray->id;
  double t = kInf;
  const double limit = std::min(best_t, t_max);
  if (kind == kItemStem) {
    if (hitStem(stems_[idx], stem_bound_[idx], o, d, limit, &t) && t >= t_min && t < best_t) {
      best_t = t;
      best.material = Material::kBark;
      best.stem_id = stems_[idx].sapling ? -1 : stems_[idx].id;
    }
  } else if (kind == kItemCylinder) {
    if (hitCylinder(cylinders_[idx], o, d, t_min, &t) && t < best_t && t <= t_max) {
      best_t = t;
      best.material = cylinders_[idx].material;
      best.stem_id = -1;
    }
  } else {
    double tin, tout;
    if (chordFoliage(foliage_[idx], o, d, &tin, &tout) && tout > t_min && tin < limit) {
      // Porous volume: exponential free path (one draw per crossed volume; the distribution
      // holds no state, so a fresh one per draw gives the same numbers).
      std::uniform_real_distribution<double> unit(0.0, 1.0);
      const double depth = -std::log(1.0 - unit(ray->scratch->rng)) / foliage_[idx].density;
      t = std::max(tin, t_min) + depth;
      if (t < tout && t < best_t && t <= t_max) {
        best_t = t;
        best.material = Material::kFoliage;
        best.stem_id = -1;
      }
    }
  }
}

ScanPattern::ScanPattern(const SensorParams& p)
    : rate_(p.points_per_s), el_min_(p.fov_min_deg * kDeg), el_max_(p.fov_max_deg * kDeg) {}

Eigen::Vector3d ScanPattern::direction(uint64_t k) const {
  // Four emitters interleaved; each sweeps azimuth at ~25 rev/s while its elevation follows a
  // triangle wave at ~1.5 kHz. Incommensurate frequencies plus a slow phase precession make
  // the pattern non-repetitive: coverage of the FOV keeps growing with integration time.
  const int laser = static_cast<int>(k & 3u);
  const double t = static_cast<double>(k) / rate_;
  const double az =
      2 * kPi * (25.13 * t + 0.25 * laser) + 0.35 * std::sin(2 * kPi * 0.618 * t + laser);
  double ph = 1481.37 * t + 0.25 * laser + 0.5 * std::sin(2 * kPi * 0.1732 * t);
  ph -= std::floor(ph);
  const double tri = ph < 0.5 ? 2 * ph : 2 - 2 * ph;
  const double el = el_min_ + (el_max_ - el_min_) * tri;
  return Eigen::Vector3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
}

}  // namespace dtif::sim
