#include "dtif/core/merge/stem_slices.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>

#include "dtif/core/cells.h"
#include "dtif/core/extraction/trunk_extractor.h"

namespace dtif {
namespace {

constexpr double kMinRadiusM = 0.01;  // a seed radius below this is taken as this [m]
constexpr double kCellM = 1.0;        // stem lookup grid [m]
constexpr double kMaxReachM = 10.0;   // a trunk reaching farther is no stem [m]

double seedRadius(const MergedStem& s) { return std::max(0.5 * s.dbh, kMinRadiusM); }

}  // namespace

SliceFit fitStemSlice(const std::vector<Eigen::Vector2d>& xy, double x0, double y0, double r0,
                      const StemFusionParams& params) {
  SliceFit out;
  r0 = std::max(r0, kMinRadiusM);
  CircleFitParams cp;
  cp.inlier_m = params.slice_inlier_m;
  // The inventory's radius can be half the true one (fits up the stem where the base was a
  // guess), but a circle farther off it, or centred beyond the margin, is a neighbour, a branch
  // or a shrub in the slice.
  cp.min_radius_m = 0.5 * r0;
  cp.max_radius_m = 2.0 * r0 + 0.05;
  const CircleFit f = fitCircleRobust(xy, cp);
  if (!f.ok || std::hypot(f.cx - x0, f.cy - y0) > params.slice_margin_m) return out;
  out.cx = f.cx, out.cy = f.cy, out.r = f.r, out.arc_deg = f.arc_deg;
  out.one_sided = f.arc_deg < params.slice_min_arc_deg;
  out.shrunk = !out.one_sided && f.r < (1.0 - params.slice_max_shrink) * r0;
  out.encloses = !out.one_sided && !out.shrunk && f.inlier_ratio < params.slice_min_inlier_ratio;
  out.ok = !out.one_sided && !out.shrunk && !out.encloses;
  return out;
}

StemSlices::StemSlices(const std::vector<MergedStem>& stems, const StemFusionParams& params)
    : stems_(stems), p_(params), slices_(stems.size()) {
  auto cell = [&](double v) { return cellIndex(v / kCellM); };
  for (size_t k = 0; k < stems_.size(); ++k) {
    const MergedStem& s = stems_[k];
    if (!std::isfinite(s.x) || !std::isfinite(s.y) || !std::isfinite(s.z_base)) continue;
    const double reach = seedRadius(s) + p_.slice_margin_m;
    for (int64_t ix = cell(s.x - reach); ix <= cell(s.x + reach); ++ix) {
      for (int64_t iy = cell(s.y - reach); iy <= cell(s.y + reach); ++iy)
        grid_[packCell(ix, iy)].push_back(k);
    }
  }
}

void StemSlices::addSubmap(int component, const Pose& T_M_S, const Cloud& cloud_S) {
  if (grid_.empty()) return;
  const Eigen::Matrix3d R = T_M_S.linear();
  const Eigen::Vector3d t = T_M_S.translation();
  const uint32_t view = static_cast<uint32_t>(origins_.size());
  origins_.push_back(t.head<2>());
  std::map<size_t, std::vector<Eigen::Vector2f>> found;  // stem -> points, relative to its centre
  for (const pcl::PointXYZ& pt : cloud_S.points) {
    if (!std::isfinite(pt.x) || !std::isfinite(pt.y) || !std::isfinite(pt.z)) continue;
    const Eigen::Vector3d q = R * Eigen::Vector3d(pt.x, pt.y, pt.z) + t;
    auto it = grid_.find(packCell(cellIndex(q.x() / kCellM), cellIndex(q.y() / kCellM)));
    if (it == grid_.end()) continue;
    for (size_t k : it->second) {
      const MergedStem& s = stems_[k];
      const double h = q.z() - s.z_base;
      if (s.component != component || h < p_.slice_min_h_m || h > p_.slice_max_h_m) continue;
      // Relative to the centre: floats keep millimetres even in plot coordinates.
      const double dx = q.x() - s.x, dy = q.y() - s.y;
      if (std::hypot(dx, dy) <= seedRadius(s) + p_.slice_margin_m)
        found[k].emplace_back(static_cast<float>(dx), static_cast<float>(dy));
    }
  }
  const size_t cap = static_cast<size_t>(p_.slice_max_points_per_submap);
  for (const auto& [k, pts] : found) {
    Slice& sl = slices_[k];
    const size_t n = std::min(cap, pts.size());
    for (size_t j = 0; j < n; ++j) sl.xy.push_back(pts[j * pts.size() / n]);
    sl.view.insert(sl.view.end(), n, view);
    ++sl.submaps;
  }
}

Cloud::Ptr keepSliceCandidates(const Cloud& cloud_S, const Trunks& trunks_S,
                               const Eigen::Matrix3d& R_L_S, const StemFusionParams& params) {
  const double lo = params.slice_min_h_m - params.slice_keep_band_m;
  const double hi = params.slice_max_h_m + params.slice_keep_band_m;
  std::vector<Eigen::Vector3d> base_L;
  std::vector<double> reach;
  for (const TrunkLandmark& t : trunks_S) {
    base_L.push_back(R_L_S * Eigen::Vector3d(t.x, t.y, t.z));
    reach.push_back(std::max(t.r, kMinRadiusM) + params.slice_margin_m +
                    params.slice_keep_margin_m);
  }
  // Trunks by the cells their reach touches: a point tests only the trunks of its own cell
  // (a submap of ~1 M points and ~200 trunks and known stems would otherwise test every pair).
  auto cell = [](double v) { return cellIndex(v / kCellM); };
  std::unordered_map<int64_t, std::vector<size_t>> grid;
  for (size_t k = 0; k < base_L.size(); ++k) {
    if (!base_L[k].allFinite() || !(reach[k] <= kMaxReachM)) continue;  // no stem: malformed
    for (int64_t ix = cell(base_L[k].x() - reach[k]); ix <= cell(base_L[k].x() + reach[k]); ++ix) {
      for (int64_t iy = cell(base_L[k].y() - reach[k]); iy <= cell(base_L[k].y() + reach[k]); ++iy)
        grid[packCell(ix, iy)].push_back(k);
    }
  }
  std::vector<std::vector<size_t>> near(trunks_S.size());  // trunk -> point indices, in order
  for (size_t i = 0; i < cloud_S.size(); ++i) {
    const pcl::PointXYZ& pt = cloud_S[i];
    if (!std::isfinite(pt.x) || !std::isfinite(pt.y) || !std::isfinite(pt.z)) continue;
    const Eigen::Vector3d q = R_L_S * Eigen::Vector3d(pt.x, pt.y, pt.z);
    const auto it = grid.find(packCell(cell(q.x()), cell(q.y())));
    if (it == grid.end()) continue;
    for (size_t k : it->second) {
      const double h = q.z() - base_L[k].z();
      if (h >= lo && h <= hi &&
          std::hypot(q.x() - base_L[k].x(), q.y() - base_L[k].y()) <= reach[k])
        near[k].push_back(i);
    }
  }
  // A point near two trunks is kept once; the strided picks stay in cloud order.
  std::vector<size_t> keep;
  const size_t cap = static_cast<size_t>(params.slice_keep_max_points);
  for (const std::vector<size_t>& idx : near) {
    const size_t n = std::min(cap, idx.size());
    for (size_t j = 0; j < n; ++j) keep.push_back(idx[j * idx.size() / n]);
  }
  std::sort(keep.begin(), keep.end());
  keep.erase(std::unique(keep.begin(), keep.end()), keep.end());
  Cloud::Ptr out(new Cloud);
  out->reserve(keep.size());
  for (size_t i : keep) out->push_back(cloud_S[i]);
  return out;
}

Cloud::Ptr keepSliceBand(const Cloud& cloud_S, const Eigen::Matrix3d& R_L_S,
                         const StemFusionParams& params) {
  constexpr double kBandCellM = 1.0;   // cell of the lowest points [m]
  constexpr double kSlopeRiseM = 1.0;  // a slope's rise across a cell, allowed for [m]
  const double top = params.slice_max_h_m + params.slice_keep_band_m + kSlopeRiseM;
  const Eigen::Matrix3f R = R_L_S.cast<float>();
  // Levelled z and cell per point (the cell key of a non-finite point is never looked up).
  std::vector<float> z_L(cloud_S.size());
  std::vector<int64_t> key(cloud_S.size());
  std::unordered_map<int64_t, float> lowest;
  for (size_t i = 0; i < cloud_S.size(); ++i) {
    const Eigen::Vector3f q = R * cloud_S[i].getVector3fMap();
    if (!q.allFinite()) {
      z_L[i] = NAN;
      continue;
    }
    z_L[i] = q.z();
    key[i] = packCell(cellIndex(q.x() / kBandCellM), cellIndex(q.y() / kBandCellM));
    auto [it, fresh] = lowest.emplace(key[i], q.z());
    if (!fresh) it->second = std::min(it->second, q.z());
  }
  Cloud::Ptr out(new Cloud);
  for (size_t i = 0; i < cloud_S.size(); ++i) {
    if (std::isfinite(z_L[i]) && z_L[i] <= lowest[key[i]] + top) out->push_back(cloud_S[i]);
  }
  return out;
}

bool StemSlices::enoughPoints(size_t k) const {
  const Slice& sl = slices_[k];
  return sl.xy.size() >= static_cast<size_t>(p_.slice_min_points) &&
         sl.submaps >= p_.slice_min_submaps;
}

std::vector<ViewCorrection> StemSlices::alignViews(StemSliceStats* st) const {
  if (!(p_.slice_align_sigma_m > 0.0)) return {};  // the points as they are
  // Only stems whose pooled circle is accepted as it is: their arcs span the stem, so the
  // views' offsets show against each other instead of in the radius.
  std::vector<AlignedSlice> stems;
  for (size_t k = 0; k < stems_.size(); ++k) {
    if (!enoughPoints(k)) continue;
    const SliceFit f = fitStemSlice(correctedSlice(k, {}), 0.0, 0.0, seedRadius(stems_[k]), p_);
    if (!f.ok) continue;
    stems.push_back({Eigen::Vector2d(stems_[k].x, stems_[k].y), &slices_[k].xy, &slices_[k].view,
                     f.cx, f.cy, f.r});
  }
  SliceAlignmentParams ap;
  ap.sigma_m = p_.slice_align_sigma_m;
  ap.sigma_deg = p_.slice_align_sigma_deg;
  return alignSliceViews(origins_, stems, p_.slice_inlier_m, ap, &st->alignment);
}

std::vector<Eigen::Vector2d> StemSlices::correctedSlice(
    size_t k, const std::vector<ViewCorrection>& c) const {
  const Slice& sl = slices_[k];
  const Eigen::Vector2d seed(stems_[k].x, stems_[k].y);
  std::vector<Eigen::Vector2d> xy;
  xy.reserve(sl.xy.size());
  for (size_t j = 0; j < sl.xy.size(); ++j) {
    const Eigen::Vector2d p = sl.xy[j].cast<double>();
    xy.push_back(c.empty() ? p : correctedPoint(p, origins_[sl.view[j]] - seed, c[sl.view[j]]));
  }
  return xy;
}

std::vector<MergedStem> StemSlices::refit(StemSliceStats* stats) const {
  StemSliceStats st;
  st.stems = stems_.size();
  std::vector<MergedStem> out = stems_;
  const std::vector<ViewCorrection> corrections = alignViews(&st);
  for (size_t k = 0; k < stems_.size(); ++k) {
    const Slice& sl = slices_[k];
    st.points += sl.xy.size();
    st.submap_views += static_cast<size_t>(sl.submaps);
    if (!enoughPoints(k)) {
      ++st.too_few;
      continue;
    }
    const std::vector<Eigen::Vector2d> xy = correctedSlice(k, corrections);
    const SliceFit f = fitStemSlice(xy, 0.0, 0.0, seedRadius(stems_[k]), p_);
    if (!f.ok) {
      if ((f.one_sided || f.shrunk) && f.arc_deg >= p_.slice_blend_min_arc_deg) {
        out[k].dbh = 0.5 * (out[k].dbh + 2.0 * f.r);
        ++st.blended;
      } else {
        // An enclosing circle's radius is the clutter's: nothing of it is worth blending.
        ++(f.one_sided  ? st.one_sided
           : f.shrunk   ? st.shrunk
           : f.encloses ? st.enclosing
                        : st.no_fit);
      }
      continue;
    }
    out[k].dbh = 2.0 * f.r;
    // The pooled circle's centre is the stem's axis; the observations' median leans toward
    // where the robots walked (each one-sided fit's centre sits too close to its sensor).
    out[k].x += f.cx;
    out[k].y += f.cy;
    ++st.refitted;
  }
  if (stats) *stats = st;
  return out;
}

}  // namespace dtif
