#include "dtif/core/merge/slice_store.h"

#include <algorithm>
#include <cmath>

namespace dtif {

void SlicePointStore::addTrunks(int64_t id, const Trunks& trunks_S, const Eigen::Matrix3d& R_L_S) {
  sources_[id] = Source{trunks_S, R_L_S};
}

namespace {

// The stems of `known` in `component` whose base, in S, lies within the cloud's horizontal
// extent grown by `grow`, as trunks in S (base point, radius dbh / 2).
Trunks knownInCloud(const Cloud& cloud_S, const std::vector<MergedStem>& known, int component,
                    const Pose& T_M_S, double grow) {
  Trunks out;
  if (cloud_S.empty() || known.empty()) return out;
  Eigen::Vector2f lo = Eigen::Vector2f::Constant(INFINITY), hi = -lo;
  for (const pcl::PointXYZ& p : cloud_S) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) continue;
    lo = lo.cwiseMin(Eigen::Vector2f(p.x, p.y));
    hi = hi.cwiseMax(Eigen::Vector2f(p.x, p.y));
  }
  const Pose T_S_M = T_M_S.inverse();
  for (const MergedStem& s : known) {
    if (s.component != component) continue;
    const Eigen::Vector3d b = T_S_M * Eigen::Vector3d(s.x, s.y, s.z_base);
    if (b.x() < lo.x() - grow || b.x() > hi.x() + grow || b.y() < lo.y() - grow ||
        b.y() > hi.y() + grow)
      continue;
    TrunkLandmark t;
    t.x = b.x(), t.y = b.y(), t.z = b.z(), t.r = 0.5 * s.dbh;
    out.push_back(t);
  }
  return out;
}

}  // namespace

bool SlicePointStore::addCloud(int64_t id, const Cloud& cloud_S,
                               const std::vector<MergedStem>& known, int component,
                               const Pose& T_M_S) {
  auto src = sources_.find(id);
  if (src == sources_.end()) return false;
  Trunks trunks = src->second.trunks_S;
  const Trunks more = knownInCloud(cloud_S, known, component, T_M_S, 1.0);
  trunks.insert(trunks.end(), more.begin(), more.end());
  drop(id);
  Cloud::ConstPtr kept = keepSliceCandidates(cloud_S, trunks, src->second.R_L_S, p_);
  points_ += kept->size();
  clouds_[id] = std::move(kept);
  return true;
}

void SlicePointStore::drop(int64_t id) {
  if (auto it = clouds_.find(id); it != clouds_.end()) {
    points_ -= it->second->size();
    clouds_.erase(it);
  }
  if (auto it = held_.find(id); it != held_.end()) {
    points_ -= it->second.cloud->size();
    held_.erase(it);
  }
}

bool SlicePointStore::holdCloud(int64_t id, const Cloud& cloud_S) {
  auto src = sources_.find(id);
  if (src == sources_.end()) return false;
  drop(id);
  Cloud::ConstPtr band = keepSliceBand(cloud_S, src->second.R_L_S, p_);
  points_ += band->size();
  held_[id] = Held{std::move(band), holds_++};
  return true;
}

std::vector<int64_t> SlicePointStore::overdue() const {
  const size_t window = static_cast<size_t>(std::max(p_.slice_defer_clouds, 0));
  std::vector<std::pair<size_t, int64_t>> due;  // (arrival, id)
  for (const auto& [id, h] : held_) {
    if (h.arrival + window < holds_) due.emplace_back(h.arrival, id);
  }
  std::sort(due.begin(), due.end());
  std::vector<int64_t> out;
  for (const auto& [arrival, id] : due) out.push_back(id);
  return out;
}

bool SlicePointStore::settle(int64_t id, const std::vector<MergedStem>& known, int component,
                             const Pose& T_M_S) {
  auto it = held_.find(id);
  if (it == held_.end()) return false;
  const Cloud::ConstPtr band = it->second.cloud;  // addCloud drops it from held_
  addCloud(id, *band, known, component, T_M_S);
  return true;
}

std::vector<MergedStem> SlicePointStore::refit(const std::vector<MergedStem>& stems,
                                               const std::vector<MergedPose>& poses,
                                               StemSliceStats* stats) const {
  StemSlices slices(stems, p_);
  // In the merger's submap order (refitStemDbh: the dataset's order).
  for (const MergedPose& pose : poses) {
    if (auto it = clouds_.find(pose.id); it != clouds_.end()) {
      slices.addSubmap(pose.component, pose.T_M_S, *it->second);
    } else if (auto h = held_.find(pose.id); h != held_.end()) {
      slices.addSubmap(pose.component, pose.T_M_S, *h->second.cloud);
    }
  }
  return slices.refit(stats);
}

size_t SlicePointStore::bytes() const {
  size_t b = points_ * sizeof(pcl::PointXYZ);
  for (const auto& [id, s] : sources_)
    b += sizeof(Source) + s.trunks_S.size() * sizeof(TrunkLandmark);
  return b;
}

}  // namespace dtif
