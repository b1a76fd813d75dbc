// Point cloud files: PLY (own reader/writer), XYZ text, PCD (PCL, own TU).
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "long3r/eval/eval.hpp"

namespace long3r {

std::vector<Eigen::Vector3f> load_point_cloud_pcd(const std::string& path);  // point_io_pcd.cpp

namespace {

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

double decode(const std::string& type, const unsigned char* p, bool swap) {
  unsigned char b[8];
  const int n = type_size(type);
  for (int i = 0; i < n; ++i) b[i] = swap ? p[n - 1 - i] : p[i];
  if (type == "char" || type == "int8") return static_cast<int8_t>(b[0]);
  if (type == "uchar" || type == "uint8") return b[0];
  if (type == "short" || type == "int16") {
    int16_t v;
    std::memcpy(&v, b, 2);
    return v;
  }
  if (type == "ushort" || type == "uint16") {
    uint16_t v;
    std::memcpy(&v, b, 2);
    return v;
  }
  if (type == "int" || type == "int32") {
    int32_t v;
    std::memcpy(&v, b, 4);
    return v;
  }
  if (type == "uint" || type == "uint32") {
    uint32_t v;
    std::memcpy(&v, b, 4);
    return v;
  }
  if (type == "float" || type == "float32") {
    float v;
    std::memcpy(&v, b, 4);
    return v;
  }
  double v;
  std::memcpy(&v, b, 8);
  return v;
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
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot open " + path);
  std::vector<Eigen::Vector3f> out;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream ss(line);
    float x, y, z;
    if (!(ss >> x)) continue;  // blank line
    if (!(ss >> y >> z))
      throw std::runtime_error(path + ":" + std::to_string(number) + ": expected x y z");
    out.emplace_back(x, y, z);
  }
  return out;
}

}  // namespace

std::vector<Eigen::Vector3f> load_point_cloud(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".ply") return load_ply(path);
  if (ext == ".pcd") return load_point_cloud_pcd(path);
  if (ext == ".xyz" || ext == ".txt") return load_xyz(path);
  throw std::runtime_error(path + ": unknown point cloud extension (ply, pcd, xyz, txt)");
}

void save_point_cloud_ply(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                          const std::vector<cv::Vec3b>* colours) {
  if (colours && colours->size() != points.size()) {
    throw std::invalid_argument("save_point_cloud_ply: colours and points differ in size");
  }
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << points.size()
      << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (colours) out << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out << "end_header\n";
  for (size_t i = 0; i < points.size(); ++i) {
    out.write(reinterpret_cast<const char*>(points[i].data()), 3 * sizeof(float));
    if (colours) {
      const cv::Vec3b& c = (*colours)[i];
      const unsigned char rgb[3] = {c[2], c[1], c[0]};
      out.write(reinterpret_cast<const char*>(rgb), 3);
    }
  }
  if (!out) throw std::runtime_error("error writing " + path);
}

}  // namespace long3r
