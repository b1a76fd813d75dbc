#include "long3r/mapping/voxel_map.hpp"

#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

namespace long3r {

namespace {

// 21 bits per axis, biased so that the packed key orders like (i, j, k).
constexpr int kBits = 21;
constexpr std::int64_t kBias = std::int64_t{1} << (kBits - 1);
constexpr std::uint64_t kMask = (std::uint64_t{1} << kBits) - 1;

bool index_of(const Eigen::Vector3f& p, double voxel, std::int64_t out[3]) {
  for (int a = 0; a < 3; ++a) {
    const double f = std::floor(static_cast<double>(p[a]) / voxel);
    if (!(f >= -static_cast<double>(kBias) && f < static_cast<double>(kBias))) return false;
    out[a] = static_cast<std::int64_t>(f);
  }
  return true;
}

std::uint64_t pack(const std::int64_t idx[3]) {
  return (static_cast<std::uint64_t>(idx[0] + kBias) << (2 * kBits)) |
         (static_cast<std::uint64_t>(idx[1] + kBias) << kBits) |
         static_cast<std::uint64_t>(idx[2] + kBias);
}

Eigen::Vector3i unpack(std::uint64_t key) {
  return {static_cast<int>(static_cast<std::int64_t>((key >> (2 * kBits)) & kMask) - kBias),
          static_cast<int>(static_cast<std::int64_t>((key >> kBits) & kMask) - kBias),
          static_cast<int>(static_cast<std::int64_t>(key & kMask) - kBias)};
}

std::uint8_t round_colour(float c) {
  return static_cast<std::uint8_t>(std::lround(std::clamp(c, 0.0f, 255.0f)));
}

}  // namespace

void VoxelMapConfig::validate(const config::FieldCheck& check) const {
  check.require(voxel_size_m > 0.0 && std::isfinite(voxel_size_m), "voxel_size_m",
                "must be positive and finite");
  // Positions are 32-bit; a frame may add voxels beyond the cap before eviction.
  check.require(max_points >= 1 && max_points <= (std::size_t{1} << 31), "max_map_points",
                "must be in [1, 2^31]");
  check.require(conf_threshold >= 0.0f && std::isfinite(conf_threshold), "conf_threshold",
                "must be >= 0");
}

VoxelMap::VoxelMap(const VoxelMapConfig& config) : config_(config) {
  config.validate({"voxel map config", ""});
}

Eigen::Vector3i VoxelMap::voxel_index(const Eigen::Vector3f& p) const {
  std::int64_t idx[3];
  if (!index_of(p, config_.voxel_size_m, idx)) {
    throw std::out_of_range("VoxelMap::voxel_index: point outside the map's index range");
  }
  return {static_cast<int>(idx[0]), static_cast<int>(idx[1]), static_cast<int>(idx[2])};
}

void VoxelMap::fuse_locked(const Eigen::Vector3f& p, const std::uint8_t* rgb, std::int64_t frame,
                           IntegrationStats& stats) {
  std::int64_t idx[3];
  if (!index_of(p, config_.voxel_size_m, idx)) {
    ++stats.out_of_range;
    return;
  }
  const std::uint64_t key = pack(idx);
  const auto [pos, inserted] = index_.try_emplace(key, static_cast<std::uint32_t>(voxels_.size()));
  bool rebucket = false;
  if (inserted) {
    voxels_.push_back(
        Voxel{key, {p.x(), p.y(), p.z()}, {float(rgb[0]), float(rgb[1]), float(rgb[2])}, 1, frame});
    ++stats.new_voxels;
    rebucket = true;
  } else {
    Voxel& v = voxels_[pos];
    ++v.hits;
    const double inv = 1.0 / v.hits;
    for (int a = 0; a < 3; ++a) {
      v.mean[a] += (static_cast<double>(p[a]) - v.mean[a]) * inv;
      v.color[a] += (static_cast<float>(rgb[a]) - v.color[a]) * static_cast<float>(inv);
    }
    if (frame > v.last_seen) {
      v.last_seen = frame;
      rebucket = true;
    }
  }
  if (rebucket) {  // the voxel's last-seen frame is now `frame`
    buckets_[frame].push_back(key);
    ++bucket_entries_;
  }
  ++stats.fused;
}

void VoxelMap::erase_locked(std::uint64_t key) {
  const std::uint32_t pos = *index_.find(key);
  index_.erase(key);
  // Swap-remove keeps the storage dense.
  if (pos + 1 != voxels_.size()) {
    voxels_[pos] = voxels_.back();
    index_.assign(voxels_[pos].key, pos);
  }
  voxels_.pop_back();
}

void VoxelMap::compact_buckets_locked() {
  buckets_.clear();
  for (const Voxel& v : voxels_) buckets_[v.last_seen].push_back(v.key);
  bucket_entries_ = voxels_.size();
}

void VoxelMap::evict_locked(IntegrationStats& stats) {
  while (voxels_.size() > config_.max_points && !buckets_.empty()) {
    auto bucket = buckets_.begin();
    // Live entries of the oldest frame, fewest hits first, then by index.
    std::vector<std::pair<std::uint32_t, std::uint64_t>> live;
    live.reserve(bucket->second.size());
    for (std::uint64_t key : bucket->second) {
      const std::uint32_t* pos = index_.find(key);
      if (pos && voxels_[*pos].last_seen == bucket->first) {
        live.emplace_back(voxels_[*pos].hits, key);
      }
    }
    std::sort(live.begin(), live.end());
    live.erase(std::unique(live.begin(), live.end()), live.end());
    bucket_entries_ -= bucket->second.size();
    const std::size_t excess = voxels_.size() - config_.max_points;
    const std::size_t n = std::min(excess, live.size());
    for (std::size_t i = 0; i < n; ++i) erase_locked(live[i].second);
    stats.evicted += n;
    if (n == live.size()) {
      buckets_.erase(bucket);
    } else {
      bucket->second.clear();
      for (std::size_t i = n; i < live.size(); ++i) bucket->second.push_back(live[i].second);
      bucket_entries_ += bucket->second.size();
    }
  }
}

IntegrationStats VoxelMap::integrate(const cv::Mat& pts3d_W, const cv::Mat& conf,
                                     const cv::Mat& rgb, std::int64_t frame_index) {
  if (pts3d_W.type() != CV_32FC3 || conf.type() != CV_32FC1 || rgb.type() != CV_8UC3) {
    throw std::invalid_argument(
        "VoxelMap::integrate: expected CV_32FC3 points, CV_32FC1 conf, CV_8UC3 rgb");
  }
  if (conf.size() != pts3d_W.size() || rgb.size() != pts3d_W.size()) {
    throw std::invalid_argument("VoxelMap::integrate: points, conf and rgb differ in size");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  IntegrationStats stats;
  for (int v = 0; v < pts3d_W.rows; ++v) {
    const auto* p = pts3d_W.ptr<cv::Vec3f>(v);
    const float* c = conf.ptr<float>(v);
    const auto* col = rgb.ptr<cv::Vec3b>(v);
    for (int u = 0; u < pts3d_W.cols; ++u) {
      if (!(c[u] >= config_.conf_threshold)) continue;
      const Eigen::Vector3f q(p[u][0], p[u][1], p[u][2]);
      if (!q.allFinite()) continue;
      ++stats.candidates;
      fuse_locked(q, &col[u][0], frame_index, stats);
    }
  }
  evict_locked(stats);
  if (bucket_entries_ > 2 * voxels_.size() + 4096) compact_buckets_locked();
  if (stats.fused > 0) ++revision_;
  stats.map_size = voxels_.size();
  return stats;
}

IntegrationStats VoxelMap::integrate(const std::vector<Eigen::Vector3f>& points,
                                     const std::vector<Rgb8>& colors, std::int64_t frame_index) {
  if (points.size() != colors.size()) {
    throw std::invalid_argument("VoxelMap::integrate: points and colors differ in length");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  IntegrationStats stats;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite()) continue;
    ++stats.candidates;
    fuse_locked(points[i], colors[i].data(), frame_index, stats);
  }
  evict_locked(stats);
  if (bucket_entries_ > 2 * voxels_.size() + 4096) compact_buckets_locked();
  if (stats.fused > 0) ++revision_;
  stats.map_size = voxels_.size();
  return stats;
}

void VoxelMap::rescale(double factor) {
  if (!(factor > 0.0) || !std::isfinite(factor)) {
    throw std::invalid_argument("VoxelMap::rescale: the factor must be positive and finite");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<Voxel> old;
  old.swap(voxels_);
  index_.clear();
  index_.reserve(old.size());  // at most as many voxels as before: no rehash on the way
  IntegrationStats stats;
  for (const Voxel& o : old) {
    const double mean[3] = {o.mean[0] * factor, o.mean[1] * factor, o.mean[2] * factor};
    std::int64_t idx[3];
    const Eigen::Vector3f p(static_cast<float>(mean[0]), static_cast<float>(mean[1]),
                            static_cast<float>(mean[2]));
    if (!index_of(p, config_.voxel_size_m, idx)) {
      ++stats.out_of_range;
      continue;
    }
    const std::uint64_t key = pack(idx);
    const auto [pos, inserted] =
        index_.try_emplace(key, static_cast<std::uint32_t>(voxels_.size()));
    if (inserted) {
      voxels_.push_back(Voxel{key,
                              {mean[0], mean[1], mean[2]},
                              {o.color[0], o.color[1], o.color[2]},
                              o.hits,
                              o.last_seen});
      continue;
    }
    Voxel& v = voxels_[pos];
    const double total = static_cast<double>(v.hits) + o.hits;
    for (int a = 0; a < 3; ++a) {
      v.mean[a] = (v.mean[a] * v.hits + mean[a] * o.hits) / total;
      v.color[a] = static_cast<float>((v.color[a] * v.hits + o.color[a] * o.hits) / total);
    }
    v.hits += o.hits;
    v.last_seen = std::max(v.last_seen, o.last_seen);
  }
  compact_buckets_locked();
  evict_locked(stats);
  ++revision_;
}

std::size_t VoxelMap::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return voxels_.size();
}

void VoxelMap::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  voxels_.clear();
  index_.clear();
  buckets_.clear();
  bucket_entries_ = 0;
  ++revision_;
}

std::uint64_t VoxelMap::revision() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return revision_;
}

MapSnapshot VoxelMap::snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  MapSnapshot s;
  s.points.reserve(voxels_.size());
  s.colors.reserve(voxels_.size());
  for (const Voxel& v : voxels_) {
    s.points.emplace_back(static_cast<float>(v.mean[0]), static_cast<float>(v.mean[1]),
                          static_cast<float>(v.mean[2]));
    s.colors.push_back(
        {round_colour(v.color[0]), round_colour(v.color[1]), round_colour(v.color[2])});
  }
  return s;
}

std::vector<VoxelInfo> VoxelMap::voxels() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<VoxelInfo> out;
  out.reserve(voxels_.size());
  for (const Voxel& v : voxels_) {
    VoxelInfo info;
    info.index = unpack(v.key);
    info.position = Eigen::Vector3f(static_cast<float>(v.mean[0]), static_cast<float>(v.mean[1]),
                                    static_cast<float>(v.mean[2]));
    info.color = {round_colour(v.color[0]), round_colour(v.color[1]), round_colour(v.color[2])};
    info.hits = v.hits;
    info.last_seen = v.last_seen;
    out.push_back(info);
  }
  return out;
}

std::vector<VoxelRecord> VoxelMap::records() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<VoxelRecord> out(voxels_.size());
  for (std::size_t i = 0; i < voxels_.size(); ++i) {
    const Voxel& v = voxels_[i];
    out[i].index = unpack(v.key);
    out[i].mean = Eigen::Vector3d(v.mean[0], v.mean[1], v.mean[2]);
    out[i].color = Eigen::Vector3f(v.color[0], v.color[1], v.color[2]);
    out[i].hits = v.hits;
    out[i].last_seen = v.last_seen;
  }
  return out;
}

void VoxelMap::restore(const std::vector<VoxelRecord>& records) {
  if (records.size() > config_.max_points) {
    throw std::invalid_argument("map of " + std::to_string(records.size()) +
                                " voxels, more than max_points (" +
                                std::to_string(config_.max_points) + ")");
  }
  std::vector<Voxel> voxels;
  voxels.reserve(records.size());
  VoxelKeyIndex index;
  index.reserve(records.size());
  // A mean lies inside its voxel up to the rounding of the running mean.
  const double slack = 1e-6 * config_.voxel_size_m;
  for (std::size_t n = 0; n < records.size(); ++n) {
    const VoxelRecord& r = records[n];
    const std::string which = "map voxel " + std::to_string(n) + ": ";
    std::int64_t idx[3];
    for (int a = 0; a < 3; ++a) {
      idx[a] = r.index[a];
      if (idx[a] < -kBias || idx[a] >= kBias)
        throw std::invalid_argument(which + "index out of range");
      const double lo = static_cast<double>(idx[a]) * config_.voxel_size_m;
      if (!(r.mean[a] >= lo - slack && r.mean[a] <= lo + config_.voxel_size_m + slack)) {
        throw std::invalid_argument(which + "mean position outside its voxel");
      }
      if (!(r.color[a] >= 0.0f && r.color[a] <= 255.0f)) {
        throw std::invalid_argument(which + "colour outside [0, 255]");
      }
    }
    if (r.hits == 0) throw std::invalid_argument(which + "no hits");
    const std::uint64_t key = pack(idx);
    if (!index.try_emplace(key, static_cast<std::uint32_t>(n)).second) {
      throw std::invalid_argument(which + "a second voxel with the same index");
    }
    voxels.push_back(Voxel{key,
                           {r.mean[0], r.mean[1], r.mean[2]},
                           {r.color[0], r.color[1], r.color[2]},
                           r.hits,
                           r.last_seen});
  }
  std::lock_guard<std::mutex> lock(mutex_);
  voxels_ = std::move(voxels);
  index_ = std::move(index);
  compact_buckets_locked();
  ++revision_;
}

StateDict VoxelMap::state() const {
  const std::vector<VoxelRecord> voxels = records();
  const int64_t m = static_cast<int64_t>(voxels.size());
  at::Tensor index = at::empty({m, 3}, at::kLong), mean = at::empty({m, 3}, at::kDouble),
             color = at::empty({m, 3}, at::kFloat), hits = at::empty({m}, at::kLong),
             seen = at::empty({m}, at::kLong);
  int64_t* index_p = index.data_ptr<int64_t>();
  double* mean_p = mean.data_ptr<double>();
  float* color_p = color.data_ptr<float>();
  for (int64_t i = 0; i < m; ++i) {
    const VoxelRecord& v = voxels[static_cast<std::size_t>(i)];
    for (int a = 0; a < 3; ++a) {
      index_p[3 * i + a] = v.index[a];
      mean_p[3 * i + a] = v.mean[a];
      color_p[3 * i + a] = v.color[a];
    }
    hits.data_ptr<int64_t>()[i] = v.hits;
    seen.data_ptr<int64_t>()[i] = v.last_seen;
  }
  return {{"index", index}, {"mean", mean}, {"color", color}, {"hits", hits}, {"last_seen", seen}};
}

void VoxelMap::restore(const StateReader& r) {
  const at::Tensor index = r.int64("index", {-1, 3}).contiguous();
  const int64_t m = index.size(0);
  const at::Tensor mean = r.floating("mean", {m, 3}).to(at::kDouble).contiguous();
  const at::Tensor color = r.floating("color", {m, 3}).to(at::kFloat).contiguous();
  const at::Tensor hits = r.int64("hits", {m}).contiguous();
  const at::Tensor seen = r.int64("last_seen", {m}).contiguous();
  std::vector<VoxelRecord> voxels(static_cast<std::size_t>(m));
  for (int64_t i = 0; i < m; ++i) {
    VoxelRecord& v = voxels[static_cast<std::size_t>(i)];
    for (int a = 0; a < 3; ++a) {
      const int64_t k = index.data_ptr<int64_t>()[3 * i + a];
      if (k < std::numeric_limits<int>::min() || k > std::numeric_limits<int>::max()) {
        r.fail("index", "out of range");
      }
      v.index[a] = static_cast<int>(k);
      v.mean[a] = mean.data_ptr<double>()[3 * i + a];
      v.color[a] = color.data_ptr<float>()[3 * i + a];
    }
    const int64_t h = hits.data_ptr<int64_t>()[i];
    if (h < 1 || h > std::numeric_limits<std::uint32_t>::max()) r.fail("hits", "out of range");
    v.hits = static_cast<std::uint32_t>(h);
    v.last_seen = seen.data_ptr<int64_t>()[i];
  }
  try {
    restore(voxels);
  } catch (const std::invalid_argument& e) {
    r.fail("mean", e.what());
  }
}

void VoxelMap::save(const std::string& path, const MapSaveOptions& options) const {
  // Copy under the lock, write without it: fusing is not blocked by disk I/O.
  const MapSnapshot s = snapshot();
  save_colored_cloud(path, s.points, s.colors, options);
}

}  // namespace long3r
