// Where a submap saw anything at trunk height: the occupied horizontal cells of its points
// 0.3-3.0 m above the local ground, in the submap frame S. These are the cells of the evaluation
// protocol's overlap (DATASET.md), so verification can measure how much an aligned pair shares.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/types.h"

namespace dtif {

/// Occupancy bitmap of horizontal cells in S. Cell (ix, iy) covers
/// [ix * cell_m, (ix + 1) * cell_m) x [iy * cell_m, (iy + 1) * cell_m). Immutable once built.
struct Footprint {
  double cell_m = 0.0;        ///< cell size; 0: no footprint [m]
  int32_t x0 = 0, y0 = 0;     ///< cell index of the bitmap's first column / row
  int32_t width = 0;          ///< columns
  int32_t height = 0;         ///< rows
  std::vector<uint8_t> bits;  ///< row-major; cell (x0 + k % width, y0 + k / width) is bit k

  bool empty() const { return cell_m <= 0.0 || count() == 0; }
  /// A cell size, a size that fits the wire formats (16-bit sides) and a bitmap of that size.
  bool wellFormed() const;
  size_t count() const;                         ///< occupied cells
  bool occupied(int64_t ix, int64_t iy) const;  ///< false outside the bitmap
};

/// Largest bitmap side [cells]; a wider extent doubles the cell size until it fits, which keeps
/// the descriptor within its radio budget (at most kMaxFootprintSide^2 / 8 bytes).
constexpr int32_t kMaxFootprintSide = 160;

/// Footprint of the given occupied cells (indices at `cell_m`); duplicates are fine.
Footprint makeFootprint(const std::vector<std::pair<int64_t, int64_t>>& cells, double cell_m);

/// Overlap of two footprints under T_c_q (query cells mapped into the candidate frame):
/// |cells(q) ∩ cells(c)| / min(|cells(q)|, |cells(c)|), DATASET.md's definition. Returns -1
/// when either footprint is empty.
double footprintOverlap(const Footprint& q, const Footprint& c, const Pose& T_c_q);

/// DATASET.md's overlap cells: the cells (side `cell_m`, in frame F) of a submap's points
/// 0.3-3.0 m above its local ground, the local ground of each 2 m tile of S being the 5th
/// percentile of z in the 6 m window around it. `max_ground_samples` > 0 takes the percentiles
/// on an even subsample of at most that many points (the descriptor's footprint, timed);
/// 0 uses every point (the evaluation). Sorted, unique.
std::vector<std::pair<int64_t, int64_t>> trunkHeightCells(const Cloud& cloud_S, const Pose& T_F_S,
                                                          double cell_m,
                                                          size_t max_ground_samples = 0);

/// What trunkHeightCells reads in its first passes over a cloud, gathered by a caller that
/// passes over the cloud anyway (extraction), so trunkHeightCells passes over it once more only.
struct HeightCellsPrepass {
  size_t finite = 0;               ///< finite points of the cloud
  float minx = 0.0f, maxx = 0.0f;  ///< extent of the finite points [m]
  float miny = 0.0f, maxy = 0.0f;  ///< [m]
  size_t stride = 0;               ///< samples: every stride-th finite point, from the first
  std::vector<float> sx, sy, sz;   ///< the samples' coordinates [m]
};

/// trunkHeightCells with the extent and ground samples of `pre` (the same cells); its samples
/// are used when their stride is the one max_ground_samples asks for, else taken again.
std::vector<std::pair<int64_t, int64_t>> trunkHeightCells(const Cloud& cloud_S, const Pose& T_F_S,
                                                          double cell_m, size_t max_ground_samples,
                                                          const HeightCellsPrepass& pre);

}  // namespace dtif
