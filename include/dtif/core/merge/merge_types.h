// The map merger's value types: its parameters, the submaps and loops it takes, and what it
// reports (poses, events, verdicts, solve statistics, graph edges). Apart from MapMerger so that
// the merger's own pieces (src/core/merge) need not include the class they implement.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/merge/stem_inventory.h"
#include "dtif/core/merge/stem_map.h"
#include "dtif/core/types.h"

namespace dtif {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

struct MergeParams {
  // Odometry edges: standard deviations grow with the distance travelled between submaps.
  double odom_sigma_xy_m = 0.02;         ///< horizontal sigma of one edge, floor [m]
  double odom_sigma_xy_per_m = 0.01;     ///< horizontal sigma per metre travelled [m/m]
  double odom_sigma_z_m = 0.02;          ///< vertical sigma floor [m]
  double odom_sigma_z_per_m = 0.005;     ///< vertical sigma per metre travelled [m/m]
  double odom_sigma_rot_rad = 0.002;     ///< yaw sigma floor [rad]
  double odom_sigma_rot_per_m = 0.0005;  ///< yaw sigma per metre travelled [rad/m]
  /// Roll and pitch: lidar-inertial odometry sees gravity, so between consecutive submaps they
  /// hardly drift (a tilted camera_init is the same tilt for every submap), while a loop's
  /// roll/pitch from trunks is good to a few tenths of a degree only.
  double odom_sigma_tilt_rad = 0.0005;    ///< roll/pitch sigma floor [rad]
  double odom_sigma_tilt_per_m = 0.0001;  ///< roll/pitch sigma per metre travelled [rad/m]
  // Loop edges: the loop's covariance, with floors (a trunk-based covariance can be optimistic).
  double loop_sigma_xy_min_m = 0.05;      ///< [m]
  double loop_sigma_z_min_m = 0.05;       ///< [m]
  double loop_sigma_rot_min_rad = 0.005;  ///< [rad]
  /// The horizontal floor of a loop with a submap in an open stand (MergeSubmap::open_stand):
  /// fitted to a handful of stems chained by odometry, such loops are off by 0.14 m on
  /// very_sparse (0.06 m in dense stands), and at loop_sigma_xy_min_m they bent the map
  /// towards them against the trees seen in common [m].
  double loop_open_sigma_xy_min_m = 0.15;
  double robust_loss_scale = 3.0;  ///< Cauchy scale on loop residuals, in sigmas
  // PCM: two loops of one robot pair are consistent when the cycle they close with the two
  // odometry chains is within pcm_sigmas standard deviations (translation and rotation).
  bool pcm = true;
  double pcm_sigmas = 3.0;
  /// The only loop of a robot pair must agree with a path through a third robot whose two pairs
  /// PCM checked (docs/merge.md), else it is rejected. With pcm only.
  bool pcm_single_loop_paths = true;
  /// A robot pair's only loop is also rejected when the two robots' trunks around it disagree:
  /// those of their submaps within single_loop_reach_m (travelled) of the loop's two (which the
  /// front end matched already, so they are left out), placed by
  /// odometry and the loop, each within single_loop_zone_m of the other robot's submap origins
  /// (ground both saw), compared at least single_loop_min_trunks times, of which fewer than
  /// single_loop_min_agreement had a trunk of the other robot within single_loop_gate_m.
  bool pcm_single_loop_trunks = true;
  double single_loop_reach_m = 30.0;  ///< [m]
  double single_loop_zone_m = 8.0;    ///< [m]
  double single_loop_gate_m = 0.5;    ///< [m]
  int single_loop_min_trunks = 40;
  double single_loop_min_agreement = 0.25;
  int max_iterations = 30;  ///< Ceres iterations per solve
  /// The linear solver: sparse Cholesky while its factorisation costs at most this many
  /// multiply-subtracts per submap-level pattern (AMD's estimate; x 6^3 flops), conjugate
  /// gradients above (a graph whose loops join every pass over the same paths).
  double direct_solver_max_work = 1e6;
  /// Landmark refinement after the pose graph: every submap's trunks are
  /// associated across submaps and robots through the merged poses (landmarks.h), and the
  /// poses re-solved with submap-landmark factors (odometry and loop edges kept). Ties submaps
  /// that overlap without a detected loop.
  bool landmarks = true;
  double landmark_gate_m = 0.3;  ///< association gate, horizontal [m]
  /// The gate for the trunks of submaps in an open stand (MergeSubmap::open_stand): their
  /// loops are few and carry the odometry's drift (their descriptors chain several submaps),
  /// so the pose graph leaves them farther off than landmark_gate_m, while their stems stand
  /// far enough apart (tens per hectare) for a wider gate to stay unambiguous [m].
  double landmark_open_gate_m = 0.8;
  double landmark_radius_tol_m = 0.1;  ///< radii agree within max(this, 0.5 r) [m]
  int landmark_min_observations = 2;   ///< submaps that must see a tree to make it a landmark
  double landmark_sigma_xy_m = 0.05;   ///< a trunk centre's horizontal sigma [m]
  double landmark_sigma_z_m = 0.05;    ///< a seen stem base's vertical sigma [m]
  /// Trunks whose base was hidden: horizontal only, with this sigma (their centre was fitted
  /// relative to a guessed base, up a leaning stem); 0: left out [m].
  double landmark_hidden_base_sigma_xy_m = 0.2;
  double landmark_loss_scale = 2.0;  ///< Cauchy scale on landmark residuals, in sigmas
  int landmark_rounds = 2;           ///< associate, solve; repeated (re-association)
  /// ... when a submap is in an open stand: its wider gate associates more as the poses
  /// converge (very_sparse: 2 rounds left seed 1 at 0.21 m ATE, 4 at 0.08 m), while more rounds
  /// in dense stands only shuffle millimetres.
  int landmark_open_rounds = 4;
  /// A tree seen by more submaps keeps this many of its observations, spread over them: a
  /// survey of laps sees every tree from dozens of submaps, and each landmark couples all of
  /// its submaps in the reduced system (the soak test's 712 submaps: 111 s with all); 0: all
  int landmark_max_observations = 8;
  /// The final map (refine()) joins a component to component 0 when its stem inventory
  /// registers to component 0's (descriptor match of the two inventories, then planar least
  /// squares on nearest pairs): at least this many stems paired within join_pair_radius_m,
  /// with an RMS of at most join_max_rms_m. A robot that overlaps the others without a detected
  /// loop. The join is a loop between the two submaps nearest each other after registration,
  /// through PCM and the solve like any loop; 0: never.
  int join_min_pairs = 20;
  double join_pair_radius_m = 0.4;  ///< [m]
  double join_max_rms_m = 0.15;     ///< [m]
  StemFusionParams stems;           ///< YAML section `stems` (its own visit)
  StemMapParams stem_map;           ///< field stem maps: fixed (fieldStemMapLoopParams)
  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("odom_sigma_xy_m", odom_sigma_xy_m);
    v("odom_sigma_xy_per_m", odom_sigma_xy_per_m);
    v("odom_sigma_z_m", odom_sigma_z_m);
    v("odom_sigma_z_per_m", odom_sigma_z_per_m);
    v("odom_sigma_rot_rad", odom_sigma_rot_rad);
    v("odom_sigma_rot_per_m", odom_sigma_rot_per_m);
    v("odom_sigma_tilt_rad", odom_sigma_tilt_rad);
    v("odom_sigma_tilt_per_m", odom_sigma_tilt_per_m);
    v("loop_sigma_xy_min_m", loop_sigma_xy_min_m);
    v("loop_sigma_z_min_m", loop_sigma_z_min_m);
    v("loop_sigma_rot_min_rad", loop_sigma_rot_min_rad);
    v("loop_open_sigma_xy_min_m", loop_open_sigma_xy_min_m);
    v("robust_loss_scale", robust_loss_scale);
    v("pcm", pcm);
    v("pcm_sigmas", pcm_sigmas);
    v("pcm_single_loop_paths", pcm_single_loop_paths);
    v("pcm_single_loop_trunks", pcm_single_loop_trunks);
    v("single_loop_reach_m", single_loop_reach_m);
    v("single_loop_zone_m", single_loop_zone_m);
    v("single_loop_gate_m", single_loop_gate_m);
    v("single_loop_min_trunks", single_loop_min_trunks);
    v("single_loop_min_agreement", single_loop_min_agreement);
    v("max_iterations", max_iterations);
    v("direct_solver_max_work", direct_solver_max_work);
    v("landmarks", landmarks);
    v("landmark_gate_m", landmark_gate_m);
    v("landmark_open_gate_m", landmark_open_gate_m);
    v("landmark_radius_tol_m", landmark_radius_tol_m);
    v("landmark_min_observations", landmark_min_observations);
    v("landmark_sigma_xy_m", landmark_sigma_xy_m);
    v("landmark_sigma_z_m", landmark_sigma_z_m);
    v("landmark_hidden_base_sigma_xy_m", landmark_hidden_base_sigma_xy_m);
    v("landmark_loss_scale", landmark_loss_scale);
    v("landmark_rounds", landmark_rounds);
    v("landmark_open_rounds", landmark_open_rounds);
    v("landmark_max_observations", landmark_max_observations);
    v("join_min_pairs", join_min_pairs);
    v("join_pair_radius_m", join_pair_radius_m);
    v("join_max_rms_m", join_max_rms_m);
  }
};

/// One submap of a robot's chain, in acquisition order per robot.
struct MergeSubmap {
  std::string robot;
  int64_t id = -1;
  double stamp = 0.0;             ///< [s]
  Pose T_O_S = Pose::Identity();  ///< odometry pose
  Trunks trunks;                  ///< in S (may be empty)
  /// Described with stems accumulated over several submaps (Descriptor::accumulated): an open
  /// stand, whose trunks associate within landmark_open_gate_m.
  bool open_stand = false;
};

/// A descriptor's submap for the merger: robot, id, stamp, T_O_S, and the trunks it observed
/// (Descriptor::observedTrunks: its own, not the stems an accumulated descriptor carries) in S
/// (a levelled descriptor holds them in L: Descriptor::level_rotation, undone here).
MergeSubmap mergeSubmapOf(const Descriptor& d, const Pose& T_O_S);

/// A submap's levelling R_L_S expressed for its robot's odometry frame: R_L_O = R_L_S R_O_S^T.
Eigen::Matrix3d levellingInOdom(const Eigen::Matrix3d& R_L_S, const Pose& T_O_S);

/// A robot changed component (joined another, or a rejected loop split it off): log it.
struct MergeEvent {
  std::string robot;
  int from_component = -1;  ///< -1: the robot was new
  int to_component = -1;
  std::string text;  ///< one human-readable line
};

/// A submap's merged pose.
struct MergedPose {
  int64_t id = -1;
  std::string robot;
  int component = 0;
  Pose T_M_S = Pose::Identity();
};

/// The back end's verdict on one loop.
struct LoopVerdict {
  int64_t query_id = -1, candidate_id = -1;
  bool inter_robot = false;
  bool used = false;             ///< in the maximum consistent set (PCM) and in the solve
  double residual_sigmas = 0.0;  ///< whitened residual after the last solve
};

struct MergeSolveStats {
  double pcm_ms = 0.0, solve_ms = 0.0;
  int iterations = 0;
  bool iterative = false;  ///< conjugate gradients instead of sparse Cholesky (a dense factor)
  double initial_cost = 0.0, final_cost = 0.0;
  size_t loops_used = 0, loops_rejected = 0;
  int components = 0;
  double landmark_ms = 0.0;                         ///< the landmark refinement's share of solve_ms
  size_t landmarks = 0, landmark_observations = 0;  ///< in the last refinement round
};

/// An edge of the pose graph (for export, e.g. g2o): T_from_to with its information matrix in
/// (x, y, z, roll, pitch, yaw) order.
struct MergeGraphEdge {
  int64_t from = -1, to = -1;
  Pose T_from_to = Pose::Identity();
  Matrix6d information = Matrix6d::Identity();
  bool loop = false;
};

}  // namespace dtif
