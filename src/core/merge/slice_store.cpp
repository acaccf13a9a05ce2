#include "dtif/core/merge/slice_store.h"

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
  Cloud::ConstPtr kept = keepSliceCandidates(cloud_S, trunks, src->second.R_L_S, p_);
  Cloud::ConstPtr& slot = clouds_[id];
  if (slot) points_ -= slot->size();
  points_ += kept->size();
  slot = kept;
  return true;
}

std::vector<MergedStem> SlicePointStore::refit(const std::vector<MergedStem>& stems,
                                               const std::vector<MergedPose>& poses,
                                               StemSliceStats* stats) const {
  StemSlices slices(stems, p_);
  // In the merger's submap order (refitStemDbh: the dataset's order).
  for (const MergedPose& pose : poses) {
    auto it = clouds_.find(pose.id);
    if (it != clouds_.end()) slices.addSubmap(pose.component, pose.T_M_S, *it->second);
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
