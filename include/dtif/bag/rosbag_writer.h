// A small, ROS-free writer of rosbag format 2.0 files (http://wiki.ros.org/Bags/Format/2.0), so
// the offline tool can write bags without linking ROS. Uncompressed chunks; the three message
// types dtif replays (sensor_msgs/PointCloud2, nav_msgs/Odometry, tf2_msgs/TFMessage) are
// serialised by hand, with the MD5 sums and definitions of the installed ROS messages.
//
// File layout (as rosbag::Bag writes it): "#ROSBAG V2.0\n", the bag header record padded to
// 4096 bytes (rewritten at close with index_pos, conn_count, chunk_count), then per chunk: a
// chunk record (connection records of connections new to the bag, message data records)
// followed by one index data record (version 1) per connection in the chunk; at index_pos, one
// connection record per connection and one chunk info record per chunk.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "dtif/core/types.h"

namespace dtif::bag {

/// Any failure to write the bag; the message names the file.
class RosbagError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// ros::Time: seconds and nanoseconds.
struct Time {
  uint32_t sec = 0;
  uint32_t nsec = 0;
  /// As ros::Time::fromSec: nanoseconds rounded. Throws RosbagError outside [0, 2^32) s.
  static Time fromSec(double t);
  double toSec() const { return sec + 1e-9 * nsec; }
  bool operator<(const Time& o) const { return sec != o.sec ? sec < o.sec : nsec < o.nsec; }
  bool operator==(const Time& o) const { return sec == o.sec && nsec == o.nsec; }
};

/// std_msgs/Header.
struct Header {
  uint32_t seq = 0;
  Time stamp;
  std::string frame_id;
};

/// The message types the writer knows.
enum class MessageType { kPointCloud2, kOdometry, kTfMessage };
const char* typeName(MessageType type);  ///< e.g. "sensor_msgs/PointCloud2"
const char* md5sum(MessageType type);    ///< MD5 sum of the installed ROS message

/// sensor_msgs/PointCloud2, unorganised (height 1), fields x, y, z, intensity (float32, offsets
/// 0, 4, 8, 12; point_step 16), little-endian, is_dense. `intensity` is empty (zeros) or one
/// per point. Appends to *out.
void serializePointCloud2(const Header& header, const std::vector<Eigen::Vector3f>& points,
                          const std::vector<float>& intensity, std::string* out);

/// nav_msgs/Odometry: pose T_frame_child (header.frame_id <- child_frame_id); twist and both
/// covariances zero (FAST-LIO2 leaves them unset, too).
struct Odometry {
  Header header;
  std::string child_frame_id;
  Pose T_frame_child = Pose::Identity();
};
void serializeOdometry(const Odometry& odom, std::string* out);

/// geometry_msgs/TransformStamped: T_frame_child (header.frame_id <- child_frame_id).
struct TransformStamped {
  Header header;
  std::string child_frame_id;
  Pose T_frame_child = Pose::Identity();
};
/// tf2_msgs/TFMessage.
void serializeTfMessage(const std::vector<TransformStamped>& transforms, std::string* out);

struct RosbagWriterParams {
  /// A chunk is written to disk once its data reaches this size [bytes] (rosbag: 768 KiB).
  size_t chunk_bytes = 1 << 20;
  /// Publisher node written into the connection headers when write() names none (rosbag record
  /// keeps the publisher's).
  std::string callerid = "/dtif_simulate";
  /// Empty when valid, else the problems, one per line.
  std::string validate() const;
};

/// Writes `path` + ".tmp" and renames it to `path` in close(). Only the current chunk (about
/// chunk_bytes) and the index are held in memory. Messages may be written out of time order
/// (rosbag play orders them by the index; see write()). Not thread-safe: one caller at a time.
class RosbagWriter {
 public:
  /// Opens the temporary file; throws RosbagError (naming it) when it cannot be created.
  explicit RosbagWriter(const std::string& path, const RosbagWriterParams& params = {});
  /// Without close(), the temporary file is removed: no incomplete bag is left behind.
  ~RosbagWriter();
  RosbagWriter(const RosbagWriter&) = delete;
  RosbagWriter& operator=(const RosbagWriter&) = delete;

  /// One serialised message on `topic` (absolute, e.g. "/robot1/Odometry") received at `time`,
  /// published by node `callerid` (empty: params.callerid). Each (topic, callerid) is a
  /// connection, as in a recorded bag. A topic keeps the type of its first message; another type
  /// throws RosbagError. Any time order is accepted: a message older than the latest of its
  /// connection starts another connection with the same header (Python's rosbag expects each
  /// connection in time order), so write in time order per (topic, callerid) where possible.
  void write(const std::string& topic, MessageType type, Time time, const std::string& data,
             const std::string& callerid = "");
  /// Writes the last chunk and the index, rewrites the bag header, renames the file.
  void close();

  const std::string& path() const;
  uint64_t messages() const;      ///< messages written so far
  uint64_t bytesWritten() const;  ///< bytes in the file so far (chunks are written when full)

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dtif::bag
