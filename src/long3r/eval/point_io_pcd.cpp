// PCD reading through PCL, kept in its own translation unit (PCL headers are
// slow to compile).
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace long3r {

std::vector<Eigen::Vector3f> load_point_cloud_pcd(const std::string& path) {
  pcl::PointCloud<pcl::PointXYZ> cloud;
  if (pcl::io::loadPCDFile(path, cloud) != 0) throw std::runtime_error("cannot read PCD " + path);
  std::vector<Eigen::Vector3f> out;
  out.reserve(cloud.size());
  for (const auto& p : cloud) {
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
      out.emplace_back(p.x, p.y, p.z);
  }
  return out;
}

}  // namespace long3r
