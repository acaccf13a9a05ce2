// Walking trajectories: A* paths around stems and logs, smoothed; a walker with head motion;
// a FAST-LIO2-like drifting odometry.
#include "sim_trajectory.h"

#include <algorithm>
#include <cmath>
#include <queue>
#include <random>

#include "dtif/core/params.h"

namespace dtif::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

double uniform(std::mt19937_64& rng, double a, double b) {
  return std::uniform_real_distribution<double>(a, b)(rng);
}

// Occupancy grid of the plot for path planning: stems (+ clearance) and logs are blocked.
class WalkGrid {
 public:
  WalkGrid(const World& w, double clearance) : cell_(0.25) {
    size_ = w.plotSize();
    nx_ = static_cast<int>(size_.x() / cell_) + 1;
    ny_ = static_cast<int>(size_.y() / cell_) + 1;
    cost_.assign(static_cast<size_t>(nx_) * ny_, 1.0f);
    for (const Stem& s : w.stems()) {
      const double r = s.maxRadius() + (s.sapling ? 0.25 : clearance);
      block(s.axisAt(0.0), r);
      block(s.axisAt(1.7), r);
    }
    for (const Cylinder& c : w.cylinders()) {
      if (c.material != Material::kLog) continue;
      for (double a = 0; a <= c.length; a += 0.2) {
        block((c.a + a * c.axis).head<2>(), c.radius + 0.3);
      }
    }
  }
  bool free(int i, int j) const { return inside(i, j) && cost_[idx(i, j)] < 1e8f; }
  bool freeAt(const Eigen::Vector2d& p) const { return free(ci(p.x()), cj(p.y())); }
  int ci(double x) const { return std::clamp(static_cast<int>(std::round(x / cell_)), 0, nx_ - 1); }
  int cj(double y) const { return std::clamp(static_cast<int>(std::round(y / cell_)), 0, ny_ - 1); }
  Eigen::Vector2d pos(int i, int j) const { return Eigen::Vector2d(i * cell_, j * cell_); }

  // Nearest free cell (spiral search).
  std::pair<int, int> nearestFree(int i, int j) const {
    for (int r = 0; r < 200; ++r) {
      for (int dj = -r; dj <= r; ++dj) {
        for (int di = -r; di <= r; ++di) {
          if (std::max(std::abs(di), std::abs(dj)) != r) continue;
          if (free(i + di, j + dj)) return {i + di, j + dj};
        }
      }
    }
    throw ParamError("simulate: no free space to walk near a waypoint");
  }

  // A* (8-connected, octile heuristic), returns cell centres from a to b.
  std::vector<Eigen::Vector2d> plan(const Eigen::Vector2d& a, const Eigen::Vector2d& b) const {
    auto [ai, aj] = nearestFree(ci(a.x()), cj(a.y()));
    // Not a structured binding: the heuristic lambda captures it (C++17 clang refuses that).
    const auto goal_cell = nearestFree(ci(b.x()), cj(b.y()));
    const int bi = goal_cell.first, bj = goal_cell.second;
    const size_t n = cost_.size();
    std::vector<float> g(n, 1e30f);
    std::vector<int32_t> parent(n, -1);
    using Node = std::pair<float, int32_t>;
    std::priority_queue<Node, std::vector<Node>, std::greater<Node>> open;
    auto h = [&](int i, int j) {
      const int dx = std::abs(i - bi), dy = std::abs(j - bj);
      return static_cast<float>(std::max(dx, dy) + 0.41421356 * std::min(dx, dy));
    };
    const int32_t start = static_cast<int32_t>(idx(ai, aj)),
                  goal = static_cast<int32_t>(idx(bi, bj));
    g[start] = 0;
    open.push({h(ai, aj), start});
    while (!open.empty()) {
      auto [f, cur] = open.top();
      open.pop();
      if (cur == goal) break;
      const int i = cur % nx_, j = cur / nx_;
      if (f > g[cur] + h(i, j) + 1e-3f) continue;
      for (int dj = -1; dj <= 1; ++dj) {
        for (int di = -1; di <= 1; ++di) {
          if (!di && !dj) continue;
          if (!free(i + di, j + dj)) continue;
          const size_t nb = idx(i + di, j + dj);
          const float step = (di && dj) ? 1.41421356f : 1.0f;
          const float ng = g[cur] + step * cost_[nb];
          if (ng < g[nb]) {
            g[nb] = ng;
            parent[nb] = cur;
            open.push({ng + h(i + di, j + dj), static_cast<int32_t>(nb)});
          }
        }
      }
    }
    if (parent[goal] < 0 && goal != start) {
      throw ParamError("simulate: a waypoint cannot be reached (blocked by stems or logs)");
    }
    std::vector<Eigen::Vector2d> path;
    for (int32_t c = goal; c >= 0; c = parent[c]) path.push_back(pos(c % nx_, c / nx_));
    std::reverse(path.begin(), path.end());
    return path;
  }

 private:
  bool inside(int i, int j) const { return i >= 0 && j >= 0 && i < nx_ && j < ny_; }
  size_t idx(int i, int j) const { return static_cast<size_t>(j) * nx_ + i; }
  void block(const Eigen::Vector2d& c, double r) {
    const int i0 = ci(c.x() - r), i1 = ci(c.x() + r), j0 = cj(c.y() - r), j1 = cj(c.y() + r);
    for (int j = j0; j <= j1; ++j) {
      for (int i = i0; i <= i1; ++i) {
        const double d = (pos(i, j) - c).norm();
        if (d <= r) {
          cost_[idx(i, j)] = 1e9f;
        } else if (d <= r + 0.5 && cost_[idx(i, j)] < 1e8f) {
          cost_[idx(i, j)] = std::max(cost_[idx(i, j)], 3.0f);  // prefer some extra room
        }
      }
    }
  }

  double cell_;
  Eigen::Vector2d size_;
  int nx_ = 0, ny_ = 0;
  std::vector<float> cost_;
};

// Smooths a grid path (Laplacian, keeping every point in free space) and resamples it at ds.
std::vector<Eigen::Vector2d> smoothPath(std::vector<Eigen::Vector2d> p, const WalkGrid& grid,
                                        double ds) {
  for (int it = 0; it < 60; ++it) {
    for (size_t i = 1; i + 1 < p.size(); ++i) {
      const Eigen::Vector2d q = 0.5 * p[i] + 0.25 * (p[i - 1] + p[i + 1]);
      if (grid.freeAt(q)) p[i] = q;
    }
  }
  std::vector<Eigen::Vector2d> out{p.front()};
  double carry = 0.0;
  for (size_t i = 1; i < p.size(); ++i) {
    const Eigen::Vector2d seg = p[i] - p[i - 1];
    const double len = seg.norm();
    double s = ds - carry;
    while (s <= len) {
      out.push_back(p[i - 1] + seg * (s / len));
      s += ds;
    }
    carry = len - (s - ds);
  }
  if ((out.back() - p.back()).norm() > 1e-6) out.push_back(p.back());
  return out;
}

double wrapAngle(double a) {
  while (a > kPi) a -= 2 * kPi;
  while (a < -kPi) a += 2 * kPi;
  return a;
}

Eigen::Matrix3d rpy(double roll, double pitch, double yaw) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

// The walking path of a route: A* legs between its waypoints, smoothed and resampled at ds.
std::vector<Eigen::Vector2d> walkingPath(const WalkGrid& grid, const RobotRoute& route, double ds) {
  std::vector<Eigen::Vector2d> raw;
  for (size_t i = 0; i + 1 < route.waypoints.size(); ++i) {
    auto leg = grid.plan(route.waypoints[i], route.waypoints[i + 1]);
    if (!raw.empty()) leg.erase(leg.begin());
    raw.insert(raw.end(), leg.begin(), leg.end());
  }
  std::vector<Eigen::Vector2d> path = smoothPath(raw, grid, ds);
  // PathSampler needs a segment: coinciding waypoints (on one grid cell) give none.
  if (path.size() < 2) {
    throw ParamError("simulate: robot " + route.name + ": the route has no length");
  }
  return path;
}

// A path sampled every ds metres, looked up by arc length (clamped to its ends).
class PathSampler {
 public:
  PathSampler(std::vector<Eigen::Vector2d> path, double ds) : path_(std::move(path)), ds_(ds) {}
  Eigen::Vector2d at(double s) const {
    const size_t np = path_.size();
    const double f = std::clamp(s / ds_, 0.0, static_cast<double>(np - 1));
    const size_t i = std::min(static_cast<size_t>(f), np - 2);
    return Eigen::Vector2d(path_[i] + (f - i) * (path_[i + 1] - path_[i]));
  }
  double length() const { return ds_ * static_cast<double>(path_.size() - 1); }

 private:
  std::vector<Eigen::Vector2d> path_;
  double ds_;
};

// The operator along the path: random smooth speed and head motion, as sums of slow sinusoids
// with random phases, and a head that turns and follows the ground with some lag.
class Walker {
 public:
  // Draws the eight phases from `rng` (before the odometry draws its own).
  Walker(const World& world, const MotionParams& mp, const PathSampler& path, std::mt19937_64& rng)
      : world_(world), mp_(mp), path_(path) {
    for (double& p : ph_) p = uniform(rng, 0, 2 * kPi);
  }

  // Walking speed at arc length s, time t: slower where the path turns (looking ahead 1.5 m).
  double speed(double s, double t) const {
    const double v_mid = 0.5 * (mp_.speed_min_mps + mp_.speed_max_mps);
    const double v_amp = 0.5 * (mp_.speed_max_mps - mp_.speed_min_mps);
    const Eigen::Vector2d t0 = path_.at(s + 0.5) - path_.at(s),
                          t1 = path_.at(s + 1.5) - path_.at(s + 1.0);
    const double turn = (t0.norm() > 1e-6 && t1.norm() > 1e-6)
                            ? std::acos(std::clamp(t0.normalized().dot(t1.normalized()), -1.0, 1.0))
                            : 0.0;
    double v = v_mid + v_amp * (0.6 * std::sin(2 * kPi * t / 37.0 + ph_[0]) +
                                0.4 * std::sin(2 * kPi * t / 13.0 + ph_[1]));
    v = std::max(mp_.speed_min_mps, v - 0.8 * turn * v_amp);
    return v;
  }

  // The sensor's true pose at arc length s, time t; advances the head's yaw and height filters
  // by one step of dt (`first`: start them at their targets).
  Pose pose(double s, double t, double dt, bool first) {
    const Eigen::Vector2d xy = path_.at(s);
    const Eigen::Vector2d ahead = path_.at(s + 1.0) - path_.at(std::max(0.0, s - 0.3));
    const double path_yaw = ahead.norm() > 1e-6 ? std::atan2(ahead.y(), ahead.x()) : yaw_;
    const double look =
        mp_.look_around_deg * kDeg *
        (0.7 * std::sin(2 * kPi * t / 9.0 + ph_[2]) + 0.3 * std::sin(2 * kPi * t / 3.7 + ph_[3]));
    const double target = path_yaw + look;
    if (first) {
      yaw_ = target;
    } else {
      yaw_ += wrapAngle(target - yaw_) * (1.0 - std::exp(-dt / 0.4));  // head turns smoothly
    }
    const double ground = world_.terrainHeight(xy.x(), xy.y());
    z_f_ = first ? ground : z_f_ + (ground - z_f_) * (1.0 - std::exp(-dt / 0.3));
    const double step_ph = 2 * kPi * mp_.step_frequency_hz * t;
    const double z = z_f_ + mp_.head_height_m + mp_.bob_amplitude_m * std::sin(step_ph + ph_[4]);
    const double roll = mp_.sway_deg * kDeg * std::sin(0.5 * step_ph + ph_[5]);
    const double pitch = mp_.sway_deg * kDeg *
                         (0.5 * std::sin(step_ph + ph_[6]) + std::sin(2 * kPi * t / 11.0 + ph_[7]));
    Pose T_W_B = Pose::Identity();
    T_W_B.linear() = rpy(roll, pitch, yaw_);
    T_W_B.translation() = Eigen::Vector3d(xy.x(), xy.y(), z);
    return T_W_B;
  }

  double yaw() const { return yaw_; }  ///< of the last pose [rad]

 private:
  const World& world_;
  const MotionParams& mp_;
  const PathSampler& path_;
  double ph_[8];
  double yaw_ = 0.0, z_f_ = 0.0;
};

// FAST-LIO2 stand-in: integrates the true motion with yaw drift, per-axis translation drift
// (both per metre walked) and a slowly wandering roll/pitch error (Ornstein-Uhlenbeck).
class DriftingOdometry {
 public:
  // Draws the robot's drift rates and initial tilt from `rng`. `R_tilt` (identity: level) is
  // camera_init's attitude relative to the robot's initial heading (FastLioParams).
  DriftingOdometry(const OdometryParams& op, double dt, const Eigen::Matrix3d& R_tilt,
                   std::mt19937_64& rng)
      : n01_(0.0, 1.0), R_tilt_(R_tilt) {
    auto signedRate = [&](double lo, double hi) {
      const double sign = uniform(rng, 0, 1) < 0.5 ? -1.0 : 1.0;
      return sign * uniform(rng, lo, hi);
    };
    // One draw per statement, z first: the order gcc evaluated the three arguments of
    // `Vector3d(signedRate(...), ...)` in (C++ leaves it open), so every compiler drifts alike.
    const double drift_z = signedRate(op.trans_drift_min, op.trans_drift_max);
    const double drift_y = signedRate(op.trans_drift_min, op.trans_drift_max);
    const double drift_x = signedRate(op.trans_drift_min, op.trans_drift_max);
    drift_ = Eigen::Vector3d(drift_x, drift_y, drift_z);
    yaw_rate_ = signedRate(op.yaw_drift_min_deg_per_m, op.yaw_drift_max_deg_per_m) * kDeg;
    tilt_r_ = op.tilt_sd_deg * kDeg * n01_(rng);
    tilt_p_ = op.tilt_sd_deg * kDeg * n01_(rng);
    a_ou_ = std::exp(-dt / op.tilt_time_s);
    b_ou_ = op.tilt_sd_deg * kDeg * std::sqrt(1 - a_ou_ * a_ou_);
  }

  // The odometry pose T_O_B for the next true pose T_W_B with head yaw `yaw`. `first`: the
  // odometry frame O (camera_init) starts there, gravity-aligned unless tilted.
  Pose step(const Pose& T_W_B, double yaw, bool first, std::mt19937_64& rng) {
    const Eigen::Vector3d p = T_W_B.translation();
    if (first) {
      T_W_O_.linear() = rotZ(yaw);
      // Skipped when level, so that level scenes stay bit for bit as they were.
      if (!R_tilt_.isIdentity(0.0)) T_W_O_.linear() = T_W_O_.linear() * R_tilt_;
      T_W_O_.translation() = p;
      p_est_ = p;
    } else {
      const double step = (p - p_prev_).norm();
      dist_ += step;
      dpsi_ += yaw_rate_ * step;
      p_est_ += rotZ(dpsi_) * (p - p_prev_) + drift_ * step;
      tilt_r_ = a_ou_ * tilt_r_ + b_ou_ * n01_(rng);
      tilt_p_ = a_ou_ * tilt_p_ + b_ou_ * n01_(rng);
    }
    p_prev_ = p;
    Pose T_W_Best = Pose::Identity();  // the estimate, expressed as if it were in W
    T_W_Best.linear() = rpy(tilt_r_, tilt_p_, 0.0) * rotZ(dpsi_) * T_W_B.linear();
    T_W_Best.translation() = p_est_;
    return T_W_O_.inverse() * T_W_Best;
  }

  double distance() const { return dist_; }  ///< walked so far [m]

 private:
  // One stream for the initial tilt and every update: std::normal_distribution keeps a spare.
  std::normal_distribution<double> n01_;
  Eigen::Matrix3d R_tilt_;
  Eigen::Vector3d drift_;
  double yaw_rate_ = 0.0;
  double tilt_r_ = 0.0, tilt_p_ = 0.0;
  double a_ou_ = 0.0, b_ou_ = 0.0;
  Pose T_W_O_ = Pose::Identity();
  Eigen::Vector3d p_est_{0, 0, 0}, p_prev_{0, 0, 0};
  double dpsi_ = 0.0, dist_ = 0.0;
};

// camera_init's tilt of robot r: the route's own values, else drawn from the scene's range on
// a stream of its own (so that a level scene draws nothing and stays as it was).
void drawTilt(const SceneParams& scene, const RobotRoute& route, uint64_t seed, size_t r,
              Trajectory* tr) {
  std::mt19937_64 rng(seed * 1000003ULL + 7919ULL * (r + 1) + 0x7e1e7ULL);
  const FastLioParams& f = scene.fastlio;
  const bool draw = f.init_tilt_max_deg > 0.0;
  const double tilt = draw ? uniform(rng, f.init_tilt_min_deg, f.init_tilt_max_deg) : 0.0;
  const double azimuth = draw ? uniform(rng, 0.0, 360.0) : 0.0;
  tr->tilt_deg = route.tilt_deg.value_or(tilt);
  tr->tilt_azimuth_deg = route.tilt_azimuth_deg.value_or(azimuth);
}

// camera_init relative to the initial heading: z leans by tilt towards the azimuth.
Eigen::Matrix3d tiltRotation(double tilt_deg, double azimuth_deg) {
  if (tilt_deg == 0.0) return Eigen::Matrix3d::Identity();
  const double a = azimuth_deg * kDeg;
  return Eigen::AngleAxisd(tilt_deg * kDeg, Eigen::Vector3d(-std::sin(a), std::cos(a), 0.0))
      .toRotationMatrix();
}

// Ground truth and odometry of one robot, sampled at kTrajectoryRateHz.
Trajectory makeTrajectory(const World& world, const WalkGrid& grid, const SceneParams& scene,
                          const RobotRoute& route, uint64_t seed, size_t r) {
  std::mt19937_64 rng(seed * 1000003ULL + 7919ULL * (r + 1));
  const double ds = 0.05;
  const PathSampler path(walkingPath(grid, route, ds), ds);
  Walker walker(world, scene.motion, path, rng);
  const double dt = 1.0 / kTrajectoryRateHz;
  Trajectory tr;
  drawTilt(scene, route, seed, r, &tr);
  const Eigen::Matrix3d R_tilt = tiltRotation(tr.tilt_deg, tr.tilt_azimuth_deg);
  // Gravity's up seen from O: the initial heading's z through the tilt.
  tr.up_O = R_tilt.transpose() * Eigen::Vector3d::UnitZ();
  DriftingOdometry odometry(scene.odometry, dt, R_tilt, rng);
  tr.robot = route.name;
  tr.start_s = route.start_s;
  double s = 0.0, t = 0.0;
  for (bool first = true;; first = false) {
    const double v = walker.speed(s, t);
    const Pose T_W_B = walker.pose(s, t, dt, first);
    tr.T_W_B.push_back(T_W_B);
    tr.T_O_B.push_back(odometry.step(T_W_B, walker.yaw(), first, rng));
    tr.distance.push_back(odometry.distance());
    if (s >= path.length()) break;
    s += v * dt;
    t += dt;
  }
  return tr;
}

}  // namespace

std::vector<Trajectory> makeTrajectories(const World& world, const SceneParams& scene,
                                         uint64_t seed) {
  const WalkGrid grid(world, scene.motion.clearance_m);
  std::vector<Trajectory> trajectories;
  for (size_t r = 0; r < scene.robots.size(); ++r) {
    trajectories.push_back(makeTrajectory(world, grid, scene, scene.robots[r], seed, r));
  }
  return trajectories;
}

}  // namespace dtif::sim
