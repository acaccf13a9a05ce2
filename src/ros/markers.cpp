#include "dtif/ros/markers.h"

#include <algorithm>
#include <set>
#include <utility>

#include "dtif/ros/conversions.h"

namespace dtif {
namespace ros_glue {

std_msgs::ColorRGBA color(float r, float g, float b, float a) {
  std_msgs::ColorRGBA c;
  c.r = r;
  c.g = g;
  c.b = b;
  c.a = a;
  return c;
}

geometry_msgs::Point point(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

visualization_msgs::Marker newMarker(const std::string& frame, const std::string& ns, int id,
                                     int type, const ros::Time& stamp) {
  visualization_msgs::Marker m;
  m.header.frame_id = frame;
  m.header.stamp = stamp;
  m.ns = ns;
  m.id = id;
  m.type = type;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  return m;
}

namespace {

Eigen::Vector3d trunkPoint(const TrunkLandmark& t, double dz = 0.0) { return {t.x, t.y, t.z + dz}; }

// Delaunay edges of a descriptor as a LINE_LIST at 1.3 m above the stem bases.
visualization_msgs::Marker edgeMarker(const Descriptor& d, const Pose& T_F_S,
                                      const std::string& frame, const std::string& ns, int id,
                                      const ros::Time& stamp, const std_msgs::ColorRGBA& c) {
  visualization_msgs::Marker m =
      newMarker(frame, ns, id, visualization_msgs::Marker::LINE_LIST, stamp);
  m.scale.x = 0.05;
  m.color = c;
  std::set<std::pair<int, int>> edges;
  for (const Triangle& tri : d.triangles) {
    for (int e = 0; e < 3; ++e) {
      int a = tri.v[e], b = tri.v[(e + 1) % 3];
      if (a > b) std::swap(a, b);
      edges.emplace(a, b);
    }
  }
  const int n = static_cast<int>(d.trunks.size());
  for (const auto& e : edges) {
    if (e.first < 0 || e.second >= n) continue;
    m.points.push_back(point(T_F_S * trunkPoint(d.trunks[e.first], 1.3)));
    m.points.push_back(point(T_F_S * trunkPoint(d.trunks[e.second], 1.3)));
  }
  return m;
}

void addCylinders(const Descriptor& d, const Pose& T_F_S, const std::string& frame,
                  const std::string& ns, const ros::Time& stamp, const std_msgs::ColorRGBA& c,
                  visualization_msgs::MarkerArray* out) {
  const Eigen::Quaterniond q(T_F_S.rotation());
  for (size_t i = 0; i < d.trunks.size(); ++i) {
    visualization_msgs::Marker m =
        newMarker(frame, ns, static_cast<int>(i), visualization_msgs::Marker::CYLINDER, stamp);
    m.pose.position = point(T_F_S * trunkPoint(d.trunks[i], 1.0));
    m.pose.orientation.x = q.x();
    m.pose.orientation.y = q.y();
    m.pose.orientation.z = q.z();
    m.pose.orientation.w = q.w();
    const double diameter = std::max(0.05, 2.0 * d.trunks[i].r);
    m.scale.x = diameter;
    m.scale.y = diameter;
    m.scale.z = 2.0;
    m.color = c;
    out->markers.push_back(m);
  }
}

}  // namespace

visualization_msgs::MarkerArray trunkMarkers(const Descriptor& d, const Pose& T_F_S,
                                             const std::string& frame, const std::string& ns,
                                             const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  addCylinders(d, T_F_S, frame, ns + "/trunks", stamp, color(0.55f, 0.35f, 0.15f), &out);
  out.markers.push_back(
      edgeMarker(d, T_F_S, frame, ns + "/topology", 0, stamp, color(0.2f, 0.6f, 1.0f, 0.8f)));
  return out;
}

visualization_msgs::MarkerArray loopMarkers(const Descriptor& q, const Descriptor& c,
                                            const Loop& lc, const Pose& T_F_Sq,
                                            const std::string& frame, const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  {
    visualization_msgs::Marker clear;
    clear.action = visualization_msgs::Marker::DELETEALL;
    clear.header.frame_id = frame;
    clear.header.stamp = stamp;
    out.markers.push_back(clear);
  }
  // Trunks are in each descriptor's levelled frame L (= S when not levelled).
  auto levelledFrame = [](const Pose& T_F_S, const Descriptor& d) {
    Pose T_F_L = T_F_S;
    T_F_L.linear() = T_F_S.rotation() * d.level_rotation.conjugate().toRotationMatrix();
    return T_F_L;
  };
  const Pose T_F_Lq = levelledFrame(T_F_Sq, q);
  const Pose T_F_Lc = levelledFrame(T_F_Sq * lc.T_c_q.inverse(), c);
  addCylinders(q, T_F_Lq, frame, "query/trunks", stamp, color(1.0f, 0.5f, 0.0f, 0.8f), &out);
  addCylinders(c, T_F_Lc, frame, "candidate/trunks", stamp, color(0.3f, 0.3f, 1.0f, 0.8f), &out);
  out.markers.push_back(
      edgeMarker(q, T_F_Lq, frame, "query/topology", 0, stamp, color(1.0f, 0.5f, 0.0f)));
  out.markers.push_back(
      edgeMarker(c, T_F_Lc, frame, "candidate/topology", 0, stamp, color(0.3f, 0.3f, 1.0f)));

  auto pairs = [&](const std::vector<std::pair<int, int>>& ps, const std::string& ns,
                   const std_msgs::ColorRGBA& col, double width) {
    visualization_msgs::Marker m =
        newMarker(frame, ns, 0, visualization_msgs::Marker::LINE_LIST, stamp);
    m.scale.x = width;
    m.color = col;
    for (const auto& p : ps) {
      if (p.first < 0 || p.second < 0 || p.first >= static_cast<int>(q.trunks.size()) ||
          p.second >= static_cast<int>(c.trunks.size())) {
        continue;
      }
      // Query vertex at 2.5 m, candidate vertex at 3.0 m so coincident pairs stay visible.
      m.points.push_back(point(T_F_Lq * trunkPoint(q.trunks[p.first], 2.5)));
      m.points.push_back(point(T_F_Lc * trunkPoint(c.trunks[p.second], 3.0)));
    }
    out.markers.push_back(m);
  };
  pairs(lc.all_pairs, "pairs", color(0.6f, 0.6f, 0.6f, 0.6f), 0.03);
  pairs(lc.inlier_pairs, "inliers", color(0.1f, 1.0f, 0.1f), 0.08);
  return out;
}

void RecentMarkers::add(visualization_msgs::MarkerArray m) {
  if (capacity_ == 0) return;
  std::lock_guard<std::mutex> lock(mutex_);
  kept_.push_back(std::move(m));
  while (kept_.size() > capacity_) kept_.pop_front();
}

boost::shared_ptr<const visualization_msgs::MarkerArray> RecentMarkers::all() const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (kept_.empty()) return nullptr;
  boost::shared_ptr<visualization_msgs::MarkerArray> out(new visualization_msgs::MarkerArray);
  for (const auto& a : kept_) {
    out->markers.insert(out->markers.end(), a.markers.begin(), a.markers.end());
  }
  return out;
}

size_t RecentMarkers::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return kept_.size();
}

}  // namespace ros_glue
}  // namespace dtif
