// Simulator frames -> rosbag (see sim_bag.h), with rosbag_storage and the generated messages.
#include "dtif/bag/sim_bag.h"

#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_msgs/TFMessage.h>

#include <Eigen/Geometry>
#include <boost/make_shared.hpp>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <unordered_map>

namespace dtif::sim {
namespace {

struct VoxelKey {
  int64_t x, y, z;
  bool operator==(const VoxelKey& o) const { return x == o.x && y == o.y && z == o.z; }
};
struct VoxelKeyHash {
  size_t operator()(const VoxelKey& k) const {
    return static_cast<size_t>((static_cast<uint64_t>(k.x) * 73856093u) ^
                               (static_cast<uint64_t>(k.y) * 19349663u) ^
                               (static_cast<uint64_t>(k.z) * 83492791u));
  }
};

class Timer {
 public:
  explicit Timer(double* total) : total_(total), start_(std::chrono::steady_clock::now()) {}
  ~Timer() {
    *total_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  double* total_;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace

std::string BagParams::validate() const {
  std::string e;
  if (!std::isfinite(voxel_m) || voxel_m < 0.0) e += "voxel_m must be >= 0\n";
  if (!std::isfinite(cloud_delay_s) || cloud_delay_s < 0.0 || cloud_delay_s > 1.0) {
    e += "cloud_delay_s must be in [0, 1]\n";
  }
  if (node.empty() || node.find('/') != std::string::npos) e += "node must be a plain name\n";
  if (chunk_bytes == 0 || chunk_bytes > (1u << 30)) e += "chunk_bytes must be in (0, 1 GiB]\n";
  if (compression != "none" && compression != "lz4") e += "compression must be none or lz4\n";
  if (layout != kLayoutNamespaced && layout != kLayoutFastlio) {
    e += "layout must be " + std::string(kLayoutNamespaced) + " or " + kLayoutFastlio + "\n";
  }
  return e;
}

std::string odomFrame(const std::string& robot) { return robot + "/odom"; }
std::string bodyFrame(const std::string& robot) { return robot + "/base_link"; }

std::string unitBagPath(const std::string& path, const std::string& robot) {
  std::filesystem::path p(path);
  const std::string stem = p.extension() == ".bag" ? p.stem().string() : p.filename().string();
  return (p.parent_path() / (stem + "_" + robot + ".bag")).string();
}

void voxelFilter(const std::vector<Eigen::Vector3f>& points, const std::vector<float>& intensity,
                 double voxel_m, std::vector<Eigen::Vector3f>* points_out,
                 std::vector<float>* intensity_out) {
  const bool with_intensity = intensity.size() == points.size();
  points_out->clear();
  intensity_out->clear();
  if (voxel_m <= 0.0) {  // copy the finite points (PointCloud2 says is_dense)
    points_out->reserve(points.size());
    intensity_out->reserve(points.size());
    for (size_t i = 0; i < points.size(); ++i) {
      if (!points[i].allFinite()) continue;
      points_out->push_back(points[i]);
      intensity_out->push_back(with_intensity ? intensity[i] : 0.0f);
    }
    return;
  }
  // Sums relative to the voxel's first point keep float precision far from the origin.
  struct Cell {
    Eigen::Vector3f first, sum{0, 0, 0};
    float intensity = 0.0f;
    uint32_t n = 0;
  };
  std::vector<Cell> cells;
  std::unordered_map<VoxelKey, uint32_t, VoxelKeyHash> index;
  index.reserve(points.size());
  const double inv = 1.0 / voxel_m;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    if (!p.allFinite()) continue;
    const VoxelKey key{static_cast<int64_t>(std::floor(p.x() * inv)),
                       static_cast<int64_t>(std::floor(p.y() * inv)),
                       static_cast<int64_t>(std::floor(p.z() * inv))};
    const auto [it, added] = index.emplace(key, static_cast<uint32_t>(cells.size()));
    if (added) cells.push_back(Cell{p});
    Cell& c = cells[it->second];
    c.sum += p - c.first;
    c.intensity += with_intensity ? intensity[i] : 0.0f;
    ++c.n;
  }
  points_out->reserve(cells.size());
  intensity_out->reserve(cells.size());
  for (const Cell& c : cells) {
    const float inv_n = 1.0f / static_cast<float>(c.n);
    points_out->push_back(c.first + c.sum * inv_n);
    intensity_out->push_back(c.intensity * inv_n);
  }
}

void thinEvenly(uint32_t max_points, std::vector<Eigen::Vector3f>* points,
                std::vector<float>* intensity) {
  const size_t n = points->size();
  if (max_points == 0 || n <= max_points) return;
  const bool with_intensity = intensity->size() == n;
  for (size_t i = 0; i < max_points; ++i) {
    const size_t k = i * n / max_points;  // >= i: in-place is safe
    (*points)[i] = (*points)[k];
    if (with_intensity) (*intensity)[i] = (*intensity)[k];
  }
  points->resize(max_points);
  if (with_intensity) intensity->resize(max_points);
}

void cloudRegistered(const Frame& frame, const BagParams& params,
                     std::vector<Eigen::Vector3f>* points, std::vector<float>* intensity) {
  voxelFilter(frame.points, frame.intensity, params.voxel_m, points, intensity);
  thinEvenly(params.max_points, points, intensity);
}

// ---------------------------------------------------------------------------------------------

namespace {

// The connection header rosbag record stores: the publisher's, as received. One per robot and
// topic, so each robot's /tf is a connection of its own, in time order.
template <class Msg>
boost::shared_ptr<ros::M_string> connectionHeader(const std::string& topic,
                                                  const std::string& callerid) {
  auto h = boost::make_shared<ros::M_string>();
  (*h)["callerid"] = callerid;
  (*h)["latching"] = "0";
  (*h)["md5sum"] = ros::message_traits::MD5Sum<Msg>::value();
  (*h)["message_definition"] = ros::message_traits::Definition<Msg>::value();
  (*h)["topic"] = topic;
  (*h)["type"] = ros::message_traits::DataType<Msg>::value();
  return h;
}

// geometry_msgs/Pose and geometry_msgs/Transform carry the same numbers.
template <class Vector, class Quaternion>
void setPose(const Pose& T, Vector* t, Quaternion* q) {
  const Eigen::Quaterniond e(T.rotation());
  t->x = T.translation().x();
  t->y = T.translation().y();
  t->z = T.translation().z();
  q->x = e.x();
  q->y = e.y();
  q->z = e.z();
  q->w = e.w();
}

// Unorganised (height 1), fields x, y, z, intensity (float32, offsets 0, 4, 8, 12; point_step
// 16), little-endian, is_dense; intensity zero unless there is one per point.
void fillPointCloud2(const std::vector<Eigen::Vector3f>& points,
                     const std::vector<float>& intensity, sensor_msgs::PointCloud2* msg) {
  static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "is_bigendian is written false");
  constexpr uint32_t kPointStep = 16;
  const auto n = static_cast<uint32_t>(points.size());
  const bool with_intensity = intensity.size() == points.size();
  msg->height = 1;
  msg->width = n;
  const char* names[] = {"x", "y", "z", "intensity"};
  msg->fields.resize(4);
  for (uint32_t i = 0; i < 4; ++i) {
    msg->fields[i].name = names[i];
    msg->fields[i].offset = 4 * i;
    msg->fields[i].datatype = sensor_msgs::PointField::FLOAT32;
    msg->fields[i].count = 1;
  }
  msg->is_bigendian = false;
  msg->point_step = kPointStep;
  msg->row_step = kPointStep * n;
  msg->data.resize(size_t{kPointStep} * n);
  for (uint32_t i = 0; i < n; ++i) {
    const float v[4] = {points[i].x(), points[i].y(), points[i].z(),
                        with_intensity ? intensity[i] : 0.0f};
    std::memcpy(&msg->data[size_t{kPointStep} * i], v, sizeof(v));
  }
  msg->is_dense = true;
}

// The MID-360's IMU between two frames, as its driver publishes it (/livox/imu, frame
// livox_frame, 200 Hz, acceleration in g): the true specific force R_B_W (a_W + g z) and angular
// rate of the body, attitude slerped between the frames, a_W from the last three frames'
// positions (constant over the interval). FAST-LIO2's body is the IMU frame.
std::vector<sensor_msgs::Imu> imuBetween(const std::vector<std::pair<double, Pose>>& last,
                                         double t1, const Pose& T_W_B1) {
  std::vector<sensor_msgs::Imu> out;
  if (last.empty()) return out;
  const auto& [t0, T0] = last.back();
  const double dt = t1 - t0;
  if (!(dt > 0.0)) return out;
  Eigen::Vector3d a_W = Eigen::Vector3d::Zero();
  if (last.size() == 2) {
    const auto& [tm, Tm] = last.front();
    const Eigen::Vector3d v0 = (T0.translation() - Tm.translation()) / (t0 - tm);
    const Eigen::Vector3d v1 = (T_W_B1.translation() - T0.translation()) / dt;
    a_W = (v1 - v0) / (0.5 * (t1 - tm));
  }
  const Eigen::Quaterniond q0(T0.rotation()), q1(T_W_B1.rotation());
  const Eigen::AngleAxisd turn(q0.conjugate() * q1);
  const Eigen::Vector3d gyro_B = turn.axis() * turn.angle() / dt;
  constexpr double kG = 9.81, kRateHz = 200.0;
  const int n = std::max(1, static_cast<int>(std::lround(dt * kRateHz)));
  for (int i = 1; i <= n; ++i) {
    const double f = static_cast<double>(i) / n;
    const Eigen::Quaterniond q = q0.slerp(f, q1);
    const Eigen::Vector3d f_B = q.conjugate() * (a_W + kG * Eigen::Vector3d::UnitZ()) / kG;
    sensor_msgs::Imu m;
    m.header.stamp = ros::Time().fromSec(t0 + f * dt);
    m.header.frame_id = "livox_frame";
    m.orientation_covariance[0] = -1.0;  // no orientation, as the Livox driver
    m.linear_acceleration.x = f_B.x();
    m.linear_acceleration.y = f_B.y();
    m.linear_acceleration.z = f_B.z();
    m.angular_velocity.x = gyro_B.x();
    m.angular_velocity.y = gyro_B.y();
    m.angular_velocity.z = gyro_B.z();
    out.push_back(m);
  }
  return out;
}

}  // namespace

struct BagFrameSink::Writer {
  // One output file: written as tmp_path, renamed to path by close().
  struct File {
    std::string path, tmp_path;
    rosbag::Bag bag;
    bool open = false;  // until close()
  };
  struct Robot {  // its topics' connection headers, sequence numbers and file
    boost::shared_ptr<ros::M_string> odometry, tf, cloud, imu;
    uint32_t odometry_seq = 0, cloud_seq = 0, imu_seq = 0;
    std::vector<std::pair<double, Pose>> last_frames;  // (stamp, T_W_B) of the last two frames
    std::string odom_frame, body_frame;
    File* file = nullptr;
  };

  std::string path;  // as given: the bag, or the name the per-unit bags derive from
  BagParams params;
  bool open = false;                                   // until close()
  std::map<std::string, std::unique_ptr<File>> files;  // by robot; "" in the namespaced layout
  std::map<std::string, Robot> robots;

  ~Writer() {
    for (auto& [name, f] : files) {
      if (!f->open) continue;
      try {  // abandoned (not closed): finish the file only to remove it
        f->bag.close();
      } catch (const std::exception&) {
      }
      std::error_code ec;
      std::filesystem::remove(f->tmp_path, ec);
    }
  }

  bool fastlio() const { return params.layout == kLayoutFastlio; }

  // Creates `file_path`.tmp; throws RosbagError naming it.
  File* create(const std::string& key, const std::string& file_path) {
    auto f = std::make_unique<File>();
    f->path = file_path;
    f->tmp_path = file_path + ".tmp";
    try {
      f->bag.open(f->tmp_path, rosbag::bagmode::Write);
    } catch (const rosbag::BagException& e) {
      throw bag::RosbagError(f->tmp_path + ": cannot create: " + e.what());
    }
    f->open = true;
    f->bag.setChunkThreshold(params.chunk_bytes);
    f->bag.setCompression(params.compression == "lz4" ? rosbag::compression::LZ4
                                                      : rosbag::compression::Uncompressed);
    return (files[key] = std::move(f)).get();
  }

  // t [s] as ros::Time (as ros::Time::fromSec); throws RosbagError naming the file outside it.
  static ros::Time time(double t, const File& f) {
    if (!std::isfinite(t) || t < 0.0 || t >= 4294967295.0) {
      throw bag::RosbagError(f.tmp_path + ": time " + std::to_string(t) +
                             " s is outside the range of ros::Time");
    }
    return ros::Time().fromSec(t);
  }

  // A robot's names: /<robot>/... in the shared bag, or a stock unit's in a bag of its own
  // (FAST-LIO2's laserMapping node: absolute /Odometry, /cloud_registered; camera_init, body).
  Robot& robot(const std::string& name) {
    const auto [it, added] = robots.try_emplace(name);
    Robot& r = it->second;
    if (!added) return r;
    const std::string ns = fastlio() ? "" : "/" + name;
    const std::string callerid = fastlio() ? "/laserMapping" : ns + "/" + params.node;
    r.odometry = connectionHeader<nav_msgs::Odometry>(ns + "/Odometry", callerid);
    r.tf = connectionHeader<tf2_msgs::TFMessage>("/tf", callerid);
    r.cloud = connectionHeader<sensor_msgs::PointCloud2>(ns + "/cloud_registered", callerid);
    if (fastlio())
      r.imu = connectionHeader<sensor_msgs::Imu>("/livox/imu", "/livox_lidar_publisher");
    r.odom_frame = fastlio() ? "camera_init" : odomFrame(name);
    r.body_frame = fastlio() ? "body" : bodyFrame(name);
    r.file = fastlio() ? create(name, unitBagPath(path, name)) : files.at("").get();
    return r;
  }

  template <class Msg>
  static void write(File& f, const boost::shared_ptr<ros::M_string>& connection, ros::Time t,
                    const Msg& msg) {
    try {
      f.bag.write(connection->at("topic"), t, msg, connection);
    } catch (const rosbag::BagException& e) {
      throw bag::RosbagError(f.tmp_path + ": cannot write: " + e.what());
    }
  }

  uint64_t bytes() const {
    uint64_t n = 0;
    for (const auto& [name, f] : files) n += f->bag.getSize();
    return n;
  }
};

BagFrameSink::BagFrameSink(const std::string& path, const BagParams& params)
    : params_(params), writer_(std::make_unique<Writer>()) {
  const std::string problems = params.validate();
  if (!problems.empty()) throw bag::RosbagError(path + ": invalid bag parameters:\n" + problems);
  writer_->path = path;
  writer_->params = params;
  writer_->open = true;
  // The per-unit bags are created with their robot's first frame.
  if (!writer_->fastlio()) writer_->create("", path);
}

BagFrameSink::~BagFrameSink() = default;

std::vector<std::string> BagFrameSink::paths() const {
  std::vector<std::string> out;
  for (const auto& [name, f] : writer_->files) out.push_back(f->path);
  return out;
}

void BagFrameSink::onFrame(const Frame& frame) {
  Timer timer(&stats_.write_seconds);
  Writer& w = *writer_;
  if (!w.open) throw bag::RosbagError(w.path + ": write after close");
  Writer::Robot& robot = w.robot(frame.robot);
  Writer::File& file = *robot.file;
  const ros::Time stamp = Writer::time(frame.stamp, file);
  const ros::Time cloud_time = Writer::time(frame.stamp + params_.cloud_delay_s, file);

  if (robot.imu) {  // a stock unit's bag records its IMU too
    for (sensor_msgs::Imu& m : imuBetween(robot.last_frames, frame.stamp, frame.T_W_B)) {
      m.header.seq = robot.imu_seq++;
      Writer::write(file, robot.imu, m.header.stamp, m);
      ++stats_.messages;
    }
    robot.last_frames.emplace_back(frame.stamp, frame.T_W_B);
    if (robot.last_frames.size() > 2) robot.last_frames.erase(robot.last_frames.begin());
  }

  // FAST-LIO2 publishes Odometry first, then cloud_registered (laserMapping.cpp); twist and
  // covariances stay zero, as FAST-LIO2 leaves them.
  nav_msgs::Odometry odom;
  odom.header.seq = robot.odometry_seq++;
  odom.header.stamp = stamp;
  odom.header.frame_id = robot.odom_frame;
  odom.child_frame_id = robot.body_frame;
  setPose(frame.T_O_B, &odom.pose.pose.position, &odom.pose.pose.orientation);
  Writer::write(file, robot.odometry, stamp, odom);

  tf2_msgs::TFMessage tf;
  tf.transforms.resize(1);
  geometry_msgs::TransformStamped& t = tf.transforms[0];
  t.header = odom.header;
  t.header.seq = 0;  // tf2_ros::TransformBroadcaster leaves it 0
  t.child_frame_id = odom.child_frame_id;
  setPose(frame.T_O_B, &t.transform.translation, &t.transform.rotation);
  Writer::write(file, robot.tf, stamp, tf);

  std::vector<Eigen::Vector3f> points;
  std::vector<float> intensity;
  cloudRegistered(frame, params_, &points, &intensity);
  sensor_msgs::PointCloud2 cloud;
  cloud.header.seq = robot.cloud_seq++;
  cloud.header.stamp = stamp;
  cloud.header.frame_id = odom.header.frame_id;
  fillPointCloud2(points, intensity, &cloud);
  Writer::write(file, robot.cloud, cloud_time, cloud);

  ++stats_.frames;
  stats_.messages += 3;
  stats_.points_in += frame.points.size();
  stats_.points_out += points.size();
  stats_.bytes = w.bytes();
}

void BagFrameSink::close() {
  Timer timer(&stats_.write_seconds);
  Writer& w = *writer_;
  if (!w.open) throw bag::RosbagError(w.path + ": already closed");
  w.open = false;
  stats_.bytes = 0;
  // Each file finished and renamed in turn; on an error the files not yet renamed are removed
  // (the Writer's destructor), so no bag is left half-written.
  for (auto& [name, f] : w.files) {
    std::error_code ec;
    f->open = false;
    try {
      f->bag.close();
    } catch (const rosbag::BagException& e) {
      std::filesystem::remove(f->tmp_path, ec);
      throw bag::RosbagError(f->tmp_path + ": cannot write: " + e.what());
    }
    stats_.bytes += std::filesystem::file_size(f->tmp_path, ec);
    std::filesystem::rename(f->tmp_path, f->path, ec);
    if (ec) {
      const std::string what = ec.message();
      std::filesystem::remove(f->tmp_path, ec);
      throw bag::RosbagError(f->path + ": cannot rename " + f->tmp_path + " to it: " + what);
    }
  }
}

}  // namespace dtif::sim
