// Survey simulation: stem-avoiding walking paths, helmet motion, FAST-LIO2-like drifting
// odometry, MID-360 scanning, frames and submaps.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <map>
#include <mutex>
#include <queue>
#include <thread>

#include "dtif/core/params.h"
#include "dtif/core/voxel_grid.h"
#include "dtif/sim/sim_world.h"
#include "dtif/sim/simulator.h"

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
    auto [bi, bj] = nearestFree(ci(b.x()), cj(b.y()));
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

double yawOf(const Eigen::Matrix3d& R) { return std::atan2(R(1, 0), R(0, 0)); }

// Ground truth and odometry of one robot.
Trajectory makeTrajectory(const World& world, const WalkGrid& grid, const SceneParams& scene,
                          const RobotRoute& route, std::mt19937_64& rng) {
  const MotionParams& mp = scene.motion;
  std::vector<Eigen::Vector2d> raw;
  for (size_t i = 0; i + 1 < route.waypoints.size(); ++i) {
    auto leg = grid.plan(route.waypoints[i], route.waypoints[i + 1]);
    if (!raw.empty()) leg.erase(leg.begin());
    raw.insert(raw.end(), leg.begin(), leg.end());
  }
  const double ds = 0.05;
  const std::vector<Eigen::Vector2d> path = smoothPath(raw, grid, ds);
  const size_t np = path.size();
  auto at = [&](double s) {
    const double f = std::clamp(s / ds, 0.0, static_cast<double>(np - 1));
    const size_t i = std::min(static_cast<size_t>(f), np - 2);
    return Eigen::Vector2d(path[i] + (f - i) * (path[i + 1] - path[i]));
  };
  const double length = ds * static_cast<double>(np - 1);

  // Random smooth speed and head motion (sums of slow sinusoids with random phases).
  const double ph[8] = {uniform(rng, 0, 2 * kPi), uniform(rng, 0, 2 * kPi),
                        uniform(rng, 0, 2 * kPi), uniform(rng, 0, 2 * kPi),
                        uniform(rng, 0, 2 * kPi), uniform(rng, 0, 2 * kPi),
                        uniform(rng, 0, 2 * kPi), uniform(rng, 0, 2 * kPi)};
  const double dt = 1.0 / kTrajectoryRateHz;
  Trajectory tr;
  tr.robot = route.name;
  tr.start_s = route.start_s;
  double s = 0.0, t = 0.0, yaw = 0.0, z_f = 0.0;
  bool first = true;
  const OdometryParams& op = scene.odometry;
  auto signedRate = [&](double lo, double hi) {
    return (uniform(rng, 0, 1) < 0.5 ? -1.0 : 1.0) * uniform(rng, lo, hi);
  };
  const Eigen::Vector3d drift(signedRate(op.trans_drift_min, op.trans_drift_max),
                              signedRate(op.trans_drift_min, op.trans_drift_max),
                              signedRate(op.trans_drift_min, op.trans_drift_max));
  const double yaw_rate = signedRate(op.yaw_drift_min_deg_per_m, op.yaw_drift_max_deg_per_m) * kDeg;
  std::normal_distribution<double> n01(0.0, 1.0);
  double tilt_r = op.tilt_sd_deg * kDeg * n01(rng), tilt_p = op.tilt_sd_deg * kDeg * n01(rng);
  const double a_ou = std::exp(-dt / op.tilt_time_s);
  const double b_ou = op.tilt_sd_deg * kDeg * std::sqrt(1 - a_ou * a_ou);
  Pose T_W_O = Pose::Identity();
  Eigen::Vector3d p_est(0, 0, 0), p_prev(0, 0, 0);
  double dpsi = 0.0, dist = 0.0;
  while (true) {
    const double v_mid = 0.5 * (mp.speed_min_mps + mp.speed_max_mps);
    const double v_amp = 0.5 * (mp.speed_max_mps - mp.speed_min_mps);
    // Slow down where the path turns (looking ahead 1.5 m).
    const Eigen::Vector2d t0 = at(s + 0.5) - at(s), t1 = at(s + 1.5) - at(s + 1.0);
    const double turn = (t0.norm() > 1e-6 && t1.norm() > 1e-6)
                            ? std::acos(std::clamp(t0.normalized().dot(t1.normalized()), -1.0, 1.0))
                            : 0.0;
    double v = v_mid + v_amp * (0.6 * std::sin(2 * kPi * t / 37.0 + ph[0]) +
                                0.4 * std::sin(2 * kPi * t / 13.0 + ph[1]));
    v = std::max(mp.speed_min_mps, v - 0.8 * turn * v_amp);
    const Eigen::Vector2d xy = at(s);
    const Eigen::Vector2d ahead = at(s + 1.0) - at(std::max(0.0, s - 0.3));
    const double path_yaw = ahead.norm() > 1e-6 ? std::atan2(ahead.y(), ahead.x()) : yaw;
    const double look =
        mp.look_around_deg * kDeg *
        (0.7 * std::sin(2 * kPi * t / 9.0 + ph[2]) + 0.3 * std::sin(2 * kPi * t / 3.7 + ph[3]));
    const double target = path_yaw + look;
    if (first) {
      yaw = target;
    } else {
      yaw += wrapAngle(target - yaw) * (1.0 - std::exp(-dt / 0.4));  // head turns smoothly
    }
    const double ground = world.terrainHeight(xy.x(), xy.y());
    z_f = first ? ground : z_f + (ground - z_f) * (1.0 - std::exp(-dt / 0.3));
    const double step_ph = 2 * kPi * mp.step_frequency_hz * t;
    const double z = z_f + mp.head_height_m + mp.bob_amplitude_m * std::sin(step_ph + ph[4]);
    const double roll = mp.sway_deg * kDeg * std::sin(0.5 * step_ph + ph[5]);
    const double pitch = mp.sway_deg * kDeg *
                         (0.5 * std::sin(step_ph + ph[6]) + std::sin(2 * kPi * t / 11.0 + ph[7]));
    Pose T_W_B = Pose::Identity();
    T_W_B.linear() = rpy(roll, pitch, yaw);
    T_W_B.translation() = Eigen::Vector3d(xy.x(), xy.y(), z);

    // Odometry: integrate the true motion with yaw drift, per-axis translation drift (both per
    // metre walked) and a slowly wandering roll/pitch error (Ornstein-Uhlenbeck).
    const Eigen::Vector3d p = T_W_B.translation();
    if (first) {
      T_W_O.linear() = rotZ(yaw);  // camera_init: gravity-aligned, at the start pose
      T_W_O.translation() = p;
      p_est = p;
    } else {
      const double step = (p - p_prev).norm();
      dist += step;
      dpsi += yaw_rate * step;
      p_est += rotZ(dpsi) * (p - p_prev) + drift * step;
      tilt_r = a_ou * tilt_r + b_ou * n01(rng);
      tilt_p = a_ou * tilt_p + b_ou * n01(rng);
    }
    p_prev = p;
    Pose T_W_Best = Pose::Identity();  // the estimate, expressed as if it were in W
    T_W_Best.linear() = rpy(tilt_r, tilt_p, 0.0) * rotZ(dpsi) * T_W_B.linear();
    T_W_Best.translation() = p_est;
    tr.T_W_B.push_back(T_W_B);
    tr.T_O_B.push_back(T_W_O.inverse() * T_W_Best);
    tr.distance.push_back(dist);
    first = false;
    if (s >= length) break;
    s += v * dt;
    t += dt;
  }
  return tr;
}

// Gravity-aligned submap frame from an odometry pose: yaw only, origin at the sensor.
Pose gravityAligned(const Pose& T_O_B) {
  Pose T = Pose::Identity();
  T.linear() = rotZ(yawOf(T_O_B.linear()));
  T.translation() = T_O_B.translation();
  return T;
}

float reflectivity(Material m) {
  switch (m) {
    case Material::kGround:
      return 25.0f;
    case Material::kBark:
      return 60.0f;
    case Material::kBranch:
      return 45.0f;
    case Material::kFoliage:
      return 15.0f;
    case Material::kLog:
      return 40.0f;
    default:
      return 0.0f;
  }
}

// Fraction of the nominal max range (MID-360: 40 m at 10 % reflectivity) at which a target
// still returns: grazing ground and leaves that fill only part of the beam fade earlier.
double rangeFactor(Material m) {
  switch (m) {
    case Material::kGround:
      return 0.7;
    case Material::kFoliage:
      return 0.8;
    case Material::kBranch:
      return 0.9;
    default:
      return 1.0;
  }
}

}  // namespace

Simulator::Simulator(const SceneParams& scene, uint64_t seed) : scene_(scene), seed_(seed) {
  const std::string problems = scene.validate();
  if (!problems.empty()) throw ParamError("scene: " + problems.substr(0, problems.find('\n')));
  world_ = std::make_unique<World>(scene_, seed_);
  const WalkGrid grid(*world_, scene_.motion.clearance_m);
  for (size_t r = 0; r < scene_.robots.size(); ++r) {
    std::mt19937_64 rng(seed_ * 1000003ULL + 7919ULL * (r + 1));
    trajectories_.push_back(makeTrajectory(*world_, grid, scene_, scene_.robots[r], rng));
  }
}

Simulator::~Simulator() = default;

namespace {

// One unit of parallel work: the frames of one submap window of one robot. The window's random
// streams are seeded from (seed, robot, window), so the output does not depend on which thread
// runs it or in which order.
struct WindowTask {
  int robot;
  int window;
  int f_begin, f_end;  // frames [f_begin, f_end)
};

uint64_t splitmix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

uint64_t streamSeed(uint64_t seed, uint64_t stream, int robot, int window) {
  return splitmix64(splitmix64(splitmix64(seed) ^ stream) ^
                    (static_cast<uint64_t>(robot) << 32 | static_cast<uint32_t>(window)));
}

// A frame-producing window may run ahead of the oldest undelivered window of its robot by at
// most this many windows, which bounds the frames held back for in-order delivery.
constexpr int kMaxWindowsAhead = 3;

}  // namespace

SimulationStats Simulator::run(FrameSink* frames, SubmapSink* submaps, int threads) {
  const auto t_start = std::chrono::steady_clock::now();
  const SensorParams& sp = scene_.sensor;
  const double dur = scene_.submap.duration_s;
  const int slices_per_frame = static_cast<int>(std::lround(kTrajectoryRateHz / sp.frame_rate_hz));
  const int frames_per_window = static_cast<int>(std::lround(dur * sp.frame_rate_hz));
  // Only whole frames are scanned, and only windows that are complete become submaps.
  auto numFrames = [&](const Trajectory& tr) {
    return static_cast<int>((tr.T_W_B.size() - 1) / slices_per_frame);
  };
  auto numWindows = [&](const Trajectory& tr) { return numFrames(tr) / frames_per_window; };

  // Submap ids: rank of the anchor stamp over all robots (acquisition order of submaps.csv).
  struct Slot {
    double stamp;
    int robot;
    int window;
  };
  std::vector<Slot> slots;
  std::vector<WindowTask> tasks;
  for (size_t r = 0; r < trajectories_.size(); ++r) {
    const Trajectory& tr = trajectories_[r];
    const int n_frames = numFrames(tr);
    for (int w = 0; w < numWindows(tr); ++w) {
      slots.push_back({scene_.epoch_s + tr.start_s + (w + 0.5) * dur, static_cast<int>(r), w});
    }
    // Frames after the last complete window still go to `frames`.
    for (int w = 0; w * frames_per_window < n_frames; ++w) {
      tasks.push_back({static_cast<int>(r), w, w * frames_per_window,
                       std::min(n_frames, (w + 1) * frames_per_window)});
    }
  }
  std::sort(slots.begin(), slots.end(), [](const Slot& a, const Slot& b) {
    return a.stamp != b.stamp ? a.stamp < b.stamp : a.robot < b.robot;
  });
  std::map<std::pair<int, int>, int64_t> slot_id;
  for (size_t i = 0; i < slots.size(); ++i) slot_id[{slots[i].robot, slots[i].window}] = i;
  // Robots interleaved window by window, so that every robot's frames advance together.
  std::stable_sort(tasks.begin(), tasks.end(),
                   [](const WindowTask& a, const WindowTask& b) { return a.window < b.window; });

  SimulationStats stats;
  stats.stems = 0;
  for (const auto& s : world_->stems()) (s.sapling ? stats.saplings : stats.stems)++;
  stats.shrubs = world_->numShrubs();
  stats.logs = world_->numLogs();
  stats.branches = world_->cylinders().size() - world_->numLogs();
  double submap_points = 0.0;

  // Shared state, guarded by `mutex`: results, the frame sink (calls serialised), in-order frame
  // delivery, the first failure.
  std::mutex mutex;
  std::condition_variable delivered_cv;
  size_t next_task = 0;
  std::vector<int> next_window(trajectories_.size(), 0);  // oldest undelivered window per robot
  std::vector<std::map<int, std::vector<Frame>>> held(trajectories_.size());
  std::exception_ptr failure;  // the first exception of a worker

  // Scans one window; per-thread scratch objects are reused across windows.
  auto scanWindow = [&](const WindowTask& task, World::RayScratch* scratch,
                        VoxelCentroidGrid* voxels, std::vector<Frame>* out_frames) {
    const int r = task.robot;
    const Trajectory& tr = trajectories_[r];
    const bool is_submap = task.window < numWindows(tr);
    const ScanPattern pattern(sp);
    scratch->rng.seed(streamSeed(seed_, 1, r, task.window));
    std::mt19937_64 rng(streamSeed(seed_, 2, r, task.window));
    std::normal_distribution<double> noise(0.0, sp.range_noise_m);
    std::normal_distribution<double> jitter(0.0, 0.25 * sp.divergence_deg * kDeg);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    const size_t n_samples = tr.T_W_B.size();
    const double pts_per_slice = sp.points_per_s / kTrajectoryRateHz;
    // Rays fired before slice i; each robot's sensor starts at a different point of the
    // (non-repetitive) pattern.
    auto raysBefore = [&](size_t i) {
      return static_cast<uint64_t>(std::floor(static_cast<double>(i) * pts_per_slice + 1e-9));
    };
    const uint64_t k_pt0 = static_cast<uint64_t>(r) * 7777777ULL;
    voxels->clear();
    Pose T_S_O = Pose::Identity(), T_O_S = Pose::Identity(), T_W_S = Pose::Identity();
    if (is_submap) {
      // Anchor at the window's centre: the submap's pose is defined there.
      const size_t ia =
          std::min(n_samples - 1,
                   static_cast<size_t>(std::lround((task.window + 0.5) * dur * kTrajectoryRateHz)));
      T_O_S = gravityAligned(tr.T_O_B[ia]);
      T_S_O = T_O_S.inverse();
      // Ground truth: the estimate maps to W through T_W_B * T_O_B^-1 at the anchor.
      T_W_S = tr.T_W_B[ia] * tr.T_O_B[ia].inverse() * T_O_S;
    }
    size_t rays = 0, returns = 0;
    Frame scratch_frame;
    for (int f = task.f_begin; f < task.f_end; ++f) {
      Frame* frame = out_frames ? &out_frames->emplace_back() : &scratch_frame;
      frame->robot = tr.robot;
      frame->robot_index = r;
      for (int sl = 0; sl < slices_per_frame; ++sl) {
        const size_t i = static_cast<size_t>(f) * slices_per_frame + sl;
        const Pose& T_W_B = tr.T_W_B[i];
        const Pose& T_O_B = tr.T_O_B[i];
        const Eigen::Vector3d o = T_W_B.translation();
        const uint64_t k_end = k_pt0 + raysBefore(i + 1);
        for (uint64_t k_pt = k_pt0 + raysBefore(i); k_pt < k_end; ++k_pt) {
          Eigen::Vector3d dir_B = pattern.direction(k_pt);
          if (sp.divergence_deg > 0) {
            // The beam's footprint: the return comes from somewhere inside it.
            dir_B += Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
            dir_B.normalize();
          }
          const Eigen::Vector3d dir_W = T_W_B.linear() * dir_B;
          ++rays;
          const RayHit hit = world_->castRay(o, dir_W, sp.min_range_m, sp.max_range_m, scratch);
          if (hit.material == Material::kNone) continue;
          const double fade = unit(rng);
          if (hit.range > sp.max_range_m * rangeFactor(hit.material) * (0.75 + 0.25 * fade)) {
            continue;
          }
          if (unit(rng) < sp.dropout) continue;
          const double range = hit.range + noise(rng);
          if (range < sp.min_range_m) continue;
          const Eigen::Vector3d p_O = T_O_B * (dir_B * range);  // de-skewed as FAST-LIO2 does
          const float intensity = std::clamp(
              reflectivity(hit.material) * static_cast<float>(0.8 + 0.4 * unit(rng)), 0.0f, 255.0f);
          ++returns;
          if (out_frames) {
            frame->points.push_back(p_O.cast<float>());
            frame->intensity.push_back(intensity);
          }
          if (is_submap) voxels->add((T_S_O * p_O).cast<float>());
        }
      }
      const size_t i_end = static_cast<size_t>(f + 1) * slices_per_frame;
      frame->stamp = scene_.epoch_s + tr.start_s + static_cast<double>(i_end) / kTrajectoryRateHz;
      frame->T_O_B = tr.T_O_B[i_end];
      frame->T_W_B = tr.T_W_B[i_end];
    }

    if (is_submap) {
      Submap sm;
      sm.id = slot_id.at({r, task.window});
      sm.robot = tr.robot;
      sm.robot_index = r;
      sm.stamp = scene_.epoch_s + tr.start_s + (task.window + 0.5) * dur;
      sm.T_O_S = T_O_S;
      sm.T_W_S = T_W_S;
      sm.points = voxels->centroids();
      sm.raw_points = voxels->raw();
      if (submaps) submaps->onSubmap(sm);  // concurrently: the sink synchronises itself
      std::lock_guard<std::mutex> lock(mutex);
      stats.submaps++;
      submap_points += static_cast<double>(sm.points.size());
    }
    std::lock_guard<std::mutex> lock(mutex);
    stats.frames += static_cast<size_t>(task.f_end - task.f_begin);
    stats.rays += rays;
    stats.returns += returns;
    if (out_frames) {
      // Frames of one robot leave in time order: hold this window until its predecessors left.
      held[r][task.window] = std::move(*out_frames);
      for (auto it = held[r].begin(); it != held[r].end() && it->first == next_window[r];
           it = held[r].erase(it)) {
        for (const Frame& fr : it->second) frames->onFrame(fr);
        ++next_window[r];
      }
      delivered_cv.notify_all();
    }
  };

  auto worker = [&]() {
    World::RayScratch scratch = world_->makeScratch(0);
    VoxelCentroidGrid voxels(scene_.submap.voxel_m);
    std::vector<Frame> window_frames;
    while (true) {
      WindowTask task;
      {
        std::unique_lock<std::mutex> lock(mutex);
        if (next_task >= tasks.size()) return;
        task = tasks[next_task++];
        // Every earlier window of this robot is already running or held, so this wait ends.
        if (frames) {
          delivered_cv.wait(lock, [&] {
            return failure || task.window - next_window[task.robot] <= kMaxWindowsAhead;
          });
        }
        if (failure) return;
      }
      window_frames.clear();
      try {
        scanWindow(task, &scratch, &voxels, frames ? &window_frames : nullptr);
      } catch (...) {
        // A sink failed (e.g. disk full): stop every worker, rethrow in the caller's thread.
        std::lock_guard<std::mutex> lock(mutex);
        if (!failure) failure = std::current_exception();
        next_task = tasks.size();
        delivered_cv.notify_all();
        return;
      }
    }
  };

  int n_threads =
      threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  n_threads = std::max(1, std::min<int>(n_threads, static_cast<int>(tasks.size())));
  std::vector<std::thread> pool;
  for (int t = 1; t < n_threads; ++t) pool.emplace_back(worker);
  worker();
  for (auto& th : pool) th.join();
  if (failure) std::rethrow_exception(failure);
  stats.mean_submap_points = stats.submaps ? submap_points / stats.submaps : 0.0;
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats;
}

}  // namespace dtif::sim
