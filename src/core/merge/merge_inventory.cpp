// The merged stem inventory: its registration to the field stem map, and the loops that join a
// component to component 0 when their inventories register to each other.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/merge/merge_graph.h"

namespace dtif {
namespace {

std::vector<MergedStem> fuseInventory(const MergeGraph& m, bool with_field_transform) {
  std::vector<StemObservation> obs;
  std::vector<SensorPosition> sensors;
  std::map<std::string, int> robot_ids;
  for (const MergeGraph::Node& n : m.nodes) {
    const int comp = m.robots.at(n.robot).component;
    const Pose T = (with_field_transform ? m.outputTransform(comp) : Pose::Identity()) * n.pose();
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
  return fuseStems(obs, m.p.stems, sensors);
}

/// Component c's stems of the inventory as trunks (base elevation, radius from the DBH).
Trunks componentStems(const std::vector<MergedStem>& inv, int c) {
  Trunks stems;
  for (const MergedStem& s : inv) {
    if (s.component != c) continue;
    TrunkLandmark t;
    t.x = s.x, t.y = s.y, t.z = s.z_base, t.r = s.dbh / 2.0;
    stems.push_back(t);
  }
  return stems;
}

StemMapParams joinParams(const MergeParams& p) {
  StemMapParams s;
  s.loop = LoopDetectorParams();  // two LiDAR inventories: the loop detector's tolerances
  s.pair_radius_m = p.join_pair_radius_m;
  s.min_pairs = p.join_min_pairs;
  return s;
}

/// The registration's planar pose, with the elevation from the paired stems' bases (median).
Pose joinPose(const StemMapRegistration& reg, const Trunks& stems,
              const std::vector<double>& target_z) {
  std::vector<double> dz;
  for (const auto& [i, j] : reg.pairs) dz.push_back(target_z[j] - stems[i].z);
  std::nth_element(dz.begin(), dz.begin() + dz.size() / 2, dz.end());
  Pose T_0_c = reg.T_P_M;
  T_0_c.translation().z() = dz[dz.size() / 2];
  return T_0_c;
}

/// The loop that joins component c to 0: from c's submap to the one of component 0 nearest it
/// under T_0_c (horizontally).
Loop joinLoop(const MergeGraph& m, int c, const Pose& T_0_c, const StemMapRegistration& reg) {
  size_t qa = 0, cb = 0;
  double best = std::numeric_limits<double>::infinity();
  for (size_t a = 0; a < m.nodes.size(); ++a) {
    if (m.robots.at(m.nodes[a].robot).component != c) continue;
    const Eigen::Vector3d pa = T_0_c * m.nodes[a].t;
    for (size_t b = 0; b < m.nodes.size(); ++b) {
      if (m.robots.at(m.nodes[b].robot).component != 0) continue;
      const double d = (pa - m.nodes[b].t).head<2>().norm();
      if (d < best) best = d, qa = a, cb = b;
    }
  }
  Loop l;
  l.query_robot = m.nodes[qa].robot;
  l.query_id = m.nodes[qa].id;
  l.candidate_robot = m.nodes[cb].robot;
  l.candidate_id = m.nodes[cb].id;
  l.T_c_q = m.nodes[cb].pose().inverse() * T_0_c * m.nodes[qa].pose();
  Vector6d sd;
  sd << reg.rms_m, reg.rms_m, 0.1, 0.005, 0.005, 0.005;  // z from the bases: a decimetre
  l.covariance = sd.cwiseAbs2().asDiagonal();
  l.inliers = static_cast<int>(reg.pairs.size());
  return l;
}

void logJoin(MergeGraph& m, int c, const Loop& l, const StemMapRegistration& reg) {
  std::ostringstream e;
  e << "component " << c << " (robot " << l.query_robot << ") registers to component 0 by its "
    << "stem inventory: " << reg.pairs.size() << " stems paired, RMS " << reg.rms_m
    << " m; join loop " << l.query_robot << "/" << l.query_id << " -> " << l.candidate_robot << "/"
    << l.candidate_id;
  m.events.push_back({l.query_robot, c, 0, e.str()});
}

void registerField(MergeGraph& m) {
  m.registration = StemMapRegistration{};
  if (m.field.empty()) return;
  m.registration =
      registerStemMap(componentStems(fuseInventory(m, false), 0), m.field, m.p.stem_map);
}

}  // namespace

/// For each component c > 0 whose inventory registers to component 0's
/// (MergeParams::join_min_pairs): a loop from c's submap to component 0's submap nearest it
/// after registration, with the registration's pose (planar; the elevation from the paired
/// stems' bases). Appends one event per loop.
std::vector<Loop> inventoryJoins(MergeGraph& m) {
  std::vector<Loop> out;
  if (m.p.join_min_pairs < 1 || m.countComponents() < 2) return out;
  const std::vector<MergedStem> inv = fuseInventory(m, false);
  std::vector<FieldStem> target;  // component 0's inventory, the map the others register to
  std::vector<double> target_z;
  for (const MergedStem& s : inv) {
    if (s.component != 0) continue;
    target.push_back({std::to_string(s.stem_id), s.x, s.y, s.dbh});
    target_z.push_back(s.z_base);
  }
  for (int c = 1; c < m.countComponents(); ++c) {
    const Trunks stems = componentStems(inv, c);
    const StemMapRegistration reg = registerStemMap(stems, target, joinParams(m.p));
    if (!reg.ok || reg.rms_m > m.p.join_max_rms_m) continue;
    Loop l = joinLoop(m, c, joinPose(reg, stems, target_z), reg);
    // Once per submap pair: a join PCM rejected is not offered again at the next refine().
    if (std::none_of(m.loops.begin(), m.loops.end(), [&](const MergeGraph::LoopRec& r) {
          return r.loop.query_id == l.query_id && r.loop.candidate_id == l.candidate_id;
        })) {
      logJoin(m, c, l, reg);
      out.push_back(std::move(l));
    }
  }
  return out;
}

void buildInventory(MergeGraph& m) {
  registerField(m);
  m.stems = fuseInventory(m, true);
  if (!m.registration.ok) return;
  // The field ids of the paired stems (the inventory in P is registration's order, again).
  for (MergedStem& s : m.stems) {
    if (s.component != 0) continue;
    double best = m.p.stem_map.pair_radius_m;
    for (const FieldStem& f : m.field) {
      const double d = std::hypot(s.x - f.x, s.y - f.y);
      if (d < best) {
        best = d;
        s.field_id = f.id;
      }
    }
  }
}

}  // namespace dtif
