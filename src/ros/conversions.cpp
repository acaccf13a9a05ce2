#include "dtif/ros/conversions.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "dtif/core/descriptor/validation.h"

namespace dtif {
namespace ros_glue {
namespace {

bool fail(std::string* error, const std::string& why) {
  if (error) *error = why;
  return false;
}

bool finite(double v) { return std::isfinite(v); }

}  // namespace

geometry_msgs::Pose toMsg(const Pose& T) {
  geometry_msgs::Pose m;
  const Eigen::Vector3d t = T.translation();
  const Eigen::Quaterniond q(T.rotation());
  m.position.x = t.x();
  m.position.y = t.y();
  m.position.z = t.z();
  m.orientation.x = q.x();
  m.orientation.y = q.y();
  m.orientation.z = q.z();
  m.orientation.w = q.w();
  return m;
}

geometry_msgs::Transform toTransformMsg(const Pose& T) {
  const geometry_msgs::Pose p = toMsg(T);
  geometry_msgs::Transform m;
  m.translation.x = p.position.x;
  m.translation.y = p.position.y;
  m.translation.z = p.position.z;
  m.rotation = p.orientation;
  return m;
}

bool fromMsg(const geometry_msgs::Pose& msg, Pose* T, std::string* error) {
  const auto& p = msg.position;
  const auto& o = msg.orientation;
  if (!finite(p.x) || !finite(p.y) || !finite(p.z) || !finite(o.x) || !finite(o.y) ||
      !finite(o.z) || !finite(o.w)) {
    return fail(error, "pose has a non-finite value");
  }
  Eigen::Quaterniond q(o.w, o.x, o.y, o.z);
  if (q.norm() < 1e-6) return fail(error, "pose has a zero quaternion");
  q.normalize();
  *T = Pose::Identity();
  T->linear() = q.toRotationMatrix();
  T->translation() = Eigen::Vector3d(p.x, p.y, p.z);
  return true;
}

namespace {

// All zeros (a sender from before the field) is no levelling; anything else must be a unit
// quaternion, which is kept as sent (exactly identity stays "not levelled").
bool levelRotationFromMsg(const geometry_msgs::Quaternion& m, Eigen::Quaterniond* q,
                          std::string* error) {
  if (m.x == 0.0 && m.y == 0.0 && m.z == 0.0 && m.w == 0.0) {
    *q = Eigen::Quaterniond::Identity();
    return true;
  }
  const Eigen::Quaterniond r(m.w, m.x, m.y, m.z);
  if (!r.coeffs().allFinite() || std::abs(r.norm() - 1.0) > 1e-3) {
    *error = "not a unit quaternion";
    return false;
  }
  *q = std::abs(r.norm() - 1.0) > 0.0 ? r.normalized() : r;
  return true;
}

std::vector<dtif::Trunk> trunksToMsg(const Trunks& trunks) {
  std::vector<dtif::Trunk> out;
  out.reserve(trunks.size());
  for (const TrunkLandmark& t : trunks) {
    dtif::Trunk mt;
    mt.x = static_cast<float>(t.x);
    mt.y = static_cast<float>(t.y);
    mt.z = static_cast<float>(t.z);
    mt.r = static_cast<float>(t.r);
    mt.base_seen = t.base_seen;
    out.push_back(mt);
  }
  return out;
}

Trunks trunksFromMsg(const std::vector<dtif::Trunk>& msg) {
  Trunks out;
  out.reserve(msg.size());
  for (const dtif::Trunk& t : msg)
    out.push_back(TrunkLandmark{t.x, t.y, t.z, t.r, t.base_seen != 0});
  return out;
}

}  // namespace

dtif::TrunkDescriptor toMsg(const Descriptor& d, const Pose& T_O_S, const std::string& odom_frame) {
  dtif::TrunkDescriptor m;
  m.header.frame_id = odom_frame;
  if (d.stamp > 0.0 && std::isfinite(d.stamp)) m.header.stamp.fromSec(d.stamp);
  m.robot = d.robot;
  m.submap_id = d.submap_id;
  m.odom_pose = toMsg(T_O_S);
  const Eigen::Quaterniond& q = d.level_rotation;
  m.level_rotation.x = q.x();
  m.level_rotation.y = q.y();
  m.level_rotation.z = q.z();
  m.level_rotation.w = q.w();
  m.trunks = trunksToMsg(d.trunks);
  m.accumulated = d.accumulated;
  if (d.accumulated) m.own_trunks = trunksToMsg(d.own_trunks);
  m.faces.reserve(3 * d.triangles.size());
  for (const Triangle& tri : d.triangles) {
    for (int i : tri.v) m.faces.push_back(static_cast<uint16_t>(i));
  }
  m.edge_hist = d.edge_hist;
  m.radius_hist = d.radius_hist;
  m.valid = d.valid;
  m.invalid_reason = d.invalid_reason;
  const Footprint& f = d.footprint;
  if (f.wellFormed()) {
    m.footprint_cell_m = static_cast<float>(f.cell_m);
    m.footprint_x0 = f.x0;
    m.footprint_y0 = f.y0;
    m.footprint_width = static_cast<uint16_t>(f.width);
    m.footprint_height = static_cast<uint16_t>(f.height);
    m.footprint_bits = f.bits;
  }
  m.ground_map = encodeGroundMap(d.ground_map);
  return m;
}

bool fromMsg(const dtif::TrunkDescriptor& msg, const DescriptorParams& params, Descriptor* d,
             Pose* T_O_S, std::string* error) {
  Descriptor out;
  out.robot = msg.robot;
  out.submap_id = msg.submap_id;
  out.stamp = msg.header.stamp.toSec();
  out.trunks = trunksFromMsg(msg.trunks);
  out.accumulated = msg.accumulated;
  if (out.accumulated) out.own_trunks = trunksFromMsg(msg.own_trunks);
  if (msg.faces.size() % 3 != 0) return fail(error, "faces is not a list of triples");
  out.triangles.resize(msg.faces.size() / 3);
  for (size_t f = 0; f < out.triangles.size(); ++f) {
    for (int k = 0; k < 3; ++k) out.triangles[f].v[k] = msg.faces[3 * f + k];
  }
  out.edge_hist = msg.edge_hist;
  out.radius_hist = msg.radius_hist;
  out.valid = msg.valid;
  out.invalid_reason = msg.invalid_reason;
  if (msg.footprint_cell_m != 0.0f) {  // 0: none; a bad one is kept for the check to name
    out.footprint.cell_m = msg.footprint_cell_m;
    out.footprint.x0 = msg.footprint_x0;
    out.footprint.y0 = msg.footprint_y0;
    out.footprint.width = msg.footprint_width;
    out.footprint.height = msg.footprint_height;
    out.footprint.bits = msg.footprint_bits;
  }
  std::string problem =
      decodeReceivedGroundMap(msg.ground_map.data(), msg.ground_map.size(), &out.ground_map);
  // The same checks, order and downgrade as decodeDescriptor.
  if (problem.empty()) problem = acceptReceivedDescriptor(&out, params);
  if (!problem.empty()) return fail(error, problem);
  Pose T = Pose::Identity();
  std::string pose_error;
  if (!fromMsg(msg.odom_pose, &T, &pose_error)) return fail(error, "odom_pose: " + pose_error);
  if (!levelRotationFromMsg(msg.level_rotation, &out.level_rotation, &problem)) {
    return fail(error, "level_rotation: " + problem);
  }
  if (T_O_S) *T_O_S = T;
  *d = std::move(out);
  return true;
}

dtif::LoopClosure toMsg(const Loop& lc) {
  dtif::LoopClosure m;
  m.query_robot = lc.query_robot;
  m.query_id = lc.query_id;
  m.candidate_robot = lc.candidate_robot;
  m.candidate_id = lc.candidate_id;
  m.T_c_q = toMsg(lc.T_c_q);
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) m.covariance[6 * r + c] = lc.covariance(r, c);
  }
  m.inliers = lc.inliers;
  m.score = lc.score;
  m.inlier_query_trunks.reserve(lc.inlier_pairs.size());
  m.inlier_candidate_trunks.reserve(lc.inlier_pairs.size());
  for (const auto& p : lc.inlier_pairs) {
    m.inlier_query_trunks.push_back(p.first);
    m.inlier_candidate_trunks.push_back(p.second);
  }
  return m;
}

bool fromMsg(const dtif::LoopClosure& msg, Loop* lc, std::string* error) {
  Loop out;
  out.query_robot = msg.query_robot;
  out.query_id = msg.query_id;
  out.candidate_robot = msg.candidate_robot;
  out.candidate_id = msg.candidate_id;
  std::string pose_error;
  if (!fromMsg(msg.T_c_q, &out.T_c_q, &pose_error)) return fail(error, "T_c_q: " + pose_error);
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) {
      const double v = msg.covariance[6 * r + c];
      if (!std::isfinite(v)) return fail(error, "covariance is not finite");
      out.covariance(r, c) = v;
    }
  }
  if (!std::isfinite(msg.score)) return fail(error, "score is not finite");
  if (msg.inlier_query_trunks.size() != msg.inlier_candidate_trunks.size()) {
    return fail(error, "inlier index lists differ in length");
  }
  out.inliers = msg.inliers;
  out.score = msg.score;
  for (size_t i = 0; i < msg.inlier_query_trunks.size(); ++i) {
    out.inlier_pairs.emplace_back(msg.inlier_query_trunks[i], msg.inlier_candidate_trunks[i]);
  }
  *lc = std::move(out);
  return true;
}

namespace {

// Reads one coordinate of a point; datatype is FLOAT32 or FLOAT64 (checked by the caller).
double readCoord(const uint8_t* p, uint8_t datatype, bool bigendian) {
  uint8_t buf[8];
  const size_t n = datatype == sensor_msgs::PointField::FLOAT64 ? 8 : 4;
  std::memcpy(buf, p, n);
  if (bigendian) std::reverse(buf, buf + n);
  if (n == 8) {
    double d;
    std::memcpy(&d, buf, 8);
    return d;
  }
  float f;
  std::memcpy(&f, buf, 4);
  return f;
}

}  // namespace

bool fromMsg(const sensor_msgs::PointCloud2& msg, Cloud* cloud, size_t* dropped,
             std::string* error) {
  const sensor_msgs::PointField* fields[3] = {nullptr, nullptr, nullptr};
  for (const auto& f : msg.fields) {
    for (int i = 0; i < 3; ++i) {
      if (f.name == std::string(1, static_cast<char>('x' + i))) fields[i] = &f;
    }
  }
  for (int i = 0; i < 3; ++i) {
    if (!fields[i]) return fail(error, std::string("cloud has no field ") + char('x' + i));
    const uint8_t t = fields[i]->datatype;
    if (t != sensor_msgs::PointField::FLOAT32 && t != sensor_msgs::PointField::FLOAT64) {
      return fail(error, "cloud coordinates are neither float32 nor float64");
    }
    const size_t size = t == sensor_msgs::PointField::FLOAT64 ? 8 : 4;
    if (fields[i]->offset + size > msg.point_step) {
      return fail(error, "cloud field lies outside point_step");
    }
  }
  const size_t n = static_cast<size_t>(msg.width) * msg.height;
  if (msg.height > 0 && msg.row_step < static_cast<size_t>(msg.width) * msg.point_step) {
    return fail(error, "cloud row_step is smaller than width * point_step");
  }
  if (static_cast<size_t>(msg.row_step) * msg.height > msg.data.size()) {
    return fail(error, "cloud data is shorter than its header says");
  }
  cloud->clear();
  cloud->reserve(n);
  size_t bad = 0;
  for (size_t row = 0; row < msg.height; ++row) {
    const uint8_t* base = msg.data.data() + row * msg.row_step;
    for (size_t col = 0; col < msg.width; ++col) {
      const uint8_t* p = base + col * msg.point_step;
      const double x = readCoord(p + fields[0]->offset, fields[0]->datatype, msg.is_bigendian);
      const double y = readCoord(p + fields[1]->offset, fields[1]->datatype, msg.is_bigendian);
      const double z = readCoord(p + fields[2]->offset, fields[2]->datatype, msg.is_bigendian);
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
        ++bad;
        continue;
      }
      cloud->push_back(
          pcl::PointXYZ(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)));
    }
  }
  cloud->width = static_cast<uint32_t>(cloud->size());
  cloud->height = 1;
  cloud->is_dense = true;
  if (dropped) *dropped = bad;
  return true;
}

}  // namespace ros_glue
}  // namespace dtif
