// Centroid voxel filter, filled incrementally: the downsampling of dataset submaps (dtif
// simulate) and of submaps assembled from a cloud stream (the ROS glue's SubmapAssembler), so
// that both give the same points from the same returns.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "dtif/core/cloud.h"

namespace dtif {

/// Voxels of `voxel_m` on the grid floor(p / voxel_m); each occupied voxel yields the mean of
/// its points. Bounded memory (one entry per voxel: open addressing with linear probing, cheap
/// enough to run once per lidar return). Points more than 2^20 voxels from the origin are
/// ignored. Not thread-safe; reusable across submaps via clear().
class VoxelCentroidGrid {
 public:
  /// voxel_m > 0 [m].
  explicit VoxelCentroidGrid(double voxel_m);

  void add(const Eigen::Vector3f& p);
  /// Centroids in ascending voxel key order (x, then y, then z index): deterministic, and
  /// independent of the order the points were added in.
  std::vector<Eigen::Vector3f> centroids() const;
  size_t raw() const { return raw_; }      ///< points added since clear()
  size_t voxels() const { return used_; }  ///< occupied voxels
  /// Empties the grid; keeps a grown table (the next submap needs about as many cells).
  void clear();

 private:
  // Sums relative to nothing: submap coordinates stay within ~50 m, so float sums of a few
  // hundred points keep sub-millimetre precision.
  struct Cell {
    uint64_t key = 0;
    Eigen::Vector3f sum{0, 0, 0};
    uint32_t n = 0;
  };
  Cell& find(uint64_t key);
  void grow();

  double inv_;
  std::vector<Cell> cells_;
  size_t used_ = 0;
  size_t raw_ = 0;
};

/// The same filter for a whole cloud at once: the centroids a VoxelCentroidGrid of voxel_m gives
/// for the cloud's points added in order (the same float values, in the same key order), from a
/// stable radix sort of the points' voxel keys and each voxel's sum taken in point order. A
/// submap's millions of returns are filtered several times faster than through the grid's hash
/// table (a cache miss per return) and its final sort. Keeps its buffers between calls; not
/// thread-safe.
class VoxelCentroidSorter {
 public:
  /// voxel_m > 0 [m].
  explicit VoxelCentroidSorter(double voxel_m);
  /// *cloud replaced by its voxels' centroids (a cloud of height 1).
  void filter(Cloud* cloud);

 private:
  /// Voxel keys of the points in range (their indices in idx_), packed to the bits their extent
  /// needs, in key32_ when they fit 32 bits, else in key_; the number of those bits.
  int packedKeys(const Cloud& cloud);

  double inv_;
  std::vector<uint64_t> key_, key_tmp_;
  std::vector<uint32_t> key32_, key32_tmp_;
  std::vector<uint32_t> idx_, idx_tmp_;
  std::vector<Eigen::Vector3f> centroids_;
};

}  // namespace dtif
