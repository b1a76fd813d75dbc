// long3r_map_bench: the voxel map's per-frame cost, side by side with PCL.
//
// The package fuses every frame's confident points into its own voxel-hashed
// map (VoxelMap: a hash from voxel index to a running mean, hits, last seen,
// a point cap), and publishes the map through PCL (~map: PointXYZRGB,
// VoxelGrid for display). This measures why the fusion stays ours: PCL has no
// incremental voxel map, so fusing with PCL means filtering the map and the
// new frame together again every frame (VoxelGrid on map + frame), whose cost
// grows with the map. Both run on the same synthetic frames: a camera moving
// along a textured room's walls, 224 x 224 points per frame, 1 mm noise.
//
// Printed per checkpoint frame: map points, ms per frame of VoxelMap::integrate,
// of the PCL re-filter, and of ~map's conversion (snapshot -> PointXYZRGB ->
// PointCloud2-ready cloud) for reference. The PCL re-filter is a lower bound of
// a PCL fusion: it keeps centroids of centroids (not hit-weighted means) and
// neither hits nor a cap.
#include <pcl/filters/voxel_grid.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/geometry/cv/pcl_cloud.hpp"
#include "long3r/mapping/voxel_map.hpp"
#include "long3r/model/runtime/inference.hpp"

namespace {

using Cloud = long3r::ColoredCloud;

// Frame k: points of a 4 x 3 x 2.5 m room seen from a camera sliding along
// it, 224 x 224 rays, noise of 1 mm; colours from the position (texture).
void make_frame(int k, std::mt19937& rng, std::vector<Eigen::Vector3f>* points,
                std::vector<long3r::Rgb8>* colors) {
  constexpr int kSide = 224;
  std::normal_distribution<float> noise(0.0f, 0.001f);
  points->clear();
  colors->clear();
  const float cam_x = -1.5f + 0.01f * static_cast<float>(k);  // 1 cm per frame
  for (int v = 0; v < kSide; ++v) {
    for (int u = 0; u < kSide; ++u) {
      // A ray fan of about 60 degrees towards +z, hitting the wall z = 2 or
      // the floor / ceiling y = +-1.25.
      const float dx = (static_cast<float>(u) / kSide - 0.5f) * 1.2f;
      const float dy = (static_cast<float>(v) / kSide - 0.5f) * 1.2f;
      float t = 2.0f;
      if (std::abs(dy) * t > 1.25f) t = 1.25f / std::abs(dy);
      const Eigen::Vector3f p(cam_x + dx * t + noise(rng), dy * t + noise(rng), t + noise(rng));
      points->push_back(p);
      const auto c = static_cast<std::uint8_t>(static_cast<int>(std::floor(p.x() * 20.0f)) & 255);
      colors->push_back({c, static_cast<std::uint8_t>(255 - c), 128});
    }
  }
}

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 300;
  double voxel_m = long3r::VoxelMapConfig().voxel_size_m;
  long3r::CliOptions cli("long3r_map_bench",
                         "Per-frame cost of the package's voxel map beside fusing with PCL's "
                         "VoxelGrid (map + frame filtered again each frame), same frames.");
  cli.option("--frames", "N", &frames, "frames to fuse").min(1);
  cli.option("--voxel-size-m", "M", &voxel_m, "voxel size").above(0.0);
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;

  std::printf("cpu: %s\n", long3r::describe_cpu().c_str());
  std::printf("%d frames of 224 x 224 points, voxel %.3f m\n", frames, voxel_m);
  std::printf("%6s %10s %12s %12s %14s\n", "frame", "map_pts", "voxelmap_ms", "pcl_ms",
              "to_pcl_ms");
  long3r::VoxelMapConfig config;
  config.voxel_size_m = voxel_m;
  long3r::VoxelMap map(config);
  Cloud pcl_map;
  pcl::VoxelGrid<pcl::PointXYZRGB> grid;
  const auto leaf = static_cast<float>(voxel_m);
  grid.setLeafSize(leaf, leaf, leaf);
  std::mt19937 rng(7);
  std::vector<Eigen::Vector3f> points;
  std::vector<long3r::Rgb8> colors;
  double sum_ours = 0.0, sum_pcl = 0.0;
  for (int k = 0; k < frames; ++k) {
    make_frame(k, rng, &points, &colors);

    auto t0 = std::chrono::steady_clock::now();
    map.integrate(points, colors, k);
    const double ours_ms = ms_since(t0);

    t0 = std::chrono::steady_clock::now();
    Cloud::Ptr both(new Cloud(pcl_map));
    both->reserve(both->size() + points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
      pcl::PointXYZRGB p;
      p.getVector3fMap() = points[i];
      p.r = colors[i][0];
      p.g = colors[i][1];
      p.b = colors[i][2];
      both->push_back(p);
    }
    grid.setInputCloud(both);
    grid.filter(pcl_map);
    const double pcl_ms = ms_since(t0);
    sum_ours += ours_ms;
    sum_pcl += pcl_ms;

    const bool report = k + 1 == frames || k + 1 == 10 || k + 1 == 50 || (k + 1) % 100 == 0;
    if (!report) continue;
    t0 = std::chrono::steady_clock::now();
    const long3r::MapSnapshot snap = map.snapshot();
    const Cloud cloud = long3r::to_pcl_cloud(snap.points, snap.colors);
    const double to_pcl_ms = ms_since(t0);
    std::printf("%6d %10zu %12.2f %12.2f %14.2f   (PCL map %zu points)\n", k + 1, map.size(),
                ours_ms, pcl_ms, to_pcl_ms, pcl_map.size());
  }
  std::printf("mean ms per frame: voxel map %.2f, PCL re-filter %.2f (ratio %.1fx)\n",
              sum_ours / frames, sum_pcl / frames, sum_pcl / sum_ours);
  return 0;
}
