#include "dtif/ros/merge_outputs.h"

#include <map>

#include "dtif/ros/conversions.h"
#include "dtif/ros/markers.h"

namespace dtif {
namespace ros_glue {
namespace {

// A distinct colour per robot (index in sorted order).
std_msgs::ColorRGBA robotColour(size_t k) {
  static const float kPalette[][3] = {{0.12f, 0.47f, 0.71f}, {1.0f, 0.5f, 0.05f},
                                      {0.58f, 0.4f, 0.74f},  {0.55f, 0.34f, 0.29f},
                                      {0.89f, 0.47f, 0.76f}, {0.09f, 0.75f, 0.81f}};
  const float* p = kPalette[k % 6];
  return color(p[0], p[1], p[2], 1.0f);
}

}  // namespace

nav_msgs::Path pathMsg(const std::vector<std::pair<double, Pose>>& T_M_S, const std::string& frame,
                       const ros::Time& stamp) {
  nav_msgs::Path path;
  path.header.frame_id = frame;
  path.header.stamp = stamp;
  for (const auto& [t, T] : T_M_S) {
    geometry_msgs::PoseStamped p;
    p.header.frame_id = frame;
    p.header.stamp.fromSec(t);
    p.pose = toMsg(T);
    path.poses.push_back(p);
  }
  return path;
}

dtif::StemInventory stemInventoryMsg(const std::vector<MergedStem>& stems, int component,
                                     const std::string& frame, const ros::Time& stamp) {
  dtif::StemInventory msg;
  msg.header.frame_id = frame;
  msg.header.stamp = stamp;
  for (const MergedStem& s : stems) {
    if (s.component != component) continue;
    dtif::InventoryStem m;
    m.stem_id = static_cast<uint32_t>(s.stem_id);
    m.base.x = s.x;
    m.base.y = s.y;
    m.base.z = s.z_base;
    m.dbh = static_cast<float>(s.dbh);
    m.observations = static_cast<uint32_t>(s.observations);
    m.field_id = s.field_id;
    msg.stems.push_back(m);
  }
  return msg;
}

visualization_msgs::MarkerArray mergedMapMarkers(const std::vector<MergedPose>& poses,
                                                 const std::vector<LoopVerdict>& loops,
                                                 const std::vector<MergedStem>& stems,
                                                 const std::function<std::string(int)>& frame_of,
                                                 const ros::Time& stamp) {
  using visualization_msgs::Marker;
  visualization_msgs::MarkerArray out;
  Marker clear;
  clear.action = Marker::DELETEALL;
  out.markers.push_back(clear);
  std::map<int64_t, const MergedPose*> by_id;
  std::map<std::string, size_t> robot_index;
  for (const MergedPose& p : poses) {
    by_id[p.id] = &p;
    robot_index.emplace(p.robot, 0);
  }
  size_t k = 0;
  for (auto& r : robot_index) r.second = k++;
  std::map<int, Marker> nodes, used, rejected;
  auto get = [&](std::map<int, Marker>& m, int comp, const char* ns, int type) -> Marker* {
    const std::string frame = frame_of(comp);
    if (frame.empty()) return nullptr;
    auto it = m.find(comp);
    if (it == m.end()) it = m.emplace(comp, newMarker(frame, ns, comp, type, stamp)).first;
    return &it->second;
  };
  for (const MergedPose& p : poses) {
    Marker* m = get(nodes, p.component, "submaps", Marker::SPHERE_LIST);
    if (!m) continue;
    m->scale.x = m->scale.y = m->scale.z = 0.6;
    m->points.push_back(point(p.T_M_S.translation()));
    m->colors.push_back(robotColour(robot_index[p.robot]));
  }
  for (const LoopVerdict& l : loops) {
    auto a = by_id.find(l.query_id), b = by_id.find(l.candidate_id);
    if (a == by_id.end() || b == by_id.end()) continue;
    if (a->second->component != b->second->component) continue;
    Marker* m = get(l.used ? used : rejected, a->second->component,
                    l.used ? "loops" : "rejected_loops", Marker::LINE_LIST);
    if (!m) continue;
    m->scale.x = l.used ? 0.15 : 0.1;
    m->color = l.used ? color(0.1f, 0.85f, 0.2f, 1.0f) : color(0.9f, 0.1f, 0.1f, 1.0f);
    m->points.push_back(point(a->second->T_M_S.translation()));
    m->points.push_back(point(b->second->T_M_S.translation()));
  }
  int stem_id = 0;
  for (const MergedStem& s : stems) {
    const std::string frame = frame_of(s.component);
    if (frame.empty()) continue;
    Marker m = newMarker(frame, "stems", stem_id++, Marker::CYLINDER, stamp);
    m.scale.x = m.scale.y = std::max(0.05, s.dbh);
    m.scale.z = 1.3;
    m.pose.position = point(Eigen::Vector3d(s.x, s.y, s.z_base + 0.65));
    m.color = color(0.45f, 0.3f, 0.15f, 0.9f);
    out.markers.push_back(m);
  }
  for (auto* group : {&nodes, &used, &rejected}) {
    for (auto& g : *group) out.markers.push_back(g.second);
  }
  return out;
}

}  // namespace ros_glue
}  // namespace dtif
