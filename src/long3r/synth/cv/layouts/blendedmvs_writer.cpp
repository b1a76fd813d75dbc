// A sequence written as a BlendedMVS scene in the raw layout Spann3R reads
// (src/long3r/train/cv/datasets/blendedmvs.cpp has the layout): JPEG colour,
// PFM depth, MVSNet camera files (world-to-camera), pair.txt, and the scene
// added to train_list.txt.
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/layouts/layout_files.hpp"

namespace long3r::synth {

namespace {

namespace fs = std::filesystem;

// One-channel PFM: "Pf", size, a negative scale (little endian), then the
// rows bottom first.
void write_pfm(const std::string& path, const cv::Mat& depth) {
  std::string out =
      "Pf\n" + std::to_string(depth.cols) + " " + std::to_string(depth.rows) + "\n-1\n";
  for (int r = depth.rows - 1; r >= 0; --r) {
    const float* p = depth.ptr<float>(r);
    for (int c = 0; c < depth.cols; ++c) {
      uint32_t bits = 0;
      std::memcpy(&bits, &p[c], 4);
      for (int b = 0; b < 4; ++b) out.push_back(static_cast<char>((bits >> (8 * b)) & 0xff));
    }
  }
  layouts::write_text(path, out);
}

// MVSNet camera: world-to-camera extrinsic, K, then the depth range line
// "depth_min depth_interval depth_num depth_max" (192 planes, as MVSNet).
void write_camera(const std::string& path, const LayoutFrame& f) {
  double lo = std::numeric_limits<double>::infinity(), hi = 0.0;
  for (int r = 0; r < f.depth_m.rows; ++r) {
    const float* p = f.depth_m.ptr<float>(r);
    for (int c = 0; c < f.depth_m.cols; ++c) {
      if (std::isfinite(p[c]) && p[c] > 0.0f) {
        lo = std::min(lo, static_cast<double>(p[c]));
        hi = std::max(hi, static_cast<double>(p[c]));
      }
    }
  }
  if (!(hi > 0.0)) lo = hi = 1.0;
  std::ostringstream out;
  out.precision(17);
  const Eigen::Matrix4d e = f.T_W_C.inverse().matrix();
  out << "extrinsic\n";
  for (int r = 0; r < 4; ++r) {
    out << e(r, 0) << " " << e(r, 1) << " " << e(r, 2) << " " << e(r, 3) << "\n";
  }
  const Eigen::Matrix3d k = f.intrinsics.matrix();
  out << "\nintrinsic\n";
  for (int r = 0; r < 3; ++r) out << k(r, 0) << " " << k(r, 1) << " " << k(r, 2) << "\n";
  out << "\n" << lo << " " << (hi - lo) / 191.0 << " 192 " << hi << "\n";
  layouts::write_text(path, out.str());
}

std::string id_name(std::size_t i) {
  char buf[24];
  std::snprintf(buf, sizeof(buf), "%08zu", i);
  return buf;
}

}  // namespace

void write_blendedmvs_sequence(const std::string& root, const std::string& name,
                               const std::vector<LayoutFrame>& frames) {
  if (frames.empty()) throw std::invalid_argument("write_blendedmvs_sequence: no frames");
  const fs::path dir = fs::path(root) / name;
  for (const char* sub : {"blended_images", "rendered_depth_maps", "cams"}) {
    layouts::make_dirs((dir / sub).string());
  }
  const std::size_t n = frames.size();
  for (std::size_t i = 0; i < n; ++i) {
    const LayoutFrame& f = frames[i];
    const std::string id = id_name(i);
    const std::string image = (dir / "blended_images" / (id + ".jpg")).string();
    layouts::write_image(image, f.bgr, {cv::IMWRITE_JPEG_QUALITY, 95});
    write_pfm((dir / "rendered_depth_maps" / (id + ".pfm")).string(), f.depth_m);
    write_camera((dir / "cams" / (id + "_cam.txt")).string(), f);
  }
  // Each view's neighbours: those within 3 along the path, nearest first.
  std::ostringstream out;
  out << n << "\n";
  for (std::size_t i = 0; i < n; ++i) {
    std::vector<std::size_t> near;
    for (std::size_t d = 1; d <= 3; ++d) {
      if (i >= d) near.push_back(i - d);
      if (i + d < n) near.push_back(i + d);
    }
    out << i << "\n" << near.size();
    for (const std::size_t j : near) {
      const double gap = j > i ? static_cast<double>(j - i) : static_cast<double>(i - j);
      out << " " << j << " " << 1.0 / (1.0 + gap);
    }
    out << "\n";
  }
  layouts::write_text((dir / "cams" / "pair.txt").string(), out.str());

  // In the "train" split, once however often the scene is written.
  layouts::list_once((fs::path(root) / "train_list.txt").string(), name);
}

}  // namespace long3r::synth
