#include "dtif/core/merge/map_merger.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <set>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

#include "core/merge/merge_graph.h"
#include "dtif/core/merge/join_check.h"
#include "dtif/core/merge/pcm.h"
#include "dtif/core/timing.h"

namespace dtif {
namespace {

bool finitePose(const Pose& T) { return T.matrix().allFinite(); }

}  // namespace

// The merger's state (merge_graph.h) with the pieces that have no file of their own yet.
struct MapMerger::Impl : MergeGraph {
  using MergeGraph::MergeGraph;

  // --- stems ---------------------------------------------------------------------------------
  std::vector<MergedStem> fuseInventory(bool with_field_transform) const {
    std::vector<StemObservation> obs;
    std::vector<SensorPosition> sensors;
    std::map<std::string, int> robot_ids;
    for (const Node& n : nodes) {
      const int comp = robots.at(n.robot).component;
      const Pose T = (with_field_transform ? outputTransform(comp) : Pose::Identity()) * n.pose();
      // S's origin is the sensor at the submap's anchor time (DATASET.md).
      const Eigen::Vector3d sensor = T.translation();
      const int robot_id =
          robot_ids.emplace(n.robot, static_cast<int>(robot_ids.size())).first->second;
      sensors.push_back({comp, robot_id, sensor.x(), sensor.y(), sensor.z()});
      for (const TrunkLandmark& tr : n.trunks) {
        const Eigen::Vector3d pm = T * Eigen::Vector3d(tr.x, tr.y, tr.z);
        StemObservation o;
        o.submap = n.id;
        o.component = comp;
        o.x = pm.x();
        o.y = pm.y();
        o.z = pm.z();
        o.r = tr.r;
        o.base_seen = tr.base_seen;
        obs.push_back(o);
      }
    }
    return fuseStems(obs, p.stems, sensors);
  }

  // --- joining components by their inventories ---------------------------------------------
  /// For each component c > 0 whose inventory registers to component 0's
  /// (MergeParams::join_min_pairs): a loop from c's submap to component 0's submap nearest it
  /// after registration, with the registration's pose (planar; the elevation from the paired
  /// stems' bases). Appends one event per loop.
  std::vector<Loop> inventoryJoins() {
    std::vector<Loop> out;
    if (p.join_min_pairs < 1 || countComponents() < 2) return out;
    const std::vector<MergedStem> inv = fuseInventory(false);
    std::vector<FieldStem> target;  // component 0's inventory, the map the others register to
    std::vector<double> target_z;
    for (const MergedStem& s : inv) {
      if (s.component != 0) continue;
      target.push_back({std::to_string(s.stem_id), s.x, s.y, s.dbh});
      target_z.push_back(s.z_base);
    }
    for (int c = 1; c < countComponents(); ++c) {
      Trunks stems;
      for (const MergedStem& s : inv) {
        if (s.component != c) continue;
        TrunkLandmark t;
        t.x = s.x, t.y = s.y, t.z = s.z_base, t.r = s.dbh / 2.0;
        stems.push_back(t);
      }
      const StemMapRegistration reg = registerStemMap(stems, target, joinParams());
      if (!reg.ok || reg.rms_m > p.join_max_rms_m) continue;
      std::vector<double> dz;
      for (const auto& [i, j] : reg.pairs) dz.push_back(target_z[j] - stems[i].z);
      std::nth_element(dz.begin(), dz.begin() + dz.size() / 2, dz.end());
      Pose T_0_c = reg.T_P_M;
      T_0_c.translation().z() = dz[dz.size() / 2];
      Loop l = joinLoop(c, T_0_c, reg);
      // Once per submap pair: a join PCM rejected is not offered again at the next refine().
      if (std::none_of(loops.begin(), loops.end(), [&](const LoopRec& r) {
            return r.loop.query_id == l.query_id && r.loop.candidate_id == l.candidate_id;
          })) {
        logJoin(c, l, reg);
        out.push_back(std::move(l));
      }
    }
    return out;
  }

  StemMapParams joinParams() const {
    StemMapParams s;
    s.loop = LoopDetectorParams();  // two LiDAR inventories: the loop detector's tolerances
    s.pair_radius_m = p.join_pair_radius_m;
    s.min_pairs = p.join_min_pairs;
    return s;
  }

  /// The loop that joins component c to 0: from c's submap to the one of component 0 nearest it
  /// under T_0_c (horizontally).
  Loop joinLoop(int c, const Pose& T_0_c, const StemMapRegistration& reg) {
    size_t qa = 0, cb = 0;
    double best = std::numeric_limits<double>::infinity();
    for (size_t a = 0; a < nodes.size(); ++a) {
      if (robots.at(nodes[a].robot).component != c) continue;
      const Eigen::Vector3d pa = T_0_c * nodes[a].t;
      for (size_t b = 0; b < nodes.size(); ++b) {
        if (robots.at(nodes[b].robot).component != 0) continue;
        const double d = (pa - nodes[b].t).head<2>().norm();
        if (d < best) best = d, qa = a, cb = b;
      }
    }
    Loop l;
    l.query_robot = nodes[qa].robot;
    l.query_id = nodes[qa].id;
    l.candidate_robot = nodes[cb].robot;
    l.candidate_id = nodes[cb].id;
    l.T_c_q = nodes[cb].pose().inverse() * T_0_c * nodes[qa].pose();
    Vector6d sd;
    sd << reg.rms_m, reg.rms_m, 0.1, 0.005, 0.005, 0.005;  // z from the bases: a decimetre
    l.covariance = sd.cwiseAbs2().asDiagonal();
    l.inliers = static_cast<int>(reg.pairs.size());
    return l;
  }

  void logJoin(int c, const Loop& l, const StemMapRegistration& reg) {
    std::ostringstream e;
    e << "component " << c << " (robot " << l.query_robot << ") registers to component 0 by its "
      << "stem inventory: " << reg.pairs.size() << " stems paired, RMS " << reg.rms_m
      << " m; join loop " << l.query_robot << "/" << l.query_id << " -> " << l.candidate_robot
      << "/" << l.candidate_id;
    events.push_back({l.query_robot, c, 0, e.str()});
  }

  void registerField() {
    registration = StemMapRegistration{};
    if (field.empty()) return;
    Trunks comp0;
    for (const MergedStem& s : fuseInventory(false)) {
      if (s.component != 0) continue;
      TrunkLandmark t;
      t.x = s.x;
      t.y = s.y;
      t.z = s.z_base;
      t.r = s.dbh / 2.0;
      comp0.push_back(t);
    }
    registration = registerStemMap(comp0, field, p.stem_map);
  }

  void buildInventory() {
    registerField();
    stems = fuseInventory(true);
    if (!registration.ok) return;
    // The field ids of the paired stems (the inventory in P is registration's order, again).
    for (MergedStem& s : stems) {
      if (s.component != 0) continue;
      double best = p.stem_map.pair_radius_m;
      for (const FieldStem& f : field) {
        const double d = std::hypot(s.x - f.x, s.y - f.y);
        if (d < best) {
          best = d;
          s.field_id = f.id;
        }
      }
    }
  }
};

std::string MergeParams::validate() const {
  std::ostringstream e;
  for (double v : {odom_sigma_xy_m, odom_sigma_z_m, odom_sigma_rot_rad, odom_sigma_tilt_rad,
                   loop_sigma_xy_min_m, loop_sigma_z_min_m, loop_sigma_rot_min_rad,
                   robust_loss_scale, pcm_sigmas}) {
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
  for (double v : {landmark_gate_m, landmark_sigma_xy_m, landmark_sigma_z_m, landmark_loss_scale}) {
    if (!(v > 0.0)) e << "merge landmark gate, sigmas and loss scale must be > 0; ";
  }
  if (!(landmark_radius_tol_m >= 0.0)) e << "merge landmark_radius_tol_m must be >= 0; ";
  if (landmark_min_observations < 2) e << "merge landmark_min_observations must be >= 2; ";
  if (landmark_rounds < 1) e << "merge landmark_rounds must be >= 1; ";
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
  l.sigmas = m.loopSigmas(loop.covariance);
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
    m.buildInventory();
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
  for (const Loop& l : m.inventoryJoins()) joined = addLoop(l) || joined;
  if (joined) st = solve();
  if (m.p.landmarks) {
    const auto t0 = std::chrono::steady_clock::now();
    refineWithLandmarks(m, &st);
    updateLoopResiduals(m);
    m.buildInventory();
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
  s.trunks = d.trunks;
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
