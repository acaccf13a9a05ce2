// The Ceres solve of the merged pose graph (submap poses, odometry and loop edges), and its
// refinement with the trunks as landmarks. The only file of the merger that includes Ceres.
#include <ceres/ceres.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>

#include "core/merge/merge_graph.h"
#include "core/merge/pose_graph_cost.h"
#include "dtif/core/merge/factor_cost.h"
#include "dtif/core/merge/landmarks.h"
#include "dtif/core/timing.h"

namespace dtif {
namespace {

Matrix6d diagonalSqrtInformation(const Vector6d& sigmas) {
  return sigmas.cwiseInverse().asDiagonal();
}

/// Every submap's pose, the odometry edges and the used loops (each with its loss wrapper in
/// `losses`); each robot's anchor submap fixed.
void addGraph(MergeGraph& m, ceres::Problem* problem, ceres::Manifold* quaternion,
              std::vector<ceres::LossFunctionWrapper*>* losses) {
  for (MergeGraph::Node& n : m.nodes) {
    problem->AddParameterBlock(n.q.coeffs().data(), 4, quaternion);
    problem->AddParameterBlock(n.t.data(), 3);
  }
  for (const auto& [name, r] : m.robots) {
    if (r.nodes.empty()) continue;
    for (size_t k = 1; k < r.nodes.size(); ++k) {
      const size_t a = r.nodes[k - 1], b = r.nodes[k];
      const Pose T = m.odom(a, b);
      const double d = T.translation().norm();
      problem->AddResidualBlock(
          RelativePoseCost::create(T.translation(), Eigen::Quaterniond(T.rotation()),
                                   diagonalSqrtInformation(m.odomSigmas(d))),
          nullptr, m.nodes[a].q.coeffs().data(), m.nodes[a].t.data(), m.nodes[b].q.coeffs().data(),
          m.nodes[b].t.data());
    }
    MergeGraph::Node& anchor = m.nodes[r.nodes.front()];
    if (anchor.id == r.frame) {
      problem->SetParameterBlockConstant(anchor.q.coeffs().data());
      problem->SetParameterBlockConstant(anchor.t.data());
    }
  }
  for (const MergeGraph::LoopRec& l : m.loops) {
    if (!l.used) continue;
    losses->push_back(new ceres::LossFunctionWrapper(nullptr, ceres::TAKE_OWNERSHIP));
    problem->AddResidualBlock(
        RelativePoseCost::create(l.T_a_b.translation(), Eigen::Quaterniond(l.T_a_b.rotation()),
                                 diagonalSqrtInformation(l.sigmas)),
        losses->back(), m.nodes[l.a].q.coeffs().data(), m.nodes[l.a].t.data(),
        m.nodes[l.b].q.coeffs().data(), m.nodes[l.b].t.data());
  }
}

ceres::Problem::Options problemOptions() {
  ceres::Problem::Options popt;
  popt.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  return popt;
}

/// The robust stages of the loops' loss (none: least squares).
std::vector<double> lossStages(const MergeGraph& m) {
  const double s = m.p.robust_loss_scale;
  return m.p.pcm ? std::vector<double>{0.0, s} : std::vector<double>{10.0 * s, 3.0 * s, s};
}

void setLoss(const std::vector<ceres::LossFunctionWrapper*>& losses, double scale) {
  for (ceres::LossFunctionWrapper* w : losses) {
    w->Reset(scale > 0.0 ? new ceres::CauchyLoss(scale) : nullptr, ceres::TAKE_OWNERSHIP);
  }
}

// The sparse Cholesky's work on the graph's node-level pattern (factor_cost.h).
double graphCholeskyMultiplies(const MergeGraph& m) {
  std::vector<std::pair<size_t, size_t>> edges;
  for (const auto& [name, r] : m.robots) {
    for (size_t k = 1; k < r.nodes.size(); ++k) edges.emplace_back(r.nodes[k - 1], r.nodes[k]);
  }
  for (const MergeGraph::LoopRec& l : m.loops) {
    if (l.used) edges.emplace_back(l.a, l.b);
  }
  return choleskyMultiplies(m.nodes.size(), edges);
}

// Sparse Cholesky, unless its factor would be dense: surveys that walk the same paths all
// hour (six units, laps of one plot) join every pass by loops, and minimum degree then leaves
// fronts of hundreds of submaps: 5 s of CPU and +60 MB per solve at 2,000 submaps (the soak
// test), growing as the cube. Conjugate gradients need no factor; a tight forcing sequence (eta)
// keeps their solution within ~2 mm of the exact one there. Chains with few loops (most
// surveys) are the opposite case: cheap to factor, badly conditioned for CG.
ceres::Solver::Options linearSolverOptions(const MergeGraph& m, MergeSolveStats* st) {
  ceres::Solver::Options opt;
  // Node-level multiply-subtracts; a 6-dof block costs 6^3 of them (~2e8 flops at 1e6).
  st->iterative = graphCholeskyMultiplies(m) > m.p.direct_solver_max_work;
  if (st->iterative) {
    opt.linear_solver_type = ceres::CGNR;
    opt.preconditioner_type = ceres::JACOBI;
    opt.eta = 0.01;
  } else {
    opt.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  }
  return opt;
}

ceres::Solver::Options solverOptions(const MergeGraph& m, MergeSolveStats* st) {
  ceres::Solver::Options opt = linearSolverOptions(m, st);
  opt.max_num_iterations = m.p.max_iterations;
  opt.num_threads = 1;
  opt.logging_type = ceres::SILENT;
  return opt;
}

// --- landmarks -------------------------------------------------------------------------------
/// The trunks of the submaps of one component, in insertion order, moved into M. A hidden
/// base is a guess (the centre was fitted relative to it, up a leaning stem): such trunks
/// count horizontally only, with a larger sigma, or not at all.
std::vector<LandmarkObservation> landmarkObservations(const MergeGraph& m, int component) {
  std::vector<LandmarkObservation> obs;
  for (size_t i = 0; i < m.nodes.size(); ++i) {
    const MergeGraph::Node& n = m.nodes[i];
    if (m.robots.at(n.robot).component != component) continue;
    const Pose T = n.pose();
    for (const TrunkLandmark& tr : n.trunks) {
      if (!tr.base_seen && !(m.p.landmark_hidden_base_sigma_xy_m > 0.0)) continue;
      LandmarkObservation o;
      o.base_seen = tr.base_seen;
      o.open_stand = n.open_stand;
      o.submap = i;
      o.p_S = Eigen::Vector3d(tr.x, tr.y, tr.z);
      o.p_M = T * o.p_S;
      o.r = tr.r;
      obs.push_back(o);
    }
  }
  return obs;
}

LandmarkAssociationParams associationParams(const MergeParams& p) {
  LandmarkAssociationParams a;
  a.gate_m = p.landmark_gate_m;
  a.open_gate_m = p.landmark_open_gate_m;
  a.radius_abs_tol_m = p.landmark_radius_tol_m;
  a.min_observations = p.landmark_min_observations;
  return a;
}

/// A component's trunk observations and their groups, one per landmark.
using ComponentLandmarks =
    std::pair<std::vector<LandmarkObservation>, std::vector<std::vector<size_t>>>;

std::vector<ComponentLandmarks> associateComponents(const MergeGraph& m) {
  std::vector<ComponentLandmarks> comps;
  for (int c = 0; c < m.countComponents(); ++c) {
    auto obs = landmarkObservations(m, c);
    auto groups = associateLandmarks(obs, associationParams(m.p));
    comps.emplace_back(std::move(obs), std::move(groups));
  }
  return comps;
}

// At most landmark_max_observations of a landmark's observations, evenly spread over them
// (in submap order), one with a seen base among them when any has one (it fixes the height).
std::vector<size_t> spreadObservations(const MergeParams& p,
                                       const std::vector<LandmarkObservation>& obs,
                                       const std::vector<size_t>& members) {
  const size_t k = static_cast<size_t>(p.landmark_max_observations);
  if (k == 0 || members.size() <= k) return members;
  std::vector<size_t> kept;
  kept.reserve(k);
  for (size_t j = 0; j < k; ++j) kept.push_back(members[j * (members.size() - 1) / (k - 1)]);
  const auto seen = [&](size_t i) { return obs[i].base_seen; };
  if (std::none_of(kept.begin(), kept.end(), seen)) {
    const auto first = std::find_if(members.begin(), members.end(), seen);
    if (first != members.end()) kept.back() = *first;
  }
  return kept;
}

/// Adds every landmark, at the mean of its kept observations, with their residuals.
/// `positions` (empty) receives the landmarks' parameter blocks; `horizontal` is the manifold
/// of a landmark whose base no one saw.
void addLandmarks(MergeGraph& m, const std::vector<ComponentLandmarks>& comps,
                  ceres::Manifold* horizontal, std::vector<Eigen::Vector3d>* positions,
                  ceres::Problem* problem, MergeSolveStats* st) {
  const MergeParams& p = m.p;
  const Eigen::Vector3d seen(p.landmark_sigma_xy_m, p.landmark_sigma_xy_m, p.landmark_sigma_z_m);
  // A hidden base's elevation says nothing: an infinite sigma (a zero residual).
  const double h = p.landmark_hidden_base_sigma_xy_m;
  const Eigen::Vector3d hidden(h, h, std::numeric_limits<double>::infinity());
  size_t total = 0;
  for (const auto& c : comps) total += c.second.size();
  positions->reserve(total);  // the parameter blocks must not move
  st->landmarks = total;
  st->landmark_observations = 0;
  for (const auto& [obs, groups] : comps) {
    for (const auto& all_members : groups) {
      const std::vector<size_t> members = spreadObservations(p, obs, all_members);
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (size_t i : members) mean += obs[i].p_M;
      positions->push_back(mean / static_cast<double>(members.size()));
      bool any_seen = false;
      for (size_t i : members) any_seen = any_seen || obs[i].base_seen;
      problem->AddParameterBlock(positions->back().data(), 3, any_seen ? nullptr : horizontal);
      for (size_t i : members) {
        MergeGraph::Node& n = m.nodes[obs[i].submap];
        problem->AddResidualBlock(
            LandmarkCost::create(obs[i].p_S, obs[i].base_seen ? seen : hidden),
            new ceres::CauchyLoss(p.landmark_loss_scale), n.q.coeffs().data(), n.t.data(),
            positions->back().data());
      }
      st->landmark_observations += members.size();
    }
  }
}

ceres::Solver::Options landmarkSolverOptions(MergeGraph& m, std::vector<Eigen::Vector3d>* positions,
                                             MergeSolveStats* st) {
  ceres::Solver::Options opt = solverOptions(m, st);
  // Landmarks eliminated first: the reduced system is the submaps' (Schur complement).
  opt.linear_solver_type = st->iterative ? ceres::ITERATIVE_SCHUR : ceres::SPARSE_SCHUR;
  opt.preconditioner_type = ceres::SCHUR_JACOBI;
  auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
  for (Eigen::Vector3d& l : *positions) ordering->AddElementToGroup(l.data(), 0);
  for (MergeGraph::Node& n : m.nodes) {
    ordering->AddElementToGroup(n.q.coeffs().data(), 1);
    ordering->AddElementToGroup(n.t.data(), 1);
  }
  opt.linear_solver_ordering = ordering;
  return opt;
}

/// One round: associate through the current poses, then solve the graph with the landmarks.
void landmarkRound(MergeGraph& m, MergeSolveStats* st) {
  ceres::Problem problem(problemOptions());
  ceres::EigenQuaternionManifold quaternion;
  std::vector<ceres::LossFunctionWrapper*> losses;
  addGraph(m, &problem, &quaternion, &losses);
  setLoss(losses, lossStages(m).back());
  ceres::SubsetManifold horizontal(3, {2});  // a landmark no one saw the base of: z fixed
  std::vector<Eigen::Vector3d> positions;    // landmark parameter blocks
  addLandmarks(m, associateComponents(m), &horizontal, &positions, &problem, st);
  ceres::Solver::Options opt = landmarkSolverOptions(m, &positions, st);
  ceres::Solver::Summary summary;
  ceres::Solve(opt, &problem, &summary);
  st->iterations += static_cast<int>(summary.iterations.size());
  st->final_cost = summary.final_cost;
}

}  // namespace

MergeSolveStats solveGraph(MergeGraph& m) {
  MergeSolveStats st;
  ceres::Problem problem(problemOptions());
  ceres::EigenQuaternionManifold quaternion;
  std::vector<ceres::LossFunctionWrapper*> losses;
  addGraph(m, &problem, &quaternion, &losses);
  ceres::Solver::Options opt = solverOptions(m, &st);
  // Graduated robustness: a robust loss alone cannot pull a map that odometry has drifted by
  // many sigmas (every loop looks like an outlier), so the first stage trusts the loops PCM
  // kept (least squares; without PCM a wide Cauchy), the last uses robust_loss_scale.
  const std::vector<double> stages = lossStages(m);
  for (size_t k = 0; k < stages.size(); ++k) {
    setLoss(losses, stages[k]);
    ceres::Solver::Summary summary;
    ceres::Solve(opt, &problem, &summary);
    st.iterations += static_cast<int>(summary.iterations.size());
    if (k == 0) st.initial_cost = summary.initial_cost;
    st.final_cost = summary.final_cost;
  }
  return st;
}

void refineWithLandmarks(MergeGraph& m, MergeSolveStats* st) {
  const auto t0 = std::chrono::steady_clock::now();
  const bool open = std::any_of(m.nodes.begin(), m.nodes.end(),
                                [](const MergeGraph::Node& n) { return n.open_stand; });
  const int rounds = open ? m.p.landmark_open_rounds : m.p.landmark_rounds;
  for (int k = 0; k < rounds; ++k) landmarkRound(m, st);
  st->landmark_ms = msSince(t0);
}

void updateLoopResiduals(MergeGraph& m) {
  for (MergeGraph::LoopRec& l : m.loops) {
    const Pose err = l.T_a_b.inverse() * m.nodes[l.a].pose().inverse() * m.nodes[l.b].pose();
    const Eigen::Vector3d et = err.translation().cwiseQuotient(l.sigmas.head<3>());
    const double er = rotationAngle(err.linear()) / l.sigmas.tail<3>().maxCoeff();
    l.residual_sigmas = std::sqrt(et.squaredNorm() + er * er);
  }
}

}  // namespace dtif
