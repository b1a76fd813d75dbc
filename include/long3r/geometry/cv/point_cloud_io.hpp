// Point-cloud files, one reader and one writer per format: the voxel map's
// ~save_map and long3r_reconstruct output, the evaluator's clouds (ground
// truth, aligned prediction) and the clouds it is given.
//
// Formats, chosen by the extension (case-insensitive):
//   .ply       written: binary_little_endian 1.0 (or ascii), element vertex
//              with float x, y, z [and uchar red, green, blue];
//              read: ascii, binary_little_endian or binary_big_endian, vertex
//              x y z of any scalar type (float, double, ...), other
//              properties and elements skipped
//   .pcd       written: PCD v0.7, FIELDS x y z [rgb], TYPE F F F [U],
//              rgb = r << 16 | g << 8 | b, DATA binary (or ascii);
//              read through PCL (any PCD it reads; non-finite points dropped)
//   .xyz/.txt  "x y z [r g b]" per line; read: '#' comments, blank lines,
//              commas as separators, extra columns ignored
// Writes go through AtomicFile (long3r/io/atomic_file.hpp). The writers are
// ours and PCL's readers take their files (tested): PCL's PCDWriter refuses
// an empty cloud, and an empty map (~save_map before the first frame) is a
// valid file.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace long3r {

using Rgb8 = std::array<std::uint8_t, 3>;  // red, green, blue

// Points and their colours, index-aligned (RGB), in no particular order:
// a map's or a surface's.
struct ColoredPoints {
  std::vector<Eigen::Vector3f> points;
  std::vector<Rgb8> colors;
};

enum class PointCloudFormat { kPly, kPcd, kXyz };

// The format of a path's extension; nullopt for any other.
std::optional<PointCloudFormat> point_cloud_format(const std::string& path);

struct PointCloudWriteOptions {
  bool ascii = false;   // .ply: ascii instead of binary_little_endian; .pcd: DATA ascii
  std::string comment;  // .ply: a "comment" header line when not empty
};

// Writes points (and, when `colors` is given, their colours, index-aligned)
// atomically. Throws std::invalid_argument for an unknown extension (naming
// it) or colours of another length, AtomicWriteError when the write fails.
void save_point_cloud(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                      const std::vector<Rgb8>* colors = nullptr,
                      const PointCloudWriteOptions& options = {});

// A triangle mesh as .ply (the only mesh format): the vertices as
// save_point_cloud writes them, then element face with "property list uchar
// int vertex_indices" (rviz, MeshLab, Open3D and PCL read it). Triangles are
// vertex indices. Throws std::invalid_argument for another extension, colours
// of another length or an index outside the vertices, AtomicWriteError when
// the write fails.
using Triangle = std::array<std::int32_t, 3>;
void save_mesh_ply(const std::string& path, const std::vector<Eigen::Vector3f>& vertices,
                   const std::vector<Rgb8>* colors, const std::vector<Triangle>& triangles,
                   const PointCloudWriteOptions& options = {});

// The points of a .ply, .pcd, .xyz or .txt file (a mesh's vertices). Throws
// std::runtime_error.
std::vector<Eigen::Vector3f> load_point_cloud(const std::string& path);

}  // namespace long3r
