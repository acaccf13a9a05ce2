// dtif/TrunkExtractionNodelet: one per robot. Assembles submaps (or takes ready-made ones),
// levels them with the robot's gravity estimate (core Leveller), extracts trunks and publishes
// the trunk-topology descriptor.
#include <nav_msgs/Odometry.h>
#include <nodelet/nodelet.h>
#include <pcl/common/transforms.h>
#include <pcl_conversions/pcl_conversions.h>
#include <ros/ros.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>

#include <algorithm>
#include <chrono>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <pluginlib/class_list_macros.hpp>
#include <regex>
#include <thread>

#include "dtif/core/descriptor/describe.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/descriptor/trunk_accumulator.h"
#include "dtif/core/extraction/gravity.h"
#include "dtif/core/extraction/point_bounds.h"
#include "dtif/core/extraction/trunk_extractor.h"
#include "dtif/core/timing.h"
#include "dtif/ros/bounded_queue.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/frame_lock.h"
#include "dtif/ros/frames.h"
#include "dtif/ros/markers.h"
#include "dtif/ros/msgs.h"
#include "dtif/ros/node_params.h"
#include "dtif/ros/params.h"
#include "dtif/ros/submap_assembler.h"

namespace dtif {

/// Thread-safety: subscriber callbacks may run concurrently (multi-threaded manager); they
/// share the assembler under mutex_ and only enqueue. One worker thread extracts and publishes.
/// The worker is joined in the destructor.
class TrunkExtractionNodelet : public nodelet::Nodelet {
 public:
  ~TrunkExtractionNodelet() override {
    queue_.close();
    if (worker_.joinable()) worker_.join();
  }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    try {
      readParams(nh, getPrivateNodeHandle());
    } catch (const ParamError& e) {
      NODELET_FATAL("%s", e.what());
      throw;
    }
    queue_.setCapacity(static_cast<size_t>(node_.queue_size));

    // The voxel filter of assembled submaps runs on the worker, off the cloud callback.
    ros_glue::SubmapAssemblerParams in_callback = assembler_params_;
    in_callback.voxel_m = 0.0;
    assembler_ = std::make_unique<ros_glue::SubmapAssembler>(in_callback, node_.first_submap_id);
    if (node_.input == "odometry" && assembler_params_.voxel_m > 0.0) {
      voxel_filter_ = std::make_unique<VoxelCentroidSorter>(assembler_params_.voxel_m);
    }
    leveller_ = std::make_unique<Leveller>(levelling_params_);
    setUpAccumulator();
    recent_markers_ =
        std::make_unique<ros_glue::RecentMarkers>(static_cast<size_t>(node_.marker_history));
    advertise(nh);
    subscribe(nh);
    if (node_.marker_period_s > 0.0 && node_.marker_history > 0) {
      marker_timer_ =
          nh.createWallTimer(ros::WallDuration(node_.marker_period_s),
                             [this](const ros::WallTimerEvent&) { republishMarkers(); });
    }
    watchInputs(nh);
    worker_ = std::thread(&TrunkExtractionNodelet::work, this);
    NODELET_INFO("robot '%s', input '%s', window %.1f s", node_.robot.c_str(), node_.input.c_str(),
                 assembler_params_.window_s);
  }

  // Every parameter section, validated; a ParamError lists every problem at once.
  void readParams(const ros::NodeHandle& nh, const ros::NodeHandle& pnh) {
    ros_glue::ParamReader reader(pnh);
    reader.readSection("", &node_);
    reader.readSection("", &assembler_params_);
    reader.readSection("trunk_extraction", &extractor_params_);
    reader.readSection("descriptor", &descriptor_params_);
    reader.readSection("levelling", &levelling_params_);
    reader.readSection("multi_submap", &multi_submap_params_);
    reader.checkNoUnknownKeys();
    if (node_.robot.empty()) {  // the robot's namespace names it
      const std::string ns = nh.getNamespace();
      node_.robot = ns.substr(ns.find_last_of('/') + 1);
    }
    const std::string problems = assembler_params_.validate() + extractor_params_.validate() +
                                 descriptor_params_.validate() + levelling_params_.validate() +
                                 multi_submap_params_.validate() + nodeProblems();
    if (!problems.empty()) throw ParamError(pnh.getNamespace() + ": " + problems);
  }

  std::string nodeProblems() const {
    std::string problems;
    if (node_.input != "odometry" && node_.input != "submap") {
      problems += "input must be 'odometry' or 'submap', not '" + node_.input + "'\n";
    }
    if (node_.queue_size < 1) problems += "queue_size must be >= 1\n";
    if (!node_.imu_topic.empty() && node_.input != "odometry") {
      problems += "imu_topic needs input 'odometry' (the IMU is rotated by the odometry)\n";
    }
    if (node_.marker_history < 0) problems += "marker_history must be >= 0\n";
    if (!(node_.marker_period_s >= 0.0)) problems += "marker_period_s must be >= 0\n";
    if (!(node_.input_timeout_s >= 0.0)) problems += "input_timeout_s must be >= 0\n";
    if (!std::regex_match(node_.robot, std::regex("[A-Za-z0-9_]+"))) {
      problems += "robot name '" + node_.robot +
                  "' is not [A-Za-z0-9_]+ (set ~robot or run in the robot's namespace)\n";
    }
    return problems;
  }

  void advertise(ros::NodeHandle& nh) {
    descriptor_pub_ = nh.advertise<dtif::TrunkDescriptor>("descriptor", 10);
    // Earlier submaps described again with their successors' stems (multi_submap/
    // forward_submaps): the loop-closure nodelet replaces their database entries.
    update_pub_ = nh.advertise<dtif::TrunkDescriptor>("descriptor_updates", 10);
    trunks_pub_ = nh.advertise<visualization_msgs::MarkerArray>("trunks", 2);
    if (node_.publish_submap_cloud) {
      cloud_pub_ = nh.advertise<sensor_msgs::PointCloud2>("submap_cloud", 2);
    }
  }

  void subscribe(ros::NodeHandle& nh) {
    if (node_.input == "odometry") {
      odom_sub_ = nh.subscribe("Odometry", 200, &TrunkExtractionNodelet::onOdometry, this);
      cloud_sub_ = nh.subscribe("cloud_registered", 20, &TrunkExtractionNodelet::onCloud, this);
      if (!node_.imu_topic.empty()) {
        imu_sub_ = nh.subscribe(node_.imu_topic, 2000, &TrunkExtractionNodelet::onImu, this);
      }
      return;
    }
    if (!node_.odom_frame.empty()) {
      tf_buffer_ = std::make_unique<tf2_ros::Buffer>();
      tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_, nh);
    }
    submap_sub_ = nh.subscribe("submap", 4, &TrunkExtractionNodelet::onSubmap, this);
  }

  // A periodic warning, naming the resolved topic, while an input stays silent (wall time: a
  // unit whose front end is not running, or a bag not played, or a wrong remap).
  void watchInputs(ros::NodeHandle& nh) {
    if (node_.input_timeout_s <= 0.0) return;
    input_watch_ = std::make_unique<ros_glue::InputWatch>(node_.input_timeout_s);
    const double now = ros::WallTime::now().toSec();
    for (const ros::Subscriber* sub : {&odom_sub_, &cloud_sub_, &submap_sub_, &imu_sub_}) {
      if (*sub) input_watch_->watch(sub->getTopic(), now);
    }
    input_timer_ = nh.createWallTimer(
        ros::WallDuration(node_.input_timeout_s), [this](const ros::WallTimerEvent&) {
          const double t = ros::WallTime::now().toSec();
          for (const auto& s : input_watch_->silent(t)) {
            NODELET_WARN("%s", ros_glue::InputWatch::describe(s).c_str());
          }
        });
  }

  void noteInput(const ros::Subscriber& sub) {
    if (input_watch_) input_watch_->seen(sub.getTopic(), ros::WallTime::now().toSec());
  }

  // TF output frame -> <robot>/<child_frame_id>, so rviz can show where each unit is. Skipped
  // when the child is already the robot's (its source publishes that TF). Stamped on receipt, as
  // the loop-closure nodelet stamps the TF between robots, so the two chain also when per-unit
  // bags play without a shared clock (their stamps are then far from ROS time).
  void publishBodyTf(const nav_msgs::Odometry& msg, const std::string& frame) {
    if (!node_.publish_body_tf || msg.child_frame_id.empty()) return;
    const std::string child = ros_glue::robotFrame(node_.robot, msg.child_frame_id);
    if (child == msg.child_frame_id) return;
    geometry_msgs::TransformStamped t;
    t.header.stamp = ros::Time::now();
    t.header.frame_id = frame;
    t.child_frame_id = child;
    t.transform.translation.x = msg.pose.pose.position.x;
    t.transform.translation.y = msg.pose.pose.position.y;
    t.transform.translation.z = msg.pose.pose.position.z;
    t.transform.rotation = msg.pose.pose.orientation;
    if (!tf_broadcaster_) tf_broadcaster_ = std::make_unique<tf2_ros::TransformBroadcaster>();
    tf_broadcaster_->sendTransform(t);
  }

  // The robot's multi-submap trunk sets chain submaps by T_O_S: without odometry (ready-made
  // submaps and no ~odom_frame) there is no chain, so each submap keeps its own trunks.
  void setUpAccumulator() {
    MultiSubmapParams p = multi_submap_params_;
    if (node_.input == "submap" && node_.odom_frame.empty() && p.min_trunks > 0) {
      NODELET_INFO("multi_submap off: input 'submap' without odom_frame has no T_O_S to chain");
      p.min_trunks = 0;
    }
    accumulator_ = std::make_unique<TrunkAccumulator>(p);
  }

  // Checks the frame of a message against ~odom_frame (learnt from the first message if unset).
  bool acceptFrame(const std::string& frame, const char* what) {
    if (frame.empty()) {
      NODELET_WARN_THROTTLE(5.0, "%s without frame_id: dropped", what);
      return false;
    }
    if (!frame_lock_) frame_lock_ = std::make_unique<ros_glue::FrameLock>(node_.odom_frame);
    const std::string before = frame_lock_->frame();
    const ros_glue::FrameLock::Verdict v = frame_lock_->check(frame);
    if (v == ros_glue::FrameLock::Verdict::kDrop) {
      NODELET_WARN_THROTTLE(5.0, "%s in frame '%s', expected '%s': dropped", what, frame.c_str(),
                            before.c_str());
      return false;
    }
    if (v == ros_glue::FrameLock::Verdict::kSwitched) {
      NODELET_WARN("%s: only frame '%s' arrives now, not '%s': switched to it", what, frame.c_str(),
                   before.c_str());
      assembler_->reset();  // nothing of the old frame mixes with the new one
    }
    if (frame_lock_->frame() != odom_frame_) {
      odom_frame_ = frame_lock_->frame();
      out_frame_ = ros_glue::outputOdomFrame(node_.robot, odom_frame_, node_.output_odom_frame);
      NODELET_INFO("odometry frame '%s', published as '%s'", odom_frame_.c_str(),
                   out_frame_.c_str());
    }
    return true;
  }

  // One throttled warning per input and status (a macro's throttle is per call site, which would
  // let one kind of bad input hide another). Called under mutex_.
  void report(ros_glue::SubmapAssembler::Status s, const char* what) {
    if (s == ros_glue::SubmapAssembler::Status::kOk) return;
    const ros::WallTime now = ros::WallTime::now();
    ros::WallTime& last = last_warning_[{what, static_cast<int>(s)}];
    if (!last.isZero() && (now - last).toSec() < 5.0) return;
    last = now;
    NODELET_WARN("%s: %s", what, ros_glue::SubmapAssembler::describe(s));
  }

  void onOdometry(const nav_msgs::Odometry::ConstPtr& msg) {
    noteInput(odom_sub_);
    Pose T_O_B;
    std::string error;
    if (!ros_glue::fromMsg(msg->pose.pose, &T_O_B, &error)) {
      NODELET_WARN_THROTTLE(5.0, "Odometry: %s: dropped", error.c_str());
      return;
    }
    std::string frame;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!acceptFrame(msg->header.frame_id, "Odometry")) return;
      report(assembler_->addOdometry(msg->header.stamp.toSec(), T_O_B), "Odometry");
      if (imu_sub_)
        imu_window_.addOdometry(msg->header.stamp.toSec(), Eigen::Quaterniond(T_O_B.rotation()));
      frame = out_frame_;
    }
    publishBodyTf(*msg, frame);
  }

  void onCloud(const sensor_msgs::PointCloud2::ConstPtr& msg) {
    noteInput(cloud_sub_);
    Cloud cloud;
    size_t dropped = 0;
    std::string error;
    if (!ros_glue::fromMsg(*msg, &cloud, &dropped, &error)) {
      NODELET_WARN_THROTTLE(5.0, "cloud_registered: %s: dropped", error.c_str());
      return;
    }
    if (dropped > 0) {
      NODELET_WARN_THROTTLE(30.0, "cloud_registered: %zu non-finite points dropped", dropped);
    }
    std::optional<ros_glue::AssembledSubmap> done;
    std::string frame;
    ImuGravityWindow::Reading imu;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!acceptFrame(msg->header.frame_id, "cloud_registered")) return;
      report(assembler_->addCloud(msg->header.stamp.toSec(), cloud, &done), "cloud_registered");
      frame = out_frame_;
      if (done && imu_sub_) imu = imu_window_.take();  // the IMU over this submap's window
    }
    if (done) enqueue(std::move(*done), frame, imu);
  }

  // The IMU (imu_topic): its accelerometer over each submap's window is a gravity reading in the
  // odometry frame (core ImuGravityWindow), added to the robot's estimate before levelling.
  void onImu(const sensor_msgs::Imu::ConstPtr& msg) {
    noteInput(imu_sub_);
    const auto& a = msg->linear_acceleration;
    const auto& w = msg->angular_velocity;
    std::lock_guard<std::mutex> lock(mutex_);
    if (!imu_window_.addImu(msg->header.stamp.toSec(), Eigen::Vector3d(a.x, a.y, a.z),
                            Eigen::Vector3d(w.x, w.y, w.z))) {
      NODELET_WARN_THROTTLE(5.0, "%s: an IMU message without a finite acceleration: dropped",
                            imu_sub_.getTopic().c_str());
    }
  }

  void onSubmap(const sensor_msgs::PointCloud2::ConstPtr& msg) {
    noteInput(submap_sub_);
    if (msg->header.frame_id.empty()) {
      NODELET_WARN_THROTTLE(5.0, "submap without frame_id: dropped");
      return;
    }
    ros_glue::AssembledSubmap s;
    s.cloud.reset(new Cloud);
    size_t dropped = 0;
    std::string error;
    if (!ros_glue::fromMsg(*msg, s.cloud.get(), &dropped, &error)) {
      NODELET_WARN_THROTTLE(5.0, "submap: %s: dropped", error.c_str());
      return;
    }
    if (s.cloud->empty()) {
      NODELET_WARN_THROTTLE(5.0, "submap: empty cloud: dropped");
      return;
    }
    const double stamp = msg->header.stamp.toSec();
    std::string frame = msg->header.frame_id;
    if (tf_buffer_) {
      // T_O_S from TF; without it the descriptor would carry a wrong pose, so drop.
      try {
        const auto tf = tf_buffer_->lookupTransform(node_.odom_frame, frame, msg->header.stamp,
                                                    ros::Duration(0.1));
        const auto& t = tf.transform;
        s.T_O_S = Eigen::Translation3d(t.translation.x, t.translation.y, t.translation.z) *
                  Eigen::Quaterniond(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z);
        frame = node_.odom_frame;
      } catch (const tf2::TransformException& e) {
        NODELET_WARN_THROTTLE(5.0, "submap: no transform %s <- %s: %s: dropped",
                              node_.odom_frame.c_str(), msg->header.frame_id.c_str(), e.what());
        return;
      }
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stamp <= last_submap_stamp_) {
        NODELET_WARN_THROTTLE(5.0, "submap: stamp not newer than the previous one: dropped");
        return;
      }
      last_submap_stamp_ = stamp;
      s.id = next_submap_id_++ + node_.first_submap_id;
    }
    s.stamp = stamp;
    s.end_stamp = stamp;
    enqueue(std::move(s), ros_glue::outputOdomFrame(node_.robot, frame, node_.output_odom_frame));
  }

  void enqueue(ros_glue::AssembledSubmap s, const std::string& frame,
               const ImuGravityWindow::Reading& imu = {}) {
    if (const std::optional<Job> dropped = queue_.push(Job{std::move(s), frame, imu})) {
      NODELET_WARN_THROTTLE(5.0, "extraction is behind: dropping submap %ld",
                            static_cast<long>(dropped->submap.id));
    }
  }

  void work() {
    while (std::optional<Job> job = queue_.pop()) process(job->submap, job->frame, job->imu);
  }

  void process(ros_glue::AssembledSubmap& s, const std::string& frame,
               const ImuGravityWindow::Reading& imu) {
    const auto t0 = std::chrono::steady_clock::now();
    if (voxel_filter_) ros_glue::voxelFilterSubmap(voxel_filter_.get(), s.cloud.get());
    if (imu.ok) leveller_->addImu(node_.robot, imu.up_O);
    if (imu_sub_ && !imu.ok) {
      NODELET_WARN_THROTTLE(30.0,
                            "%s: %d usable IMU samples over submap %ld (need %d): no IMU "
                            "gravity reading",
                            imu_sub_.getTopic().c_str(), imu.samples, static_cast<long>(s.id),
                            ImuGravityParams().min_samples);
    }
    // Levelling (the odometry frame may be tilted, e.g. upstream FAST-LIO2's camera_init).
    const Leveller::Result lev =
        leveller_->level(node_.robot, *s.cloud, Eigen::Quaterniond(s.T_O_S.rotation()));
    logLevelling(lev.estimate);
    TrunkExtractionResult ext;
    AccumulatedTrunks acc;
    std::vector<Descriptor> updates;
    const Descriptor d = describeLevelledCloudAccumulated(
        *s.cloud, lev.R_L_S, {node_.robot, s.id, s.stamp}, s.T_O_S, accumulator_.get(),
        extractor_params_, descriptor_params_, nullptr, &ext, &acc, &updates);
    const std::string bounds = boundsWarning(ext.stats, extractor_params_);
    if (!bounds.empty()) NODELET_WARN("submap %ld: %s", static_cast<long>(s.id), bounds.c_str());
    Pose T_O_L = s.T_O_S;  // trunks are in the levelled frame
    T_O_L.linear() = s.T_O_S.rotation() * lev.R_L_S.conjugate().toRotationMatrix();
    const double ms = msSince(t0);
    NODELET_DEBUG("submap %ld: %zu points, %zu trunks from %d submaps, %zu faces, %.1f ms%s%s",
                  static_cast<long>(s.id), s.cloud->size(), d.trunks.size(), acc.submaps,
                  d.triangles.size(), ms, d.valid ? "" : ", invalid: ", d.invalid_reason.c_str());
    boost::shared_ptr<dtif::TrunkDescriptor> msg(
        new dtif::TrunkDescriptor(ros_glue::toMsg(d, s.T_O_S, frame)));
    msg->data_end.fromSec(s.end_stamp);
    descriptor_pub_.publish(boost::shared_ptr<const dtif::TrunkDescriptor>(msg));
    publishUpdates(updates, frame);
    recent_poses_.push_back({s.id, s.T_O_S, s.end_stamp});
    if (recent_poses_.size() > kRecentPoses) recent_poses_.pop_front();
    // Markers and the cloud are in the odometry frame, where they do not move: stamp 0 lets
    // rviz use the latest transform to another robot's frame, which exists only after the first
    // loop between the two, i.e. after most submaps' stamps.
    visualization_msgs::MarkerArray markers = ros_glue::trunkMarkers(
        d, T_O_L, frame, node_.robot + "/submap_" + std::to_string(s.id), ros::Time());
    if (trunks_pub_.getNumSubscribers() > 0) {
      trunks_pub_.publish(boost::shared_ptr<const visualization_msgs::MarkerArray>(
          new visualization_msgs::MarkerArray(markers)));
    }
    recent_markers_->add(std::move(markers));
    if (node_.publish_submap_cloud && cloud_pub_.getNumSubscribers() > 0 && !s.cloud->empty()) {
      // In the odometry frame, so rviz needs no extra TF for the submap frame; stamped with the
      // submap's anchor time, as its descriptor, so the map merge places it on its submap.
      Cloud cloud_O;
      pcl::transformPointCloud(*s.cloud, cloud_O, s.T_O_S.matrix().cast<float>());
      boost::shared_ptr<sensor_msgs::PointCloud2> cloud(new sensor_msgs::PointCloud2);
      pcl::toROSMsg(cloud_O, *cloud);
      cloud->header.frame_id = frame;
      cloud->header.stamp.fromSec(s.stamp);
      cloud_pub_.publish(boost::shared_ptr<const sensor_msgs::PointCloud2>(cloud));
    }
  }

  // The forward updates of earlier submaps, each with its own T_O_S (worker thread).
  void publishUpdates(const std::vector<Descriptor>& updates, const std::string& frame) {
    for (const Descriptor& u : updates) {
      auto it = std::find_if(recent_poses_.begin(), recent_poses_.end(),
                             [&](const RecentPose& r) { return r.id == u.submap_id; });
      if (it == recent_poses_.end()) continue;  // older than any update reaches
      boost::shared_ptr<dtif::TrunkDescriptor> msg(
          new dtif::TrunkDescriptor(ros_glue::toMsg(u, it->T_O_S, frame)));
      msg->data_end.fromSec(it->end_stamp);
      update_pub_.publish(boost::shared_ptr<const dtif::TrunkDescriptor>(msg));
    }
  }

  // The robot's gravity estimate, every 30 s (worker thread).
  void logLevelling(const GravityEstimate& e) {
    if (!leveller_->enabled() || !e.valid) return;
    NODELET_INFO_THROTTLE(30.0,
                          "gravity: odometry frame tilted %.2f deg (+- %.2f deg, %d submaps, %d "
                          "IMU), levelling %s",
                          e.tilt_deg, e.sigma_deg, e.submaps, e.imu,
                          e.applied ? "applied" : "not needed (below min_tilt_deg)");
  }

  // The trunk markers of the latest marker_history submaps, all again (timer thread).
  void republishMarkers() {
    if (trunks_pub_.getNumSubscribers() == 0) return;
    if (auto markers = recent_markers_->all()) trunks_pub_.publish(markers);
  }

  ros_glue::TrunkExtractionNodeParams node_;
  ros_glue::SubmapAssemblerParams assembler_params_;
  TrunkExtractorParams extractor_params_;
  DescriptorParams descriptor_params_;
  LevellingParams levelling_params_;
  std::unique_ptr<Leveller> leveller_;  // worker thread only
  MultiSubmapParams multi_submap_params_;

  // assembler_, odom_frame_, out_frame_, last_submap_stamp_, next_submap_id_, last_warning_
  std::mutex mutex_;
  std::unique_ptr<ros_glue::SubmapAssembler> assembler_;
  std::map<std::pair<std::string, int>, ros::WallTime> last_warning_;
  std::string odom_frame_;                           // of the input
  std::string out_frame_;                            // published: robot-qualified (outputOdomFrame)
  std::unique_ptr<ros_glue::FrameLock> frame_lock_;  // created on the first message
  double last_submap_stamp_ = -1.0;
  int64_t next_submap_id_ = 0;

  struct Job {
    ros_glue::AssembledSubmap submap;
    std::string frame;              // published odometry frame
    ImuGravityWindow::Reading imu;  // over the submap's window (imu_topic)
  };
  ros_glue::BoundedQueue<Job> queue_;  // capacity node_.queue_size (onInit)
  std::thread worker_;
  std::unique_ptr<VoxelCentroidSorter> voxel_filter_;  // worker thread only; null: no voxel filter
  std::unique_ptr<TrunkAccumulator> accumulator_;      // worker thread only (after onInit)
  // The recent submaps' poses, for their forward updates' messages (worker thread only): more
  // than multi_submap/max_submaps + forward_submaps can reach (at most 100 + 100).
  struct RecentPose {
    int64_t id = -1;
    Pose T_O_S = Pose::Identity();
    double end_stamp = 0.0;
  };
  static constexpr size_t kRecentPoses = 256;
  std::deque<RecentPose> recent_poses_;

  std::unique_ptr<ros_glue::RecentMarkers> recent_markers_;
  ros::WallTimer marker_timer_;

  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_broadcaster_;  // Odometry callback only
  std::unique_ptr<ros_glue::InputWatch> input_watch_;
  ros::WallTimer input_timer_;
  ros::Publisher descriptor_pub_, update_pub_, trunks_pub_, cloud_pub_;
  ros::Subscriber odom_sub_, cloud_sub_, submap_sub_, imu_sub_;
  ImuGravityWindow imu_window_;  // under mutex_
};

}  // namespace dtif

PLUGINLIB_EXPORT_CLASS(dtif::TrunkExtractionNodelet, nodelet::Nodelet)
