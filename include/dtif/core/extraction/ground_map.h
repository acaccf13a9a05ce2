// The lowest surface a submap saw: per horizontal cell of its frame S, the lowest point's z.
// Where stem bases are hidden (a helmet at -7 deg sees hardly any ground downhill on a steep
// slope), two aligned submaps still share much of this surface: where both saw the same ground,
// log or shrub top as the lowest thing in a cell, the cells differ by t_z. The mode of those
// differences fixes the elevation of a loop that no pair of seen stem bases fixes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "dtif/core/types.h"

namespace dtif {

/// Lowest point per cell, quantised. Cell (ix, iy) covers [ix, ix + 1) x [iy, iy + 1) * cell_m
/// in S; its value v gives z = z0_m + v * z_step_m. Immutable once built.
struct GroundMap {
  static constexpr int16_t kUnknown = INT16_MIN;  ///< no point in the cell

  double cell_m = 0.0;     ///< cell size; 0: no map [m]
  double z_step_m = 0.05;  ///< quantisation step of z [m]
  double z0_m = 0.0;       ///< z of value 0 [m]
  int32_t x0 = 0, y0 = 0;  ///< cell index of the first column / row
  int32_t width = 0;       ///< columns
  int32_t height = 0;      ///< rows
  std::vector<int16_t> z;  ///< row-major, width x height values (kUnknown: empty cell)

  bool empty() const { return cell_m <= 0.0 || z.empty(); }
  /// Positive sizes that fit the wire format (16-bit sides) and a value per cell.
  bool wellFormed() const;
  size_t count() const;  ///< cells with a value
  /// Value of the cell holding (x, y) in S; false when outside the map or empty.
  bool at(double x, double y, double* z_m) const;
};

/// Largest map side [cells]: a wider extent doubles the cell size until it fits.
constexpr int32_t kMaxGroundMapSide = 400;

/// Lowest point per cell of the points (x[i], y[i], z[i]) + origin (S coordinates) inside the
/// box [lo, hi] of S; cells with fewer than min_points points stay empty (far from the path a
/// cell's lowest point is whatever a few rays hit, not the same surface in two submaps).
/// Non-finite points are skipped; no point inside gives an empty map.
GroundMap makeGroundMap(const float* x, const float* y, const float* z, size_t n,
                        const Eigen::Vector3d& origin, const Eigen::Vector2d& lo,
                        const Eigen::Vector2d& hi, double cell_m, double z_step_m,
                        uint32_t min_points);

/// The map cropped, about its centre, until its wire form (encodeGroundMap) takes at most
/// max_bytes (0: no limit): a descriptor crosses a radio link and has a budget (DESIGN: 8 KB),
/// and the cells far out are the ones a loop's partner is least likely to share. A map that no
/// crop brings under the budget comes back empty.
GroundMap fitGroundMapBytes(GroundMap m, size_t max_bytes);

/// Wire form: f32 cell, f32 z step, f64 z0, i32 x0, y0, u16 width, height, then the zlib
/// stream of the row-major cells, each as its difference to a neighbour (left, else above,
/// else the previous value) in one byte: -128 empty, -127 escape followed by the i16 value.
/// An empty map encodes to no bytes.
std::vector<uint8_t> encodeGroundMap(const GroundMap& m);
/// Inverse of encodeGroundMap; no bytes give an empty map. Throws std::runtime_error on
/// malformed input.
GroundMap decodeGroundMap(const uint8_t* data, size_t size);

/// The query cells that fall on a candidate cell with a value under T_c_q: each one's centre
/// (at its value) in the candidate frame, horizontal, and the difference zc - z there.
struct GroundDifferences {
  std::vector<Eigen::Vector2d> xy;
  std::vector<double> dz;
};

/// Maps every query cell centre (at its value) through T_c_q and differences it with the
/// candidate cell it falls on. Where both maps saw the same lowest surface the differences are
/// t_z plus the residual tilt's plane; canopy or shrub tops seen in only one are outliers.
GroundDifferences groundDifferences(const GroundMap& q, const GroundMap& c, const Pose& T_c_q);

/// The elevation two maps agree on under a horizontal alignment.
struct GroundElevation {
  bool ok = false;         ///< a mode was found (see groundElevation)
  double dz_m = 0.0;       ///< correction of T_c_q's t_z [m]
  int compared = 0;        ///< query cells that fell on a candidate cell with a value
  int support = 0;         ///< of those, cells within the window of the mode
  double spread_m = 0.0;   ///< std dev of the supporting differences [m]
  double ambiguity = 1.0;  ///< runner-up / mode of the smoothed difference histogram
};

/// The mode of groundDifferences (5 cm bins, smoothed), refined to the mean within
/// `window_m`. The runner-up is the highest bin more than 2 x window_m from the mode. ok when at
/// least one cell was compared and either map is non-empty.
GroundElevation groundElevation(const GroundMap& q, const GroundMap& c, const Pose& T_c_q,
                                double window_m);

/// groundElevation of given differences (e.g. groundDifferences with a plane removed);
/// `compared` is their count.
GroundElevation groundElevationOf(const std::vector<double>& differences, double window_m);

}  // namespace dtif
