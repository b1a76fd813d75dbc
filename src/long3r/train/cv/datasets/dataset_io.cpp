// The pieces shared by the dataset layout readers; see
// include/long3r/train/cv/datasets/dataset_io.hpp.
#include "long3r/train/cv/datasets/dataset_io.hpp"

#include <ATen/ATen.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

namespace long3r::datasets {

namespace {

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw DatasetError(path + ": cannot be read (missing?)");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

uint32_t le32(const std::string& b, std::size_t at) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(b[at + i]);
  return v;
}
uint16_t le16(const std::string& b, std::size_t at) {
  return static_cast<uint16_t>(static_cast<unsigned char>(b[at]) |
                               (static_cast<unsigned char>(b[at + 1]) << 8));
}

// The array of an .npy file's bytes; `what` names it in messages.
NpyArray parse_npy(const std::string& b, const std::string& what) {
  if (b.size() < 10 || b.compare(0, 6, "\x93NUMPY") != 0) {
    throw DatasetError(what + ": not a .npy array");
  }
  const int major = static_cast<unsigned char>(b[6]);
  std::size_t header_len = 0, start = 0;
  if (major == 1) {
    header_len = le16(b, 8);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (b.size() < 12) throw DatasetError(what + ": truncated .npy header");
    header_len = le32(b, 8);
    start = 12;
  } else {
    throw DatasetError(what + ": .npy version " + std::to_string(major) + " is not read");
  }
  if (start + header_len > b.size()) throw DatasetError(what + ": truncated .npy header");
  const std::string header = b.substr(start, header_len);
  auto field = [&](const std::string& key) {
    const std::size_t k = header.find("'" + key + "'");
    if (k == std::string::npos) throw DatasetError(what + ": .npy header without " + key);
    return header.substr(header.find(':', k) + 1);
  };
  const std::string descr_field = field("descr");
  const std::size_t q0 = descr_field.find('\''), q1 = descr_field.find('\'', q0 + 1);
  const std::string descr = descr_field.substr(q0 + 1, q1 - q0 - 1);
  if (field("fortran_order").find("True") < field("fortran_order").find(',')) {
    throw DatasetError(what + ": Fortran-ordered .npy arrays are not read");
  }
  NpyArray a;
  const std::string shape_field = field("shape");
  const std::string dims = shape_field.substr(shape_field.find('(') + 1,
                                              shape_field.find(')') - shape_field.find('(') - 1);
  std::stringstream ds(dims);
  std::string d;
  int64_t count = 1;
  while (std::getline(ds, d, ',')) {
    if (d.find_first_not_of(" ") == std::string::npos) continue;
    a.shape.push_back(std::stoll(d));
    count *= a.shape.back();
  }
  if (descr.size() < 3 || (descr[0] != '<' && descr[0] != '|')) {
    throw DatasetError(what + ": .npy type \"" + descr + "\" (only little-endian numbers)");
  }
  const char kind = descr[1];
  const int size = std::stoi(descr.substr(2));
  const std::size_t data = start + header_len;
  if (data + static_cast<std::size_t>(count * size) > b.size()) {
    throw DatasetError(what + ": truncated .npy data");
  }
  a.values.resize(static_cast<std::size_t>(count));
  const char* p = b.data() + data;
  for (int64_t i = 0; i < count; ++i, p += size) {
    double v = 0;
    if (kind == 'f' && size == 4) {
      float f;
      std::memcpy(&f, p, 4);
      v = f;
    } else if (kind == 'f' && size == 8) {
      std::memcpy(&v, p, 8);
    } else if ((kind == 'i' || kind == 'u') && (size == 1 || size == 2 || size == 4 || size == 8)) {
      int64_t x = 0;
      std::memcpy(&x, p, static_cast<std::size_t>(size));
      if (kind == 'i' && size < 8 && (x >> (8 * size - 1)) & 1) x -= int64_t{1} << (8 * size);
      v = static_cast<double>(x);
    } else {
      throw DatasetError(what + ": .npy type \"" + descr + "\" is not read");
    }
    a.values[static_cast<std::size_t>(i)] = v;
  }
  return a;
}

}  // namespace

cv::Mat read_color(const std::string& path) {
  const cv::Mat m = cv::imread(path, cv::IMREAD_COLOR);
  if (m.empty()) throw DatasetError(path + ": not a readable image (missing or truncated?)");
  return m;
}

cv::Mat read_pfm(const std::string& path) {
  const std::string b = read_bytes(path);
  std::istringstream in(b);
  std::string magic;
  int w = 0, h = 0;
  double scale = 0;
  in >> magic >> w >> h >> scale;
  if (magic != "Pf" || w <= 0 || h <= 0 || scale == 0.0 || !in) {
    throw DatasetError(path + ": not a one-channel PFM image");
  }
  in.get();  // the single white-space character before the data
  const std::size_t data = static_cast<std::size_t>(in.tellg());
  const std::size_t need = static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 4;
  if (data + need > b.size()) throw DatasetError(path + ": truncated PFM data");
  if (scale > 0) throw DatasetError(path + ": big-endian PFM is not read");
  cv::Mat m(h, w, CV_32F);
  for (int r = 0; r < h; ++r) {  // stored bottom row first
    std::memcpy(m.ptr<float>(h - 1 - r), b.data() + data + static_cast<std::size_t>(r) * w * 4,
                static_cast<std::size_t>(w) * 4);
  }
  return m;
}

cv::Mat read_depth(const std::string& path, double scale) {
  cv::Mat raw;
  if (path.size() > 4 && path.compare(path.size() - 4, 4, ".pfm") == 0) {
    raw = read_pfm(path);
  } else {
    raw = cv::imread(path, cv::IMREAD_ANYDEPTH);
    if (raw.empty())
      throw DatasetError(path + ": not a readable depth image (missing or truncated?)");
  }
  if (raw.channels() != 1) throw DatasetError(path + ": a depth image has one channel");
  cv::Mat depth;
  raw.convertTo(depth, CV_32F, scale);
  for (int r = 0; r < depth.rows; ++r) {
    float* p = depth.ptr<float>(r);
    for (int c = 0; c < depth.cols; ++c) {
      if (!std::isfinite(p[c]) || p[c] < 0.0f) p[c] = 0.0f;
    }
  }
  return depth;
}

Eigen::MatrixXd read_matrix_text(const std::string& path, int rows, int cols) {
  std::istringstream in(read_bytes(path));
  Eigen::MatrixXd m(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      std::string token;
      if (!(in >> token)) {
        throw DatasetError(path + ": fewer than " + std::to_string(rows * cols) + " numbers");
      }
      try {
        std::size_t used = 0;
        m(r, c) = std::stod(token, &used);
        if (used != token.size()) throw std::invalid_argument(token);
      } catch (const std::exception&) {
        throw DatasetError(path + ": \"" + token + "\" is not a number");
      }
    }
  }
  return m;
}

nlohmann::json read_json(const std::string& path) {
  try {
    return nlohmann::json::parse(read_bytes(path));
  } catch (const nlohmann::json::exception& e) {
    throw DatasetError(path + ": not valid JSON (" + e.what() + ")");
  }
}

std::vector<std::string> read_lines(const std::string& path) {
  std::istringstream in(read_bytes(path));
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(in, line)) {
    const std::size_t b = line.find_first_not_of(" \t\r");
    if (b == std::string::npos) continue;
    lines.push_back(line.substr(b, line.find_last_not_of(" \t\r") - b + 1));
  }
  return lines;
}

bool parse_finite(const std::string& token, double* value) {
  if (token.empty()) return false;
  char* end = nullptr;
  *value = std::strtod(token.c_str(), &end);
  return end == token.c_str() + token.size() && std::isfinite(*value);
}

NpyArray read_npy(const std::string& path) { return parse_npy(read_bytes(path), path); }

std::map<std::string, NpyArray> read_npz(const std::string& path) {
  const std::string b = read_bytes(path);
  std::map<std::string, NpyArray> out;
  std::size_t at = 0;
  // Local file entries one after another (numpy.savez stores them
  // uncompressed, sizes in the local headers), up to the central directory.
  while (at + 4 <= b.size() && le32(b, at) == 0x04034b50) {
    if (at + 30 > b.size()) throw DatasetError(path + ": truncated zip entry");
    const uint16_t flags = le16(b, at + 6), method = le16(b, at + 8);
    uint64_t size = le32(b, at + 18);
    const uint16_t name_len = le16(b, at + 26), extra_len = le16(b, at + 28);
    if (at + 30 + name_len + extra_len > b.size())
      throw DatasetError(path + ": truncated zip entry");
    std::string name = b.substr(at + 30, name_len);
    if (size == 0xffffffffu) {  // zip64: the size is in the extra field
      std::size_t e = at + 30 + name_len;
      const std::size_t end = e + extra_len;
      while (e + 4 <= end) {
        const uint16_t id = le16(b, e), len = le16(b, e + 2);
        if (id == 0x0001 && len >= 16) {
          size = le32(b, e + 4) | (static_cast<uint64_t>(le32(b, e + 8)) << 32);
        }
        e += 4 + len;
      }
    }
    if (method != 0) {
      throw DatasetError(
          path + ": entry " + name +
          " is compressed (numpy.savez_compressed); only numpy.savez files are read");
    }
    if (flags & 0x08) throw DatasetError(path + ": zip entries with trailing sizes are not read");
    const std::size_t data = at + 30 + name_len + extra_len;
    if (data + size > b.size()) throw DatasetError(path + ": truncated entry " + name);
    if (name.size() > 4 && name.compare(name.size() - 4, 4, ".npy") == 0) {
      name.resize(name.size() - 4);
    }
    out[name] = parse_npy(b.substr(data, size), path + ":" + name);
    at = data + size;
  }
  if (out.empty()) throw DatasetError(path + ": not an npz archive (or an empty one)");
  return out;
}

Eigen::MatrixXd npz_matrix(const std::map<std::string, NpyArray>& npz, const std::string& key,
                           int rows, int cols, const std::string& path) {
  const auto it = npz.find(key);
  if (it == npz.end()) throw DatasetError(path + ": no \"" + key + "\"");
  const NpyArray& a = it->second;
  if (static_cast<int64_t>(a.values.size()) != int64_t{rows} * cols) {
    throw DatasetError(path + ": \"" + key + "\" holds " + std::to_string(a.values.size()) +
                       " values, not " + std::to_string(rows) + " x " + std::to_string(cols));
  }
  Eigen::MatrixXd m(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) m(r, c) = a.values[static_cast<std::size_t>(r * cols + c)];
  }
  return m;
}

PinholeIntrinsics intrinsics_from_k(const Eigen::Matrix3d& k, int width, int height,
                                    const std::string& what) {
  if (!k.allFinite() || k(0, 1) != 0.0 || k(1, 0) != 0.0 || k(2, 0) != 0.0 || k(2, 1) != 0.0 ||
      k(2, 2) != 1.0 || !(k(0, 0) > 0.0) || !(k(1, 1) > 0.0)) {
    std::ostringstream m;
    m << what << ": not a pinhole K without skew: [" << k.row(0) << "; " << k.row(1) << "; "
      << k.row(2) << "]";
    throw DatasetError(m.str());
  }
  PinholeIntrinsics p;
  p.fx = k(0, 0);
  p.fy = k(1, 1);
  p.cx = k(0, 2);
  p.cy = k(1, 2);
  p.width = width;
  p.height = height;
  return p;
}

Eigen::Isometry3d rigid_from_matrix(const Eigen::Matrix4d& m, const std::string& what) {
  const Eigen::Matrix3d r = m.topLeftCorner<3, 3>();
  if (!m.allFinite()) throw DatasetError(what + ": a pose with non-finite values");
  if (m.row(3).transpose() != Eigen::Vector4d(0, 0, 0, 1) ||
      (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() > 1e-3 || r.determinant() < 0.0) {
    throw DatasetError(what + ": not a rigid transform (a rotation and a translation)");
  }
  // Exactly orthonormal: the nearest rotation (SVD).
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(r, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = svd.matrixU() * svd.matrixV().transpose();
  t.translation() = m.topRightCorner<3, 1>();
  return t;
}

at::Tensor tensor_of_mat(const cv::Mat& m, at::ScalarType type) {
  const cv::Mat c = m.isContinuous() ? m : m.clone();
  std::vector<int64_t> shape = {c.rows, c.cols};
  if (c.channels() > 1) shape.push_back(c.channels());
  return at::from_blob(const_cast<uint8_t*>(c.data), shape, type).clone();
}

RawFrame make_frame(const cv::Mat& bgr, const cv::Mat& depth, const PinholeIntrinsics& k,
                    const Eigen::Isometry3d& T_W_C, const std::string& what, bool resize_color) {
  if (bgr.type() != CV_8UC3 || depth.type() != CV_32F) {
    throw std::logic_error("make_frame: colour must be CV_8UC3 and depth CV_32F");
  }
  cv::Mat color = bgr;
  if (color.size() != depth.size()) {
    if (!resize_color) {
      throw DatasetError(what + ": colour " + std::to_string(bgr.cols) + " x " +
                         std::to_string(bgr.rows) + " and depth " + std::to_string(depth.cols) +
                         " x " + std::to_string(depth.rows) + " differ in size");
    }
    cv::resize(bgr, color, depth.size(), 0, 0, cv::INTER_AREA);
  }
  if ((k.width != 0 && k.width != depth.cols) || (k.height != 0 && k.height != depth.rows)) {
    throw DatasetError(what + ": intrinsics of a " + std::to_string(k.width) + " x " +
                       std::to_string(k.height) + " image for " + std::to_string(depth.cols) +
                       " x " + std::to_string(depth.rows) + " pixels");
  }
  RawFrame f;
  f.bgr = tensor_of_mat(color, at::kByte);
  f.depth = tensor_of_mat(depth, at::kFloat);
  f.intrinsics = k;
  f.intrinsics.width = depth.cols;
  f.intrinsics.height = depth.rows;
  f.T_W_C = T_W_C;
  return f;
}

DatasetScan open_dataset(const DatasetSource& source) {
  if (source.layout == "scannet") return open_scannet(source);
  if (source.layout == "scannetpp") return open_scannetpp(source);
  if (source.layout == "arkitscenes") return open_arkitscenes(source);
  if (source.layout == "co3d") return open_co3d(source);
  if (source.layout == "blendedmvs") return open_blendedmvs(source);
  if (source.layout == "habitat") return open_habitat(source);
  throw std::invalid_argument("open_dataset: no layout \"" + source.layout + "\"");
}

}  // namespace long3r::datasets
