// rosbag format 2.0 writer; see rosbag_writer.h for the layout. Records are
// <header_len:u32><header><data_len:u32><data>; a header is a list of <len:u32><name>=<value>
// fields. Integers are little-endian (the ROS serialization; checked below).
#include "dtif/bag/rosbag_writer.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <sstream>

#include "ros_message_definitions.h"

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "ROS serialization is little-endian");

namespace dtif::bag {
namespace {

constexpr char kMagic[] = "#ROSBAG V2.0\n";
constexpr size_t kBagHeaderLength = 4096;  // header + padding of the bag header record
constexpr uint8_t kOpMessageData = 0x02;
constexpr uint8_t kOpBagHeader = 0x03;
constexpr uint8_t kOpIndexData = 0x04;
constexpr uint8_t kOpChunk = 0x05;
constexpr uint8_t kOpChunkInfo = 0x06;
constexpr uint8_t kOpConnection = 0x07;
constexpr uint8_t kPointFieldFloat32 = 7;  // sensor_msgs/PointField::FLOAT32

template <class T>
void put(std::string* out, T v) {
  out->append(reinterpret_cast<const char*>(&v), sizeof(T));
}

void putString(std::string* out, const std::string& s) {
  put<uint32_t>(out, static_cast<uint32_t>(s.size()));
  out->append(s);
}

void putTime(std::string* out, Time t) {
  put<uint32_t>(out, t.sec);
  put<uint32_t>(out, t.nsec);
}

template <class T>
std::string bytesOf(T v) {
  std::string s;
  put(&s, v);
  return s;
}

std::string timeBytes(Time t) {
  std::string s;
  putTime(&s, t);
  return s;
}

// A record header or connection header: fields `name=value`, in the order given (rosbag writes
// them from a std::map, i.e. sorted by name; readers do not care).
using Fields = std::vector<std::pair<std::string, std::string>>;
std::string encodeFields(const Fields& fields) {
  std::string s;
  for (const auto& [name, value] : fields) {
    put<uint32_t>(&s, static_cast<uint32_t>(name.size() + 1 + value.size()));
    s.append(name).append("=").append(value);
  }
  return s;
}

void putRecord(std::string* out, const Fields& header, const std::string& data) {
  putString(out, encodeFields(header));
  putString(out, data);
}

void putHeader(std::string* out, const Header& h) {
  put<uint32_t>(out, h.seq);
  putTime(out, h.stamp);
  putString(out, h.frame_id);
}

// geometry_msgs/Pose and geometry_msgs/Transform share the layout: 3 + 4 float64.
void putPose(std::string* out, const Pose& T) {
  const Eigen::Vector3d t = T.translation();
  const Eigen::Quaterniond q(T.rotation());
  for (double v : {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()}) put<double>(out, v);
}

/// Type name, MD5 sum and full definition of each message type, in one place.
struct MessageInfo {
  const char* type;
  const char* md5;
  const char* definition;
};
const MessageInfo& info(MessageType type) {
  static const MessageInfo kInfo[] = {
      {defs::kPointCloud2Type, defs::kPointCloud2Md5, defs::kPointCloud2Definition},
      {defs::kOdometryType, defs::kOdometryMd5, defs::kOdometryDefinition},
      {defs::kTfMessageType, defs::kTfMessageMd5, defs::kTfMessageDefinition}};
  switch (type) {
    case MessageType::kPointCloud2:
      return kInfo[0];
    case MessageType::kOdometry:
      return kInfo[1];
    case MessageType::kTfMessage:
      return kInfo[2];
  }
  static const MessageInfo kNone{"", "", ""};
  return kNone;
}

std::string errnoText() { return std::strerror(errno); }

}  // namespace

Time Time::fromSec(double t) {
  if (!std::isfinite(t) || t < 0.0 || t >= 4294967296.0) {
    std::ostringstream s;
    s << "time " << t << " s is outside the range of ros::Time";
    throw RosbagError(s.str());
  }
  Time r;
  double sec = std::floor(t);
  int64_t nsec = std::llround((t - sec) * 1e9);
  if (nsec >= 1000000000) {  // rounding carried into the next second
    sec += 1.0;
    nsec -= 1000000000;
  }
  if (sec >= 4294967296.0) throw RosbagError("time rounds beyond the range of ros::Time");
  r.sec = static_cast<uint32_t>(sec);
  r.nsec = static_cast<uint32_t>(nsec);
  return r;
}

const char* typeName(MessageType type) { return info(type).type; }

const char* md5sum(MessageType type) { return info(type).md5; }

void serializePointCloud2(const Header& header, const std::vector<Eigen::Vector3f>& points,
                          const std::vector<float>& intensity, std::string* out) {
  if (!intensity.empty() && intensity.size() != points.size()) {
    throw RosbagError("PointCloud2: " + std::to_string(intensity.size()) + " intensities for " +
                      std::to_string(points.size()) + " points");
  }
  constexpr uint32_t kPointStep = 16;
  const auto n = static_cast<uint32_t>(points.size());
  out->reserve(out->size() + 200 + header.frame_id.size() + size_t{kPointStep} * n);
  putHeader(out, header);
  put<uint32_t>(out, 1);  // height
  put<uint32_t>(out, n);  // width
  put<uint32_t>(out, 4);  // fields
  const char* names[] = {"x", "y", "z", "intensity"};
  for (uint32_t i = 0; i < 4; ++i) {
    putString(out, names[i]);
    put<uint32_t>(out, 4 * i);  // offset
    put<uint8_t>(out, kPointFieldFloat32);
    put<uint32_t>(out, 1);  // count
  }
  put<uint8_t>(out, 0);  // is_bigendian
  put<uint32_t>(out, kPointStep);
  put<uint32_t>(out, kPointStep * n);  // row_step
  put<uint32_t>(out, kPointStep * n);  // data length
  for (uint32_t i = 0; i < n; ++i) {
    const float v[4] = {points[i].x(), points[i].y(), points[i].z(),
                        intensity.empty() ? 0.0f : intensity[i]};
    out->append(reinterpret_cast<const char*>(v), sizeof(v));
  }
  put<uint8_t>(out, 1);  // is_dense
}

void serializeOdometry(const Odometry& odom, std::string* out) {
  putHeader(out, odom.header);
  putString(out, odom.child_frame_id);
  putPose(out, odom.T_frame_child);            // pose.pose
  for (int i = 0; i < 36; ++i) put(out, 0.0);  // pose.covariance
  for (int i = 0; i < 6; ++i) put(out, 0.0);   // twist.twist (linear, angular)
  for (int i = 0; i < 36; ++i) put(out, 0.0);  // twist.covariance
}

void serializeTfMessage(const std::vector<TransformStamped>& transforms, std::string* out) {
  put<uint32_t>(out, static_cast<uint32_t>(transforms.size()));
  for (const TransformStamped& t : transforms) {
    putHeader(out, t.header);
    putString(out, t.child_frame_id);
    putPose(out, t.T_frame_child);
  }
}

std::string RosbagWriterParams::validate() const {
  std::string e;
  if (chunk_bytes == 0 || chunk_bytes > (1u << 30)) e += "chunk_bytes must be in (0, 1 GiB]\n";
  if (callerid.empty()) e += "callerid must not be empty\n";
  return e;
}

// ---------------------------------------------------------------------------------------------

struct RosbagWriter::Impl {
  struct Connection {
    uint32_t id = 0;
    std::string topic, callerid;
    MessageType type = MessageType::kPointCloud2;
    Time last;  // latest message time
  };
  struct IndexEntry {
    Time time;
    uint32_t offset = 0;  // of the message data record in the uncompressed chunk data
  };
  struct ChunkInfo {
    uint64_t pos = 0;  // of the chunk record in the file
    Time start, end;
    std::map<uint32_t, uint32_t> counts;  // connection -> messages in the chunk
  };

  std::string path, tmp_path;
  RosbagWriterParams params;
  std::FILE* file = nullptr;
  uint64_t pos = 0;  // bytes written
  uint64_t messages = 0;
  std::vector<Connection> connections;                                // by id
  std::map<std::pair<std::string, std::string>, uint32_t> open_conn;  // (topic, callerid) -> id
  std::map<std::string, MessageType> topic_types;
  std::vector<ChunkInfo> chunks;
  // The open chunk.
  std::string chunk;
  std::map<uint32_t, std::vector<IndexEntry>> chunk_index;
  Time chunk_start, chunk_end;

  ~Impl() {
    if (file) {  // not closed: abandon the temporary file
      std::fclose(file);
      std::error_code ec;
      std::filesystem::remove(tmp_path, ec);
    }
  }

  void fail(const std::string& what) {
    throw RosbagError(tmp_path + ": " + what + ": " + errnoText());
  }

  void writeBytes(const std::string& s) {
    if (s.empty()) return;
    if (std::fwrite(s.data(), 1, s.size(), file) != s.size()) fail("cannot write");
    pos += s.size();
  }

  std::string bagHeaderRecord(uint64_t index_pos) const {
    const Fields header = {{"chunk_count", bytesOf<uint32_t>(chunks.size())},
                           {"conn_count", bytesOf<uint32_t>(connections.size())},
                           {"index_pos", bytesOf<uint64_t>(index_pos)},
                           {"op", bytesOf<uint8_t>(kOpBagHeader)}};
    const std::string h = encodeFields(header);
    std::string r;
    putString(&r, h);
    putString(&r, std::string(kBagHeaderLength - h.size(), ' '));  // as rosbag::Bag pads it
    return r;
  }

  // The connection header rosbag record stores: the publisher's, as received.
  std::string connectionRecord(const Connection& c) const {
    const Fields conn_header = {
        {"callerid", c.callerid},   {"latching", "0"},
        {"md5sum", md5sum(c.type)}, {"message_definition", info(c.type).definition},
        {"topic", c.topic},         {"type", typeName(c.type)}};
    std::string r;
    putRecord(&r,
              {{"conn", bytesOf<uint32_t>(c.id)},
               {"op", bytesOf<uint8_t>(kOpConnection)},
               {"topic", c.topic}},
              encodeFields(conn_header));
    return r;
  }

  void flushChunk() {
    if (chunk.empty()) return;
    if (chunk.size() > UINT32_MAX) throw RosbagError(tmp_path + ": chunk larger than 4 GiB");
    ChunkInfo info;
    info.pos = pos;
    info.start = chunk_start;
    info.end = chunk_end;
    std::string r;
    putString(&r, encodeFields({{"compression", "none"},
                                {"op", bytesOf<uint8_t>(kOpChunk)},
                                {"size", bytesOf<uint32_t>(chunk.size())}}));
    put<uint32_t>(&r, static_cast<uint32_t>(chunk.size()));
    writeBytes(r);
    writeBytes(chunk);
    // Index data records (version 1), one per connection of the chunk, entries in time order.
    for (auto& [conn, entries] : chunk_index) {
      std::stable_sort(entries.begin(), entries.end(),
                       [](const IndexEntry& a, const IndexEntry& b) { return a.time < b.time; });
      std::string data;
      for (const IndexEntry& e : entries) {
        putTime(&data, e.time);
        put<uint32_t>(&data, e.offset);
      }
      std::string rec;
      putRecord(&rec,
                {{"conn", bytesOf<uint32_t>(conn)},
                 {"count", bytesOf<uint32_t>(entries.size())},
                 {"op", bytesOf<uint8_t>(kOpIndexData)},
                 {"ver", bytesOf<uint32_t>(1)}},
                data);
      writeBytes(rec);
      info.counts[conn] = static_cast<uint32_t>(entries.size());
    }
    chunks.push_back(std::move(info));
    chunk.clear();
    chunk_index.clear();
  }
};

RosbagWriter::RosbagWriter(const std::string& path, const RosbagWriterParams& params)
    : impl_(std::make_unique<Impl>()) {
  const std::string problems = params.validate();
  if (!problems.empty()) throw RosbagError(path + ": invalid writer parameters:\n" + problems);
  impl_->path = path;
  impl_->tmp_path = path + ".tmp";
  impl_->params = params;
  impl_->file = std::fopen(impl_->tmp_path.c_str(), "wb");
  if (!impl_->file) impl_->fail("cannot create");
  impl_->chunk.reserve(params.chunk_bytes + (1 << 16));
  impl_->writeBytes(kMagic);
  impl_->writeBytes(impl_->bagHeaderRecord(0));  // rewritten by close()
}

RosbagWriter::~RosbagWriter() = default;

void RosbagWriter::write(const std::string& topic, MessageType type, Time time,
                         const std::string& data, const std::string& callerid) {
  Impl& m = *impl_;
  if (!m.file) throw RosbagError(m.path + ": write after close");
  if (topic.empty()) throw RosbagError(m.path + ": empty topic name");
  const auto [type_it, new_topic] = m.topic_types.emplace(topic, type);
  if (!new_topic && type_it->second != type) {
    throw RosbagError(m.path + ": topic " + topic + " has type " + typeName(type_it->second) +
                      ", not " + typeName(type));
  }
  const std::string& caller = callerid.empty() ? m.params.callerid : callerid;
  // Python's rosbag merges each connection's index as if it were in time order (rosbag record
  // receives in time order), so a message older than its connection's latest opens another
  // connection with the same header; rosbag's C++ reader sorts them all the same.
  const auto key = std::make_pair(topic, caller);
  auto open = m.open_conn.find(key);
  if (open == m.open_conn.end() || time < m.connections[open->second].last) {
    Impl::Connection c;
    c.id = static_cast<uint32_t>(m.connections.size());
    c.topic = topic;
    c.callerid = caller;
    c.type = type;
    c.last = time;
    m.connections.push_back(c);
    m.open_conn[key] = c.id;
    m.chunk += m.connectionRecord(c);  // first appearance: in the chunk, too
    open = m.open_conn.find(key);
  }
  Impl::Connection& conn = m.connections[open->second];
  conn.last = std::max(conn.last, time);
  if (m.chunk_index.empty()) {
    m.chunk_start = m.chunk_end = time;
  } else {
    m.chunk_start = std::min(m.chunk_start, time);
    m.chunk_end = std::max(m.chunk_end, time);
  }
  m.chunk_index[conn.id].push_back({time, static_cast<uint32_t>(m.chunk.size())});
  putRecord(&m.chunk,
            {{"conn", bytesOf<uint32_t>(conn.id)},
             {"op", bytesOf<uint8_t>(kOpMessageData)},
             {"time", timeBytes(time)}},
            data);
  ++m.messages;
  if (m.chunk.size() >= m.params.chunk_bytes) m.flushChunk();
}

void RosbagWriter::close() {
  Impl& m = *impl_;
  if (!m.file) throw RosbagError(m.path + ": already closed");
  m.flushChunk();
  const uint64_t index_pos = m.pos;
  for (const Impl::Connection& c : m.connections) m.writeBytes(m.connectionRecord(c));
  for (const Impl::ChunkInfo& info : m.chunks) {
    std::string data;
    for (const auto& [conn, count] : info.counts) {
      put<uint32_t>(&data, conn);
      put<uint32_t>(&data, count);
    }
    std::string rec;
    putRecord(&rec,
              {{"chunk_pos", bytesOf<uint64_t>(info.pos)},
               {"count", bytesOf<uint32_t>(info.counts.size())},
               {"end_time", timeBytes(info.end)},
               {"op", bytesOf<uint8_t>(kOpChunkInfo)},
               {"start_time", timeBytes(info.start)},
               {"ver", bytesOf<uint32_t>(1)}},
              data);
    m.writeBytes(rec);
  }
  const uint64_t end = m.pos;
  if (std::fseek(m.file, static_cast<long>(sizeof(kMagic) - 1), SEEK_SET) != 0) m.fail("seek");
  m.pos = sizeof(kMagic) - 1;
  m.writeBytes(m.bagHeaderRecord(index_pos));
  m.pos = end;
  if (std::fflush(m.file) != 0) m.fail("cannot write");  // ~Impl removes the file
  std::FILE* f = m.file;
  m.file = nullptr;
  if (std::fclose(f) != 0) {
    const std::string what = errnoText();
    std::error_code ec;
    std::filesystem::remove(m.tmp_path, ec);
    throw RosbagError(m.tmp_path + ": cannot write: " + what);
  }
  std::error_code ec;
  std::filesystem::rename(m.tmp_path, m.path, ec);
  if (ec) {
    const std::string what = ec.message();
    std::filesystem::remove(m.tmp_path, ec);
    throw RosbagError(m.path + ": cannot rename " + m.tmp_path + " to it: " + what);
  }
}

const std::string& RosbagWriter::path() const { return impl_->path; }
uint64_t RosbagWriter::messages() const { return impl_->messages; }
uint64_t RosbagWriter::bytesWritten() const { return impl_->pos; }

}  // namespace dtif::bag
