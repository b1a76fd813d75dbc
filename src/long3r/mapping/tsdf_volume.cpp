#include "long3r/mapping/tsdf_volume.hpp"

#ifdef LONG3R_WITH_OPEN3D
#include <open3d/core/Tensor.h>
#include <open3d/geometry/Image.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/RGBDImage.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/pipelines/integration/ScalableTSDFVolume.h>
#include <open3d/t/geometry/Image.h>
#include <open3d/t/geometry/PointCloud.h>
#include <open3d/t/geometry/TriangleMesh.h>
#include <open3d/t/geometry/VoxelBlockGrid.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace long3r {

void TsdfConfig::validate(const config::FieldCheck& check) const {
  check.require(voxel_size_m > 0.0 && std::isfinite(voxel_size_m), "voxel_size_m",
                "must be positive and finite");
  check.require(truncation_m >= voxel_size_m && std::isfinite(truncation_m), "truncation_m",
                "must be finite and at least voxel_size_m");
  check.require(max_depth_m > 0.0 && std::isfinite(max_depth_m), "max_depth_m",
                "must be positive and finite");
  check.require(min_weight >= 0.0f && std::isfinite(min_weight), "min_weight", "must be >= 0");
  check.require(block_resolution >= 1 && block_resolution <= 64, "block_resolution",
                "must be in [1, 64]");
  check.require(initial_blocks >= 1, "initial_blocks", "must be >= 1");
}

namespace {

void transform_in_place(std::vector<Eigen::Vector3f>& points, const Eigen::Isometry3d& T_B_A) {
  const Eigen::Isometry3f T = T_B_A.cast<float>();
  for (Eigen::Vector3f& p : points) p = T * p;
}

}  // namespace

ColoredPoints transformed(ColoredPoints points_A, const Eigen::Isometry3d& T_B_A) {
  transform_in_place(points_A.points, T_B_A);
  return points_A;
}

ColoredMesh transformed(ColoredMesh mesh_A, const Eigen::Isometry3d& T_B_A) {
  transform_in_place(mesh_A.vertices, T_B_A);
  return mesh_A;
}

void append(ColoredPoints& into, const ColoredPoints& more) {
  into.points.insert(into.points.end(), more.points.begin(), more.points.end());
  into.colors.insert(into.colors.end(), more.colors.begin(), more.colors.end());
}

void append(ColoredMesh& into, const ColoredMesh& more) {
  const auto offset = static_cast<std::int32_t>(into.vertices.size());
  into.vertices.insert(into.vertices.end(), more.vertices.begin(), more.vertices.end());
  into.colors.insert(into.colors.end(), more.colors.begin(), more.colors.end());
  into.triangles.reserve(into.triangles.size() + more.triangles.size());
  for (const Triangle& t : more.triangles) {
    into.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
  }
}

bool TsdfVolume::available() {
#ifdef LONG3R_WITH_OPEN3D
  return true;
#else
  return false;
#endif
}

#ifdef LONG3R_WITH_OPEN3D

namespace o3d = open3d;

namespace {

Rgb8 to_rgb8(double r, double g, double b) {
  auto c = [](double v) {
    return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0));
  };
  return {c(r), c(g), c(b)};
}

}  // namespace

// The backend's state; one of the two is set.
struct TsdfVolume::Impl {
  std::unique_ptr<o3d::t::geometry::VoxelBlockGrid> grid;
  std::unique_ptr<o3d::pipelines::integration::ScalableTSDFVolume> scalable;

  explicit Impl(const TsdfConfig& c) {
    if (c.backend == TsdfBackend::kBlockGrid) {
      // Float tsdf, weight and colour: Open3D's accurate mode (its uint16
      // mode rounds the weights, which matters for few views).
      grid = std::make_unique<o3d::t::geometry::VoxelBlockGrid>(
          std::vector<std::string>{"tsdf", "weight", "color"},
          std::vector<o3d::core::Dtype>{o3d::core::Float32, o3d::core::Float32, o3d::core::Float32},
          std::vector<o3d::core::SizeVector>{{1}, {1}, {3}}, static_cast<float>(c.voxel_size_m),
          c.block_resolution, c.initial_blocks);
    } else {
      scalable = std::make_unique<o3d::pipelines::integration::ScalableTSDFVolume>(
          c.voxel_size_m, c.truncation_m, o3d::pipelines::integration::TSDFVolumeColorType::RGB8,
          c.block_resolution, 1);
    }
  }
};

TsdfVolume::TsdfVolume(const TsdfConfig& config) : config_(config) {
  config.validate({"tsdf config", ""});
  impl_ = std::make_unique<Impl>(config_);
}
TsdfVolume::~TsdfVolume() = default;
TsdfVolume::TsdfVolume(TsdfVolume&&) noexcept = default;
TsdfVolume& TsdfVolume::operator=(TsdfVolume&&) noexcept = default;

void TsdfVolume::clear() {
  impl_ = std::make_unique<Impl>(config_);
  frames_ = 0;
}

namespace {

// rgb: nullptr where there is none to check.
void check_view(const cv::Mat& points_C, const cv::Mat& conf, const cv::Mat* rgb) {
  if (points_C.type() != CV_32FC3 ||
      (rgb && (rgb->type() != CV_8UC3 || rgb->size() != points_C.size())) ||
      (!conf.empty() && (conf.type() != CV_32FC1 || conf.size() != points_C.size()))) {
    throw std::invalid_argument(
        "TsdfVolume::integrate: points_C must be CV_32FC3, rgb CV_8UC3 and conf CV_32FC1 (or "
        "empty), all of one size");
  }
}

}  // namespace

std::pair<cv::Mat, std::size_t> TsdfVolume::depth_of(const cv::Mat& points_C, const cv::Mat& conf,
                                                     float conf_threshold) const {
  check_view(points_C, conf, nullptr);
  cv::Mat depth(points_C.size(), CV_32FC1);
  std::size_t used = 0;
  const auto max_depth = static_cast<float>(config_.max_depth_m);
  for (int v = 0; v < points_C.rows; ++v) {
    const auto* p = points_C.ptr<cv::Vec3f>(v);
    const auto* c = conf.empty() ? nullptr : conf.ptr<float>(v);
    auto* d = depth.ptr<float>(v);
    for (int u = 0; u < points_C.cols; ++u) {
      const float z = p[u][2];
      const bool ok = std::isfinite(p[u][0]) && std::isfinite(p[u][1]) && std::isfinite(z) &&
                      z > 0.0f && z <= max_depth && (c == nullptr || c[u] >= conf_threshold);
      d[u] = ok ? z : 0.0f;
      used += ok ? 1 : 0;
    }
  }
  return {depth, used};
}

std::size_t TsdfVolume::integrate(const cv::Mat& points_C, const cv::Mat& rgb, const cv::Mat& conf,
                                  float conf_threshold, const PinholeIntrinsics& K,
                                  const Eigen::Isometry3d& T_W_C) {
  check_view(points_C, conf, &rgb);
  return integrate_depth(depth_of(points_C, conf, conf_threshold).first, rgb, K, T_W_C);
}

std::size_t TsdfVolume::integrate_depth(const cv::Mat& depth_m, const cv::Mat& rgb,
                                        const PinholeIntrinsics& K,
                                        const Eigen::Isometry3d& T_W_C) {
  if (depth_m.type() != CV_32FC1 || rgb.type() != CV_8UC3 || rgb.size() != depth_m.size()) {
    throw std::invalid_argument(
        "TsdfVolume::integrate_depth: the depth must be CV_32FC1 and rgb CV_8UC3 of its size");
  }
  if (!(K.fx > 0 && K.fy > 0 && std::isfinite(K.cx) && std::isfinite(K.cy))) {
    throw std::invalid_argument("TsdfVolume::integrate: intrinsics without a focal length");
  }
  if (!T_W_C.matrix().allFinite()) {
    throw std::invalid_argument("TsdfVolume::integrate: the pose is not finite");
  }
  const int H = depth_m.rows, W = depth_m.cols;
  // Open3D's images; the block grid's float path takes float colour (0-1)
  // with float depth, the legacy volume 8-bit colour.
  const bool float_color = impl_->grid != nullptr;
  o3d::geometry::Image depth, color;
  depth.Prepare(W, H, 1, 4);
  color.Prepare(W, H, 3, float_color ? 4 : 1);
  std::size_t used = 0;
  const auto max_depth = static_cast<float>(config_.max_depth_m);
  for (int v = 0; v < H; ++v) {
    const auto* src_d = depth_m.ptr<float>(v);
    float* d = depth.PointerAt<float>(0, v);
    for (int u = 0; u < W; ++u) {
      const float z = src_d[u];
      const bool ok = std::isfinite(z) && z > 0.0f && z <= max_depth;
      d[u] = ok ? z : 0.0f;
      used += ok ? 1 : 0;
    }
    const std::uint8_t* src = rgb.ptr<std::uint8_t>(v);
    if (float_color) {
      float* dst = color.PointerAt<float>(0, v, 0);
      for (int i = 0; i < 3 * W; ++i) dst[i] = src[i] * (1.0f / 255.0f);
    } else {
      std::memcpy(color.PointerAt<std::uint8_t>(0, v, 0), src, static_cast<std::size_t>(W) * 3);
    }
  }
  ++frames_;
  if (used == 0) return 0;
  const Eigen::Matrix4d T_C_W = T_W_C.inverse().matrix();
  if (impl_->grid) {
    using o3d::core::Tensor;
    const Tensor intrinsic =
        Tensor::Init<double>({{K.fx, 0.0, K.cx}, {0.0, K.fy, K.cy}, {0.0, 0.0, 1.0}});
    Tensor extrinsic = Tensor::Zeros({4, 4}, o3d::core::Float64);
    for (int r = 0; r < 4; ++r) {
      for (int k = 0; k < 4; ++k) extrinsic[r][k] = T_C_W(r, k);
    }
    const auto depth_t = o3d::t::geometry::Image::FromLegacy(depth);
    const auto color_t = o3d::t::geometry::Image::FromLegacy(color);
    const auto trunc = static_cast<float>(config_.truncation_m / config_.voxel_size_m);
    const Tensor blocks = impl_->grid->GetUniqueBlockCoordinates(depth_t, intrinsic, extrinsic,
                                                                 1.0f, max_depth, trunc);
    impl_->grid->Integrate(blocks, depth_t, color_t, intrinsic, extrinsic, 1.0f, max_depth, trunc);
  } else {
    const auto rgbd = o3d::geometry::RGBDImage::CreateFromColorAndDepth(color, depth, 1.0,
                                                                        config_.max_depth_m, false);
    const o3d::camera::PinholeCameraIntrinsic intrinsic(W, H, K.fx, K.fy, K.cx, K.cy);
    impl_->scalable->Integrate(*rgbd, intrinsic, T_C_W);
  }
  return used;
}

ColoredPoints TsdfVolume::extract_points() const {
  ColoredPoints out;
  if (impl_->grid) {
    if (impl_->grid->GetHashMap().Size() == 0) return out;
    const auto pcd = impl_->grid->ExtractPointCloud(config_.min_weight);
    if (pcd.IsEmpty()) return out;
    const auto positions = pcd.GetPointPositions().To(o3d::core::Float32).Contiguous();
    const auto n = static_cast<std::size_t>(positions.GetLength());
    const float* p = positions.GetDataPtr<float>();
    out.points.resize(n);
    for (std::size_t i = 0; i < n; ++i) out.points[i] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
    if (pcd.HasPointColors()) {
      const auto colors = pcd.GetPointColors().To(o3d::core::Float32).Contiguous();
      const float* c = colors.GetDataPtr<float>();
      out.colors.resize(n);
      for (std::size_t i = 0; i < n; ++i)
        out.colors[i] = to_rgb8(c[3 * i], c[3 * i + 1], c[3 * i + 2]);
    }
  } else {
    const auto pcd = impl_->scalable->ExtractPointCloud();
    // The legacy volume has no weight threshold of its own: it keeps every
    // zero crossing.
    out.points.reserve(pcd->points_.size());
    for (const auto& p : pcd->points_) out.points.push_back(p.cast<float>());
    for (const auto& c : pcd->colors_) out.colors.push_back(to_rgb8(c.x(), c.y(), c.z()));
  }
  if (out.colors.size() != out.points.size()) out.colors.assign(out.points.size(), Rgb8{0, 0, 0});
  return out;
}

ColoredMesh TsdfVolume::extract_mesh() const {
  ColoredMesh out;
  std::shared_ptr<o3d::geometry::TriangleMesh> mesh;
  if (impl_->grid) {
    if (impl_->grid->GetHashMap().Size() == 0) return out;
    mesh = std::make_shared<o3d::geometry::TriangleMesh>(
        impl_->grid->ExtractTriangleMesh(config_.min_weight).ToLegacy());
  } else {
    mesh = impl_->scalable->ExtractTriangleMesh();
  }
  out.vertices.reserve(mesh->vertices_.size());
  for (const auto& v : mesh->vertices_) out.vertices.push_back(v.cast<float>());
  for (const auto& c : mesh->vertex_colors_) out.colors.push_back(to_rgb8(c.x(), c.y(), c.z()));
  if (out.colors.size() != out.vertices.size()) {
    out.colors.assign(out.vertices.size(), Rgb8{0, 0, 0});
  }
  out.triangles.reserve(mesh->triangles_.size());
  for (const auto& t : mesh->triangles_) out.triangles.push_back({t.x(), t.y(), t.z()});
  return out;
}

#else  // without Open3D: the volume cannot be made

struct TsdfVolume::Impl {};

TsdfVolume::TsdfVolume(const TsdfConfig& config) : config_(config) {
  config.validate({"tsdf config", ""});
  throw std::runtime_error(
      "the TSDF surface needs Open3D: long3r was built without it (install libopen3d-dev and "
      "build again)");
}
TsdfVolume::~TsdfVolume() = default;
TsdfVolume::TsdfVolume(TsdfVolume&&) noexcept = default;
TsdfVolume& TsdfVolume::operator=(TsdfVolume&&) noexcept = default;
void TsdfVolume::clear() {}
std::size_t TsdfVolume::integrate(const cv::Mat&, const cv::Mat&, const cv::Mat&, float,
                                  const PinholeIntrinsics&, const Eigen::Isometry3d&) {
  return 0;
}
std::pair<cv::Mat, std::size_t> TsdfVolume::depth_of(const cv::Mat&, const cv::Mat&, float) const {
  return {};
}
std::size_t TsdfVolume::integrate_depth(const cv::Mat&, const cv::Mat&, const PinholeIntrinsics&,
                                        const Eigen::Isometry3d&) {
  return 0;
}
ColoredPoints TsdfVolume::extract_points() const { return {}; }
ColoredMesh TsdfVolume::extract_mesh() const { return {}; }

#endif

}  // namespace long3r
