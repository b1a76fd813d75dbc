// A surface fused from every posed view: a truncated signed distance field
// (TSDF) on Open3D, as voxblox and nvblox fuse depth, its zero crossing
// extracted as coloured points and as a triangle mesh.
//
// Frames: the volume lives in the world frame W (camera 0 of the stream),
// lengths in the stream's units (metres once the scale is metric). A frame is
// integrated from its pointmap in its own camera optical frame C (points_C,
// whose z is the depth along the pixel's optical axis), at T_W_C.
//
// Each view moves the field towards its own surface along its rays and clears
// what lies in front of it, so errors that differ from view to view average
// out, where the voxel map (voxel_map.hpp) keeps every view's points. What
// every view gets wrong alike stays (eval/fusion_bound.hpp measures that part).
//
// Two of Open3D's volumes, chosen by `backend`: its tensor VoxelBlockGrid
// (the default: it saves and loads) and its legacy ScalableTSDFVolume.
// Not thread-safe: the caller (the pipeline's worker) serialises access.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/geometry/cv/point_cloud_io.hpp"
#include "long3r/geometry/pinhole_intrinsics.hpp"

namespace long3r {

enum class TsdfBackend {
  kBlockGrid,  // open3d::t::geometry::VoxelBlockGrid
  kScalable,   // open3d::pipelines::integration::ScalableTSDFVolume
};
inline const std::array<std::pair<TsdfBackend, const char*>, 2>& enum_names(TsdfBackend) {
  static const std::array<std::pair<TsdfBackend, const char*>, 2> names{
      {{TsdfBackend::kBlockGrid, "block_grid"}, {TsdfBackend::kScalable, "scalable"}}};
  return names;
}

struct TsdfConfig {
  static constexpr double kDefaultVoxelSizeM = 0.02;
  static constexpr double kDefaultTruncationM = 0.08;

  TsdfBackend backend = TsdfBackend::kBlockGrid;
  double voxel_size_m = kDefaultVoxelSizeM;
  // Distance behind and in front of a view's surface that it updates.
  double truncation_m = kDefaultTruncationM;
  double max_depth_m = 20.0;  // pixels deeper than this are left out
  // Surface voxels with less weight (views that saw them) are not extracted.
  float min_weight = 3.0f;
  // Voxels per block edge and the blocks the grid holds before it grows.
  int block_resolution = 16;
  int initial_blocks = 256;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, TsdfConfig> visit_fields(S& s, V& v) {
  v("backend", s.backend);
  v("voxel_size_m", s.voxel_size_m);
  v("truncation_m", s.truncation_m);
  v("max_depth_m", s.max_depth_m);
  v("min_weight", s.min_weight);
}

// A triangle mesh: vertices with colours, triangles by vertex index.
struct ColoredMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Rgb8> colors;
  std::vector<Triangle> triangles;
};

// Points and mesh vertices moved by T_B_A (from frame A to frame B).
ColoredPoints transformed(ColoredPoints points_A, const Eigen::Isometry3d& T_B_A);
ColoredMesh transformed(ColoredMesh mesh_A, const Eigen::Isometry3d& T_B_A);
// `more` added to `into` (both in one frame); a mesh's triangles re-indexed.
void append(ColoredPoints& into, const ColoredPoints& more);
void append(ColoredMesh& into, const ColoredMesh& more);

class TsdfVolume {
 public:
  // Whether long3r was built with Open3D (libopen3d-dev); without it the
  // constructor throws std::runtime_error saying so.
  static bool available();

  // Throws ConfigError (config.validate()).
  explicit TsdfVolume(const TsdfConfig& config = {});
  ~TsdfVolume();
  TsdfVolume(TsdfVolume&&) noexcept;
  TsdfVolume& operator=(TsdfVolume&&) noexcept;

  // One view: points_C CV_32FC3 (camera frame; its z is the depth), rgb
  // CV_8UC3 (RGB order), conf CV_32FC1 (pixels below conf_threshold are left
  // out; empty: all), all [H, W]; K the intrinsics of those pixels. Pixels
  // with a non-finite point, z <= 0 or z > max_depth_m are left out. Returns
  // the pixels integrated. Throws std::invalid_argument for mismatched
  // images, intrinsics without a focal length or a non-finite pose.
  std::size_t integrate(const cv::Mat& points_C, const cv::Mat& rgb, const cv::Mat& conf,
                        float conf_threshold, const PinholeIntrinsics& K,
                        const Eigen::Isometry3d& T_W_C);
  // The depth image such a view integrates (CV_32FC1, 0 where a pixel is left
  // out), and the number of pixels it keeps. Same checks as integrate().
  std::pair<cv::Mat, std::size_t> depth_of(const cv::Mat& points_C, const cv::Mat& conf,
                                           float conf_threshold) const;
  // One view as a depth image of depth_of(): each pixel's z (0: none), rgb
  // CV_8UC3 of its size. Returns the pixels integrated (depth > 0).
  std::size_t integrate_depth(const cv::Mat& depth, const cv::Mat& rgb, const PinholeIntrinsics& K,
                              const Eigen::Isometry3d& T_W_C);

  ColoredPoints extract_points() const;
  ColoredMesh extract_mesh() const;

  void clear();
  std::size_t frames() const { return frames_; }
  const TsdfConfig& config() const { return config_; }

 private:
  struct Impl;
  TsdfConfig config_;
  std::unique_ptr<Impl> impl_;
  std::size_t frames_ = 0;
};

}  // namespace long3r
