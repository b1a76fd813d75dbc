// Coloured points as PCL's cloud (pcl::PointXYZRGB): the map's type at the
// boundary where PCL takes over (~map through pcl_conversions, PCL's filters).
// Frames: the points' own; no transform is applied.
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Core>
#include <vector>

#include "long3r/geometry/cv/point_cloud_io.hpp"

namespace long3r {

using ColoredCloud = pcl::PointCloud<pcl::PointXYZRGB>;

// An unorganised cloud (height 1), dense when every point is finite. colors
// are RGB, index-aligned with points; std::invalid_argument when their
// numbers differ.
ColoredCloud to_pcl_cloud(const std::vector<Eigen::Vector3f>& points,
                          const std::vector<Rgb8>& colors);

}  // namespace long3r
