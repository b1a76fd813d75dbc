// The map's file formats (see save_colored_cloud in voxel_map.hpp): coloured
// .ply / .pcd through the point-cloud writer.
#include <filesystem>
#include <stdexcept>
#include <string>

#include "long3r/geometry/cv/point_cloud_io.hpp"
#include "long3r/mapping/voxel_map.hpp"

namespace long3r {

void save_colored_cloud(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                        const std::vector<Rgb8>& colors, const MapSaveOptions& options) {
  // A map keeps its colours: .xyz, which the writer also knows, is refused.
  const std::optional<PointCloudFormat> format = point_cloud_format(path);
  if (format != PointCloudFormat::kPly && format != PointCloudFormat::kPcd) {
    throw std::invalid_argument("save_colored_cloud: unknown file extension '" +
                                std::filesystem::path(path).extension().string() + "' in '" + path +
                                "' (use .ply or .pcd)");
  }
  if (points.size() != colors.size()) {
    throw std::invalid_argument("save_colored_cloud: points and colors differ in length");
  }
  PointCloudWriteOptions o;
  o.ascii = options.ascii;
  o.comment = "long3r map";
  save_point_cloud(path, points, &colors, o);
}

}  // namespace long3r
