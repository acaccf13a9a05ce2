#include "dtif/ros/submap_assembler.h"

#include <cmath>
#include <sstream>

namespace dtif {
namespace ros_glue {

std::string SubmapAssemblerParams::validate() const {
  std::ostringstream os;
  if (!(window_s > 0.0)) os << "window_s must be > 0\n";
  if (!(max_odom_gap_s > 0.0)) os << "max_odom_gap_s must be > 0\n";
  if (!(max_odom_age_s >= 0.0)) os << "max_odom_age_s must be >= 0\n";
  if (max_submap_points <= 0) os << "max_submap_points must be > 0\n";
  return os.str();
}

Pose gravityAlignedPose(const Pose& T_O_B) {
  const Eigen::Matrix3d R = T_O_B.rotation();
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  Pose T_O_S = Pose::Identity();
  T_O_S.linear() = rotZ(yaw);
  T_O_S.translation() = T_O_B.translation();
  return T_O_S;
}

SubmapAssembler::SubmapAssembler(const SubmapAssemblerParams& params, int64_t first_id)
    : params_(params), next_id_(first_id) {}

const char* SubmapAssembler::describe(Status s) {
  switch (s) {
    case Status::kOk:
      return "ok";
    case Status::kDuplicateStamp:
      return "duplicate stamp, message dropped";
    case Status::kOutOfOrder:
      return "stamp older than the previous message, message dropped";
    case Status::kNoOdometry:
      return "no odometry near the cloud's stamp, cloud dropped";
    case Status::kOdometryGap:
      return "odometry gap, open submap discarded";
    case Status::kEmptyCloud:
      return "empty cloud";
    case Status::kTruncated:
      return "submap point limit reached, points dropped";
  }
  return "?";
}

SubmapAssembler::Status SubmapAssembler::addOdometry(double stamp, const Pose& T_O_B) {
  if (!odom_.empty()) {
    const double last = odom_.back().stamp;
    if (stamp == last) return Status::kDuplicateStamp;
    if (stamp < last) return Status::kOutOfOrder;
  }
  Status status = Status::kOk;
  if (!odom_.empty() && stamp - odom_.back().stamp > params_.max_odom_gap_s) {
    // The front end may have re-initialised (a new O): do not mix points across the gap.
    if (open_) status = Status::kOdometryGap;
    open_.reset();
    odom_.clear();
  }
  odom_.push_back({stamp, T_O_B});
  // Keep a few seconds: anchors are looked up near the newest clouds only.
  while (odom_.size() > 2 && odom_.front().stamp < stamp - 5.0) odom_.pop_front();
  return status;
}

std::optional<Pose> SubmapAssembler::poseAt(double stamp) const {
  if (odom_.empty()) return std::nullopt;
  const double tol = params_.max_odom_age_s;
  if (stamp >= odom_.back().stamp) {
    if (stamp - odom_.back().stamp <= tol) return odom_.back().T_O_B;
    return std::nullopt;
  }
  if (stamp <= odom_.front().stamp) {
    if (odom_.front().stamp - stamp <= tol) return odom_.front().T_O_B;
    return std::nullopt;
  }
  for (size_t i = 1; i < odom_.size(); ++i) {
    if (odom_[i].stamp < stamp) continue;
    const Stamped& a = odom_[i - 1];
    const Stamped& b = odom_[i];
    if (b.stamp - a.stamp > params_.max_odom_gap_s) return std::nullopt;
    const double s = (stamp - a.stamp) / (b.stamp - a.stamp);
    Pose T = Pose::Identity();
    const Eigen::Quaterniond qa(a.T_O_B.rotation()), qb(b.T_O_B.rotation());
    T.linear() = qa.slerp(s, qb).toRotationMatrix();
    T.translation() = (1.0 - s) * a.T_O_B.translation() + s * b.T_O_B.translation();
    return T;
  }
  return std::nullopt;
}

bool SubmapAssembler::startWindow(double stamp) {
  const std::optional<Pose> T_O_B = poseAt(stamp);
  if (!T_O_B) return false;
  AssembledSubmap s;
  s.id = next_id_++;
  s.stamp = stamp;
  s.T_O_S = gravityAlignedPose(*T_O_B);
  s.cloud.reset(new Cloud);
  T_S_O_ = s.T_O_S.inverse();
  open_ = std::move(s);
  return true;
}

SubmapAssembler::Status SubmapAssembler::addCloud(double stamp, const Cloud& cloud_O,
                                                  std::optional<AssembledSubmap>* done) {
  done->reset();
  if (last_cloud_stamp_ >= 0.0) {
    if (stamp == last_cloud_stamp_) return Status::kDuplicateStamp;
    if (stamp < last_cloud_stamp_) return Status::kOutOfOrder;
  }
  last_cloud_stamp_ = stamp;
  if (cloud_O.empty()) return Status::kEmptyCloud;
  if (open_ && stamp - open_->stamp >= params_.window_s) {
    *done = std::move(open_);
    open_.reset();
  }
  if (!open_ && !startWindow(stamp)) return Status::kNoOdometry;
  Cloud& out = *open_->cloud;
  const Eigen::Affine3f T_S_O = T_S_O_.cast<float>();
  Status status = Status::kOk;
  for (const auto& p : cloud_O) {
    if (out.size() >= static_cast<size_t>(params_.max_submap_points)) {
      status = Status::kTruncated;
      break;
    }
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
    const Eigen::Vector3f q = T_S_O * p.getVector3fMap();
    out.push_back(pcl::PointXYZ(q.x(), q.y(), q.z()));
  }
  return status;
}

std::optional<AssembledSubmap> SubmapAssembler::flush() {
  std::optional<AssembledSubmap> out = std::move(open_);
  open_.reset();
  if (out && out->cloud->empty()) return std::nullopt;
  return out;
}

void SubmapAssembler::reset() {
  open_.reset();
  odom_.clear();
  last_cloud_stamp_ = -1.0;
}

}  // namespace ros_glue
}  // namespace dtif
