// Scan-context-style place recognition baseline for issue #5, written here from the idea of
// Scan Context (G. Kim, A. Kim, IROS 2018): a polar grid around the submap origin whose bins
// hold the highest point above the local ground, a rotation-invariant ring key for a k-nearest
// pre-selection, and a column-shift search that gives the distance and the yaw. It recognises
// places only (no translation). ROS-free; plain loops over the cloud, no PCL algorithms. Every
// function is pure: safe to call from several threads on shared const inputs.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "dtif/core/cloud.h"
#include "dtif/core/types.h"

namespace dtif::baselines {

struct ScanContextParams {
  int rings = 20;                   ///< radial bins up to max_range_m [-]
  int sectors = 60;                 ///< azimuth bins over 360 deg (6 deg each) [-]
  double max_range_m = 30.0;        ///< points farther from the origin are ignored [m]
  double ground_tile_m = 4.0;       ///< side of the square tiles of the local ground [m]
  double ground_percentile = 0.05;  ///< local ground = this quantile of z in the tile [0..1]
  double max_height_m = 30.0;       ///< heights above ground are clamped to this [m]
  int min_occupied_bins = 30;       ///< fewer non-empty bins make the descriptor invalid [-]
  int candidates = 10;              ///< ring-key nearest neighbours compared in full [-]
  double max_distance = 0.3;        ///< an answer needs a distance below this [0..1]
  /// Empty when every field is usable, else the problems, one per line.
  std::string validate() const;
};

/// One submap's scan context: rings x sectors bin heights (row r, column s; 0 = empty) and its
/// ring key (fraction of occupied sectors per ring). Immutable after makeScanContext.
struct ScanContext {
  int rings = 0, sectors = 0;
  std::vector<float> bins;      ///< row-major, rings * sectors, height above ground [m]
  std::vector<float> ring_key;  ///< per ring, occupied sectors / sectors [0..1]
  bool valid = false;
  std::string invalid_reason;  ///< why it is not valid (empty when valid)
  /// Bytes of the stored descriptor (bins and ring key as float32).
  size_t bytes() const;
};

/// Builds the scan context of a gravity-aligned submap in its own frame S. Non-finite points
/// are dropped; an empty or too sparse cloud gives an invalid descriptor (never throws, except
/// std::invalid_argument when params do not validate).
ScanContext makeScanContext(const Cloud& cloud_S, const ScanContextParams& params);

/// Distance of two scan contexts and the yaw that aligns them.
struct ScanContextMatch {
  double distance = 1.0;  ///< min over column shifts of the mean cosine distance [0..1]
  int shift = 0;          ///< best column shift, sectors [0, sectors)
  double yaw_rad = 0.0;   ///< yaw of T_c_q implied by the shift, in (-pi, pi] [rad]
};

/// The scan-context distance of query q against candidate c: for every shift s, column k of q
/// is compared with column (k + s) mod sectors of c (a point of q at azimuth a lies at a + yaw
/// in c); the mean cosine distance over the columns non-empty in both, 1 when none are. The
/// smallest gives distance, shift and yaw. Invalid or differently shaped inputs give distance 1.
ScanContextMatch scanContextDistance(const ScanContext& q, const ScanContext& c);

/// Squared Euclidean distance of two ring keys (infinity when the shapes differ).
double ringKeyDistance(const ScanContext& a, const ScanContext& b);

/// The best of `database` for q: ring-key pre-selection of params.candidates entries, then the
/// full distance on those. `index` is the database position of the answer (or -1 when the
/// database has no valid entry); the answer is accepted by the caller against max_distance.
struct ScanContextAnswer {
  int64_t index = -1;
  ScanContextMatch match;
};
ScanContextAnswer queryScanContext(const ScanContext& q,
                                   const std::vector<const ScanContext*>& database,
                                   const ScanContextParams& params);

}  // namespace dtif::baselines
