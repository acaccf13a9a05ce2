// The simulator's bag sink: per-frame cloud reduction, parameters, frame names, the file
// (temporary until close(), errors naming it), and its bags read back with rosbag::View: topics,
// types, MD5 sums and definitions of the generated messages, connection headers, counts, time
// order, exact values, LZ4 chunks; then a shortened tiny scene's bag replayed through the
// nodelet's submap assembler. (rosbag_storage writes the file format itself: not tested here.)
#include "dtif/bag/sim_bag.h"

#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <tuple>

#include "dtif/ros/conversions.h"
#include "dtif/ros/submap_assembler.h"
#include "dtif_test/test_config.h"
#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
  return test::freshTempDir("dtif_sim_bag_test_" + name);
}

TEST(SimBag, VoxelFilterAveragesPerVoxelInFirstSeenOrder) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<Eigen::Vector3f> pts = {
      {0.1f, 0.1f, 0.1f},  {2.5f, 0.0f, 0.0f}, {0.3f, 0.5f, 0.9f},   // voxels A, B, A
      {-0.5f, 0.2f, 0.2f}, {nan, 0.0f, 0.0f},  {0.9f, 0.9f, 0.2f}};  // C (x < 0), dropped, A
  const std::vector<float> in = {10, 20, 30, 40, 50, 80};
  std::vector<Eigen::Vector3f> out;
  std::vector<float> out_i;
  sim::voxelFilter(pts, in, 1.0, &out, &out_i);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_TRUE(out[0].isApprox(Eigen::Vector3f(1.3f / 3, 1.5f / 3, 1.2f / 3), 1e-6f));
  EXPECT_TRUE(out[1].isApprox(Eigen::Vector3f(2.5f, 0, 0)));
  EXPECT_TRUE(out[2].isApprox(Eigen::Vector3f(-0.5f, 0.2f, 0.2f)));
  EXPECT_FLOAT_EQ(out_i[0], 40.0f);
  EXPECT_FLOAT_EQ(out_i[1], 20.0f);
  EXPECT_FLOAT_EQ(out_i[2], 40.0f);

  // Far from the origin the centroid stays exact (sums relative to the voxel's first point;
  // float steps are 1/32 m at 5e5 m).
  const Eigen::Vector3f far(500000.0f, 0.0f, 0.0f), step(0.03125f, 0.0f, 0.0f);
  sim::voxelFilter({far, far + step, far + 2 * step}, {}, 1.0, &out, &out_i);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].x(), 500000.03125f);
  EXPECT_EQ(out_i, std::vector<float>{0.0f});  // no intensities: zeros

  // voxel 0: a copy without the NaN point.
  sim::voxelFilter(pts, in, 0.0, &out, &out_i);
  ASSERT_EQ(out.size(), 5u);
  EXPECT_EQ(out[3], pts[3]);
  EXPECT_EQ(out[4], pts[5]);
  EXPECT_EQ(out_i, (std::vector<float>{10, 20, 30, 40, 80}));

  sim::voxelFilter({}, {}, 0.1, &out, &out_i);
  EXPECT_TRUE(out.empty());
  EXPECT_TRUE(out_i.empty());
}

TEST(SimBag, ThinEvenlyKeepsSpreadIndices) {
  std::vector<Eigen::Vector3f> p;
  std::vector<float> in;
  for (int i = 0; i < 10; ++i) {
    p.emplace_back(static_cast<float>(i), 0.0f, 0.0f);
    in.push_back(static_cast<float>(100 + i));
  }
  auto q = p;
  auto qi = in;
  sim::thinEvenly(4, &q, &qi);  // floor(i * 10 / 4) = 0, 2, 5, 7
  ASSERT_EQ(q.size(), 4u);
  EXPECT_EQ(q[1].x(), 2.0f);
  EXPECT_EQ(q[2].x(), 5.0f);
  EXPECT_EQ(q[3].x(), 7.0f);
  EXPECT_EQ(qi, (std::vector<float>{100, 102, 105, 107}));
  q = p;
  sim::thinEvenly(0, &q, &qi);  // no limit
  EXPECT_EQ(q.size(), 10u);
  sim::thinEvenly(10, &q, &qi);
  EXPECT_EQ(q, p);
}

TEST(SimBag, ParamsValidateAndFrameNames) {
  EXPECT_EQ(sim::BagParams{}.validate(), "");
  sim::BagParams p;
  p.voxel_m = -1.0;
  p.node = "a/b";
  EXPECT_NE(p.validate().find("voxel_m"), std::string::npos);
  EXPECT_NE(p.validate().find("node"), std::string::npos);
  EXPECT_THROW(sim::BagFrameSink((tempDir("params") / "x.bag").string(), p), bag::RosbagError);
  EXPECT_FALSE(fs::exists(tempDir("params") / "x.bag.tmp"));
  sim::BagParams q;
  q.chunk_bytes = 0;
  q.compression = "zip";
  EXPECT_NE(q.validate().find("chunk_bytes"), std::string::npos);
  EXPECT_NE(q.validate().find("compression"), std::string::npos);
  q = sim::BagParams{};
  q.compression = "lz4";
  EXPECT_EQ(q.validate(), "");
  EXPECT_EQ(sim::odomFrame("alpha"), "alpha/odom");
  EXPECT_EQ(sim::bodyFrame("alpha"), "alpha/base_link");
}

// ---------------------------------------------------------------------------------------------
// The file: written as `path`.tmp, renamed by close(), removed when the sink is destroyed
// without close(); errors name the file.

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const bag::RosbagError& e) {
    return e.what();
  }
  return "";
}

sim::Frame testFrame(const std::string& robot, double stamp) {
  sim::Frame f;
  f.robot = robot;
  f.stamp = stamp;
  f.points = {{1.0f, 2.0f, 3.0f}, {4.0f, 5.0f, 6.0f}};
  f.intensity = {7.0f, 8.0f};
  f.T_O_B = test::makePose(1.0, 2.0, 0.5, 0.1, -0.2, 0.3);
  return f;
}

TEST(SimBagFile, RenamedOnCloseAbandonedWithoutClose) {
  const fs::path dir = tempDir("files");
  const std::string path = (dir / "a.bag").string();
  {
    sim::BagFrameSink sink(path);
    sink.onFrame(testFrame("r", 10.0));
    EXPECT_TRUE(fs::exists(path + ".tmp"));
    EXPECT_FALSE(fs::exists(path));
  }  // destroyed without close(): no bag, no temporary file
  EXPECT_FALSE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path + ".tmp"));

  sim::BagFrameSink sink(path);
  sink.close();
  EXPECT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path + ".tmp"));
  EXPECT_EQ(sink.stats().bytes, fs::file_size(path));
  std::ifstream in(path, std::ios::binary);
  std::string magic(13, '\0');
  in.read(magic.data(), 13);
  EXPECT_EQ(magic, "#ROSBAG V2.0\n");
  EXPECT_NE(errorOf([&] { sink.close(); }), "");
  EXPECT_NE(errorOf([&] { sink.onFrame(testFrame("r", 10.0)); }), "");

  // An empty bag is readable.
  rosbag::Bag b;
  b.open(path, rosbag::bagmode::Read);
  rosbag::View view(b);
  EXPECT_EQ(view.size(), 0u);
}

TEST(SimBagFile, ErrorsNameTheFile) {
  const fs::path dir = tempDir("errors");
  const std::string missing = (dir / "no_such_dir" / "x.bag").string();
  const std::string e1 = errorOf([&] { sim::BagFrameSink s(missing); });
  EXPECT_NE(e1.find(missing + ".tmp"), std::string::npos) << e1;

  // The target is a directory: rename fails, the temporary file is removed.
  const std::string target = (dir / "is_a_dir.bag").string();
  fs::create_directories(fs::path(target) / "inside");
  sim::BagFrameSink sink(target);
  const std::string e2 = errorOf([&] { sink.close(); });
  EXPECT_NE(e2.find(target), std::string::npos) << e2;
  EXPECT_FALSE(fs::exists(target + ".tmp"));

  // A stamp outside ros::Time.
  const std::string path = (dir / "time.bag").string();
  sim::BagFrameSink t(path);
  for (double stamp : {-0.5, std::nan(""), 5e9}) {
    const std::string e3 = errorOf([&] { t.onFrame(testFrame("r", stamp)); });
    EXPECT_NE(e3.find(path + ".tmp"), std::string::npos) << e3;
  }
}

// ---------------------------------------------------------------------------------------------
// Bags read back with rosbag::View.

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

void expectCloudLayout(const sensor_msgs::PointCloud2& c) {
  EXPECT_EQ(c.height, 1u);
  ASSERT_EQ(c.fields.size(), 4u);
  const char* names[] = {"x", "y", "z", "intensity"};
  for (uint32_t f = 0; f < 4; ++f) {
    EXPECT_EQ(c.fields[f].name, names[f]);
    EXPECT_EQ(c.fields[f].offset, 4 * f);
    EXPECT_EQ(c.fields[f].datatype, sensor_msgs::PointField::FLOAT32);
    EXPECT_EQ(c.fields[f].count, 1u);
  }
  EXPECT_FALSE(c.is_bigendian);
  EXPECT_TRUE(c.is_dense);
  EXPECT_EQ(c.point_step, 16u);
  EXPECT_EQ(c.row_step, 16u * c.width);
  EXPECT_EQ(c.data.size(), 16u * c.width);
}

// Each robot's messages on its own connections, published by /<robot>/dtif_simulate.
void expectConnections(rosbag::View& view, const std::set<std::string>& robots) {
  std::set<std::pair<std::string, std::string>> seen;  // (topic, callerid)
  for (const rosbag::ConnectionInfo* c : view.getConnections()) {
    ASSERT_TRUE(c->header);
    const std::string callerid = c->header->at("callerid");
    EXPECT_TRUE(seen.emplace(c->topic, callerid).second) << c->topic << " " << callerid;
    EXPECT_EQ(c->header->at("latching"), "0");
    EXPECT_EQ(c->header->at("topic"), c->topic);
    const std::string robot = callerid.substr(1, callerid.find('/', 1) - 1);
    EXPECT_EQ(robots.count(robot), 1u) << callerid;
    EXPECT_EQ(callerid, "/" + robot + "/dtif_simulate");
    if (c->topic == "/tf") {
      expectConnectionOf<tf2_msgs::TFMessage>(*c);
    } else if (c->topic == "/" + robot + "/Odometry") {
      expectConnectionOf<nav_msgs::Odometry>(*c);
    } else {
      EXPECT_EQ(c->topic, "/" + robot + "/cloud_registered");
      expectConnectionOf<sensor_msgs::PointCloud2>(*c);
    }
  }
  EXPECT_EQ(seen.size(), 3 * robots.size());  // per robot: cloud_registered, Odometry, /tf
}

// The serialized messages of a bag in View order: (topic, time, callerid, bytes).
using RawMessage = std::tuple<std::string, ros::Time, std::string, std::vector<uint8_t>>;
std::vector<RawMessage> rawMessages(const std::string& path) {
  rosbag::Bag b;
  b.open(path, rosbag::bagmode::Read);
  rosbag::View view(b);
  std::vector<RawMessage> out;
  for (const rosbag::MessageInstance& m : view) {
    std::vector<uint8_t> bytes(m.size());
    ros::serialization::OStream s(bytes.data(), m.size());
    m.write(s);
    out.emplace_back(m.getTopic(), m.getTime(), m.getCallerId(), std::move(bytes));
  }
  return out;
}

bool containsString(const std::string& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  const std::string buf((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return buf.find(what) != std::string::npos;
}

TEST(SimBag, OneFrameReadsBackExactly) {
  const fs::path dir = tempDir("one_frame");
  const std::string path = (dir / "one.bag").string();
  sim::BagParams params;
  params.cloud_delay_s = 0.25;
  sim::BagFrameSink sink(path, params);
  const sim::Frame f = testFrame("r", 1700000000.5);
  sink.onFrame(f);
  sim::Frame g = testFrame("r", 1700000000.6);
  g.intensity.clear();  // none: zeros
  sink.onFrame(g);
  sink.close();
  EXPECT_EQ(sink.stats().messages, 6u);

  rosbag::Bag b;
  b.open(path, rosbag::bagmode::Read);
  rosbag::View view(b);
  expectConnections(view, {"r"});
  EXPECT_EQ(view.size(), 6u);
  EXPECT_EQ(view.getBeginTime(), ros::Time(1700000000, 500000000));
  EXPECT_EQ(view.getEndTime(), ros::Time(g.stamp + 0.25));
  std::map<std::string, uint32_t> seq;
  for (const rosbag::MessageInstance& m : view) {
    if (auto o = m.instantiate<nav_msgs::Odometry>()) {
      EXPECT_EQ(o->header.seq, seq[m.getTopic()]++);
      EXPECT_EQ(o->header.stamp, m.getTime());
      EXPECT_EQ(o->header.frame_id, "r/odom");
      EXPECT_EQ(o->child_frame_id, "r/base_link");
      expectPose(o->pose.pose.position, o->pose.pose.orientation, f.T_O_B);
      for (double v : o->pose.covariance) EXPECT_EQ(v, 0.0);
      for (double v : o->twist.covariance) EXPECT_EQ(v, 0.0);
      EXPECT_EQ(o->twist.twist.linear.x, 0.0);
      EXPECT_EQ(o->twist.twist.angular.z, 0.0);
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      ASSERT_EQ(tf->transforms.size(), 1u);
      const auto& t = tf->transforms[0];
      EXPECT_EQ(t.header.seq, 0u);
      EXPECT_EQ(t.header.stamp, m.getTime());
      EXPECT_EQ(t.header.frame_id, "r/odom");
      EXPECT_EQ(t.child_frame_id, "r/base_link");
      geometry_msgs::Point p;
      p.x = t.transform.translation.x;
      p.y = t.transform.translation.y;
      p.z = t.transform.translation.z;
      expectPose(p, t.transform.rotation, f.T_O_B);
    } else if (auto c = m.instantiate<sensor_msgs::PointCloud2>()) {
      const uint32_t k = seq[m.getTopic()]++;
      EXPECT_EQ(c->header.seq, k);
      EXPECT_EQ(c->header.frame_id, "r/odom");
      EXPECT_EQ(m.getTime(), ros::Time((k == 0 ? f : g).stamp + 0.25));
      expectCloudLayout(*c);
      ASSERT_EQ(c->width, 2u);
      float v[8];
      std::memcpy(v, c->data.data(), sizeof(v));
      EXPECT_EQ(std::vector<float>(v, v + 8),
                (std::vector<float>{1, 2, 3, k == 0 ? 7.0f : 0.0f, 4, 5, 6, k == 0 ? 8.0f : 0.0f}));
    } else {
      ADD_FAILURE() << "unknown type " << m.getDataType();
    }
  }
  EXPECT_EQ(seq["/r/Odometry"], 2u);
  EXPECT_EQ(seq["/r/cloud_registered"], 2u);
}

// ---------------------------------------------------------------------------------------------
// The simulator's bag sink on the tiny scene, shortened: every frame's messages, with the frame's
// stamp, odometry pose and points, the same messages in an LZ4 bag, and a replay through the
// nodelet's submap assembler.

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

// The replay through the submap assembler, per robot: submaps made and statuses other than kOk.
struct Replay {
  std::map<std::string, ros_glue::SubmapAssembler> assemblers;
  std::map<std::string, size_t> submaps, bad_status;

  ros_glue::SubmapAssembler& of(const std::string& robot) {
    return assemblers.try_emplace(robot, ros_glue::SubmapAssemblerParams{}).first->second;
  }
  void odometry(const std::string& robot, const nav_msgs::Odometry& o) {
    Pose T_O_B;
    ASSERT_TRUE(ros_glue::fromMsg(o.pose.pose, &T_O_B));
    if (of(robot).addOdometry(o.header.stamp.toSec(), T_O_B) !=
        ros_glue::SubmapAssembler::Status::kOk) {
      ++bad_status[robot];
    }
  }
  void cloud(const std::string& robot, const sensor_msgs::PointCloud2& c) {
    Cloud cloud;
    ASSERT_TRUE(ros_glue::fromMsg(c, &cloud));
    std::optional<ros_glue::AssembledSubmap> done;
    if (of(robot).addCloud(c.header.stamp.toSec(), cloud, &done) !=
        ros_glue::SubmapAssembler::Status::kOk) {
      ++bad_status[robot];
    }
    if (done) ++submaps[robot];
  }
};

// The fastlio layout: a bag per robot, named from the path, each with a stock FAST-LIO2 unit's
// names (the same on every unit) and the same messages otherwise, plus the unit's IMU
// (/livox/imu, 200 Hz between frames: here a body held still, rolled 0.2 rad).
TEST(SimBag, FastlioLayoutWritesABagPerUnitWithStockNames) {
  EXPECT_EQ(sim::unitBagPath("/d/run.bag", "alpha"), "/d/run_alpha.bag");
  EXPECT_EQ(sim::unitBagPath("run", "alpha"), "run_alpha.bag");
  sim::BagParams bad;
  bad.layout = "flat";
  EXPECT_NE(bad.validate().find("layout"), std::string::npos);

  const fs::path dir = tempDir("fastlio");
  sim::BagParams params;
  params.layout = sim::kLayoutFastlio;
  {  // abandoned: no bag, no temporary file
    sim::BagFrameSink sink((dir / "run.bag").string(), params);
    sink.onFrame(testFrame("alpha", 10.0));
    EXPECT_TRUE(fs::exists(dir / "run_alpha.bag.tmp"));
  }
  EXPECT_TRUE(fs::is_empty(dir));

  sim::BagFrameSink sink((dir / "run.bag").string(), params);
  const Pose T_W_B = test::makePose(0.0, 0.0, 1.7, 0.2, 0.0, 0.0);
  for (int k = 0; k < 3; ++k) {
    for (const char* robot : {"bravo", "alpha"}) {
      sim::Frame f = testFrame(robot, 10.0 + 0.1 * k);
      f.T_W_B = T_W_B;
      sink.onFrame(f);
    }
  }
  sink.close();
  EXPECT_EQ(sink.paths(), (std::vector<std::string>{(dir / "run_alpha.bag").string(),
                                                    (dir / "run_bravo.bag").string()}));
  EXPECT_FALSE(fs::exists(dir / "run.bag"));
  EXPECT_EQ(sink.stats().bytes,
            fs::file_size(dir / "run_alpha.bag") + fs::file_size(dir / "run_bravo.bag"));
  for (const std::string robot : {"alpha", "bravo"}) {
    rosbag::Bag b;
    b.open((dir / ("run_" + robot + ".bag")).string(), rosbag::bagmode::Read);
    rosbag::View view(b);
    std::map<std::string, int> count;
    for (const rosbag::ConnectionInfo* c : view.getConnections()) {
      EXPECT_EQ(c->header->at("callerid"),
                c->topic == "/livox/imu" ? "/livox_lidar_publisher" : "/laserMapping")
          << c->topic;
    }
    for (const rosbag::MessageInstance& m : view) {
      ++count[m.getTopic()];
      if (auto o = m.instantiate<nav_msgs::Odometry>()) {
        EXPECT_EQ(o->header.frame_id, "camera_init");
        EXPECT_EQ(o->child_frame_id, "body");
        expectPose(o->pose.pose.position, o->pose.pose.orientation, testFrame(robot, 0).T_O_B);
      } else if (auto c = m.instantiate<sensor_msgs::PointCloud2>()) {
        EXPECT_EQ(c->header.frame_id, "camera_init");
        EXPECT_EQ(c->width, 2u);
      } else if (auto imu = m.instantiate<sensor_msgs::Imu>()) {
        // The specific force in g in the body frame: gravity's up, rolled; no rotation rate.
        const Eigen::Vector3d up_B = T_W_B.rotation().transpose() * Eigen::Vector3d::UnitZ();
        EXPECT_EQ(imu->header.frame_id, "livox_frame");
        EXPECT_NEAR(imu->linear_acceleration.x, up_B.x(), 1e-9);
        EXPECT_NEAR(imu->linear_acceleration.y, up_B.y(), 1e-9);
        EXPECT_NEAR(imu->linear_acceleration.z, up_B.z(), 1e-9);
        EXPECT_NEAR(imu->angular_velocity.x, 0.0, 1e-9);
        EXPECT_GT(imu->header.stamp.toSec(), 10.0);
        EXPECT_LE(imu->header.stamp.toSec(), 10.2 + 1e-6);
      } else if (auto t = m.instantiate<tf2_msgs::TFMessage>()) {
        ASSERT_EQ(t->transforms.size(), 1u);
        EXPECT_EQ(t->transforms[0].header.frame_id, "camera_init");
        EXPECT_EQ(t->transforms[0].child_frame_id, "body");
      }
    }
    EXPECT_EQ(count,
              (std::map<std::string, int>{
                  {"/Odometry", 3}, {"/cloud_registered", 3}, {"/tf", 3}, {"/livox/imu", 40}}))
        << robot;
  }
}

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
  sim::BagParams lz4_params;
  lz4_params.compression = "lz4";
  sim::BagFrameSink lz4((dir / "lz4.bag").string(), lz4_params);
  Tee tee;
  tee.sinks = {&raw, &voxel, &lz4};
  const sim::DatasetRunResult result =
      sim::simulateDataset(scene, 3, (dir / "dataset").string(), &tee, "", 2);
  raw.close();
  voxel.close();
  lz4.close();
  ASSERT_GT(tee.frames.size(), 200u);
  EXPECT_EQ(raw.stats().frames, tee.frames.size());
  EXPECT_EQ(raw.stats().messages, 3 * tee.frames.size());
  EXPECT_EQ(raw.stats().points_out, raw.stats().points_in);
  EXPECT_LT(voxel.stats().points_out, voxel.stats().points_in);
  EXPECT_GT(voxel.stats().points_out, voxel.stats().points_in / 2);
  EXPECT_LT(fs::file_size(dir / "voxel.bag"), fs::file_size(dir / "raw.bag"));
  EXPECT_EQ(raw.stats().bytes, fs::file_size(dir / "raw.bag"));

  // The LZ4 bag: compressed chunks, the same messages.
  EXPECT_TRUE(containsString((dir / "lz4.bag").string(), "compression=lz4"));
  EXPECT_FALSE(containsString((dir / "raw.bag").string(), "compression=lz4"));
  EXPECT_TRUE(containsString((dir / "raw.bag").string(), "compression=none"));
  EXPECT_EQ(lz4.stats().bytes, fs::file_size(dir / "lz4.bag"));
  const std::vector<RawMessage> raw_messages = rawMessages((dir / "raw.bag").string());
  EXPECT_EQ(raw_messages.size(), 3 * tee.frames.size());
  EXPECT_TRUE(rawMessages((dir / "lz4.bag").string()) == raw_messages);

  // Frames by (robot, stamp).
  std::map<std::pair<std::string, ros::Time>, size_t> frames;  // -> index in tee.frames
  std::set<std::string> robots;
  for (size_t i = 0; i < tee.frames.size(); ++i) {
    frames[{tee.frames[i].robot, ros::Time(tee.frames[i].stamp)}] = i;
    robots.insert(tee.frames[i].robot);
  }
  ASSERT_EQ(frames.size(), tee.frames.size());

  rosbag::Bag b;
  b.open((dir / "raw.bag").string(), rosbag::bagmode::Read);
  rosbag::View view(b);
  expectConnections(view, robots);
  EXPECT_EQ(view.size(), 3 * tee.frames.size());
  std::map<std::string, size_t> counts;
  std::map<std::string, uint32_t> seq;  // next per topic
  Replay replay;
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
      EXPECT_EQ(o->header.seq, seq[m.getTopic()]++);
      EXPECT_EQ(o->header.frame_id, robot + "/odom");
      EXPECT_EQ(o->child_frame_id, robot + "/base_link");
      EXPECT_EQ(m.getTime(), o->header.stamp);
      const auto it = frames.find({robot, o->header.stamp});
      ASSERT_NE(it, frames.end());
      expectPose(o->pose.pose.position, o->pose.pose.orientation, tee.frames[it->second].T_O_B);
      replay.odometry(robot, *o);
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      ASSERT_EQ(tf->transforms.size(), 1u);
      const auto& t = tf->transforms[0];
      const std::string robot = t.header.frame_id.substr(0, t.header.frame_id.find('/'));
      EXPECT_EQ(m.getTopic(), "/tf");
      EXPECT_EQ(m.getCallerId(), "/" + robot + "/dtif_simulate");
      EXPECT_EQ(t.header.frame_id, robot + "/odom");
      EXPECT_EQ(t.child_frame_id, robot + "/base_link");
      EXPECT_EQ(m.getTime(), t.header.stamp);
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
      EXPECT_EQ(m.getCallerId(), "/" + robot + "/dtif_simulate");
      EXPECT_EQ(c->header.seq, seq[m.getTopic()]++);
      EXPECT_EQ(c->header.frame_id, robot + "/odom");
      EXPECT_GT(m.getTime(), c->header.stamp) << "recorded after its odometry";
      const auto it = frames.find({robot, c->header.stamp});
      ASSERT_NE(it, frames.end());
      const sim::Frame& f = tee.frames[it->second];
      EXPECT_EQ(m.getTime(), ros::Time(f.stamp + sim::BagParams{}.cloud_delay_s));
      expectCloudLayout(*c);
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
      replay.cloud(robot, *c);
    } else {
      ADD_FAILURE() << "unknown type " << m.getDataType();
    }
  }
  EXPECT_GT(points_compared, 1000u);
  std::map<std::string, size_t> frames_per_robot;
  for (const sim::Frame& f : tee.frames) ++frames_per_robot[f.robot];
  size_t assembled = 0;
  for (const auto& [robot, n] : frames_per_robot) {
    EXPECT_EQ(counts["/" + robot + "/Odometry"], n);
    EXPECT_EQ(counts["/" + robot + "/cloud_registered"], n);
    EXPECT_EQ(replay.bad_status[robot], 0u) << robot;
    assembled += replay.submaps[robot];
  }
  EXPECT_EQ(counts["/tf"], tee.frames.size());
  // The simulator's submaps are whole 10 s windows; the assembler cuts the same windows and
  // closes each at its last cloud, so it makes as many.
  EXPECT_EQ(assembled, result.stats.submaps);
  EXPECT_GE(assembled, 4u);
}

}  // namespace
}  // namespace dtif
