#include "long3r/mapping/occupancy_map.hpp"

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <sstream>
#include <stdexcept>
#include <unordered_map>
#include <vector>

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
  check.require(pixel_step >= 1, "pixel_step", "must be >= 1");
}

void GridProjectionConfig::validate(const config::FieldCheck& check) const {
  check.require(std::isfinite(min_height_m), "min_height_m", "must be finite");
  check.require(max_height_m > min_height_m && std::isfinite(max_height_m), "max_height_m",
                "must be finite and above min_height_m");
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

namespace {

octomap::point3d to_octomap(const Eigen::Vector3d& p) {
  return {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())};
}

}  // namespace

OccupancyMap::OccupancyMap(const OccupancyMapConfig& config) : config_(config) {
  config.validate({"occupancy map config", ""});
  impl_ = std::make_unique<Impl>(config_);
}
OccupancyMap::~OccupancyMap() = default;

std::size_t OccupancyMap::insert(const std::vector<Eigen::Vector3f>& points_M,
                                 const Eigen::Vector3d& origin_M) {
  octomap::Pointcloud cloud;
  cloud.reserve(points_M.size());
  for (const Eigen::Vector3f& p : points_M) {
    if (p.allFinite()) cloud.push_back(p.x(), p.y(), p.z());
  }
  return insert_rays(cloud, origin_M);
}

std::size_t OccupancyMap::insert(const cv::Mat& points_M, const cv::Mat& conf, float conf_threshold,
                                 const Eigen::Vector3d& origin_M) {
  if (points_M.type() != CV_32FC3 ||
      (!conf.empty() && (conf.type() != CV_32FC1 || conf.size() != points_M.size()))) {
    throw std::invalid_argument(
        "OccupancyMap::insert: points must be CV_32FC3 and conf CV_32FC1 (or empty) of its size");
  }
  octomap::Pointcloud cloud;
  const int step = config_.pixel_step;
  for (int v = step / 2; v < points_M.rows; v += step) {
    const auto* p = points_M.ptr<cv::Vec3f>(v);
    const auto* c = conf.empty() ? nullptr : conf.ptr<float>(v);
    for (int u = step / 2; u < points_M.cols; u += step) {
      if (c != nullptr && !(c[u] >= conf_threshold)) continue;
      if (std::isfinite(p[u][0]) && std::isfinite(p[u][1]) && std::isfinite(p[u][2])) {
        cloud.push_back(p[u][0], p[u][1], p[u][2]);
      }
    }
  }
  return insert_rays(cloud, origin_M);
}

std::size_t OccupancyMap::insert_rays(const octomap::Pointcloud& cloud,
                                      const Eigen::Vector3d& origin_M) {
  if (!origin_M.allFinite()) {
    throw std::invalid_argument("OccupancyMap::insert: the camera's position is not finite");
  }
  if (cloud.size() == 0) return 0;
  std::lock_guard<std::mutex> lock(mutex_);
  // discretize: one ray per endpoint voxel, as octomap_server does for dense clouds.
  impl_->tree.insertPointCloud(cloud, to_octomap(origin_M), config_.max_range_m,
                               /*lazy_eval=*/false, /*discretize=*/true);
  ++revision_;
  return cloud.size();
}

std::unique_ptr<OccupancyMap> OccupancyMap::clone() const {
  auto copy = std::make_unique<OccupancyMap>(config_);
  std::lock_guard<std::mutex> lock(mutex_);
  copy->impl_ = std::make_unique<Impl>(*impl_);
  return copy;
}

void OccupancyMap::swap(OccupancyMap& other) {
  if (&other == this) return;
  std::scoped_lock lock(mutex_, other.mutex_);
  std::swap(impl_, other.impl_);
  std::swap(config_, other.config_);
  ++revision_;
  ++other.revision_;
}

void OccupancyMap::rescale(double factor) {
  if (!(factor > 0.0 && std::isfinite(factor))) {
    throw std::invalid_argument("OccupancyMap::rescale: factor must be positive and finite");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (factor == 1.0) return;
  octomap::OcTree& old = impl_->tree;
  auto fresh = std::make_unique<Impl>(config_);
  octomap::OcTree& tree = fresh->tree;
  const double res = config_.resolution_m;
  // Each new voxel takes the largest log-odds of the old voxels that cover it
  // (an obstacle is never thinned away by the free space beside it).
  std::unordered_map<octomap::OcTreeKey, float, octomap::OcTreeKey::KeyHash> value;
  for (auto it = old.begin_leafs(), end = old.end_leafs(); it != end; ++it) {
    // Half the extent of the new voxel centres to take: those in the scaled
    // cube, at least the one holding its centre.
    const double half = std::max(0.0, 0.5 * it.getSize() * factor - 0.5 * res);
    const Eigen::Vector3d c = factor * Eigen::Vector3d(it.getX(), it.getY(), it.getZ());
    const float logodds = it->getLogOdds();
    octomap::OcTreeKey lo, hi;
    if (!tree.coordToKeyChecked(to_octomap(c - Eigen::Vector3d::Constant(half)), lo) ||
        !tree.coordToKeyChecked(to_octomap(c + Eigen::Vector3d::Constant(half)), hi)) {
      continue;  // beyond OctoMap's range
    }
    octomap::OcTreeKey k;
    for (k[0] = lo[0]; k[0] <= hi[0]; ++k[0]) {
      for (k[1] = lo[1]; k[1] <= hi[1]; ++k[1]) {
        for (k[2] = lo[2]; k[2] <= hi[2]; ++k[2]) {
          const auto [at, inserted] = value.emplace(k, logodds);
          if (!inserted) at->second = std::max(at->second, logodds);
        }
      }
    }
  }
  for (const auto& [key, logodds] : value) tree.setNodeValue(key, logodds, /*lazy_eval=*/true);
  tree.updateInnerOccupancy();
  tree.prune();
  impl_ = std::move(fresh);
  ++revision_;
}

OccupancyGrid OccupancyMap::project(const GridBand& band, const Eigen::Isometry3d& T_F_M) const {
  std::lock_guard<std::mutex> lock(mutex_);
  OccupancyGrid g;
  const octomap::OcTree& tree = impl_->tree;
  if (tree.size() == 0) return g;
  const double res = config_.resolution_m;
  const double z_lo = band.floor_z_m + band.min_height_m, z_hi = band.floor_z_m + band.max_height_m;
  // The voxels in the band, at their centres in F (a pruned leaf as the
  // voxels it stands for), then the grid that spans them.
  struct Cell {
    double x, y;
    bool occupied;
  };
  std::vector<Cell> cells;
  double x0 = HUGE_VAL, y0 = HUGE_VAL, x1 = -HUGE_VAL, y1 = -HUGE_VAL;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const bool occ = tree.isNodeOccupied(*it);
    const double size = it.getSize();
    const int n = std::max(1, static_cast<int>(std::lround(size / res)));
    const Eigen::Vector3d corner =
        Eigen::Vector3d(it.getX(), it.getY(), it.getZ()) - Eigen::Vector3d::Constant(0.5 * size);
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        for (int k = 0; k < n; ++k) {
          const Eigen::Vector3d p_F =
              T_F_M * (corner + res * Eigen::Vector3d(i + 0.5, j + 0.5, k + 0.5));
          // Free space counts from the floor up (rays that end on the floor
          // clear the cells before it), obstacles only in the band.
          if (p_F.z() < (occ ? z_lo : band.floor_z_m) || p_F.z() > z_hi) continue;
          cells.push_back({p_F.x(), p_F.y(), occ});
          x0 = std::min(x0, p_F.x());
          y0 = std::min(y0, p_F.y());
          x1 = std::max(x1, p_F.x());
          y1 = std::max(y1, p_F.y());
        }
      }
    }
  }
  if (cells.empty()) return g;
  g.resolution_m = res;
  g.origin_x_m = std::floor(x0 / res) * res;
  g.origin_y_m = std::floor(y0 / res) * res;
  g.width = static_cast<int>(std::floor((x1 - g.origin_x_m) / res)) + 1;
  g.height = static_cast<int>(std::floor((y1 - g.origin_y_m) / res)) + 1;
  g.cells.assign(static_cast<std::size_t>(g.width) * g.height, OccupancyGrid::kUnknown);
  for (const Cell& c : cells) {
    const int cx =
        std::clamp(static_cast<int>(std::floor((c.x - g.origin_x_m) / res)), 0, g.width - 1);
    const int cy =
        std::clamp(static_cast<int>(std::floor((c.y - g.origin_y_m) / res)), 0, g.height - 1);
    std::int8_t& v = g.cells[static_cast<std::size_t>(cy) * g.width + cx];
    if (c.occupied) {
      v = OccupancyGrid::kOccupied;
    } else if (v == OccupancyGrid::kUnknown) {
      v = OccupancyGrid::kFree;
    }
  }
  for (std::int8_t v : g.cells) {
    g.occupied += v == OccupancyGrid::kOccupied ? 1 : 0;
    g.free += v == OccupancyGrid::kFree ? 1 : 0;
  }
  return g;
}

std::optional<double> OccupancyMap::floor_z(const Eigen::Isometry3d& T_F_M) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const octomap::OcTree& tree = impl_->tree;
  const double res = config_.resolution_m;
  // Occupied voxels per layer of F's z (a pruned leaf counts for its voxels).
  std::map<long, double> count;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    if (!tree.isNodeOccupied(*it)) continue;
    const double n = std::pow(it.getSize() / res, 3);
    const double z = (T_F_M * Eigen::Vector3d(it.getX(), it.getY(), it.getZ())).z();
    count[static_cast<long>(std::floor(z / res))] += n;
  }
  if (count.empty()) return std::nullopt;
  // The lowest layer of the lowest metre that holds a quarter of the most any
  // layer there holds: the floor, not a table top above a floor seen little,
  // nor a stray voxel below it.
  const long lowest = count.begin()->first;
  const long top = lowest + static_cast<long>(std::ceil(1.0 / res));
  double most = 0;
  for (const auto& [layer, n] : count) {
    if (layer > top) break;
    most = std::max(most, n);
  }
  long best = lowest;
  for (const auto& [layer, n] : count) {
    if (n >= 0.25 * most) {
      best = layer;
      break;
    }
  }
  return (best + 0.5) * res;
}

std::optional<bool> OccupancyMap::occupied(const Eigen::Vector3d& p_M) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const octomap::OcTreeNode* n = impl_->tree.search(p_M.x(), p_M.y(), p_M.z());
  if (n == nullptr) return std::nullopt;
  return impl_->tree.isNodeOccupied(n);
}

std::size_t OccupancyMap::voxels() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return impl_->tree.getNumLeafNodes();
}

std::uint64_t OccupancyMap::revision() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return revision_;
}

void OccupancyMap::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  impl_->tree.clear();
  ++revision_;
}

std::string OccupancyMap::write() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::ostringstream out;
  if (!impl_->tree.write(out)) throw std::runtime_error("OccupancyMap::write: OctoMap failed");
  return out.str();
}

namespace {

// OctoMap's .ot reader trusts its input: the children bits of a damaged or
// crafted file make it recurse without bound and allocate without limit. So
// the file is read here first: the header as write() makes it, then every
// node (a float log-odds and a byte of children bits) walked within the
// bytes and the tree's 16 levels, all finite, as many as the header says,
// nothing left over. Only then does OctoMap read the nodes.
constexpr int kOcTreeDepth = 16;
constexpr std::size_t kNodeBytes = sizeof(float) + 1;

struct OtFile {
  double resolution_m = 0.0;
  std::size_t nodes = 0;
  std::size_t data_offset = 0;  // where the nodes start
};

[[noreturn]] void refuse(const std::string& problem) {
  throw std::runtime_error("OccupancyMap::read: not an OctoMap OcTree file (.ot): " + problem);
}

OtFile read_ot_header(const std::string& bytes) {
  std::size_t pos = 0;
  auto next_line = [&](std::string& line) {
    const std::size_t end = bytes.find('\n', pos);
    if (end == std::string::npos || end - pos > 256) refuse("its header does not end");
    line.assign(bytes, pos, end - pos);
    pos = end + 1;
  };
  std::string line;
  next_line(line);
  if (line.rfind("# Octomap OcTree file", 0) != 0) refuse("the first line is not OctoMap's");
  OtFile f;
  bool id = false, size = false, res = false;
  for (;;) {
    next_line(line);
    if (!line.empty() && line[0] == '#') continue;
    std::istringstream words(line);
    std::string key, rest;
    words >> key;
    if (key == "data") break;
    if (key == "id") {
      words >> rest;
      if (rest != "OcTree") refuse("a tree of kind '" + rest + "', not an OcTree");
      id = true;
    } else if (key == "size") {
      long long n = -1;
      if (!(words >> n) || n < 0) refuse("no node count");
      f.nodes = static_cast<std::size_t>(n);
      size = true;
    } else if (key == "res") {
      if (!(words >> f.resolution_m) || !(f.resolution_m > 0.0) || !std::isfinite(f.resolution_m)) {
        refuse("no positive resolution");
      }
      res = true;
    } else {
      refuse("an unknown header line '" + line + "'");
    }
  }
  if (!id || !size || !res) refuse("its header lacks the id, size or res line");
  f.data_offset = pos;
  return f;
}

// The nodes from data_offset, walked depth first as OctoMap wrote them.
void check_ot_nodes(const std::string& bytes, const OtFile& f) {
  if (f.nodes == 0) {
    if (f.data_offset != bytes.size()) refuse("bytes after an empty tree");
    return;
  }
  if (f.nodes > (bytes.size() - f.data_offset) / kNodeBytes) {
    refuse("a node count its bytes cannot hold");
  }
  std::size_t pos = f.data_offset, walked = 0;
  std::vector<int> pending_depths{0};  // nodes still to read, by depth
  while (!pending_depths.empty()) {
    const int depth = pending_depths.back();
    pending_depths.pop_back();
    // walked <= nodes, and the bytes hold that many: the read stays inside.
    if (++walked > f.nodes) refuse("more nodes than its header says");
    float log_odds = 0.0f;
    std::memcpy(&log_odds, bytes.data() + pos, sizeof(float));
    const auto children = static_cast<unsigned char>(bytes[pos + sizeof(float)]);
    pos += kNodeBytes;
    if (!std::isfinite(log_odds)) refuse("a node whose value is not finite");
    if (children != 0 && depth == kOcTreeDepth) refuse("nodes below the tree's last level");
    for (int i = 0; i < 8; ++i) {
      if (children & (1u << i)) pending_depths.push_back(depth + 1);
    }
  }
  if (walked != f.nodes) refuse("fewer nodes than its header says");
  if (pos != bytes.size()) refuse("bytes after its last node");
}

}  // namespace

void OccupancyMap::restore(const StateReader& state, const std::string& key) {
  const std::string bytes = state.bytes(key);
  try {
    read(bytes);
  } catch (const std::runtime_error& e) {
    state.fail(key, e.what());
  }
}

void OccupancyMap::read(const std::string& bytes) {
  const OtFile f = read_ot_header(bytes);
  if (std::abs(f.resolution_m - config_.resolution_m) > 1e-9) {
    throw std::runtime_error("OccupancyMap::read: resolution " + std::to_string(f.resolution_m) +
                             " m, this map's " + std::to_string(config_.resolution_m) + " m");
  }
  check_ot_nodes(bytes, f);
  octomap::OcTree tree(f.resolution_m);
  if (f.nodes > 0) {
    std::istringstream in(bytes.substr(f.data_offset));
    if (!tree.readData(in)) refuse("OctoMap could not read its nodes");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  impl_->tree.swapContent(tree);
  ++revision_;
}

}  // namespace long3r
