// The bag writer without ROS: file handling (temporary file, rename, errors naming the file),
// time conversion, parameters, message sizes. Reading bags back with rosbag itself:
// test/ros/rosbag_writer_test.cpp.

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>

#include "dtif/bag/rosbag_writer.h"
#include "test_utils.h"

namespace dtif {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
  return test::freshTempDir("dtif_rosbag_file_test_" + name);
}

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const bag::RosbagError& e) {
    return e.what();
  }
  return "";
}

TEST(RosbagWriterFiles, RenamedOnCloseAbandonedWithoutClose) {
  const fs::path dir = tempDir("files");
  const std::string path = (dir / "a.bag").string();
  {
    bag::RosbagWriter w(path);
    std::string data;
    bag::serializeTfMessage({}, &data);
    w.write("/tf", bag::MessageType::kTfMessage, bag::Time::fromSec(10.0), data);
    EXPECT_TRUE(fs::exists(path + ".tmp"));
    EXPECT_FALSE(fs::exists(path));
  }  // destroyed without close(): no bag, no temporary file
  EXPECT_FALSE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path + ".tmp"));

  bag::RosbagWriter w(path);
  w.close();
  EXPECT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path + ".tmp"));
  // Magic line plus the bag header record padded to 4096 bytes, nothing else in an empty bag.
  EXPECT_EQ(fs::file_size(path), 13u + 4u + 4096u + 4u);
  std::ifstream in(path, std::ios::binary);
  std::string magic(13, '\0');
  in.read(magic.data(), 13);
  EXPECT_EQ(magic, "#ROSBAG V2.0\n");
  EXPECT_NE(errorOf([&] { w.close(); }), "");
}

TEST(RosbagWriterFiles, ErrorsNameTheFile) {
  const fs::path dir = tempDir("errors");
  const std::string missing = (dir / "no_such_dir" / "x.bag").string();
  EXPECT_NE(errorOf([&] { bag::RosbagWriter w(missing); }).find(missing + ".tmp"),
            std::string::npos);

  // The target is a directory: rename fails, the temporary file is removed.
  const std::string target = (dir / "is_a_dir.bag").string();
  fs::create_directories(fs::path(target) / "inside");
  bag::RosbagWriter w(target);
  const std::string e = errorOf([&] { w.close(); });
  EXPECT_NE(e.find(target), std::string::npos) << e;
  EXPECT_FALSE(fs::exists(target + ".tmp"));

  bag::RosbagWriter t((dir / "types.bag").string());
  t.write("/x", bag::MessageType::kOdometry, bag::Time{1, 0}, "");
  EXPECT_NE(errorOf([&] {
              t.write("/x", bag::MessageType::kTfMessage, bag::Time{2, 0}, "");
            }).find("/x has type nav_msgs/Odometry"),
            std::string::npos);

  bag::RosbagWriterParams bad;
  bad.chunk_bytes = 0;
  bad.callerid = "";
  EXPECT_NE(bad.validate().find("chunk_bytes"), std::string::npos);
  EXPECT_NE(bad.validate().find("callerid"), std::string::npos);
  EXPECT_NE(errorOf([&] { bag::RosbagWriter b((dir / "bad.bag").string(), bad); }), "");
  EXPECT_FALSE(fs::exists(dir / "bad.bag.tmp"));
}

TEST(RosbagTime, FromSecRoundsLikeRosTime) {
  EXPECT_EQ(bag::Time::fromSec(0.0), (bag::Time{0, 0}));
  EXPECT_EQ(bag::Time::fromSec(1.5), (bag::Time{1, 500000000}));
  EXPECT_EQ(bag::Time::fromSec(1.9999999999), (bag::Time{2, 0}));  // rounding carries
  EXPECT_EQ(bag::Time::fromSec(1700000000.25), (bag::Time{1700000000, 250000000}));
  EXPECT_THROW(bag::Time::fromSec(-0.5), bag::RosbagError);
  EXPECT_THROW(bag::Time::fromSec(std::nan("")), bag::RosbagError);
  EXPECT_THROW(bag::Time::fromSec(5e9), bag::RosbagError);
  EXPECT_TRUE((bag::Time{1, 999999999}) < (bag::Time{2, 0}));
  EXPECT_FALSE((bag::Time{2, 0}) < (bag::Time{2, 0}));
}

TEST(RosbagSerialize, MessageSizes) {
  // Odometry: header (4 + 8 + 4 + frame) + child frame (4 + n) + pose (7 doubles) + covariance
  // (36) + twist (6) + covariance (36).
  bag::Odometry o;
  o.header.frame_id = "r/odom";
  o.child_frame_id = "r/base_link";
  std::string data;
  bag::serializeOdometry(o, &data);
  EXPECT_EQ(data.size(), 16u + 6u + 4u + 11u + 8u * (7 + 36 + 6 + 36));
  // PointCloud2: header, height, width, 4 fields (4 + name + 4 + 1 + 4), is_bigendian,
  // point_step, row_step, data (4 + 16 n), is_dense.
  data.clear();
  bag::Header h;
  h.frame_id = "r/odom";
  bag::serializePointCloud2(h, {Eigen::Vector3f(1, 2, 3), Eigen::Vector3f(4, 5, 6)}, {}, &data);
  EXPECT_EQ(data.size(), 22u + 8u + 4u + (13u * 4 + 1 + 1 + 1 + 9) + 1u + 8u + 4u + 32u + 1u);
  EXPECT_THROW(bag::serializePointCloud2(h, {Eigen::Vector3f(1, 2, 3)}, {1.0f, 2.0f}, &data),
               bag::RosbagError);
}

}  // namespace
}  // namespace dtif
