// The simulator's frames as a rosbag that looks like a recorded MID-360 + FAST-LIO2 multi-robot
// session (`dtif simulate --bag`), for replay into dtif's nodelets with `rosbag play --clock`
// (launch/demo_bag.launch). Per robot and frame:
//   /<robot>/cloud_registered  sensor_msgs/PointCloud2, frame <robot>/odom, points in O
//   /<robot>/Odometry          nav_msgs/Odometry, <robot>/odom <- <robot>/base_link, T_O_B
//   /tf                        tf2_msgs/TFMessage, the same transform
// published by /<robot>/dtif_simulate (BagParams::node). That is the default layout,
// "namespaced"; layout "fastlio" writes instead one bag per robot as recorded on a stock FAST-LIO2
// unit (<stem>_<robot>.bag, see unitBagPath): /cloud_registered (frame camera_init), /Odometry
// (camera_init <- body) and /tf, published by /laserMapping, the same names on every unit.
// All stamped with Frame::stamp. Written with rosbag_storage's rosbag::Bag and the generated
// message types; this header stays free of ROS headers (the tool includes it).
#pragma once

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "dtif/sim/simulator.h"

namespace dtif::bag {

/// Any failure to write the bag; the message names the file.
class RosbagError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace dtif::bag

namespace dtif::sim {

/// BagParams::layout values.
inline constexpr const char* kLayoutNamespaced = "namespaced";
inline constexpr const char* kLayoutFastlio = "fastlio";

struct BagParams {
  /// Topic and frame names, and files: "namespaced" (one bag, /<robot>/cloud_registered,
  /// /<robot>/Odometry, frames <robot>/odom and <robot>/base_link) or "fastlio" (a bag per robot,
  /// unitBagPath, with a stock FAST-LIO2 unit's names: /cloud_registered, /Odometry, camera_init,
  /// body; node /laserMapping, BagParams::node unused).
  std::string layout = kLayoutNamespaced;
  /// Per-frame centroid voxel filter of cloud_registered (as FAST-LIO2 publishes a downsampled
  /// scan unless dense_publish_en); 0 keeps every return (dense_publish_en), the default: the
  /// submaps TrunkExtractionNodelet assembles from the bag are then the dataset's (both are the
  /// centroid voxel filter of all returns of the window) [m].
  double voxel_m = 0.0;
  /// Then at most this many points per cloud_registered, thinned evenly in scan order (a lower
  /// point rate; a smaller bag: 16 bytes per point, ~3.2 MB/s per robot at 200k returns/s); 0: no
  /// limit, the default.
  uint32_t max_points = 0;
  /// cloud_registered is recorded this long after Odometry and /tf of the same frame, so replay
  /// delivers the pose first, as FAST-LIO2 publishes it (header stamps are not shifted) [s].
  double cloud_delay_s = 0.001;
  /// Publisher of a robot's messages in the connection headers: /<robot>/<node> (each robot's
  /// FAST-LIO2 runs in its namespace; one /tf connection per robot, each in time order).
  std::string node = "dtif_simulate";
  /// A chunk is written to disk once its data exceeds this size (rosbag record: 768 KiB)
  /// [bytes].
  uint32_t chunk_bytes = 1 << 20;
  /// Compression of the chunks: "none" (the default: fastest to write and to replay) or "lz4"
  /// (rosbag record --lz4; rosbag play decompresses it).
  std::string compression = "none";
  /// Empty when valid, else the problems, one per line.
  std::string validate() const;
};

/// Frame names of a robot in the bag (also what docs/ros.md and the launch files use).
std::string odomFrame(const std::string& robot);  ///< "<robot>/odom"
std::string bodyFrame(const std::string& robot);  ///< "<robot>/base_link"

/// The bag of one robot in the fastlio layout: `<dir>/<stem>_<robot>.bag` for path
/// `<dir>/<stem>.bag` (a path without .bag: its whole file name is the stem).
std::string unitBagPath(const std::string& path, const std::string& robot);

/// Centroid voxel filter of one frame: points and intensities averaged per voxel, voxels in
/// order of their first point; non-finite points dropped. voxel_m <= 0: no averaging.
void voxelFilter(const std::vector<Eigen::Vector3f>& points, const std::vector<float>& intensity,
                 double voxel_m, std::vector<Eigen::Vector3f>* points_out,
                 std::vector<float>* intensity_out);

/// Keeps max_points of the points (and intensities), evenly spread over the input order: indices
/// floor(i * n / max_points). max_points == 0 or n <= max_points: unchanged.
void thinEvenly(uint32_t max_points, std::vector<Eigen::Vector3f>* points,
                std::vector<float>* intensity);

/// The points (in O) and intensities of a frame's cloud_registered: voxelFilter, then
/// thinEvenly, with params' voxel_m and max_points.
void cloudRegistered(const Frame& frame, const BagParams& params,
                     std::vector<Eigen::Vector3f>* points, std::vector<float>* intensity);

/// FrameSink writing a bag (fastlio layout: a bag per robot, created with the robot's first frame).
/// Writes each bag as `<its path>`.tmp, renamed by close(); destroyed without close() (e.g. the
/// simulation threw), it leaves no bag. Not thread-safe (the simulator
/// serialises onFrame calls).
class BagFrameSink : public FrameSink {
 public:
  struct Stats {
    uint64_t frames = 0, messages = 0;
    uint64_t points_in = 0, points_out = 0;  ///< returns before / after voxel filter and thinning
    uint64_t bytes = 0;                      ///< size of the bag files
    double write_seconds = 0.0;              ///< wall-clock time spent in onFrame and close [s]
  };

  /// Throws bag::RosbagError naming the file when it cannot be created or params are invalid.
  BagFrameSink(const std::string& path, const BagParams& params = {});
  /// Without close(), removes the temporary file.
  ~BagFrameSink() override;
  BagFrameSink(const BagFrameSink&) = delete;
  BagFrameSink& operator=(const BagFrameSink&) = delete;

  /// Throws bag::RosbagError naming the file on a write error, a stamp outside ros::Time or
  /// after close().
  void onFrame(const Frame& frame) override;
  /// Finishes the bag; throws bag::RosbagError naming the file on any I/O error or when already
  /// closed.
  void close();
  const Stats& stats() const { return stats_; }
  /// The bags written (or being written), in robot name order for the fastlio layout.
  std::vector<std::string> paths() const;

 private:
  struct Writer;  // rosbag::Bag and the connections, kept out of this header
  BagParams params_;
  std::unique_ptr<Writer> writer_;
  Stats stats_;
};

}  // namespace dtif::sim
