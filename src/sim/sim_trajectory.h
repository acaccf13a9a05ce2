// Walking trajectories of the simulated operators (internal to dtif_sim): stem-avoiding paths,
// helmet motion and a FAST-LIO2-like drifting odometry.
#pragma once

#include <cstdint>
#include <vector>

#include "dtif/sim/sim_world.h"
#include "dtif/sim/simulator.h"

namespace dtif::sim {

/// Ground truth and odometry of every robot of the scene, walking its route around stems and
/// logs. Robot r draws from its own stream, seeded from (seed, r).
std::vector<Trajectory> makeTrajectories(const World& world, const SceneParams& scene,
                                         uint64_t seed);

}  // namespace dtif::sim
