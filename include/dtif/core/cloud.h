// The point cloud every stage of the core reads: a submap in its frame S.
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

namespace dtif {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;

}  // namespace dtif
