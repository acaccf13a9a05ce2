// dtif/LoopClosureNodelet: one, shared by all robots. Keeps the descriptor database, queries
// each new descriptor before inserting it, publishes loop closures, markers and the TF between
// the robots' odometry frames.
#include <geometry_msgs/TransformStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include <boost/bind/bind.hpp>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <pluginlib/class_list_macros.hpp>
#include <thread>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/database/robot_links.h"
#include "dtif/core/descriptor/validation.h"
#include "dtif/core/file_io.h"
#include "dtif/core/timing.h"
#include "dtif/io/dataset.h"
#include "dtif/ros/bounded_queue.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/frames.h"
#include "dtif/ros/markers.h"
#include "dtif/ros/msgs.h"
#include "dtif/ros/node_params.h"
#include "dtif/ros/params.h"

namespace dtif {

/// Thread-safety: descriptor callbacks only enqueue (queue_). One worker thread queries
/// and inserts; it and the service callbacks serialise on db_mutex_ (the LoopDetector is not
/// thread-safe). The TF timer reads links_ under db_mutex_. Worker joined on destruction.
class LoopClosureNodelet : public nodelet::Nodelet {
 public:
  ~LoopClosureNodelet() override {
    queue_.close();
    if (worker_.joinable()) worker_.join();
  }

 private:
  // What the database itself does not keep: the submap's pose in its odometry frame.
  struct Meta {
    Pose T_O_S = Pose::Identity();
    std::string odom_frame;
  };
  using Key = std::pair<std::string, int64_t>;

  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    detector_ = std::make_unique<LoopDetector>(readParams(pnh));
    queue_.setCapacity(static_cast<size_t>(node_.queue_size));
    openLoopLog();
    // A save that a crash interrupted leaves its temporary; the file itself is whole.
    if (!node_.database_file.empty() && removeStaleTemporary(node_.database_file)) {
      NODELET_WARN("removed a stale %s.tmp (an interrupted save)", node_.database_file.c_str());
    }
    // Exists, not opened: opening a FIFO would block (loadDatabase refuses one).
    if (!node_.database_file.empty() && std::filesystem::exists(node_.database_file)) {
      std::string message;
      loadDatabase(node_.database_file, &message);
      NODELET_INFO("%s", message.c_str());
    }

    loop_pub_ = nh.advertise<dtif::LoopClosure>("loop_closures", 50);
    marker_pub_ = nh.advertise<visualization_msgs::MarkerArray>("markers", 2);
    for (const std::string& robot : node_.robots) {
      const std::string topic = robot + "/" + node_.descriptor_topic;
      subs_.push_back(nh.subscribe<dtif::TrunkDescriptor>(
          topic, 50,
          boost::bind(&LoopClosureNodelet::onDescriptor, this, boost::placeholders::_1, robot,
                      nh.resolveName(topic))));
      NODELET_INFO("subscribed to %s", nh.resolveName(topic).c_str());
      if (node_.descriptor_update_topic.empty()) continue;
      const std::string updates = robot + "/" + node_.descriptor_update_topic;
      subs_.push_back(
          nh.subscribe<dtif::TrunkDescriptor>(updates, 50,
                                              boost::bind(&LoopClosureNodelet::onDescriptorUpdate,
                                                          this, boost::placeholders::_1, robot)));
    }
    watchInputs(nh);
    save_srv_ = pnh.advertiseService("save_database", &LoopClosureNodelet::onSave, this);
    load_srv_ = pnh.advertiseService("load_database", &LoopClosureNodelet::onLoad, this);
    size_srv_ = pnh.advertiseService("database_size", &LoopClosureNodelet::onSize, this);
    if (node_.publish_tf && node_.tf_rate_hz > 0.0) {
      tf_timer_ = nh.createWallTimer(ros::WallDuration(1.0 / node_.tf_rate_hz),
                                     [this](const ros::WallTimerEvent&) { publishTf(); });
    }
    if (node_.marker_period_s > 0.0) {
      marker_timer_ =
          nh.createWallTimer(ros::WallDuration(node_.marker_period_s),
                             [this](const ros::WallTimerEvent&) { republishMarkers(); });
    }
    worker_ = std::thread(&LoopClosureNodelet::work, this);
  }

  // node_ and the detector's params from ~ (strict: unknown keys and bad values are fatal).
  LoopDetectorParams readParams(ros::NodeHandle& pnh) {
    LoopDetectorParams det;
    try {
      ros_glue::ParamReader reader(pnh);
      reader.readSection("", &node_);
      reader.readSection("matcher", &det.matcher);
      reader.readSection("pose", &det.pose);
      reader.readSection("verification", &det.verification);
      reader.readSection("database", &det.database);
      reader.checkNoUnknownKeys();
      std::string problems = det.validate();
      if (node_.robots.empty()) problems += "robots: list at least one robot\n";
      if (node_.queue_size < 1) problems += "queue_size must be >= 1\n";
      if (!(node_.tf_rate_hz >= 0.0)) problems += "tf_rate_hz must be >= 0\n";
      if (!(node_.marker_period_s >= 0.0)) problems += "marker_period_s must be >= 0\n";
      if (!(node_.input_timeout_s >= 0.0)) problems += "input_timeout_s must be >= 0\n";
      if (!problems.empty()) throw ParamError(pnh.getNamespace() + ": " + problems);
    } catch (const ParamError& e) {
      NODELET_FATAL("%s", e.what());
      throw;
    }
    return det;
  }

  // A periodic warning, naming the resolved topic, while a robot's descriptors do not come.
  void watchInputs(ros::NodeHandle& nh) {
    if (node_.input_timeout_s <= 0.0) return;
    input_watch_ = std::make_unique<ros_glue::InputWatch>(node_.input_timeout_s);
    const double now = ros::WallTime::now().toSec();
    for (const ros::Subscriber& sub : subs_) input_watch_->watch(sub.getTopic(), now);
    input_timer_ = nh.createWallTimer(
        ros::WallDuration(node_.input_timeout_s), [this](const ros::WallTimerEvent&) {
          const double t = ros::WallTime::now().toSec();
          for (const auto& s : input_watch_->silent(t)) {
            NODELET_WARN("%s", ros_glue::InputWatch::describe(s).c_str());
          }
        });
  }

  // ~loop_log, when set: truncated, header first; failing to open it is fatal.
  void openLoopLog() {
    if (node_.loop_log.empty()) return;
    loop_log_.open(node_.loop_log, std::ios::trunc);
    if (!loop_log_) {
      NODELET_FATAL("loop_log: cannot open '%s' for writing", node_.loop_log.c_str());
      throw ParamError("loop_log: cannot open " + node_.loop_log);
    }
    loop_log_ << loopLogHeader() << std::endl;
  }

  // The latest loop's markers again (timer thread): its query frame may have been linked to the
  // fixed frame only by this loop, after rviz dropped the first publication.
  void republishMarkers() {
    if (marker_pub_.getNumSubscribers() == 0) return;
    if (auto markers = latest_loop_markers_.all()) marker_pub_.publish(markers);
  }

  void onDescriptor(const dtif::TrunkDescriptor::ConstPtr& msg, const std::string& robot,
                    const std::string& topic) {
    if (input_watch_) input_watch_->seen(topic, ros::WallTime::now().toSec());
    if (msg->robot != robot) {
      NODELET_WARN_THROTTLE(5.0, "descriptor of robot '%s' on the topic of '%s': dropped",
                            msg->robot.c_str(), robot.c_str());
      return;
    }
    enqueue(msg, false);
  }

  // An earlier submap described again (forward accumulation): queued behind the descriptors
  // already waiting, so that it finds its entry.
  void onDescriptorUpdate(const dtif::TrunkDescriptor::ConstPtr& msg, const std::string& robot) {
    if (msg->robot != robot) {
      NODELET_WARN_THROTTLE(5.0, "descriptor update of robot '%s' on the topic of '%s': dropped",
                            msg->robot.c_str(), robot.c_str());
      return;
    }
    enqueue(msg, true);
  }

  void enqueue(const dtif::TrunkDescriptor::ConstPtr& msg, bool update) {
    if (const std::optional<Queued> dropped = queue_.push(Queued{msg, update})) {
      NODELET_WARN_THROTTLE(5.0, "loop detection is behind: dropping a descriptor of '%s'",
                            dropped->msg->robot.c_str());
    }
  }

  void work() {
    while (std::optional<Queued> q = queue_.pop()) {
      if (q->update) {
        processUpdate(*q->msg);
      } else {
        process(*q->msg);
      }
    }
  }

  // What one query found (filled under db_mutex_, used after it).
  struct QueryResult {
    std::optional<Loop> lc;
    double t_loop_ms = 0.0;
    std::shared_ptr<const Descriptor> candidate;
    std::optional<Meta> candidate_meta;
    /// Beside an own-robot lc: the best loop with another robot
    /// (database/inter_robot_verifications).
    std::optional<Loop> inter_lc;
    std::optional<Meta> inter_meta;
  };

  // Worker thread: convert, query, insert, then publish what was found.
  void process(const dtif::TrunkDescriptor& msg) {
    auto d = std::make_shared<Descriptor>();
    Meta meta;
    if (!convert(msg, d.get(), &meta)) return;
    QueryResult q;
    if (!queryAndInsert(d, meta, &q)) return;
    if (!q.lc) {
      logQuery(msg, *d, std::nullopt, nullptr, q.t_loop_ms);
      return;
    }
    publishLoop(msg, *d, meta, q);
    if (q.inter_lc) sendLoop(msg, *q.inter_lc, q.inter_meta, true);
    if (node_.publish_tf && node_.tf_rate_hz <= 0.0) publishTf();
  }

  // Replaces the entry of an updated descriptor (not queried: its submap was, when it came).
  void processUpdate(const dtif::TrunkDescriptor& msg) {
    auto d = std::make_shared<Descriptor>();
    Meta meta;
    if (!convert(msg, d.get(), &meta)) return;
    std::lock_guard<std::mutex> lock(db_mutex_);
    const Key key(d->robot, d->submap_id);
    if (!index_.count(key) || !detector_->replace(d)) {
      NODELET_DEBUG("update of %s/%ld: no such entry (dropped or not valid): ignored",
                    d->robot.c_str(), static_cast<long>(d->submap_id));
      return;
    }
    index_[key] = d;
  }

  // The message as a retrievable descriptor, or false (logged) when it is malformed or invalid.
  bool convert(const dtif::TrunkDescriptor& msg, Descriptor* d, Meta* meta) {
    std::string error;
    if (!ros_glue::fromMsg(msg, receiver_params_, d, &meta->T_O_S, &error)) {
      NODELET_WARN_THROTTLE(5.0, "descriptor %s/%ld: %s: dropped", msg.robot.c_str(),
                            static_cast<long>(msg.submap_id), error.c_str());
      return false;
    }
    // Keyed by robot: a sender that did not qualify its frame (every stock FAST-LIO2 unit says
    // camera_init) still gets a frame of its own.
    meta->odom_frame = ros_glue::robotFrame(msg.robot, msg.header.frame_id);
    if (!d->valid) {
      NODELET_DEBUG("descriptor %s/%ld is invalid (%s): not queried, not inserted",
                    d->robot.c_str(), static_cast<long>(d->submap_id), d->invalid_reason.c_str());
      return false;
    }
    return true;
  }

  // Queries the database, then inserts d and links the odometry frames of an inter-robot loop.
  // False (logged) when d is already in the database.
  bool queryAndInsert(const std::shared_ptr<const Descriptor>& d, const Meta& meta,
                      QueryResult* q) {
    std::lock_guard<std::mutex> lock(db_mutex_);
    const Key key(d->robot, d->submap_id);
    if (index_.count(key)) {
      NODELET_WARN_THROTTLE(5.0, "descriptor %s/%ld already in the database: dropped",
                            d->robot.c_str(), static_cast<long>(d->submap_id));
      return false;
    }
    const auto t0 = std::chrono::steady_clock::now();
    try {
      q->lc = detector_->query(*d, nullptr, &q->inter_lc);
      q->t_loop_ms = msSince(t0);
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "query of %s/%ld failed: %s", d->robot.c_str(),
                             static_cast<long>(d->submap_id), e.what());
    }
    if (q->lc) {
      const Key c(q->lc->candidate_robot, q->lc->candidate_id);
      auto it = index_.find(c);
      if (it != index_.end()) q->candidate = it->second;
      auto m = meta_.find(c);
      if (m != meta_.end()) q->candidate_meta = m->second;
    }
    if (q->inter_lc) {
      auto m = meta_.find(Key(q->inter_lc->candidate_robot, q->inter_lc->candidate_id));
      if (m != meta_.end()) q->inter_meta = m->second;
    }
    EntryOdometry odometry;
    odometry.odom_frame = meta.odom_frame;
    odometry.T_O_S = meta.T_O_S;
    if (detector_->insert(d, odometry)) {
      index_[key] = d;
      meta_[key] = meta;
    }
    for (const std::optional<Loop>* lc : {&q->lc, &q->inter_lc}) {
      if (*lc) detector_->recordLoop(**lc);  // saved with the database (relocalisation)
    }
    if (q->lc && q->candidate_meta) linkOdometryFrames(*q->lc, *q->candidate_meta, meta);
    if (q->inter_lc && q->inter_meta) linkOdometryFrames(*q->inter_lc, *q->inter_meta, meta);
    return true;
  }

  // An inter-robot loop links the two robots' odometry frames (db_mutex_).
  void linkOdometryFrames(const Loop& lc, const Meta& candidate, const Meta& query) {
    if (lc.candidate_robot == lc.query_robot || candidate.odom_frame.empty() ||
        query.odom_frame.empty()) {
      return;
    }
    if (candidate.odom_frame == query.odom_frame) {  // only when configured so (output_odom_frame)
      NODELET_WARN_THROTTLE(30.0, "robots '%s' and '%s' both publish in frame '%s': no TF",
                            lc.candidate_robot.c_str(), lc.query_robot.c_str(),
                            query.odom_frame.c_str());
      return;
    }
    // T_Oc_Oq = T_Oc_Sc * T_c_q * inverse(T_Oq_Sq): the latest accepted estimate wins.
    const Pose T_Oc_Oq = candidate.T_O_S * lc.T_c_q * query.T_O_S.inverse();
    links_.add(candidate.odom_frame, query.odom_frame, T_Oc_Oq);
  }

  // The loop message, its log row and its markers (worker thread).
  void publishLoop(const dtif::TrunkDescriptor& msg, const Descriptor& d, const Meta& meta,
                   const QueryResult& q) {
    const Loop& lc = *q.lc;
    sendLoop(msg, lc, q.candidate_meta, false);
    logQuery(msg, d, lc, q.candidate.get(), q.t_loop_ms);
    if (!q.candidate) return;
    // Stamp 0: rviz uses the latest transform between odometry frames (as for trunks).
    visualization_msgs::MarkerArray markers =
        ros_glue::loopMarkers(d, *q.candidate, lc, meta.T_O_S, meta.odom_frame, ros::Time());
    if (marker_pub_.getNumSubscribers() > 0) {
      marker_pub_.publish(boost::shared_ptr<const visualization_msgs::MarkerArray>(
          new visualization_msgs::MarkerArray(markers)));
    }
    latest_loop_markers_.add(std::move(markers));
  }

  // A loop on ~loop_closures, logged (worker). inter_robot_extra: the inter-robot loop beside a
  // query's own-robot best loop, for the map merge (it joins the robots); ~loop_log, which
  // scores each query's best loop, does not get it.
  void sendLoop(const dtif::TrunkDescriptor& msg, const Loop& lc,
                const std::optional<Meta>& candidate_meta, bool inter_robot_extra) {
    boost::shared_ptr<dtif::LoopClosure> out(new dtif::LoopClosure(ros_glue::toMsg(lc)));
    out->inter_robot_extra = inter_robot_extra;
    out->header.stamp = msg.header.stamp;
    out->header.frame_id = candidate_meta ? candidate_meta->odom_frame : std::string();
    loop_pub_.publish(boost::shared_ptr<const dtif::LoopClosure>(out));
    NODELET_INFO("%s %s/%ld -> %s/%ld: %d inliers, score %.2f",
                 inter_robot_extra ? "inter-robot loop beside it" : "loop", lc.query_robot.c_str(),
                 static_cast<long>(lc.query_id), lc.candidate_robot.c_str(),
                 static_cast<long>(lc.candidate_id), lc.inliers, lc.score);
  }

  // One row of ~loop_log (worker thread only).
  void logQuery(const dtif::TrunkDescriptor& msg, const Descriptor& d,
                const std::optional<Loop>& lc, const Descriptor* candidate, double t_loop_ms) {
    if (!loop_log_.is_open()) return;
    LoopLogRow r;
    r.query_robot = d.robot;
    r.query_id = d.submap_id;
    r.query_stamp = d.stamp;
    r.query_data_end = msg.data_end.isZero() ? d.stamp : msg.data_end.toSec();
    if (lc) {
      r.accepted = true;
      r.candidate_robot = lc->candidate_robot;
      r.candidate_id = lc->candidate_id;
      r.candidate_stamp = candidate ? candidate->stamp : 0.0;
      r.T_c_q = lc->T_c_q;
      r.inliers = lc->inliers;
      r.score = lc->score;
    }
    r.t_loop_ms = t_loop_ms;
    r.ros_time = ros::Time::now().toSec();
    r.wall_time = ros::WallTime::now().toSec();
    loop_log_ << formatLoopLogRow(r) << std::endl;  // flushed: the run may end any time
    if (!loop_log_) NODELET_ERROR_THROTTLE(30.0, "loop_log: write failed");
  }

  // Publishes RobotLinks' spanning tree of the odometry frames (timer or worker thread).
  void publishTf() {
    std::vector<RobotLinks::Edge> tree;
    {
      std::lock_guard<std::mutex> lock(db_mutex_);
      tree = links_.spanningTree();
    }
    if (tree.empty()) return;
    std::vector<geometry_msgs::TransformStamped> tfs;
    tfs.reserve(tree.size());
    const ros::Time now = ros::Time::now();
    for (const RobotLinks::Edge& e : tree) {
      geometry_msgs::TransformStamped t;
      t.header.stamp = now;
      t.header.frame_id = e.parent;
      t.child_frame_id = e.child;
      t.transform = ros_glue::toTransformMsg(e.T_parent_child);
      tfs.push_back(t);
    }
    if (!tf_broadcaster_) tf_broadcaster_ = std::make_unique<tf2_ros::TransformBroadcaster>();
    tf_broadcaster_->sendTransform(tfs);
  }

  bool loadDatabase(const std::string& path, std::string* message) {
    // Read and checked before the lock: a slow disk never stalls queries and inserts.
    DatabaseContents contents;
    try {
      contents = readDatabaseFile(path);  // throws on a bad file; the database is unchanged
    } catch (const std::exception& e) {
      *message = std::string("load failed, database unchanged: ") + e.what();
      return false;
    }
    std::lock_guard<std::mutex> lock(db_mutex_);
    detector_->replaceContents(std::move(contents));
    // The file's odometry poses (version 2) place loops against the loaded run; entries of
    // version-1 files have none: they keep what this run saw of them, or get no frame.
    index_.clear();
    std::map<Key, Meta> meta;
    for (size_t i = 0; i < detector_->size(); ++i) {
      const auto& e = detector_->entries()[i];
      const Key key(e->robot, e->submap_id);
      index_[key] = e;
      const EntryOdometry& o = detector_->odometry(i);
      if (o.known()) {
        meta[key] = Meta{o.T_O_S, o.odom_frame};
      } else if (meta_.count(key)) {
        meta[key] = meta_[key];
      }
    }
    meta_ = std::move(meta);
    *message = "loaded " + std::to_string(detector_->size()) + " descriptors from " + path;
    return true;
  }

  bool onSave(dtif::SaveDatabase::Request& req, dtif::SaveDatabase::Response& res) {
    std::lock_guard<std::mutex> lock(db_mutex_);
    res.size = detector_->size();
    if (req.path.empty()) {
      res.success = false;
      res.message = "empty path";
      return true;
    }
    try {
      detector_->save(req.path);
      res.success = true;
      res.message = "saved " + std::to_string(res.size) + " descriptors to " + req.path;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("save failed: ") + e.what();
      NODELET_ERROR("%s", res.message.c_str());
    }
    return true;
  }

  bool onLoad(dtif::LoadDatabase::Request& req, dtif::LoadDatabase::Response& res) {
    res.success = loadDatabase(req.path, &res.message);
    if (!res.success) NODELET_ERROR("%s", res.message.c_str());
    std::lock_guard<std::mutex> lock(db_mutex_);
    res.size = detector_->size();
    return true;
  }

  bool onSize(dtif::GetDatabaseSize::Request&, dtif::GetDatabaseSize::Response& res) {
    std::lock_guard<std::mutex> lock(db_mutex_);
    res.size = detector_->size();
    std::map<std::string, uint64_t> per_robot;
    for (const auto& e : detector_->entries()) ++per_robot[e->robot];
    for (const auto& p : per_robot) {
      res.robots.push_back(p.first);
      res.per_robot.push_back(p.second);
    }
    return true;
  }

  ros_glue::LoopClosureNodeParams node_;

  // This nodelet builds no descriptors: each keeps the validity its sender gave it, down to
  // what the matcher can use.
  const DescriptorParams receiver_params_ = loosestDescriptorParams();

  std::mutex db_mutex_;  // detector_, index_, meta_, links_
  std::unique_ptr<LoopDetector> detector_;
  std::map<Key, std::shared_ptr<const Descriptor>> index_;
  std::map<Key, Meta> meta_;
  RobotLinks links_;  // odometry frames linked by inter-robot loops

  struct Queued {
    dtif::TrunkDescriptor::ConstPtr msg;
    bool update = false;  ///< a forward update of a stored entry
  };
  ros_glue::BoundedQueue<Queued> queue_;  // capacity node_.queue_size (onInit)
  std::thread worker_;

  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_broadcaster_;
  ros_glue::RecentMarkers latest_loop_markers_{1};  // the latest loop's
  ros::WallTimer marker_timer_;
  ros::Publisher loop_pub_, marker_pub_;
  std::vector<ros::Subscriber> subs_;
  ros::ServiceServer save_srv_, load_srv_, size_srv_;
  ros::WallTimer tf_timer_;
  std::unique_ptr<ros_glue::InputWatch> input_watch_;
  ros::WallTimer input_timer_;
  std::ofstream loop_log_;  // worker thread only
};

}  // namespace dtif

PLUGINLIB_EXPORT_CLASS(dtif::LoopClosureNodelet, nodelet::Nodelet)
