#include "dtif/ros/submap_assembler.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace dtif {
namespace ros_glue {

std::string SubmapAssemblerParams::validate() const {
  std::ostringstream os;
  if (!(window_s > 0.0)) os << "window_s must be > 0\n";
  if (!(cloud_period_s > 0.0 && cloud_period_s < window_s)) {
    os << "cloud_period_s must be > 0 and < window_s\n";
  }
  if (!(max_odom_gap_s > 0.0)) os << "max_odom_gap_s must be > 0\n";
  if (!(max_odom_age_s >= 0.0)) os << "max_odom_age_s must be >= 0\n";
  if (max_submap_points <= 0) os << "max_submap_points must be > 0\n";
  if (!(std::isfinite(voxel_m) && voxel_m >= 0.0)) os << "voxel_m must be >= 0\n";
  if (!(clock_jump_s > 0.0 && std::isfinite(clock_jump_s))) os << "clock_jump_s must be > 0\n";
  return os.str();
}

void voxelFilterSubmap(VoxelCentroidSorter* voxels, Cloud* cloud_S) { voxels->filter(cloud_S); }

Pose gravityAlignedPose(const Pose& T_O_B) {
  const Eigen::Matrix3d R = T_O_B.rotation();
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  Pose T_O_S = Pose::Identity();
  T_O_S.linear() = rotZ(yaw);
  T_O_S.translation() = T_O_B.translation();
  return T_O_S;
}

SubmapAssembler::SubmapAssembler(const SubmapAssemblerParams& params, int64_t first_id)
    : params_(params), next_id_(first_id), voxels_(params.voxel_m > 0.0 ? params.voxel_m : 1.0) {}

const char* SubmapAssembler::describe(Status s) {
  switch (s) {
    case Status::kOk:
      return "ok";
    case Status::kDuplicateStamp:
      return "duplicate stamp, message dropped";
    case Status::kOutOfOrder:
      return "stamp older than the previous message, message dropped";
    case Status::kNoAnchorPose:
      return "no odometry at the finished window's centre, submap discarded";
    case Status::kOdometryGap:
      return "odometry gap, open submap discarded";
    case Status::kEmptyCloud:
      return "empty cloud";
    case Status::kTruncated:
      return "submap point limit reached, points dropped";
    case Status::kClockJump:
      return "stamp jumped back by more than clock_jump_s (bag replayed, or a future stamp "
             "before): resynchronised, open submap discarded";
  }
  return "?";
}

SubmapAssembler::Status SubmapAssembler::addOdometry(double stamp, const Pose& T_O_B) {
  if (!std::isfinite(stamp)) return Status::kOutOfOrder;
  Status status = Status::kOk;
  if (!odom_.empty()) {
    const double last = odom_.back().stamp;
    if (stamp == last) return Status::kDuplicateStamp;
    if (stamp < last - params_.clock_jump_s) {
      // One future stamp must not silence the stream for good: start the history afresh.
      odom_.clear();
      status = Status::kClockJump;
    } else if (stamp < last) {
      return Status::kOutOfOrder;
    }
  }
  if (!odom_.empty() && stamp - odom_.back().stamp > params_.max_odom_gap_s) {
    // The front end may have re-initialised (a new O): do not mix points across the gap, and
    // partition the new stream afresh.
    if (open_) status = Status::kOdometryGap;
    open_.reset();
    odom_.clear();
    t0_.reset();
  }
  odom_.push_back({stamp, T_O_B});
  // Keep what the open window's anchor (its centre) and clouds a few seconds late may need.
  double keep_from = stamp - params_.window_s - 5.0;
  if (open_) keep_from = std::min(keep_from, centreOf(open_->index) - 1.0);
  while (odom_.size() > 2 && odom_.front().stamp < keep_from) odom_.pop_front();
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
  const auto it = std::lower_bound(odom_.begin(), odom_.end(), stamp,
                                   [](const Stamped& o, double t) { return o.stamp < t; });
  const Stamped& a = *std::prev(it);
  const Stamped& b = *it;
  if (b.stamp - a.stamp > params_.max_odom_gap_s) return std::nullopt;
  const double s = (stamp - a.stamp) / (b.stamp - a.stamp);
  Pose T = Pose::Identity();
  const Eigen::Quaterniond qa(a.T_O_B.rotation()), qb(b.T_O_B.rotation());
  T.linear() = qa.slerp(s, qb).toRotationMatrix();
  T.translation() = (1.0 - s) * a.T_O_B.translation() + s * b.T_O_B.translation();
  return T;
}

int64_t SubmapAssembler::windowOf(double stamp) const {
  // Window k holds the stamps in (t0 + k * window_s, t0 + (k + 1) * window_s].
  return static_cast<int64_t>(std::ceil((stamp - *t0_ - kStampTolS) / params_.window_s)) - 1;
}

double SubmapAssembler::centreOf(int64_t window) const {
  return *t0_ + (static_cast<double>(window) + 0.5) * params_.window_s;
}

std::optional<AssembledSubmap> SubmapAssembler::close() {
  Window w = std::move(*open_);
  open_.reset();
  const double centre = centreOf(w.index);
  const std::optional<Pose> T_O_B = poseAt(centre);
  if (!T_O_B) return std::nullopt;
  AssembledSubmap s;
  s.id = next_id_++;
  s.stamp = centre;
  s.end_stamp = w.end_stamp;
  s.T_O_S = gravityAlignedPose(*T_O_B);
  s.cloud.reset(new Cloud);
  // In double, as the simulator transforms its returns into S before its voxel filter.
  const Pose T_S_O = s.T_O_S.inverse();
  s.cloud->reserve(w.cloud_O->size());
  for (const auto& p : *w.cloud_O) {
    const Eigen::Vector3f q = (T_S_O * p.getVector3fMap().cast<double>()).cast<float>();
    s.cloud->push_back(pcl::PointXYZ(q.x(), q.y(), q.z()));
  }
  if (params_.voxel_m > 0.0) voxelFilterSubmap(&voxels_, s.cloud.get());
  return s;
}

SubmapAssembler::Status SubmapAssembler::addCloud(double stamp, const Cloud& cloud_O,
                                                  std::optional<AssembledSubmap>* done) {
  done->reset();
  if (!std::isfinite(stamp)) return Status::kOutOfOrder;
  Status status = Status::kOk;
  if (last_cloud_stamp_ >= 0.0) {
    if (stamp == last_cloud_stamp_) return Status::kDuplicateStamp;
    if (stamp < last_cloud_stamp_ - params_.clock_jump_s) {
      // A bag replayed again, or the last cloud was stamped in the future: the windows start
      // afresh from this cloud (the odometry resynchronises itself the same way).
      open_.reset();
      t0_.reset();
      status = Status::kClockJump;
    } else if (stamp < last_cloud_stamp_) {
      return Status::kOutOfOrder;
    }
  }
  last_cloud_stamp_ = stamp;
  if (cloud_O.empty()) return Status::kEmptyCloud;
  // The points are in O already: only the window's centre needs a pose, so a cloud that
  // arrives before its odometry (another connection; a fast replay) is kept.
  if (!t0_) t0_ = stamp - params_.cloud_period_s;
  const int64_t k = windowOf(stamp);
  if (open_ && open_->index != k) {
    // The open window's last cloud never came: finish it with what it has.
    *done = close();
    if (!*done) status = Status::kNoAnchorPose;
  }
  if (!open_) open_ = Window{k, stamp, Cloud::Ptr(new Cloud)};
  Cloud& out = *open_->cloud_O;
  for (const auto& p : cloud_O) {
    if (out.size() >= static_cast<size_t>(params_.max_submap_points)) {
      status = Status::kTruncated;
      break;
    }
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
    out.push_back(p);
  }
  open_->end_stamp = stamp;
  // The window's last cloud finishes it at once (unless this call already returns a submap).
  if (!*done && stamp >= *t0_ + static_cast<double>(k + 1) * params_.window_s - kStampTolS) {
    *done = close();
    if (!*done) status = Status::kNoAnchorPose;
  }
  return status;
}

std::optional<AssembledSubmap> SubmapAssembler::flush() {
  if (!open_ || open_->cloud_O->empty()) {
    open_.reset();
    return std::nullopt;
  }
  return close();
}

void SubmapAssembler::reset() {
  open_.reset();
  odom_.clear();
  t0_.reset();
  last_cloud_stamp_ = -1.0;
}

}  // namespace ros_glue
}  // namespace dtif
