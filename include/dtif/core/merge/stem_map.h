// A field stem map (the inventory foresters have: x, y[, dbh] in plot coordinates P) as an
// anchor: registering a set of stems to it with dtif's own descriptor matching.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/types.h"

namespace dtif {

/// One tree of a field stem map.
struct FieldStem {
  std::string id;           ///< field tree id (the row number when the file has none)
  double x = 0.0, y = 0.0;  ///< plot coordinates [m]
  double dbh = 0.0;         ///< [m]; 0 when unknown
};

struct StemMapParams {
  /// Matcher/pose/verification settings for field-vs-LiDAR stems: field positions carry
  /// decimetre errors and the sources disagree on dbh (see fieldStemMapLoopParams()).
  LoopDetectorParams loop;
  DescriptorParams descriptor;     ///< of both stem sets
  double default_radius_m = 0.12;  ///< radius of a field stem without dbh [m]
  double pair_radius_m = 0.6;      ///< a stem pairs with the nearest field stem within this [m]
  int min_pairs = 6;               ///< fewer paired stems: not registered
  StemMapParams();
};

/// Matcher settings for field stem maps (wider edge/radius tolerances than LiDAR-vs-LiDAR).
LoopDetectorParams fieldStemMapLoopParams();

struct StemMapRegistration {
  bool ok = false;
  std::string reason;             ///< why not, when !ok
  Pose T_P_M = Pose::Identity();  ///< planar: yaw and x, y (z unchanged)
  /// (stem index, field index) pairs within pair_radius_m after registration.
  std::vector<std::pair<size_t, size_t>> pairs;
  double rms_m = 0.0;     ///< horizontal RMS residual of the pairs [m]
  double median_m = 0.0;  ///< median horizontal residual [m]
};

/// Field stems as trunks (z = 0 on the plot's plane, r = dbh / 2 or the default).
Trunks fieldStemsAsTrunks(const std::vector<FieldStem>& field, const StemMapParams& params);

/// Registers `stems` (any frame M, z up) to the field map: descriptor matching (matchPair) of
/// the two trunk sets, then a planar least-squares refinement on nearest-neighbour pairs.
StemMapRegistration registerStemMap(const Trunks& stems, const std::vector<FieldStem>& field,
                                    const StemMapParams& params);

}  // namespace dtif
