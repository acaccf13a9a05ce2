// Which submap pairs may form a loop: the one rule shared by the database query, the evaluation's
// ground truth, the simulator's dataset statistics and the benchmark (DATASET.md).
#pragma once

#include <cmath>

namespace dtif {

/// A query (robot_q, stamp_q [s]) may be matched with a candidate (robot_c, stamp_c [s]) when
/// they come from different robots or lie at least exclude_recent_s [s] apart: a robot's recent
/// submaps overlap it by construction, which is odometry, not a loop. `Robot` is any
/// identifier comparable with != (the robot's name, or the simulator's robot index).
template <class Robot>
bool eligibleLoopPair(const Robot& robot_q, double stamp_q, const Robot& robot_c, double stamp_c,
                      double exclude_recent_s) {
  return robot_c != robot_q || std::fabs(stamp_c - stamp_q) >= exclude_recent_s;
}

}  // namespace dtif
