// Survey simulation: MID-360 scanning of every robot's trajectory (sim_trajectory.cpp) over
// a pool of threads, frames in time order per robot, and submaps.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "dtif/core/params.h"
#include "dtif/core/voxel_grid.h"
#include "dtif/sim/sim_world.h"
#include "dtif/sim/simulator.h"
#include "dtif/sim/window_plan.h"
#include "sim_trajectory.h"

namespace dtif::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

double yawOf(const Eigen::Matrix3d& R) { return std::atan2(R(1, 0), R(0, 0)); }

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
  trajectories_ = makeTrajectories(*world_, scene_, seed_);
}

Simulator::~Simulator() = default;

WindowPlan planWindows(const std::vector<Trajectory>& trajectories, double epoch_s, double window_s,
                       int slices_per_frame, int frames_per_window) {
  // A submap slot per complete window, ranked below by its anchor stamp.
  struct Slot {
    double stamp;
    int robot;
    int window;
  };
  std::vector<Slot> slots;
  WindowPlan plan;
  for (size_t r = 0; r < trajectories.size(); ++r) {
    const Trajectory& tr = trajectories[r];
    const int n_frames = static_cast<int>((tr.T_W_B.size() - 1) / slices_per_frame);
    const int n_windows = n_frames / frames_per_window;
    for (int w = 0; w < n_windows; ++w) {
      slots.push_back({epoch_s + tr.start_s + (w + 0.5) * window_s, static_cast<int>(r), w});
    }
    // Frames after the last complete window still go to the frame sink.
    for (int w = 0; w * frames_per_window < n_frames; ++w) {
      plan.tasks.push_back({static_cast<int>(r), w, w * frames_per_window,
                            std::min(n_frames, (w + 1) * frames_per_window), -1});
    }
  }
  std::sort(slots.begin(), slots.end(), [](const Slot& a, const Slot& b) {
    return a.stamp != b.stamp ? a.stamp < b.stamp : a.robot < b.robot;
  });
  std::map<std::pair<int, int>, int64_t> slot_id;
  for (size_t i = 0; i < slots.size(); ++i) slot_id[{slots[i].robot, slots[i].window}] = i;
  for (WindowTask& task : plan.tasks) {
    const auto it = slot_id.find({task.robot, task.window});
    if (it != slot_id.end()) task.submap_id = it->second;
  }
  plan.submaps = slots.size();
  // Robots interleaved window by window, so that every robot's frames advance together.
  std::stable_sort(plan.tasks.begin(), plan.tasks.end(),
                   [](const WindowTask& a, const WindowTask& b) { return a.window < b.window; });
  return plan;
}

namespace {

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

int slicesPerFrame(const SensorParams& sp) {
  return static_cast<int>(std::lround(kTrajectoryRateHz / sp.frame_rate_hz));
}

// The sensor-side random stream of one window (the ray caster's foliage stream is the other).
// The distributions live as long as the window: std::normal_distribution keeps a spare draw,
// so recreating one would change the sequence.
struct WindowStreams {
  WindowStreams(const SensorParams& sp, uint64_t seed)
      : rng(seed), noise(0.0, sp.range_noise_m), jitter(0.0, 0.25 * sp.divergence_deg * kDeg) {}
  std::mt19937_64 rng;
  std::normal_distribution<double> noise;
  std::normal_distribution<double> jitter;
  std::uniform_real_distribution<double> unit{0.0, 1.0};
};

// The submap frame S of a complete window and its poses.
struct SubmapAnchor {
  Pose T_S_O = Pose::Identity(), T_O_S = Pose::Identity(), T_W_S = Pose::Identity();
};

// Anchored at the window's centre: the submap's pose is defined there.
SubmapAnchor anchorOf(const Trajectory& tr, int window, double window_s) {
  const size_t n_samples = tr.T_W_B.size();
  const size_t ia =
      std::min(n_samples - 1,
               static_cast<size_t>(std::lround((window + 0.5) * window_s * kTrajectoryRateHz)));
  SubmapAnchor a;
  a.T_O_S = gravityAligned(tr.T_O_B[ia]);
  a.T_S_O = a.T_O_S.inverse();
  // Ground truth: the estimate maps to W through T_W_B * T_O_B^-1 at the anchor.
  a.T_W_S = tr.T_W_B[ia] * tr.T_O_B[ia].inverse() * a.T_O_S;
  return a;
}

// What scanning one window produced besides its frames.
struct WindowScan {
  size_t rays = 0, returns = 0;
  std::optional<Submap> submap;  // complete windows only
};

// Scans windows for one thread. Its ray scratch (mailboxes, foliage stream) and voxel grid are
// reused from window to window; every window reseeds both random streams and empties the grid,
// so which windows a scanner gets does not change what they produce.
class WindowScanner {
 public:
  WindowScanner(const World& world, const SceneParams& scene, uint64_t seed)
      : world_(world),
        scene_(scene),
        sp_(scene.sensor),
        seed_(seed),
        pattern_(scene.sensor),
        slices_per_frame_(slicesPerFrame(scene.sensor)),
        pts_per_slice_(scene.sensor.points_per_s / kTrajectoryRateHz),
        scratch_(world.makeScratch(0)),
        voxels_(scene.submap.voxel_m) {}

  // Scans the window's frames, appending them to *frames unless it is null (then only the
  // submap is built); a complete window also yields its submap.
  WindowScan scan(const Trajectory& tr, const WindowTask& task, std::vector<Frame>* frames) {
    const bool is_submap = task.submap_id >= 0;
    scratch_.rng.seed(streamSeed(seed_, 1, task.robot, task.window));
    WindowStreams streams(sp_, streamSeed(seed_, 2, task.robot, task.window));
    voxels_.clear();
    const SubmapAnchor anchor =
        is_submap ? anchorOf(tr, task.window, scene_.submap.duration_s) : SubmapAnchor();
    WindowScan out;
    Frame scratch_frame;
    for (int f = task.f_begin; f < task.f_end; ++f) {
      Frame* frame = frames ? &frames->emplace_back() : &scratch_frame;
      scanFrame(tr, task.robot, f, is_submap ? &anchor : nullptr, frames != nullptr, &streams,
                frame, &out);
    }
    if (is_submap) out.submap = makeSubmap(tr, task, anchor);
    return out;
  }

 private:
  // Rays fired before trajectory slice i; each robot's sensor starts at a different point of
  // the (non-repetitive) pattern.
  uint64_t firstRay(int robot, size_t i) const {
    return static_cast<uint64_t>(robot) * 7777777ULL +
           static_cast<uint64_t>(std::floor(static_cast<double>(i) * pts_per_slice_ + 1e-9));
  }

  // The rays of frame f: its points (when kept) go to *frame in O, and into the submap's
  // voxels in S when `anchor` is set.
  void scanFrame(const Trajectory& tr, int robot, int f, const SubmapAnchor* anchor,
                 bool keep_points, WindowStreams* streams, Frame* frame, WindowScan* out) {
    frame->robot = tr.robot;
    frame->robot_index = robot;
    // FAST-LIO2's preprocess: every point_filter_num-th valid return of the frame is kept.
    const int filter_num = scene_.fastlio.point_filter_num;
    int valid = 0;
    for (int sl = 0; sl < slices_per_frame_; ++sl) {
      const size_t i = static_cast<size_t>(f) * slices_per_frame_ + sl;
      const Pose& T_W_B = tr.T_W_B[i];
      const Pose& T_O_B = tr.T_O_B[i];
      const uint64_t k_end = firstRay(robot, i + 1);
      for (uint64_t k_pt = firstRay(robot, i); k_pt < k_end; ++k_pt) {
        Eigen::Vector3d p_O;
        float intensity = 0.0f;
        ++out->rays;
        if (!scanRay(T_W_B, T_O_B, k_pt, streams, &p_O, &intensity)) continue;
        ++out->returns;
        if (++valid % filter_num != 0) continue;
        if (keep_points) {
          frame->points.push_back(p_O.cast<float>());
          frame->intensity.push_back(intensity);
        }
        if (anchor) voxels_.add((anchor->T_S_O * p_O).cast<float>());
      }
    }
    const size_t i_end = static_cast<size_t>(f + 1) * slices_per_frame_;
    frame->stamp = scene_.epoch_s + tr.start_s + static_cast<double>(i_end) / kTrajectoryRateHz;
    frame->T_O_B = tr.T_O_B[i_end];
    frame->T_W_B = tr.T_W_B[i_end];
  }

  // Fires point k_pt of the pattern from pose T_W_B. True when it returns: then *p_O is the
  // point, de-skewed into O as FAST-LIO2 does, and *intensity its reflectivity. The draws of
  // `streams` must stay in this order (beam jitter; then, on a hit, fade, dropout, range noise,
  // intensity) for the datasets to stay the same.
  bool scanRay(const Pose& T_W_B, const Pose& T_O_B, uint64_t k_pt, WindowStreams* streams,
               Eigen::Vector3d* p_O, float* intensity) {
    std::mt19937_64& rng = streams->rng;
    auto& jitter = streams->jitter;
    Eigen::Vector3d dir_B = pattern_.direction(k_pt);
    if (sp_.divergence_deg > 0) {
      // The beam's footprint: the return comes from somewhere inside it.
      // One draw per statement, z first: the order gcc evaluated the three arguments of
      // `Vector3d(jitter(rng), ...)` in, whatever the compiler.
      const double jz = jitter(rng);
      const double jy = jitter(rng);
      const double jx = jitter(rng);
      dir_B += Eigen::Vector3d(jx, jy, jz);
      dir_B.normalize();
    }
    const Eigen::Vector3d dir_W = T_W_B.linear() * dir_B;
    const RayHit hit =
        world_.castRay(T_W_B.translation(), dir_W, sp_.min_range_m, sp_.max_range_m, &scratch_);
    if (hit.material == Material::kNone) return false;
    const double fade = streams->unit(rng);
    if (hit.range > sp_.max_range_m * rangeFactor(hit.material) * (0.75 + 0.25 * fade)) {
      return false;
    }
    if (streams->unit(rng) < sp_.dropout) return false;
    const double range = hit.range + streams->noise(rng);
    if (range < sp_.min_range_m) return false;
    *p_O = T_O_B * (dir_B * range);
    *intensity =
        std::clamp(reflectivity(hit.material) * static_cast<float>(0.8 + 0.4 * streams->unit(rng)),
                   0.0f, 255.0f);
    return true;
  }

  Submap makeSubmap(const Trajectory& tr, const WindowTask& task, const SubmapAnchor& anchor) {
    Submap sm;
    sm.id = task.submap_id;
    sm.robot = tr.robot;
    sm.robot_index = task.robot;
    sm.stamp = scene_.epoch_s + tr.start_s + (task.window + 0.5) * scene_.submap.duration_s;
    sm.T_O_S = anchor.T_O_S;
    sm.T_W_S = anchor.T_W_S;
    sm.points = voxels_.centroids();
    sm.raw_points = voxels_.raw();
    return sm;
  }

  const World& world_;
  const SceneParams& scene_;
  const SensorParams& sp_;
  uint64_t seed_;
  ScanPattern pattern_;
  int slices_per_frame_;
  double pts_per_slice_;
  World::RayScratch scratch_;
  VoxelCentroidGrid voxels_;
};

// Frames of one robot leave in time order: a window's frames are held until every earlier
// window of that robot has left. Not synchronised: SurveyRun calls it under its mutex.
class InOrderDelivery {
 public:
  InOrderDelivery(size_t robots, FrameSink* sink)
      : next_window_(robots, 0), held_(robots), sink_(sink) {}

  int oldestUndelivered(int robot) const { return next_window_[robot]; }

  // Takes the frames of (robot, window) and passes on every window that is now next in line.
  void add(int robot, int window, std::vector<Frame>* frames) {
    std::map<int, std::vector<Frame>>& held = held_[robot];
    held[window] = std::move(*frames);
    for (auto it = held.begin(); it != held.end() && it->first == next_window_[robot];
         it = held.erase(it)) {
      for (const Frame& fr : it->second) sink_->onFrame(fr);
      ++next_window_[robot];
    }
  }

 private:
  std::vector<int> next_window_;                         // oldest undelivered window per robot
  std::vector<std::map<int, std::vector<Frame>>> held_;  // per robot, by window
  FrameSink* sink_;
};

// One run over a worker pool. The workers share, under `mutex_`: the task queue, the
// statistics, the frame sink (calls serialised, in order per robot) and the first failure.
class SurveyRun {
 public:
  SurveyRun(const World& world, const SceneParams& scene, uint64_t seed,
            const std::vector<Trajectory>& trajectories, const WindowPlan& plan, FrameSink* frames,
            SubmapSink* submaps, SimulationStats* stats)
      : world_(world),
        scene_(scene),
        seed_(seed),
        trajectories_(trajectories),
        plan_(plan),
        frames_(frames),
        submaps_(submaps),
        stats_(stats),
        delivery_(trajectories.size(), frames) {}

  // Runs every task on `n_threads` threads, the caller's being one of them; rethrows the first
  // failure in the caller's thread.
  void run(int n_threads) {
    std::vector<std::thread> pool;
    for (int t = 1; t < n_threads; ++t) pool.emplace_back([this] { work(); });
    work();
    for (auto& th : pool) th.join();
    if (failure_) std::rethrow_exception(failure_);
  }

  double submapPoints() const { return submap_points_; }  ///< summed over the submaps

 private:
  void work() {
    WindowScanner scanner(world_, scene_, seed_);
    std::vector<Frame> window_frames;
    WindowTask task;
    while (nextTask(&task)) {
      window_frames.clear();
      try {
        const WindowScan scan =
            scanner.scan(trajectories_[task.robot], task, frames_ ? &window_frames : nullptr);
        // Concurrently: the sink synchronises itself, so writing overlaps scanning.
        if (scan.submap && submaps_) submaps_->onSubmap(*scan.submap);
        finish(task, scan, &window_frames);
      } catch (...) {
        // A sink failed (e.g. disk full): stop every worker, rethrow in the caller's thread.
        std::lock_guard<std::mutex> lock(mutex_);
        if (!failure_) failure_ = std::current_exception();
        next_task_ = plan_.tasks.size();
        delivered_cv_.notify_all();
        return;
      }
    }
  }

  // The next task, false when none is left or a worker failed. With a frame sink, waits until
  // the task is close enough to its robot's delivered frames; every earlier window of that
  // robot is already running or held, so the wait ends.
  bool nextTask(WindowTask* task) {
    std::unique_lock<std::mutex> lock(mutex_);
    if (next_task_ >= plan_.tasks.size()) return false;
    *task = plan_.tasks[next_task_++];
    if (frames_) {
      delivered_cv_.wait(lock, [&] {
        return failure_ ||
               task->window - delivery_.oldestUndelivered(task->robot) <= kMaxWindowsAhead;
      });
    }
    return !failure_;
  }

  // Counts the window and passes its frames on (held until their turn).
  void finish(const WindowTask& task, const WindowScan& scan, std::vector<Frame>* frames) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (scan.submap) {
      stats_->submaps++;
      submap_points_ += static_cast<double>(scan.submap->points.size());
    }
    stats_->frames += static_cast<size_t>(task.f_end - task.f_begin);
    stats_->rays += scan.rays;
    stats_->returns += scan.returns;
    if (frames_) {
      delivery_.add(task.robot, task.window, frames);
      delivered_cv_.notify_all();
    }
  }

  const World& world_;
  const SceneParams& scene_;
  uint64_t seed_;
  const std::vector<Trajectory>& trajectories_;
  const WindowPlan& plan_;
  FrameSink* frames_;
  SubmapSink* submaps_;
  SimulationStats* stats_;

  std::mutex mutex_;
  std::condition_variable delivered_cv_;
  size_t next_task_ = 0;
  InOrderDelivery delivery_;
  std::exception_ptr failure_;  // the first exception of a worker
  double submap_points_ = 0.0;
};

// The stand's sizes, for the report.
SimulationStats worldStats(const World& world) {
  SimulationStats stats;
  stats.stems = 0;
  for (const auto& s : world.stems()) (s.sapling ? stats.saplings : stats.stems)++;
  stats.shrubs = world.numShrubs();
  stats.logs = world.numLogs();
  stats.branches = world.cylinders().size() - world.numLogs();
  return stats;
}

}  // namespace

SimulationStats Simulator::run(FrameSink* frames, SubmapSink* submaps, int threads) {
  const auto t_start = std::chrono::steady_clock::now();
  const int frames_per_window =
      static_cast<int>(std::lround(scene_.submap.duration_s * scene_.sensor.frame_rate_hz));
  const WindowPlan plan = planWindows(trajectories_, scene_.epoch_s, scene_.submap.duration_s,
                                      slicesPerFrame(scene_.sensor), frames_per_window);
  SimulationStats stats = worldStats(*world_);
  int n_threads =
      threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  n_threads = std::max(1, std::min<int>(n_threads, static_cast<int>(plan.tasks.size())));
  SurveyRun survey(*world_, scene_, seed_, trajectories_, plan, frames, submaps, &stats);
  survey.run(n_threads);
  stats.mean_submap_points = stats.submaps ? survey.submapPoints() / stats.submaps : 0.0;
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats;
}

}  // namespace dtif::sim
