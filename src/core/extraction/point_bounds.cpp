// The region of a submap that extraction keeps (point_bounds.h).
#include "dtif/core/extraction/point_bounds.h"

#include <pcl/common/point_tests.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <vector>

namespace dtif {
namespace {

double median(std::vector<float>* v) {
  const auto mid = v->begin() + static_cast<std::ptrdiff_t>(v->size() / 2);
  std::nth_element(v->begin(), mid, v->end());
  return *mid;
}

}  // namespace

PointBounds pointBounds(const Cloud& cloud, double max_range_m) {
  constexpr size_t kSamples = 4097;
  PointBounds b;
  b.half_side_m = max_range_m;
  const size_t stride = std::max<size_t>(1, cloud.size() / kSamples);
  std::vector<float> x, y, z;
  for (size_t i = 0; i < cloud.size(); i += stride) {
    const pcl::PointXYZ& p = cloud[i];
    if (!pcl::isFinite(p)) continue;
    x.push_back(p.x), y.push_back(p.y), z.push_back(p.z);
  }
  if (x.empty()) return b;
  b.centre = Eigen::Vector3d(median(&x), median(&y), median(&z));
  return b;
}

Cloud pointsInside(const Cloud& cloud, const PointBounds& b, size_t* dropped) {
  Cloud out;
  out.reserve(cloud.size());
  *dropped = 0;
  for (const pcl::PointXYZ& p : cloud) {
    if (!pcl::isFinite(p)) continue;
    if (b.inside(p)) {
      out.push_back(p);
    } else {
      ++*dropped;
    }
  }
  out.width = static_cast<uint32_t>(out.size());
  out.height = 1;
  return out;
}

std::string boundsWarning(const TrunkExtractionStats& st, const TrunkExtractorParams& p) {
  if (st.over_point_limit) {
    return std::to_string(st.input_points) + " points exceed trunk_extraction.max_points (" +
           std::to_string(p.max_points) + "): cloud refused, no trunks extracted";
  }
  if (st.far_points > 0) {
    std::ostringstream os;
    os << st.far_points << " points farther than trunk_extraction.max_range_m (" << p.max_range_m
       << " m) from the cloud's median point dropped";
    return os.str();
  }
  return {};
}

}  // namespace dtif
