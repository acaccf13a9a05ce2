#include "dtif/core/merge/map_merger.h"

#include <chrono>
#include <sstream>
#include <stdexcept>

#include "core/merge/merge_graph.h"
#include "dtif/core/timing.h"

namespace dtif {
namespace {

bool finitePose(const Pose& T) { return T.matrix().allFinite(); }

}  // namespace

// The merger's state; its pieces are in merge_consistency.cpp (PCM), merge_components.cpp,
// merge_solve.cpp (Ceres) and merge_inventory.cpp (stems and joins).
struct MapMerger::Impl : MergeGraph {
  using MergeGraph::MergeGraph;
};

std::string MergeParams::validate() const {
  std::ostringstream e;
  for (double v : {odom_sigma_xy_m, odom_sigma_z_m, odom_sigma_rot_rad, odom_sigma_tilt_rad,
                   loop_sigma_xy_min_m, loop_sigma_z_min_m, loop_sigma_rot_min_rad,
                   loop_open_sigma_xy_min_m, robust_loss_scale, pcm_sigmas}) {
    if (!(v > 0.0)) e << "merge sigmas, robust_loss_scale and pcm_sigmas must be > 0; ";
  }
  for (double v :
       {odom_sigma_xy_per_m, odom_sigma_z_per_m, odom_sigma_rot_per_m, odom_sigma_tilt_per_m}) {
    if (!(v >= 0.0)) e << "merge per-metre sigmas must be >= 0; ";
  }
  if (max_iterations < 1) e << "merge max_iterations must be >= 1; ";
  if (!(direct_solver_max_work >= 0.0)) e << "merge direct_solver_max_work must be >= 0; ";
  if (!(landmark_hidden_base_sigma_xy_m >= 0.0)) {
    e << "merge landmark_hidden_base_sigma_xy_m must be >= 0; ";
  }
  for (double v : {landmark_gate_m, landmark_open_gate_m, landmark_sigma_xy_m, landmark_sigma_z_m,
                   landmark_loss_scale}) {
    if (!(v > 0.0)) e << "merge landmark gate, sigmas and loss scale must be > 0; ";
  }
  if (!(landmark_radius_tol_m >= 0.0)) e << "merge landmark_radius_tol_m must be >= 0; ";
  if (landmark_min_observations < 2) e << "merge landmark_min_observations must be >= 2; ";
  if (landmark_rounds < 1 || landmark_open_rounds < 1) {
    e << "merge landmark_rounds and landmark_open_rounds must be >= 1; ";
  }
  if (join_min_pairs < 0) e << "merge join_min_pairs must be >= 0; ";
  if (!(join_pair_radius_m > 0.0) || !(join_max_rms_m > 0.0)) {
    e << "merge join_pair_radius_m and join_max_rms_m must be > 0; ";
  }
  if (landmark_max_observations < 0 || landmark_max_observations == 1) {
    e << "merge landmark_max_observations must be 0 (all) or >= 2; ";
  }
  if (!(single_loop_reach_m >= 0.0 && single_loop_reach_m <= 1000.0)) {
    e << "merge single_loop_reach_m must be in [0, 1000]; ";
  }
  if (!(single_loop_zone_m > 0.0 && single_loop_zone_m <= 1000.0) ||
      !(single_loop_gate_m > 0.0 && single_loop_gate_m <= 1000.0)) {
    e << "merge single_loop_zone_m and single_loop_gate_m must be in (0, 1000]; ";
  }
  if (single_loop_min_trunks < 1) e << "merge single_loop_min_trunks must be >= 1; ";
  if (!(single_loop_min_agreement >= 0.0 && single_loop_min_agreement <= 1.0)) {
    e << "merge single_loop_min_agreement must be in [0, 1]; ";
  }
  e << stems.validate();
  return e.str();
}

MapMerger::MapMerger(const MergeParams& params) : impl_(std::make_unique<Impl>(params)) {
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument("MergeParams: " + err);
}
MapMerger::~MapMerger() = default;
MapMerger::MapMerger(MapMerger&&) noexcept = default;
MapMerger& MapMerger::operator=(MapMerger&&) noexcept = default;
MapMerger::MapMerger(const MapMerger& other) : impl_(std::make_unique<Impl>(*other.impl_)) {}
MapMerger& MapMerger::operator=(const MapMerger& other) {
  if (this != &other) impl_ = std::make_unique<Impl>(*other.impl_);
  return *this;
}

void MapMerger::addSubmap(const MergeSubmap& s) {
  Impl& m = *impl_;
  if (m.index.count(s.id)) {
    throw std::invalid_argument("map merger: duplicate submap id " + std::to_string(s.id));
  }
  if (!finitePose(s.T_O_S)) {
    throw std::invalid_argument("map merger: submap " + std::to_string(s.id) +
                                " has a non-finite pose");
  }
  Impl::Node n;
  n.id = s.id;
  n.robot = s.robot;
  n.stamp = s.stamp;
  n.T_O_S = s.T_O_S;
  n.trunks = s.trunks;
  n.open_stand = s.open_stand;
  auto [it, is_new] = m.robots.try_emplace(s.robot);
  Impl::Robot& r = it->second;
  if (is_new) r.order = m.robots.size() - 1;
  if (r.nodes.empty()) {
    Pose T = Pose::Identity();
    T.linear() = r.R_L_O * s.T_O_S.linear();
    n.setPose(T);
  } else {
    const Impl::Node& prev = m.nodes[r.nodes.back()];
    n.travelled = prev.travelled + (prev.T_O_S.inverse() * s.T_O_S).translation().norm();
    n.setPose(prev.pose() * prev.T_O_S.inverse() * s.T_O_S);
  }
  m.index[s.id] = m.nodes.size();
  r.nodes.push_back(m.nodes.size());
  m.nodes.push_back(std::move(n));
  m.dirty = true;
}

void MapMerger::setLevelling(const std::string& robot, const Eigen::Matrix3d& R_L_O) {
  auto [it, is_new] = impl_->robots.try_emplace(robot);
  if (is_new) it->second.order = impl_->robots.size() - 1;
  it->second.R_L_O = R_L_O;
  impl_->dirty = true;
}

bool MapMerger::addLoop(const Loop& loop) {
  Impl& m = *impl_;
  auto iq = m.index.find(loop.query_id), ic = m.index.find(loop.candidate_id);
  if (iq == m.index.end() || ic == m.index.end() || !finitePose(loop.T_c_q)) return false;
  if (iq->second == ic->second) return false;
  Impl::LoopRec l;
  l.loop = loop;
  const size_t q = iq->second, c = ic->second;
  // Normalise so that a's robot sorts first (the group key is an ordered robot pair).
  if (m.nodes[c].robot <= m.nodes[q].robot) {
    l.a = c;
    l.b = q;
    l.T_a_b = loop.T_c_q;
  } else {
    l.a = q;
    l.b = c;
    l.T_a_b = loop.T_c_q.inverse();
  }
  l.sigmas = m.loopSigmas(loop.covariance, m.nodes[q].open_stand || m.nodes[c].open_stand);
  m.loops.push_back(l);
  addToGroup(m, m.loops.size() - 1);
  m.dirty = true;
  return true;
}

void MapMerger::setStemMap(const std::vector<FieldStem>& field) {
  impl_->field = field;
  impl_->dirty = true;
}

MergeSolveStats MapMerger::solve() {
  Impl& m = *impl_;
  MergeSolveStats st;
  if (m.dirty && !m.nodes.empty()) {
    const auto t0 = std::chrono::steady_clock::now();
    runPcm(m);
    updateComponents(m);
    st.pcm_ms = msSince(t0);
    const auto t1 = std::chrono::steady_clock::now();
    const MergeSolveStats g = solveGraph(m);
    st.solve_ms = msSince(t1);
    st.iterations = g.iterations;
    st.iterative = g.iterative;
    st.initial_cost = g.initial_cost;
    st.final_cost = g.final_cost;
    updateLoopResiduals(m);
    buildInventory(m);
    m.dirty = false;
    m.refined = false;
  }
  for (const auto& l : m.loops) (l.used ? st.loops_used : st.loops_rejected)++;
  st.components = componentCount();
  return st;
}

MergeSolveStats MapMerger::refine() {
  Impl& m = *impl_;
  MergeSolveStats st = solve();
  if (m.refined || m.nodes.empty()) return st;
  bool joined = false;
  for (const Loop& l : inventoryJoins(m)) joined = addLoop(l) || joined;
  if (joined) st = solve();
  if (m.p.landmarks) {
    const auto t0 = std::chrono::steady_clock::now();
    refineWithLandmarks(m, &st);
    updateLoopResiduals(m);
    buildInventory(m);
    st.solve_ms += msSince(t0);
  }
  m.refined = true;
  return st;
}

std::vector<MergeEvent> MapMerger::takeEvents() {
  std::vector<MergeEvent> out;
  out.swap(impl_->events);
  return out;
}

size_t MapMerger::submapCount() const { return impl_->nodes.size(); }

std::vector<std::string> MapMerger::robots() const { return impl_->robotOrder(); }

int MapMerger::component(const std::string& robot) const {
  auto it = impl_->robots.find(robot);
  return it == impl_->robots.end() ? -1 : it->second.component;
}

int MapMerger::componentCount() const { return impl_->countComponents(); }

std::optional<Pose> MapMerger::pose(int64_t id) const {
  auto it = impl_->index.find(id);
  if (it == impl_->index.end()) return std::nullopt;
  const Impl::Node& n = impl_->nodes[it->second];
  return impl_->outputTransform(impl_->robots.at(n.robot).component) * n.pose();
}

std::optional<Pose> MapMerger::mapFromOdom(const std::string& robot) const {
  auto it = impl_->robots.find(robot);
  if (it == impl_->robots.end() || it->second.nodes.empty()) return std::nullopt;
  // Of the latest submap: where the robot is now is what the TF should get right.
  const Impl::Node& n = impl_->nodes[it->second.nodes.back()];
  return *pose(n.id) * n.T_O_S.inverse();
}

std::vector<MergedPose> MapMerger::poses() const {
  std::vector<MergedPose> out;
  for (const Impl::Node& n : impl_->nodes) {
    MergedPose mp;
    mp.id = n.id;
    mp.robot = n.robot;
    mp.component = impl_->robots.at(n.robot).component;
    mp.T_M_S = impl_->outputTransform(mp.component) * n.pose();
    out.push_back(mp);
  }
  return out;
}

std::vector<LoopVerdict> MapMerger::loops() const {
  std::vector<LoopVerdict> out;
  for (const auto& l : impl_->loops) {
    LoopVerdict v;
    v.query_id = l.loop.query_id;
    v.candidate_id = l.loop.candidate_id;
    v.inter_robot = l.loop.query_robot != l.loop.candidate_robot;
    v.used = l.used;
    v.residual_sigmas = l.residual_sigmas;
    out.push_back(v);
  }
  return out;
}

std::vector<MergedStem> MapMerger::stems() const { return impl_->stems; }

StemMapRegistration MapMerger::stemMapRegistration() const { return impl_->registration; }

std::vector<MergeGraphEdge> MapMerger::graphEdges() const {
  const Impl& m = *impl_;
  std::vector<MergeGraphEdge> out;
  for (const auto& [name, r] : m.robots) {
    for (size_t k = 1; k < r.nodes.size(); ++k) {
      MergeGraphEdge e;
      e.from = m.nodes[r.nodes[k - 1]].id;
      e.to = m.nodes[r.nodes[k]].id;
      e.T_from_to = m.odom(r.nodes[k - 1], r.nodes[k]);
      const Vector6d s = m.odomSigmas(e.T_from_to.translation().norm());
      e.information = s.cwiseAbs2().cwiseInverse().asDiagonal();
      out.push_back(e);
    }
  }
  for (const auto& l : m.loops) {
    if (!l.used) continue;
    MergeGraphEdge e;
    e.from = m.nodes[l.a].id;
    e.to = m.nodes[l.b].id;
    e.T_from_to = l.T_a_b;
    e.information = l.sigmas.cwiseAbs2().cwiseInverse().asDiagonal();
    e.loop = true;
    out.push_back(e);
  }
  return out;
}

const MergeParams& MapMerger::params() const { return impl_->p; }

MergeSubmap mergeSubmapOf(const Descriptor& d, const Pose& T_O_S) {
  MergeSubmap s;
  s.robot = d.robot;
  s.id = d.submap_id;
  s.stamp = d.stamp;
  s.T_O_S = T_O_S;
  s.trunks = d.observedTrunks();
  s.open_stand = d.accumulated;
  if (!d.levelled()) return s;
  const Eigen::Matrix3d R_S_L = d.level_rotation.normalized().conjugate().toRotationMatrix();
  for (TrunkLandmark& t : s.trunks) {
    const Eigen::Vector3d p = R_S_L * Eigen::Vector3d(t.x, t.y, t.z);
    t.x = p.x(), t.y = p.y(), t.z = p.z();
  }
  return s;
}

Eigen::Matrix3d levellingInOdom(const Eigen::Matrix3d& R_L_S, const Pose& T_O_S) {
  return R_L_S * T_O_S.linear().transpose();
}

}  // namespace dtif
