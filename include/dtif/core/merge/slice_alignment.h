// The submaps aligned on the bark itself before the inventory's DBH refit (StemSlices): the
// merged poses are a few centimetres off each other, and a pooled slice drawn from arcs that far
// apart fits a circle centimetres too small or too large (with the ground-truth poses instead of
// the merged ones, the median DBH error of the built-in scenes falls by 0.1-0.55 cm). Each
// submap's slices of many stems, seen from different sides, fix a small planar correction of
// that submap; each well-seen stem contributes its circle. A Ceres problem like a bundle
// adjustment: submaps as cameras, stems as landmarks, bark points as observations.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace dtif {

/// A submap's planar correction in M: p' = o + R(dyaw) (p - o) + (dx, dy), about its origin o.
struct ViewCorrection {
  double dx = 0.0, dy = 0.0;  ///< [m]
  double dyaw = 0.0;          ///< [rad]
};

struct SliceAlignmentParams {
  double sigma_m = 0.03;        ///< prior std dev of a submap's correction, per axis [m]
  double sigma_deg = 0.3;       ///< ... of its yaw [deg]
  double point_sigma_m = 0.01;  ///< a bark point's distance to its circle: noise [m]
  double loss_sigmas = 2.0;     ///< Cauchy scale on a point's residual [point_sigma_m]
  size_t points_per_view = 32;  ///< per stem and submap, evenly strided
  /// A submap is corrected only with points on at least this many stems: on one stem its shift
  /// trades against the radius, and a one-sided arc's curvature is biased small by the range
  /// noise (2 sigma^2 / r), so one stem would pull the arcs into that smaller circle.
  size_t min_stems_per_view = 3;
  /// ... and whose arcs face different ways: the length of the mean of the unit vectors from
  /// each stem's centre to its arc's middle at most this. A submap that sees its stems from one
  /// side (a sensor beside the group) could shift along that side as freely as their radii
  /// change, and would take up their range-noise bias [0..1]
  double max_facing_resultant = 0.8;
  int max_iterations = 20;  ///< Levenberg-Marquardt iterations
};

/// One stem's pooled slice for the alignment: its points relative to `seed` (M), the submap
/// (view) of each, each view's points consecutive (as StemSlices gathers them), and the circle
/// fitted to them all (relative to seed).
struct AlignedSlice {
  Eigen::Vector2d seed = Eigen::Vector2d::Zero();
  const std::vector<Eigen::Vector2f>* xy = nullptr;
  const std::vector<uint32_t>* view = nullptr;
  double cx = 0.0, cy = 0.0, r = 0.0;
};

/// What the alignment used and did.
struct SliceAlignmentStats {
  size_t stems = 0;          ///< stems that took part
  size_t views = 0;          ///< submaps corrected (min_stems_per_view)
  size_t points = 0;         ///< residuals
  double max_shift_m = 0.0;  ///< the largest correction's shift [m]
};

/// The correction of each view (`origins`: the views' origins in M, by view index) that brings
/// the stems' points onto common circles, each view's correction drawn towards none by the
/// prior. Only points within `inlier_m` of their stem's given circle take part. Views with
/// points on fewer than min_stems_per_view stems, or on stems seen from one side
/// (max_facing_resultant), keep none (their points still shape the circles). Deterministic; no
/// stems: all zero.
std::vector<ViewCorrection> alignSliceViews(const std::vector<Eigen::Vector2d>& origins,
                                            const std::vector<AlignedSlice>& stems, double inlier_m,
                                            const SliceAlignmentParams& params,
                                            SliceAlignmentStats* stats = nullptr);

/// A point p of a slice (relative to its stem's seed) moved by correction c of its view, whose
/// origin lies at o relative to the seed. Relative coordinates throughout: plot coordinates
/// (500 km out) would cost the point its sub-millimetres on the way through them.
inline Eigen::Vector2d correctedPoint(const Eigen::Vector2d& p, const Eigen::Vector2d& o,
                                      const ViewCorrection& c) {
  const Eigen::Vector2d a = p - o;
  const double cs = std::cos(c.dyaw), sn = std::sin(c.dyaw);
  return o + Eigen::Vector2d(cs * a.x() - sn * a.y() + c.dx, sn * a.x() + cs * a.y() + c.dy);
}

}  // namespace dtif
