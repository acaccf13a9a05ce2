// The database file: save/load of every entry's encoded descriptor, atomically written and
// checksummed; read with bounded size and checked entries (docs/limits.md).
#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <set>
#include <stdexcept>
#include <utility>

#include "core/byte_io.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/validation.h"
#include "dtif/core/file_io.h"

namespace dtif {
namespace {

constexpr char kDbMagic[8] = {'D', 'T', 'I', 'F', 'D', 'B', '\0', '\0'};
// Version 2 adds each entry's odometry pose and frame and the accepted loops; version 3 each
// entry's match triangles (a load then need not compute them again); versions 1 and 2 still
// load.
constexpr uint32_t kDbVersion = 3;
constexpr uint32_t kDbVersionNoTriangles = 2;
constexpr uint32_t kDbVersionNoOdometry = 1;

constexpr size_t kEntryHeaderBytes = 4;

using detail::fnv1a;

// Frame (length-prefixed; empty: unknown), translation, quaternion (x, y, z, w).
void putOdometry(detail::ByteWriter& w, const EntryOdometry& o) {
  w.putString(o.odom_frame);
  const Eigen::Quaterniond q(o.T_O_S.rotation());
  for (double v : {o.T_O_S.translation().x(), o.T_O_S.translation().y(), o.T_O_S.translation().z(),
                   q.x(), q.y(), q.z(), q.w()}) {
    w.put<double>(v);
  }
}

EntryOdometry getOdometry(detail::ByteReader& r) {
  EntryOdometry o;
  o.odom_frame = r.getString();
  double v[7];
  for (double& x : v) x = r.get<double>();
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  for (double x : v) {
    if (!std::isfinite(x)) throw std::runtime_error("odometry pose is not finite");
  }
  if (std::fabs(q.norm() - 1.0) > 1e-6) throw std::runtime_error("odometry rotation not unit");
  o.T_O_S = Pose::Identity();
  o.T_O_S.linear() = q.normalized().toRotationMatrix();
  o.T_O_S.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return o;
}

// A count, then per triangle its three trunk indices (u16) and whether it is a Delaunay face
// (u8), in matchTriangles' order.
void putTriangles(detail::ByteWriter& w, const std::vector<MatchTriangle>& t) {
  w.put<uint32_t>(static_cast<uint32_t>(t.size()));
  for (const MatchTriangle& m : t) {
    for (int v : m.t.v) w.put<uint16_t>(static_cast<uint16_t>(v));
    w.put<uint8_t>(m.delaunay ? 1 : 0);
  }
}

// The triangles again from their trunks as the file holds them (trunk positions are stored as
// floats, like the descriptor's Delaunay faces: values within float rounding of the saving
// detector's), checked (trunk indices in range and distinct, a valid flag) and sorted by
// longest edge again, as matching requires (a stable sort: float rounding can swap two
// near-equal neighbours, nothing else).
std::vector<MatchTriangle> getTriangles(detail::ByteReader& r, const Descriptor& d) {
  constexpr size_t kTriangleBytes = 3 * 2 + 1;
  const uint32_t n = r.get<uint32_t>();
  if (n > r.remaining() / kTriangleBytes) throw std::runtime_error("triangle count exceeds file");
  std::vector<MatchTriangle> out(n);
  const int trunks = static_cast<int>(d.trunks.size());
  for (MatchTriangle& m : out) {
    int v[3];
    for (int& x : v) x = r.get<uint16_t>();
    const uint8_t face = r.get<uint8_t>();
    if (v[0] >= trunks || v[1] >= trunks || v[2] >= trunks || v[0] == v[1] || v[1] == v[2] ||
        v[0] == v[2] || face > 1) {
      throw std::runtime_error("match triangle out of range");
    }
    m.t = makeCanonicalTriangle(d.trunks, v[0], v[1], v[2]);
    m.delaunay = face == 1;
  }
  std::stable_sort(out.begin(), out.end(), [](const MatchTriangle& a, const MatchTriangle& b) {
    return a.t.len[0] < b.t.len[0];
  });
  return out;
}

// Robots, ids, T_c_q (translation, quaternion x y z w), covariance, inliers, score.
void putLoop(detail::ByteWriter& w, const Loop& l) {
  w.putString(l.query_robot);
  w.put<int64_t>(l.query_id);
  w.putString(l.candidate_robot);
  w.put<int64_t>(l.candidate_id);
  EntryOdometry pose;
  pose.T_O_S = l.T_c_q;
  putOdometry(w, pose);  // an empty frame, then the pose
  for (int i = 0; i < 36; ++i) w.put<double>(l.covariance(i / 6, i % 6));
  w.put<int32_t>(l.inliers);
  w.put<double>(l.score);
}

Loop getLoop(detail::ByteReader& r) {
  Loop l;
  l.query_robot = r.getString();
  l.query_id = r.get<int64_t>();
  l.candidate_robot = r.getString();
  l.candidate_id = r.get<int64_t>();
  l.T_c_q = getOdometry(r).T_O_S;
  for (int i = 0; i < 36; ++i) l.covariance(i / 6, i % 6) = r.get<double>();
  if (!l.covariance.allFinite()) throw std::runtime_error("loop covariance is not finite");
  l.inliers = r.get<int32_t>();
  l.score = r.get<double>();
  return l;
}

// The body (after magic and version, before the checksum); throws on the first problem.
DatabaseContents readContents(detail::ByteReader& r, uint32_t version) {
  const uint64_t n = r.get<uint64_t>();
  // Bounded before anything is reserved: every entry takes at least its size field.
  if (n > kMaxDatabaseEntries) {
    throw std::runtime_error(std::to_string(n) + " entries exceed kMaxDatabaseEntries (" +
                             std::to_string(kMaxDatabaseEntries) + ")");
  }
  if (n > r.remaining() / kEntryHeaderBytes) throw std::runtime_error("entry count exceeds file");
  DatabaseContents c;
  std::set<std::pair<std::string, int64_t>> keys;
  // The loosest params: keep each descriptor's saved validity.
  const DescriptorParams loose = loosestDescriptorParams();
  if (version >= kDbVersion) c.triangles_k = r.get<int32_t>();
  for (uint64_t i = 0; i < n; ++i) {
    const uint32_t sz = r.get<uint32_t>();
    if (r.remaining() < sz) throw std::runtime_error("entry truncated");
    const uint8_t* at = r.take(sz);
    auto d =
        std::make_shared<Descriptor>(decodeDescriptor(std::vector<uint8_t>(at, at + sz), loose));
    const std::string entry = "entry " + std::to_string(i);
    if (!d->valid) throw std::runtime_error(entry + " is not valid");
    if (!keys.emplace(d->robot, d->submap_id).second) {
      throw std::runtime_error(entry + " repeats robot '" + d->robot + "' submap " +
                               std::to_string(d->submap_id));
    }
    c.odometry.push_back(version >= kDbVersionNoTriangles ? getOdometry(r) : EntryOdometry{});
    if (version >= kDbVersion) {
      try {
        c.triangles.push_back(getTriangles(r, *d));
      } catch (const std::runtime_error& e) {
        throw std::runtime_error(entry + ": " + e.what());
      }
    }
    c.entries.push_back(std::move(d));
  }
  if (version >= kDbVersionNoTriangles) {
    const uint64_t m = r.get<uint64_t>();
    // A loop takes far more than its two length fields: bounded by the bytes left.
    if (m > r.remaining() / 8) throw std::runtime_error("loop count exceeds file");
    for (uint64_t i = 0; i < m; ++i) c.loops.push_back(getLoop(r));
  }
  if (r.remaining() != 0) throw std::runtime_error("trailing bytes");
  return c;
}

}  // namespace

// File layout: 8-byte magic, u32 version, u64 entry count, i32 neighbour_triangles of the
// match triangles, entries (u32 size + encoded descriptor + odometry record + match
// triangles), u64 loop count, loops, u32 FNV-1a of everything before it. Version 2 files have
// no match triangles (nor their k), version 1 files neither odometry records nor loops.
void LoopDetector::save(const std::string& path) const {
  detail::ByteWriter w;
  w.bytes.assign(kDbMagic, kDbMagic + 8);
  w.put<uint32_t>(kDbVersion);
  w.put<uint64_t>(entries_.size());
  w.put<int32_t>(params_.matcher.neighbour_triangles);
  for (size_t i = 0; i < entries_.size(); ++i) {
    const std::vector<uint8_t> e = encodeDescriptor(*entries_[i]);
    w.put<uint32_t>(static_cast<uint32_t>(e.size()));
    w.putBytes(e);
    putOdometry(w, odometry_[i]);
    putTriangles(w, triangles_[i]);
  }
  w.put<uint64_t>(loops_.size());
  for (const Loop& l : loops_) putLoop(w, l);
  w.put<uint32_t>(fnv1a(w.bytes.data(), w.bytes.size()));
  if (w.bytes.size() > kMaxDatabaseBytes) {
    throw std::runtime_error(path + ": database of " + std::to_string(w.bytes.size()) +
                             " bytes exceeds kMaxDatabaseBytes: not written");
  }
  writeFileAtomically(path, w.bytes);
}

DatabaseContents readDatabaseFile(const std::string& path) {
  const std::vector<uint8_t> buf = readRegularFile(path, kMaxDatabaseBytes);
  auto fail = [&](const std::string& why) {
    throw std::runtime_error(path + ": not a valid dtif database: " + why);
  };
  if (buf.size() < 8 + 4 + 8 + 4 || std::memcmp(buf.data(), kDbMagic, 8) != 0) fail("bad magic");
  // The body: everything between the magic and the checksum.
  detail::ByteReader r(buf.data() + 8, buf.size() - 8 - 4, "truncated");
  const uint32_t version = r.get<uint32_t>();
  if (version < kDbVersionNoOdometry || version > kDbVersion) {
    fail("version " + std::to_string(version) + ", expected " +
         std::to_string(kDbVersionNoOdometry) + " to " + std::to_string(kDbVersion));
  }
  uint32_t stored_sum;
  std::memcpy(&stored_sum, buf.data() + buf.size() - 4, 4);
  if (fnv1a(buf.data(), buf.size() - 4) != stored_sum) fail("checksum mismatch");
  try {
    return readContents(r, version);
  } catch (const std::exception& e) {  // also length_error / bad_alloc: name the file
    fail(e.what());
  }
  return {};
}

void LoopDetector::load(const std::string& path) { replaceContents(readDatabaseFile(path)); }

void LoopDetector::replaceContents(DatabaseContents contents) {
  entries_ = std::move(contents.entries);
  odometry_ = std::move(contents.odometry);
  loops_ = std::move(contents.loops);
  // Saved match triangles only when they are what this detector's matcher computes.
  const bool saved = contents.triangles.size() == entries_.size() &&
                     contents.triangles_k == params_.matcher.neighbour_triangles;
  rebuildIndex(saved ? &contents.triangles : nullptr);
}

}  // namespace dtif
