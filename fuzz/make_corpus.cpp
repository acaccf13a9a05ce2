// Writes the binary seeds of fuzz/corpus/ (descriptor, database, ground map, ROS messages) from
// a small valid descriptor; run once by hand when a format changes:
//   .ws-san/devel/lib/dtif/fuzz_make_corpus fuzz/corpus
#include <ros/serialization.h>

#include <filesystem>
#include <fstream>
#include <iostream>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/extraction/ground_map.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/msgs.h"

namespace {

void write(const std::filesystem::path& p, const std::vector<uint8_t>& b, uint8_t prefix = 0,
           bool with_prefix = false) {
  std::filesystem::create_directories(p.parent_path());
  std::ofstream f(p, std::ios::binary);
  if (with_prefix) f.put(static_cast<char>(prefix));
  f.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

template <class Msg>
std::vector<uint8_t> serialise(const Msg& m) {
  std::vector<uint8_t> b(ros::serialization::serializationLength(m));
  ros::serialization::OStream out(b.data(), static_cast<uint32_t>(b.size()));
  ros::serialization::serialize(out, m);
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: fuzz_make_corpus <corpus dir>\n";
    return 2;
  }
  const std::filesystem::path dir = argv[1];
  dtif::Trunks trunks;
  const double xy[][2] = {{0, 0}, {4, 1}, {1, 5}, {6, 6}, {-3, 4}, {2, -4}};
  for (const auto& p : xy) {
    dtif::TrunkLandmark t;
    t.x = p[0], t.y = p[1], t.z = 0.1 * p[0], t.r = 0.15, t.base_seen = p[0] > 0;
    trunks.push_back(t);
  }
  dtif::Descriptor d = dtif::buildDescriptor(trunks, dtif::DescriptorParams());
  d.robot = "alpha", d.submap_id = 3, d.stamp = 1700000000.5;
  dtif::GroundMap m;
  m.cell_m = 0.5, m.z_step_m = 0.05, m.width = 3, m.height = 2;
  m.z = {1, 2, dtif::GroundMap::kUnknown, 4, 300, -7};
  d.ground_map = m;
  write(dir / "descriptor" / "valid", dtif::encodeDescriptor(d));
  write(dir / "ground_map" / "valid", dtif::encodeGroundMap(m));
  dtif::LoopDetector db{dtif::LoopDetectorParams{}};
  db.insert(std::make_shared<dtif::Descriptor>(d));
  dtif::Descriptor d2 = d;
  d2.submap_id = 4;
  db.insert(std::make_shared<dtif::Descriptor>(d2));
  const std::string db_path = (dir / "database" / "valid").string();
  std::filesystem::create_directories(dir / "database");
  db.save(db_path);
  const dtif::TrunkDescriptor msg = dtif::ros_glue::toMsg(d, dtif::Pose::Identity(), "odom");
  write(dir / "ros_msgs" / "descriptor", serialise(msg), 0, true);
  dtif::Loop lc;
  lc.query_robot = "alpha", lc.query_id = 4, lc.candidate_robot = "alpha", lc.candidate_id = 3;
  write(dir / "ros_msgs" / "loop", serialise(dtif::ros_glue::toMsg(lc)), 1, true);
  sensor_msgs::PointCloud2 cloud;
  cloud.height = 1, cloud.width = 2, cloud.point_step = 12, cloud.row_step = 24;
  for (int k = 0; k < 3; ++k) {
    sensor_msgs::PointField f;
    f.name = std::string(1, "xyz"[k]), f.offset = 4 * k, f.datatype = 7, f.count = 1;
    cloud.fields.push_back(f);
  }
  cloud.data.assign(24, 0);
  write(dir / "ros_msgs" / "cloud", serialise(cloud), 2, true);
  std::cout << "wrote seeds under " << dir << "\n";
  return 0;
}
