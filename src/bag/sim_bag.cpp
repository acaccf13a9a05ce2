// Simulator frames -> rosbag (see sim_bag.h).
#include "dtif/bag/sim_bag.h"

#include <chrono>
#include <cmath>
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
  return e + writer.validate();
}

std::string odomFrame(const std::string& robot) { return robot + "/odom"; }
std::string bodyFrame(const std::string& robot) { return robot + "/base_link"; }

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

BagFrameSink::BagFrameSink(const std::string& path, const BagParams& params) : params_(params) {
  const std::string problems = params.validate();
  if (!problems.empty()) throw bag::RosbagError(path + ": invalid bag parameters:\n" + problems);
  writer_ = std::make_unique<bag::RosbagWriter>(path, params.writer);
}

BagFrameSink::~BagFrameSink() = default;

void cloudRegistered(const Frame& frame, const BagParams& params,
                     std::vector<Eigen::Vector3f>* points, std::vector<float>* intensity) {
  voxelFilter(frame.points, frame.intensity, params.voxel_m, points, intensity);
  thinEvenly(params.max_points, points, intensity);
}

void BagFrameSink::onFrame(const Frame& frame) {
  Timer timer(&stats_.write_seconds);
  const std::string ns = "/" + frame.robot;
  const bag::Time stamp = bag::Time::fromSec(frame.stamp);
  const std::string odom_frame = odomFrame(frame.robot);
  const std::string callerid = ns + "/" + params_.node;

  // FAST-LIO2 publishes Odometry first, then cloud_registered (laserMapping.cpp).
  bag::Odometry odom;
  odom.header.seq = seq_[ns + "/Odometry"]++;
  odom.header.stamp = stamp;
  odom.header.frame_id = odom_frame;
  odom.child_frame_id = bodyFrame(frame.robot);
  odom.T_frame_child = frame.T_O_B;
  std::string data;
  bag::serializeOdometry(odom, &data);
  writer_->write(ns + "/Odometry", bag::MessageType::kOdometry, stamp, data, callerid);

  bag::TransformStamped tf;
  tf.header = odom.header;
  tf.header.seq = 0;  // tf2_ros::TransformBroadcaster leaves it 0
  tf.child_frame_id = odom.child_frame_id;
  tf.T_frame_child = frame.T_O_B;
  data.clear();
  bag::serializeTfMessage({tf}, &data);
  writer_->write("/tf", bag::MessageType::kTfMessage, stamp, data, callerid);

  std::vector<Eigen::Vector3f> points;
  std::vector<float> intensity;
  cloudRegistered(frame, params_, &points, &intensity);
  bag::Header h;
  h.seq = seq_[ns + "/cloud_registered"]++;
  h.stamp = stamp;
  h.frame_id = odom_frame;
  data.clear();
  bag::serializePointCloud2(h, points, intensity, &data);
  writer_->write(ns + "/cloud_registered", bag::MessageType::kPointCloud2,
                 bag::Time::fromSec(frame.stamp + params_.cloud_delay_s), data, callerid);

  ++stats_.frames;
  stats_.points_in += frame.points.size();
  stats_.points_out += points.size();
  stats_.messages = writer_->messages();
  stats_.bytes = writer_->bytesWritten();
}

void BagFrameSink::close() {
  Timer timer(&stats_.write_seconds);
  writer_->close();
  stats_.bytes = writer_->bytesWritten();
}

}  // namespace dtif::sim
