// Components: the robots joined by used loops, each component in the map frame M of its anchor
// (its earliest robot's first submap, levelled).
#include <algorithm>
#include <set>
#include <sstream>

#include "core/merge/merge_graph.h"

namespace dtif {
namespace {

using Members = std::vector<std::string>;

/// Robots joined by used inter-robot loops, largest (by submaps) first; ties: earliest robot.
std::vector<Members> computeComponents(const MergeGraph& m) {
  const Members order = m.robotOrder();
  std::map<std::string, std::string> parent;
  for (const auto& r : order) parent[r] = r;
  auto find = [&](std::string r) {
    while (parent[r] != r) r = parent[r] = parent[parent[r]];
    return r;
  };
  for (const MergeGraph::LoopRec& l : m.loops) {
    if (!l.used) continue;
    const std::string ra = find(m.nodes[l.a].robot), rb = find(m.nodes[l.b].robot);
    if (ra == rb) continue;
    // The earlier robot stays the root, so the component's anchor is its earliest robot.
    if (m.robots.at(ra).order < m.robots.at(rb).order) {
      parent[rb] = ra;
    } else {
      parent[ra] = rb;
    }
  }
  std::map<std::string, Members> by_root;
  for (const auto& r : order) by_root[find(r)].push_back(r);
  std::vector<Members> comps;
  for (auto& [root, members] : by_root) comps.push_back(members);
  auto size = [&](const Members& c) {
    size_t n = 0;
    for (const auto& r : c) n += m.robots.at(r).nodes.size();
    return n;
  };
  std::sort(comps.begin(), comps.end(), [&](const auto& a, const auto& b) {
    const size_t sa = size(a), sb = size(b);
    if (sa != sb) return sa > sb;
    return m.robots.at(a.front()).order < m.robots.at(b.front()).order;
  });
  return comps;
}

void rebase(MergeGraph& m, const Members& members, int64_t old_frame, const Pose& T_new_old) {
  for (const auto& r : members) {
    if (m.robots.at(r).frame != old_frame) continue;
    for (size_t n : m.robots.at(r).nodes) m.nodes[n].setPose(T_new_old * m.nodes[n].pose());
  }
}

/// Moves the component's anchor to its levelled first pose when it is not there: the robots
/// in the anchor robot's frame move with it.
void placeAnchor(MergeGraph& m, const Members& members) {
  MergeGraph::Robot& first = m.robots.at(members.front());
  const MergeGraph::Node& anchor = m.nodes[first.nodes.front()];
  Pose target = Pose::Identity();
  target.linear() = first.R_L_O * anchor.T_O_S.linear();
  const Pose T_fix = target * anchor.pose().inverse();
  if (first.frame != anchor.id || !T_fix.isApprox(Pose::Identity(), 1e-12)) {
    const int64_t old = first.frame;
    for (const auto& r : members) {
      if (m.robots.at(r).frame == old) rebase(m, {r}, old, T_fix);
    }
    for (const auto& r : members) {
      if (m.robots.at(r).frame == old) m.robots.at(r).frame = anchor.id;
    }
  }
}

/// Expresses every robot of a component in the M of its anchor (its earliest robot's first
/// submap, levelled): rebases the robots reached through loops from other frames.
void placeComponent(MergeGraph& m, const Members& members) {
  placeAnchor(m, members);
  const int64_t anchor_id = m.nodes[m.robots.at(members.front()).nodes.front()].id;
  // Breadth first over used loops from the placed robots.
  const std::set<std::string> in(members.begin(), members.end());
  bool changed = true;
  while (changed) {
    changed = false;
    for (const MergeGraph::LoopRec& l : m.loops) {
      if (!l.used) continue;
      const std::string& ra = m.nodes[l.a].robot;
      const std::string& rb = m.nodes[l.b].robot;
      if (!in.count(ra) || !in.count(rb)) continue;
      const bool pa = m.robots.at(ra).frame == anchor_id, pb = m.robots.at(rb).frame == anchor_id;
      if (pa == pb) continue;
      const size_t placed = pa ? l.a : l.b, other = pa ? l.b : l.a;
      const Pose T_placed_other = pa ? l.T_a_b : l.T_a_b.inverse();
      const Pose T_new_old =
          m.nodes[placed].pose() * T_placed_other * m.nodes[other].pose().inverse();
      const int64_t old = m.robots.at(m.nodes[other].robot).frame;
      for (const auto& r : members) {
        if (m.robots.at(r).frame != old) continue;
        rebase(m, {r}, old, T_new_old);
        m.robots.at(r).frame = anchor_id;
      }
      changed = true;
    }
  }
}

/// What happened to robot r (now in component cid with `members`) since it was in component
/// rob.component in the frame of submap old_frame.
std::string componentChange(const std::string& r, const MergeGraph::Robot& rob, int cid,
                            int64_t old_frame, const Members& members) {
  std::ostringstream os;
  if (rob.component < 0) {
    os << "robot " << r << " starts in component " << cid;
  } else if (old_frame == rob.frame) {
    os << "robot " << r << " renumbered: component " << rob.component << " -> " << cid
       << " (same map frame)";
  } else {
    os << "robot " << r << " moves from component " << rob.component << " to " << cid
       << " (map frame of submap " << rob.frame << ")";
  }
  if (members.size() > 1) {
    os << " with";
    for (const auto& o : members) os << " " << o;
  }
  return os.str();
}

}  // namespace

void updateComponents(MergeGraph& m) {
  const auto comps = computeComponents(m);
  for (size_t c = 0; c < comps.size(); ++c) {
    std::map<std::string, int64_t> old_frames;
    for (const auto& r : comps[c]) old_frames[r] = m.robots.at(r).frame;
    placeComponent(m, comps[c]);
    for (const auto& r : comps[c]) {
      MergeGraph::Robot& rob = m.robots.at(r);
      const int cid = static_cast<int>(c);
      if (rob.component == cid && old_frames[r] == rob.frame) continue;
      MergeEvent ev;
      ev.robot = r;
      ev.from_component = rob.component;
      ev.to_component = cid;
      ev.text = componentChange(r, rob, cid, old_frames[r], comps[c]);
      rob.component = cid;
      m.events.push_back(ev);
    }
  }
}

}  // namespace dtif
