// The core's rosbag writer (ROS-free) read back with rosbag's own C++ API: topics, types, MD5
// sums and definitions of the installed messages, counts, time order, exact field values, and
// the index (chunk infos) checked by an independent parser of the file. Then the simulator's
// bag sink on a shortened tiny scene, replayed through the nodelet's submap assembler.
#include "dtif/bag/rosbag_writer.h"

#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <tuple>

#include "dtif/bag/sim_bag.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/submap_assembler.h"
#include "dtif/sim/simulator.h"
#include "dtif_test/test_config.h"
#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
  return test::freshTempDir("dtif_rosbag_writer_test_" + name);
}

using test::makePose;

ros::Time toRos(bag::Time t) { return ros::Time(t.sec, t.nsec); }

template <class Msg>
void expectConnectionOf(const rosbag::ConnectionInfo& c) {
  EXPECT_EQ(c.datatype, ros::message_traits::DataType<Msg>::value()) << c.topic;
  EXPECT_EQ(c.md5sum, ros::message_traits::MD5Sum<Msg>::value()) << c.topic;
  EXPECT_EQ(c.msg_def, ros::message_traits::Definition<Msg>::value()) << c.topic;
}

void expectPose(const geometry_msgs::Point& p, const geometry_msgs::Quaternion& q, const Pose& T) {
  const Eigen::Quaterniond e(T.rotation());
  EXPECT_EQ(p.x, T.translation().x());
  EXPECT_EQ(p.y, T.translation().y());
  EXPECT_EQ(p.z, T.translation().z());
  EXPECT_EQ(q.x, e.x());
  EXPECT_EQ(q.y, e.y());
  EXPECT_EQ(q.z, e.z());
  EXPECT_EQ(q.w, e.w());
}

// ---------------------------------------------------------------------------------------------
// An independent reader of the records (http://wiki.ros.org/Bags/Format/2.0), for what rosbag's
// C++ API does not expose: the bag header, chunk infos and the order inside each connection.
struct Record {
  std::map<std::string, std::string> header;
  std::string data;
  uint64_t pos = 0;
  uint8_t op() const { return static_cast<uint8_t>(header.at("op").at(0)); }
  template <class T>
  T get(const std::string& name) const {
    const std::string& v = header.at(name);
    EXPECT_EQ(v.size(), sizeof(T)) << name;
    T x{};
    std::memcpy(&x, v.data(), std::min(v.size(), sizeof(T)));
    return x;
  }
};

uint32_t u32(const std::string& s, size_t at) {
  uint32_t v = 0;
  std::memcpy(&v, s.data() + at, 4);
  return v;
}

std::map<std::string, std::string> parseFields(const std::string& s) {
  std::map<std::string, std::string> m;
  for (size_t i = 0; i + 4 <= s.size();) {
    const uint32_t n = u32(s, i);
    const std::string f = s.substr(i + 4, n);
    const size_t eq = f.find('=');
    m[f.substr(0, eq)] = f.substr(eq + 1);
    i += 4 + n;
  }
  return m;
}

// The record at *at in buf; advances *at.
Record readRecord(const std::string& buf, size_t* at) {
  Record r;
  r.pos = *at;
  const uint32_t hl = u32(buf, *at);
  r.header = parseFields(buf.substr(*at + 4, hl));
  const uint32_t dl = u32(buf, *at + 4 + hl);
  r.data = buf.substr(*at + 8 + hl, dl);
  *at += 8 + hl + dl;
  return r;
}

uint64_t timeNs(const std::string& bytes8) {
  return uint64_t{u32(bytes8, 0)} * 1000000000ull + u32(bytes8, 4);
}

struct ParsedBag {
  uint32_t header_record_size = 0;
  uint32_t chunks = 0, connections = 0;
  uint64_t messages = 0;
  bool chunk_infos_match = true;          // start/end/counts/pos agree with the chunks' contents
  bool connections_in_time_order = true;  // what Python's rosbag assumes
  std::set<uint32_t> connection_ids;
};

ParsedBag parseBag(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  const std::string buf((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ParsedBag p;
  EXPECT_EQ(buf.substr(0, 13), "#ROSBAG V2.0\n");
  size_t at = 13;
  const Record bh = readRecord(buf, &at);
  EXPECT_EQ(bh.op(), 0x03);
  p.header_record_size = static_cast<uint32_t>(at - 13);
  const auto index_pos = bh.get<uint64_t>("index_pos");
  p.chunks = bh.get<uint32_t>("chunk_count");
  p.connections = bh.get<uint32_t>("conn_count");
  struct Seen {
    uint64_t start = UINT64_MAX, end = 0;
    std::map<uint32_t, uint32_t> counts;
  };
  std::map<uint64_t, Seen> seen;  // by chunk position
  std::map<uint32_t, uint64_t> last_time;
  while (at < index_pos) {
    const Record chunk = readRecord(buf, &at);
    EXPECT_EQ(chunk.op(), 0x05);
    EXPECT_EQ(chunk.header.at("compression"), "none");
    EXPECT_EQ(chunk.get<uint32_t>("size"), chunk.data.size());
    Seen& s = seen[chunk.pos];
    std::map<uint32_t, std::map<uint32_t, uint64_t>> by_offset;  // conn -> offset -> time
    for (size_t c = 0; c < chunk.data.size();) {
      const size_t offset = c;
      const Record r = readRecord(chunk.data, &c);
      if (r.op() == 0x07) continue;  // connection record
      EXPECT_EQ(r.op(), 0x02);
      const uint64_t t = timeNs(r.header.at("time"));
      s.start = std::min(s.start, t);
      s.end = std::max(s.end, t);
      by_offset[r.get<uint32_t>("conn")][static_cast<uint32_t>(offset)] = t;
      ++p.messages;
    }
    // Index data records: one per connection of the chunk, each entry pointing at its message.
    for (size_t i = 0; i < by_offset.size(); ++i) {
      const Record ix = readRecord(buf, &at);
      EXPECT_EQ(ix.op(), 0x04);
      EXPECT_EQ(ix.get<uint32_t>("ver"), 1u);
      const auto conn = ix.get<uint32_t>("conn");
      const auto count = ix.get<uint32_t>("count");
      EXPECT_EQ(ix.data.size(), 12u * count);
      EXPECT_EQ(count, by_offset[conn].size());
      s.counts[conn] = count;
      for (uint32_t k = 0; k < count; ++k) {
        const uint64_t t = timeNs(ix.data.substr(12 * k, 8));
        const uint32_t off = u32(ix.data, 12 * k + 8);
        EXPECT_EQ(by_offset[conn].count(off), 1u) << "index entry points at no message";
        if (by_offset[conn].count(off)) {
          EXPECT_EQ(by_offset[conn][off], t);
        }
        if (last_time.count(conn) && t < last_time[conn]) p.connections_in_time_order = false;
        last_time[conn] = t;
      }
    }
  }
  EXPECT_EQ(at, index_pos);
  for (uint32_t i = 0; i < p.connections; ++i) {
    const Record c = readRecord(buf, &at);
    EXPECT_EQ(c.op(), 0x07);
    p.connection_ids.insert(c.get<uint32_t>("conn"));
  }
  for (uint32_t i = 0; i < p.chunks; ++i) {
    const Record ci = readRecord(buf, &at);
    EXPECT_EQ(ci.op(), 0x06);
    const auto pos = ci.get<uint64_t>("chunk_pos");
    if (!seen.count(pos)) {
      p.chunk_infos_match = false;
      continue;
    }
    const Seen& s = seen[pos];
    std::map<uint32_t, uint32_t> counts;
    for (uint32_t k = 0; k < ci.get<uint32_t>("count"); ++k) {
      counts[u32(ci.data, 8 * k)] = u32(ci.data, 8 * k + 4);
    }
    p.chunk_infos_match = p.chunk_infos_match && timeNs(ci.header.at("start_time")) == s.start &&
                          timeNs(ci.header.at("end_time")) == s.end && counts == s.counts;
  }
  EXPECT_EQ(at, buf.size());
  EXPECT_EQ(seen.size(), p.chunks);
  return p;
}

// ---------------------------------------------------------------------------------------------

struct Written {
  std::string topic, callerid;
  bag::Time time;
  uint32_t seq = 0;
  std::string frame_id, child_frame_id;
  Pose T = Pose::Identity();
  std::vector<Eigen::Vector3f> points;
  std::vector<float> intensity;
  std::tuple<uint64_t, std::string, uint32_t> key() const {
    return {uint64_t{time.sec} * 1000000000ull + time.nsec, topic, seq};
  }
};

Written writtenAs(const std::string& topic, const std::string& callerid, bag::Time time,
                  uint32_t seq, const std::string& frame_id, const std::string& child_frame_id,
                  const Pose& T) {
  Written w;
  w.topic = topic;
  w.callerid = callerid;
  w.time = time;
  w.seq = seq;
  w.frame_id = frame_id;
  w.child_frame_id = child_frame_id;
  w.T = T;
  return w;
}

TEST(RosbagWriter, RoundTripThroughRosbagCpp) {
  const fs::path dir = tempDir("roundtrip");
  const std::string path = (dir / "test.bag").string();
  bag::RosbagWriterParams params;
  params.chunk_bytes = 8 * 1024;  // many chunks
  bag::RosbagWriter writer(path, params);

  std::mt19937 rng(7);
  std::uniform_real_distribution<float> coord(-50.0f, 50.0f), refl(0.0f, 255.0f);
  std::uniform_real_distribution<double> small(-0.3, 0.3);
  std::vector<Written> written;
  const double t0 = 1700000000.0;
  // Robot a's whole run first, then robot b's, whose stamps fall between a's: out of order
  // across robots; /tf (one caller for both) also goes back in time within one connection.
  for (const std::string robot : {"a", "b"}) {
    const double offset = robot == "a" ? 0.0 : 0.05;
    for (uint32_t i = 0; i < 25; ++i) {
      const bag::Time stamp = bag::Time::fromSec(t0 + offset + 0.1 * i);
      const Pose T = makePose(0.5 * i, small(rng), small(rng), small(rng), small(rng), 0.2 * i);
      const Written odom = writtenAs("/" + robot + "/Odometry", "/" + robot + "/lio", stamp, i,
                                     robot + "/odom", robot + "/base_link", T);
      const Written tf =
          writtenAs("/tf", params.callerid, stamp, 0, robot + "/odom", robot + "/base_link", T);
      Written cloud = writtenAs("/" + robot + "/cloud_registered", odom.callerid, stamp, i,
                                robot + "/odom", "", Pose::Identity());
      const size_t n = i == 3 ? 0 : 100 + 10 * i;  // one empty cloud
      for (size_t k = 0; k < n; ++k) {
        cloud.points.emplace_back(coord(rng), coord(rng), coord(rng));
        cloud.intensity.push_back(refl(rng));
      }
      std::string data;
      bag::Odometry o;
      o.header = {odom.seq, odom.time, odom.frame_id};
      o.child_frame_id = odom.child_frame_id;
      o.T_frame_child = odom.T;
      bag::serializeOdometry(o, &data);
      writer.write(odom.topic, bag::MessageType::kOdometry, odom.time, data, odom.callerid);
      data.clear();
      bag::TransformStamped t;
      t.header = {0, tf.time, tf.frame_id};
      t.child_frame_id = tf.child_frame_id;
      t.T_frame_child = tf.T;
      bag::serializeTfMessage({t}, &data);
      writer.write("/tf", bag::MessageType::kTfMessage, tf.time, data);
      data.clear();
      bag::serializePointCloud2({cloud.seq, cloud.time, cloud.frame_id}, cloud.points,
                                cloud.intensity, &data);
      writer.write(cloud.topic, bag::MessageType::kPointCloud2, cloud.time, data, cloud.callerid);
      written.push_back(odom);
      written.push_back(tf);
      written.push_back(cloud);
    }
  }
  EXPECT_THROW(writer.write("/tf", bag::MessageType::kOdometry, bag::Time::fromSec(t0), ""),
               bag::RosbagError);
  EXPECT_FALSE(fs::exists(path)) << "written to the temporary file until close()";
  EXPECT_TRUE(fs::exists(path + ".tmp"));
  writer.close();
  EXPECT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path + ".tmp"));
  EXPECT_EQ(writer.messages(), written.size());
  EXPECT_EQ(writer.bytesWritten(), fs::file_size(path));

  const ParsedBag parsed = parseBag(path);
  EXPECT_EQ(parsed.header_record_size, 4096u + 8u);
  EXPECT_GT(parsed.chunks, 5u);
  EXPECT_EQ(parsed.messages, written.size());
  EXPECT_TRUE(parsed.chunk_infos_match);
  EXPECT_TRUE(parsed.connections_in_time_order);
  // 2 robots x (Odometry, cloud_registered) + /tf, whose going back in time opened a second one.
  EXPECT_EQ(parsed.connections, 6u);
  EXPECT_EQ(parsed.connection_ids.size(), 6u);

  rosbag::Bag b;
  b.open(path, rosbag::bagmode::Read);
  rosbag::View view(b);
  std::set<std::string> topics;
  for (const rosbag::ConnectionInfo* c : view.getConnections()) {
    topics.insert(c->topic);
    ASSERT_TRUE(c->header);
    EXPECT_EQ(c->header->at("latching"), "0");
    EXPECT_EQ(c->header->at("topic"), c->topic);
    if (c->topic == "/tf") {
      EXPECT_EQ(c->header->at("callerid"), "/dtif_simulate");
      expectConnectionOf<tf2_msgs::TFMessage>(*c);
    } else {
      EXPECT_EQ(c->header->at("callerid"), "/" + c->topic.substr(1, 1) + "/lio");
      if (c->topic.find("Odometry") != std::string::npos) {
        expectConnectionOf<nav_msgs::Odometry>(*c);
      } else {
        expectConnectionOf<sensor_msgs::PointCloud2>(*c);
      }
    }
  }
  EXPECT_EQ(topics, (std::set<std::string>{"/a/Odometry", "/a/cloud_registered", "/b/Odometry",
                                           "/b/cloud_registered", "/tf"}));
  EXPECT_EQ(view.size(), written.size());
  EXPECT_EQ(view.getBeginTime(), toRos(bag::Time::fromSec(t0)));
  EXPECT_EQ(view.getEndTime(), toRos(bag::Time::fromSec(t0 + 0.05 + 2.4)));

  std::sort(written.begin(), written.end(),
            [](const Written& a, const Written& b) { return a.key() < b.key(); });
  std::vector<Written> read;
  ros::Time last(0, 0);
  for (const rosbag::MessageInstance& m : view) {
    EXPECT_GE(m.getTime(), last) << "View not in time order";
    last = m.getTime();
    Written r;
    r.topic = m.getTopic();
    r.callerid = m.getCallerId();
    r.time = {m.getTime().sec, m.getTime().nsec};
    if (auto o = m.instantiate<nav_msgs::Odometry>()) {
      r.seq = o->header.seq;
      ASSERT_EQ(o->header.stamp, m.getTime());
      r.frame_id = o->header.frame_id;
      r.child_frame_id = o->child_frame_id;
      const auto it = std::find_if(written.begin(), written.end(),
                                   [&](const Written& w) { return w.key() == r.key(); });
      ASSERT_NE(it, written.end());
      expectPose(o->pose.pose.position, o->pose.pose.orientation, it->T);
      for (double v : o->pose.covariance) EXPECT_EQ(v, 0.0);
      for (double v : o->twist.covariance) EXPECT_EQ(v, 0.0);
      EXPECT_EQ(o->twist.twist.linear.x, 0.0);
      EXPECT_EQ(o->twist.twist.angular.z, 0.0);
      r.T = it->T;
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      ASSERT_EQ(tf->transforms.size(), 1u);
      const auto& t = tf->transforms[0];
      r.seq = t.header.seq;
      ASSERT_EQ(t.header.stamp, m.getTime());
      r.frame_id = t.header.frame_id;
      r.child_frame_id = t.child_frame_id;
      const auto it = std::find_if(written.begin(), written.end(), [&](const Written& w) {
        return w.key() == r.key() && w.frame_id == r.frame_id;
      });
      ASSERT_NE(it, written.end());
      geometry_msgs::Point p;
      p.x = t.transform.translation.x;
      p.y = t.transform.translation.y;
      p.z = t.transform.translation.z;
      expectPose(p, t.transform.rotation, it->T);
      r.T = it->T;
    } else if (auto c = m.instantiate<sensor_msgs::PointCloud2>()) {
      r.seq = c->header.seq;
      ASSERT_EQ(c->header.stamp, m.getTime());
      r.frame_id = c->header.frame_id;
      EXPECT_EQ(c->height, 1u);
      ASSERT_EQ(c->fields.size(), 4u);
      const char* names[] = {"x", "y", "z", "intensity"};
      for (uint32_t f = 0; f < 4; ++f) {
        EXPECT_EQ(c->fields[f].name, names[f]);
        EXPECT_EQ(c->fields[f].offset, 4 * f);
        EXPECT_EQ(c->fields[f].datatype, sensor_msgs::PointField::FLOAT32);
        EXPECT_EQ(c->fields[f].count, 1u);
      }
      EXPECT_FALSE(c->is_bigendian);
      EXPECT_TRUE(c->is_dense);
      EXPECT_EQ(c->point_step, 16u);
      EXPECT_EQ(c->row_step, 16u * c->width);
      ASSERT_EQ(c->data.size(), 16u * c->width);
      for (uint32_t k = 0; k < c->width; ++k) {
        float v[4];
        std::memcpy(v, &c->data[16 * k], 16);
        r.points.emplace_back(v[0], v[1], v[2]);
        r.intensity.push_back(v[3]);
      }
    } else {
      ADD_FAILURE() << "unknown type " << m.getDataType();
    }
    read.push_back(r);
  }
  ASSERT_EQ(read.size(), written.size());
  // Equal times may come in any order: compare sorted by (time, topic, seq) (plus frame for /tf).
  const auto order = [](const Written& a, const Written& b) {
    return std::tie(a.time.sec, a.time.nsec, a.topic, a.seq, a.frame_id) <
           std::tie(b.time.sec, b.time.nsec, b.topic, b.seq, b.frame_id);
  };
  std::sort(read.begin(), read.end(), order);
  std::sort(written.begin(), written.end(), order);
  for (size_t i = 0; i < read.size(); ++i) {
    const Written &r = read[i], &w = written[i];
    EXPECT_EQ(r.topic, w.topic);
    EXPECT_EQ(r.callerid, w.callerid) << r.topic;
    EXPECT_EQ(r.time, w.time);
    EXPECT_EQ(r.seq, w.seq);
    EXPECT_EQ(r.frame_id, w.frame_id);
    EXPECT_EQ(r.child_frame_id, w.child_frame_id);
    EXPECT_EQ(r.points, w.points) << r.topic << " " << r.seq;
    EXPECT_EQ(r.intensity, w.intensity);
  }
  b.close();
}

TEST(RosbagWriter, EmptyBagIsReadable) {
  const fs::path dir = tempDir("empty");
  const std::string path = (dir / "empty.bag").string();
  bag::RosbagWriter writer(path);
  writer.close();
  const ParsedBag parsed = parseBag(path);
  EXPECT_EQ(parsed.chunks, 0u);
  EXPECT_EQ(parsed.connections, 0u);
  rosbag::Bag b;
  b.open(path, rosbag::bagmode::Read);
  rosbag::View view(b);
  EXPECT_EQ(view.size(), 0u);
}

// ---------------------------------------------------------------------------------------------
// The simulator's bag sink on the tiny scene, shortened: every frame's messages, with the frame's
// stamp, odometry pose and points, and a replay through the nodelet's submap assembler.

struct Tee : sim::FrameSink {
  std::vector<sim::FrameSink*> sinks;
  std::vector<sim::Frame> frames;  // points kept for the first 20 frames only
  std::vector<size_t> point_counts;
  void onFrame(const sim::Frame& f) override {
    for (sim::FrameSink* s : sinks) s->onFrame(f);
    frames.push_back(f);
    point_counts.push_back(f.points.size());
    if (frames.size() > 20) {
      frames.back().points.clear();
      frames.back().intensity.clear();
    }
  }
};

TEST(SimulateBag, FramesRoundTripAndAssembleIntoSubmaps) {
  sim::SceneParams scene =
      sim::loadSceneYaml(std::string(DTIF_SCENES_DIR) + "/tiny.yaml");  // a fast version of it:
  scene.sensor.points_per_s = 8000;
  scene.robots[0].waypoints = {{5, 4}, {22, 4}, {22, 16}};
  scene.robots[1].waypoints = {{60, 11}, {35, 9}};
  const fs::path dir = tempDir("simulate");
  sim::BagFrameSink raw((dir / "raw.bag").string());  // default: every return
  sim::BagParams voxel_params;
  voxel_params.voxel_m = 0.1;
  sim::BagFrameSink voxel((dir / "voxel.bag").string(), voxel_params);
  Tee tee;
  tee.sinks = {&raw, &voxel};
  const sim::DatasetRunResult result =
      sim::simulateDataset(scene, 3, (dir / "dataset").string(), &tee, "", 2);
  raw.close();
  voxel.close();
  ASSERT_GT(tee.frames.size(), 200u);
  EXPECT_EQ(raw.stats().frames, tee.frames.size());
  EXPECT_EQ(raw.stats().messages, 3 * tee.frames.size());
  EXPECT_EQ(raw.stats().points_out, raw.stats().points_in);
  EXPECT_LT(voxel.stats().points_out, voxel.stats().points_in);
  EXPECT_GT(voxel.stats().points_out, voxel.stats().points_in / 2);
  EXPECT_LT(fs::file_size(dir / "voxel.bag"), fs::file_size(dir / "raw.bag"));
  EXPECT_EQ(raw.stats().bytes, fs::file_size(dir / "raw.bag"));

  const ParsedBag parsed = parseBag((dir / "raw.bag").string());
  EXPECT_TRUE(parsed.chunk_infos_match);
  EXPECT_TRUE(parsed.connections_in_time_order);
  EXPECT_EQ(parsed.connections, 6u);  // per robot: cloud_registered, Odometry, /tf

  // Frames by (robot, stamp).
  std::map<std::pair<std::string, ros::Time>, size_t> frames;  // -> index in tee.frames
  for (size_t i = 0; i < tee.frames.size(); ++i) {
    frames[{tee.frames[i].robot, ros::Time(tee.frames[i].stamp)}] = i;
  }
  ASSERT_EQ(frames.size(), tee.frames.size());

  rosbag::Bag b;
  b.open((dir / "raw.bag").string(), rosbag::bagmode::Read);
  rosbag::View view(b);
  EXPECT_EQ(view.size(), 3 * tee.frames.size());
  std::map<std::string, size_t> counts;
  std::map<std::string, ros_glue::SubmapAssembler> assemblers;
  std::map<std::string, size_t> submaps, bad_status;
  size_t points_compared = 0;
  ros::Time last(0, 0);
  for (const rosbag::MessageInstance& m : view) {
    EXPECT_GE(m.getTime(), last);
    last = m.getTime();
    ++counts[m.getTopic()];
    if (auto o = m.instantiate<nav_msgs::Odometry>()) {
      const std::string robot = o->header.frame_id.substr(0, o->header.frame_id.find('/'));
      EXPECT_EQ(m.getTopic(), "/" + robot + "/Odometry");
      EXPECT_EQ(m.getCallerId(), "/" + robot + "/dtif_simulate");
      EXPECT_EQ(o->header.frame_id, robot + "/odom");
      EXPECT_EQ(o->child_frame_id, robot + "/base_link");
      EXPECT_EQ(m.getTime(), o->header.stamp);
      const auto it = frames.find({robot, o->header.stamp});
      ASSERT_NE(it, frames.end());
      expectPose(o->pose.pose.position, o->pose.pose.orientation, tee.frames[it->second].T_O_B);
      Pose T_O_B;
      ASSERT_TRUE(ros_glue::fromMsg(o->pose.pose, &T_O_B));
      auto [a, added] = assemblers.try_emplace(robot, ros_glue::SubmapAssemblerParams{});
      if (a->second.addOdometry(o->header.stamp.toSec(), T_O_B) !=
          ros_glue::SubmapAssembler::Status::kOk) {
        ++bad_status[robot];
      }
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      ASSERT_EQ(tf->transforms.size(), 1u);
      const auto& t = tf->transforms[0];
      const std::string robot = t.header.frame_id.substr(0, t.header.frame_id.find('/'));
      EXPECT_EQ(m.getTopic(), "/tf");
      EXPECT_EQ(t.header.frame_id, robot + "/odom");
      EXPECT_EQ(t.child_frame_id, robot + "/base_link");
      const auto it = frames.find({robot, t.header.stamp});
      ASSERT_NE(it, frames.end());
      geometry_msgs::Point p;
      p.x = t.transform.translation.x;
      p.y = t.transform.translation.y;
      p.z = t.transform.translation.z;
      expectPose(p, t.transform.rotation, tee.frames[it->second].T_O_B);
    } else if (auto c = m.instantiate<sensor_msgs::PointCloud2>()) {
      const std::string robot = c->header.frame_id.substr(0, c->header.frame_id.find('/'));
      EXPECT_EQ(m.getTopic(), "/" + robot + "/cloud_registered");
      EXPECT_EQ(c->header.frame_id, robot + "/odom");
      EXPECT_GT(m.getTime(), c->header.stamp) << "recorded after its odometry";
      const auto it = frames.find({robot, c->header.stamp});
      ASSERT_NE(it, frames.end());
      const sim::Frame& f = tee.frames[it->second];
      ASSERT_EQ(c->width, tee.point_counts[it->second]);
      if (!f.points.empty()) {
        for (uint32_t k = 0; k < c->width; ++k) {
          float v[4];
          std::memcpy(v, &c->data[16 * k], 16);
          ASSERT_EQ(Eigen::Vector3f(v[0], v[1], v[2]), f.points[k]);
          ASSERT_EQ(v[3], f.intensity[k]);
          ++points_compared;
        }
      }
      Cloud cloud;
      ASSERT_TRUE(ros_glue::fromMsg(*c, &cloud));
      std::optional<ros_glue::AssembledSubmap> done;
      auto [a, added] = assemblers.try_emplace(robot, ros_glue::SubmapAssemblerParams{});
      if (a->second.addCloud(c->header.stamp.toSec(), cloud, &done) !=
          ros_glue::SubmapAssembler::Status::kOk) {
        ++bad_status[robot];
      }
      if (done) ++submaps[robot];
    }
  }
  EXPECT_GT(points_compared, 1000u);
  std::map<std::string, size_t> frames_per_robot;
  for (const sim::Frame& f : tee.frames) ++frames_per_robot[f.robot];
  size_t assembled = 0;
  for (const auto& [robot, n] : frames_per_robot) {
    EXPECT_EQ(counts["/" + robot + "/Odometry"], n);
    EXPECT_EQ(counts["/" + robot + "/cloud_registered"], n);
    EXPECT_EQ(bad_status[robot], 0u) << robot;
    assembled += submaps[robot];
  }
  EXPECT_EQ(counts["/tf"], tee.frames.size());
  // The simulator's submaps are whole 10 s windows; the assembler cuts the same windows and
  // closes each at its last cloud, so it makes as many.
  EXPECT_EQ(assembled, result.stats.submaps);
  EXPECT_GE(assembled, 4u);
}

}  // namespace
}  // namespace dtif
