// How Simulator::run() cuts a survey into units of parallel work: the submap windows of every
// robot, the id of each window's submap, and the order in which windows go to the threads.
// A header of its own so that the planning can be tested without casting a ray.
#pragma once

#include <cstdint>
#include <vector>

#include "dtif/sim/simulator.h"

namespace dtif::sim {

/// One unit of parallel work: the frames of one submap window of one robot. The window's random
/// streams are seeded from (seed, robot, window), so the output does not depend on which thread
/// runs it or in which order.
struct WindowTask {
  int robot = 0;
  int window = 0;
  int f_begin = 0, f_end = 0;  ///< frames [f_begin, f_end)
  int64_t submap_id = -1;      ///< -1: the trailing incomplete window, which makes no submap
};

/// The windows of a survey.
struct WindowPlan {
  std::vector<WindowTask> tasks;  ///< robots interleaved window by window
  size_t submaps = 0;             ///< tasks with a submap id (ids are 0..submaps-1)
};

/// Frames are `slices_per_frame` trajectory samples long, windows `frames_per_window` frames.
/// Only whole frames are scanned and only complete windows become submaps; the frames after a
/// robot's last complete window still form a (frames-only) task. Submap ids rank the anchor
/// stamps `epoch_s + start_s + (window + 0.5) * window_s` over all robots, ties by robot index:
/// the acquisition order of submaps.csv.
WindowPlan planWindows(const std::vector<Trajectory>& trajectories, double epoch_s, double window_s,
                       int slices_per_frame, int frames_per_window);

}  // namespace dtif::sim
