#include "dtif/ros/fleet_map.h"

#include <pcl/common/transforms.h>

#include <iomanip>
#include <sstream>

#include "dtif/core/file_io.h"
#include "dtif/core/voxel_grid.h"

namespace dtif {
namespace ros_glue {

FleetMap::FleetMap(const MergeParams& params, std::vector<FieldStem> field, double cloud_voxel_m)
    : params_(params), field_(std::move(field)), cloud_voxel_m_(cloud_voxel_m) {
  reset();
}

void FleetMap::reset() {
  merger_ = MapMerger(params_);
  if (!field_.empty()) merger_.setStemMap(field_);
  chains_.clear();
  global_id_.clear();
  stamp_index_.clear();
  stamp_of_.clear();
  chain_of_.clear();
  odom_of_.clear();
  clouds_.clear();
  slices_ = SlicePointStore(params_.stems);
  pending_.clear();
  next_id_ = 0;
}

std::string FleetMap::addSubmap(const Descriptor& d, const std::string& odom_frame, double stamp,
                                const Pose& T_O_S) {
  if (odom_frame.empty()) return "no odometry frame (frame_id)";
  Chain& chain = chains_[d.robot];
  if (!chain.odom_frame.empty() && chain.odom_frame != odom_frame) {
    return "in frame " + odom_frame + ", the robot's is " + chain.odom_frame;
  }
  chain.odom_frame = odom_frame;
  // A tilted odometry frame (stock FAST-LIO2): the robot's latest levelling keeps map z up.
  if (d.levelled()) {
    merger_.setLevelling(d.robot, levellingInOdom(d.level_rotation.toRotationMatrix(), T_O_S));
  }
  MergeSubmap s = mergeSubmapOf(d, T_O_S);
  s.stamp = stamp;
  const Trunks trunks_S = s.trunks;
  const std::string why = addToMerger(d.robot, std::move(s));
  if (!why.empty()) return why;
  if (params_.stems.dbh_from_points) {
    slices_.addTrunks(next_id_ - 1, trunks_S, d.level_rotation.normalized().toRotationMatrix());
  }
  return "";
}

std::string FleetMap::addToMerger(const std::string& chain, MergeSubmap s) {
  const Key key(s.robot, s.id);
  if (global_id_.count(key)) return "already merged";
  const std::string robot = s.robot;
  const double stamp = s.stamp;
  s.robot = chain;
  s.id = next_id_;
  try {
    merger_.addSubmap(s);
  } catch (const std::exception& e) {
    return e.what();
  }
  global_id_[key] = next_id_;
  stamp_index_[{robot, stamp}] = next_id_;
  stamp_of_[next_id_] = stamp;
  chain_of_[next_id_] = chain;
  odom_of_[next_id_] = s.T_O_S;
  ++next_id_;
  return "";
}

bool FleetMap::addPendingLoops(size_t max_waiting, std::vector<Loop>* refused, bool* dropped) {
  bool added = false;
  for (auto it = pending_.begin(); it != pending_.end();) {
    const auto q = global_id_.find({it->query_robot, it->query_id});
    const auto c = global_id_.find({it->candidate_robot, it->candidate_id});
    if (q == global_id_.end() || c == global_id_.end()) {  // a descriptor may come later
      ++it;
      continue;
    }
    Loop lc = *it;
    lc.query_id = q->second;
    lc.candidate_id = c->second;
    if (merger_.addLoop(lc)) {
      added = true;
    } else if (refused) {
      refused->push_back(*it);
    }
    it = pending_.erase(it);
  }
  *dropped = pending_.size() > max_waiting;
  if (*dropped) pending_.pop_front();
  return added;
}

std::string FleetMap::robotOfFrame(const std::string& frame) const {
  for (const auto& [robot, chain] : chains_) {
    if (chain.odom_frame == frame) return robot;
  }
  return "";
}

std::string FleetMap::addCloud(const std::string& robot, double stamp, const Cloud& cloud_O,
                               const std::vector<MergedStem>& known) {
  const auto it = stamp_index_.find({robot, stamp});
  if (it == stamp_index_.end()) return "matches no submap";
  // O -> S with the submap's own odometry pose.
  const Pose T_S_O = odom_of_.at(it->second).inverse();
  Cloud::Ptr in_s(new Cloud);
  pcl::transformPointCloud(cloud_O, *in_s, T_S_O.matrix().cast<float>());
  clouds_[it->second] = voxelDown(*in_s);
  if (!params_.stems.dbh_from_points) return "";
  if (params_.stems.slice_defer_clouds > 0) {
    slices_.holdCloud(it->second, *in_s);
    for (int64_t id : slices_.overdue()) {
      const auto [component, T_M_S] = placement(id);
      slices_.settle(id, known, component, T_M_S);
    }
  } else {
    const auto [component, T_M_S] = placement(it->second);
    slices_.addCloud(it->second, *in_s, known, component, T_M_S);
  }
  return "";
}

std::pair<int, Pose> FleetMap::placement(int64_t id) const {
  const std::optional<Pose> T_M_S = merger_.pose(id);
  if (!T_M_S) return {-1, Pose::Identity()};
  return {merger_.component(chain_of_.at(id)), *T_M_S};
}

FleetMap::Loaded FleetMap::loadDatabase(const LoopDetector& db) {
  reset();
  Loaded n;
  for (size_t i : entriesInStampOrder(db)) {
    const Descriptor& d = *db.entries()[i];
    const EntryOdometry& o = db.odometry(i);
    if (!o.known()) {
      ++n.without_odometry;
      continue;
    }
    const std::string chain = d.robot + "@database";
    chains_[chain] = Chain{o.odom_frame, false};
    n.submaps += addToMerger(chain, mergeSubmapOf(d, o.T_O_S)).empty();
  }
  // The earlier run's loops rebuild its map, so the new run lands in that map.
  for (Loop lc : db.loops()) {
    const auto q = global_id_.find({lc.query_robot, lc.query_id});
    const auto c = global_id_.find({lc.candidate_robot, lc.candidate_id});
    if (q == global_id_.end() || c == global_id_.end()) continue;
    lc.query_id = q->second;
    lc.candidate_id = c->second;
    n.loops += merger_.addLoop(lc);
  }
  return n;
}

// The core's centroid voxel filter (as the submaps' own downsampling).
Cloud::Ptr FleetMap::voxelDown(const Cloud& in) const {
  Cloud::Ptr out(new Cloud);
  out->points.assign(in.points.begin(), in.points.end());
  VoxelCentroidSorter(cloud_voxel_m_).filter(out.get());  // the grid's centroids, sorted faster
  return out;
}

Cloud::Ptr FleetMap::mergedCloud(const std::vector<MergedPose>& poses, int component) const {
  Cloud all;
  std::map<int64_t, const MergedPose*> by_id;
  for (const MergedPose& p : poses) by_id[p.id] = &p;
  for (const auto& [id, cloud] : clouds_) {
    const auto p = by_id.find(id);
    if (p == by_id.end() || p->second->component != component) continue;
    Cloud moved;
    pcl::transformPointCloud(*cloud, moved, p->second->T_M_S.matrix().cast<float>());
    all += moved;
  }
  if (all.empty()) return nullptr;
  return voxelDown(all);
}

double FleetMap::stampOf(int64_t id) const {
  const auto it = stamp_of_.find(id);
  return it == stamp_of_.end() ? 0.0 : it->second;
}

void FleetMap::writeSubmapIds(const std::string& path, const std::vector<MergedPose>& poses) const {
  std::map<int64_t, const Key*> own;
  for (const auto& [key, id] : global_id_) own[id] = &key;
  std::ostringstream out;
  out << "id,chain,robot,submap_id,stamp\n" << std::setprecision(17);
  for (const MergedPose& p : poses) {
    const Key& k = *own.at(p.id);
    out << p.id << ',' << p.robot << ',' << k.first << ',' << k.second << ',' << stamp_of_.at(p.id)
        << '\n';
  }
  writeFileAtomically(path, out.str());
}

}  // namespace ros_glue
}  // namespace dtif
