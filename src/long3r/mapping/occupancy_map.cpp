#include "long3r/mapping/occupancy_map.hpp"

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <stdexcept>

namespace long3r {

void OccupancyMapConfig::validate(const config::FieldCheck& check) const {
  check.require(resolution_m > 0.0 && std::isfinite(resolution_m), "resolution_m",
                "must be positive and finite");
  check.require(prob_hit > 0.5 && prob_hit < 1.0, "prob_hit", "must be in (0.5, 1)");
  check.require(prob_miss > 0.0 && prob_miss < 0.5, "prob_miss", "must be in (0, 0.5)");
  check.require(clamp_min > 0.0 && clamp_min < 0.5, "clamp_min", "must be in (0, 0.5)");
  check.require(clamp_max > 0.5 && clamp_max < 1.0, "clamp_max", "must be in (0.5, 1)");
  check.require(max_range_m > 0.0 && std::isfinite(max_range_m), "max_range_m",
                "must be positive and finite");
}

struct OccupancyMap::Impl {
  octomap::OcTree tree;
  explicit Impl(const OccupancyMapConfig& c) : tree(c.resolution_m) {
    tree.setProbHit(c.prob_hit);
    tree.setProbMiss(c.prob_miss);
    tree.setClampingThresMin(c.clamp_min);
    tree.setClampingThresMax(c.clamp_max);
  }
};

OccupancyMap::OccupancyMap(const OccupancyMapConfig& config) : config_(config) {
  config.validate({"occupancy map config", ""});
  impl_ = std::make_unique<Impl>(config_);
}
OccupancyMap::~OccupancyMap() = default;
OccupancyMap::OccupancyMap(OccupancyMap&&) noexcept = default;
OccupancyMap& OccupancyMap::operator=(OccupancyMap&&) noexcept = default;

std::size_t OccupancyMap::insert(const std::vector<Eigen::Vector3f>& points_F,
                                 const Eigen::Vector3d& origin_F) {
  if (!origin_F.allFinite()) {
    throw std::invalid_argument("OccupancyMap::insert: the camera's position is not finite");
  }
  octomap::Pointcloud cloud;
  cloud.reserve(points_F.size());
  for (const Eigen::Vector3f& p : points_F) {
    if (p.allFinite()) cloud.push_back(p.x(), p.y(), p.z());
  }
  if (cloud.size() == 0) return 0;
  // discretize: one ray per endpoint voxel, as octomap_server's dense clouds.
  impl_->tree.insertPointCloud(
      cloud,
      octomap::point3d(static_cast<float>(origin_F.x()), static_cast<float>(origin_F.y()),
                       static_cast<float>(origin_F.z())),
      config_.max_range_m, /*lazy_eval=*/false, /*discretize=*/true);
  return cloud.size();
}

OccupancyGrid OccupancyMap::project(const GridBand& band) const {
  OccupancyGrid g;
  const octomap::OcTree& tree = impl_->tree;
  if (tree.size() == 0) return g;
  const double res = config_.resolution_m;
  double x0, y0, z0, x1, y1, z1;
  tree.getMetricMin(x0, y0, z0);
  tree.getMetricMax(x1, y1, z1);
  g.resolution_m = res;
  g.origin_x_m = std::floor(x0 / res) * res;
  g.origin_y_m = std::floor(y0 / res) * res;
  g.width = std::max(1, static_cast<int>(std::ceil((x1 - g.origin_x_m) / res - 1e-9)));
  g.height = std::max(1, static_cast<int>(std::ceil((y1 - g.origin_y_m) / res - 1e-9)));
  g.cells.assign(static_cast<std::size_t>(g.width) * g.height, OccupancyGrid::kUnknown);
  const double z_lo = band.floor_z_m + band.min_height_m, z_hi = band.floor_z_m + band.max_height_m;
  const octomap::point3d lo(static_cast<float>(x0), static_cast<float>(y0),
                            static_cast<float>(z_lo));
  const octomap::point3d hi(static_cast<float>(x1), static_cast<float>(y1),
                            static_cast<float>(z_hi));
  for (auto it = tree.begin_leafs_bbx(lo, hi), end = tree.end_leafs_bbx(); it != end; ++it) {
    const double half = 0.5 * it.getSize();
    // A leaf only partly inside the band (a pruned one) still speaks for it.
    if (it.getZ() + half <= z_lo || it.getZ() - half >= z_hi) continue;
    const bool occ = tree.isNodeOccupied(*it);
    const int cx0 =
        std::max(0, static_cast<int>(std::floor((it.getX() - half - g.origin_x_m) / res + 1e-6)));
    const int cy0 =
        std::max(0, static_cast<int>(std::floor((it.getY() - half - g.origin_y_m) / res + 1e-6)));
    const int cx1 = std::min(
        g.width, static_cast<int>(std::ceil((it.getX() + half - g.origin_x_m) / res - 1e-6)));
    const int cy1 = std::min(
        g.height, static_cast<int>(std::ceil((it.getY() + half - g.origin_y_m) / res - 1e-6)));
    for (int cy = cy0; cy < cy1; ++cy) {
      for (int cx = cx0; cx < cx1; ++cx) {
        std::int8_t& c = g.cells[static_cast<std::size_t>(cy) * g.width + cx];
        if (occ) {
          c = OccupancyGrid::kOccupied;
        } else if (c == OccupancyGrid::kUnknown) {
          c = OccupancyGrid::kFree;
        }
      }
    }
  }
  for (std::int8_t c : g.cells) {
    g.occupied += c == OccupancyGrid::kOccupied ? 1 : 0;
    g.free += c == OccupancyGrid::kFree ? 1 : 0;
  }
  return g;
}

std::optional<double> OccupancyMap::floor_z() const {
  const octomap::OcTree& tree = impl_->tree;
  const double res = config_.resolution_m;
  // Occupied area per voxel layer (a pruned leaf counts for its cells).
  std::map<long, double> area;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    if (!tree.isNodeOccupied(*it)) continue;
    const double s = it.getSize();
    area[static_cast<long>(std::floor((it.getZ() - 0.5 * s) / res + 1e-6))] +=
        (s / res) * (s / res);
  }
  if (area.empty()) return std::nullopt;
  const long lowest = area.begin()->first;
  const long top = lowest + static_cast<long>(std::ceil(1.0 / res));
  long best = lowest;
  for (const auto& [layer, a] : area) {
    if (layer > top) break;
    if (a > area[best]) best = layer;
  }
  return (best + 0.5) * res;
}

std::optional<bool> OccupancyMap::occupied(const Eigen::Vector3d& p_F) const {
  const octomap::OcTreeNode* n = impl_->tree.search(p_F.x(), p_F.y(), p_F.z());
  if (n == nullptr) return std::nullopt;
  return impl_->tree.isNodeOccupied(n);
}

std::size_t OccupancyMap::voxels() const { return impl_->tree.getNumLeafNodes(); }

void OccupancyMap::clear() { impl_->tree.clear(); }

std::string OccupancyMap::write() const {
  std::ostringstream out;
  if (!impl_->tree.write(out)) throw std::runtime_error("OccupancyMap::write: OctoMap failed");
  return out.str();
}

void OccupancyMap::read(const std::string& bytes) {
  std::istringstream in(bytes);
  std::unique_ptr<octomap::AbstractOcTree> read(octomap::AbstractOcTree::read(in));
  auto* tree = dynamic_cast<octomap::OcTree*>(read.get());
  if (tree == nullptr) {
    throw std::runtime_error("OccupancyMap::read: not an OctoMap OcTree file (.ot)");
  }
  if (std::abs(tree->getResolution() - config_.resolution_m) > 1e-9) {
    throw std::runtime_error("OccupancyMap::read: resolution " +
                             std::to_string(tree->getResolution()) + " m, this map's " +
                             std::to_string(config_.resolution_m) + " m");
  }
  impl_->tree.swapContent(*tree);
}

}  // namespace long3r
