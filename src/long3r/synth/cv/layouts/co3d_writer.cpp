// Frames written as a Co3D-v2 sequence as DUSt3R's preprocess_co3d.py leaves
// it (the layout train/cv/datasets/co3d.cpp reads):
//   <root>/<category>/<sequence>/images/frame<n:06d>.jpg and .npz (numpy.savez:
//   camera_intrinsics, camera_pose camera-to-world OpenCV, maximum_depth, all
//   float32), depths/frame<n:06d>.jpg.geometric.png (uint16 = depth /
//   maximum_depth * 65535), masks/frame<n:06d>.png (uint8, 255 on the object),
//   listed in <root>/selected_seqs_train.json (and in the category's own list).
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/layouts/layout_files.hpp"

namespace long3r::synth {

namespace {

using layouts::write_image;
using layouts::write_text;

uint32_t crc32(const std::string& bytes) {
  static const std::array<uint32_t, 256> table = [] {
    std::array<uint32_t, 256> t{};
    for (uint32_t i = 0; i < 256; ++i) {
      uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  uint32_t c = 0xFFFFFFFFu;
  for (const char ch : bytes) c = table[(c ^ static_cast<unsigned char>(ch)) & 0xFFu] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

void put16(std::string* b, uint32_t v) {
  b->push_back(static_cast<char>(v & 0xFFu));
  b->push_back(static_cast<char>((v >> 8) & 0xFFu));
}
void put32(std::string* b, uint32_t v) {
  put16(b, v & 0xFFFFu);
  put16(b, v >> 16);
}

// A float32 array as an .npy (version 1.0) file: the header dict padded with
// spaces and a newline to a multiple of 64 bytes, as numpy writes it.
std::string npy_float32(const std::vector<float>& values, const std::vector<int>& shape) {
  std::string dims;
  for (const int d : shape) dims += std::to_string(d) + ", ";
  if (shape.size() > 1) dims.resize(dims.size() - 2);  // (3, 3); (6,) and () as numpy
  if (shape.size() == 1) dims.resize(dims.size() - 1);
  std::string header = "{'descr': '<f4', 'fortran_order': False, 'shape': (" + dims + "), }";
  const std::size_t total = 10 + header.size() + 1;
  header.append((64 - total % 64) % 64, ' ');
  header.push_back('\n');
  std::string b("\x93NUMPY\x01\x00", 8);
  put16(&b, static_cast<uint32_t>(header.size()));
  b += header;
  static_assert(sizeof(float) == 4, "float32");
  const std::size_t at = b.size();
  b.resize(at + 4 * values.size());
  // Little-endian hosts only (as the project's other binary formats).
  std::memcpy(&b[at], values.data(), 4 * values.size());
  return b;
}

// numpy.savez's archive: each array an uncompressed ("stored") zip entry
// <key>.npy, then the central directory and its end record.
std::string npz(const std::vector<std::pair<std::string, std::string>>& entries) {
  std::string out, directory;
  for (const auto& [key, data] : entries) {
    const std::string name = key + ".npy";
    const uint32_t crc = crc32(data), size = static_cast<uint32_t>(data.size());
    const uint32_t offset = static_cast<uint32_t>(out.size());
    put32(&out, 0x04034b50u);  // local file header
    put16(&out, 20);           // version needed to extract
    put16(&out, 0);            // flags
    put16(&out, 0);            // stored
    put16(&out, 0);            // time
    put16(&out, 0x21);         // date: 1980-01-01
    put32(&out, crc);
    put32(&out, size);  // compressed
    put32(&out, size);  // uncompressed
    put16(&out, static_cast<uint32_t>(name.size()));
    put16(&out, 0);  // extra field
    out += name;
    out += data;

    put32(&directory, 0x02014b50u);  // central directory header
    put16(&directory, 20);           // made by
    put16(&directory, 20);           // needed
    put16(&directory, 0);
    put16(&directory, 0);
    put16(&directory, 0);
    put16(&directory, 0x21);
    put32(&directory, crc);
    put32(&directory, size);
    put32(&directory, size);
    put16(&directory, static_cast<uint32_t>(name.size()));
    put16(&directory, 0);            // extra field
    put16(&directory, 0);            // comment
    put16(&directory, 0);            // disk
    put16(&directory, 0);            // internal attributes
    put32(&directory, 0600u << 16);  // external: a -rw------- file
    put32(&directory, offset);
    directory += name;
  }
  const uint32_t directory_offset = static_cast<uint32_t>(out.size());
  out += directory;
  put32(&out, 0x06054b50u);  // end of central directory
  put16(&out, 0);
  put16(&out, 0);
  put16(&out, static_cast<uint32_t>(entries.size()));
  put16(&out, static_cast<uint32_t>(entries.size()));
  put32(&out, static_cast<uint32_t>(directory.size()));
  put32(&out, directory_offset);
  put16(&out, 0);  // comment
  return out;
}

// Adds the frame numbers at `keys` of a selected_seqs_train.json, created when
// absent.
void list_sequence(const std::string& path, const std::vector<std::string>& keys,
                   const std::vector<int>& numbers) {
  nlohmann::json list = nlohmann::json::object();
  std::ifstream in(path);
  if (in) {
    std::stringstream ss;
    ss << in.rdbuf();
    try {
      list = nlohmann::json::parse(ss.str());
    } catch (const nlohmann::json::exception& e) {
      throw std::runtime_error(path + ": not valid JSON, cannot be extended (" + e.what() + ")");
    }
  }
  nlohmann::json* at = &list;
  for (const std::string& key : keys) at = &(*at)[key];
  *at = numbers;
  write_text(path, list.dump());
}

}  // namespace

void write_co3d_sequence(const std::string& root, const std::string& name,
                         const std::vector<LayoutFrame>& frames) {
  // "<category>/<sequence>", or a sequence of the category "synthetic".
  const std::size_t slash = name.find('/');
  const std::string category = slash == std::string::npos ? "synthetic" : name.substr(0, slash);
  const std::string sequence = slash == std::string::npos ? name : name.substr(slash + 1);
  const std::string dir = root + "/" + category + "/" + sequence;
  for (const char* sub : {"/images", "/depths", "/masks"}) layouts::make_dirs(dir + sub);
  std::vector<int> numbers;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const LayoutFrame& f = frames[i];
    const int number = static_cast<int>(i) + 1;  // Co3D numbers frames from 1
    numbers.push_back(number);
    char stem[32];
    std::snprintf(stem, sizeof(stem), "frame%06d", number);
    // Best JPEG quality: the fixtures' small, noisy images lose several grey
    // levels at the default.
    write_image(dir + "/images/" + stem + ".jpg", f.bgr, {cv::IMWRITE_JPEG_QUALITY, 100});

    // Depth relative to the frame's largest, as preprocess_co3d.py scales it
    // (rounded here rather than truncated: half a step of error at most).
    float maximum_depth = 0.0f;
    for (int r = 0; r < f.depth_m.rows; ++r) {
      const float* d = f.depth_m.ptr<float>(r);
      for (int c = 0; c < f.depth_m.cols; ++c) {
        if (std::isfinite(d[c])) maximum_depth = std::max(maximum_depth, d[c]);
      }
    }
    cv::Mat depth(f.depth_m.size(), CV_16U, cv::Scalar(0));
    if (maximum_depth > 0.0f) {
      for (int r = 0; r < depth.rows; ++r) {
        const float* d = f.depth_m.ptr<float>(r);
        uint16_t* o = depth.ptr<uint16_t>(r);
        for (int c = 0; c < depth.cols; ++c) {
          if (!(std::isfinite(d[c]) && d[c] > 0.0f)) continue;
          const double v = std::round(static_cast<double>(d[c]) / maximum_depth * 65535.0);
          o[c] = static_cast<uint16_t>(std::clamp(v, 0.0, 65535.0));
        }
      }
    }
    write_image(dir + "/depths/" + stem + ".jpg.geometric.png", depth);

    // The object's mask: all of the image but a band of columns
    // [w / 4, 3 w / 8), so that a reader's background masking shows.
    cv::Mat mask(f.depth_m.size(), CV_8U, cv::Scalar(255));
    const int w = mask.cols;
    mask.colRange(w / 4, std::max(w / 4 + 1, 3 * w / 8)).setTo(0);
    write_image(dir + "/masks/" + stem + ".png", mask);

    std::vector<float> k(9), pose(16);
    const Eigen::Matrix3d km = f.intrinsics.matrix();
    const Eigen::Matrix4d pm = f.T_W_C.matrix();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        k[static_cast<std::size_t>(3 * r + c)] = static_cast<float>(km(r, c));
      }
    }
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) {
        pose[static_cast<std::size_t>(4 * r + c)] = static_cast<float>(pm(r, c));
      }
    }
    write_text(dir + "/images/" + stem + ".npz",
               npz({{"camera_intrinsics", npy_float32(k, {3, 3})},
                    {"camera_pose", npy_float32(pose, {4, 4})},
                    {"maximum_depth", npy_float32({maximum_depth}, {})}}));
  }
  // The split's list {category: {sequence: [frames]}}, which the reader
  // uses, and the category's own {sequence: [frames]} beside it.
  list_sequence(root + "/selected_seqs_train.json", {category, sequence}, numbers);
  list_sequence(root + "/" + category + "/selected_seqs_train.json", {sequence}, numbers);
}

}  // namespace long3r::synth
