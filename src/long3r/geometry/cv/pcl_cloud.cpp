#include "long3r/geometry/cv/pcl_cloud.hpp"

#include <stdexcept>

namespace long3r {

ColoredCloud to_pcl_cloud(const std::vector<Eigen::Vector3f>& points,
                          const std::vector<Rgb8>& colors) {
  if (points.size() != colors.size()) {
    throw std::invalid_argument("to_pcl_cloud: " + std::to_string(points.size()) + " points but " +
                                std::to_string(colors.size()) + " colours");
  }
  ColoredCloud cloud;
  cloud.resize(points.size());  // width = size, height = 1
  bool finite = true;
  for (std::size_t i = 0; i < points.size(); ++i) {
    pcl::PointXYZRGB& p = cloud[i];
    p.getVector3fMap() = points[i];
    p.r = colors[i][0];
    p.g = colors[i][1];
    p.b = colors[i][2];
    finite = finite && points[i].allFinite();
  }
  cloud.is_dense = finite;
  return cloud;
}

}  // namespace long3r
