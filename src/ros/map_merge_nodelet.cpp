// dtif/MapMergeNodelet: one, shared by all robots. Feeds every robot's submap chain (descriptor
// T_O_S) and the accepted loops into the merge back end (core/merge/map_merger.h), re-solves on
// a worker thread and publishes TF map -> <robot odometry frame>, per-robot paths, the merged
// stem inventory, markers and, on request, the merged cloud. All merging is in the core.
#include <geometry_msgs/TransformStamped.h>
#include <malloc.h>
#include <nodelet/nodelet.h>
#include <pcl/io/pcd_io.h>
#include <pcl_conversions/pcl_conversions.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>

#include <algorithm>
#include <boost/bind/bind.hpp>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <pluginlib/class_list_macros.hpp>
#include <set>
#include <thread>

#include "dtif/core/cloud.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/validation.h"
#include "dtif/core/file_io.h"
#include "dtif/core/merge/map_merger.h"
#include "dtif/core/merge/slice_store.h"
#include "dtif/core/timing.h"
#include "dtif/io/dataset.h"
#include "dtif/io/merge_files.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/fleet_map.h"
#include "dtif/ros/map_frames.h"
#include "dtif/ros/merge_outputs.h"
#include "dtif/ros/merge_params.h"
#include "dtif/ros/msgs.h"
#include "dtif/ros/params.h"

namespace dtif {

/// Thread-safety: subscriber callbacks only enqueue (queue_mutex_). One worker thread feeds the
/// merger and re-solves at most every solve_period_s; it and the services serialise on
/// merge_mutex_. What is published comes from a snapshot (out_mutex_) the TF timer reads.
class MapMergeNodelet : public nodelet::Nodelet {
 public:
  ~MapMergeNodelet() override {
    {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      stop_ = true;
    }
    cv_.notify_all();
    if (worker_.joinable()) worker_.join();
  }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readParams(pnh);
    frames_ = ros_glue::MapFrames(node_.map_frame);
    if (!node_.database_file.empty()) {
      std::string message;
      loadDatabase(node_.database_file, &message);
      NODELET_INFO("%s", message.c_str());
    }
    for (const std::string& robot : node_.robots) {
      subs_.push_back(nh.subscribe<dtif::TrunkDescriptor>(
          robot + "/" + node_.descriptor_topic, 50,
          boost::bind(&MapMergeNodelet::onDescriptor, this, boost::placeholders::_1, robot)));
      if (!node_.cloud_topic.empty() && node_.cloud_topic[0] != '/') {
        subs_.push_back(nh.subscribe<sensor_msgs::PointCloud2>(
            robot + "/" + node_.cloud_topic, 5,
            boost::bind(&MapMergeNodelet::onCloud, this, boost::placeholders::_1, robot)));
      }
      path_pubs_[robot] = pnh.advertise<nav_msgs::Path>("path/" + robot, 1, true);
    }
    if (!node_.cloud_topic.empty() && node_.cloud_topic[0] == '/') {
      // One topic for every robot (dtif.launch's default /submap_cloud): the cloud's frame names
      // its robot (robotOfFrame).
      subs_.push_back(nh.subscribe<sensor_msgs::PointCloud2>(
          node_.cloud_topic, 5,
          boost::bind(&MapMergeNodelet::onCloud, this, boost::placeholders::_1, std::string())));
    }
    subs_.push_back(nh.subscribe(node_.loop_topic, 100, &MapMergeNodelet::onLoop, this));
    stems_pub_ = pnh.advertise<dtif::StemInventory>("stems", 1, true);
    markers_pub_ = pnh.advertise<visualization_msgs::MarkerArray>("markers", 1, true);
    cloud_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("merged_cloud", 1, true);
    save_srv_ = pnh.advertiseService("save_map", &MapMergeNodelet::onSaveMap, this);
    info_srv_ = pnh.advertiseService("get_map_info", &MapMergeNodelet::onInfo, this);
    cloud_srv_ = pnh.advertiseService("publish_cloud", &MapMergeNodelet::onPublishCloud, this);
    load_srv_ = pnh.advertiseService("load_database", &MapMergeNodelet::onLoad, this);
    if (node_.tf_rate_hz > 0.0) {
      tf_timer_ = nh.createWallTimer(ros::WallDuration(1.0 / node_.tf_rate_hz),
                                     [this](const ros::WallTimerEvent&) { publishTf(); });
    }
    worker_ = std::thread(&MapMergeNodelet::work, this);
  }

  void readParams(ros::NodeHandle& pnh) {
    try {
      ros_glue::ParamReader reader(pnh);
      reader.readSection("", &node_);
      reader.readSection("merge", &merge_params_);
      reader.readSection("stems", &merge_params_.stems);
      reader.checkNoUnknownKeys();
      std::string problems = merge_params_.validate();
      if (node_.robots.empty()) problems += "robots: list at least one robot\n";
      if (node_.map_frame.empty()) problems += "map_frame must not be empty\n";
      if (!(node_.solve_period_s >= 0.0)) problems += "solve_period_s must be >= 0\n";
      if (!(node_.tf_rate_hz >= 0.0)) problems += "tf_rate_hz must be >= 0\n";
      if (!(node_.cloud_voxel_m > 0.0)) problems += "cloud_voxel_m must be > 0\n";
      if (node_.queue_size < 1) problems += "queue_size must be >= 1\n";
      if (!problems.empty()) throw ParamError(pnh.getNamespace() + ": " + problems);
      loadStemMap();
    } catch (const ParamError& e) {
      NODELET_FATAL("%s", e.what());
      throw;
    }
    fleet_ = std::make_unique<ros_glue::FleetMap>(merge_params_, field_, node_.cloud_voxel_m);
  }

  // The field stem map (stem_map_file), once at start-up: a file that cannot be read is a
  // configuration error, as an unknown key is.
  void loadStemMap() {
    if (node_.stem_map_file.empty()) return;
    try {
      field_ = readStemMapCsv(node_.stem_map_file, node_.stem_map_plot);
    } catch (const DatasetError& e) {
      throw ParamError(std::string("stem_map_file: ") + e.what());
    }
    if (field_.empty()) {
      throw ParamError("stem_map_file: " + node_.stem_map_file + " holds no stem" +
                       (node_.stem_map_plot.empty() ? "" : " of plot " + node_.stem_map_plot));
    }
    NODELET_INFO("stem map %s: %zu field stems; %s becomes the plot's frame once they register",
                 node_.stem_map_file.c_str(), field_.size(), node_.map_frame.c_str());
  }

  // Logs when component 0 registers to the field stem map, or stops registering (merge_mutex_).
  void reportStemMap() {
    if (field_.empty()) return;
    const StemMapRegistration r = fleet_->merger().stemMapRegistration();
    if (r.ok == stem_map_registered_) return;
    stem_map_registered_ = r.ok;
    if (r.ok) {
      NODELET_INFO(
          "stem map: registered, %zu stems paired, residual RMS %.2f m: %s is now the "
          "plot's frame",
          r.pairs.size(), r.rms_m, node_.map_frame.c_str());
    } else {
      NODELET_WARN("stem map: no longer registered (%s): %s is the first robot's frame again",
                   r.reason.c_str(), node_.map_frame.c_str());
    }
  }

  // ---- Callbacks: enqueue only. ----

  template <class Q, class M>
  void enqueue(Q* q, const M& msg, const char* what) {
    {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      if (q->size() >= static_cast<size_t>(node_.queue_size)) {
        NODELET_WARN_THROTTLE(5.0, "map merge is behind: dropping a %s", what);
        q->pop_front();
      }
      q->push_back(msg);
    }
    cv_.notify_one();
  }

  void onDescriptor(const dtif::TrunkDescriptor::ConstPtr& msg, const std::string& robot) {
    if (msg->robot != robot) {
      NODELET_WARN_THROTTLE(5.0, "descriptor of robot '%s' on the topic of '%s': dropped",
                            msg->robot.c_str(), robot.c_str());
      return;
    }
    enqueue(&descriptors_, msg, "descriptor");
  }

  void onLoop(const dtif::LoopClosure::ConstPtr& msg) { enqueue(&loops_in_, msg, "loop"); }

  void onCloud(const sensor_msgs::PointCloud2::ConstPtr& msg, const std::string& robot) {
    enqueue(&clouds_in_, std::make_pair(robot, msg), "submap cloud");
  }

  // ---- Worker: feed the merger, re-solve, publish. ----

  void work() {
    while (true) {
      std::vector<dtif::TrunkDescriptor::ConstPtr> ds;
      std::vector<dtif::LoopClosure::ConstPtr> ls;
      std::vector<std::pair<std::string, sensor_msgs::PointCloud2::ConstPtr>> cs;
      {
        std::unique_lock<std::mutex> lock(queue_mutex_);
        cv_.wait_for(lock, std::chrono::duration<double>(std::max(node_.solve_period_s, 0.05)),
                     [this] { return stop_; });
        if (stop_) return;
        ds.assign(descriptors_.begin(), descriptors_.end());
        ls.assign(loops_in_.begin(), loops_in_.end());
        cs.assign(clouds_in_.begin(), clouds_in_.end());
        descriptors_.clear();
        loops_in_.clear();
        clouds_in_.clear();
      }
      try {
        update(ds, ls, cs);
      } catch (const std::exception& e) {
        NODELET_ERROR_THROTTLE(5.0, "map merge update failed: %s", e.what());
      }
    }
  }

  void update(std::vector<dtif::TrunkDescriptor::ConstPtr>& ds,
              const std::vector<dtif::LoopClosure::ConstPtr>& ls,
              const std::vector<std::pair<std::string, sensor_msgs::PointCloud2::ConstPtr>>& cs) {
    std::unique_lock<std::mutex> lock(merge_mutex_);
    if (!ds.empty() || !ls.empty()) ++generation_;
    // Submaps in (stamp, robot) order: simultaneous first submaps of two robots enter in the
    // same order every run, so a component's anchor (its earliest robot) is reproducible.
    std::sort(ds.begin(), ds.end(), [](const auto& a, const auto& b) {
      return a->header.stamp != b->header.stamp ? a->header.stamp < b->header.stamp
                                                : a->robot < b->robot;
    });
    bool changed = false;
    for (const auto& d : ds) changed |= addSubmap(*d);
    for (const auto& l : ls) addLoop(*l);
    changed |= addWaitingLoops();
    // The inventory so far, for the clouds' DBH points (stems a submap saw but did not extract).
    const std::vector<MergedStem> known = cs.empty() || !merge_params_.stems.dbh_from_points
                                              ? std::vector<MergedStem>()
                                              : fleet_->merger().stems();
    for (const auto& c : cs) addCloud(c.first, *c.second, known);
    if (!changed && !dirty_) {
      releaseFreedMemory(true);  // idle: whatever the last solve freed goes back now
      return;
    }
    dirty_ = false;
    const auto t0 = std::chrono::steady_clock::now();
    MapMerger& merger = fleet_->merger();
    const MergeSolveStats st = merger.solve();
    last_solve_ms_ = msSince(t0);
    max_solve_ms_ = std::max(max_solve_ms_, last_solve_ms_);
    ++solves_;
    loops_used_ = st.loops_used;
    loops_rejected_ = st.loops_rejected;
    NODELET_DEBUG("re-solve: %zu submaps, %zu loops used, %zu rejected, %.1f ms",
                  merger.submapCount(), st.loops_used, st.loops_rejected, last_solve_ms_);
    for (const MergeEvent& e : merger.takeEvents()) NODELET_INFO("%s", e.text.c_str());
    reportStemMap();
    assignFrames();
    publishOutputs();
    releaseFreedMemory(false);
  }

  // Each re-solve builds and frees a Ceres problem of the whole graph; glibc keeps the freed
  // pages in its arenas, so over an hour the resident size climbed ~50 MB above what the map
  // itself holds (the soak test). Handing them back costs a few ms: at most every 10 s while
  // solves follow each other, and once when the worker falls idle after one.
  void releaseFreedMemory(bool idle) {
#ifdef __GLIBC__
    const auto now = std::chrono::steady_clock::now();
    if (!idle && now - last_trim_ < std::chrono::seconds(10)) {
      trim_pending_ = true;  // handed back when the worker falls idle
      return;
    }
    if (idle && !trim_pending_) return;
    last_trim_ = now;
    trim_pending_ = false;
    malloc_trim(0);
#else
    (void)idle;
#endif
  }

  // A descriptor's submap on its robot's chain; false (logged) when malformed or known.
  bool addSubmap(const dtif::TrunkDescriptor& msg) {
    Descriptor d;
    Pose T_O_S;
    std::string error;
    if (!ros_glue::fromMsg(msg, receiver_params_, &d, &T_O_S, &error)) {
      NODELET_WARN_THROTTLE(5.0, "descriptor %s/%ld: %s: dropped", msg.robot.c_str(),
                            static_cast<long>(msg.submap_id), error.c_str());
      return false;
    }
    error = fleet_->addSubmap(d, msg.header.frame_id, msg.header.stamp.toSec(), T_O_S);
    if (!error.empty()) {
      NODELET_WARN_THROTTLE(5.0, "descriptor %s/%ld: %s: dropped", msg.robot.c_str(),
                            static_cast<long>(msg.submap_id), error.c_str());
      return false;
    }
    return true;
  }

  void addLoop(const dtif::LoopClosure& msg) {
    Loop lc;
    std::string error;
    if (ros_glue::fromMsg(msg, &lc, &error)) {
      fleet_->addLoop(lc);
    } else {
      NODELET_WARN_THROTTLE(5.0, "loop closure: %s: dropped", error.c_str());
    }
  }

  // Loops whose submaps are both merged go in; the others wait (their descriptor may come
  // later than the loop). True when one went in.
  bool addWaitingLoops() {
    std::vector<Loop> refused;
    bool dropped = false;
    const bool added =
        fleet_->addPendingLoops(static_cast<size_t>(node_.queue_size), &refused, &dropped);
    for (const Loop& l : refused) {
      NODELET_WARN_THROTTLE(5.0, "loop %s -> %s refused by the merge back end",
                            l.query_robot.c_str(), l.candidate_robot.c_str());
    }
    if (dropped) NODELET_WARN_THROTTLE(5.0, "loops whose submaps never came: dropping the oldest");
    return added;
  }

  // A submap cloud (odometry frame, stamped with the submap's anchor time: the extraction
  // nodelet's submap_cloud); on the cloud topic shared by all robots, its frame names the robot.
  void addCloud(const std::string& topic_robot, const sensor_msgs::PointCloud2& msg,
                const std::vector<MergedStem>& known) {
    const std::string robot =
        topic_robot.empty() ? fleet_->robotOfFrame(msg.header.frame_id) : topic_robot;
    Cloud cloud;
    std::string error;
    if (ros_glue::fromMsg(msg, &cloud, nullptr, &error)) {
      error = fleet_->addCloud(robot, msg.header.stamp.toSec(), cloud, known);
    }
    if (!error.empty()) {
      NODELET_WARN_THROTTLE(5.0, "submap cloud of %s at %.3f: %s: dropped", robot.c_str(),
                            msg.header.stamp.toSec(), error.c_str());
    }
  }

  // Map frames per component (merge_mutex_); robots that change frame are logged.
  void assignFrames() {
    std::map<int, std::set<std::string>> comps;
    const MapMerger& merger = fleet_->merger();
    for (const std::string& r : merger.robots()) comps[merger.component(r)].insert(r);
    std::vector<std::set<std::string>> list;
    for (auto& c : comps) list.push_back(c.second);
    for (const auto& ch : frames_.assign(list)) {
      if (ch.from.empty()) {
        NODELET_INFO("robot %s is in frame %s", ch.robot.c_str(), ch.to.c_str());
      } else {
        NODELET_WARN("robot %s moves from frame %s to %s (its component joined another)",
                     ch.robot.c_str(), ch.from.c_str(), ch.to.c_str());
      }
    }
    component_frame_.clear();
    for (const std::string& r : merger.robots()) {
      component_frame_[merger.component(r)] = frames_.frameOf(r);
    }
  }

  std::string frameOfComponent(int c) const {
    auto it = component_frame_.find(c);
    return it == component_frame_.end() ? std::string() : it->second;
  }

  // Paths, stems, markers and the TF snapshot from the latest solve (merge_mutex_ held).
  void publishOutputs() {
    const ros::Time now = ros::Time::now();
    const MapMerger& merger = fleet_->merger();
    const std::vector<MergedPose> poses = merger.poses();
    std::map<std::string, std::vector<std::pair<double, Pose>>> per_robot;
    for (const MergedPose& p : poses)
      per_robot[p.robot].emplace_back(fleet_->stampOf(p.id), p.T_M_S);
    std::vector<geometry_msgs::TransformStamped> tfs;
    for (const auto& [robot, chain] : fleet_->chains()) {
      if (!chain.live) continue;
      const std::optional<Pose> T_M_O = merger.mapFromOdom(robot);
      if (!T_M_O) continue;
      geometry_msgs::TransformStamped t;
      t.header.frame_id = frames_.frameOf(robot);
      t.child_frame_id = chain.odom_frame;
      t.transform = ros_glue::toTransformMsg(*T_M_O);
      tfs.push_back(t);
      auto pub = path_pubs_.find(robot);
      if (pub != path_pubs_.end()) {
        pub->second.publish(ros_glue::pathMsg(per_robot[robot], frames_.frameOf(robot), now));
      }
    }
    {
      std::lock_guard<std::mutex> lock(out_mutex_);
      tf_snapshot_ = tfs;
      tf_changed_ = true;
    }
    publishTf();
    const std::vector<MergedStem> stems = merger.stems();
    stems_count_ = stems.size();
    const int map_component = componentOfFrame(node_.map_frame);
    if (map_component >= 0) {
      stems_pub_.publish(ros_glue::stemInventoryMsg(stems, map_component, node_.map_frame, now));
    }
    markers_pub_.publish(ros_glue::mergedMapMarkers(
        poses, merger.loops(), stems, [this](int c) { return frameOfComponent(c); }, now));
  }

  int componentOfFrame(const std::string& frame) const {
    for (const auto& c : component_frame_) {
      if (c.second == frame) return c.first;
    }
    return -1;
  }

  // The snapshot's map -> odometry transforms, stamped now (timer or worker thread). tf2 ignores
  // a transform whose stamp it already holds, so a new solve while the clock stands (a bag that
  // ended, a paused replay) goes out a microsecond after the last one, and an unchanged snapshot
  // is not sent again at the same time.
  void publishTf() {
    std::lock_guard<std::mutex> lock(out_mutex_);
    if (tf_snapshot_.empty()) return;
    ros::Time stamp = ros::Time::now();
    if (stamp + ros::Duration(1.0) < last_tf_stamp_) last_tf_stamp_ = ros::Time();  // replay
    if (stamp <= last_tf_stamp_) {
      if (!tf_changed_) return;
      stamp = last_tf_stamp_ + ros::Duration(1e-6);
    }
    for (auto& t : tf_snapshot_) t.header.stamp = stamp;
    if (!tf_broadcaster_) tf_broadcaster_ = std::make_unique<tf2_ros::TransformBroadcaster>();
    tf_broadcaster_->sendTransform(tf_snapshot_);
    last_tf_stamp_ = stamp;
    tf_changed_ = false;
  }

  // ---- Database of an earlier run: its submaps as chains of their own. ----

  // Replaces the merged map by the database's submaps whose odometry is known (version-2 files),
  // one chain "<robot>@database" per robot, and its loops. Loops of the new run against them then
  // place the new robots in that map.
  bool loadDatabase(const std::string& path, std::string* message) {
    LoopDetector db{LoopDetectorParams{}};
    try {
      db.load(path);
    } catch (const std::exception& e) {
      *message = std::string("database not loaded, map unchanged: ") + e.what();
      return false;
    }
    std::lock_guard<std::mutex> lock(merge_mutex_);
    const ros_glue::FleetMap::Loaded n = fleet_->loadDatabase(db);  // replaces the whole map
    resetFrames();
    dirty_ = true;
    *message = "map: " + std::to_string(n.submaps) + " submaps and " + std::to_string(n.loops) +
               " loops of an earlier run from " + path +
               (n.without_odometry
                    ? " (" + std::to_string(n.without_odometry) + " without odometry pose skipped)"
                    : "");
    return true;
  }

  // A new map (a database loaded): its frames, stem map registration and generation start over.
  void resetFrames() {
    ++generation_;
    stem_map_registered_ = false;
    frames_ = ros_glue::MapFrames(node_.map_frame);
    component_frame_.clear();
  }

  bool onLoad(dtif::LoadDatabase::Request& req, dtif::LoadDatabase::Response& res) {
    res.success = loadDatabase(req.path, &res.message);
    if (res.success) {
      NODELET_INFO("%s", res.message.c_str());
    } else {
      NODELET_ERROR("%s", res.message.c_str());
    }
    std::lock_guard<std::mutex> lock(merge_mutex_);
    res.size = fleet_->merger().submapCount();
    cv_.notify_one();
    return true;
  }

  // ---- Services. ----

  bool onInfo(dtif::GetMapInfo::Request&, dtif::GetMapInfo::Response& res) {
    std::lock_guard<std::mutex> lock(merge_mutex_);
    std::map<std::string, uint32_t> count;
    for (const MergedPose& p : fleet_->merger().poses()) ++count[p.robot];
    for (const auto& [robot, chain] : fleet_->chains()) {
      res.robots.push_back(robot);
      res.map_frames.push_back(frames_.frameOf(robot));
      res.odom_frames.push_back(chain.odom_frame);
      res.submaps.push_back(count[robot]);
    }
    res.loops_used = static_cast<uint32_t>(loops_used_);
    res.loops_rejected = static_cast<uint32_t>(loops_rejected_);
    res.stems = static_cast<uint32_t>(stems_count_);
    res.solves = static_cast<uint32_t>(solves_);
    res.last_solve_ms = last_solve_ms_;
    res.max_solve_ms = max_solve_ms_;
    res.slice_submaps = static_cast<uint32_t>(fleet_->slices().submapsWithPoints());
    res.slice_bytes = fleet_->slices().bytes();
    res.stems_dbh_from_points = static_cast<uint32_t>(stems_dbh_from_points_);
    {
      std::lock_guard<std::mutex> qlock(queue_mutex_);
      res.up_to_date = !dirty_ && descriptors_.empty() && loops_in_.empty() &&
                       fleet_->waitingLoops() == 0 && solves_ > 0;
    }
    return true;
  }

  bool onPublishCloud(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::lock_guard<std::mutex> lock(merge_mutex_);
    const int c = componentOfFrame(node_.map_frame);
    Cloud::Ptr cloud = c >= 0 ? fleet_->mergedCloud(fleet_->merger().poses(), c) : nullptr;
    if (!cloud) {
      res.success = false;
      res.message = "no submap clouds in " + node_.map_frame +
                    " (enable the extraction nodelets' publish_submap_cloud)";
      return true;
    }
    sensor_msgs::PointCloud2 msg;
    pcl::toROSMsg(*cloud, msg);
    msg.header.frame_id = node_.map_frame;
    msg.header.stamp = ros::Time::now();
    cloud_pub_.publish(msg);
    res.success = true;
    res.message = std::to_string(cloud->size()) + " points on " + cloud_pub_.getTopic();
    return true;
  }

  // What save_map writes, copied under merge_mutex_: the landmark refinement and the files take
  // seconds on a large map (2.4 s on the soak test's 712 submaps), and the worker goes on
  // merging meanwhile.
  struct SaveSnapshot {
    ros_glue::FleetMap map;  // a copy: submap clouds are shared, never modified
    uint64_t generation = 0;
    int component = -1;  // the component in node_.map_frame
  };

  SaveSnapshot saveSnapshot() {
    std::lock_guard<std::mutex> lock(merge_mutex_);
    return SaveSnapshot{*fleet_, generation_, componentOfFrame(node_.map_frame)};
  }

  bool onSaveMap(dtif::SaveMap::Request& req, dtif::SaveMap::Response& res) {
    namespace fs = std::filesystem;
    try {
      if (req.directory.empty()) throw std::runtime_error("empty directory");
      fs::create_directories(req.directory);
      const fs::path dir(req.directory);
      SaveSnapshot snap = saveSnapshot();
      // The saved map is the landmark-refined one (too costly for every re-solve).
      const MergeSolveStats st = snap.map.merger().refine();
      NODELET_INFO("save_map: landmark refinement %.1f ms (%zu landmarks)", st.landmark_ms,
                   st.landmarks);
      const std::vector<MergedPose> poses = snap.map.merger().poses();
      writeMergedPosesCsv((dir / "merged_poses.csv").string(), poses);
      writeMergedStemsCsv((dir / "merged_stems.csv").string(), savedStems(snap, poses));
      writeG2o((dir / "pose_graph.g2o").string(), poses, snap.map.merger().graphEdges());
      snap.map.writeSubmapIds((dir / "submap_ids.csv").string(), poses);
      res.files = {"merged_poses.csv", "merged_stems.csv", "pose_graph.g2o", "submap_ids.csv"};
      if (Cloud::Ptr cloud =
              snap.component >= 0 ? snap.map.mergedCloud(poses, snap.component) : nullptr) {
        writePcdAtomically((dir / "merged_cloud.pcd").string(), *cloud);
        res.files.push_back("merged_cloud.pcd");
      }
      adoptRefined(&snap);
      res.success = true;
      res.message = "saved " + std::to_string(poses.size()) + " submaps to " + req.directory;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("save_map failed: ") + e.what();
      NODELET_ERROR("%s", res.message.c_str());
    }
    return true;
  }

  // The saved inventory: with stems.dbh_from_points, the DBH measured on the points the submap
  // clouds kept (SlicePointStore), as dtif merge measures it on the dataset's clouds.
  std::vector<MergedStem> savedStems(const SaveSnapshot& snap,
                                     const std::vector<MergedPose>& poses) {
    std::vector<MergedStem> stems = snap.map.merger().stems();
    if (!merge_params_.stems.dbh_from_points) return stems;
    const auto t0 = std::chrono::steady_clock::now();
    StemSliceStats st;
    const SlicePointStore& slices = snap.map.slices();
    stems = slices.refit(stems, poses, &st);
    const size_t n = slices.submapsWithPoints();
    NODELET_INFO(
        "save_map: DBH from the points on %zu of %zu stems, half-way on %zu (%zu too few, %zu "
        "one-sided, %zu shrunk, %zu around clutter, %zu no fit; %zu slice points from %zu submap "
        "views; %zu submaps aligned on %zu stems, largest shift %.1f cm), %.1f ms; kept "
        "%zu points of %zu submaps, %zu bytes (%zu per submap)",
        st.refitted, st.stems, st.blended, st.too_few, st.one_sided, st.shrunk, st.enclosing,
        st.no_fit, st.points, st.submap_views, st.alignment.views, st.alignment.stems,
        100.0 * st.alignment.max_shift_m, msSince(t0), slices.points(), n, slices.bytes(),
        n ? slices.bytes() / n : size_t{0});
    std::lock_guard<std::mutex> lock(merge_mutex_);
    stems_dbh_from_points_ = st.refitted;
    return stems;
  }

  // The published TFs and paths follow the refined map until the next solve, which starts from
  // it; unless submaps or loops arrived while saving: then the live map keeps its own solve.
  void adoptRefined(SaveSnapshot* snap) {
    std::lock_guard<std::mutex> lock(merge_mutex_);
    if (snap->generation != generation_) {
      NODELET_INFO(
          "save_map: the map changed while saving; the saved files are the map as it "
          "was when save_map was called");
      return;
    }
    fleet_->merger() = std::move(snap->map.merger());
    // A component joined by its stem inventory (refine) is logged and moves into its frame.
    for (const MergeEvent& e : fleet_->merger().takeEvents()) NODELET_INFO("%s", e.text.c_str());
    assignFrames();
    publishOutputs();
  }

  static void writePcdAtomically(const std::string& path, const Cloud& cloud) {
    if (pcl::io::savePCDFileBinaryCompressed(path + ".tmp", cloud) != 0) {
      std::remove((path + ".tmp").c_str());
      throw std::runtime_error(path + ".tmp: cannot write");
    }
    replaceWithTemporary(path);
  }

  ros_glue::MapMergeNodeParams node_;
  MergeParams merge_params_;
  std::vector<FieldStem> field_;  // the field stem map, if any
  bool stem_map_registered_ = false;
  std::chrono::steady_clock::time_point last_trim_;  // worker thread only
  bool trim_pending_ = false;                        // worker thread only
  // This nodelet builds no descriptors: it keeps each one's trunks as its sender sent them.
  const DescriptorParams receiver_params_ = loosestDescriptorParams();

  std::mutex merge_mutex_;                     // everything down to out_mutex_
  std::unique_ptr<ros_glue::FleetMap> fleet_;  // built once the parameters are read
  ros_glue::MapFrames frames_;
  size_t stems_dbh_from_points_ = 0;  // the latest save_map's refitted stems
  std::map<int, std::string> component_frame_;
  bool dirty_ = false;       // a database load wants a solve
  uint64_t generation_ = 0;  // counts changes of the merged graph (save_map's snapshots)
  size_t loops_used_ = 0, loops_rejected_ = 0, stems_count_ = 0;
  size_t solves_ = 0;
  double last_solve_ms_ = 0.0, max_solve_ms_ = 0.0;

  std::mutex queue_mutex_;  // the three queues, stop_
  std::condition_variable cv_;
  std::deque<dtif::TrunkDescriptor::ConstPtr> descriptors_;
  std::deque<dtif::LoopClosure::ConstPtr> loops_in_;
  std::deque<std::pair<std::string, sensor_msgs::PointCloud2::ConstPtr>> clouds_in_;
  bool stop_ = false;
  std::thread worker_;

  std::mutex out_mutex_;  // tf_snapshot_, tf_changed_, last_tf_stamp_, tf_broadcaster_
  std::vector<geometry_msgs::TransformStamped> tf_snapshot_;
  bool tf_changed_ = false;  // the snapshot was not sent since the last solve
  ros::Time last_tf_stamp_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_broadcaster_;

  std::vector<ros::Subscriber> subs_;
  std::map<std::string, ros::Publisher> path_pubs_;
  ros::Publisher stems_pub_, markers_pub_, cloud_pub_;
  ros::ServiceServer save_srv_, info_srv_, cloud_srv_, load_srv_;
  ros::WallTimer tf_timer_;
};

}  // namespace dtif

PLUGINLIB_EXPORT_CLASS(dtif::MapMergeNodelet, nodelet::Nodelet)
