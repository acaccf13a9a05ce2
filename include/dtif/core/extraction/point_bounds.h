// What a submap's cloud may hold before extraction sizes anything from it: the sensor sees a
// bounded region, so the grids of extraction are bounded by max_range_m about the cloud's
// median point, never by its worst point (one stray return at 1e7 m would otherwise size a
// grid of kilometres, or cost every other point its float precision). docs/limits.md.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <string>

#include "dtif/core/cloud.h"
#include "dtif/core/extraction/trunk_extractor.h"

namespace dtif {

/// The box of a cloud that extraction keeps: within half_side_m of centre on every axis.
struct PointBounds {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< median point of the finite points [m]
  double half_side_m = 0.0;                          ///< max_range_m [m]
  bool inside(const pcl::PointXYZ& p) const {
    return std::abs(p.x - centre.x()) <= half_side_m && std::abs(p.y - centre.y()) <= half_side_m &&
           std::abs(p.z - centre.z()) <= half_side_m;
  }
};

/// The per-axis median of the finite points (of an even subsample of at most 4097 points: a
/// median does not need more) and the box of half side max_range_m about it. A cloud without
/// finite points gets the box about the origin.
PointBounds pointBounds(const Cloud& cloud, double max_range_m);

/// The finite points of `cloud` inside `b`; *dropped counts the finite points outside.
Cloud pointsInside(const Cloud& cloud, const PointBounds& b, size_t* dropped);

/// The warning an extraction's bounds call for ("" when none applied): points dropped beyond
/// max_range_m, or a cloud refused for more than max_points.
std::string boundsWarning(const TrunkExtractionStats& st, const TrunkExtractorParams& p);

}  // namespace dtif
