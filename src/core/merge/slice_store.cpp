#include "dtif/core/merge/slice_store.h"

namespace dtif {

void SlicePointStore::addTrunks(int64_t id, const Trunks& trunks_S, const Eigen::Matrix3d& R_L_S) {
  sources_[id] = Source{trunks_S, R_L_S};
}

bool SlicePointStore::addCloud(int64_t id, const Cloud& cloud_S) {
  auto src = sources_.find(id);
  if (src == sources_.end()) return false;
  Cloud::ConstPtr kept = keepSliceCandidates(cloud_S, src->second.trunks_S, src->second.R_L_S, p_);
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
