// Density adaptation of trunk extraction: the point-count thresholds were tuned on clouds of a
// given density; a unit that keeps every third return (FAST-LIO2's point_filter_num: 3) or a
// slower sensor puts a third of the points on every stem, and fixed counts then lose the
// trunks beyond two thirds of the range the thresholds allowed. The density is measured on the
// trunks a first pass fits, where it matters (bark at breast height), as an angular density
// (normalised to 10 m from the sensor), so it does not depend on how far the stand's stems are.
#include <algorithm>
#include <cmath>
#include <vector>

#include "dtif/core/extraction/extraction_stages.h"

namespace dtif {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRangeNorm = 10.0;  // range the density is normalised to [m]

int scaledCount(int n, double scale, int floor) {
  return std::max(floor, static_cast<int>(std::lround(n * scale)));
}

}  // namespace

double barkDensity(const std::vector<FoundTrunk>& found, const TrunkExtractorParams& p) {
  const double band_h = p.fit_max_h_m - p.fit_min_h_m;
  std::vector<double> rho;
  for (const FoundTrunk& f : found) {
    const double d = planarDist(f.trunk.x, f.trunk.y);
    // Near stems are seen from everywhere along the route and saturate the submap's voxel
    // filter: their density says nothing about the sensor's.
    if (d < p.density_min_range_m || !(f.arc_deg > 0.0) || !(f.trunk.r > 0.0)) continue;
    const double bark_m2 = f.arc_deg / 360.0 * 2.0 * kPi * f.trunk.r * band_h;
    rho.push_back(static_cast<double>(f.inliers) / bark_m2 * (d / kRangeNorm) * (d / kRangeNorm));
  }
  if (rho.empty() || rho.size() < static_cast<size_t>(p.density_min_trunks)) return 0.0;
  // The median: occlusion and partial views lower single trunks, not the sensor.
  const size_t mid = (rho.size() - 1) / 2;
  std::nth_element(rho.begin(), rho.begin() + mid, rho.end());
  return rho[mid];
}

double densityScale(double density, const TrunkExtractorParams& p) {
  if (!(p.density_reference > 0.0) || !(density > 0.0)) return 1.0;
  return std::clamp(density / p.density_reference, p.density_min_scale, 1.0);
}

TrunkExtractorParams scaledForDensity(const TrunkExtractorParams& p, double scale) {
  TrunkExtractorParams q = p;
  if (!(scale < 1.0)) return q;
  // Floors: two points per column, and 3 points for a circle's RANSAC sample plus two to tell
  // it from noise. The stem-base counts stay: with fewer ring points a base on a shrub or log
  // passes the max_base_below_points check (dense_slope at a third of the returns: a loop
  // 0.75 m off in z).
  q.min_column_points = scaledCount(p.min_column_points, scale, std::min(p.min_column_points, 2));
  q.min_fit_points = scaledCount(p.min_fit_points, scale, std::min(p.min_fit_points, 5));
  return q;
}

}  // namespace dtif
