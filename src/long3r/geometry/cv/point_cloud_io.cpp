// Point-cloud reading and writing; see include/long3r/geometry/cv/point_cloud_io.hpp.
#include "long3r/geometry/cv/point_cloud_io.hpp"

#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <cctype>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "long3r/io/atomic_file.hpp"
#include "long3r/io/data_lines.hpp"

namespace long3r {

namespace {

// ------------------------------------------------------------- writing

void put_le32(unsigned char* out, std::uint32_t bits) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<unsigned char>((bits >> (8 * i)) & 0xffu);
}
std::uint32_t float_bits(float f) {
  std::uint32_t bits;
  std::memcpy(&bits, &f, sizeof(bits));
  return bits;
}
std::uint32_t pack_rgb(const Rgb8& c) {
  return (static_cast<std::uint32_t>(c[0]) << 16) | (static_cast<std::uint32_t>(c[1]) << 8) |
         static_cast<std::uint32_t>(c[2]);
}

// "x y z [r g b]" per line: the .xyz format and the vertices of an ascii PLY.
void write_text_points(AtomicFile& f, const std::vector<Eigen::Vector3f>& points,
                       const std::vector<Rgb8>* colors) {
  char line[128];
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    // %.9g round-trips a float exactly.
    int n = std::snprintf(line, sizeof(line), "%.9g %.9g %.9g", p.x(), p.y(), p.z());
    if (colors) {
      const Rgb8& c = (*colors)[i];
      n += std::snprintf(line + n, sizeof(line) - static_cast<std::size_t>(n), " %u %u %u",
                         unsigned{c[0]}, unsigned{c[1]}, unsigned{c[2]});
    }
    line[n++] = '\n';
    f.write(line, static_cast<std::size_t>(n));
  }
}

void write_ply(AtomicFile& f, const std::vector<Eigen::Vector3f>& points,
               const std::vector<Rgb8>* colors, const PointCloudWriteOptions& o,
               const std::vector<Triangle>* faces = nullptr) {
  std::string header =
      std::string("ply\nformat ") + (o.ascii ? "ascii" : "binary_little_endian") + " 1.0\n";
  if (!o.comment.empty()) header += "comment " + o.comment + "\n";
  header += "element vertex " + std::to_string(points.size()) +
            "\nproperty float x\nproperty float y\nproperty float z\n";
  if (colors) header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (faces) {
    header += "element face " + std::to_string(faces->size()) +
              "\nproperty list uchar int vertex_indices\n";
  }
  header += "end_header\n";
  f.write(header);
  if (o.ascii) {
    write_text_points(f, points, colors);
    if (faces) {
      char line[64];
      for (const Triangle& t : *faces) {
        const int n = std::snprintf(line, sizeof line, "3 %d %d %d\n", t[0], t[1], t[2]);
        f.write(line, static_cast<std::size_t>(n));
      }
    }
    return;
  }
  unsigned char rec[15];
  const std::size_t rec_size = colors ? 15 : 12;
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (int a = 0; a < 3; ++a) put_le32(rec + 4 * a, float_bits(points[i][a]));
    if (colors) std::memcpy(rec + 12, (*colors)[i].data(), 3);
    f.write(rec, rec_size);
  }
  if (faces) {
    rec[0] = 3;
    for (const Triangle& t : *faces) {
      for (int a = 0; a < 3; ++a) put_le32(rec + 1 + 4 * a, static_cast<std::uint32_t>(t[a]));
      f.write(rec, 13);
    }
  }
}

void write_pcd(AtomicFile& f, const std::vector<Eigen::Vector3f>& points,
               const std::vector<Rgb8>* colors, const PointCloudWriteOptions& o) {
  const std::string n = std::to_string(points.size());
  f.write(std::string("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n") +
          (colors ? "FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n"
                  : "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n") +
          "WIDTH " + n + "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " + n + "\nDATA " +
          (o.ascii ? "ascii" : "binary") + "\n");
  char line[128];
  unsigned char rec[16];
  const std::size_t rec_size = colors ? 16 : 12;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    if (o.ascii) {
      int len = std::snprintf(line, sizeof(line), "%.9g %.9g %.9g", p.x(), p.y(), p.z());
      if (colors) {
        len += std::snprintf(line + len, sizeof(line) - static_cast<std::size_t>(len), " %" PRIu32,
                             pack_rgb((*colors)[i]));
      }
      line[len++] = '\n';
      f.write(line, static_cast<std::size_t>(len));
    } else {
      for (int a = 0; a < 3; ++a) put_le32(rec + 4 * a, float_bits(p[a]));
      if (colors) put_le32(rec + 12, pack_rgb((*colors)[i]));
      f.write(rec, rec_size);
    }
  }
}

// ------------------------------------------------------------- reading

int type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "int32" || t == "uint32" || t == "float" ||
      t == "float32") {
    return 4;
  }
  if (t == "double" || t == "float64") return 8;
  return 0;
}

struct Property {
  std::string name, type;
  bool list = false;
  std::string count_type;  // list only
};
struct Element {
  std::string name;
  size_t count = 0;
  std::vector<Property> props;
};

// One scalar of type T from its bytes (already in host order).
template <class T>
double load_as(const unsigned char* b) {
  T v;
  std::memcpy(&v, b, sizeof(T));
  return static_cast<double>(v);
}

double decode(const std::string& type, const unsigned char* p, bool swap) {
  unsigned char b[8];
  const int n = type_size(type);
  for (int i = 0; i < n; ++i) b[i] = swap ? p[n - 1 - i] : p[i];
  if (type == "char" || type == "int8") return load_as<int8_t>(b);
  if (type == "uchar" || type == "uint8") return load_as<uint8_t>(b);
  if (type == "short" || type == "int16") return load_as<int16_t>(b);
  if (type == "ushort" || type == "uint16") return load_as<uint16_t>(b);
  if (type == "int" || type == "int32") return load_as<int32_t>(b);
  if (type == "uint" || type == "uint32") return load_as<uint32_t>(b);
  if (type == "float" || type == "float32") return load_as<float>(b);
  return load_as<double>(b);
}

std::vector<Eigen::Vector3f> load_ply(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open " + path);
  std::string line;
  std::getline(in, line);
  if (line.rfind("ply", 0) != 0) throw std::runtime_error(path + ": not a PLY file");
  std::string format;
  std::vector<Element> elements;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ss(line);
    std::string word;
    ss >> word;
    if (word == "format") {
      ss >> format;
    } else if (word == "element") {
      Element e;
      ss >> e.name >> e.count;
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) throw std::runtime_error(path + ": property before element");
      Property p;
      ss >> p.type;
      if (p.type == "list") {
        p.list = true;
        ss >> p.count_type >> p.type;
      }
      ss >> p.name;
      if (type_size(p.type) == 0 || (p.list && type_size(p.count_type) == 0)) {
        throw std::runtime_error(path + ": unsupported PLY type in '" + line + "'");
      }
      elements.back().props.push_back(p);
    } else if (word == "end_header") {
      break;
    }
  }
  if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian") {
    throw std::runtime_error(path + ": unsupported PLY format '" + format + "'");
  }
  const bool ascii = format == "ascii";
  const bool swap = format == "binary_big_endian";  // this project targets little-endian hosts

  std::vector<Eigen::Vector3f> out;
  for (const Element& e : elements) {
    const bool vertex = e.name == "vertex";
    int ix = -1, iy = -1, iz = -1;
    for (size_t k = 0; k < e.props.size(); ++k) {
      if (e.props[k].name == "x") ix = static_cast<int>(k);
      if (e.props[k].name == "y") iy = static_cast<int>(k);
      if (e.props[k].name == "z") iz = static_cast<int>(k);
    }
    if (vertex && (ix < 0 || iy < 0 || iz < 0))
      throw std::runtime_error(path + ": vertex lacks x/y/z");
    if (vertex) out.reserve(e.count);
    for (size_t i = 0; i < e.count; ++i) {
      double xyz[3] = {0, 0, 0};
      if (ascii) {
        if (!std::getline(in, line)) throw std::runtime_error(path + ": truncated PLY");
        std::istringstream ss(line);
        for (size_t k = 0; k < e.props.size(); ++k) {
          double v;
          if (!(ss >> v)) throw std::runtime_error(path + ": bad PLY data line");
          if (e.props[k].list) {
            for (long c = static_cast<long>(v); c > 0; --c) ss >> v;
            continue;
          }
          if (static_cast<int>(k) == ix) xyz[0] = v;
          if (static_cast<int>(k) == iy) xyz[1] = v;
          if (static_cast<int>(k) == iz) xyz[2] = v;
        }
      } else {
        unsigned char buf[8];
        for (size_t k = 0; k < e.props.size(); ++k) {
          const Property& p = e.props[k];
          if (p.list) {
            if (!in.read(reinterpret_cast<char*>(buf), type_size(p.count_type))) {
              throw std::runtime_error(path + ": truncated PLY");
            }
            const long c = static_cast<long>(decode(p.count_type, buf, swap));
            in.seekg(c * type_size(p.type), std::ios::cur);
            continue;
          }
          if (!in.read(reinterpret_cast<char*>(buf), type_size(p.type))) {
            throw std::runtime_error(path + ": truncated PLY");
          }
          if (static_cast<int>(k) == ix) xyz[0] = decode(p.type, buf, swap);
          if (static_cast<int>(k) == iy) xyz[1] = decode(p.type, buf, swap);
          if (static_cast<int>(k) == iz) xyz[2] = decode(p.type, buf, swap);
        }
      }
      if (vertex)
        out.emplace_back(static_cast<float>(xyz[0]), static_cast<float>(xyz[1]),
                         static_cast<float>(xyz[2]));
    }
    if (vertex) break;  // later elements (faces) are not needed
  }
  return out;
}

std::vector<Eigen::Vector3f> load_xyz(const std::string& path) {
  std::vector<Eigen::Vector3f> out;
  for (const auto& [number, line] : data_lines(path)) {
    std::istringstream ss(line);
    float x, y, z;
    if (!(ss >> x)) continue;  // not a number (e.g. a header line without '#')
    if (!(ss >> y >> z))
      throw std::runtime_error(path + ":" + std::to_string(number) + ": expected x y z");
    out.emplace_back(x, y, z);
  }
  return out;
}

std::vector<Eigen::Vector3f> load_pcd(const std::string& path) {
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

}  // namespace

std::optional<PointCloudFormat> point_cloud_format(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".ply") return PointCloudFormat::kPly;
  if (ext == ".pcd") return PointCloudFormat::kPcd;
  if (ext == ".xyz" || ext == ".txt") return PointCloudFormat::kXyz;
  return std::nullopt;
}

void save_point_cloud(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                      const std::vector<Rgb8>* colors, const PointCloudWriteOptions& options) {
  const std::optional<PointCloudFormat> format = point_cloud_format(path);
  if (!format) {
    throw std::invalid_argument("save_point_cloud: unknown file extension '" +
                                std::filesystem::path(path).extension().string() + "' in '" + path +
                                "' (use .ply, .pcd, .xyz or .txt)");
  }
  if (colors && colors->size() != points.size()) {
    throw std::invalid_argument("save_point_cloud: points and colors differ in length");
  }
  AtomicFile file(path);
  switch (*format) {
    case PointCloudFormat::kPly:
      write_ply(file, points, colors, options);
      break;
    case PointCloudFormat::kPcd:
      write_pcd(file, points, colors, options);
      break;
    case PointCloudFormat::kXyz:
      write_text_points(file, points, colors);
      break;
  }
  file.commit();
}

void save_mesh_ply(const std::string& path, const std::vector<Eigen::Vector3f>& vertices,
                   const std::vector<Rgb8>* colors, const std::vector<Triangle>& triangles,
                   const PointCloudWriteOptions& options) {
  if (point_cloud_format(path) != PointCloudFormat::kPly) {
    throw std::invalid_argument("save_mesh_ply: '" + path + "' is not a .ply file");
  }
  if (colors && colors->size() != vertices.size()) {
    throw std::invalid_argument("save_mesh_ply: vertices and colors differ in length");
  }
  const auto n = static_cast<std::int64_t>(vertices.size());
  for (std::size_t i = 0; i < triangles.size(); ++i) {
    for (std::int32_t v : triangles[i]) {
      if (v < 0 || v >= n) {
        throw std::invalid_argument("save_mesh_ply: triangle " + std::to_string(i) +
                                    " names vertex " + std::to_string(v) + " of " +
                                    std::to_string(n));
      }
    }
  }
  AtomicFile file(path);
  write_ply(file, vertices, colors, options, &triangles);
  file.commit();
}

std::vector<Eigen::Vector3f> load_point_cloud(const std::string& path) {
  const std::optional<PointCloudFormat> format = point_cloud_format(path);
  if (!format) {
    throw std::runtime_error(path + ": unknown point cloud extension (ply, pcd, xyz, txt)");
  }
  switch (*format) {
    case PointCloudFormat::kPly:
      return load_ply(path);
    case PointCloudFormat::kPcd:
      return load_pcd(path);
    case PointCloudFormat::kXyz:
      break;
  }
  return load_xyz(path);
}

}  // namespace long3r
